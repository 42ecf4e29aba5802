#!/usr/bin/env python3
"""The fused render + image loss + gradient in PyTorch (autograd) beside anisocap's SIMD renderer.

Usage: /usr/bin/python3 studies/render_torch.py PATH/TO/anisocap_bench_render [--runs 7] [--rounds 3]

Runs anisocap's benchmark `fused/full/(simd|scalar)/{1,2}/0` (256 x 256 texels, 12 images, full
kernel, 1 and 2 threads, no culling; Google Benchmark, 5 repetitions, medians) and times the same
loss and gradient written with PyTorch autograd (studies/reference/ward_reference.py on float32
tensors, torch.set_num_threads(1) and (2)) on inputs of the same sizes and the same mix as bench/render.cpp
(random maps in the same ranges, cameras and lights drawn the same way; a numpy generator instead
of std::mt19937_64): median of the runs after one warm-up. Prints texel-image evaluations per
second for each and the ratios at equal thread counts. (Both sides are measured at 1 thread too
because on a loaded machine 2 OpenMP threads can be much slower than 1, for torch especially.)
The machine is shared and its load changes by the second, so the two sides are measured in
alternating rounds; the ratio reported is the median over rounds of the ratio within a round. First checks once that torch's gradient agrees with central
finite differences on a tiny case in float64, so the comparison is against a correct program.
"""
import json
import os
import statistics
import subprocess
import sys
import time

import numpy as np
import torch

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "reference"))
import ward_reference as ward  # noqa: E402

SIZE, IMAGES, THREADS = 256, 12, (1, 2)


def bench_maps(w, h, seed, dtype):
    """Same ranges as bench/render.cpp's bench_maps (full kernel)."""
    rng = np.random.default_rng(seed)
    u = lambda *s: rng.random((h, w) + s)  # noqa: E731
    m = {"diffuse": 0.05 + 0.9 * u(3), "specular": 0.05 + 0.9 * u(3), "sx": 0.05 + 0.4 * u(),
         "sy": 0.05 + 0.4 * u(), "f0": 0.05 + 0.9 * u(), "nx": 0.3 * (u() - 0.5), "ny": 0.3 * (u() - 0.5),
         "alpha": 3.0 * (u() - 0.5)}
    return {k: torch.tensor(v, dtype=dtype) for k, v in m.items()}


def bench_capture(n, seed):
    """Same distribution as bench/render.cpp's bench_capture."""
    rng = np.random.default_rng(seed)
    u = lambda: rng.uniform(-1.0, 1.0)  # noqa: E731
    cap = []
    for _ in range(n):
        cam = [u(), u(), 1.5 + u()]
        light = [-cam[0] + 0.2 * u(), -cam[1] + 0.2 * u(), 1.5 + u()]
        cap.append({"camera": cam, "light": light, "intensity": [3.0, 3.0, 3.0]})
    return cap


def loss_and_gradient(maps, capture, targets):
    for v in maps.values():
        v.grad = None
    loss = ward.image_loss(torch, ward.render(torch, maps, capture), targets)
    loss.backward()
    return loss


def check_gradient():
    """torch autograd against central differences, float64, 5 x 4 texels, 3 images."""
    maps = bench_maps(5, 4, 11, torch.float64)
    cap = bench_capture(3, 12)
    with torch.no_grad():
        targets = ward.render(torch, bench_maps(5, 4, 13, torch.float64), cap)
    for v in maps.values():
        v.requires_grad_(True)
    loss_and_gradient(maps, cap, targets)
    worst, eps = 0.0, 1e-6
    with torch.no_grad():
        for name, v in maps.items():
            flat, grad = v.view(-1), v.grad.view(-1)
            for i in range(flat.numel()):
                old = flat[i].item()
                flat[i] = old + eps
                up = ward.image_loss(torch, ward.render(torch, maps, cap), targets).item()
                flat[i] = old - eps
                down = ward.image_loss(torch, ward.render(torch, maps, cap), targets).item()
                flat[i] = old
                fd = (up - down) / (2 * eps)
                worst = max(worst, abs(fd - grad[i].item()) / max(abs(fd), 1e-3))
    print(f"gradient check (float64, 5x4 texels, 3 images, all 12 channels): "
          f"max relative difference autograd vs central differences {worst:.2e}")
    if worst > 1e-5:
        sys.exit("gradient check failed")


