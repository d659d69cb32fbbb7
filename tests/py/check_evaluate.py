#!/usr/bin/env python3
"""Independent check of `awl evaluate`'s numbers with Open3D (no awl code).

Usage: check_evaluate.py OUT_DIR MODEL.ply CAD.ply [--tolerance 0.05] [--json OUT.json]

Reads OUT_DIR/summary.json and OUT_DIR/T_object_model.json, moves MODEL (its own frame, e.g. world)
into the CAD frame with that T_object_model, then:
  - model -> CAD distance: o3d PointCloud.compute_point_cloud_distance from the model points to a
    dense uniform sampling of the CAD surface (density --density per m^2): the distance to the
    nearest CAD sample, an overestimate of the distance to the surface by about the sample spacing;
    also the exact point-to-mesh distance (o3d RaycastingScene.compute_distance) for reference.
    RMSE over the on-object points (distance <= summary's on_object_m) and over all points.
  - completeness: CAD samples (100 000, uniform) -> model distance (compute_point_cloud_distance);
    the share within 5 mm among samples whose outward normal, turned into the model frame, is not
    within summary's facing_down_deg of -up_model (same rule as awl, independent samples).
Each must agree with summary.json within --tolerance (relative). Exit 0 pass, 1 fail, 2 unusable input.
"""
import argparse
import json
import math
import sys

import numpy as np

try:
    import open3d as o3d
except ImportError as e:  # pragma: no cover
    print(f"open3d missing: {e}", file=sys.stderr)
    sys.exit(2)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("out_dir")
    ap.add_argument("model")
    ap.add_argument("cad")
    ap.add_argument("--tolerance", type=float, default=0.05)
    ap.add_argument("--density", type=float, default=1e7, help="CAD samples per m^2 for the distances")
    ap.add_argument("--json")
    a = ap.parse_args()
    try:
        with open(f"{a.out_dir}/summary.json") as f:
            summary = json.load(f)
        with open(f"{a.out_dir}/T_object_model.json") as f:
            t = np.array(json.load(f)["T_object_model"], dtype=float)
        model = o3d.io.read_point_cloud(a.model)
        mesh = o3d.io.read_triangle_mesh(a.cad)
    except (OSError, KeyError, ValueError) as e:
        print(f"unusable input: {e}", file=sys.stderr)
        return 2
    if len(model.points) == 0 or len(mesh.triangles) == 0 or t.shape != (4, 4):
        print("unusable input: empty model or CAD, or T not 4x4", file=sys.stderr)
        return 2
    o3d.utility.random.seed(7)
    model.transform(t)
    mesh.compute_triangle_normals()
    area = mesh.get_surface_area()
    n_dense = int(min(1.2e7, max(1e5, a.density * area)))
    dense = mesh.sample_points_uniformly(number_of_points=n_dense)
    d = np.asarray(model.compute_point_cloud_distance(dense))
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.t.geometry.TriangleMesh.from_legacy(mesh))
    exact = scene.compute_distance(o3d.core.Tensor(np.asarray(model.points, dtype=np.float32))).numpy()

    on_m = summary["distances"]["on_object_m"]
    rmse = lambda x: float(math.sqrt(np.mean(np.square(x)))) if len(x) else float("nan")
    theirs = {
        "rmse_on_object_mm": rmse(d[d <= on_m]) * 1e3,
        "rmse_all_mm": rmse(d) * 1e3,
        "rmse_on_object_exact_mm": rmse(exact[exact <= on_m]) * 1e3,
    }
    comp = summary["completeness"]
    samples = mesh.sample_points_uniformly(number_of_points=100_000, use_triangle_normal=True)
    normals_model = np.asarray(samples.normals) @ t[:3, :3]  # rows: R^T n, i.e. object -> model frame
    up = np.array(comp["up_model"], dtype=float)
    up /= np.linalg.norm(up)
    keep = np.ones(len(normals_model), dtype=bool)
    if comp["facing_down_deg"] is not None:
        keep = -(normals_model @ up) < math.cos(math.radians(comp["facing_down_deg"]))
    samples_model_frame = samples.select_by_index(np.flatnonzero(keep).tolist())
    dc = np.asarray(samples_model_frame.compute_point_cloud_distance(model))
    theirs["completeness_5mm"] = float(np.mean(dc <= 0.005))
    theirs["completeness_counted_share"] = float(np.mean(keep))

    ours = {
        "rmse_on_object_mm": summary["distances"]["on_object"]["rmse_m"] * 1e3,
        "rmse_all_mm": summary["distances"]["all"]["rmse_m"] * 1e3,
        "completeness_5mm": next(c["fraction"] for c in comp["thresholds"] if abs(c["threshold_mm"] - 5.0) < 1e-9),
        "completeness_counted_share": comp["samples_counted"] / comp["samples"],
    }
    failures = []
    for key in ["rmse_on_object_mm", "rmse_all_mm", "completeness_5mm", "completeness_counted_share"]:
        rel = abs(ours[key] - theirs[key]) / max(abs(theirs[key]), 1e-12)
        status = "ok" if rel <= a.tolerance else "FAIL"
        print(f"{key}: awl {ours[key]:.4f}, open3d {theirs[key]:.4f}, relative difference {rel:.4f} {status}")
        if rel > a.tolerance:
            failures.append(key)
    print(f"(open3d exact point-to-mesh on-object RMSE {theirs['rmse_on_object_exact_mm']:.4f} mm; "
          f"{n_dense} dense CAD samples, {len(d)} model points)")
    if a.json:
        with open(a.json, "w") as f:
            json.dump({"awl": ours, "open3d": theirs, "failures": failures}, f, indent=2)
    return 1 if failures else 0


if __name__ == "__main__":
    sys.exit(main())
