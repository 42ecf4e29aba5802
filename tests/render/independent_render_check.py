#!/usr/bin/env python3
"""`anisocap render` against an independent implementation of docs/method.md sections 3-4.

Usage: independent_render_check.py PATH/TO/anisocap [--tolerance T] [--keep DIR]

For a few seeds, sizes (square, non-square, odd) and both configuration sets, synthesizes a
procedural material with the program, renders its truth map set with `anisocap render`, and
compares every pixel of every image (and the inputs that synthesize wrote) with the float64 render
of studies/reference/ward_reference.py, which was written from docs/method.md alone; then the same under
hand-made extreme configurations, and the image loss (docs/method.md section 5) that `anisocap capture --steps 0`
reports (relative difference), and a hand-written map set at the clamps (docs/method.md section 3 numerics). The error of a pixel channel is |cpp - ref| / max(ref, 1e-3); the
program prints the maximum per case and exits 1 if any exceeds the tolerance (float32 against
float64; about 4e-5 is what the program shows, the default tolerance is 5e-4). Exits 77 (CTest SKIP_RETURN_CODE) if numpy is
missing.
"""
import json
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
sys.path.insert(0, os.path.join(HERE, "..", "..", "studies", "reference"))
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

# Hand-made configurations beyond what the samplers produce: grazing camera and light, a light
# skimming the plane (2e-3 above it: most texels see it from below their shading normal's horizon;
# a light or camera at or below the plane is rejected by the capture reader), a camera so low
# that tilted normals turn away from it (n.v <= 0 at some texels), a light just above the material
# (large 1/r^2), a camera straight above, RGB intensities.
EXTREME_CAPTURE = {"images": [
    {"file": "grazing.exr", "camera": [3.0, 0.2, 0.02], "light": [-2.5, -0.1, 0.03], "intensity": [1.0, 2.0, 0.5]},
    {"file": "light_skimming.exr", "camera": [0.1, 0.2, 1.0], "light": [0.3, -0.2, 0.002], "intensity": 5.0},
    {"file": "camera_low.exr", "camera": [0.0, 4.0, 0.01], "light": [0.3, -0.2, 0.5], "intensity": 5.0},
    {"file": "light_close.exr", "camera": [0.0, 0.0, 2.0], "light": [0.05, -0.03, 0.02], "intensity": [0.01, 0.02, 0.03]},
    {"file": "overhead_mirror.exr", "camera": [0.2, 0.1, 1.5], "light": [-0.2, -0.1, 1.5], "intensity": [6.0, 4.0, 2.0]},
    {"file": "sub/far.exr", "camera": [-8.0, 5.0, 3.0], "light": [6.0, -7.0, 9.0], "intensity": 100.0},
]}


def relative_error(cpp, ref):
    return np.abs(cpp - ref) / np.maximum(np.abs(ref), FLOOR)


