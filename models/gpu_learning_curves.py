#!/usr/bin/env python3
"""Learning curves of runs trained on a GPU with studies/train_torch.py: each network's validation
(64 validation materials at the runs' training size, --size, default 128; the errors of
compare_maps) against materials drawn, one line per network, with the runs of a chain (each
continuing the previous one's weights) laid end to end and their boundaries marked.

    H=models/compact/history
    /usr/bin/python3 models/gpu_learning_curves.py -o models/run13_gpu.png \
        estimator:$H/estimator_run13_gpu_call1.csv,$H/estimator_run13_gpu_call2.csv,$H/estimator_run13_gpu_call3.csv \
        autoencoder:$H/autoencoder_run13_gpu_call1.csv,$H/autoencoder_run13_gpu_call2.csv,$H/autoencoder_run13_gpu_call3.csv
"""
import argparse
import csv

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

PANELS = [("val_l1", "validation L1 (network space)"), ("mse_diffuse", "a_d MSE"), ("mse_specular", "a'_s MSE"),
          ("mse_normal", "n_s MSE"), ("mse_lobes", "sigma MSE"), ("mse_rotation", "alpha MSE (mod pi)"),
          ("mse_fresnel", "F0 MSE")]


def read_chain(spec):
    kind, files = spec.split(":", 1)
    files = files.split(",")
    xs, ys, boundaries, offset, seconds = [], {k: [] for k, _ in PANELS}, [], 0, 0.0
    for f in files:
        rows = list(csv.DictReader(open(f)))
        for r in rows:
            if xs and int(r["step"]) == 0:
                continue  # a continued run's step-0 row repeats the previous run's last weights
            xs.append(offset + int(r["materials_drawn"]))
            for k, _ in PANELS:
                ys[k].append(float(r[k]))
        offset += int(rows[-1]["materials_drawn"])
        seconds += float(rows[-1]["seconds"])
        boundaries.append(offset)
    return kind, xs, ys, boundaries[:-1], seconds


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("-o", "--out", required=True)
    parser.add_argument("--size", type=int, default=128, help="the runs' training and validation size (the title's)")
    parser.add_argument("chains", nargs="+", help="KIND:CSV,CSV,...")
    args = parser.parse_args()
    chains = [read_chain(c) for c in args.chains]
    fig, grid = plt.subplots(2, 4, figsize=(16, 7.5))
    axes = grid.flatten()
    axes[-1].axis("off")
    for kind, xs, ys, boundaries, seconds in chains:
        for ax, (key, title) in zip(axes, PANELS):
            line, = ax.plot(xs, ys[key], label=f"{kind} ({seconds / 60:.0f} min)")
            for b in boundaries:
                ax.axvline(b, color=line.get_color(), alpha=0.25, linestyle=":")
            ax.set_title(title, fontsize=10)
            ax.set_xlabel("materials drawn")
            ax.set_yscale("log")
            ax.grid(alpha=0.3)
    handles, labels = axes[0].get_legend_handles_labels()
    axes[-1].legend(handles, labels, loc="center")
    fig.suptitle(f"GPU training (studies/train_torch.py): validation on 64 materials, {args.size} x {args.size}\ndotted lines: a new run "
                 "from the previous one's weights (learning rate warmed up again, then decayed)", fontsize=11)
    fig.tight_layout()
    fig.savefig(args.out, dpi=90)


if __name__ == "__main__":
    main()
