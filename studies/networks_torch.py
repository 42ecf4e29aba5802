#!/usr/bin/python3
"""The estimation network and the auto-encoder of networks/estimator.hpp in PyTorch, beside
anisocap_bench_networks: training steps (forward, L1 loss, backward, Adam) per second.

    OMP_WAIT_POLICY=passive /usr/bin/python3 studies/networks_torch.py build/bench/anisocap_bench_networks

Debian's PyTorch calls the system BLAS for ConvTranspose2d and Linear; the netlib reference BLAS
makes it several times slower. studies/README.md "Against PyTorch" runs it with OpenBLAS through
LD_LIBRARY_PATH; the header line prints which BLAS the process loaded. --transposed subpixel runs
the transposed convolutions as oneDNN Conv2d + pixel_shuffle instead (by default both are timed).

The PyTorch networks copy the presets layer by layer (widths, 4x4 stride-2 convolutions, 4x4
stride-2 transposed convolutions, 3x3 and 1x1 reducing convolutions, all with biases; instance
norms with affine parameters, the batch norm ending the auto-encoder's encoder, leaky ReLU 0.2,
SELU on the global track, tanh outputs, max-pooling over each set's 5 images); their trainable
parameter counts are printed and, when the anisocap binary is given, asserted equal to its
`parameters` counter. Layout NCHW float32 (or channels_last with --channels-last).

Loss: mean |y - truth| over the 12 output channels (the L1 term of training::map_losses), on
random inputs and targets. The auto-encoder step also decodes z + delta and adds
0.1 * mean |y - y2| (the smoothness term: a second decode, forward and backward). anisocap's
training step adds the render loss (4 renders of each output and their gradients) on top;
anisocap_bench_networks times both its full step (render:1) and the L1-only step (render:0),
and the ratio is taken against the L1-only step (same work on both sides).

Each PyTorch step: zero_grad(set_to_none), forward, loss, backward, Adam (torch.optim.Adam,
defaults). Timing: warm-up steps, then the median over repetitions of the mean step time of a
loop of at least --min-time seconds (the paper presets: one step per repetition). On 1 thread it
also compares CPU time per step (process time here, the benchmark's cpu_time there), which a
shared, oversubscribed machine disturbs less than wall-clock time.
With the binary, it also runs it (OMP_NUM_THREADS = each --threads value, OMP_WAIT_POLICY
passive, --benchmark_repetitions, medians) right before the PyTorch runs of the same thread count.
"""
import argparse
import json
import os
import subprocess
import sys
import time

import torch
import torch.nn as nn
import torch.nn.functional as F

SLOPE = 0.2  # network_detail::leaky_slope

ESTIMATOR = {
    "compact": dict(encoder=[16, 32, 64, 64, 64, 64], track1=[64, 64, 64, 32, 16, 16], track2=[32, 32, 32, 16, 8, 8]),
    "paper": dict(encoder=[64, 128, 256, 512, 1024, 1024], track1=[512, 512, 256, 128, 64, 64],
                  track2=[256, 256, 128, 64, 32, 32]),
}
AUTOENCODER = {"compact": [32, 64, 128, 128, 128], "paper": [64, 128, 256, 512, 1024]}
PARAMETERS = 12  # parameter_count: channels of the maps in network space
IMAGES = 5       # training inputs per material (docs/method.md section 6)


# Rows (and columns) of the 4x4 transposed kernel that output parity p reads at input offset
# -1, 0, +1; 4 is a zero row.
SUBPIXEL_TAPS = torch.tensor([[3, 1, 4], [4, 2, 0]])


class SubpixelConvTranspose2d(nn.ConvTranspose2d):
    """ConvTranspose2d(4, stride 2, padding 1) with the same parameters, run as one 3x3 convolution
    to 4 x Cout channels (one group per output parity, zero taps where a parity reads no input)
    and a pixel shuffle: 2.25x the multiply-adds, but on PyTorch's oneDNN Conv2d instead of its
    im2col + BLAS transposed convolution. anisocap's kernel does the same split without the zeros."""

    def forward(self, x):
        w = F.pad(self.weight, (0, 1, 0, 1))  # Cin x Cout x 5 x 5
        i = SUBPIXEL_TAPS
        k = w[:, :, i[:, None, :, None], i[None, :, None, :]]  # Cin x Cout x 2 x 2 x 3 x 3
        k = k.permute(1, 2, 3, 0, 4, 5).reshape(-1, w.shape[0], 3, 3)
        return F.pixel_shuffle(F.conv2d(x, k, self.bias.repeat_interleave(4), padding=1), 2)


