#!/usr/bin/env python3
"""The capture guide's loop through the program, as a user without a camera runs it.

Per material: `anisocap photograph` takes a flash-only start (perspective 8-bit JPEGs with sensor
noise), `rectify` and `capture --truth` fit it, and `plan` proposes the next photographs. Then the
same photographs are taken again with two more added by `photograph --plan` (the set's
photographs are the same bytes) from one of three plan files:
  - plan:   the plan.json `plan` wrote;
  - rule:   the paper's Fresnel pair (set alpha's two grazing configurations: camera low, light
            mirrored), written as a plan.json of lamp photographs;
  - random: two independent configurations of set beta (camera and light each anywhere above),
            written the same way;
and each is rectified with the others and captured again. Errors against the truth: the mean of
report.json's five map errors (diffuse, specular, normal, lobes, F0), F0's, and the mean
|log(R + 0.01) - log(B + 0.01)| of three grazing views (camera and lamp 17 degrees above the
plane on opposite sides, rendered by `anisocap render`). Prints one line per material and a
markdown table of the means.

    studies/plan_loop.py build/anisocap OUT [--size 64] [--start 6] [--seeds 1] [--families plain,...]
"""
import json
import math
import pathlib
import sys

import numpy as np

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent / "reference"))
from exr import read_rgb  # noqa: E402

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))
from program_runs import FAMILIES, parse_arguments, run  # noqa: E402

STRATEGIES = ["start", "plan", "rule", "random"]


def plan_file(capture_json, indices, path):
    """A plan.json of lamp photographs at the configurations `indices` of a capture.json."""
    images = json.loads(pathlib.Path(capture_json).read_text())["images"]
    photos = [{"kind": "lamp", "camera": images[i]["camera"], "light": images[i]["light"]} for i in indices]
    pathlib.Path(path).write_text(json.dumps({"photos": photos}, indent=2) + "\n")


def grazing_capture(folder):
    """Three grazing views: camera and lamp 17 degrees above the plane, opposite, 2 sample lengths away."""
    e = math.radians(17)
    images = []
    for k, a in enumerate([0.0, 0.25 * math.pi, 0.5 * math.pi]):
        camera = [2 * math.cos(e) * math.cos(a), 2 * math.cos(e) * math.sin(a), 2 * math.sin(e)]
        light = [-camera[0], -camera[1], camera[2]]
        i = math.pi * 4 / math.sin(e)  # irradiance 1 at the centre
        images.append({"file": f"grazing_{k}.exr", "camera": camera, "light": light, "intensity": [i, i, i]})
    path = pathlib.Path(folder) / "grazing.json"
    path.write_text(json.dumps({"images": images}, indent=2) + "\n")
    return path


def grazing_error(binary, maps, truth_views, grazing, out, cwd):
    run([binary, "render", "--maps", maps, "--capture", grazing, "-o", out], cwd)
    total = 0.0
    for k in range(3):
        r = read_rgb(pathlib.Path(cwd) / out / f"grazing_{k}.exr")
        b = read_rgb(pathlib.Path(cwd) / truth_views / f"grazing_{k}.exr")
        total += float(np.mean(np.abs(np.log(np.maximum(r, 0) + 0.01) - np.log(np.maximum(b, 0) + 0.01))))
    return total / 3


def main():
    a, binary, out = parse_arguments(__doc__, 1, lambda p: p.add_argument("--start", type=int, default=6))
    grazing = grazing_capture(out).resolve()
    sums = {s: np.zeros(3) for s in STRATEGIES}
    wins = {s: np.zeros(3, dtype=int) for s in STRATEGIES[1:]}
    rows = []
    for f, family in enumerate(a.families.split(",")):
        for s in range(a.seeds):
            seed = 900 + FAMILIES.index(family) + 100 * s
            d = out / f"{family}_{seed}"
            d.mkdir(exist_ok=True)
            shoot = ["--size", a.size, "--kind", family, "--seed", seed, "--images", a.start, "--flash",
                     "--shot-noise", 0.01, "--read-noise", 0.002]
            run([binary, "photograph", "-o", "start"] + shoot, d)
            run([binary, "render", "--maps", "start/truth", "--capture", grazing, "-o", "truth-grazing"], d)
            # Other configurations for the rule and random additions (material and noise unused).
            other = ["--size", 8, "--photo-width", 16, "--photo-height", 12, "--seed", seed + 50000]
            run([binary, "photograph", "-o", "alpha", "--set", "alpha", "--images", 8] + other, d)
            run([binary, "photograph", "-o", "beta", "--set", "beta", "--images", 4] + other, d)
            plan_file(d / "alpha/direct/capture.json", [0, 1], d / "rule.json")
            plan_file(d / "beta/direct/capture.json", [0, 1], d / "random.json")
            errors = {}
            for strategy in STRATEGIES:
                shots = "start" if strategy == "start" else f"shoot-{strategy}"
                if strategy != "start":
                    plan = "start-result/plan.json" if strategy == "plan" else f"{strategy}.json"
                    run([binary, "photograph", "-o", shots, "--plan", plan] + shoot, d)
                run([binary, "rectify", f"{shots}/photos/photos.json", "-o", f"{shots}-rectified", "--resolution", a.size], d)
                run([binary, "capture", f"{shots}-rectified/capture.json", "-o", f"{shots}-result", "--truth", "start/truth",
                     "--no-view"], d)
                if strategy == "start":
                    run([binary, "plan", "start-result", "--sample-mm", 100], d)
                e = json.loads((d / f"{shots}-result/report.json").read_text())["errors"]
                maps = (e["diffuse"] + e["specular"] + e["normal"] + e["lobes"] + e["fresnel"]) / 5
                g = grazing_error(binary, f"{shots}-result", "truth-grazing", grazing, f"{shots}-grazing", d)
                errors[strategy] = np.array([maps, e["fresnel"], g])
                sums[strategy] += errors[strategy]
            for k in range(3):
                best = min(STRATEGIES[1:], key=lambda t: errors[t][k])
                wins[best][k] += 1
            rows.append((family, seed, errors))
            print(f"{family} {seed}: " + "  ".join(f"{t} {errors[t][0]:.4f}/{errors[t][1]:.4f}/{errors[t][2]:.3f}"
                                                   for t in STRATEGIES), flush=True)
    n = len(rows)
    names = {"start": f"{a.start} flash", "plan": "+ 2 planned", "rule": "+ 2 rule-based", "random": "+ 2 random"}
    print("\n| photographs | mean map error | F0 error | grazing-view error |\n|---|---|---|---|")
    for t in STRATEGIES:
        m = sums[t] / n
        print(f"| {names[t]} | {m[0]:.4f} | {m[1]:.4f} | {m[2]:.3f} |")
    print(f"| lowest of the three additions, of {n} materials | " +
          " | ".join(" / ".join(str(wins[t][k]) for t in STRATEGIES[1:]) for k in range(3)) + " |")


if __name__ == "__main__":
    main()
