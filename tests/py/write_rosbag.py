#!/usr/bin/env python3
"""Writes a rosbag2 recording of an awl scan folder with the independent `rosbags` package.

The bag replays the rig as a ROS 2 system records it: the arm and the base stand still at each of
the scan's views (`--still-s` seconds) and move between them (translation interpolated linearly,
rotation by slerp, with a smoothstep in time), TF on /tf at `--tf-hz` (map -> base_link and
base_link -> tool0), the hand-eye on /tf_static (tool0 -> camera_color_optical_frame), depth on
/camera/depth/image_rect_raw at `--image-hz` with its CameraInfo, and color `--color-delay-ms`
after each depth frame. Image stamps fall between TF samples (offset `--image-offset-ms`).

Usage: write_rosbag.py SCAN_DIR OUT_BAG [--storage mcap|sqlite3] [--depth 16UC1|32FC1]
       [--color rgb8|bgr8|jpeg|png|none|yuv422] [--bad no-still|tf-gap] [--truth OUT.json]

`--truth` writes, for the Rust test, the true poses at stamps between TF samples during the
motions (`moving`) and each view's still period (`stills`, nanoseconds).
Used by crates/awl-cli/tests/import_rosbag.rs (AWL_PYTHON).
"""

import argparse
import io
import json
import sys
from pathlib import Path

import numpy as np
from PIL import Image as PilImage
from rosbags.rosbag2 import StoragePlugin, Writer
from rosbags.typesys import Stores, get_typestore

TS = get_typestore(Stores.ROS2_HUMBLE)
T = TS.types
T0_NS = 1_700_000_000 * 1_000_000_000
CAMERA_FRAME = "camera_color_optical_frame"


def quat_from_matrix(r):
    """Unit quaternion (x, y, z, w) of a rotation matrix (Shepperd's method)."""
    tr = np.trace(r)
    if tr > 0:
        s = np.sqrt(tr + 1.0) * 2
        w, x, y, z = 0.25 * s, (r[2, 1] - r[1, 2]) / s, (r[0, 2] - r[2, 0]) / s, (r[1, 0] - r[0, 1]) / s
    elif r[0, 0] > r[1, 1] and r[0, 0] > r[2, 2]:
        s = np.sqrt(1.0 + r[0, 0] - r[1, 1] - r[2, 2]) * 2
        w, x, y, z = (r[2, 1] - r[1, 2]) / s, 0.25 * s, (r[0, 1] + r[1, 0]) / s, (r[0, 2] + r[2, 0]) / s
    elif r[1, 1] > r[2, 2]:
        s = np.sqrt(1.0 + r[1, 1] - r[0, 0] - r[2, 2]) * 2
        w, x, y, z = (r[0, 2] - r[2, 0]) / s, (r[0, 1] + r[1, 0]) / s, 0.25 * s, (r[1, 2] + r[2, 1]) / s
    else:
        s = np.sqrt(1.0 + r[2, 2] - r[0, 0] - r[1, 1]) * 2
        w, x, y, z = (r[1, 0] - r[0, 1]) / s, (r[0, 2] + r[2, 0]) / s, (r[1, 2] + r[2, 1]) / s, 0.25 * s
    q = np.array([x, y, z, w])
    return q / np.linalg.norm(q)


def matrix_from_quat(q):
    x, y, z, w = q
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
    ])


def slerp(q0, q1, s):
    d = float(np.dot(q0, q1))
    if d < 0:
        q1, d = -q1, -d
    if d > 0.9995:
        q = q0 + s * (q1 - q0)
        return q / np.linalg.norm(q)
    theta = np.arccos(d)
    return (np.sin((1 - s) * theta) * q0 + np.sin(s * theta) * q1) / np.sin(theta)


def pose(m):
    """(translation, quaternion) of a 4x4 matrix."""
    m = np.asarray(m, dtype=float)
    return m[:3, 3].copy(), quat_from_matrix(m[:3, :3])


def interp(a, b, s):
    return (1 - s) * a[0] + s * b[0], slerp(a[1], b[1], s)


def to_rows(p):
    m = np.eye(4)
    m[:3, :3] = matrix_from_quat(p[1])
    m[:3, 3] = p[0]
    return m.tolist()