TRANSPOSED = nn.ConvTranspose2d  # --transposed subpixel: SubpixelConvTranspose2d


def up(cin, cout):
    """conv_transpose2d: 4x4, stride 2, output twice the input's size."""
    return TRANSPOSED(cin, cout, 4, stride=2, padding=1)


def down(cin, cout):
    """conv2d<Cin, Cout, 4, 2, 1>."""
    return nn.Conv2d(cin, cout, 4, stride=2, padding=1)


class DecoderTrack(nn.Module):
    """network_detail::decoder_track: 6 transposed convolutions, each after the first fed by
    [previous, skip]; instance norm, + linear(global vector) as channel bias, leaky ReLU."""

    def __init__(self, E, D):
        super().__init__()
        ins = [E[5]] + [D[k - 1] + E[5 - k] for k in range(1, 6)]
        self.up = nn.ModuleList(up(ins[k], D[k]) for k in range(6))
        self.norm = nn.ModuleList(nn.InstanceNorm2d(D[k], affine=True) for k in range(6))
        self.glob = nn.ModuleList(nn.Linear(E[5], D[k]) for k in range(6))

    def forward(self, skips, g):
        d = None
        for k in range(6):
            x = skips[5] if k == 0 else torch.cat([d, skips[5 - k]], 1)
            h = self.norm[k](self.up[k](x)) + self.glob[k](g)[:, :, None, None]
            d = F.leaky_relu(h, SLOPE)
        return d


class ReducingHead(nn.Module):
    """network_detail::reducing_head: 3x3 D->D (+ linear(global) bias), 3x3 D->D, 1x1 D->Out, tanh."""

    def __init__(self, G, D, out):
        super().__init__()
        self.c0 = nn.Conv2d(D, D, 3, padding=1)
        self.c1 = nn.Conv2d(D, D, 3, padding=1)
        self.c2 = nn.Conv2d(D, out, 1)
        self.glob = nn.Linear(G, D)

    def forward(self, x, g):
        h = F.leaky_relu(self.c0(x) + self.glob(g)[:, :, None, None], SLOPE)
        h = F.leaky_relu(self.c1(h), SLOPE)
        return torch.tanh(self.c2(h))


