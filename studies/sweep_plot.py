#!/usr/bin/env python3
"""Run time against error from studies/sweep.cpp's CSV: a plot with the Pareto front and Markdown tables.

For every configuration (input count, path, fine-tune steps / early stopping, refine variant) the
errors and seconds are averaged over the materials (mean error, median seconds). The Pareto front
is the set of configurations that no other configuration beats on both run time and novel-view
error. Writes PNG (run time against novel-view error and against each per-parameter error) and
prints Markdown: the front, the paper-default reference and the cheapest configuration that
matches its novel-view error, the effect of each skip at one starting point, and a NaN/Inf count.

usage: studies/sweep_plot.py studies/results/sweep_256.csv [--png studies/results/sweep_256.png]
"""
import argparse
import csv
import math
import statistics
import sys
from collections import OrderedDict

PARAMS = [("novel_view_loss", "novel-view image loss"), ("diffuse", "a_d MSE"), ("specular", "a'_s MSE"),
          ("normal", "n_s MSE"), ("lobes", "sigma MSE"), ("rotation", "alpha MSE (mod pi)"), ("fresnel", "F0 MSE")]


PAPER_LR = 7.5e-4


def precision_of(r):
    """The row's network precision (CSVs written before the column existed are FP32)."""
    return r.get("network_precision") or "fp32"


def key_of(r):
    """(N, path, fine-tune steps, stop, refine variant, lr, (warm-up, half-life, crop), network precision)."""
    lr = float(r.get("finetune_lr") or PAPER_LR)
    schedule = tuple(int(r.get(c) or 0) for c in ("finetune_warmup", "finetune_half_life", "finetune_crop"))
    return (int(r["images"]), r["path"], int(r["finetune_steps"]), float(r["finetune_stop"]), r["refine"], lr, schedule,
            precision_of(r))


def label(k):
    n, path, ft, stop, ref, lr, (warmup, half_life, crop), precision = k
    if path == "refine-only":
        return f"N={n} no networks, refine {ref}"
    ft_text = f"fine-tune stop {stop:g}" if stop > 0 else f"fine-tune {ft}"
    extra = []
    if abs(lr - PAPER_LR) > 1e-9:
        extra.append(f"lr {lr:g}")
    if warmup:
        extra.append(f"warm-up {warmup}")
    if half_life:
        extra.append(f"half-life {half_life}")
    if crop:
        extra.append(f"crop {crop}")
    if precision != "fp32":
        extra.append(precision)
    if extra:
        ft_text += " (" + ", ".join(extra) + ")"
    return f"N={n} {ft_text}, refine {ref}"


