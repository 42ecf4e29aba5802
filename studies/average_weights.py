#!/usr/bin/env python3
"""Averages the weights of networks of one kind and preset (a "model soup", Wortsman et al. 2022):

    python3 studies/average_weights.py -o OUT.safetensors A.safetensors B.safetensors [C ...]
    python3 studies/average_weights.py -o OUT.safetensors --weights 0.5,0.25,0.25 A B C

Every tensor of OUT is the weighted mean of the same tensor in the inputs (equal weights unless
--weights says otherwise; they are normalised to sum to 1), batch norms' running statistics
included. This is only meaningful for networks fine-tuned from one starting point, which stay in
one basin of the loss: models/README.md "Run 18" measures it on run 17's estimators. The inputs
must agree on the network, the preset and every tensor's name and shape; OUT keeps the first
input's metadata and records what it averaged."""
import argparse
import os

import numpy as np

from train_torch import read_safetensors, write_safetensors


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("inputs", nargs="+", help="weights to average (at least two)")
    parser.add_argument("-o", "--out", required=True, help="the averaged weights (.safetensors)")
    parser.add_argument("--weights", help="comma-separated non-negative mixing weights, one per input")
    args = parser.parse_args()
    if len(args.inputs) < 2:
        raise SystemExit("average_weights.py: give at least two weight files")
    if args.weights is None:
        mix = np.full(len(args.inputs), 1.0 / len(args.inputs))
    else:
        try:
            mix = np.array([float(w) for w in args.weights.split(",")])
        except ValueError:
            raise SystemExit(f"--weights: '{args.weights}' is not a comma-separated list of numbers")
        if len(mix) != len(args.inputs) or not np.all(np.isfinite(mix)) or np.any(mix < 0) or mix.sum() <= 0:
            raise SystemExit(f"--weights: need {len(args.inputs)} non-negative numbers with a positive sum")
        mix = mix / mix.sum()

    first, meta, names = None, None, None
    total = None
    for path, w in zip(args.inputs, mix):
        if not os.path.isfile(path):
            raise SystemExit(f"{path}: no such file")
        tensors, m, n = read_safetensors(path)
        if first is None:
            first, meta, names = path, m, n
            total = {k: np.zeros_like(v, dtype=np.float64) for k, v in tensors.items()}
        for key in ("network", "preset"):
            if m.get(key) != meta.get(key):
                raise SystemExit(f"{path}: {key} is {m.get(key)}, {first} has {meta.get(key)}")
        if set(n) != set(names):
            raise SystemExit(f"{path}: its tensors differ from {first}'s")
        for k, v in tensors.items():
            if v.shape != total[k].shape:
                raise SystemExit(f"{path}: {k} has shape {v.shape}, {first} has {total[k].shape}")
            total[k] += w * v.astype(np.float64)
    out = {k: v.astype(np.float32) for k, v in total.items()}
    record = ", ".join(f"{os.path.basename(os.path.dirname(p)) or p}/{os.path.basename(p)} x {w:.3g}"
                       for p, w in zip(args.inputs, mix))
    write_safetensors(args.out, out, names, dict(meta, averaged=record + " (studies/average_weights.py)"))


if __name__ == "__main__":
    main()
