#!/usr/bin/env python3
"""The Python package's speed: the image loss and gradient from Python against PyTorch autograd, and
a small capture from Python against the program (docs/python.md, "Speed").

Usage:
    OMP_NUM_THREADS=2 PYTHONPATH=BUILD/python /usr/bin/python3 bench/python_speed.py \\
        --program BUILD/anisocap [--runs 7] [--rounds 3] [--capture-size 64]

1. Loss and gradient on 256 x 256 texels and 12 photographs (full kernel, float32, the same
   threads on both sides: OMP_NUM_THREADS and torch.set_num_threads of the same number): anisocap.loss_and_gradient on
   NumPy arrays, anisocap.torch.ImageLoss forward + backward on a tensor, and the same loss written
   in PyTorch (studies/reference/ward_reference.py) differentiated by autograd. Random maps in the
   parameters' ranges, photographs synthesized by anisocap (set alpha). The machine may be shared,
   so the sides alternate in rounds; each figure is the median over all runs after a warm-up, the
   ratio the median of the per-round ratios.
2. A capture of a synthesized CAPTURE_SIZE^2 material (12 photographs, the default options, the
   shipped weights): `anisocap capture` as a process (its wall time: start, reading, weights,
   stages, writing the outputs) against anisocap.capture on the same capture.json, first call
   (which loads the weights) and second call (weights cached), each split into the stages' time
   (the program's report.json, the call's result) and the rest: what each adds around the same
   stages, which a loaded machine leaves readable when it makes the stages' time vary.
"""
import argparse
import json
import os
import pathlib
import statistics
import subprocess
import sys
import tempfile
import time

import numpy as np
import torch

import anisocap
import anisocap.torch

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1] / "studies" / "reference"))
import ward_reference  # noqa: E402


def random_maps(size, seed):
    rng = np.random.default_rng(seed)
    m = np.empty((size, size, 12), np.float32)
    m[..., 0:6] = rng.uniform(0.05, 0.95, (size, size, 6))
    m[..., 6:8] = rng.uniform(0.05, 0.45, (size, size, 2))
    m[..., 8] = rng.uniform(0.05, 0.95, (size, size))
    m[..., 9:11] = rng.uniform(-0.15, 0.15, (size, size, 2))
    m[..., 11] = rng.uniform(-1.5, 1.5, (size, size))
    return m


def median_seconds(fn, runs):
    fn()  # warm-up
    times = []
    for _ in range(runs):
        t = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t)
    return times


def loss_table(runs, rounds):
    torch.set_num_threads(int(os.environ.get("OMP_NUM_THREADS", "2")))
    data = anisocap.synthesize(width=256, height=256, images=12, seed=1)
    configs, photos = data["configurations"], data["photos"]
    maps = random_maps(256, 2)
    targets = anisocap.loss_targets(photos)
    loss_fn = anisocap.torch.ImageLoss(configs, photos)
    ours = torch.tensor(maps, requires_grad=True)
    theirs = torch.tensor(maps, requires_grad=True)
    capture = [{"camera": c.camera, "light": c.light, "intensity": c.intensity} for c in configs]
    photo_tensor = torch.from_numpy(photos)

    def numpy_call():
        anisocap.loss_and_gradient(maps, configs, targets)

    def torch_function():
        ours.grad = None
        loss_fn(ours).backward()

    def autograd():
        theirs.grad = None
        named = {"diffuse": theirs[..., 0:3], "specular": theirs[..., 3:6], "sx": theirs[..., 6], "sy": theirs[..., 7],
                 "f0": theirs[..., 8], "nx": theirs[..., 9], "ny": theirs[..., 10], "alpha": theirs[..., 11]}
        ward_reference.image_loss(torch, ward_reference.render(torch, named, capture), photo_tensor).backward()

    sides = {"anisocap.loss_and_gradient (NumPy)": numpy_call, "anisocap.torch.ImageLoss (forward + backward)": torch_function,
             "PyTorch autograd (ward_reference.py)": autograd}
    times = {name: [] for name in sides}
    ratios = []
    for _ in range(rounds):
        this_round = {name: median_seconds(fn, runs) for name, fn in sides.items()}
        for name, t in this_round.items():
            times[name] += t
        ratios.append(statistics.median(this_round["PyTorch autograd (ward_reference.py)"]) /
                      statistics.median(this_round["anisocap.torch.ImageLoss (forward + backward)"]))
    print(f"loss and gradient, 256 x 256 texels, 12 photographs, float32, OMP_NUM_THREADS={os.environ.get('OMP_NUM_THREADS')},"
          f" torch threads {torch.get_num_threads()}, {rounds} rounds of {runs} runs")
    print("| call | ms per loss and gradient | texel-image evaluations / s |\n|---|---|---|")
    for name, t in times.items():
        seconds = statistics.median(t)
        print(f"| {name} | {1000 * seconds:.1f} | {256 * 256 * 12 / seconds / 1e6:.1f} M |")
    print(f"PyTorch autograd / anisocap.torch: {statistics.median(ratios):.1f}x (median of the rounds' ratios)\n")


def capture_table(program, size):
    with tempfile.TemporaryDirectory() as work:
        work = pathlib.Path(work)
        data = anisocap.synthesize(width=size, height=size, images=12, seed=1)
        anisocap.write_capture(data["configurations"], data["photos"], work / "syn")
        capture_json = work / "syn" / "capture.json"
        t = time.perf_counter()
        subprocess.run([program, "capture", str(capture_json), "-o", str(work / "out"), "--no-view"], check=True,
                       capture_output=True)
        program_seconds = time.perf_counter() - t
        calls = []
        for _ in range(2):
            t = time.perf_counter()
            result = anisocap.capture(capture_json)
            calls.append(time.perf_counter() - t)
            if len(calls) == 1:
                first_stages = sum(s["seconds"] for s in result["stages"])
        same = np.array_equal(result["maps"], anisocap.read_maps(work / "out"))
        stages = sum(s["seconds"] for s in result["stages"])
        timings = json.loads((work / "out" / "report.json").read_text())["timings"]
    print(f"capture of a {size} x {size} material, 12 photographs, default options")
    print("| run | seconds | of which the stages | the rest |\n|---|---|---|---|")
    print(f"| anisocap capture (a process: weights, stages, writing maps, renders, report) | {program_seconds:.2f} | "
          f"{timings['stages']:.2f} | {program_seconds - timings['stages']:.2f} |")
    print(f"| anisocap.capture, first call (loads the weights) | {calls[0]:.2f} | {first_stages:.2f} | {calls[0] - first_stages:.2f} |")
    print(f"| anisocap.capture, second call | {calls[1]:.2f} | {stages:.2f} | {calls[1] - stages:.2f} |")
    print(f"maps equal to the program's: {same}")


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--program", help="the anisocap program, for the capture comparison")
    parser.add_argument("--runs", type=int, default=7)
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--capture-size", type=int, default=64)
    parser.add_argument("--no-loss", action="store_true", help="leave out the loss table")
    args = parser.parse_args()
    print("load average before: %.1f %.1f %.1f" % os.getloadavg())
    if not args.no_loss:
        loss_table(args.runs, args.rounds)
    if args.program:
        capture_table(args.program, args.capture_size)
    print("load average after: %.1f %.1f %.1f" % os.getloadavg())


if __name__ == "__main__":
    main()
