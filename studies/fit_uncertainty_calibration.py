#!/usr/bin/env python3
"""Fits pipeline/uncertainty.hpp's calibration (uncertainty_calibration_table) to the per-texel
records of anisocap_study_uncertainty_calibration --raw 1 --dump FILE, and reports the coverage of
the fitted table on other records (another seed set) with --test FILE.

For each parameter it searches scale, floor and relative (sd' = sqrt((scale sd)^2 + (floor +
relative |truth-free value|)^2), value = the captured value = truth + error) over a grid, minimising
the mean over the (family, light, images) groups of (within1 - 0.68)^2 + (within2 - 0.95)^2, so that
no family's coverage is traded for another's. Prints the C++ table and the coverage table.

    fit_uncertainty_calibration.py FIT.csv [--test TEST.csv] [--plot reliability.png]
"""
import argparse
import csv
import itertools
import sys
from collections import defaultdict

import numpy as np

PARAMETERS = ["a_d.r", "a_d.g", "a_d.b", "a_s.r", "a_s.g", "a_s.b", "sigma_x", "sigma_y", "F0", "n_x", "n_y", "alpha"]


def read(path):
    """{parameter: (error, sd, value, group index)} arrays, and the group names."""
    rows = defaultdict(lambda: ([], [], [], []))
    groups = {}
    with open(path) as f:
        for r in csv.DictReader(f):
            g = groups.setdefault((r["family"], r["light"], r["images"]), len(groups))
            e, s, t = float(r["error"]), float(r["sd"]), float(r["truth"])
            cols = rows[r["parameter"]]
            cols[0].append(e)
            cols[1].append(s)
            cols[2].append(t + e)  # the captured value: what the library sees
            cols[3].append(g)
    out = {k: tuple(np.asarray(c) for c in v) for k, v in rows.items()}
    return out, groups


def coverage(error, sd, groups, n_groups):
    """Per-group shares within 1 and 2 sd, and the overall shares."""
    a = np.abs(error)
    in1, in2 = (a <= sd).astype(float), (a <= 2 * sd).astype(float)
    count = np.bincount(groups, minlength=n_groups).astype(float)
    present = count > 0
    g1 = np.bincount(groups, in1, n_groups)[present] / count[present]
    g2 = np.bincount(groups, in2, n_groups)[present] / count[present]
    return g1, g2, in1.mean(), in2.mean()


def calibrated(sd, value, scale, floor, relative):
    return np.sqrt((scale * sd) ** 2 + (floor + relative * np.abs(value)) ** 2)


def fit(error, sd, value, groups, n_groups):
    scales = np.exp(np.linspace(np.log(0.2), np.log(4.0), 31))
    floors = [0.0, 0.001, 0.002, 0.005, 0.01, 0.02, 0.05]
    relatives = [0.0, 0.02, 0.05, 0.1, 0.2, 0.3, 0.5]
    best = None
    for scale, floor, relative in itertools.product(scales, floors, relatives):
        g1, g2, _, _ = coverage(error, calibrated(sd, value, scale, floor, relative), groups, n_groups)
        # Mean squared miss over groups; a small price on widening keeps the simplest table that fits.
        cost = np.mean((g1 - 0.68) ** 2 + (g2 - 0.95) ** 2) + 1e-4 * (abs(np.log(scale)) + 10 * floor + relative)
        if best is None or cost < best[0]:
            best = (cost, scale, floor, relative)
    return best[1:]


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("fit")
    ap.add_argument("--test")
    ap.add_argument("--plot")
    a = ap.parse_args()
    data, groups = read(a.fit)
    table = {}
    for k in PARAMETERS:
        if k not in data:
            table[k] = (1.0, 0.0, 0.0)
            continue
        e, s, v, g = data[k]
        table[k] = fit(e, s, v, g, len(groups))
    print("scale    {" + ", ".join(f"{table[k][0]:.3g}" for k in PARAMETERS) + "}")
    print("floor    {" + ", ".join(f"{table[k][1]:.3g}" for k in PARAMETERS) + "}")
    print("relative {" + ", ".join(f"{table[k][2]:.3g}" for k in PARAMETERS) + "}")
    sets = [("fit", a.fit)] + ([("test", a.test)] if a.test else [])
    print("\n| parameter | " + " | ".join(f"{n}: raw 1 sd | raw 2 sd | calibrated 1 sd | calibrated 2 sd | worst group 1 sd | worst group 2 sd" for n, _ in sets) + " |")
    print("|---" * (1 + 6 * len(sets)) + "|")
    loaded = [(n, read(p)) for n, p in sets]
    curves = {}
    for k in PARAMETERS:
        cells = []
        for n, (d, gr) in loaded:
            if k not in d:
                cells += ["-"] * 6
                continue
            e, s, v, g = d[k]
            _, _, r1, r2 = coverage(e, s, g, len(gr))
            cs = calibrated(s, v, *table[k])
            g1, g2, c1, c2 = coverage(e, cs, g, len(gr))
            w1 = g1[np.argmax(np.abs(g1 - 0.68))]
            w2 = g2[np.argmax(np.abs(g2 - 0.95))]
            cells += [f"{100 * r1:.0f}%", f"{100 * r2:.0f}%", f"{100 * c1:.0f}%", f"{100 * c2:.0f}%", f"{100 * w1:.0f}%", f"{100 * w2:.0f}%"]
            if n == sets[-1][0]:
                z = np.abs(e) / np.maximum(cs, 1e-12)
                curves[k] = z
        print(f"| {k} | " + " | ".join(cells) + " |")
    if a.plot:
        import matplotlib
        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
        from math import erf, sqrt
        fig, ax = plt.subplots(figsize=(6, 5))
        levels = np.linspace(0, 3, 61)
        ax.plot([0, 1], [0, 1], "k--", lw=1, label="calibrated Gaussian")
        for k, z in curves.items():
            expected = [erf(t / sqrt(2)) for t in levels]
            observed = [(z <= t).mean() for t in levels]
            ax.plot(expected, observed, lw=1, label=k)
        ax.set_xlabel("expected share within t sd (Gaussian)")
        ax.set_ylabel("observed share within t sd")
        ax.set_title(f"Per-texel uncertainty, {sets[-1][0]} captures")
        ax.legend(fontsize=7, ncol=2)
        fig.tight_layout()
        fig.savefig(a.plot, dpi=110)


if __name__ == "__main__":
    sys.exit(main())
