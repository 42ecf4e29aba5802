#!/usr/bin/env python3
"""Rescales an auto-encoder's latent code without changing what it computes:

    python3 studies/rescale_latent.py IN.safetensors OUT.safetensors FACTOR

The batch norm that ends the encoder (latent_norm) has its scale and shift multiplied by FACTOR, so
z becomes FACTOR z, and the first decoder layer's weights (dec0.weight) are divided by FACTOR, so
D(E(m)) is unchanged up to rounding. What changes is the fine-tune (docs/method.md section 8.3):
Adam moves each decoder weight by about the learning rate, so dec0's effect on the output per step
scales with |z|. models/README.md "Run 16" uses it to ask whether the latent's scale is why
longer-trained auto-encoders fine-tune worse."""
import sys

from train_torch import read_safetensors, write_safetensors


def main():
    if len(sys.argv) != 4:
        raise SystemExit(__doc__)
    source, target, factor = sys.argv[1], sys.argv[2], float(sys.argv[3])
    if not factor > 0:
        raise SystemExit(f"FACTOR must be positive, got {sys.argv[3]}")
    tensors, meta, names = read_safetensors(source)
    if meta.get("network") != "autoencoder":
        raise SystemExit(f"{source}: holds {meta.get('network')} weights, not auto-encoder weights")
    for name in ("latent_norm.weight", "latent_norm.bias", "dec0.weight"):
        if name not in tensors:
            raise SystemExit(f"{source}: no tensor {name}")
    tensors["latent_norm.weight"] *= factor
    tensors["latent_norm.bias"] *= factor
    tensors["dec0.weight"] /= factor
    write_safetensors(target, tensors, names, dict(meta, rescaled_latent=f"{factor:g} (studies/rescale_latent.py)"))


if __name__ == "__main__":
    main()
