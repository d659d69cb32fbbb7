#!/usr/bin/env python3
"""Independent check of a simulated `awl-scan/1` folder against its ground truth.

Written from the contract (shared/spec/scan-format.md) alone: numpy + Pillow + scipy, no awl code.

    python3 tests/py/check_scan.py SCAN_DIR --noise none|low|realistic|harsh [--json OUT.json]

It back-projects every depth pixel labelled workpiece (label 2) with the pinhole model (integer pixel
centres), moves it into the object frame with the TRUE camera pose and the TRUE object pose from
truth.json, and measures its exact distance to the CAD mesh (point-to-triangle, no approximation).
It also checks the floor (label 1) height in the world frame, the recorded poses in scan.json against
the true ones, and a few format rules (image sizes, depth range, labels vs. returns).

Exit code 0 when every check passes, 1 when one fails (each failure is printed), 2 on unusable input.
"""

import argparse
import json
import math
import os
import sys
import time

import numpy as np
from PIL import Image
from scipy.spatial import cKDTree

NOISE_K = {"none": 0.0, "low": 0.5, "realistic": 1.0, "harsh": 2.0}
# rigid misalignment of the workpiece points against the CAD (one robust point-to-plane step):
# (translation mm, rotation deg) limits at noise none / with noise. Not part of the noise model: a
# global depth-scale error of ~0.1 % shows up as ~1 mm here, a 5 mm error of T_world_object as ~4-5 mm.
MISALIGN_LIMITS = {"none": (1.0, 0.1), "noisy": (2.5, 0.5)}
MISALIGN_OUTLIER_M = 0.02
MAX_POINTS_PER_VIEW = 20_000
SEED = 12345
BRUTE_FORCE_MAX_TRIANGLES = 64
PATCH_TRIANGLES = 16


class InputError(Exception):
    pass


# ----------------------------------------------------------------------------------------------
# noise model (mm), z in metres
# ----------------------------------------------------------------------------------------------

def sigma_mm(z, k):
    return k * (1.2 + 1.9 * (np.asarray(z, dtype=float) - 0.4) ** 2)


# ----------------------------------------------------------------------------------------------
# PLY reader (own, numpy only): binary_little_endian / binary_big_endian / ascii
# ----------------------------------------------------------------------------------------------

_PLY_TYPES = {
    "char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1",
    "short": "i2", "int16": "i2", "ushort": "u2", "uint16": "u2",
    "int": "i4", "int32": "i4", "uint": "u4", "uint32": "u4",
    "float": "f4", "float32": "f4", "double": "f8", "float64": "f8",
}


def _ply_type(name):
    try:
        return _PLY_TYPES[name]
    except KeyError:
        raise InputError(f"PLY: unknown property type {name!r}")


def read_ply_mesh(path):
    """Return (vertices (V,3) float64, triangles (F,3) int64). Polygons are fan-triangulated."""
    with open(path, "rb") as f:
        data = f.read()
    end = data.find(b"end_header")
    if not data.startswith(b"ply") or end < 0:
        raise InputError(f"{path}: not a PLY file")
    nl = data.find(b"\n", end)
    header = data[:end].decode("ascii", "replace").replace("\r", "").split("\n")
    body = data[nl + 1:]
    fmt = None
    elements = []  # [name, count, [(prop name, type) or (prop name, ("list", count type, item type))]]
    for line in header:
        tok = line.split()
        if not tok:
            continue
        if tok[0] == "format":
            fmt = tok[1]
        elif tok[0] == "element":
            elements.append([tok[1], int(tok[2]), []])
        elif tok[0] == "property":
            if not elements:
                raise InputError(f"{path}: property before element")
            if tok[1] == "list":
                elements[-1][2].append((tok[4], ("list", _ply_type(tok[2]), _ply_type(tok[3]))))
            else:
                elements[-1][2].append((tok[2], _ply_type(tok[1])))
    if fmt not in ("binary_little_endian", "binary_big_endian", "ascii"):
        raise InputError(f"{path}: unsupported PLY format {fmt!r}")

    verts = None
    faces = None
    if fmt == "ascii":
        tokens = body.split()
        pos = 0
        for name, count, props in elements:
            has_list = any(isinstance(t, tuple) for _, t in props)
            if not has_list:
                n = count * len(props)
                arr = np.array(tokens[pos:pos + n], dtype=np.float64).reshape(count, len(props))
                pos += n
                if name == "vertex":
                    names = [p for p, _ in props]
                    verts = arr[:, [names.index("x"), names.index("y"), names.index("z")]]
                continue
            polys = []
            for _ in range(count):
                for pname, ptype in props:
                    if isinstance(ptype, tuple):
                        m = int(tokens[pos]); pos += 1
                        vals = [int(t) for t in tokens[pos:pos + m]]; pos += m
                        if name == "face" and pname in ("vertex_indices", "vertex_index"):
                            polys.append(vals)
                    else:
                        pos += 1
            if name == "face":
                faces = _triangulate(polys)
            elif name == "vertex":
                raise InputError(f"{path}: list property on vertex not supported")
    else:
        bo = "<" if fmt == "binary_little_endian" else ">"
        pos = 0
        for name, count, props in elements:
            has_list = any(isinstance(t, tuple) for _, t in props)
            if not has_list:
                dt = np.dtype([(p, bo + t) for p, t in props])
                arr = np.frombuffer(body, dtype=dt, count=count, offset=pos)
                pos += dt.itemsize * count
                if name == "vertex":
                    verts = np.stack([arr["x"], arr["y"], arr["z"]], axis=1).astype(np.float64)
                continue
            # fast path: every list holds 3 items (a triangle mesh)
            fields = []
            for p, t in props:
                if isinstance(t, tuple):
                    fields.append((p + "__n", bo + t[1]))
                    fields.append((p, bo + t[2], (3,)))
                else:
                    fields.append((p, bo + t))
            dt = np.dtype(fields)
            ok = False
            if pos + dt.itemsize * count <= len(body):
                arr = np.frombuffer(body, dtype=dt, count=count, offset=pos)
                ok = all((arr[p + "__n"] == 3).all() for p, t in props if isinstance(t, tuple))
            if ok:
                pos += dt.itemsize * count
                if name == "face":
                    key = "vertex_indices" if "vertex_indices" in arr.dtype.names else "vertex_index"
                    faces = arr[key].astype(np.int64)
                continue
            # slow path: general polygons
            polys = []
            for _ in range(count):
                for pname, ptype in props:
                    if isinstance(ptype, tuple):
                        cdt = np.dtype(bo + ptype[1])
                        m = int(np.frombuffer(body, dtype=cdt, count=1, offset=pos)[0]); pos += cdt.itemsize
                        idt = np.dtype(bo + ptype[2])
                        vals = np.frombuffer(body, dtype=idt, count=m, offset=pos); pos += idt.itemsize * m
                        if name == "face" and pname in ("vertex_indices", "vertex_index"):
                            polys.append([int(v) for v in vals])
                    else:
                        pos += np.dtype(ptype).itemsize
            if name == "face":
                faces = _triangulate(polys)
    if verts is None or faces is None or len(faces) == 0:
        raise InputError(f"{path}: PLY has no vertices or no faces")
    if faces.min() < 0 or faces.max() >= len(verts):
        raise InputError(f"{path}: face index out of range")
    return verts, faces


