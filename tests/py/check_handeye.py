#!/usr/bin/env python3
"""Independent hand-eye solution with OpenCV's cv2.calibrateHandEye (no awl code).

Reads an `awl-handeye/1` poses file ({"format": "awl-handeye/1", "poses": [{"T_base_ee": 4x4,
"T_camera_target": 4x4}, ...]}, row-major, metres) and writes OpenCV's `T_ee_camera` as JSON.
OpenCV's conventions: R_gripper2base/t_gripper2base = T_base_ee, R_target2cam/t_target2cam =
T_camera_target, and the output cam2gripper = T_ee_camera.

Usage: check_handeye.py POSES.json OUT.json [--method park|tsai|daniilidis|horaud|andreff]
Exit 0 on success, 2 on unusable input.
"""
import argparse
import json
import sys

import cv2
import numpy as np

METHODS = {
    "park": cv2.CALIB_HAND_EYE_PARK,
    "tsai": cv2.CALIB_HAND_EYE_TSAI,
    "daniilidis": cv2.CALIB_HAND_EYE_DANIILIDIS,
    "horaud": cv2.CALIB_HAND_EYE_HORAUD,
    "andreff": cv2.CALIB_HAND_EYE_ANDREFF,
}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("poses")
    ap.add_argument("out")
    ap.add_argument("--method", choices=sorted(METHODS), default="park")
    args = ap.parse_args()
    try:
        with open(args.poses) as f:
            doc = json.load(f)
        if doc.get("format") != "awl-handeye/1":
            raise ValueError(f"format is {doc.get('format')!r}, expected 'awl-handeye/1'")
        base_ee = [np.asarray(p["T_base_ee"], dtype=np.float64) for p in doc["poses"]]
        cam_target = [np.asarray(p["T_camera_target"], dtype=np.float64) for p in doc["poses"]]
        if len(base_ee) < 3 or any(m.shape != (4, 4) for m in base_ee + cam_target):
            raise ValueError("need at least 3 poses of 4x4 matrices")
    except (OSError, ValueError, KeyError, TypeError) as e:
        print(f"{args.poses}: unusable input: {e}", file=sys.stderr)
        return 2
    r_cam2gripper, t_cam2gripper = cv2.calibrateHandEye(
        [m[:3, :3] for m in base_ee],
        [m[:3, 3].reshape(3, 1) for m in base_ee],
        [m[:3, :3] for m in cam_target],
        [m[:3, 3].reshape(3, 1) for m in cam_target],
        method=METHODS[args.method],
    )
    t = np.eye(4)
    t[:3, :3] = r_cam2gripper
    t[:3, 3] = np.asarray(t_cam2gripper).ravel()
    with open(args.out, "w") as f:
        json.dump({"T_ee_camera": t.tolist(), "method": args.method, "opencv": cv2.__version__}, f, indent=1)
    print(f"OpenCV {cv2.__version__} {args.method}: t = {t[:3, 3].tolist()} m")
    return 0


if __name__ == "__main__":
    sys.exit(main())
