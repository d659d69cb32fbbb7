#!/usr/bin/env python3
"""Seed corpora for the coverage-guided fuzz targets (fuzz/fuzz_targets/*.rs): small valid files of
every format, written into fuzz/corpus/<target>/ (not committed: run again on a new checkout).

Clouds, meshes, images and the JSON formats are generated here (numpy, Pillow); scan.json and the
hand-eye poses also come from `awl` itself (simulate, calibrate --write-simulated) and from the
small files of ../shared/data, and workpiece.json and plan.json from a short `awl fuse` +
`awl pierce` run on shared/data's sim_reference scans when the binary and the data are there.

Usage: seeds.py CORPUS_DIR [--awl PATH] [--shared-data DIR]
"""

import argparse
import io
import json
import math
import shutil
import struct
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np
from PIL import Image


def put(corpus: Path, target: str, name: str, data: bytes) -> None:
    d = corpus / target
    d.mkdir(parents=True, exist_ok=True)
    (d / name).write_bytes(data)


def points(n: int, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    p = rng.uniform(-0.2, 0.2, (n, 3)).astype(np.float32)
    p[:, 2] += 0.6
    return p


def ply(fmt: str, p: np.ndarray, normals=None, colors=None, faces=None, f64=False) -> bytes:
    ty = "double" if f64 else "float"
    head = [f"ply", f"format {fmt} 1.0", "comment awl fuzz seed", f"element vertex {len(p)}"]
    head += [f"property {ty} {c}" for c in "xyz"]
    if normals is not None:
        head += [f"property float n{c}" for c in "xyz"]
    if colors is not None:
        head += [f"property uchar {c}" for c in ("red", "green", "blue")]
    if faces is not None:
        head += [f"element face {len(faces)}", "property list uchar int vertex_indices"]
    head.append("end_header")
    out = ("\n".join(head) + "\n").encode()
    if fmt == "ascii":
        rows = []
        for i in range(len(p)):
            row = [repr(float(v)) for v in p[i]]
            if normals is not None:
                row += [repr(float(v)) for v in normals[i]]
            if colors is not None:
                row += [str(int(v)) for v in colors[i]]
            rows.append(" ".join(row))
        for f in faces if faces is not None else []:
            rows.append(" ".join(str(v) for v in [len(f), *f]))
        return out + ("\n".join(rows) + "\n").encode()
    e = "<" if fmt == "binary_little_endian" else ">"
    body = bytearray()
    for i in range(len(p)):
        body += struct.pack(e + ("3d" if f64 else "3f"), *p[i])
        if normals is not None:
            body += struct.pack(e + "3f", *normals[i])
        if colors is not None:
            body += bytes(int(v) for v in colors[i])
    for f in faces if faces is not None else []:
        body += struct.pack(e + "B" + "i" * len(f), len(f), *f)
    return out + bytes(body)


def pcd(data: str, p: np.ndarray, normals=None, rgb=None, width=None) -> bytes:
    fields = ["x", "y", "z"] + (["normal_x", "normal_y", "normal_z"] if normals is not None else [])
    fields += ["rgb"] if rgb is not None else []
    k = len(fields)
    n = len(p)
    width = width or n
    head = (
        f"# .PCD v0.7 - Point Cloud Data file format\nVERSION 0.7\nFIELDS {' '.join(fields)}\n"
        f"SIZE {' '.join(['4'] * k)}\nTYPE {' '.join(['F'] * (k - (rgb is not None)) + (['U'] if rgb is not None else []))}\n"
        f"COUNT {' '.join(['1'] * k)}\nWIDTH {width}\nHEIGHT {n // width}\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS {n}\nDATA {data}\n"
    ).encode()
    cols = [p[:, 0], p[:, 1], p[:, 2]]
    if normals is not None:
        cols += [normals[:, 0], normals[:, 1], normals[:, 2]]
    if data == "ascii":
        rows = []
        for i in range(n):
            row = [repr(float(c[i])) for c in cols] + ([str(int(rgb[i]))] if rgb is not None else [])
            rows.append(" ".join(row))
        return head + ("\n".join(rows) + "\n").encode()
    if data == "binary":
        body = bytearray()
        for i in range(n):
            body += struct.pack("<%df" % len(cols), *[c[i] for c in cols])
            if rgb is not None:
                body += struct.pack("<I", int(rgb[i]))
        return head + bytes(body)
    # binary_compressed: the fields column by column, then LZF
    raw = b"".join(np.asarray(c, dtype="<f4").tobytes() for c in cols)
    if rgb is not None:
        raw += np.asarray(rgb, dtype="<u4").tobytes()
    packed = lzf(raw)
    return head + struct.pack("<II", len(packed), len(raw)) + packed


def lzf(data: bytes) -> bytes:
    """A small LZF compressor (literal runs and back-references), as liblzf's format."""
    out = bytearray()
    lit = bytearray()
    seen = {}
    i = 0

    def flush():
        nonlocal lit
        while lit:
            chunk, lit = lit[:32], lit[32:]
            out.append(len(chunk) - 1)
            out.extend(chunk)

    while i < len(data):
        key = data[i : i + 3]
        ref = seen.get(key) if len(key) == 3 else None
        seen[key] = i
        if ref is not None and 0 < i - ref - 1 < 8192:
            length = 3
            while i + length < len(data) and length < 264 and data[ref + length] == data[i + length]:
                length += 1
            flush()
            off = i - ref - 1
            l = length - 2
            if l < 7:
                out.append((l << 5) | (off >> 8))
            else:
                out.append((7 << 5) | (off >> 8))
                out.append(l - 7)
            out.append(off & 0xFF)
            i += length
        else:
            lit.append(data[i])
            i += 1
    flush()
    return bytes(out)


def stl_ascii(tris) -> bytes:
    rows = ["solid seed"]
    for t in tris:
        rows += ["facet normal 0 0 1", "outer loop"] + [f"vertex {a} {b} {c}" for a, b, c in t]
        rows += ["endloop", "endfacet"]
    rows.append("endsolid seed")
    return ("\n".join(rows) + "\n").encode()


def stl_binary(tris, header=b"binary seed") -> bytes:
    out = bytearray(header.ljust(80, b" ")) + struct.pack("<I", len(tris))
    for t in tris:
        out += struct.pack("<3f", 0, 0, 1)
        for v in t:
            out += struct.pack("<3f", *v)
        out += b"\0\0"
    return bytes(out)


def png(img: Image.Image, **kw) -> bytes:
    buf = io.BytesIO()
    img.save(buf, format="PNG", **kw)
    return buf.getvalue()


def jpeg(img: Image.Image, **kw) -> bytes:
    buf = io.BytesIO()
    img.save(buf, format="JPEG", **kw)
    return buf.getvalue()


def identity():
    return [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]


def pose(tx, ty, tz, yaw=0.0):
    c, s = math.cos(yaw), math.sin(yaw)
    return [[c, -s, 0, tx], [s, c, 0, ty], [0, 0, 1, tz], [0, 0, 0, 1]]


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("corpus", type=Path)
    ap.add_argument("--awl", type=Path)
    ap.add_argument("--shared-data", type=Path)
    args = ap.parse_args()
    corpus = args.corpus
    corpus.mkdir(parents=True, exist_ok=True)

    # clouds and meshes
    p = points(40, 1)
    normals = np.tile(np.array([[0, 0, -1]], np.float32), (len(p), 1))
    colors = np.stack([np.arange(40) * 6, 255 - np.arange(40) * 6, np.full(40, 128)], 1)
    quad = np.array([[0, 0, 0], [0.1, 0, 0], [0.1, 0.1, 0], [0, 0.1, 0]], np.float32)
    for fmt in ("ascii", "binary_little_endian", "binary_big_endian"):
        put(corpus, "ply", f"{fmt}.ply", ply(fmt, p))
        put(corpus, "ply", f"{fmt}_nc.ply", ply(fmt, p, normals, colors))
        put(corpus, "ply", f"{fmt}_mesh.ply", ply(fmt, quad, faces=[[0, 1, 2], [0, 2, 3]], f64=True))
    put(corpus, "ply", "quad_polygon.ply", ply("ascii", quad, faces=[[0, 1, 2, 3]]))
    rgb = [(int(c[0]) << 16) | (int(c[1]) << 8) | int(c[2]) for c in colors]
    for data in ("ascii", "binary", "binary_compressed"):
        put(corpus, "pcd", f"{data}.pcd", pcd(data, p))
        put(corpus, "pcd", f"{data}_nc.pcd", pcd(data, p, normals, rgb))
    grid = points(48, 2)
    grid[5] = np.nan
    put(corpus, "pcd", "organised_compressed.pcd", pcd("binary_compressed", grid, width=8))
    put(corpus, "pcd", "organised_ascii.pcd", pcd("ascii", grid, width=8))
    tris = [[(0, 0, 0), (1, 0, 0), (0, 1, 0)], [(1, 0, 0), (1, 1, 0), (0, 1, 0)], [(0, 0, 1), (1, 0, 1), (0, 1, 1)]]
    put(corpus, "stl", "ascii.stl", stl_ascii(tris))
    put(corpus, "stl", "binary.stl", stl_binary(tris))
    put(corpus, "stl", "binary_solid_header.stl", stl_binary(tris, b"solid but binary"))
    obj = "o quad\nv 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nvn 0 0 1\nvt 0 0\nf 1/1/1 2/1/1 3/1/1 4/1/1\n"
    put(corpus, "obj", "quad.obj", obj.encode())
    put(corpus, "obj", "two.obj", b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\no b\nv 0 0 1\nv 1 0 1\nv 0 1 1\nf -3 -2 -1\n")
    put(corpus, "obj", "groups.obj", b"g a\nv 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\nf 1//1 2//1 3//1\ns 1\nf 2 4 3\nl 1 2\n")

    # images
    yy, xx = np.mgrid[0:24, 0:32]
    depth = (600 + 10 * xx + 3 * yy).astype(np.uint16)
    depth[3:6, 4:9] = 0
    put(corpus, "png_depth", "depth16.png", png(Image.fromarray(depth)))
    put(corpus, "png_depth", "gray8.png", png(Image.fromarray((depth // 8).astype(np.uint8))))
    color = np.stack([xx * 8, yy * 10, (xx + yy) * 4], -1).astype(np.uint8)
    rgb_img = Image.fromarray(color)
    put(corpus, "png_color", "rgb.png", png(rgb_img))
    put(corpus, "png_color", "rgba.png", png(rgb_img.convert("RGBA")))
    put(corpus, "png_color", "gray.png", png(rgb_img.convert("L")))
    put(corpus, "png_color", "gray_alpha.png", png(rgb_img.convert("LA")))
    put(corpus, "png_color", "palette.png", png(rgb_img.convert("P")))
    put(corpus, "jpeg_color", "baseline.jpg", jpeg(rgb_img, quality=80))
    put(corpus, "jpeg_color", "progressive.jpg", jpeg(rgb_img, quality=80, progressive=True))
    put(corpus, "jpeg_color", "gray.jpg", jpeg(rgb_img.convert("L"), quality=70))
    put(corpus, "jpeg_color", "444.jpg", jpeg(rgb_img, quality=90, subsampling=0))
    try:
        put(corpus, "jpeg_color", "restart.jpg", jpeg(rgb_img, quality=60, restart_marker_blocks=2))
    except (TypeError, ValueError, OSError):
        pass

    # JSON formats
    camera = {"width": 32, "height": 24, "fx": 40.0, "fy": 40.0, "cx": 15.5, "cy": 11.5, "distortion": [0.01, 0, 0, 0, 0],
              "depth_scale": 0.001, "depth_min": 0.15, "depth_max": 3.0}
    scan = {"format": "awl-scan/1", "camera": camera, "T_ee_camera": pose(0, 0, 0.05),
            "tag": {"family": "tag36h11", "id": 3, "size": 0.08},
            "views": [
                {"depth": "depth/000000.png", "color": "color/000000.png", "T_world_base": identity(),
                 "T_base_ee": pose(0.4, 0, 0.5, 0.3), "base_stop": 0, "q": [0, -1.2, 1.4, -1.8, -1.57, 0.4], "stamp": 1.5},
                {"points": "clouds/000001.ply", "T_world_camera": pose(0.1, 0.2, 0.3, -0.5)},
            ]}
    put(corpus, "scan_json", "scan.json", json.dumps(scan, indent=1).encode())
    put(corpus, "scan_json", "camera_only.json",
        json.dumps({"format": "awl-scan/1", "views": [{"points": "a.pcd", "T_world_camera": identity()}]}).encode())
    tag = {"family": "tag36h11", "id": 0, "size": 0.08}
    workpiece = {"format": "awl-workpiece/1", "model": "model.ply", "T_world_tag": pose(0.1, 0.2, 0.3, 0.2),
                 "tag": tag, "views_checked": [0, 1], "detections": [], "refinement": None,
                 "floor": {"normal": [0, 0, 1], "offset": 0.0}, "hand_eye": None, "warnings": []}
    put(corpus, "workpiece_json", "minimal.json", json.dumps(workpiece).encode())
    dh = [{"a": 0, "alpha": math.pi / 2, "d": 0.1625, "theta_offset": 0}, {"a": -0.425, "alpha": 0, "d": 0},
          {"a": -0.3922, "alpha": 0, "d": 0}, {"a": 0, "alpha": math.pi / 2, "d": 0.1333},
          {"a": 0, "alpha": -math.pi / 2, "d": 0.0997}, {"a": 0, "alpha": 0, "d": 0.0996}]
    arm = {"format": "awl-arm/1", "name": "seed-ur5e", "dh": dh, "limits": [[-2 * math.pi, 2 * math.pi]] * 6,
           "T_dh6_flange": identity()}
    put(corpus, "arm_file", "ur5e.json", json.dumps(arm, indent=1).encode())
    put(corpus, "arm_file", "no_flange.json", json.dumps({k: v for k, v in arm.items() if k != "T_dh6_flange"}).encode())
    ur = "def awl_pierce():\n  set_tcp(p[0, 0, 0.15, 0, 0, 0])\n  movel(p[0.45, 0.15, 0.11, 3.14, 0, 0], a=0.5, v=0.02)\nend\n"
    plan = {"format": "awl-plan/1", "programs": {"urscript": ur, "techman": "$TMSCT,9,1,Exit(),*4C\r\n"},
            "targets": [{"target": "0.1,0.1,0.1", "go": True, "reach": {"reachable": True}},
                        {"target": "face-centre@0,0,0.2", "go": False, "why": "95 % bound 3 mm > 2 mm",
                         "reach": {"reachable": False, "reason": "out of reach"}}]}
    put(corpus, "plan_json", "plan.json", json.dumps(plan, indent=1).encode())
    put(corpus, "fuse_config", "override.json",
        b'{"pixel_step": 2, "registration": {"icp": {"kernel": "huber"}}, "smoothing": null, "roi": {"radius_m": 0.5}}')
    put(corpus, "fuse_config", "override.toml",
        b'pixel_step = 2\n[roi]\nradius_m = 0.6\n[registration.icp]\nkernel = "huber"\n[isolate.floor.plane]\niterations = 500\n')
    poses = {"format": "awl-handeye/1", "poses": [
        {"T_base_ee": pose(0.4 + 0.01 * i, 0.05 * i, 0.5, 0.2 * i), "T_camera_target": pose(0.02 * i, 0, 0.4, -0.1 * i)}
        for i in range(4)]}
    put(corpus, "handeye_poses", "handmade.json", json.dumps(poses).encode())

    # from awl itself and shared/data, where available
    shared = args.shared_data
    if shared and shared.is_dir():
        for rel in ["sim_reference/box_seed1/scan.json", "sim_reference/box_seed1_shot_tilt30/scan.json",
                    "sim_reference/calib_seed1/scan.json"]:
            if (shared / rel).is_file():
                put(corpus, "scan_json", rel.replace("/", "_"), (shared / rel).read_bytes())
        for rel in ["sim_reference/box_seed1/cad.ply"]:
            if (shared / rel).is_file():
                put(corpus, "ply", rel.replace("/", "_"), (shared / rel).read_bytes())
        for f in sorted((shared / "apriltag_tag36h11").glob("*.png"))[:3]:
            put(corpus, "png_color", f.name, f.read_bytes())
        bun4 = shared / "pcl/test/bun4.pcd"
        if bun4.is_file():
            put(corpus, "pcd", "bun4.pcd", bun4.read_bytes())
    awl = args.awl
    if awl and awl.is_file():
        with tempfile.TemporaryDirectory() as tmp:
            t = Path(tmp)
            run = lambda *a: subprocess.run([str(awl), *a], capture_output=True, text=True)
            r = run("calibrate", "hand-eye", "--write-simulated", str(t / "poses.json"), "--count", "6")
            if r.returncode == 0:
                put(corpus, "handeye_poses", "simulated.json", (t / "poses.json").read_bytes())
            r = run("simulate", "--scene", "box", "--views", "2", "--seed", "4", "-o", str(t / "scan"))
            if r.returncode == 0:
                put(corpus, "scan_json", "simulated.json", (t / "scan/scan.json").read_bytes())
            if shared and (shared / "sim_reference/box_seed1").is_dir():
                r = run("fuse", str(shared / "sim_reference/box_seed1"), "-o", str(t / "fuse"), "--preset", "fast", "--quiet")
                wp = t / "fuse/workpiece.json"
                if r.returncode == 0 and wp.is_file():
                    put(corpus, "workpiece_json", "fused.json", wp.read_bytes())
                    shot = shared / "sim_reference/box_seed1_shot_tilt30"
                    (t / "tcp.json").write_text(json.dumps({"T_ee_tool": pose(0, 0, 0.15)}))
                    r = run("pierce", str(wp), "--shot", str(shot), "--target", "face-centre@0.19,-0.05,0.31",
                            "--target", "0.1,0.0,0.31", "--robot", "ur10e", "--tcp", str(t / "tcp.json"),
                            "-o", str(t / "plan.json"))
                    if (t / "plan.json").is_file():
                        put(corpus, "plan_json", "pierced.json", (t / "plan.json").read_bytes())
    for d in sorted(corpus.iterdir()):
        files = list(d.iterdir())
        print(f"{d.name:>15}: {len(files):>2} seeds, {sum(f.stat().st_size for f in files):>7} bytes")
    return 0


if __name__ == "__main__":
    sys.exit(main())
