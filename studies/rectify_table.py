#!/usr/bin/env python3
"""The table of studies/rectify_eval.sh: mean per-parameter MSE and novel-view loss over materials
of three captures of the same photographs: direct (the texture-space capture, linear and
unclipped), redrawn (the same with another draw of the sensor noise, rectify_eval.sh REDRAW=K:
the capture's own spread), clipped (the same clipped at white with its clipped texels masked, as
the 8-bit photographs are) and rectified (perspective photos -> rectify -> capture); then rectified
over direct (the goal), over clipped (what rectification itself costs) and over redrawn. Runs
without one of the optional captures leave its rows out. Usage:
rectify_table.py OUTPUT_FOLDER [--light flash|separate] [--skip SEED ...] (--skip last)"""
import json, pathlib, sys
from collections import defaultdict

root = pathlib.Path(sys.argv[1])
skip = set(sys.argv[sys.argv.index("--skip") + 1:]) if "--skip" in sys.argv else set()
only_light = sys.argv[sys.argv.index("--light") + 1] if "--light" in sys.argv else None
keys = ["diffuse", "specular", "normal", "lobes", "rotation", "fresnel", "novel_view_image_loss"]
names = ["a_d", "a_s", "n_s", "sigma", "alpha", "F0", "novel-view loss"]
sources = ("direct", "redrawn", "clipped", "rectified")
sums = defaultdict(lambda: defaultdict(float))
counts = defaultdict(lambda: defaultdict(int))
runs = 0
for run in sorted(p for p in root.iterdir() if p.is_dir()):
    seed, n, light = run.name.split("-")
    if seed in skip or (only_light and light != only_light):
        continue
    reports = {s: run / f"{s}-result" / "report.json" for s in sources}
    if not (reports["direct"].exists() and reports["rectified"].exists()):
        continue
    runs += 1
    for source, path in reports.items():
        if not path.exists():
            continue
        errors = json.loads(path.read_text())["errors"]
        for k in keys:
            sums[(int(n), light, source)][k] += errors[k]
        counts[(int(n), light)][source] += 1


def ratio(a, b):
    return f"{a / b:.2f}" if b > 0 else "-"


print("| N | light | capture | " + " | ".join(names) + " |")
print("|---|---|---|" + "---|" * len(names))
for (n, light), count in sorted(counts.items()):
    present = [s for s in sources if count[s] == count["direct"]]
    rows = {s: {k: sums[(n, light, s)][k] / count[s] for k in keys} for s in present}
    for s in present:
        print(f"| {n} | {light} | {s} | " + " | ".join(f"{rows[s][k]:.4f}" for k in keys) + " |")
    print(f"| {n} | {light} | rectified / direct | " + " | ".join(ratio(rows["rectified"][k], rows["direct"][k]) for k in keys) + " |")
    if "clipped" in present:
        print(f"| {n} | {light} | rectified / clipped | " + " | ".join(ratio(rows["rectified"][k], rows["clipped"][k]) for k in keys) + " |")
    if "redrawn" in present:
        print(f"| {n} | {light} | redrawn / direct | " + " | ".join(ratio(rows["redrawn"][k], rows["direct"][k]) for k in keys) + " |")
        print(f"| {n} | {light} | rectified / redrawn | " + " | ".join(ratio(rows["rectified"][k], rows["redrawn"][k]) for k in keys) + " |")
seeds = sorted({p.name.split('-')[0] for p in root.iterdir()
                if p.is_dir() and (not only_light or p.name.endswith('-' + only_light))} - skip)
print(f"\n({runs} runs: {', '.join(seeds)} seeds)")
