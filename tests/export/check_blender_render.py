#!/usr/bin/env python3
"""The Blender export rendered by Blender itself against `anisocap render`: for every procedural
family, a 32 x 32 material (`anisocap synthesize --kind K`) is exported with `--format blender`,
rendered by `anisocap render` and by Cycles on the CPU (blender_render.py, in `blender -b`) at three
camera / point-light configurations, and compared texel by texel (relative L1: sum |Cycles - anisocap|
/ sum anisocap over the texels and channels). Each configuration has its camera and light at
distance 2 from the material's centre, mirrored about the vertical, at azimuth -60 degrees:
  near-normal  the camera 10 degrees from the vertical;
  45           the camera 45 degrees from the vertical;
  grazing      the camera 15 degrees above the horizon.
Also checked inside Blender (blender_render.py): the script run as from the Text Editor (its
__file__ inside a .blend) finds its textures, a moved export fails with a clear message, the
factory cube is removed and the script's camera sees the whole plane, and the light units on a
white Lambertian plane.

Exits 77 when `blender` is not installed. Usage:
  check_blender_render.py ANISOCAP_PROGRAM [--families a,b] [--table FILE] [--keep DIR]
--table writes the Markdown table of docs/results.md."""
import argparse
import json
import math
import os
import shutil
import subprocess
import sys
import tempfile

FAMILIES = ["plain", "basket", "twill", "herringbone", "satin", "velvet", "brushed", "spun", "leather", "coated", "printed", "foil"]
CONFIGS = [("near-normal", 10.0), ("45", 45.0), ("grazing", 75.0)]  # camera angle from the vertical
AZIMUTH = math.radians(-60.0)
DISTANCE = 2.0

# The goal: at most 10% (near-normal, 45 degrees) and 20% (grazing). Where Cycles' Principled BSDF
# cannot follow the Ward + Schlick BRDF, the bound is the error measured with Debian 12's Blender
# 3.4.1 times 1.1 plus 2 points (the renders are deterministic: one sample, direct light only), and
# the reasons are docs/results.md's ("The Blender export in Cycles"):
#   lobe   GGX's long tail against Ward's Gaussian: with alpha = 0.9 sigma the GGX peak is 1.23x
#          Ward's and its shoulders darker; narrow lobes (brushed, spun, coated, foil, satin) show it
#          texel by texel even where the brightness matches;
#   fresnel  Principled's specular Fresnel rises from F0 = a'_s to white at grazing angles, Ward's
#          to a'_s / F0 only (leather: 0.007 / 0.031, 4.3x less), so grazing highlights are too bright
#          where F0 > a'_s (twill, leather, velvet); a smaller Specular fitted to the curve cost more
#          at normal incidence than it gained;
#   diffuse  the Principled diffuse (Burley's) darkens at grazing mirror configurations, Lambert's
#          does not.
GOAL = {"near-normal": 0.10, "45": 0.10, "grazing": 0.20}
BOUNDS = {
    "plain": {"near-normal": 0.19, "45": 0.23, "grazing": 0.43},  # lobe; metal fit on its high-F0 texels
    "basket": {"grazing": 0.57},                                  # fresnel, diffuse
    "twill": {"near-normal": 0.16, "45": 0.19, "grazing": 1.25},  # lobe; fresnel (x2 at grazing)
    "herringbone": {"grazing": 0.54},                             # lobe, diffuse
    "satin": {"near-normal": 0.17, "45": 0.21, "grazing": 0.78},  # lobe
    "velvet": {"near-normal": 0.14, "45": 0.20, "grazing": 0.59}, # fresnel
    "brushed": {"near-normal": 0.27, "45": 0.28, "grazing": 0.40},# lobe (aspect 4.5)
    "spun": {"near-normal": 0.26, "45": 0.27, "grazing": 0.60},   # lobe (aspect 7.8)
    "leather": {"45": 0.17, "grazing": 1.51},                     # fresnel (x2.3 at grazing)
    "coated": {"near-normal": 0.30, "45": 0.33, "grazing": 0.39}, # lobe (sigma 0.04)
    "foil": {"near-normal": 0.31, "45": 0.33, "grazing": 0.46},   # lobe
}


def fail(message):
    print("check_blender_render: " + message, flush=True)
    sys.exit(1)


def configurations():
    out = []
    for name, zenith in CONFIGS:
        t = math.radians(zenith)
        direction = (math.cos(AZIMUTH) * math.sin(t), math.sin(AZIMUTH) * math.sin(t), math.cos(t))
        camera = [DISTANCE * c for c in direction]
        light = [-camera[0], -camera[1], camera[2]]
        out.append({"name": name, "camera": camera, "light": light, "intensity": math.pi * DISTANCE * DISTANCE})
    return out


