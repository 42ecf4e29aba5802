#!/usr/bin/env python3
"""How much better an auto-encoder's decoder reconstructs the maps from the best latent than from its
encoder's: the amortisation gap, on eval-networks' validation materials.

Goal 2 of the learned prior (models/README.md) asks the auto-encoder's reconstruction D(E(x)) for at
most 0.2x the estimator's error. Where that error lives decides the remedy: if a latent found by
gradient descent on the decoder's input, from E(x), reconstructs far better, the decoder can
express the maps and the encoder is what falls short (a wider or deeper encoder, or a few latent
steps at encode time); if not, the decoder and the compression are the limit.

For each weight file the study measures, per parameter and with compare_maps' squared errors in the
original ranges (studies/train_torch.py per_parameter_mse):

  - D(E(x)), the reconstruction eval-networks measures (its row reproduces eval-networks' numbers up
    to the maps' float16 storage);
  - D(z*), with z* = E(x) after --steps Adam steps on the latent alone (the decoder fixed, batch
    norm in inference mode), minimising the training objective of train-autoencoder on the true
    maps: the network-space L1 plus --sigma-weight and --mse-weight times the squared-error terms
    (training::map_losses without the render term).

    python3 studies/latent_gap.py --tool build-studies/studies/anisocap_study_torch_training_data \
        --autoencoder WIDER.safetensors --markdown out.md

The materials come from the tool's `materials --evaluation --materials original` (eval-networks'
seeds and kinds). One thread by default (--threads).
"""
import argparse
import os
import subprocess
import sys
import tempfile
import time

import numpy as np
import torch

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import train_torch as tt  # noqa: E402

ORDER = [0, 1, 2, 3, 4, 6, 5]  # table columns in eval-networks' order: ..., alpha, alpha anisotropic, F0