def pareto(points):
    """Indices of points (seconds, error) not dominated by any other."""
    order = sorted(range(len(points)), key=lambda i: (points[i][0], points[i][1]))
    front, best = [], float("inf")
    for i in order:
        if points[i][1] < best:
            front.append(i)
            best = points[i][1]
    return front


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("csv", nargs="+", help="one or more CSVs of studies/sweep.cpp (same materials)")
    ap.add_argument("--png", default=None)
    ap.add_argument("--finetune-step-ms", type=float, default=23.0,
                    help="quiet-machine fine-tune step (studies/README.md, capture pipeline) for the step-count cost model")
    ap.add_argument("--refine-step-ms", type=float, default=9.3, help="quiet-machine refine step, same source")
    ap.add_argument("--crop-step-ms", type=float, default=6.9,
                    help="quiet-machine fine-tune step on a crop of 4 latent cells (studies/finetune_step.cpp)")
    ap.add_argument("--bf16-finetune-step-ms", type=float, default=None,
                    help="the model's whole-tile fine-tune step with bf16 networks (needed for bf16 rows unless --x measured; "
                         "bf16 crop steps have no figure)")
    ap.add_argument("--all", action="store_true", help="also print every configuration, not only the front")
    ap.add_argument("--x", choices=["model", "measured"], default="model",
                    help="seconds on the plot's x axis and for the front: the step-count model (load-independent, "
                         "comparable across CSVs) or the measured median")
    args = ap.parse_args()
    rows = [r for f in args.csv for r in csv.DictReader(open(f))]
    if not rows:
        sys.exit(f"{args.csv}: no rows")
    materials = sorted({r["material"] for r in rows}, key=int)
    precisions = sorted({precision_of(r) for r in rows})

    def finetune_step_ms(crop, precision):
        """The model's ms per fine-tune step; NaN (not priced) where it has no figure: bf16 crop steps, and bf16
        whole-tile steps without --bf16-finetune-step-ms."""
        if precision == "bf16":
            return float("nan") if crop or args.bf16_finetune_step_ms is None else args.bf16_finetune_step_ms
        return args.crop_step_ms if crop else args.finetune_step_ms
    if args.x == "model" and any(math.isnan(finetune_step_ms(int(r.get("finetune_crop") or 0), precision_of(r))) for r in rows):
        sys.exit("bf16 rows: the step-count model prices them only as whole-tile steps with --bf16-finetune-step-ms; "
                 "plot them with --x measured")
    groups = OrderedDict()
    for r in rows:
        groups.setdefault(key_of(r), []).append(r)
    def row_model(r):
        """The step-count model's seconds for one row."""
        step_ms = finetune_step_ms(int(r.get("finetune_crop") or 0), precision_of(r))
        return (float(r["finetune_steps_run"]) * step_ms +
                float(r["refine_steps_run"]) * float(r["evaluated_fraction"]) * args.refine_step_ms) / 1000.0

    # Only configurations measured on every material.
    configs = [k for k, g in groups.items() if len({r["material"] for r in g}) == len(materials)]
    stats = {}
    for k in configs:
        g = groups[k]
        s = {p: statistics.fmean(float(r[p]) for r in g) for p, _ in PARAMS}
        s["seconds"] = statistics.median(float(r["seconds"]) for r in g)
        s["mean_seconds"] = statistics.fmean(float(r["seconds"]) for r in g)
        s["evaluated"] = statistics.fmean(float(r["evaluated_fraction"]) for r in g)
        s["ft_run"] = statistics.fmean(float(r["finetune_steps_run"]) for r in g)
        s["refine_run"] = statistics.fmean(float(r["refine_steps_run"]) for r in g)
        # Step-count cost model: independent of the machine's load while the sweep ran.
        step_ms = finetune_step_ms(k[6][2], k[7])
        s["model_seconds"] = (s["ft_run"] * step_ms +
                              s["refine_run"] * s["evaluated"] * args.refine_step_ms) / 1000.0
        stats[k] = s
    bad = sum(1 for r in rows if r["finite"] != "1")
    print(f"{len(rows)} rows, {len(materials)} materials, {len(configs)} configurations; rows with NaN/Inf in the maps: {bad}\n")

    X = "model_seconds" if args.x == "model" else "seconds"
    x_name = "step-count model seconds" if args.x == "model" else "measured seconds (median)"
    pts = [(stats[k][X], stats[k]["novel_view_loss"]) for k in configs]
    front = [configs[i] for i in pareto(pts)]
    print(f"Pareto front ({x_name} per material against mean novel-view loss):\n")
    print("| configuration | fine-tune steps run | refine steps run | model s | measured s (median) | novel-view loss | a_d | a'_s | n_s | sigma | alpha | F0 |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|")
    for k in front:
        s = stats[k]
        model = "-" if math.isnan(s["model_seconds"]) else f"{s['model_seconds']:.1f}"  # NaN: not priced
        print(f"| {label(k)} | {s['ft_run']:.0f} | {s['refine_run']:.0f} | {model} | {s['seconds']:.1f} | {s['novel_view_loss']:.4f} | {s['diffuse']:.3g} | "
              f"{s['specular']:.3g} | {s['normal']:.3g} | {s['lobes']:.3g} | {s['rotation']:.3g} | {s['fresnel']:.3g} |")

    if args.all:
        print("\nEvery configuration:\n")
        print("| configuration | measured s (median) | novel-view loss |")
        print("|---|---|---|")
        for k in sorted(configs, key=lambda k: (k[:6], k[7])):
            print(f"| {label(k)} | {stats[k]['seconds']:.1f} | {stats[k]['novel_view_loss']:.4f} |")

    ref_key = (12, "networks", 5000, 0.0, "500", PAPER_LR, (0, 0, 0), "fp32")
    if ref_key in stats:
        ref = stats[ref_key]
        print(f"\nPaper-default step counts ({label(ref_key)}): {ref['seconds']:.1f} s, novel-view loss {ref['novel_view_loss']:.4f}.")
        match = [k for k in configs if stats[k]["novel_view_loss"] <= ref["novel_view_loss"]]
        if match:
            best = min(match, key=lambda k: stats[k]["model_seconds"])
            b = stats[best]
            print(f"Cheapest configuration at or below that novel-view loss: {label(best)}: {b['seconds']:.1f} s, "
                  f"loss {b['novel_view_loss']:.4f}: {ref['seconds'] / b['seconds']:.1f}x less run time measured "
                  f"({ref['model_seconds'] / max(b['model_seconds'], 1e-9):.1f}x by the step-count model: "
                  f"{ref['model_seconds']:.0f} s against {b['model_seconds']:.0f} s at {args.finetune_step_ms:g} ms per fine-tune "
                  f"and {args.refine_step_ms:g} ms per refine step).")
            best_m = min(match, key=lambda k: stats[k]["seconds"])
            if best_m != best:
                bm = stats[best_m]
                print(f"Cheapest by measured time: {label(best_m)}: {bm['seconds']:.1f} s measured, loss {bm['novel_view_loss']:.4f}: "
                      f"{ref['model_seconds'] / max(bm['model_seconds'], 1e-9):.1f}x by the model, {ref['seconds'] / bm['seconds']:.1f}x measured.")
            # Per material: same comparison, to show it is not an average effect.
            per = []
            for m in materials:
                r_ref = next(r for r in groups[ref_key] if r["material"] == m)
                r_b = next(r for r in groups[best] if r["material"] == m)
                per.append((row_model(r_ref) / max(row_model(r_b), 1e-9), float(r_b["novel_view_loss"]) <= float(r_ref["novel_view_loss"])))
            print(f"Per material: speed-up by the step-count model {min(p[0] for p in per):.1f}x to {max(p[0] for p in per):.1f}x; "
                  f"novel-view loss at or below the reference on {sum(p[1] for p in per)} of {len(per)} materials.")

    # Effect of each skip at the starting points that have every refine variant.
    starts = sorted({k[:4] + k[5:] for k in configs if k[4] == "500 freeze 1e-2"}, key=str)
    for start6 in starts:
        start = start6[:4]
        lr = start6[4:]
        base = start + ("500",) + lr
        if base not in stats:
            continue
        b = stats[base]
        print(f"\nSkips on the refine stage, starting from {label(base).rsplit(',', 1)[0]} (refine alone; ratios against plain refine 500):\n")
        print("| refine variant | texel-steps evaluated | refine seconds ratio | novel-view loss | ratio | a_d | a'_s | n_s | sigma | alpha | F0 |")
        print("|---|---|---|---|---|---|---|---|---|---|---|")
        none = stats.get(start + ("none",) + lr)
        for k in configs:
            if k[:4] != start or k[5:] != lr or k[4] == "none":
                continue
            s = stats[k]
            ratio = (s["seconds"] - none["seconds"]) / max(b["seconds"] - none["seconds"], 1e-9) if none else float("nan")
            print(f"| {k[4]} | {s['evaluated']:.2f} | {ratio:.2f} | {s['novel_view_loss']:.4f} | {s['novel_view_loss'] / b['novel_view_loss']:.2f} | "
                  f"{s['diffuse']:.3g} | {s['specular']:.3g} | {s['normal']:.3g} | {s['lobes']:.3g} | {s['rotation']:.3g} | {s['fresnel']:.3g} |")

    if args.png:
        import matplotlib
        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
        fig, axes = plt.subplots(2, 4, figsize=(20, 9.5))
        colours = {(12, "fp32"): "tab:blue", (8, "fp32"): "tab:orange", (12, "bf16"): "tab:green", (8, "bf16"): "tab:purple"}
        for ax, (p, name) in zip(axes.flat, PARAMS):
            xs = [stats[k][X] for k in configs]
            ys = [stats[k][p] for k in configs]
            for n in (12, 8):
                for precision in precisions:
                    sel = [i for i, k in enumerate(configs) if k[0] == n and k[7] == precision]
                    if not sel:
                        continue
                    name_of = f"N = {n}" + (f", {precision}" if len(precisions) > 1 else "")
                    ax.scatter([xs[i] for i in sel], [ys[i] for i in sel], s=18, c=colours[(n, precision)], alpha=0.7,
                               marker="o" if precision == "fp32" else "^", label=name_of)
            pf = pareto(list(zip(xs, ys)))
            ax.plot([xs[i] for i in pf], [ys[i] for i in pf], "k-", lw=1.2, label="Pareto front")
            ax.scatter([xs[i] for i in pf], [ys[i] for i in pf], s=40, facecolors="none", edgecolors="k")
            if ref_key in stats:
                ax.scatter([stats[ref_key][X]], [stats[ref_key][p]], s=120, marker="*", c="tab:red", label="paper step counts")
            ax.set_xscale("log")
            ax.set_yscale("log")
            ax.set_xlabel(x_name + " per material")
            ax.set_ylabel(name + " (mean)")
            ax.grid(True, which="both", alpha=0.3)
        axes.flat[0].legend(fontsize=8)
        axes.flat[-1].axis("off")
        knobs = "fine-tune steps, early stopping, refine variant, N" + (", network precision" if len(precisions) > 1 else "")
        axes.flat[-1].text(0.0, 0.5, f"{len(materials)} procedural materials, 256 x 256, set alpha\n"
                           f"compact preset; one point per configuration\n({knobs})",
                           fontsize=11, va="center")
        fig.suptitle("anisocap: run time against error (studies/sweep.cpp)")
        fig.tight_layout()
        tmp = args.png + ".tmp.png"
        fig.savefig(tmp, dpi=90)
        import os
        os.replace(tmp, args.png)
        print(f"\nplot: {args.png}")


if __name__ == "__main__":
    main()