def run(cmd):
    r = subprocess.run(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    if r.returncode != 0:
        print("FAILED:", " ".join(cmd), "\n", r.stdout)
        sys.exit(1)


def write_edge_maps(folder):
    """An 11 x 9 map set whose texels mix extreme values of every parameter."""
    os.makedirs(folder, exist_ok=True)
    rng = np.random.default_rng(5)
    shape = (9, 11)
    pick = lambda values: rng.choice(values, shape)  # noqa: E731
    grey = lambda plane: np.stack([plane] * 3, axis=-1)  # noqa: E731
    exr.write_rgb(os.path.join(folder, "diffuse.exr"), rng.random(shape + (3,)))
    exr.write_rgb(os.path.join(folder, "specular.exr"), rng.random(shape + (3,)))
    sigmas = [1e-6, 1e-5, 1e-3, 0.02, 0.3, 1.0]
    sx, sy = pick(sigmas), pick(sigmas)
    exr.write_rgb(os.path.join(folder, "lobes.exr"), np.stack([sx, sy, 0 * sx], axis=-1))
    exr.write_rgb(os.path.join(folder, "fresnel.exr"), grey(pick([0.0, 1e-5, 1e-3, 0.5, 1.0])))
    angle, radius = rng.uniform(0, 2 * np.pi, shape), pick([0.0, 0.3, 0.9, 0.999, 1.0])
    nx, ny = radius * np.cos(angle), radius * np.sin(angle)
    nz = np.sqrt(np.maximum(1 - nx * nx - ny * ny, 0))
    exr.write_rgb(os.path.join(folder, "normal.exr"), np.stack([nx, ny, nz], axis=-1))
    exr.write_rgb(os.path.join(folder, "rotation.exr"), grey(pick([-np.pi / 2, -1.0, 0.0, 0.5, np.pi / 2])))


def compare(cpp_folder, ref, capture, tolerance, where):
    """Max relative error of the images in cpp_folder against ref; prints the worst texel of bad ones."""
    worst = 0.0
    for i, im in enumerate(capture):
        cpp = exr.read_rgb(os.path.join(cpp_folder, im["file"]))
        if cpp.shape != ref[i].shape:
            print(f"FAIL {where} {im['file']}: shape {cpp.shape}, expected {ref[i].shape}")
            return float("inf")
        err = relative_error(cpp, ref[i])
        worst = max(worst, float(err.max()))
        if err.max() > tolerance:
            y, x, c = np.unravel_index(np.argmax(err), err.shape)
            print(f"  {where} {im['file']}: worst texel (x={x}, y={y}, channel {'RGB'[c]}): "
                  f"anisocap {cpp[y, x, c]:.7g}, reference {ref[i][y, x, c]:.7g}")
    return worst


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
            case_worst = {"render": compare(os.path.join(d, "render"), ref, capture, tolerance, d + " render"),
                          "inputs": compare(d, ref, capture, tolerance, d + " inputs")}
            lit = float((ref > 0).mean())
            print(f"{w}x{h} seed {seed} set {set_name} kind {kind or 'from seed'} ({n} images, {lit:.0%} lit): "
                  f"max relative error render {case_worst['render']:.3g}, synthesize inputs {case_worst['inputs']:.3g}")
            worst = max(worst, *case_worst.values())
        # the first case's truth maps under the hand-made configurations
        d = os.path.join(root, "extreme")
        os.makedirs(d, exist_ok=True)
        with open(os.path.join(d, "capture.json"), "w") as f:
            json.dump(EXTREME_CAPTURE, f)
        w, h, _, seed, set_name, _ = CASES[0]
        maps_dir = os.path.join(root, f"case_{w}x{h}_s{seed}_{set_name}", "truth")
        run([program, "--threads", "2", "render", "--maps", maps_dir, "--capture",
             os.path.join(d, "capture.json"), "-o", os.path.join(d, "render")])
        capture = ward.read_capture(os.path.join(d, "capture.json"))
        ref = ward.render(np, ward.read_map_set(maps_dir), capture)
        err = compare(os.path.join(d, "render"), ref, capture, tolerance, "extreme")
        print(f"{w}x{h} truth of seed {seed} under {len(capture)} hand-made extreme configurations: "
              f"max relative error {err:.3g}")
        worst = max(worst, err)
        # a hand-written map set at the clamps: sigma down to 1e-6, F0 = 0 and 1e-5, normals on the
        # horizon (n_z clamped), alpha = +-pi/2 (written uncompressed by exr.py: the reader path too)
        edge_maps = os.path.join(root, "edge_maps")
        write_edge_maps(edge_maps)
        run([program, "--threads", "2", "render", "--maps", edge_maps, "--capture",
             os.path.join(d, "capture.json"), "-o", os.path.join(root, "edge_render")])
        ref = ward.render(np, ward.read_map_set(edge_maps), capture)
        err = compare(os.path.join(root, "edge_render"), ref, capture, tolerance, "edge maps")
        print(f"11x9 map set at the clamps (sigma 1e-6, F0 0, normals on the horizon, alpha +-pi/2) under the "
              f"hand-made configurations: max relative error {err:.3g}")
        worst = max(worst, err)
        # the image loss (docs/method.md section 5): `capture --steps 0 --init OTHER` reports the loss of OTHER's
        # maps (another material of the same size) against the first case's inputs.
        other = os.path.join(root, "other")
        run([program, "--threads", "2", "synthesize", "-o", other, "--width", str(w), "--height", str(h),
             "--images", "4", "--seed", "21"])
        case0 = os.path.join(root, f"case_{w}x{h}_s{seed}_{set_name}")
        report_dir = os.path.join(root, "loss")
        run([program, "--threads", "2", "capture", os.path.join(case0, "capture.json"), "-o", report_dir,
             "--init", os.path.join(other, "truth"), "--steps", "0"])
        with open(os.path.join(report_dir, "report.json")) as f:
            report = json.load(f)
        try:
            # With --steps 0 the maps are OTHER's unchanged, and "loss" is their image loss.
            cpp_loss = float(report["loss"])
        except (KeyError, TypeError, ValueError):
            print("FAIL: report.json of `anisocap capture` has no loss")
            return 1
        capture = ward.read_capture(os.path.join(case0, "capture.json"))
        targets = np.stack([exr.read_rgb(os.path.join(case0, im["file"])) for im in capture])
        # `capture` optimises and reports in a standard exposure (pipeline/exposure.hpp): photographs
        # and intensities times s = 1 / median_k(mean(I_k) cos(theta_k) / (pi |l_k|^2)), the
        # irradiance at the material's centre. Computed here from that definition.
        irradiance = []
        for im in capture:
            l = np.asarray(im["light"], dtype=np.float64)
            r2 = float(l @ l)
            if l[2] > 0:
                irradiance.append(np.mean(im["intensity"]) * (l[2] / np.sqrt(r2)) / (np.pi * r2))
        scale = 1.0 / float(np.median(irradiance))
        cpp_scale = float(report.get("exposure_scale", float("nan")))
        scale_err = abs(cpp_scale - scale) / scale
        print(f"exposure scale: anisocap {cpp_scale:.8g}, reference {scale:.8g}, relative difference {scale_err:.3g}")
        worst = max(worst, scale_err)
        scaled = [dict(im, intensity=[v * scale for v in im["intensity"]]) for im in capture]
        ref_loss = float(ward.image_loss(np, ward.render(np, ward.read_map_set(os.path.join(other, "truth")), scaled),
                                         targets * scale))
        loss_err = abs(cpp_loss - ref_loss) / abs(ref_loss)
        print(f"image loss of another material's maps against case 1's inputs: anisocap {cpp_loss:.8g}, "
              f"reference {ref_loss:.8g}, relative difference {loss_err:.3g}")
        worst = max(worst, loss_err)
    ok = worst <= tolerance
    print(f"{'PASS' if ok else 'FAIL'}: max relative error {worst:.3g} (tolerance {tolerance:g}, "
          f"relative to max(value, {FLOOR:g}))")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