def _triangulate(polys):
    tris = []
    for p in polys:
        for i in range(1, len(p) - 1):
            tris.append((p[0], p[i], p[i + 1]))
    return np.array(tris, dtype=np.int64).reshape(-1, 3)


# ----------------------------------------------------------------------------------------------
# exact point-to-triangle distance (Ericson, Real-Time Collision Detection 5.1.5), vectorised
# ----------------------------------------------------------------------------------------------

def _dot(u, v):
    return np.einsum("...i,...i->...", u, v)


def closest_point_on_triangle(p, a, b, c):
    """p, a, b, c broadcastable arrays (..., 3). Returns the closest point of triangle abc to p."""
    v, w = triangle_params(p, a, b, c)
    return a + (b - a) * v[..., None] + (c - a) * w[..., None]


def triangle_params(p, a, b, c):
    """Closest point of triangle abc to p as a + v*(b - a) + w*(c - a); returns (v, w)."""
    ab = b - a
    ac = c - a
    ap = p - a
    return _region_params(_dot(ab, ap), _dot(ac, ap), _dot(ab, ab), _dot(ab, ac), _dot(ac, ac))


def _region_params(d1, d2, abab, abac, acac):
    """Ericson's Voronoi-region test from d1 = ab.ap, d2 = ac.ap and the triangle's Gram matrix."""
    d3 = d1 - abab          # ab . bp  (bp = ap - ab)
    d4 = d2 - abac          # ac . bp
    d5 = d1 - abac          # ab . cp  (cp = ap - ac)
    d6 = d2 - acac          # ac . cp
    va = d3 * d6 - d5 * d4
    vb = d5 * d2 - d1 * d6
    vc = d1 * d4 - d3 * d2
    with np.errstate(divide="ignore", invalid="ignore"):
        # Ericson tests the regions in the order A, B, AB, C, AC, BC, inside and the first match wins:
        # apply them here in reverse so that earlier ones override
        den = va + vb + vc
        den = np.where(den == 0.0, 1.0, den)
        v = vb / den
        w = vc / den
        # edge BC
        e1 = d4 - d3
        e2 = d5 - d6
        t = e1 / np.where(e1 + e2 == 0.0, 1.0, e1 + e2)
        m = (va <= 0) & (e1 >= 0) & (e2 >= 0)
        v = np.where(m, 1.0 - t, v)
        w = np.where(m, t, w)
        # edge AC
        t = d2 / np.where(d2 - d6 == 0.0, 1.0, d2 - d6)
        m = (vb <= 0) & (d2 >= 0) & (d6 <= 0)
        v = np.where(m, 0.0, v)
        w = np.where(m, t, w)
        # vertex C
        m = (d6 >= 0) & (d5 <= d6)
        v = np.where(m, 0.0, v)
        w = np.where(m, 1.0, w)
        # edge AB
        t = d1 / np.where(d1 - d3 == 0.0, 1.0, d1 - d3)
        m = (vc <= 0) & (d1 >= 0) & (d3 <= 0)
        v = np.where(m, t, v)
        w = np.where(m, 0.0, w)
        # vertex B
        m = (d3 >= 0) & (d4 <= d3)
        v = np.where(m, 1.0, v)
        w = np.where(m, 0.0, w)
        # vertex A
        m = (d1 <= 0) & (d2 <= 0)
        v = np.where(m, 0.0, v)
        w = np.where(m, 0.0, w)
    return v, w


