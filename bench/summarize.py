#!/usr/bin/env python3
"""Tables of one `bench/compare` run: awl against its peers, end to end and per stage.

    python3 bench/summarize.py OUT_DIR        # prints Markdown; also writes OUT_DIR/summary.md

Reads what bench/compare left in OUT_DIR (stdlib only):
  e2e/runs.tsv                       tool, threads, run, wall s, peak RSS kB, output folder
  e2e/<tool>-t<T>-r<i>/              awl: report.json; open3d: timings.json
  e2e/eval-<tool>-t<T>/summary.json  `awl evaluate` of run 1's model against the scan's CAD
  stages/awl-<stage>.txt|.err|.time  divan output, `check:` lines, /usr/bin/time -v
  stages/peers-<stage>.json|.time    bench_stages.py output, /usr/bin/time -v
"""
import csv
import json
import os
import re
import statistics
import sys

UNITS = {"ns": 1e-9, "µs": 1e-6, "us": 1e-6, "ms": 1e-3, "s": 1.0}
# awl report.json stages -> the Open3D pipeline's stages (each pipeline with its own parameters)
PIPELINE = [
    ("load (PNG decode + back-projection)", ["load"], ["load"]),
    ("per-view voxel + SOR + normals", ["roi", "voxel", "outliers", "normals", "outliers + normals", "voxel + outliers + normals", "plane normals"], ["preprocess"]),
    ("register (ICP)", ["register"], ["register"]),
    ("merge", ["merge"], ["merge"]),
    ("floor + DBSCAN", ["floor + clusters"], ["segment"]),
    ("MLS", ["mls"], ["smooth"]),
]
MICRO = ["voxel", "sor", "normals", "icp_vox", "icp_full", "dbscan", "mls"]


def median(xs):
    return statistics.median(xs) if xs else None


def peak_kb(path):
    try:
        with open(path) as fh:
            m = re.search(r"Maximum resident set size \(kbytes\): (\d+)", fh.read())
        return int(m.group(1)) if m else None
    except OSError:
        return None


def parse_divan(path):
    """{'sim300k::voxel::1': median seconds} from divan's tree output."""
    out, stack = {}, []
    try:
        lines = open(path, encoding="utf-8").read().splitlines()
    except OSError:
        return out
    for line in lines:
        m = re.match(r"^((?:[│ ]  )*)[├╰]─ (\S+)\s*(.*)$", line)
        if not m:
            continue
        depth = len(m.group(1)) // 3
        stack[depth:] = [m.group(2)]
        cols = [c.strip() for c in m.group(3).split("│")]
        if len(cols) >= 3 and cols[2]:
            v = cols[2].split()
            if len(v) == 2 and v[1] in UNITS:
                out["::".join(stack)] = float(v[0]) * UNITS[v[1]]
    return out


def parse_checks(path):
    """{'sim300k icp_vox 1': {'err_mm': .., ...}} from the benches' `check:` lines."""
    out = {}
    try:
        lines = open(path, encoding="utf-8").read().splitlines()
    except OSError:
        return out
    for line in lines:
        if not line.startswith("check: "):
            continue
        w = line.split()
        kv = dict(x.split("=", 1) for x in w[3:] if "=" in x)
        out[f"{w[1]} {w[2]} {kv.get('threads')}"] = kv
    return out


def fmt_s(s):
    if s is None:
        return "—"
    return f"{s * 1e3:.1f} ms" if s < 1 else f"{s:.2f} s"


def fmt_mb(kb):
    return "—" if kb is None else f"{kb / 1024:.0f} MB"


def ratio(a, b):
    return "—" if a is None or not b else f"{a / b:.2f}"


CHECK_TEXT = {
    "err_mm": lambda c: f"{float(c['err_mm']):.2f} mm",
    "clusters": lambda c: f"{c['clusters']} clusters",
    "fitness": lambda c: f"fitness {c['fitness']}, rmse {c['rmse_mm']} mm",
    "n_out": lambda c: f"{c['n_out']} pts",
}


def check_text(check, keys):
    """The accuracy check of a stage row: the first of `keys` it has, formatted ("" if none)."""
    for key in keys:
        if key in check:
            return CHECK_TEXT[key](check)
    return ""


