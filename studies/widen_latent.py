#!/usr/bin/env python3
"""Starts a wider four-level auto-encoder from a trained narrower one with the same output:

    python3 studies/widen_latent.py SOURCE.safetensors OUT.safetensors [--to PRESET] [--seed 1]

SOURCE is a four-level auto-encoder file: `compact-fine` (32-64-128-128), `compact-fine-wide`
(32-64-128-256), `compact-fine-wider` (64-128-256-256) or `compact-fine-widest` (64-128-256-384); `--to` names a four-level preset at least
as wide at every level: `compact-fine-wide` (the default: the latent 256 wide, the paper's 12 map
values per latent value, models/README.md "Run 27"), `compact-fine-wider` (64-128-256-256: the
levels above the latent twice as wide, "Run 30"), `compact-fine-widest` (64-128-256-384: a
384-wide latent, 8 map values per latent value, "Run 31") or `compact-fine-512` (64-128-256-512:
6 map values per latent value, "Run 32").

Every layer keeps the source's weights on the source's channels. A new output channel of a
layer (a new filter) starts as PyTorch initialises a convolution, and the next layer reads it with
weights of zero; the batch norm's new channels start as the identity. Each old channel is
therefore computed as before and the decoder gives the source's maps at the start, and training
grows the new channels from there (a function-preserving widening, as Net2Net's). The script checks
that on random maps in both batch-norm modes (on copies, since training mode moves the running
statistics). The file is an `--init` for `train_torch.py train --network autoencoder` and `anisocap
train-autoencoder --preset PRESET`."""
import argparse
import copy
import os

import torch

from train_torch import AUTOENCODER_PRESETS, AutoEncoder, load_cpp, read_safetensors, save_cpp

TARGETS = ("compact-fine-wide", "compact-fine-wider", "compact-fine-widest", "compact-fine-512")


def widen_layer(old, new, transposed):
    """Copies `old` into the old channels of `new` (a wider layer of the same kind) and zeroes the
    weights by which old outputs would read new inputs. Conv2d weights are [out][in][k][k],
    ConvTranspose2d ones [in][out][k][k]."""
    w_old, w_new = old.weight, new.weight
    if transposed:
        i_old, o_old = w_old.shape[0], w_old.shape[1]
        w_new[:, :o_old] = 0
        w_new[:i_old, :o_old] = w_old
    else:
        o_old, i_old = w_old.shape[0], w_old.shape[1]
        w_new[:o_old] = 0
        w_new[:o_old, :i_old] = w_old
    new.bias[:o_old] = old.bias


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("source", help="a four-level auto-encoder's weight file")
    parser.add_argument("target", help="the wider file to write")
    parser.add_argument("--to", default="compact-fine-wide", choices=TARGETS, help="the preset to write")
    parser.add_argument("--seed", type=int, default=1, help="seed of the new filters")
    parser.add_argument("--half", action="store_true", help="write the kernels as half floats (as anisocap convert-weights --half)")
    args = parser.parse_args()
    _, meta, names = read_safetensors(args.source)
    source_preset = meta.get("preset")
    widths = AUTOENCODER_PRESETS.get(source_preset) if meta.get("network") == "autoencoder" else None
    target_widths = AUTOENCODER_PRESETS[args.to]
    if widths is None or len(widths) != len(target_widths) or any(a > b for a, b in zip(widths, target_widths)):
        raise SystemExit(f"{args.source}: holds {meta.get('network')} weights of preset {source_preset}, "
                         f"not a four-level auto-encoder at most as wide as {args.to} at every level")
    torch.manual_seed(args.seed)
    source, wide = AutoEncoder(source_preset).double(), AutoEncoder(args.to).double()
    load_cpp(source, args.source)
    old = source.latent_norm.num_features
    with torch.no_grad():
        for i in range(source.levels):
            widen_layer(getattr(source, f"enc{i}"), getattr(wide, f"enc{i}"), transposed=False)
            widen_layer(getattr(source, f"dec{i}"), getattr(wide, f"dec{i}"), transposed=True)
        for name in ("weight", "bias", "running_mean", "running_var"):
            getattr(wide.latent_norm, name)[:old] = getattr(source.latent_norm, name)
        x = torch.rand(4, 12, 64, 64, dtype=torch.float64) * 2 - 1
        for mode in (False, True):
            # Copies: a forward pass in training mode moves the batch norm's running statistics.
            a, b = copy.deepcopy(source).train(mode), copy.deepcopy(wide).train(mode)
            diff = (a.decode(a.encode(x)) - b.decode(b.encode(x))).abs().max().item()
            if diff > 1e-12:
                raise SystemExit(f"the widened network differs from {args.source} by {diff:.1e} (batch-norm training mode {mode})")
    wide.eval()
    partial = args.target + ".partial"
    save_cpp(wide.float(), partial, names,  # the presets' tensors have the same names
             {"network": "autoencoder", "preset": args.to,
              "started_from": f"{args.source} (studies/widen_latent.py --to {args.to} --seed {args.seed})"}, args.half)
    os.replace(partial, args.target)
    print(f"{args.target}: {args.to}, the same maps as {args.source} (largest difference {diff:.1e})"
          + (", the kernels as half floats" if args.half else ""))


if __name__ == "__main__":
    main()