def time_torch(runs, threads):
    torch.set_num_threads(threads)
    maps = bench_maps(SIZE, SIZE, 1, torch.float32)
    cap = bench_capture(IMAGES, 2)
    with torch.no_grad():
        targets = ward.render(torch, bench_maps(SIZE, SIZE, 3, torch.float32), cap)
    for v in maps.values():
        v.requires_grad_(True)
    loss_and_gradient(maps, cap, targets)  # warm-up
    times = []
    for _ in range(runs):
        t0 = time.perf_counter()
        loss = loss_and_gradient(maps, cap, targets)
        times.append(time.perf_counter() - t0)
    assert torch.isfinite(loss) and all(torch.isfinite(v.grad).all() for v in maps.values())
    return statistics.median(times)


def time_anisocap(binary):
    cmd = [binary, "--benchmark_filter=fused/full/(simd|scalar)/threads:[12]/cull:0/ftz:1/", "--benchmark_format=json",
           "--benchmark_repetitions=5", "--benchmark_report_aggregates_only=true"]
    out = subprocess.run(cmd, check=True, stdout=subprocess.PIPE, text=True).stdout
    result = {}
    for b in json.loads(out)["benchmarks"]:
        if b.get("aggregate_name") == "median":
            kind = "simd" if "/simd/" in b["name"] else "scalar"
            threads = int(b["name"].split("/")[3].split(":")[1])
            result[kind, threads] = (b["evals_per_second"], b.get("label", ""))
    return result


def main():
    if len(sys.argv) < 2:
        sys.exit(__doc__)
    arg = lambda name, default: int(sys.argv[sys.argv.index(name) + 1]) if name in sys.argv else default  # noqa: E731
    runs, rounds = arg("--runs", 7), arg("--rounds", 3)
    check_gradient()
    evals = SIZE * SIZE * IMAGES
    cpp, torch_rate = [], []
    for r in range(rounds):
        cpp.append(time_anisocap(sys.argv[1]))
        torch_rate.append({threads: evals / time_torch(runs, threads) for threads in THREADS})
        print(f"round {r + 1}: " + ", ".join(
            f"{t} thread(s) SIMD/PyTorch {cpp[-1]['simd', t][0] / torch_rate[-1][t]:.1f}x" for t in THREADS))
    med = statistics.median
    print(f"\nfused loss + gradient, full kernel, {SIZE}x{SIZE} texels, {IMAGES} images (torch {torch.__version__}; "
          f"medians over {rounds} alternating rounds of: anisocap median of 5 repetitions, "
          f"PyTorch median of {runs} runs after a warm-up)\n")
    print("| threads | implementation | texel-image evaluations / s | vs PyTorch (median of per-round ratios) |")
    print("|---|---|---|---|")
    for t in THREADS:
        for kind in ("simd", "scalar"):
            label = cpp[0][kind, t][1]
            rate = med(c[kind, t][0] for c in cpp)
            ratio = med(c[kind, t][0] / tr[t] for c, tr in zip(cpp, torch_rate))
            print(f"| {t} | anisocap {kind} ({label}) | {rate / 1e6:.2f} M | {ratio:.1f}x |")
        print(f"| {t} | PyTorch autograd, float32 | {med(tr[t] for tr in torch_rate) / 1e6:.3f} M | 1.0x |")
    print()
    for t in THREADS:
        ratio = med(c["simd", t][0] / tr[t] for c, tr in zip(cpp, torch_rate))
        print(f"{t} thread(s): anisocap SIMD / PyTorch = {ratio:.1f}x (goal: at least 10x): "
              f"{'met' if ratio >= 10 else 'NOT met'}")


if __name__ == "__main__":
    main()