def max_over_images(x, n):
    """nn::max_over_images: entries s * n ... s * n + n - 1 max-pooled into entry s."""
    return x.reshape(x.shape[0] // n, n, *x.shape[1:]).amax(1)


class estimation_network(nn.Module):
    """estimation_network<Preset>: shared single-image U-Net with a global-feature track, two decoder
    tracks max-pooled over each set's images, reducing heads to 9 + 3 channels."""

    def __init__(self, encoder, track1, track2):
        super().__init__()
        E = encoder
        self.enc = nn.ModuleList([down(3, E[0])] + [down(E[i - 1], E[i]) for i in range(1, 6)])
        self.norm = nn.ModuleList(nn.InstanceNorm2d(E[i], affine=True) for i in range(1, 6))
        self.glob = nn.ModuleList([nn.Linear(E[0], E[0])] + [nn.Linear(E[i - 1] + E[i], E[i]) for i in range(1, 6)])
        self.bias = nn.ModuleList(nn.Linear(E[i - 1], E[i]) for i in range(1, 6))
        self.track1 = DecoderTrack(E, track1)
        self.track2 = DecoderTrack(E, track2)
        self.head1 = ReducingHead(E[5], track1[5], 9)
        self.head2 = ReducingHead(E[5], track2[5], 3)

    def forward(self, x, n):
        h = self.enc[0](x)
        g = F.selu(self.glob[0](h.mean((2, 3))))
        a = F.leaky_relu(h, SLOPE)
        skips = [a]
        for i in range(1, 6):
            h = self.enc[i](a)
            m = h.mean((2, 3))
            h = self.norm[i - 1](h) + self.bias[i - 1](g)[:, :, None, None]
            g = F.selu(self.glob[i](torch.cat([g, m], 1)))
            a = F.leaky_relu(h, SLOPE)
            skips.append(a)
        f1 = max_over_images(self.track1(skips, g), n)
        f2 = max_over_images(self.track2(skips, g), n)
        gp = max_over_images(g, n)
        return torch.cat([self.head1(f1, gp), self.head2(f2, gp)], 1)


class auto_encoder(nn.Module):
    """auto_encoder<Preset>: 5 convolutions 4x4/2 with leaky ReLU, batch norm -> z; 5 transposed
    convolutions with leaky ReLU, tanh."""

    def __init__(self, E):
        super().__init__()
        self.enc = nn.ModuleList([down(PARAMETERS, E[0])] + [down(E[i - 1], E[i]) for i in range(1, 5)])
        self.latent_norm = nn.BatchNorm2d(E[4])
        outs = [E[3], E[2], E[1], E[0], PARAMETERS]
        self.dec = nn.ModuleList(up(E[4 - k], outs[k]) for k in range(5))

    def encode(self, x):
        for k in range(4):
            x = F.leaky_relu(self.enc[k](x), SLOPE)
        return self.latent_norm(self.enc[4](x))

    def decode(self, z):
        for k in range(4):
            z = F.leaky_relu(self.dec[k](z), SLOPE)
        return torch.tanh(self.dec[4](z))


def parameter_total(net):
    return sum(p.numel() for p in net.parameters() if p.requires_grad)


def make_step(kind, preset, size, batch, channels_last):
    """A closure running one training step, and the network's parameter count."""
    torch.manual_seed(0)
    fmt = torch.channels_last if channels_last else torch.contiguous_format
    if kind == "estimator":
        net = estimation_network(**ESTIMATOR[preset])
        x = (torch.rand(batch * IMAGES, 3, size, size) * 2 - 1).contiguous(memory_format=fmt)
    else:
        net = auto_encoder(AUTOENCODER[preset])
        x = (torch.rand(batch, PARAMETERS, size, size) * 2 - 1).contiguous(memory_format=fmt)
    net = net.to(memory_format=fmt)
    net.train()
    truth = (torch.rand(batch, PARAMETERS, size, size) * 2 - 1).contiguous(memory_format=fmt)
    opt = torch.optim.Adam(net.parameters(), lr=1e-5)

    def step():
        opt.zero_grad(set_to_none=True)
        if kind == "estimator":
            y = net(x, IMAGES)
            loss = F.l1_loss(y, truth)
        else:
            z = net.encode(x)
            y = net.decode(z)
            y2 = net.decode(z + 0.01)
            loss = F.l1_loss(y, truth) + 0.1 * (y - y2).abs().mean()
        loss.backward()
        opt.step()

    return step, parameter_total(net)


def median_step_time(step, min_time, repetitions, warmup):
    """Medians over repetitions of the wall-clock and the process CPU time per step."""
    for _ in range(warmup):
        step()
    walls, cpus = [], []
    for _ in range(repetitions):
        count, start, cpu = 0, time.perf_counter(), time.process_time()
        while True:
            step()
            count += 1
            elapsed = time.perf_counter() - start
            if elapsed >= min_time:
                break
        walls.append(elapsed / count)
        cpus.append((time.process_time() - cpu) / count)
    walls.sort()
    cpus.sort()
    return walls[len(walls) // 2], cpus[len(cpus) // 2]


# (network, preset, size, batch): the L1-only rows registered in bench/networks.cpp.
CONFIGS = [
    ("estimator", "compact", 128, 2),
    ("estimator", "compact", 256, 2),
    ("estimator", "paper", 256, 1),
    ("autoencoder", "compact", 128, 4),
    ("autoencoder", "compact", 256, 1),
    ("autoencoder", "compact", 256, 4),
    ("autoencoder", "paper", 256, 1),
]


def anisocap_name(kind, preset, size, batch, render):
    iters = "/iterations:1" if preset == "paper" else ""
    return f"{kind}_step<{kind}_{preset}>/size:{size}/batch:{batch}/render:{render}{iters}/real_time"


def run_anisocap(binary, threads, repetitions):
    cmd = [binary, "--benchmark_format=json", f"--benchmark_repetitions={repetitions}",
           "--benchmark_report_aggregates_only=true", "--benchmark_filter=_step<"]
    env = dict(os.environ, OMP_NUM_THREADS=str(threads), OMP_WAIT_POLICY="passive")
    print(f"running: OMP_NUM_THREADS={threads} OMP_WAIT_POLICY=passive " + " ".join(cmd), file=sys.stderr, flush=True)
    data = json.loads(subprocess.run(cmd, check=True, capture_output=True, text=True, env=env).stdout)
    return {b["run_name"]: b for b in data["benchmarks"] if b.get("aggregate_name") == "median"}


def blas_library():
    """The BLAS this process loaded (PyTorch's transposed convolutions and linear layers use it)."""
    with open("/proc/self/maps") as maps:
        names = {line.split()[-1] for line in maps if "blas" in line}
    return ", ".join(sorted(names)) or "?"


def load():
    return os.getloadavg()[0]


def main():
    global TRANSPOSED
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("binary", nargs="?", help="path of anisocap_bench_networks")
    parser.add_argument("--threads", type=int, nargs="+", default=[2, 1])
    parser.add_argument("--transposed", nargs="+", choices=["native", "subpixel"], default=["native", "subpixel"],
                        help="PyTorch transposed convolutions: ConvTranspose2d, and/or SubpixelConvTranspose2d")
    parser.add_argument("--repetitions", type=int, default=5, help="PyTorch repetitions, compact presets")
    parser.add_argument("--paper-repetitions", type=int, default=3, help="PyTorch repetitions (one step each), paper")
    parser.add_argument("--anisocap-repetitions", type=int, default=3)
    parser.add_argument("--min-time", type=float, default=1.0, help="seconds per PyTorch repetition (compact)")
    parser.add_argument("--channels-last", action="store_true", help="PyTorch in channels_last (NHWC) layout")
    parser.add_argument("--only", default="", help="run only configurations whose 'network preset' contains this")
    args = parser.parse_args()
    configs = [c for c in CONFIGS if args.only in f"{c[0]} {c[1]}"]
    layout = "channels_last" if args.channels_last else "NCHW"
    print(f"PyTorch {torch.__version__}, {layout}, mkldnn {torch.backends.mkldnn.is_available()}; "
          f"BLAS {blas_library()}; load average at start {load():.2f}", flush=True)
    names = {"native": "PyTorch ConvTranspose2d", "subpixel": "PyTorch subpixel"}
    print("| network | preset | size x batch | threads | anisocap L1 + render samples/s | anisocap L1 samples/s | "
          + " | ".join(f"{names[v]} samples/s" for v in args.transposed)
          + " | anisocap (L1) / best PyTorch | same, CPU time (1 thread) | parameters | load |")
    print("|" + "---|" * (10 + len(args.transposed)), flush=True)
    for threads in args.threads:
        ours = run_anisocap(args.binary, threads, args.anisocap_repetitions) if args.binary else {}
        torch.set_num_threads(threads)
        for kind, preset, size, batch in configs:
            l1 = ours.get(anisocap_name(kind, preset, size, batch, 0))
            full = ours.get(anisocap_name(kind, preset, size, batch, 1))
            paper = preset == "paper"
            theirs, theirs_cpu = [], []
            for variant in args.transposed:
                TRANSPOSED = SubpixelConvTranspose2d if variant == "subpixel" else nn.ConvTranspose2d
                step, count = make_step(kind, preset, size, batch, args.channels_last)
                if l1:
                    assert int(l1["parameters"]) == count, \
                        f"{kind} {preset}: PyTorch {count} parameters, anisocap {l1['parameters']}"
                t, cpu = median_step_time(step, 0.0 if paper else args.min_time,
                                          args.paper_repetitions if paper else args.repetitions, 1 if paper else 2)
                theirs.append(batch / t)
                theirs_cpu.append(batch / cpu)
                del step
            best = max(theirs)
            row = [kind, preset, f"{size} x {batch}", str(threads),
                   f"{full['samples_per_s']:.2f}" if full else "-",
                   f"{l1['samples_per_s']:.2f}" if l1 else "-"]
            row += [f"{v:.2f}" for v in theirs]
            # anisocap's cpu_time is its main thread's: comparable with the process's on 1 thread.
            cpu_ratio = "-"
            if l1 and threads == 1:
                unit = {"ms": 1e-3, "s": 1.0, "us": 1e-6}[l1["time_unit"]]
                cpu_ratio = f"{batch / (l1['cpu_time'] * unit) / max(theirs_cpu):.1f}"
            row += [f"{l1['samples_per_s'] / best:.1f}" if l1 else "-", cpu_ratio,
                    f"{count} (= anisocap)" if l1 else str(count), f"{load():.2f}"]
            print("| " + " | ".join(row) + " |", flush=True)


if __name__ == "__main__":
    main()