# the end-to-end rows: awl's default, awl --preset fast, the Open3D pipeline, and an earlier awl
# binary's two presets (bench/compare --baseline)
TOOLS = ("awl", "awl-fast", "open3d", "base", "base-fast")


def e2e(out):
    path = os.path.join(out, "e2e", "runs.tsv")
    if not os.path.exists(path):
        return [], {}
    runs = list(csv.DictReader(open(path), delimiter="\t"))
    by = {}
    for r in runs:
        by.setdefault((r["tool"], int(r["threads"])), []).append(r)
    lines = ["## End to end: `awl fuse` vs `open3d_pipeline.py` on the 12-view scan", "",
             "| threads | tool | runs | median wall | peak RSS | awl / open3d | RMSE on-object (all points; off-object share) | completeness@5mm | model points |",
             "|---|---|---|---|---|---|---|---|---|"]
    stage_t = {}
    for t in sorted({k[1] for k in by}, reverse=True):
        walls = {tool: median([float(r["wall_s"]) for r in by.get((tool, t), [])]) for tool in TOOLS}
        for tool in TOOLS:
            rs = by.get((tool, t), [])
            if not rs:
                continue
            peak = max(int(r["maxrss_kb"]) for r in rs)
            acc = ("—", "—", "—")
            sp = os.path.join(out, "e2e", f"eval-{tool}-t{t}", "summary.json")
            if os.path.exists(sp):
                s = json.load(open(sp))
                comp = next((c["fraction"] for c in s.get("completeness", {}).get("thresholds", [])
                             if abs(c["threshold_mm"] - 5) < 1e-9), None)
                d = s.get("distances", {})
                on, al = (d.get("on_object") or {}).get("rmse_m"), (d.get("all") or {}).get("rmse_m")
                off = d.get("off_object_fraction")
                acc = (f"{on * 1e3:.2f} mm ({al * 1e3:.1f} mm; {100 * off:.1f} % off)" if None not in (on, al, off)
                       else "—",
                       f"{100 * comp:.1f} %" if comp is not None else "—", str(s.get("model_points", "—")))
            rat = ratio(walls[tool], walls["open3d"]) if tool != "open3d" else ""
            lines.append(f"| {t} | {tool} | {len(rs)} | {fmt_s(walls[tool])} | {fmt_mb(peak)} | {rat} | "
                         f"{acc[0]} | {acc[1]} | {acc[2]} |")
            # per-stage seconds of each run
            for r in rs:
                d = r["dir"]
                if tool == "awl":
                    p = os.path.join(d, "report.json")
                    if os.path.exists(p):
                        for st in json.load(open(p))["stages"]:
                            stage_t.setdefault((tool, t, st["name"]), []).append(st["seconds"])
                elif tool == "open3d":
                    p = os.path.join(d, "timings.json")
                    if os.path.exists(p):
                        for name, sec in json.load(open(p))["stages_s"].items():
                            stage_t.setdefault((tool, t, name), []).append(sec)
    lines.append("")
    for t in sorted({k[1] for k in by}, reverse=True):
        for tool in TOOLS:
            if len(by.get((tool, t), [])) and t != 2:
                w2 = median([float(r["wall_s"]) for r in by.get((tool, 2), [])])
                w1 = median([float(r["wall_s"]) for r in by.get((tool, t), [])])
                if w1 and w2:
                    lines.append(f"{tool} speed-up 1 -> 2 threads: {w1 / w2:.2f}x")
    for t in sorted({k[1] for k in by}, reverse=True):
        for tool, base in (("awl", "base"), ("awl-fast", "base-fast")):
            now, before = by.get((tool, t), []), by.get((base, t), [])
            if now and before:
                wall = median([float(r["wall_s"]) for r in now]) / median([float(r["wall_s"]) for r in before])
                rss = median([int(r["maxrss_kb"]) for r in now]) / median([int(r["maxrss_kb"]) for r in before])
                lines.append(f"{tool} / baseline, {t} thread(s), medians: wall {wall:.3f}x, peak RSS {rss:.3f}x")
    ident = os.path.join(out, "e2e", "identical.txt")
    if os.path.exists(ident):
        lines.append(open(ident).read().strip())
    lines += ["", "## Pipeline stages (median over the runs above; each pipeline with its own parameters)", "",
              "| stage | threads | awl | open3d pipeline | awl / open3d |", "|---|---|---|---|---|"]
    for t in sorted({k[1] for k in by}, reverse=True):
        for label, a_names, o_names in PIPELINE:
            a = sum(median(stage_t.get(("awl", t, n), [])) or 0 for n in a_names)
            o = sum(median(stage_t.get(("open3d", t, n), [])) or 0 for n in o_names)
            lines.append(f"| {label} | {t} | {fmt_s(a)} | {fmt_s(o)} | {ratio(a, o)} |")
    return lines, stage_t


