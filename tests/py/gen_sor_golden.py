#!/usr/bin/env python3
"""Golden fixture for awl's statistical outlier removal: Open3D 0.20 on a real third-party PCD.

    .venv/bin/python tests/py/gen_sor_golden.py [-o crates/awl/tests/data/sor_table_mug_open3d.json]

Loads `pcl/table_scene_mug_stereo_textured.pcd` from the shared data folder (`$AWL_SHARED_DATA`, else
`<repo>/../shared/data`), drops the non-finite points while keeping file order (awl's PCD reader drops
NaN points the same way; 209,280 remain), runs
`remove_statistical_outlier(nb_neighbors=20, std_ratio=2.0)` and writes the indices (into the finite
cloud) of the REMOVED points, ascending. `crates/awl/tests/outlier_open3d.rs` compares awl against it.

Needs open3d-cpu==0.20.0 and numpy (see ../shared/bench/peers/requirements.txt). Open3D's SOR result
does not depend on its thread count (per-point averages, then a serial reduction in index order).
"""

import argparse
import json
import os
import sys

import numpy as np
import open3d as o3d

REPO = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
REL = "pcl/table_scene_mug_stereo_textured.pcd"
EXPECTED_FINITE = 209_280
NB_NEIGHBORS = 20
STD_RATIO = 2.0


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    default_out = os.path.join(REPO, "crates", "awl", "tests", "data", "sor_table_mug_open3d.json")
    parser.add_argument("-o", "--out", default=default_out)
    args = parser.parse_args()

    data = os.environ.get("AWL_SHARED_DATA") or os.path.join(REPO, "..", "shared", "data")
    path = os.path.join(data, REL)
    if not os.path.isfile(path):
        print(f"missing {path}: set AWL_SHARED_DATA", file=sys.stderr)
        return 2

    raw = o3d.io.read_point_cloud(path, remove_nan_points=False, remove_infinite_points=False)
    xyz = np.asarray(raw.points)
    finite = np.isfinite(xyz).all(axis=1)
    pts = xyz[finite]  # boolean mask keeps file order
    if len(pts) != EXPECTED_FINITE:
        print(f"{path}: {len(pts)} finite points, expected {EXPECTED_FINITE}", file=sys.stderr)
        return 1

    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(pts))
    _, kept = cloud.remove_statistical_outlier(nb_neighbors=NB_NEIGHBORS, std_ratio=STD_RATIO)
    kept = np.asarray(kept, dtype=np.int64)
    removed = np.setdiff1d(np.arange(len(pts), dtype=np.int64), kept)

    fixture = {
        "source": f"shared/data/{REL} (non-finite points dropped, file order kept)",
        "open3d_version": o3d.__version__,
        "call": f"remove_statistical_outlier(nb_neighbors={NB_NEIGHBORS}, std_ratio={STD_RATIO})",
        "nb_neighbors": NB_NEIGHBORS,
        "std_ratio": STD_RATIO,
        "points": int(len(pts)),
        "kept": int(len(kept)),
        "removed_indices": [int(i) for i in removed],
    }
    os.makedirs(os.path.dirname(os.path.abspath(args.out)), exist_ok=True)
    with open(args.out, "w") as f:
        json.dump(fixture, f, separators=(",", ":"))
        f.write("\n")
    print(f"{args.out}: {len(pts)} points, {len(kept)} kept, {len(removed)} removed")
    return 0


if __name__ == "__main__":
    sys.exit(main())
