#!/usr/bin/env python3
"""Is the rotation of a brushed metal visible in its photographs? Reads it without any learning.

For each of --count brushed tiles made by `anisocap synthesize --kind brushed` (set alpha, 6 images:
2 grazing, 1 anisotropic pair, 2 independent, the kinds the estimator is trained on), the
structure tensor of the log images the estimator sees (docs/method.md section 5, "Network input"),
summed over the tile and the images, gives the direction across which the images change most;
the brushing runs perpendicular to it. The tile's alpha is compared with that direction the way
compare_maps compares rotations (modulo pi, and modulo the swapped lobe form, so modulo pi / 2):
the printed MSE is on the same scale as the estimator's anisotropic rotation error
(studies/README.md, "Can the estimator learn the rotation?"), where a guess that knows nothing
scores pi^2 / 48 = 0.206.

usage: rotation_structure_tensor.py ANISOCAP_PROGRAM [--count 32] [--size 128]
"""
import argparse
import math
import os
import subprocess
import sys
import tempfile

import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "reference"))
import exr  # noqa: E402


def quarter_turn_difference(a, b):
    """a - b wrapped into [-pi/4, pi/4]: alpha modulo pi and modulo the swapped lobe form."""
    d = a - b
    return d - (math.pi / 2) * round(d / (math.pi / 2))


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("program", help="the anisocap program")
    ap.add_argument("--count", type=int, default=32)
    ap.add_argument("--size", type=int, default=128)
    args = ap.parse_args()
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for i in range(args.count):
            out = os.path.join(tmp, f"t{i}")
            done = subprocess.run([args.program, "--threads", "1", "synthesize", "-o", out, "--kind", "brushed",
                                   "--width", str(args.size), "--height", str(args.size), "--images", "6",
                                   "--seed", str(1000 + i)], capture_output=True, text=True)
            if done.returncode != 0:
                sys.exit(f"rotation_structure_tensor: {args.program} synthesize failed:\n{done.stderr}")
            alpha = exr.read_rgb(os.path.join(out, "truth", "rotation.exr"))[..., 0]
            # The tile's angle: the mean doubled angle (brushing wanders by at most 0.03 rad).
            truth = 0.5 * math.atan2(np.sin(2 * alpha).mean(), np.cos(2 * alpha).mean())
            jxx = jxy = jyy = 0.0
            for k in range(6):
                image = exr.read_rgb(os.path.join(out, f"input_{k:02d}.exr")).mean(axis=-1)
                u = np.log(np.maximum(image, 0) + 0.01)
                gy, gx = np.gradient(u)  # rows are y, columns x (texel (x, y) is row y, column x)
                jxx += float((gx * gx).sum())
                jxy += float((gx * gy).sum())
                jyy += float((gy * gy).sum())
            across = 0.5 * math.atan2(2 * jxy, jxx - jyy)  # direction of the strongest change
            along = across + math.pi / 2
            coherence = math.hypot(jxx - jyy, 2 * jxy) / (jxx + jyy)
            rows.append((truth, along, coherence, quarter_turn_difference(along, truth)))
    errors = np.array([r[3] for r in rows])
    print("tile,true_alpha_deg,structure_tensor_deg,coherence,difference_deg")
    for i, (t, a, c, d) in enumerate(rows):
        print(f"{i},{math.degrees(t):.1f},{math.degrees(a):.1f},{c:.3f},{math.degrees(d):.1f}")
    print(f"# {len(rows)} tiles: MSE {np.mean(errors ** 2):.4f}, "
          f"median |difference| {math.degrees(np.median(np.abs(errors))):.1f} deg "
          f"(a guess that knows nothing: MSE pi^2/48 = {math.pi ** 2 / 48:.3f})")


if __name__ == "__main__":
    main()
