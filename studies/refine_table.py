#!/usr/bin/env python3
"""Per-texel optimisation: run time against per-parameter error (issue 2's refine benchmark).

Synthesizes one 256 x 256 procedural material with 12 inputs (set alpha), runs `anisocap capture`
(the first guess from the photographs, then refine) for several step counts, and prints a Markdown
table of steps, seconds, final image loss and per-parameter MSE against the true maps.

usage: studies/refine_table.py BUILD/anisocap [--steps 0,100,250,500,1000,2000] [--seed 7] [--lr 0.03]
"""
import argparse
import json
import os
import subprocess
import sys
import tempfile


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("program", help="path of the anisocap program")
    ap.add_argument("--steps", default="0,100,250,500,1000,2000")
    ap.add_argument("--seed", type=int, default=7)
    ap.add_argument("--size", type=int, default=256)
    ap.add_argument("--images", type=int, default=12)
    ap.add_argument("--lr", default="0.03")
    ap.add_argument("--kernel", default="full")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory(prefix="anisocap_refine_") as tmp:
        syn = os.path.join(tmp, "syn")
        subprocess.run([args.program, "synthesize", "-o", syn, "--width", str(args.size), "--height", str(args.size),
                        "--images", str(args.images), "--seed", str(args.seed)], check=True)
        rows = []
        for steps in [int(s) for s in args.steps.split(",")]:
            out = os.path.join(tmp, f"out{steps}")
            subprocess.run([args.program, "capture", os.path.join(syn, "capture.json"), "-o", out, "--steps", str(steps),
                            "--lr", args.lr, "--kernel", args.kernel, "--stages", "refine", "--truth", os.path.join(syn, "truth")],
                           check=True, stderr=subprocess.DEVNULL)
            with open(os.path.join(out, "report.json")) as f:
                rep = json.load(f)
            refine = [s for s in rep["stages"] if s["name"] == "refine"]
            rows.append((steps, refine[0]["seconds"] if refine else 0.0, rep["loss"], rep["errors"]))
    print(f"\n{args.size} x {args.size}, {args.images} inputs (set alpha), seed {args.seed}, kernel {args.kernel}, lr {args.lr}\n")
    print("| steps | refine s | image loss | a_d | a'_s | n_s | sigma | alpha (mod pi) | alpha, anisotropic texels | F0 |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for steps, sec, loss, e in rows:
        ra = e["rotation_anisotropic"]
        print(f"| {steps} | {sec:.2f} | {loss:.4f} | {e['diffuse']:.5f} | {e['specular']:.5f} | {e['normal']:.5f} | "
              f"{e['lobes']:.5f} | {e['rotation']:.3f} | {'-' if ra is None else f'{ra:.3f}'} | {e['fresnel']:.4f} |")


if __name__ == "__main__":
    sys.exit(main())
