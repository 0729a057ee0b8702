#!/usr/bin/env python3
"""Turns `arbord bench --format json` output into the Markdown tables of
docs/BENCH.md: the study's tables 1-4 beside ours, the ray sets of every
model with Embree's ratios, SAH costs, and the k-d SAH build's N log N check.

    scripts/bench_tables.py ALL_THREADS.json ONE_THREAD.json KD_STATS.json > tables.md

ALL_THREADS.json: every kind and builder on every model, --embree, all cores.
ONE_THREAD.json: the sah rows and Embree at --threads 1.
KD_STATS.json: `arbord stats --accel kd --builder sah --json` lines (for refs).
"""
import json
import math
import sys

# The study's tables (STUDY.md), columns in COLUMNS order; None: not measured.
COLUMNS = [("bvh", "spatial"), ("bvh", "median"), ("bvh", "mean"), ("bvh", "sah"),
           ("kd", "spatial"), ("kd", "median"), ("kd", "mean"), ("kd", "sah")]
STUDY = {
    "build_ms": {"galleon": [5, 79, 10, None, 22, 206, 28, 36060],
                 "castle": [17, 269, 27, None, 61, 643, 85, 251319],
                 "eagle": [37, 406, 8, None, 54, 811, 83, 459217]},
    "mean_leaf_depth": {"galleon": [11, 11, 11, None, 15, 15, 15, 16],
                        "castle": [13, 13, 13, None, 18, 16, 16, 18],
                        "eagle": [16, 13, 13, None, 17, 16, 16, 18]},
    "mean_tris_per_leaf": {"galleon": [5, 2, 1, None, 19, 12, 12, 14],
                           "castle": [9, 2, 1, None, 23, 10, 10, 16],
                           "eagle": [2, 2, 1, None, 47, 11, 9, 24]},
    "render_ms": {"galleon": [9906, 2829, 1395, None, 13179, 4588, 3816, 2911],
                  "castle": [16137, 2461, 1021, None, 9964, 3525, 2232, 2224],
                  "eagle": [3532, 1992, 1418, None, 14054, 5444, 5827, 3015]},
}
TITLES = {"build_ms": "Table 1: build ms", "mean_leaf_depth": "Table 2: mean leaf depth",
          "mean_tris_per_leaf": "Table 3: mean triangles per leaf", "render_ms": "Table 4: render ms"}


def load(path):
    with open(path) as f:
        return [json.loads(line) for line in f if line.strip().startswith("{")]


def model_name(row):
    name = row["model"].rsplit("/", 1)[-1]
    for ext in (".obj.gz", ".obj"):
        if name.endswith(ext):
            return name[: -len(ext)]
    return name


def fmt(v, digits=2):
    if v is None:
        return "-"
    if isinstance(v, int) or float(v).is_integer() and abs(v) >= 100:
        return f"{int(v):,}"
    return f"{v:.{digits}f}"


def find(rows, model, accel, builder):
    for r in rows:
        if model_name(r) == model and r["accel"] == accel and r["builder"] == builder:
            return r
    return None


def study_tables(rows):
    out = []
    head = "| model | source | " + " | ".join(f"{a.upper()}-{b}" for a, b in COLUMNS) + " |"
    for key, title in TITLES.items():
        out += [f"### {title}", "", head, "|---|---|" + "---:|" * len(COLUMNS)]
        for model in ("galleon", "castle", "eagle"):
            out.append(f"| {model} | study | " + " | ".join(fmt(v, 0) for v in STUDY[key][model]) + " |")
            if model != "eagle":
                ours = [find(rows, model, a, b) for a, b in COLUMNS]
                out.append(f"| {model} | arbor | " + " | ".join(fmt(r[key] if r else None) for r in ours) + " |")
        out.append("")
    return out


