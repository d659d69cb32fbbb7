#!/usr/bin/env python3
"""Reference tag36h11 detections by pupil-apriltags (the AprilTag 3 C library's Python binding).

    python3 tests/py/check_tags.py [--decimate 2.0] [--fx FX --fy FY --cx CX --cy CY --tag-size S] IMAGE...

Prints one JSON object to stdout: {"detector": ..., "images": {IMAGE: [detection, ...]}}, each
detection with `id`, `hamming`, `decision_margin`, `corners` and `center` EXACTLY as the library
reports them (pixel centres at +0.5: no convention change here, the caller converts), and, when the
intrinsics and tag size are given, the library's own pose (`pose_R`, `pose_t`: AprilTag frame,
x right, y down, z into the tag face; homography + orthogonal iteration).

Exit code 0 on success, 2 when pupil_apriltags is missing or an image cannot be read.
"""

import argparse
import json
import sys

import numpy as np
from PIL import Image


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[1])
    ap.add_argument("images", nargs="+")
    ap.add_argument("--decimate", type=float, default=2.0)
    for k in ("fx", "fy", "cx", "cy", "tag-size"):
        ap.add_argument("--" + k, type=float)
    args = ap.parse_args()
    try:
        import pupil_apriltags
    except ImportError as e:
        print(f"pupil_apriltags is not installed ({e}): pip install -r tests/py/requirements.txt", file=sys.stderr)
        return 2
    detector = pupil_apriltags.Detector(families="tag36h11", nthreads=1, quad_decimate=args.decimate)
    pose = None not in (args.fx, args.fy, args.cx, args.cy, args.tag_size)
    out = {"detector": f"pupil_apriltags {getattr(pupil_apriltags, '__version__', '?')}", "images": {}}
    for path in args.images:
        try:
            # ITU-R BT.601 luma, like awl's ColorImage::to_gray (rounded, integer arithmetic).
            rgb = np.asarray(Image.open(path).convert("RGB"), dtype=np.uint32)
        except OSError as e:
            print(f"{path}: {e}", file=sys.stderr)
            return 2
        gray = ((299 * rgb[..., 0] + 587 * rgb[..., 1] + 114 * rgb[..., 2] + 500) // 1000).astype(np.uint8)
        kwargs = {}
        if pose:
            kwargs = dict(estimate_tag_pose=True, camera_params=(args.fx, args.fy, args.cx, args.cy),
                          tag_size=args.tag_size)
        dets = []
        for d in detector.detect(np.ascontiguousarray(gray), **kwargs):
            rec = {
                "id": int(d.tag_id),
                "hamming": int(d.hamming),
                "decision_margin": float(d.decision_margin),
                "corners": np.asarray(d.corners, dtype=float).tolist(),
                "center": np.asarray(d.center, dtype=float).tolist(),
            }
            if pose:
                rec["pose_R"] = np.asarray(d.pose_R, dtype=float).tolist()
                rec["pose_t"] = np.asarray(d.pose_t, dtype=float).ravel().tolist()
                rec["pose_err"] = float(d.pose_err)
            dets.append(rec)
        out["images"][path] = dets
    json.dump(out, sys.stdout)
    return 0


if __name__ == "__main__":
    sys.exit(main())