def micro(out, stage_t):
    sd = os.path.join(out, "stages")
    if not os.path.isdir(sd):
        return []
    lines = ["## Stages on the peers' inputs (`crates/awl/benches/stages.rs` vs `bench_stages.py`)", "",
             "Best peer = the fastest peer row with at most as many threads (for ICP: only peers whose pose "
             "error is at most max(0.25 mm, 2 x awl's)). Peak RSS = the whole bench process of that stage "
             "(awl: both inputs and both thread counts; peers: every peer of the stage, both workers).", "",
             "| stage | input | threads | awl median | best peer | peer median | awl / peer | awl peak | peers peak | check (awl; peer) |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    scan_benches = ["load_view", "icp_views", "joint"]  # divan group `scan`: one output file
    for stage in MICRO + scan_benches:
        file_stage = "scan" if stage in scan_benches else stage
        awl = parse_divan(os.path.join(sd, f"awl-{file_stage}.txt"))
        checks = parse_checks(os.path.join(sd, f"awl-{file_stage}.err"))
        a_peak = peak_kb(os.path.join(sd, f"awl-{file_stage}.time"))
        p_peak = peak_kb(os.path.join(sd, f"peers-{stage}.time"))
        rows = []
        pj = os.path.join(sd, f"peers-{stage}.json")
        if os.path.exists(pj):
            rows = json.load(open(pj))["rows"]
        keys = sorted(k for k in awl if k.split("::")[1] == stage)
        for k in keys:
            inp, _, thr = k.split("::")
            t = int(thr)
            a = awl[k]
            chk = checks.get(f"{inp} {stage} {t}", {})
            a_chk = check_text(chk, ("err_mm", "clusters", "fitness"))
            cand = [r for r in rows if r["input"] == inp and r["threads"] <= t]
            if "err_mm" in chk:
                lim = max(0.25, 2 * float(chk["err_mm"]))
                cand = [r for r in cand if r.get("err_mm", 1e9) <= lim]
            best = min(cand, key=lambda r: r["median_wall_s"]) if cand else None
            peer, pm, p_chk = "—", None, ""
            if best:
                peer, pm = f"{best['peer']} ({best['threads']}t)", best["median_wall_s"]
                p_chk = check_text(best, ("err_mm", "clusters", "n_out"))
            elif stage == "load_view":
                o = median(stage_t.get(("open3d", t, "load"), []))
                if o:
                    peer, pm = "open3d pipeline load / 12 views", o / 12
            elif stage == "mls":
                peer = "(PCL MLS: pipeline table)"
            lines.append(f"| {stage} | {inp} | {t} | {fmt_s(a)} | {peer} | {fmt_s(pm)} | {ratio(a, pm)} | "
                         f"{fmt_mb(a_peak)} | {fmt_mb(p_peak)} | {a_chk}{'; ' + p_chk if p_chk else ''} |")
    return lines


def main():
    out = sys.argv[1]
    lines, stage_t = e2e(out)
    lines += [""] + micro(out, stage_t)
    meta = os.path.join(out, "machine.txt")
    if os.path.exists(meta):
        lines = ["## Machine", "", "```", open(meta).read().strip(), "```", ""] + lines
    text = "\n".join(lines) + "\n"
    open(os.path.join(out, "summary.md"), "w").write(text)
    print(text)


if __name__ == "__main__":
    main()
