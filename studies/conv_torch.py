#!/usr/bin/python3
"""PyTorch beside anisocap_bench_conv: the same convolution shapes, forward / backward-input /
backward-weight, on 2 threads (torch.set_num_threads(2)), and a table of the ratio.

    /usr/bin/python3 studies/conv_torch.py build/bench/anisocap_bench_conv

Without the path it only times PyTorch. With it, it also runs the anisocap benchmark
(--benchmark_format=json, medians of repetitions) and prints, per shape and pass: anisocap GFLOP/s
on 2 threads, its fraction of the FMA peak measured in that run, the 2-thread / 1-thread speed-up,
the im2col + Eigen baseline, PyTorch GFLOP/s and anisocap / PyTorch.
"""
import argparse
import json
import subprocess
import sys
import time

import torch

# (kind, Cin, Cout, kernel, stride, padding, input size): the shapes registered in bench/conv.cpp.
SHAPES = [
    ("conv4x4s2", 12, 64, 4, 2, 1, 256),
    ("conv4x4s2", 64, 128, 4, 2, 1, 128),
    ("conv4x4s2", 128, 256, 4, 2, 1, 64),
    ("conv4x4s2", 256, 512, 4, 2, 1, 32),
    ("conv4x4s2", 512, 1024, 4, 2, 1, 16),
    ("convT4x4s2", 1024, 512, 4, 2, 1, 8),
    ("convT4x4s2", 512, 256, 4, 2, 1, 16),
    ("convT4x4s2", 256, 128, 4, 2, 1, 32),
    ("convT4x4s2", 128, 64, 4, 2, 1, 64),
    ("convT4x4s2", 64, 12, 4, 2, 1, 128),
    ("conv4x4s2", 3, 64, 4, 2, 1, 256),
    ("conv4x4s2", 1024, 1024, 4, 2, 1, 8),
    ("conv3x3", 64, 64, 3, 1, 1, 256),
    ("conv3x3", 128, 128, 3, 1, 1, 128),
    ("conv3x3", 256, 256, 3, 1, 1, 64),
    ("conv3x3", 512, 512, 3, 1, 1, 32),
]
PASSES = ["fwd", "bwd_in", "bwd_w"]


def flops(kind, cin, cout, k, s, p, n):
    if kind.startswith("convT"):
        return 2.0 * n * n * 16 * cin * cout
    m = (n + 2 * p - k) // s + 1
    return 2.0 * m * m * k * k * cin * cout


def median_time(fn, min_time=0.5, repetitions=5):
    """Median over `repetitions` of the mean time of a loop running at least min_time / repetitions."""
    fn()
    times = []
    for _ in range(repetitions):
        count, start = 0, time.perf_counter()
        while True:
            fn()
            count += 1
            elapsed = time.perf_counter() - start
            if elapsed >= min_time / repetitions:
                break
        times.append(elapsed / count)
    times.sort()
    return times[len(times) // 2]


def torch_gflops(kind, cin, cout, k, s, p, n):
    torch.manual_seed(0)
    if kind.startswith("convT"):
        layer = torch.nn.ConvTranspose2d(cin, cout, k, stride=s, padding=p)
    else:
        layer = torch.nn.Conv2d(cin, cout, k, stride=s, padding=p)
    x = torch.randn(1, cin, n, n)
    with torch.no_grad():
        y = layer(x)
    g = torch.randn_like(y)
    result = {}
    with torch.no_grad():
        result["fwd"] = median_time(lambda: layer(x))
    # Input gradient only (weights frozen), weight gradient only (input without gradient).
    xg = x.clone().requires_grad_(True)
    for prm in layer.parameters():
        prm.requires_grad_(False)
    y = layer(xg)
    result["bwd_in"] = median_time(lambda: torch.autograd.grad(y, xg, g, retain_graph=True))
    layer.weight.requires_grad_(True)
    y = layer(x)
    result["bwd_w"] = median_time(lambda: torch.autograd.grad(y, layer.weight, g, retain_graph=True))
    f = flops(kind, cin, cout, k, s, p, n)
    return {pas: f / t / 1e9 for pas, t in result.items()}


def run_anisocap(binary, repetitions):
    cmd = [binary, "--benchmark_format=json", f"--benchmark_repetitions={repetitions}",
           "--benchmark_report_aggregates_only=true", "--benchmark_min_time=0.2",
           "--benchmark_filter=^(anisocap|eigen_im2col|fma_peak)/"]
    print("running:", " ".join(cmd), file=sys.stderr)
    out = subprocess.run(cmd, check=True, capture_output=True, text=True).stdout
    data = json.loads(out)
    results = {}
    for b in data["benchmarks"]:
        if b.get("aggregate_name") != "median":
            continue
        name = b["run_name"].replace("/real_time", "")
        results[name] = b
    return data.get("context", {}), results


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("binary", nargs="?", help="path of anisocap_bench_conv")
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--repetitions", type=int, default=5)
    args = parser.parse_args()
    torch.set_num_threads(args.threads)

    context, ours = ({}, {})
    if args.binary:
        context, ours = run_anisocap(args.binary, args.repetitions)
        print(f"FMA peak in the anisocap run: {float(context.get('fma_peak_gflops_1thread', 0)):.0f} GFLOP/s on 1 thread, "
              f"{float(context.get('fma_peak_gflops_2threads', 0)):.0f} on 2 ({context.get('simd_arch', '?')})")
    print(f"PyTorch {torch.__version__}, {torch.get_num_threads()} threads")
    header = "| shape | pass | anisocap GFLOP/s (2 thr) | peak fraction | 2 thr / 1 thr | Eigen im2col GFLOP/s | PyTorch GFLOP/s | anisocap / PyTorch |"
    print(header)
    print("|" + "---|" * 8)
    for shape in SHAPES:
        kind, cin, cout, k, s, p, n = shape
        theirs = torch_gflops(*shape)
        label = f"{kind} {cin}->{cout} @{n}"
        key = f"{kind}/{cin}->{cout}@{n}"
        for pas in PASSES:
            row = [label, pas]
            two = ours.get(f"anisocap/{key}/{pas}/threads:{args.threads}")
            one = ours.get(f"anisocap/{key}/{pas}/threads:1")
            eig = ours.get(f"eigen_im2col/{key}/{pas}/threads:{args.threads}")
            if two:
                row += [f"{two['gflops']:.1f}", f"{two['peak_fraction']:.2f}",
                        f"{two['gflops'] / one['gflops']:.2f}" if one else "-",
                        f"{eig['gflops']:.1f}" if eig else "-"]
            else:
                row += ["-", "-", "-", "-"]
            row.append(f"{theirs[pas]:.1f}")
            row.append(f"{two['gflops'] / theirs[pas]:.2f}" if two else "-")
            print("| " + " | ".join(row) + " |", flush=True)
    for threads in (1, 2):
        step = ours.get(f"anisocap/decoder_step@256/threads:{threads}")
        if step:
            print(f"decoder step (5 transposed convolutions 8x8x1024 -> 256x256x12, forward + backward), "
                  f"{threads} thread(s): {step['real_time']:.1f} ms, {step['gflops']:.1f} GFLOP/s, "
                  f"arena {step['arena_MiB']:.1f} MiB, process max RSS {step['max_rss_MiB']:.0f} MiB")


if __name__ == "__main__":
    main()
