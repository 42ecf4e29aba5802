#!/usr/bin/env python3
"""Starts a `compact-fine` auto-encoder (latent (H/16) x (W/16) x 128, four levels) from a trained
`compact` one (five levels, latent (H/32) x (W/32) x 128):

    python3 studies/fine_latent_from_compact.py COMPACT.safetensors OUT.safetensors

The two presets share every layer but the deepest: compact-fine's encoder layers enc0-enc3 are
compact's enc0-enc3, and its decoder layers dec0-dec3 are compact's dec1-dec4 (the same shapes:
dec0 reads 128 channels at H/16, as compact's dec1 does). Compact's enc4 and dec0 are left out; the
batch norm that ends the encoder starts as the identity (scale 1, shift 0, running mean 0, variance
1), since it now normalises enc3's output. The file is an `--init` for
`anisocap train-autoencoder --preset compact-fine` (models/README.md, "Run 25")."""
import sys

import numpy as np

from train_torch import read_safetensors, write_safetensors


def main():
    if len(sys.argv) != 3:
        raise SystemExit(__doc__)
    source, target = sys.argv[1], sys.argv[2]
    tensors, meta, _ = read_safetensors(source)
    if meta.get("network") != "autoencoder" or meta.get("preset", "compact") != "compact":
        raise SystemExit(f"{source}: holds {meta.get('network')} weights of preset {meta.get('preset')}, "
                         "not a compact auto-encoder's")
    renames = {f"enc{i}.{p}": f"enc{i}.{p}" for i in range(4) for p in ("weight", "bias")}
    renames.update({f"dec{i + 1}.{p}": f"dec{i}.{p}" for i in range(4) for p in ("weight", "bias")})
    missing = [name for name in renames if name not in tensors]
    if missing:
        raise SystemExit(f"{source}: no tensor {', '.join(missing)}")
    out = {new: tensors[old] for old, new in renames.items()}
    width = tensors["enc3.bias"].shape[0]
    out["latent_norm.weight"] = np.ones(width, np.float32)
    out["latent_norm.bias"] = np.zeros(width, np.float32)
    out["latent_norm.running_mean"] = np.zeros(width, np.float32)
    out["latent_norm.running_var"] = np.ones(width, np.float32)
    names = [f"enc{i}.{p}" for i in range(4) for p in ("weight", "bias")] + ["latent_norm.weight", "latent_norm.bias"]
    names += [f"dec{i}.{p}" for i in range(4) for p in ("weight", "bias")] + ["latent_norm.running_mean", "latent_norm.running_var"]
    write_safetensors(target, out, names,
                      {"network": "autoencoder", "preset": "compact-fine",
                       "started_from": f"{source} (studies/fine_latent_from_compact.py)"})


if __name__ == "__main__":
    main()