class MeshDistance:
    """Exact unsigned distance from points to a triangle mesh, with the closest triangle and point.

    Small meshes: brute force over every triangle. Larger ones: a kd-tree over sample points, the
    centres of pieces of the triangles; each sample s carries the bounding radius r_s of its piece,
    so |p - s| - r_s is a lower bound of the distance from p to that piece.
    U, the exact distance to the triangle of the nearest sample, bounds the answer from above. Points
    are bucketed by U; for a bucket with U < hi, every (point, sample) pair closer than hi + max r_s is
    enumerated (dual kd-tree), and every triangle with a sample whose bound is below U is evaluated
    exactly. Samples farther away cannot hold a closer point, so the result is exact. Points with a
    large U (outliers) go to a two-level search with the same bound: grid patches of ~16 triangles
    with bounding spheres, then their triangles.
    """

    def __init__(self, verts, faces):
        self.a = verts[faces[:, 0]]
        self.b = verts[faces[:, 1]]
        self.c = verts[faces[:, 2]]
        self.ab = self.b - self.a
        self.ac = self.c - self.a
        self.abab = _dot(self.ab, self.ab)
        self.abac = _dot(self.ab, self.ac)
        self.acac = _dot(self.ac, self.ac)
        n = np.cross(self.ab, self.ac)
        ln = np.linalg.norm(n, axis=1, keepdims=True)
        self.normals = n / np.where(ln == 0, 1.0, ln)
        self.nfaces = len(faces)
        self.centroids = (self.a + self.b + self.c) / 3.0
        self.radii = np.max(np.stack([np.linalg.norm(x - self.centroids, axis=1)
                                      for x in (self.a, self.b, self.c)]), axis=0) * (1 + 1e-9) + 1e-12
        self.brute = self.nfaces <= BRUTE_FORCE_MAX_TRIANGLES
        self.stage_counts = []
        if not self.brute:
            self._build_samples()

    def _build_samples(self):
        """Samples with covering radii: every point of triangle t lies within r_s of one of its samples.

        Triangles with a bounding radius (around the centroid) up to r_target are one sample. Larger ones
        are cut into cells of the map (t, s) -> apex + t * ((1 - s) * (b - apex) + s * (c - apex)), the
        apex being the vertex opposite the shortest edge: m_t slices across the length, m_s along the
        short edge, so slivers (a cylinder's sides) are cut across only. Each cell is a convex polygon:
        the sample is the mean of its corners and r_s its largest distance to a corner."""
        area = 0.5 * np.linalg.norm(np.cross(self.ab, self.ac), axis=1)
        r_target = min(float(np.percentile(self.radii, 75)), math.sqrt(float(area.sum()) / 50_000))
        r_target = max(r_target, 1e-9)
        # apex opposite the shortest edge
        l_bc = np.linalg.norm(self.c - self.b, axis=1)
        l_ca = np.linalg.norm(self.a - self.c, axis=1)
        l_ab = np.linalg.norm(self.ab, axis=1)
        k = np.argmin(np.stack([l_bc, l_ca, l_ab], axis=1), axis=1)  # 0: apex a, 1: apex b, 2: apex c
        apex = np.where((k == 0)[:, None], self.a, np.where((k == 1)[:, None], self.b, self.c))
        u = np.where((k == 0)[:, None], self.b, np.where((k == 1)[:, None], self.c, self.a)) - apex
        v = np.where((k == 0)[:, None], self.c, np.where((k == 1)[:, None], self.a, self.b)) - apex
        length = np.maximum(np.linalg.norm(u, axis=1), np.linalg.norm(v, axis=1))
        short = np.linalg.norm(v - u, axis=1)
        big = self.radii > r_target
        while True:
            step = r_target * math.sqrt(2.0)
            m_t = np.where(big, np.ceil(length / step), 1).astype(np.int64)
            m_s = np.where(big, np.maximum(1, np.ceil(short / step)), 1).astype(np.int64)
            if int((m_t * m_s).sum()) <= 3_000_000:
                break
            r_target *= 1.5
        small = ~big
        pts = [self.centroids[small]]
        rs = [self.radii[small]]
        tid = [np.nonzero(small)[0]]
        combos = np.unique(np.stack([m_t[big], m_s[big]], axis=1), axis=0)
        for mt, ms in combos:
            idx = np.nonzero(big & (m_t == mt) & (m_s == ms))[0]
            tk, sj = np.meshgrid(np.arange(mt), np.arange(ms), indexing="ij")
            tk, sj = tk.ravel(), sj.ravel()
            corners_t = np.stack([tk, tk, tk + 1, tk + 1], axis=1) / mt  # (cells, 4)
            corners_s = np.stack([sj, sj + 1, sj, sj + 1], axis=1) / ms
            wu = corners_t * (1 - corners_s)
            wv = corners_t * corners_s
            for s0 in range(0, len(idx), max(1, 200_000 // (mt * ms))):
                ii = idx[s0:s0 + max(1, 200_000 // (mt * ms))]
                cp = (apex[ii][:, None, None, :] + wu[None, :, :, None] * u[ii][:, None, None, :]
                      + wv[None, :, :, None] * v[ii][:, None, None, :])  # (T, cells, 4, 3)
                cen = cp.mean(axis=2)
                r = np.linalg.norm(cp - cen[:, :, None, :], axis=3).max(axis=2)
                pts.append(cen.reshape(-1, 3))
                rs.append(r.reshape(-1) * (1 + 1e-9) + 1e-15)
                tid.append(np.repeat(ii, mt * ms))
        self.sample_pts = np.concatenate(pts)
        self.sample_r = np.concatenate(rs)
        self.sample_tri = np.concatenate(tid)
        self.r_max = float(self.sample_r.max())
        self.tree = cKDTree(self.sample_pts)

    def _exact_pairs(self, p, tri):
        """Exact distances from points p (M,3) to triangles tri (M,)."""
        out = np.empty(len(tri))
        for s in range(0, len(tri), 250_000):
            ps, t = p[s:s + 250_000], tri[s:s + 250_000]
            ab, ac = self.ab[t], self.ac[t]
            ap = ps - self.a[t]
            d1 = _dot(ab, ap)
            d2 = _dot(ac, ap)
            v, w = _region_params(d1, d2, self.abab[t], self.abac[t], self.acac[t])
            # |ap - v ab - w ac|^2 expanded (no closest point needed)
            d2sq = (_dot(ap, ap) - 2.0 * (v * d1 + w * d2)
                    + v * v * self.abab[t] + 2.0 * v * w * self.abac[t] + w * w * self.acac[t])
            out[s:s + 250_000] = np.sqrt(np.maximum(d2sq, 0.0))
        return out

    def _build_patches(self):
        """Group triangles into grid-cell patches (about 64 triangles each) with bounding spheres."""
        area = 0.5 * np.linalg.norm(np.cross(self.b - self.a, self.c - self.a), axis=1)
        g = max(float(np.sqrt(PATCH_TRIANGLES * max(area.mean(), 1e-12))), 2.0 * float(np.median(self.radii)))
        key = np.floor(self.centroids / g).astype(np.int64)
        _, inv = np.unique(key, axis=0, return_inverse=True)
        inv = inv.reshape(-1)
        order = np.argsort(inv, kind="stable")
        counts = np.bincount(inv)
        starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
        lo = np.full((len(counts), 3), np.inf)
        hi = np.full((len(counts), 3), -np.inf)
        for x in (self.a, self.b, self.c):
            np.minimum.at(lo, inv, x)
            np.maximum.at(hi, inv, x)
        centre = (lo + hi) / 2.0
        reach = np.linalg.norm(self.centroids - centre[inv], axis=1) + self.radii
        rad = np.zeros(len(counts))
        np.maximum.at(rad, inv, reach)
        self.patch_tris = order
        self.patch_start = starts
        self.patch_count = counts
        self.patch_centre = centre
        self.patch_radius = rad * (1 + 1e-9) + 1e-12
        self.patch_rmax = float(self.patch_radius.max())
        self.patch_tree = cKDTree(centre)

    def _eval_patch_pairs(self, p, ids, pi, pj, dist, best):
        """Candidate (point ids[pi], patch pj) pairs: expand to triangles, prune, evaluate, keep the best."""
        cnt = self.patch_count[pj]
        total = int(cnt.sum())
        if not total:
            return
        row = np.repeat(pi, cnt)
        first = np.repeat(self.patch_start[pj], cnt)
        within = np.arange(total) - np.repeat(np.cumsum(cnt) - cnt, cnt)
        tri = self.patch_tris[first + within]
        pr = p[ids[row]]
        lbt = np.linalg.norm(pr - self.centroids[tri], axis=1) - self.radii[tri]
        keep = lbt < dist[ids[row]]
        row, tri = row[keep], tri[keep]
        self._reduce_pairs(p, ids, row, tri, dist, best)

    def _plane_bound(self, p, smp):
        """Lower bound of the distance from p to the piece of sample smp: the piece lies in its triangle's
        plane within r_s of the sample, so d^2 >= h^2 + max(0, rho - r_s)^2 (h: height over the plane,
        rho: in-plane distance to the sample)."""
        sp = p - self.sample_pts[smp]
        h = _dot(sp, self.normals[self.sample_tri[smp]])
        rho = np.sqrt(np.maximum(_dot(sp, sp) - h * h, 0.0))
        lat = np.maximum(rho - self.sample_r[smp], 0.0)
        return np.sqrt(h * h + lat * lat) * (1 - 1e-9)

    def _reduce_pairs(self, p, ids, row, tri, dist, best):
        """Evaluate candidate pairs (point ids[row], triangle tri) exactly; keep improvements."""
        if not len(row):
            return
        d = self._exact_pairs(p[ids[row]], tri)
        dmin = np.full(len(ids), np.inf)
        np.minimum.at(dmin, row, d)
        hit = d == dmin[row]
        tmin = np.zeros(len(ids), dtype=np.int64)
        tmin[row[hit]] = tri[hit]
        better = dmin < dist[ids]
        dist[ids[better]] = dmin[better]
        best[ids[better]] = tmin[better]

    def _patch_search(self, p, ids, dist, best):
        """Exact search for points ids given an upper bound dist: nearest patches first (kd-tree on patch
        centres, settled once the k-th centre is beyond dist + max patch radius), then all patches."""
        if not hasattr(self, "patch_tree"):
            self._build_patches()
        npatch = len(self.patch_count)
        todo = ids
        for k in (16, 128):
            if not len(todo) or k >= npatch:
                break
            self.stage_counts.append((f"patches k={k}", len(todo)))
            keep = []
            step = max(1, 2_000_000 // k)
            for s in range(0, len(todo), step):
                sub = todo[s:s + step]
                dp, ip = self.patch_tree.query(p[sub], k=k)
                pi, kj = np.nonzero(dp - self.patch_radius[ip] < dist[sub][:, None])
                self._eval_patch_pairs(p, sub, pi, ip[pi, kj], dist, best)
                settled = dp[:, -1] >= dist[sub] + self.patch_rmax
                keep.append(sub[~settled])
            todo = np.concatenate(keep)
        if len(todo):
            self.stage_counts.append(("patches all", len(todo)))
            step = max(1, 1_000_000 // npatch)
            for s in range(0, len(todo), step):
                sub = todo[s:s + step]
                lbp = (np.linalg.norm(p[sub][:, None, :] - self.patch_centre[None, :, :], axis=2)
                       - self.patch_radius[None, :])
                pi, pj = np.nonzero(lbp < dist[sub][:, None])
                self._eval_patch_pairs(p, sub, pi, pj, dist, best)

    def _brute_all(self, p, dist, best):
        step = max(1, 1_000_000 // self.nfaces)
        allt = np.arange(self.nfaces)
        for s in range(0, len(p), step):
            ps = p[s:s + step]
            m = len(ps)
            d = self._exact_pairs(np.repeat(ps, self.nfaces, axis=0), np.tile(allt, m)).reshape(m, self.nfaces)
            j = np.argmin(d, axis=1)
            dist[s:s + step] = d[np.arange(m), j]
            best[s:s + step] = j

    def query(self, p):
        """Return (distance (N,), closest triangle (N,), closest point (N,3))."""
        p = np.ascontiguousarray(p, dtype=np.float64)
        n = len(p)
        dist = np.full(n, np.inf)
        best = np.zeros(n, dtype=np.int64)
        self.stage_counts = []
        if n == 0:
            return dist, best, np.zeros((0, 3))
        if self.brute:
            self._brute_all(p, dist, best)
        else:
            # upper bound U: the triangle of the nearest sample
            _, i1 = self.tree.query(p, k=1)
            best[:] = self.sample_tri[i1]
            dist[:] = self._exact_pairs(p, best)
            # bucket the points by U; within a bucket [lo, hi) enumerate every (point, sample) pair closer
            # than hi + r_max (dual-tree, in C), keep the pairs whose bound |p - s| - r_s is below U
            edges = self.r_max * np.array([0.0, 0.25, 0.5, 0.75, 1.0, 1.5, 2.0, 3.0, 4.0, 6.0, 8.0])
            u0 = dist.copy()
            for lo, hi in zip(edges[:-1], edges[1:]):
                sel = np.nonzero((u0 >= lo) & (u0 < hi))[0]
                if not len(sel):
                    continue
                self.stage_counts.append((f"U<{hi * 1000:.2f}mm", len(sel)))
                for s in range(0, len(sel), 50_000):
                    ids = sel[s:s + 50_000]
                    pairs = cKDTree(p[ids]).sparse_distance_matrix(self.tree, hi + self.r_max,
                                                                   output_type="ndarray")
                    row, smp = pairs["i"], pairs["j"]
                    keep = pairs["v"] - self.sample_r[smp] < dist[ids][row]
                    row, smp = row[keep], smp[keep]
                    keep = self._plane_bound(p[ids[row]], smp) < dist[ids][row]
                    self._reduce_pairs(p, ids, row[keep], self.sample_tri[smp[keep]], dist, best)
            far = np.nonzero(u0 >= edges[-1])[0]
            if len(far):
                self.stage_counts.append(("far", len(far)))
                self._patch_search(p, far, dist, best)
        v, w = triangle_params(p, self.a[best], self.b[best], self.c[best])
        q = self.a[best] + self.ab[best] * v[:, None] + self.ac[best] * w[:, None]
        return dist, best, q


# ----------------------------------------------------------------------------------------------
# poses
# ----------------------------------------------------------------------------------------------

def mat(x, what):
    m = np.array(x, dtype=np.float64)
    if m.shape != (4, 4):
        raise InputError(f"{what}: expected a 4x4 matrix, got shape {m.shape}")
    return m


def rot_angle_deg(r):
    # atan2 of sin and cos: accurate for small angles too (acos of the trace is not)
    s = 0.5 * math.sqrt((r[2, 1] - r[1, 2]) ** 2 + (r[0, 2] - r[2, 0]) ** 2 + (r[1, 0] - r[0, 1]) ** 2)
    c = (np.trace(r) - 1.0) / 2.0
    return math.degrees(math.atan2(s, c))


def pose_diff(ta, tb):
    """(translation difference m, rotation difference deg, max abs element difference)."""
    dt = float(np.linalg.norm(ta[:3, 3] - tb[:3, 3]))
    dr = rot_angle_deg(ta[:3, :3].T @ tb[:3, :3])
    return dt, dr, float(np.max(np.abs(ta - tb)))


def is_rigid(t, tol=1e-5):
    r = t[:3, :3]
    return (np.max(np.abs(r.T @ r - np.eye(3))) < tol and abs(np.linalg.det(r) - 1) < tol
            and np.allclose(t[3], [0, 0, 0, 1], atol=1e-12))


def inv_rigid(t):
    r = t[:3, :3]
    out = np.eye(4)
    out[:3, :3] = r.T
    out[:3, 3] = -r.T @ t[:3, 3]
    return out


# ----------------------------------------------------------------------------------------------
# images
# ----------------------------------------------------------------------------------------------

def load_depth(path):
    im = Image.open(path)
    if im.mode not in ("I;16", "I;16B", "I;16L", "I"):
        raise InputError(f"{path}: depth PNG mode {im.mode!r}, expected 16-bit")
    a = np.array(im)
    if a.ndim != 2:
        raise InputError(f"{path}: depth image is not single-channel")
    if a.min() < 0 or a.max() > 65535:
        raise InputError(f"{path}: depth values outside 16-bit range")
    return a.astype(np.uint16)


def load_label(path):
    im = Image.open(path)
    if im.mode not in ("L", "P"):
        raise InputError(f"{path}: label PNG mode {im.mode!r}, expected 8-bit single channel")
    return np.array(im).astype(np.uint8)


def undistort_normalised(xd, yd, dist):
    """Brown-Conrady [k1,k2,p1,p2,k3]: invert iteratively (same scheme as OpenCV's undistortPoints)."""
    k1, k2, p1, p2, k3 = (list(dist) + [0, 0, 0, 0, 0])[:5]
    x, y = xd.copy(), yd.copy()
    for _ in range(20):
        r2 = x * x + y * y
        radial = 1 + k1 * r2 + k2 * r2 * r2 + k3 * r2 ** 3
        dx = 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
        dy = p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
        x = (xd - dx) / radial
        y = (yd - dy) / radial
    return x, y


def backproject(depth_u16, mask, cam):
    """Pixels where mask -> camera-frame points (N,3) in metres, pixel centres at integer coordinates."""
    v, u = np.nonzero(mask)
    z = depth_u16[v, u].astype(np.float64) * cam["depth_scale"]
    x = (u - cam["cx"]) / cam["fx"]
    y = (v - cam["cy"]) / cam["fy"]
    d = cam.get("distortion") or [0, 0, 0, 0, 0]
    if any(abs(float(c)) > 0 for c in d):
        x, y = undistort_normalised(x, y, [float(c) for c in d])
    return np.stack([x * z, y * z, z], axis=1)


def transform(t, p):
    return p @ t[:3, :3].T + t[:3, 3]


# ----------------------------------------------------------------------------------------------
# the check
# ----------------------------------------------------------------------------------------------

def stats_mm(x_m):
    if len(x_m) == 0:
        return {"median": None, "p95": None, "mean": None}
    a = np.abs(x_m) * 1000.0
    return {"median": float(np.median(a)), "p95": float(np.percentile(a, 95)), "mean": float(np.mean(a))}


def check(scan_dir, noise, max_points=MAX_POINTS_PER_VIEW):
    t0 = time.time()
    k = NOISE_K[noise]
    failures = []
    notes = []

    def fail(msg):
        failures.append(msg)

    def rd(name):
        p = os.path.join(scan_dir, name)
        if not os.path.isfile(p):
            raise InputError(f"missing {p}")
        with open(p) as f:
            return json.load(f)

    scan = rd("scan.json")
    truth = rd("truth.json")
    if scan.get("format") != "awl-scan/1":
        fail(f"scan.json format is {scan.get('format')!r}, expected 'awl-scan/1'")
    cam = scan["camera"]
    for key in ("fx", "fy", "cx", "cy", "depth_scale"):
        if key not in cam:
            raise InputError(f"scan.json camera lacks {key}")
    W, H = cam.get("width"), cam.get("height")
    dmin, dmax = cam.get("depth_min"), cam.get("depth_max")
    views = scan["views"]
    tviews = truth["views"]
    if len(views) != len(tviews):
        raise InputError(f"scan.json has {len(views)} views, truth.json {len(tviews)}")
    T_world_object = mat(truth["T_world_object"], "truth T_world_object")
    T_object_world = inv_rigid(T_world_object)
    if not is_rigid(T_world_object):
        fail("truth T_world_object is not a rigid transform")
    T_ee_camera = mat(scan["T_ee_camera"], "scan T_ee_camera") if "T_ee_camera" in scan else None

    # shot detection: truth has `shot`, or every view sits on one base with identity T_world_base
    bases = [mat(v["T_world_base"], "T_world_base") for v in views if "T_world_base" in v]
    is_shot = "shot" in truth or (
        len(bases) == len(views) and all(np.allclose(b, np.eye(4), atol=1e-12) for b in bases))
    floor_z = float(truth.get("floor_z", 0.0))

    t_mesh = time.time()
    verts, faces = read_ply_mesh(os.path.join(scan_dir, truth["cad"]))
    mesh = MeshDistance(verts, faces)
    t_mesh = time.time() - t_mesh

    rng = np.random.default_rng(SEED)
    all_p_obj, all_z, all_dir_obj = [], [], []
    floor_res, floor_zc = [], []
    pose_rows = []
    per_view = []
    for i, (v, tv) in enumerate(zip(views, tviews)):
        T_true = mat(tv["T_world_camera"], f"truth view {i} T_world_camera")
        if not is_rigid(T_true):
            fail(f"view {i}: truth T_world_camera is not rigid")
        # truth self-consistency: T_world_base * T_base_ee * T_ee_camera (all true) = T_world_camera
        if "T_world_base" in tv and "T_base_ee" in tv and "T_ee_camera" in truth:
            comp = mat(tv["T_world_base"], "") @ mat(tv["T_base_ee"], "") @ mat(truth["T_ee_camera"], "")
            dt, dr, de = pose_diff(comp, T_true)
            if dt > 1e-5 or dr > 1e-3:
                fail(f"view {i}: truth T_world_base*T_base_ee*T_ee_camera differs from truth T_world_camera "
                     f"by {dt * 1000:.4f} mm / {dr:.5f} deg")
        # recorded pose
        if "T_world_camera" in v:
            T_rec = mat(v["T_world_camera"], f"scan view {i} T_world_camera")
        elif "T_world_base" in v and "T_base_ee" in v and T_ee_camera is not None:
            T_rec = mat(v["T_world_base"], "") @ mat(v["T_base_ee"], "") @ T_ee_camera
        else:
            raise InputError(f"scan view {i}: no camera pose (T_world_camera, or T_world_base+T_base_ee+T_ee_camera)")
        if not is_rigid(T_rec, tol=1e-4):
            fail(f"view {i}: recorded camera pose is not rigid")
        dt, dr, de = pose_diff(T_rec, T_true)
        pose_rows.append({"view": i, "dt_mm": dt * 1000, "dr_deg": dr, "max_abs_elem": de})
        if noise == "none":
            if de > 1e-6:
                fail(f"view {i}: recorded pose differs from truth at noise none "
                     f"(max |element diff| {de:.3g} > 1e-6; {dt * 1000:.4f} mm, {dr:.5f} deg)")
        elif dt > 0.10 or dr > 5.0:
            fail(f"view {i}: recorded pose is {dt * 100:.1f} cm / {dr:.2f} deg from truth (limit 10 cm / 5 deg)")

        if "depth" not in v:
            notes.append(f"view {i}: no depth image (points view), not checked")
            continue
        if "label" not in tv:
            raise InputError(f"truth view {i} has no label image")
        depth = load_depth(os.path.join(scan_dir, v["depth"]))
        label = load_label(os.path.join(scan_dir, tv["label"]))
        if W is not None and H is not None and depth.shape != (H, W):
            fail(f"view {i}: depth image is {depth.shape[1]}x{depth.shape[0]}, camera says {W}x{H}")
        if label.shape != depth.shape:
            raise InputError(f"view {i}: label image {label.shape} and depth image {depth.shape} differ in size")
        if v.get("color"):
            cpath = os.path.join(scan_dir, v["color"])
            if not os.path.isfile(cpath):
                fail(f"view {i}: colour image {v['color']} is missing")
            else:
                cim = Image.open(cpath)
                if cim.size != (depth.shape[1], depth.shape[0]) or cim.mode not in ("RGB", "RGBA", "L"):
                    fail(f"view {i}: colour image is {cim.mode} {cim.size}, expected 8-bit RGB of the depth size")
        ret = depth > 0
        n_unlabelled = int((ret & (label == 0)).sum())
        if n_unlabelled:
            fail(f"view {i}: {n_unlabelled} returns with label 0 (none)")
        zs = depth[ret].astype(np.float64) * cam["depth_scale"]
        q = cam["depth_scale"] * 1.0001
        if dmin is not None and dmax is not None and len(zs):
            n_out = int(((zs < dmin - q) | (zs > dmax + q)).sum())
            if n_out:
                fail(f"view {i}: {n_out} returns outside [depth_min, depth_max] = [{dmin}, {dmax}] m")
        if int(ret.sum()) == 0:
            fail(f"view {i}: depth image has no returns")

        wp = ret & (label == 2)
        n_wp = int(wp.sum())
        pc = backproject(depth, wp, cam)
        if len(pc) > max_points:
            pc = pc[np.sort(rng.choice(len(pc), max_points, replace=False))]
        T_object_camera = T_object_world @ T_true
        all_p_obj.append(transform(T_object_camera, pc))
        all_z.append(pc[:, 2])
        all_dir_obj.append((pc / pc[:, 2:3]) @ T_object_camera[:3, :3].T)  # ray with unit z, object frame
        per_view.append({"view": i, "workpiece_returns": n_wp, "checked": len(pc)})

        fl = ret & (label == 1)
        if fl.any():
            pf = backproject(depth, fl, cam)
            if len(pf) > max_points:
                pf = pf[np.sort(rng.choice(len(pf), max_points, replace=False))]
            floor_res.append(transform(T_true, pf)[:, 2])
            floor_zc.append(pf[:, 2])

    p_obj = np.concatenate(all_p_obj) if all_p_obj else np.zeros((0, 3))
    z = np.concatenate(all_z) if all_z else np.zeros(0)
    rays = np.concatenate(all_dir_obj) if all_dir_obj else np.zeros((0, 3))
    t_dist = time.time()
    dist, tri, closest = mesh.query(p_obj)
    t_dist = time.time() - t_dist
    # view-wise stats
    off = 0
    for row in per_view:
        d = dist[off:off + row["checked"]]
        off += row["checked"]
        row.update({f"{kk}_mm": vv for kk, vv in stats_mm(d).items()})

    result = {
        "scan": os.path.abspath(scan_dir), "noise": noise, "is_shot": bool(is_shot),
        "mesh": {"vertices": int(len(verts)), "triangles": int(len(faces)),
                 "method": "brute force" if mesh.brute else "kd-tree candidates, certified exact"},
        "distance_stages": [[str(a), int(b)] for a, b in mesh.stage_counts],
        "points_checked": int(len(dist)),
        "workpiece_returns": int(sum(r["workpiece_returns"] for r in per_view)),
    }
    if len(dist) == 0:
        fail("no workpiece (label 2) returns in any view: nothing to check")
        result.update({"failures": failures, "notes": notes, "pass": False})
        return result

    st = stats_mm(dist)
    z_med = float(np.median(z))
    result.update({"distance_mm": st, "median_depth_m": z_med})

    # signed axial error proxy: signed normal distance to the closest face over the ray's normal component
    # (exact for a planar face); only where the incidence is below ~72 deg
    s_norm = np.einsum("ij,ij->i", p_obj - closest, mesh.normals[tri])
    cosn = np.einsum("ij,ij->i", rays, mesh.normals[tri])  # n . (x/z, y/z, 1)
    unit_cos = np.abs(cosn) / np.linalg.norm(rays, axis=1)
    good = unit_cos > 0.3
    axial = np.where(good, s_norm / np.where(good, cosn, 1.0), np.nan)
    # sign convention: positive = measured depth larger than the true one (behind the surface)
    axial = -axial
    bins = []
    zbin = np.floor(z * 10.0 + 1e-9).astype(np.int64)  # 0.1 m bins
    for b in np.unique(zbin):
        m = zbin == b
        if m.sum() < 50:
            continue
        ax = axial[m & good]
        row = {"z_from_m": round(b / 10.0, 1), "z_to_m": round((b + 1) / 10.0, 1), "n": int(m.sum()),
               "median_abs_mm": float(np.median(dist[m]) * 1000),
               "p95_abs_mm": float(np.percentile(dist[m], 95) * 1000)}
        if len(ax) >= 50:
            mad = np.median(np.abs(ax - np.median(ax)))
            row.update({"axial_n": int(len(ax)), "axial_median_mm": float(np.median(ax) * 1000),
                        "axial_std_mm": float(np.std(ax) * 1000),
                        "axial_robust_std_mm": float(1.4826 * mad * 1000)})
        if k > 0:
            row["model_sigma_mm"] = float(sigma_mm((b + 0.5) / 10.0, k))
        bins.append(row)
    result["depth_bins"] = bins
    if good.any():
        # global depth-scale estimate: axial error / depth
        result["axial_over_depth_median"] = float(np.median(axial[good] / z[good]))
    if isinstance(truth.get("depth_scale_error"), (int, float)):
        result["truth_depth_scale_error"] = float(truth["depth_scale_error"])

    # --- rigid misalignment: the small motion (omega, t) of the points that best puts them on the CAD,
    # one Gauss-Newton step of robust (Huber) point-to-plane alignment from the true pose
    mis = rigid_misalignment(p_obj, dist, closest, mesh.normals[tri])
    result["misalignment"] = mis
    if mis is not None and mis["constrained"]:
        lt, lr = MISALIGN_LIMITS["none" if noise == "none" else "noisy"]
        mis["limit_mm"], mis["limit_deg"] = lt, lr
        if not (mis["t_norm_mm"] < lt and mis["rot_deg"] < lr):
            fail(f"workpiece points are misaligned with the CAD by {mis['t_norm_mm']:.3f} mm / "
                 f"{mis['rot_deg']:.3f} deg (limit {lt} mm / {lr} deg): check T_world_object, the true "
                 f"camera poses, intrinsics and depth scale")
    elif mis is not None:
        notes.append("rigid misalignment not checked: the visible surface constrains fewer than 3 DoF")

    # --- workpiece bound
    if noise == "none":
        result["bound"] = {"median_mm": 1.0, "p95_mm": 2.0}
        if not st["median"] < 1.0:
            fail(f"workpiece distance median {st['median']:.3f} mm >= 1.0 mm (noise none)")
        if not st["p95"] < 2.0:
            fail(f"workpiece distance p95 {st['p95']:.3f} mm >= 2.0 mm (noise none)")
    else:
        sig = float(sigma_mm(z_med, k))
        bound = 1.5 * 0.6745 * sig + 1.0
        result["bound"] = {"median_mm": bound, "sigma_at_median_depth_mm": sig}
        if not st["median"] < bound:
            fail(f"workpiece distance median {st['median']:.3f} mm >= bound {bound:.3f} mm "
                 f"(sigma({z_med:.3f} m) = {sig:.3f} mm, noise {noise})")

    # --- floor
    if floor_res:
        fz = np.concatenate(floor_res)
        fzc = np.concatenate(floor_zc)
        ref = floor_z
        if is_shot and "shot" in truth and "floor_z" in truth["shot"]:
            ref = float(truth["shot"]["floor_z"])
        fres = np.abs(fz - ref) * 1000
        fl_med = float(np.median(fres))
        fl = {"points": int(len(fz)), "floor_z_m": ref, "median_abs_mm": fl_med,
              "p95_abs_mm": float(np.percentile(fres, 95)), "median_depth_m": float(np.median(fzc))}
        if is_shot:
            fl["checked"] = False
            fl["why"] = "shot: the floor may be elsewhere (reported only)"
        else:
            fl["checked"] = True
            if noise == "none":
                fb = 2.0
            else:
                fb = 1.5 * float(sigma_mm(np.median(fzc), k)) + 1.0
            fl["bound_mm"] = fb
            if not fl_med < fb:
                fail(f"floor |z - {ref}| median {fl_med:.3f} mm >= bound {fb:.3f} mm")
        result["floor"] = fl
    elif not is_shot:
        notes.append("no floor (label 1) returns")

    result["poses"] = {
        "max_dt_mm": max(r["dt_mm"] for r in pose_rows), "max_dr_deg": max(r["dr_deg"] for r in pose_rows),
        "max_abs_elem": max(r["max_abs_elem"] for r in pose_rows), "views": pose_rows}
    result["per_view"] = per_view
    result["timing_s"] = {"mesh_setup": t_mesh, "distances": t_dist, "total": time.time() - t0}
    result["failures"] = failures
    result["notes"] = notes
    result["pass"] = not failures
    return result


def rigid_misalignment(p, dist, closest, normals):
    """One robust point-to-plane step: the small rigid motion of the points (rotation about their
    centroid, translation) that best moves them onto the surface. None when too few points."""
    good = dist < MISALIGN_OUTLIER_M
    if good.sum() < 100:
        return None
    p, q, n = p[good], closest[good], normals[good]
    r = np.einsum("ij,ij->i", p - q, n)  # signed point-to-plane residual
    x = p - p.mean(axis=0)
    jac = np.hstack([np.cross(x, n), n])  # d residual / d (omega, t)
    # scale the rotation columns by the cloud's radius so that all six directions are comparable
    rad = max(float(np.sqrt((x * x).sum(axis=1).mean())), 1e-6)
    sc = np.array([rad] * 3 + [1.0] * 3)
    sol = np.zeros(6)
    for _ in range(5):  # IRLS, Huber weights on the residual after the step
        res = r + jac @ sol
        scale = max(1.4826 * float(np.median(np.abs(res - np.median(res)))), 1e-5)
        kh = 1.345 * scale
        w = np.where(np.abs(res) <= kh, 1.0, kh / np.maximum(np.abs(res), 1e-300))
        a = (jac * w[:, None]).T @ jac * sc[:, None] * sc[None, :]
        b = -(jac * w[:, None]).T @ r * sc
        ev, vec = np.linalg.eigh(a)
        # directions the visible surface does not constrain (a dome turning about its axis, a plane
        # sliding in itself) are left out: truncated pseudo-inverse
        keep = ev > 1e-3 * ev[-1]
        sol = sc * (vec[:, keep] @ ((vec[:, keep].T @ b) / ev[keep]))
    return {"points": int(good.sum()), "t_mm": [float(v) * 1000 for v in sol[3:]],
            "t_norm_mm": float(np.linalg.norm(sol[3:]) * 1000),
            "omega_deg": [float(np.degrees(v)) for v in sol[:3]],
            "rot_deg": float(np.degrees(np.linalg.norm(sol[:3]))),
            "dof_constrained": int(keep.sum()), "constrained": bool(keep.sum() >= 3),
            "eigen_ratio": float(ev[0] / ev[-1])}


def print_report(r):
    print(f"scan  {r['scan']}  (noise {r['noise']}{', shot' if r['is_shot'] else ''})")
    m = r["mesh"]
    print(f"  CAD: {m['vertices']} vertices, {m['triangles']} triangles ({m['method']})")
    print(f"  workpiece points checked: {r['points_checked']} (of {r['workpiece_returns']} returns)")
    if "distance_mm" in r:
        d = r["distance_mm"]
        b = r["bound"]
        print(f"  distance to CAD: median {d['median']:.3f} mm, p95 {d['p95']:.3f} mm, mean {d['mean']:.3f} mm"
              f"  (median depth {r['median_depth_m']:.3f} m)")
        if "sigma_at_median_depth_mm" in b:
            print(f"  bound: median < {b['median_mm']:.3f} mm  (1.5*0.6745*sigma + 1 mm, "
                  f"sigma = {b['sigma_at_median_depth_mm']:.3f} mm)")
        else:
            print(f"  bound: median < {b['median_mm']} mm, p95 < {b['p95_mm']} mm")
        if "axial_over_depth_median" in r:
            tr = r.get("truth_depth_scale_error")
            print(f"  signed axial error / depth (median): {r['axial_over_depth_median'] * 100:+.3f} %"
                  + (f"  (truth depth_scale_error {tr * 100:+.3f} %)" if tr is not None else ""))
        mis = r.get("misalignment")
        if mis:
            print(f"  rigid misalignment vs CAD: t = ({', '.join(f'{v:+.3f}' for v in mis['t_mm'])}) mm "
                  f"|t| {mis['t_norm_mm']:.3f} mm, rotation {mis['rot_deg']:.4f} deg"
                  + f", {mis['dof_constrained']}/6 DoF constrained"
                  + (f"  (limit {mis['limit_mm']} mm / {mis['limit_deg']} deg)" if "limit_mm" in mis
                     else "  (not checked)"))
        print("  depth bin      n   med|d|  p95|d|  axial med  axial std  robust std  model sigma  (mm)")
        for row in r["depth_bins"]:
            print(f"  {row['z_from_m']:.1f}-{row['z_to_m']:.1f} m {row['n']:7d} {row['median_abs_mm']:7.3f}"
                  f" {row['p95_abs_mm']:7.3f}"
                  + (f" {row['axial_median_mm']:+10.3f} {row['axial_std_mm']:10.3f} {row['axial_robust_std_mm']:11.3f}"
                     if "axial_std_mm" in row else " " * 33)
                  + (f" {row['model_sigma_mm']:12.3f}" if "model_sigma_mm" in row else ""))
    if "floor" in r:
        f = r["floor"]
        print(f"  floor: {f['points']} points, |z - {f['floor_z_m']}| median {f['median_abs_mm']:.3f} mm, "
              f"p95 {f['p95_abs_mm']:.3f} mm" + (f", bound {f['bound_mm']:.3f} mm" if f["checked"] else
                                                   f" ({f['why']})"))
    if "poses" in r:
        p = r["poses"]
        print(f"  recorded vs true poses: max {p['max_dt_mm']:.3f} mm, {p['max_dr_deg']:.4f} deg, "
              f"max |element diff| {p['max_abs_elem']:.3g}")
    for n in r["notes"]:
        print(f"  note: {n}")
    if "timing_s" in r:
        t = r["timing_s"]
        print(f"  time: {t['total']:.2f} s (mesh {t['mesh_setup']:.2f} s, distances {t['distances']:.2f} s)")
    if r["pass"]:
        print("PASS")
    else:
        for f in r["failures"]:
            print(f"FAIL: {f}")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("scan_dir")
    ap.add_argument("--noise", required=True, choices=sorted(NOISE_K))
    ap.add_argument("--json", metavar="OUT.json", help="write the numbers and the verdict to this file")
    ap.add_argument("--max-points-per-view", type=int, default=MAX_POINTS_PER_VIEW,
                    help=f"random subsample (fixed seed) of workpiece and floor points per view "
                         f"(default {MAX_POINTS_PER_VIEW})")
    a = ap.parse_args(argv)
    try:
        r = check(a.scan_dir, a.noise, a.max_points_per_view)
    except (InputError, KeyError, ValueError, OSError) as e:
        msg = f"{type(e).__name__}: {e}" if not isinstance(e, InputError) else str(e)
        print(f"ERROR: cannot check {a.scan_dir}: {msg}", file=sys.stderr)
        if a.json:
            with open(a.json, "w") as f:
                json.dump({"scan": a.scan_dir, "noise": a.noise, "pass": False, "error": msg}, f, indent=1)
        return 2
    print_report(r)
    if a.json:
        with open(a.json, "w") as f:
            json.dump(r, f, indent=1)
    return 0 if r["pass"] else 1


if __name__ == "__main__":
    sys.exit(main())
