#!/usr/bin/env python3
"""`anisocap render` against an independent implementation of MODEL.md 3-4.

Usage: independent_render_check.py PATH/TO/anisocap [--tolerance T] [--keep DIR]

For a few seeds, sizes (square, non-square, odd) and both configuration sets, synthesizes a
procedural material with the program, renders its truth map set with `anisocap render`, and
compares every pixel of every image (and the inputs that synthesize wrote) with the float64 render
of bench/reference/ward_reference.py, which was written from MODEL.md alone. The error of a pixel
channel is |cpp - ref| / max(ref, 1e-3); the program prints the maximum per case and exits 1 if it
exceeds the tolerance (float32 against float64). Exits 77 (CTest SKIP_RETURN_CODE) if numpy is
missing.
"""
import os
import subprocess
import sys
import tempfile

try:
    import numpy as np
except ImportError:
    print("skipped: numpy is not available to", sys.executable)
    sys.exit(77)

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.join(HERE, "..", "..", "bench", "reference"))
import exr  # noqa: E402
import ward_reference as ward  # noqa: E402

# (width, height, images, seed, set, kind or None)
CASES = [
    (37, 23, 6, 1, "alpha", None),
    (23, 41, 5, 2, "beta", None),
    (32, 32, 8, 3, "alpha", None),
    (48, 31, 4, 4, "beta", None),
    (33, 33, 6, 5, "alpha", "brushed"),
    (40, 24, 6, 6, "alpha", "satin"),
    (29, 35, 6, 8, "beta", "spun"),
    (26, 19, 4, 9, "alpha", "velvet"),
    (1, 7, 4, 7, "beta", None),
]
FLOOR = 1e-3


def relative_error(cpp, ref):
    return np.abs(cpp - ref) / np.maximum(np.abs(ref), FLOOR)


def run(cmd):
    r = subprocess.run(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    if r.returncode != 0:
        print("FAILED:", " ".join(cmd), "\n", r.stdout)
        sys.exit(1)


def main():
    args = sys.argv[1:]
    if not args:
        print(__doc__)
        return 2
    program = args[0]
    tolerance = float(args[args.index("--tolerance") + 1]) if "--tolerance" in args else 5e-4
    keep = args[args.index("--keep") + 1] if "--keep" in args else None
    worst = 0.0
    with tempfile.TemporaryDirectory(prefix="anisocap-independent-") as tmp:
        root = keep or tmp
        for w, h, n, seed, set_name, kind in CASES:
            d = os.path.join(root, f"case_{w}x{h}_s{seed}_{set_name}")
            cmd = [program, "--threads", "2", "synthesize", "-o", d, "--width", str(w), "--height", str(h),
                   "--images", str(n), "--seed", str(seed), "--set", set_name]
            if kind:
                cmd += ["--kind", kind]
            run(cmd)
            run([program, "--threads", "2", "render", "--maps", os.path.join(d, "truth"), "--capture",
                 os.path.join(d, "capture.json"), "-o", os.path.join(d, "render")])
            maps = ward.read_map_set(os.path.join(d, "truth"))
            capture = ward.read_capture(os.path.join(d, "capture.json"))
            ref = ward.render(np, maps, capture)
            case_worst = {"render": 0.0, "inputs": 0.0}
            for i, im in enumerate(capture):
                for label, folder in (("render", os.path.join(d, "render")), ("inputs", d)):
                    cpp = exr.read_rgb(os.path.join(folder, im["file"]))
                    if cpp.shape != ref[i].shape:
                        print(f"FAIL {d} {label} {im['file']}: shape {cpp.shape}, expected {ref[i].shape}")
                        return 1
                    err = relative_error(cpp, ref[i])
                    if err.max() > case_worst[label]:
                        case_worst[label] = float(err.max())
                    if err.max() > tolerance:
                        y, x, c = np.unravel_index(np.argmax(err), err.shape)
                        print(f"  {label} {im['file']}: worst texel (x={x}, y={y}, channel {'RGB'[c]}): "
                              f"anisocap {cpp[y, x, c]:.7g}, reference {ref[i][y, x, c]:.7g}")
            lit = float((ref > 0).mean())
            print(f"{w}x{h} seed {seed} set {set_name} kind {kind or 'from seed'} ({n} images, {lit:.0%} lit): "
                  f"max relative error render {case_worst['render']:.3g}, synthesize inputs {case_worst['inputs']:.3g}")
            worst = max(worst, *case_worst.values())
    ok = worst <= tolerance
    print(f"{'PASS' if ok else 'FAIL'}: max relative error {worst:.3g} (tolerance {tolerance:g}, "
          f"relative to max(value, {FLOOR:g}))")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
