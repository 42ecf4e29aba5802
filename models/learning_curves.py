#!/usr/bin/env python3
"""Learning curves of the shipped networks: validation error per parameter against samples seen
and against training wall time, across every training run that led to the shipped weights.

Each run is given as KIND:CSV:BATCH:SAMPLES_BEFORE:HOURS_BEFORE:HOURS_OF_RUN[:FIRST_STEP], where
CSV is the validation.csv a `train-*` run wrote, BATCH its batch size, SAMPLES_BEFORE and
HOURS_BEFORE what the weights it started from (`--init`, or the check-point a `--resume` continued)
had already seen, HOURS_OF_RUN the run's wall time (its steps are spread evenly over it), and
FIRST_STEP the step a resumed run started at (its CSV counts steps from the original start). Example (the command behind models/learning_curves.png):

    H=models/compact/history
    /usr/bin/python3 models/learning_curves.py -o models/learning_curves.png \
        estimator:$H/estimator_run1.csv:2:0:0:0.77 \
        estimator:$H/estimator_run2.csv:2:11200:0.77:1.34 \
        estimator:$H/estimator_run3_training_mix.csv:2:22952:2.11:1.28 \
        estimator:$H/estimator_run4_lobe_l1.csv:2:28540:3.39:2.58 \
        estimator:$H/estimator_run5_resumed.csv:2:46890:5.97:1.93:9175 \
        estimator:$H/estimator_run6_resumed.csv:2:58456:7.90:0.34:14958 \
        estimator:$H/estimator_run7_resumed.csv:2:63796:8.24:2.93:17628 \
        estimator:$H/estimator_run8_resumed.csv:2:140266:11.17:1.94:55863 \
        autoencoder:$H/autoencoder_run1.csv:4:0:0:1.05 \
        autoencoder:$H/autoencoder_run2.csv:4:51344:1.05:1.34 \
        autoencoder:$H/autoencoder_run3_training_mix.csv:4:84012:2.39:1.35 \
        autoencoder:$H/autoencoder_run4_lobe_l1.csv:4:105876:3.74:2.58 \
        autoencoder:$H/autoencoder_run5_resumed.csv:4:164356:6.32:1.93:14620 \
        autoencoder:$H/autoencoder_run6_resumed.csv:4:198264:8.25:0.34:23097 \
        autoencoder:$H/autoencoder_run7_resumed.csv:4:213136:8.59:2.93:26815 \
        autoencoder:$H/autoencoder_run8_resumed.csv:4:429860:11.52:1.94:80996

With --compare, each KIND is one run of an experiment and is drawn as one line in every
parameter's panel against materials seen, so runs from the same start can be read side by side
(models/rotation_experiments.png; its command is in models/README.md, "The rotation").

Runs 3 and 4 validate on materials drawn from the training mix (the same seeds, other families),
so their rows are not comparable one for one with runs 1 and 2: the step at 23 000 (estimator) and
84 000 (auto-encoder) materials is that change.
"""
import argparse
import csv
import sys

PARAMETERS = ["mse_diffuse", "mse_specular", "mse_normal", "mse_lobes", "mse_rotation", "mse_fresnel"]
LABELS = ["a_d", "a'_s", "n_s", "sigma", "alpha", "F0"]
# Written by runs from run 4 on: alpha over the anisotropic texels only (plotted where present).
OPTIONAL = [("mse_rotation_anisotropic", "alpha, anisotropic texels")]