def rayset_table(rows, threads):
    models = sorted({model_name(r) for r in rows}, key=lambda m: min(r["triangles"] for r in rows
                                                                      if model_name(r) == m))
    out = [f"| model | triangles | tracer | build ms | primary Mrays/s | diffuse Mrays/s | shadow Mrays/s"
           f" | primary x Embree | shadow x Embree | diffuse x Embree | build x Embree | bytes/tri"
           f" | primary hits | primary tsum |",
           "|---|---:|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for m in models:
        # Embree's row, whichever mode it ran in (arbord bench --embree-robust names it "robust")
        peer = next((r for r in rows if model_name(r) == m and r["accel"] == "embree"), None)
        for r in (find(rows, m, "bvh", "sah"), find(rows, m, "kd", "sah"), peer):
            if r is None or r["threads"] != threads:
                continue
            accel, builder = r["accel"], r["builder"]
            tracer = f"{accel} {builder}"
            if accel == "embree":
                notes = [n for n in ("robust" if builder == "robust" else None,
                                     f"at most {r['kernel']}" if r.get("kernel") else None) if n]
                tracer = f"Embree ({', '.join(notes)})" if notes else "Embree"
            build_ratio = (r["build_ms"] / peer["build_ms"] if peer and accel != "embree" and peer["build_ms"]
                           else None)
            out.append(f"| {m} | {r['triangles']:,} | {tracer} | {fmt(r['build_ms'])} | {fmt(r['primary_mrays'])}"
                       f" | {fmt(r['diffuse_mrays'])} | {fmt(r['shadow_mrays'])}"
                       f" | {fmt(r.get('primary_ratio'))} | {fmt(r.get('shadow_ratio'))}"
                       f" | {fmt(r.get('diffuse_ratio'))} | {fmt(build_ratio)} | {fmt(r.get('bytes_per_tri'))}"
                       f" | {r['primary_hits']:,} | {r['primary_tsum']:.6g} |")
    return out


def sah_cost_table(rows):
    models = sorted({model_name(r) for r in rows}, key=lambda m: find(rows, m, "bvh", "sah")["triangles"])
    out = ["| model | " + " | ".join(f"{a} {b}" for a, b in COLUMNS) + " | lowest in bvh / kd |",
           "|---|" + "---:|" * len(COLUMNS) + "---|"]
    for m in models:
        costs = [find(rows, m, a, b) for a, b in COLUMNS]
        vals = [c["sah_cost"] if c else None for c in costs]
        best = []
        for kind in ("bvh", "kd"):
            kv = [(v, b) for (a, b), v in zip(COLUMNS, vals) if a == kind and v is not None]
            best.append(min(kv)[1] if kv else "-")
        out.append(f"| {m} | " + " | ".join(fmt(v) for v in vals) + f" | {best[0]} / {best[1]} |")
    return out


def nlogn_table(rows, stats):
    """kd sah build time over N log2 N, and over R log2 R where R is the
    number of triangle references (from `arbord stats --json`): a k-d tree
    duplicates straddling triangles, and the sweep's work grows with R."""
    out = ["| model | N triangles | R refs | R / N | kd sah build ms | ns / (N log2 N) | ns / (R log2 R) |",
           "|---|---:|---:|---:|---:|---:|---:|"]
    kd = sorted((r for r in rows if r["accel"] == "kd" and r["builder"] == "sah"), key=lambda r: r["triangles"])
    for r in kd:
        n, ms = r["triangles"], r["build_ms"]
        st = find(stats, model_name(r), "kd", "sah")
        refs = st["refs"] if st else None
        per_r = f"{ms / (refs * math.log2(refs)) * 1e6:.1f}" if refs else "-"
        out.append(f"| {model_name(r)} | {n:,} | {fmt(refs)} | {fmt(refs / n) if refs else '-'} | {fmt(ms)}"
                   f" | {ms / (n * math.log2(n)) * 1e6:.1f} | {per_r} |")
    return out


def main():
    all_rows = load(sys.argv[1])
    one_rows = load(sys.argv[2]) if len(sys.argv) > 2 else []
    stats = load(sys.argv[3]) if len(sys.argv) > 3 else []
    threads = max(r["threads"] for r in all_rows)
    lines = ["## The study's tables", ""] + study_tables(all_rows)
    lines += ["## Ray sets, all cores", ""] + rayset_table(all_rows, threads) + [""]
    if one_rows:
        lines += ["## Ray sets, one thread", ""] + rayset_table(one_rows, 1) + [""]
    lines += ["## SAH cost of every builder", ""] + sah_cost_table(all_rows) + [""]
    lines += ["## k-d SAH build: N log N", ""] + nlogn_table(all_rows, stats) + [""]
    print("\n".join(lines))


if __name__ == "__main__":
    main()