def stamp(ns):
    return T["builtin_interfaces/msg/Time"](sec=int(ns // 1_000_000_000), nanosec=int(ns % 1_000_000_000))


def header(ns, frame):
    return T["std_msgs/msg/Header"](stamp=stamp(ns), frame_id=frame)


def transform(ns, parent, child, p):
    v = T["geometry_msgs/msg/Vector3"](x=float(p[0][0]), y=float(p[0][1]), z=float(p[0][2]))
    q = T["geometry_msgs/msg/Quaternion"](x=float(p[1][0]), y=float(p[1][1]), z=float(p[1][2]), w=float(p[1][3]))
    return T["geometry_msgs/msg/TransformStamped"](
        header=header(ns, parent), child_frame_id=child, transform=T["geometry_msgs/msg/Transform"](translation=v, rotation=q)
    )


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("scan")
    ap.add_argument("out")
    ap.add_argument("--storage", choices=["mcap", "sqlite3"], default="mcap")
    ap.add_argument("--depth", choices=["16UC1", "32FC1"], default="16UC1")
    ap.add_argument("--color", choices=["rgb8", "bgr8", "jpeg", "png", "none", "yuv422"], default="rgb8")
    ap.add_argument("--bad", choices=["no-still", "tf-gap"])
    ap.add_argument("--still-s", type=float, default=1.0)
    ap.add_argument("--move-s", type=float, default=0.8)
    ap.add_argument("--tf-hz", type=float, default=50.0)
    ap.add_argument("--image-hz", type=float, default=5.0)
    ap.add_argument("--image-offset-ms", type=float, default=7.0)
    ap.add_argument("--color-delay-ms", type=float, default=15.0)
    ap.add_argument("--truth")
    args = ap.parse_args()

    scan_dir = Path(args.scan)
    scan = json.loads((scan_dir / "scan.json").read_text())
    cam = scan["camera"]
    if abs(cam["depth_scale"] - 0.001) > 1e-12:
        sys.exit("the scan's depth_scale must be 0.001 (16UC1 is millimetres)")
    views = scan["views"]
    world_base = [pose(v["T_world_base"]) for v in views]
    base_ee = [pose(v["T_base_ee"]) for v in views]
    ee_camera = pose(scan["T_ee_camera"])

    still_ns = 0 if args.bad == "no-still" else int(args.still_s * 1e9)

    def angle(a, b):
        return 2 * np.arccos(min(1.0, abs(float(np.dot(a[1], b[1])))))

    # each move as long as a real rig needs: peak speeds (1.5x the mean under a smoothstep) of
    # 0.5 m/s and 45 deg/s for the base, 0.25 m/s and 45 deg/s for the flange
    moves_ns = []
    for i in range(len(views) - 1):
        need = [
            args.move_s,
            1.5 * np.linalg.norm(world_base[i + 1][0] - world_base[i][0]) / 0.5,
            1.5 * angle(world_base[i], world_base[i + 1]) / np.radians(45),
            1.5 * np.linalg.norm(base_ee[i + 1][0] - base_ee[i][0]) / 0.25,
            1.5 * angle(base_ee[i], base_ee[i + 1]) / np.radians(45),
        ]
        moves_ns.append(int(max(need) * 1e9))
    starts = [T0_NS]
    for m in moves_ns:
        starts.append(starts[-1] + still_ns + m)
    # no still period at all: the recording ends as the arm reaches the last view
    end_ns = starts[-1] + still_ns

    def at(ns):
        """(view index, world_base, base_ee) at time ns: still at a view or moving to the next."""
        for i, a in enumerate(starts):
            if ns < a + still_ns or i == len(views) - 1:
                return i, world_base[i], base_ee[i]
            if ns < a + still_ns + moves_ns[i]:
                u = (ns - a - still_ns) / moves_ns[i]
                s = u * u * (3 - 2 * u)
                return i, interp(world_base[i], world_base[i + 1], s), interp(base_ee[i], base_ee[i + 1], s)
        raise AssertionError

    cache = {}

    def image(i, kind):
        if (i, kind) not in cache:
            cache[(i, kind)] = np.asarray(PilImage.open(scan_dir / views[i][kind]))
        return cache[(i, kind)]

    storage = StoragePlugin.MCAP if args.storage == "mcap" else StoragePlugin.SQLITE3
    out = Path(args.out)
    tf_step = int(1e9 / args.tf_hz)
    gap = None
    if args.bad == "tf-gap":
        # 600 ms without TF inside the second still period (longer than the importer's 0.5 s)
        gap = (starts[1] + 100_000_000, starts[1] + still_ns - 300_000_000)
    with Writer(out, version=9, storage_plugin=storage) as w:
        c_tf = w.add_connection("/tf", "tf2_msgs/msg/TFMessage", typestore=TS)
        c_static = w.add_connection("/tf_static", "tf2_msgs/msg/TFMessage", typestore=TS)
        c_depth = w.add_connection("/camera/depth/image_rect_raw", "sensor_msgs/msg/Image", typestore=TS)
        c_info = w.add_connection("/camera/depth/camera_info", "sensor_msgs/msg/CameraInfo", typestore=TS)
        if args.color in ("jpeg", "png"):
            c_color = w.add_connection(
                "/camera/color/image_raw/compressed", "sensor_msgs/msg/CompressedImage", typestore=TS
            )
        elif args.color != "none":
            c_color = w.add_connection("/camera/color/image_raw", "sensor_msgs/msg/Image", typestore=TS)
        events = []  # (ns, order, connection, message, type)
        msg = T["tf2_msgs/msg/TFMessage"](transforms=[transform(T0_NS, "tool0", CAMERA_FRAME, ee_camera)])
        events.append((T0_NS, 0, c_static, msg, "tf2_msgs/msg/TFMessage"))
        ns = T0_NS
        while ns <= end_ns:
            if gap is None or not gap[0] <= ns <= gap[1]:
                _, wb, be = at(ns)
                msg = T["tf2_msgs/msg/TFMessage"](
                    transforms=[transform(ns, "map", "base_link", wb), transform(ns, "base_link", "tool0", be)]
                )
                events.append((ns, 1, c_tf, msg, "tf2_msgs/msg/TFMessage"))
            ns += tf_step
        d = cam.get("distortion") or [0.0] * 5
        k = np.array([cam["fx"], 0, cam["cx"], 0, cam["fy"], cam["cy"], 0, 0, 1], dtype=np.float64)
        p = np.array([cam["fx"], 0, cam["cx"], 0, 0, cam["fy"], cam["cy"], 0, 0, 0, 1, 0], dtype=np.float64)
        roi = T["sensor_msgs/msg/RegionOfInterest"](x_offset=0, y_offset=0, height=0, width=0, do_rectify=False)
        width, height = cam["width"], cam["height"]
        encoded = {}

        def depth_msg(ns, i):
            depth_mm = image(i, "depth").astype(np.uint16)
            if args.depth == "16UC1":
                data, step = depth_mm.astype("<u2").tobytes(), width * 2
            else:
                data, step = (depth_mm.astype(np.float32) * np.float32(0.001)).astype("<f4").tobytes(), width * 4
            return T["sensor_msgs/msg/Image"](
                header=header(ns, CAMERA_FRAME), height=height, width=width, encoding=args.depth, is_bigendian=0,
                step=step, data=np.frombuffer(data, dtype=np.uint8),
            )

        def info_msg(ns):
            return T["sensor_msgs/msg/CameraInfo"](
                header=header(ns, CAMERA_FRAME), height=height, width=width, distortion_model="plumb_bob",
                d=np.array(d, dtype=np.float64), k=k, r=np.eye(3).reshape(9), p=p, binning_x=0, binning_y=0, roi=roi,
            )

        def color_msg(cns, i):
            rgb = image(i, "color")[:, :, :3]
            if args.color in ("jpeg", "png"):
                if i not in encoded:
                    buf = io.BytesIO()
                    PilImage.fromarray(rgb).save(buf, format="JPEG" if args.color == "jpeg" else "PNG", quality=95)
                    encoded[i] = np.frombuffer(buf.getvalue(), dtype=np.uint8)
                return T["sensor_msgs/msg/CompressedImage"](
                    header=header(cns, CAMERA_FRAME), format=f"rgb8; {args.color} compressed bgr8", data=encoded[i]
                )
            if args.color == "yuv422":
                raw, cstep = np.zeros((height, width, 2), np.uint8).tobytes(), width * 2
            else:
                raw, cstep = (rgb if args.color == "rgb8" else rgb[:, :, ::-1]).tobytes(), width * 3
            return T["sensor_msgs/msg/Image"](
                header=header(cns, CAMERA_FRAME), height=height, width=width, encoding=args.color,
                is_bigendian=0, step=cstep, data=np.frombuffer(raw, dtype=np.uint8),
            )

        # the messages are built as they are written (a long bag is never held in memory)
        color_type = "sensor_msgs/msg/CompressedImage" if args.color in ("jpeg", "png") else "sensor_msgs/msg/Image"
        ns = T0_NS + int(args.image_offset_ms * 1e6)
        image_step = int(1e9 / args.image_hz)
        while ns <= end_ns:
            i, _, _ = at(ns)
            events.append((ns, 2, c_depth, lambda ns=ns, i=i: depth_msg(ns, i), "sensor_msgs/msg/Image"))
            events.append((ns, 3, c_info, lambda ns=ns: info_msg(ns), "sensor_msgs/msg/CameraInfo"))
            cns = ns + int(args.color_delay_ms * 1e6)
            if args.color != "none":
                events.append((cns, 4, c_color, lambda cns=cns, i=i: color_msg(cns, i), color_type))
            ns += image_step
        events.sort(key=lambda e: (e[0], e[1]))
        for ns, _, conn, msg, typ in events:
            w.write(conn, ns, TS.serialize_cdr(msg() if callable(msg) else msg, typ))

    if args.truth:
        moving = []
        for i in range(len(views) - 1):
            # stamps between TF samples (a third of the way) while the arm and the base move
            a = starts[i] + still_ns
            for j in range(1, 8):
                ns = a + j * moves_ns[i] // 8
                ns = ns - (ns - T0_NS) % tf_step + tf_step // 3
                _, wb, be = at(ns)
                moving.append({"stamp_ns": ns, "T_world_base": to_rows(wb), "T_base_ee": to_rows(be)})
        stills = [[a, a + still_ns] for a in starts]
        Path(args.truth).write_text(json.dumps({"moving": moving, "stills": stills}))


if __name__ == "__main__":
    main()