def run(command, **kwargs):
    result = subprocess.run(command, capture_output=True, text=True, **kwargs)
    if result.returncode != 0:
        fail(f"{' '.join(command)} failed ({result.returncode}):\n{result.stdout[-3000:]}\n{result.stderr[-3000:]}")
    return result


def main():
    parser = argparse.ArgumentParser()
    parser.add_argument("program")
    parser.add_argument("--families", default=",".join(FAMILIES))
    parser.add_argument("--table")
    parser.add_argument("--keep")
    args = parser.parse_args()
    blender = shutil.which("blender")
    if blender is None:
        print("check_blender_render: blender is not installed (scripts/install-deps.sh --blender); skipped")
        sys.exit(77)
    families = args.families.split(",")
    configs = configurations()
    work = args.keep or tempfile.mkdtemp(prefix="anisocap-blender-")
    os.makedirs(work, exist_ok=True)
    try:
        capture = {"images": [{"file": f"{c['name']}.exr", "camera": c["camera"], "light": c["light"], "intensity": c["intensity"]} for c in configs]}
        job = {"width": 32, "height": 32, "work": work, "configs": configs, "families": [], "out": os.path.join(work, "results.json")}
        for k, family in enumerate(families):
            syn = os.path.join(work, "syn", family)
            run([args.program, "synthesize", "-o", syn, "--width", "32", "--height", "32", "--images", "4", "--kind", family, "--seed", str(11 + k), "--threads", "1"])
            with open(os.path.join(syn, "capture.json"), "w") as f:
                json.dump(capture, f)
            renders = os.path.join(work, "anisocap", family)
            run([args.program, "render", "--maps", os.path.join(syn, "truth"), "--capture", os.path.join(syn, "capture.json"), "-o", renders])
            run([args.program, "export", os.path.join(syn, "truth"), "--format", "blender", "-o", os.path.join(work, "exported", family)])
            job["families"].append({"name": family, "script": os.path.join(work, "moved", family, "material.py"),
                                    "renders": {c["name"]: os.path.join(renders, f"{c['name']}.exr") for c in configs}})
        # One export left where it was written (the Text Editor run reads the folder written into the
        # script); the others moved (the command-line runs find their textures beside the script).
        run([args.program, "export", os.path.join(work, "syn", families[0], "truth"), "--format", "blender", "-o", os.path.join(work, "editor")])
        job["editor_script"] = os.path.join(work, "editor", "material.py")
        os.rename(os.path.join(work, "exported"), os.path.join(work, "moved"))
        with open(os.path.join(work, "job.json"), "w") as f:
            json.dump(job, f)
        env = dict(os.environ, OMP_NUM_THREADS=os.environ.get("OMP_NUM_THREADS", "2"))
        result = subprocess.run([blender, "-b", "--factory-startup", "--python-exit-code", "1", "--python",
                                 os.path.join(os.path.dirname(os.path.abspath(__file__)), "blender_render.py"), "--", os.path.join(work, "job.json")],
                                capture_output=True, text=True, env=env)
        if result.returncode != 0 or not os.path.exists(job["out"]):
            fail(f"blender failed ({result.returncode}):\n{result.stdout[-4000:]}\n{result.stderr[-4000:]}")
        results = json.load(open(job["out"]))
        for line in results["checks"]:
            print("check_blender_render: " + line)
        if results["lambert"] > 0.01:
            fail(f"light units: the white Lambertian plane is {100 * results['lambert']:.2f}% from cos I / (pi d^2)")
        rows = [f"| material | " + " | ".join(c["name"] for c in configs) + " |", "|---|" + "---|" * len(configs)]
        failures = []
        for family in families:
            cells = []
            for c in configs:
                r = results["families"][family][c["name"]]
                if r["left_out"] > 0.05 * 32 * 32:
                    failures.append(f"{family} {c['name']}: {r['left_out']} texels not seen by their own pixel")
                bound = BOUNDS.get(family, {}).get(c["name"], GOAL[c["name"]])
                mark = "" if r["error"] <= GOAL[c["name"]] else " *"
                cells.append(f"{100 * r['error']:.1f}% (x{r['brightness']:.2f}){mark}")
                if r["error"] > bound:
                    failures.append(f"{family} {c['name']}: {100 * r['error']:.1f}% above {100 * bound:.0f}%")
            rows.append(f"| {family} | " + " | ".join(cells) + " |")
        table = "\n".join(rows)
        print(f"Blender {results['blender']} (Cycles, CPU) against anisocap render, relative L1 (brightness ratio):\n{table}")
        if args.table:
            with open(args.table, "w") as f:
                f.write(table + "\n")
        if failures:
            fail("\n  ".join(["above the bounds:"] + failures))
    finally:
        if not args.keep:
            shutil.rmtree(work, ignore_errors=True)


main()
