#!/usr/bin/env python3
"""How saturated an auto-encoder's output is where the pipeline's fine-tune starts:

    python3 studies/decoder_saturation.py --tool build/studies/anisocap_study_torch_training_data \\
        --estimator models/compact/estimator.safetensors AUTOENCODER.safetensors [...]

The decoder ends in tanh, so the fine-tune's gradient on a network-space value u is scaled by
1 - u^2. For 16 validation materials (256 x 256, the seeds of `eval-networks`) this prints, per
auto-encoder and per map, the mean of 1 - u^2 and the share of values with |u| > 0.99, for the
decode of the true maps, D(E(truth)), and of the estimator's estimate, D(E(estimate)) (the
fine-tune's start; the estimate from the 5 training inputs rendered by the PyTorch port), beside
the same for the true maps themselves. models/README.md "Run 25" uses it to ask whether better
trained decoders fine-tune worse because their outputs sit where tanh is flat."""
import argparse
import os
import subprocess
import tempfile

import torch

from train_torch import estimator_inputs, load_cpp, make_net, network_to_maps, read_chunk, read_safetensors, render_batch

MAPS = [("a_d", [0, 1, 2]), ("a'_s", [3, 4, 5]), ("n_s", [6, 7]), ("sigma", [8, 9]), ("alpha", [10]), ("F0", [11])]


def summary(u):
    """(mean of 1 - u^2, share of |u| > 0.99) per map of a (B, 12, H, W) tensor."""
    return [((1 - u[:, c] ** 2).mean().item(), (u[:, c].abs() > 0.99).float().mean().item()) for _, c in MAPS]


def from_file(network, path):
    """The PyTorch port of the network in a C++ weight file (its preset from the file), in eval mode."""
    _, meta, _ = read_safetensors(path)
    net = make_net(network, meta.get("preset", "compact"))
    load_cpp(net, path)
    return net.eval()


def row(name, stats):
    return f"| {name} | " + " | ".join(f"{g:.3f} / {100 * s:.1f}%" for g, s in stats) + " |"


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("autoencoders", nargs="+")
    ap.add_argument("--tool", required=True, help="anisocap_study_torch_training_data")
    ap.add_argument("--estimator", required=True)
    ap.add_argument("--count", type=int, default=16)
    args = ap.parse_args()
    torch.set_grad_enabled(False)
    with tempfile.TemporaryDirectory() as tmp:
        data = os.path.join(tmp, "v.bin")
        subprocess.run([args.tool, "materials", "--out", data, "--validation", "--first", "0", "--count", str(args.count),
                        "--size", "256"], check=True)
        rec = read_chunk(data)
    truth = torch.from_numpy(rec["maps"].astype("float32")).permute(0, 3, 1, 2)
    conf = torch.from_numpy(rec["conf"].astype("float32"))
    estimator = from_file("estimator", args.estimator)
    estimates = []
    for b in range(truth.shape[0]):
        photos = render_batch(network_to_maps(truth[b:b + 1]), conf[b:b + 1])[:, 0:5]  # (1, 5, H, W, 3)
        estimates.append(estimator(estimator_inputs(photos, estimator.inputs), 5))
    estimate = torch.cat(estimates)
    print("mean of 1 - u^2 / share of |u| > 0.99, per map (" + str(truth.shape[0]) + " validation materials, 256 x 256)\n")
    print("| maps | " + " | ".join(n for n, _ in MAPS) + " |")
    print("|---|" + "---|" * len(MAPS))
    print(row("true maps", summary(truth)))
    print(row("estimate", summary(estimate)))
    for path in args.autoencoders:
        ae = from_file("autoencoder", path)
        name = os.path.relpath(path)
        print(row(f"D(E(truth)), {name}", summary(ae.decode(ae.encode(truth)))))
        print(row(f"D(E(estimate)), {name}", summary(ae.decode(ae.encode(estimate)))))


if __name__ == "__main__":
    main()
