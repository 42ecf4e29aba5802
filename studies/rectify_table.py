#!/usr/bin/env python3
"""The table of studies/rectify_eval.sh: mean per-parameter MSE and novel-view loss over materials,
rectified (perspective photos -> rectify -> capture) against direct (texture-space capture), and
their ratio. Usage: rectify_table.py OUTPUT_FOLDER [--skip SEED ...] (leave those materials out)"""
import json, pathlib, sys
from collections import defaultdict

root = pathlib.Path(sys.argv[1])
skip = set(sys.argv[sys.argv.index("--skip") + 1:]) if "--skip" in sys.argv else set()
keys = ["diffuse", "specular", "normal", "lobes", "rotation", "fresnel", "novel_view_image_loss"]
names = ["a_d", "a_s", "n_s", "sigma", "alpha", "F0", "novel-view loss"]
sums = defaultdict(lambda: defaultdict(float))
counts = defaultdict(int)
for run in sorted(p for p in root.iterdir() if p.is_dir()):
    seed, n, light = run.name.split("-")
    if seed in skip:
        continue
    reports = {s: run / f"{s}-result" / "report.json" for s in ("direct", "rectified")}
    if not all(r.exists() for r in reports.values()):
        continue
    for source, path in reports.items():
        errors = json.loads(path.read_text())["errors"]
        for k in keys:
            sums[(int(n), light, source)][k] += errors[k]
    counts[(int(n), light)] += 1
print("| N | light | capture | " + " | ".join(names) + " |")
print("|---|---|---|" + "---|" * len(names))
for (n, light), count in sorted(counts.items()):
    rows = {s: {k: sums[(n, light, s)][k] / count for k in keys} for s in ("direct", "rectified")}
    for s in ("direct", "rectified"):
        print(f"| {n} | {light} | {s} | " + " | ".join(f"{rows[s][k]:.4f}" for k in keys) + " |")
    print(f"| {n} | {light} | ratio | " + " | ".join(f"{rows['rectified'][k] / rows['direct'][k]:.2f}" if rows['direct'][k] > 0 else "-" for k in keys) + " |")
seeds = sorted({p.name.split('-')[0] for p in root.iterdir() if p.is_dir()} - skip)
print(f"\n({sum(counts.values())} runs: {', '.join(seeds)} seeds)")