def materials(tool, count, size):
    with tempfile.TemporaryDirectory() as tmp:
        path = os.path.join(tmp, "m.bin")
        r = subprocess.run([tool, "materials", "--out", path, "--evaluation", "--materials", "original", "--first", "0",
                            "--count", str(count), "--size", str(size)], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
        if r.returncode != 0:
            raise SystemExit(f"latent_gap: {tool} failed: {r.stderr.strip()}")
        rec = tt.read_chunk(path)
    return torch.from_numpy(rec["maps"].astype(np.float32)).permute(0, 3, 1, 2).contiguous()


def errors(u, truth):
    """Mean over materials of per_parameter_mse, material by material (as compare_maps and
    eval-networks average: the anisotropic rotation's mean over each material's anisotropic texels)."""
    rows = [tt.per_parameter_mse(u[i:i + 1], truth[i:i + 1]) for i in range(u.shape[0])]
    out = []
    for k in range(7):
        v = [r[k] for r in rows if not np.isnan(r[k])]
        out.append(float(np.mean(v)) if v else float("nan"))
    return out


def in_batches(f, t, batch):
    """f over t's materials, `batch` at a time, concatenated (memory only: the networks run in inference mode)."""
    return torch.cat([f(t[i:i + batch]) for i in range(0, t.shape[0], batch)])


def row(name, e):
    return "| " + name + " | " + " | ".join(f"{e[k]:.4g}" for k in ORDER) + " |\n"


def study(path, truth, args, log):
    _, meta, _ = tt.read_safetensors(path)
    preset = meta.get("preset", "compact")
    if meta.get("network", "autoencoder") != "autoencoder" or preset not in tt.AUTOENCODER_PRESETS:
        raise SystemExit(f"latent_gap: {path}: not a compact auto-encoder file (preset {preset})")
    net = tt.make_net("autoencoder", preset)
    tt.load_cpp(net, path)
    net.eval()
    for p in net.parameters():
        p.requires_grad_(False)
    label = os.path.basename(path)
    with torch.no_grad():
        z0 = in_batches(net.encode, truth, args.batch)
        d0 = in_batches(net.decode, z0, args.batch)
    lines = [row(f"{label} ({preset}): D(E(x))", errors(d0, truth))]
    rms = z0.pow(2).mean().sqrt().item()
    lr = args.lr_relative * rms if args.lr_relative else args.lr
    z = z0.clone().requires_grad_(True)
    opt = torch.optim.Adam([z], lr=lr)
    start = time.time()
    for step in range(1, args.steps + 1):
        opt.zero_grad()
        total = 0.0
        for i in range(0, truth.shape[0], args.batch):
            u = net.decode(z[i:i + args.batch])
            # map_l1 averages over its batch; scale so the sum over batches is the mean over materials
            loss = tt.map_l1(u, truth[i:i + args.batch], sigma_weight=args.sigma_weight, mse_weight=args.mse_weight)
            loss = loss * (u.shape[0] / truth.shape[0])
            loss.backward()
            total += loss.item()
        opt.step()
        if step % max(1, args.steps // 10) == 0 or step == 1:
            log(f"{label}: latent step {step}/{args.steps}  objective {total:.5f}  {time.time() - start:.0f} s")
    with torch.no_grad():
        d1 = in_batches(net.decode, z, args.batch)
        moved = ((z - z0).norm() / z0.norm()).item()
    lines.append(row(f"{label}: D(z*), {args.steps} latent steps at {lr:.3g} (latent RMS {rms:.3g}, moved {100 * moved:.0f}% of its norm)",
                     errors(d1, truth)))
    return lines


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--autoencoder", action="append", required=True, help="a compact auto-encoder weight file (repeatable)")
    ap.add_argument("--tool", required=True, help="the anisocap_study_torch_training_data executable")
    ap.add_argument("--count", type=int, default=30, help="validation materials (eval-networks' --count)")
    ap.add_argument("--size", type=int, default=256, help="material side, texels (a multiple of 32)")
    ap.add_argument("--steps", type=int, default=200, help="Adam steps on the latent")
    ap.add_argument("--lr", type=float, default=0.03, help="Adam's learning rate on the latent, in the latent's units")
    ap.add_argument("--lr-relative", type=float, default=0.0,
                    help="instead of --lr: this fraction of the latent's RMS over the materials (the shipped compact "
                         "auto-encoder's latent RMS is about a tenth of the compact-fine-wide one's)")
    ap.add_argument("--batch", type=int, default=5, help="materials per forward pass (memory only)")
    ap.add_argument("--sigma-weight", type=float, default=5.0, help="the objective's lobe-width squared-error weight")
    ap.add_argument("--mse-weight", type=float, default=10.0, help="the objective's a_d, a'_s, F0, normal squared-error weight")
    ap.add_argument("--threads", type=int, default=1, help="PyTorch threads")
    ap.add_argument("--markdown", help="also write the table to this file")
    args = ap.parse_args()
    for p in args.autoencoder:
        if not os.path.isfile(p):
            raise SystemExit(f"latent_gap: {p}: no such file")
    if not (os.path.isfile(args.tool) and os.access(args.tool, os.X_OK)):
        raise SystemExit(f"latent_gap: {args.tool}: not an executable (build anisocap_study_torch_training_data)")
    if args.count < 1 or args.size < 32 or args.size % 32 or args.steps < 0 or args.lr <= 0 or args.lr_relative < 0 or args.batch < 1:
        raise SystemExit("latent_gap: --count >= 1, --size a positive multiple of 32, --steps >= 0, --lr > 0, --lr-relative >= 0, --batch >= 1")
    torch.set_num_threads(args.threads)
    log = lambda s: print(s, file=sys.stderr, flush=True)  # noqa: E731
    truth = materials(args.tool, args.count, args.size)
    md = (f"Validation materials: {args.count} (eval-networks' seeds and kinds, original mix), {args.size} x {args.size}, maps "
          f"through float16; latent optimised by Adam on L1 + {args.sigma_weight} x sigma SE + {args.mse_weight} x "
          f"(a_d, a'_s, F0, normal) SE; MSE in the original ranges (compare_maps)\n\n"
          "| reconstruction | a_d | a'_s | n_s | sigma | alpha (mod pi) | alpha, anisotropic | F0 |\n|---|---|---|---|---|---|---|---|\n")
    for p in args.autoencoder:
        md += "".join(study(p, truth, args, log))
    print(md, end="")
    if args.markdown:
        tmp = args.markdown + ".tmp"
        with open(tmp, "w") as f:
            f.write(md)
        os.replace(tmp, args.markdown)


if __name__ == "__main__":
    main()