def read_run(spec):
    try:
        fields = spec.split(":")
        kind, path, batch, samples_before, hours_before, hours = fields[:6]
        first_step = int(fields[6]) if len(fields) == 7 else 0
        if len(fields) not in (6, 7):
            raise ValueError
        batch, samples_before = int(batch), int(samples_before)
        hours_before, hours = float(hours_before), float(hours)
    except ValueError:
        sys.exit(f"learning_curves: '{spec}': expected KIND:CSV:BATCH:SAMPLES_BEFORE:HOURS_BEFORE:HOURS_OF_RUN[:FIRST_STEP]")
    try:
        with open(path, newline="") as f:
            rows = list(csv.DictReader(f))
    except OSError as e:
        sys.exit(f"learning_curves: {path}: {e.strerror}")
    if not rows:
        sys.exit(f"learning_curves: {path}: no validation rows")
    last_step = float(rows[-1]["step"]) - first_step
    points = []
    for r in rows:
        step = float(r["step"]) - first_step
        points.append({"samples": samples_before + step * batch,
                       "hours": hours_before + hours * step / last_step,
                       **{p: float(r[p]) for p in PARAMETERS + ["val_loss", "val_l1", "val_render"] if p in r},
                       **{p: float(r[p]) for p, _ in OPTIONAL if r.get(p) not in (None, "", "nan")}})
    return kind, points


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("runs", nargs="+", help="KIND:CSV:BATCH:SAMPLES_BEFORE:HOURS_BEFORE:HOURS_OF_RUN")
    ap.add_argument("-o", "--output", required=True, help="PNG to write")
    ap.add_argument("--compare", action="store_true",
                    help="one panel per parameter, one line per KIND (runs of one experiment)")
    args = ap.parse_args()
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    curves = {}
    for spec in args.runs:
        kind, points = read_run(spec)
        curves.setdefault(kind, []).extend(points)
    if args.compare:
        compare(curves, args.output, plt)
        return
    kinds = sorted(curves)
    fig, axes = plt.subplots(len(kinds), 2, figsize=(12, 4.2 * len(kinds)), squeeze=False)
    for row, kind in enumerate(kinds):
        points = sorted(curves[kind], key=lambda p: p["samples"])
        for col, x in enumerate(["samples", "hours"]):
            ax = axes[row][col]
            for p, label in zip(PARAMETERS, LABELS):
                ax.plot([q[x] for q in points], [q[p] for q in points], label=label, lw=1.2)
            for p, label in OPTIONAL:
                have = [q for q in points if p in q]
                if have:
                    ax.plot([q[x] for q in have], [q[p] for q in have], "--", label=label, lw=1.2)
            ax.set_yscale("log")
            ax.set_xlabel("materials seen" if x == "samples" else "training wall time (hours, 1 loaded core)")
            ax.set_ylabel("validation MSE (original ranges)")
            ax.set_title(f"{kind}: validation error per parameter")
            ax.grid(True, which="both", alpha=0.3)
            ax.legend(fontsize=8, ncol=3)
    fig.tight_layout()
    fig.savefig(args.output, dpi=90)
    print(f"wrote {args.output}")


def compare(curves, output, plt):
    """One panel per parameter (and the validation L1 and render loss), one line per run."""
    panels = list(zip(PARAMETERS, LABELS)) + OPTIONAL + [("val_l1", "validation L1 (network space)"),
                                                         ("val_render", "validation render loss")]
    fig, axes = plt.subplots(2, (len(panels) + 1) // 2, figsize=(4.2 * ((len(panels) + 1) // 2), 7.5), squeeze=False)
    for ax, (p, label) in zip(axes.flat, panels):
        for kind, points in sorted(curves.items()):
            have = sorted((q for q in points if p in q), key=lambda q: q["samples"])
            ax.plot([q["samples"] for q in have], [q[p] for q in have], label=kind, lw=1.1)
        ax.set_title(label, fontsize=10)
        ax.set_xlabel("materials seen", fontsize=8)
        ax.grid(True, alpha=0.3)
        ax.tick_params(labelsize=7)
    for ax in list(axes.flat)[len(panels):]:
        ax.axis("off")
    axes[0][0].legend(fontsize=7)
    fig.suptitle("validation MSE (original ranges) on the training-time validation materials", fontsize=10)
    fig.tight_layout()
    fig.savefig(output, dpi=90)
    print(f"wrote {output}")


if __name__ == "__main__":
    main()
