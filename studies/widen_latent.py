#!/usr/bin/env python3
"""Starts a `compact-fine-wide` auto-encoder (latent (H/16) x (W/16) x 256) from a trained
`compact-fine` one (latent (H/16) x (W/16) x 128) with the same output:

    python3 studies/widen_latent.py FINE.safetensors OUT.safetensors [--seed 1]

The two presets differ only in the deepest level's width. enc0-enc2 and dec1-dec3 are copied;
enc3's first 128 filters and the batch norm's first 128 channels are compact-fine's, its 128 new
filters start as PyTorch initialises a convolution (the batch norm's new channels as the
identity), and dec0 reads the 128 new latent channels with weights of zero. The decoder therefore
gives the compact-fine decoder's maps at the start, and training grows the new channels from
there (a function-preserving widening, as Net2Net's). The script checks that on random maps in
both batch-norm modes (on copies, since training mode moves the running statistics). The file is
an `--init` for `train_torch.py train --network autoencoder` and `anisocap train-autoencoder
--preset compact-fine-wide` (models/README.md, "Run 27")."""
import argparse
import copy
import os

import torch

from train_torch import AutoEncoder, load_cpp, read_safetensors, save_cpp


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("source", help="a compact-fine auto-encoder's weight file")
    parser.add_argument("target", help="the compact-fine-wide file to write")
    parser.add_argument("--seed", type=int, default=1, help="seed of the new filters")
    args = parser.parse_args()
    _, meta, names = read_safetensors(args.source)
    if meta.get("network") != "autoencoder" or meta.get("preset") != "compact-fine":
        raise SystemExit(f"{args.source}: holds {meta.get('network')} weights of preset {meta.get('preset')}, "
                         "not a compact-fine auto-encoder's")
    torch.manual_seed(args.seed)
    fine, wide = AutoEncoder("compact-fine").double(), AutoEncoder("compact-fine-wide").double()
    load_cpp(fine, args.source)
    old = fine.latent_norm.num_features
    with torch.no_grad():
        for i in range(3):
            getattr(wide, f"enc{i}").load_state_dict(getattr(fine, f"enc{i}").state_dict())
        for i in range(1, 4):
            getattr(wide, f"dec{i}").load_state_dict(getattr(fine, f"dec{i}").state_dict())
        wide.enc3.weight[:old] = fine.enc3.weight
        wide.enc3.bias[:old] = fine.enc3.bias
        for name in ("weight", "bias", "running_mean", "running_var"):
            getattr(wide.latent_norm, name)[:old] = getattr(fine.latent_norm, name)
        wide.dec0.weight.zero_()
        wide.dec0.weight[:old] = fine.dec0.weight  # ConvTranspose2d: [in][out][k][k]
        wide.dec0.bias.copy_(fine.dec0.bias)
        x = torch.rand(4, 12, 64, 64, dtype=torch.float64) * 2 - 1
        for mode in (False, True):
            # Copies: a forward pass in training mode moves the batch norm's running statistics.
            a, b = copy.deepcopy(fine).train(mode), copy.deepcopy(wide).train(mode)
            diff = (a.decode(a.encode(x)) - b.decode(b.encode(x))).abs().max().item()
            if diff > 1e-12:
                raise SystemExit(f"the widened network differs from {args.source} by {diff:.1e} (batch-norm training mode {mode})")
    wide.eval()
    partial = args.target + ".partial"
    save_cpp(wide.float(), partial, names,  # the two presets' tensors have the same names
             {"network": "autoencoder", "preset": "compact-fine-wide",
              "started_from": f"{args.source} (studies/widen_latent.py --seed {args.seed})"})
    os.replace(partial, args.target)
    print(f"{args.target}: compact-fine-wide, the same maps as {args.source} (largest difference {diff:.1e})")


if __name__ == "__main__":
    main()
