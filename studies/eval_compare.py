#!/usr/bin/env python3
"""Set alpha against set beta, material by material, from `anisocap eval` table.csv files.

The eval's table gives means over materials; a handful of hard materials can dominate a mean (one
spun metal whose F0 is off by 0.3 outweighs ten good fabrics). This script pairs the two sets on
the same materials and prints, per parameter and stage, the means, the medians and how many
materials each set wins, so a claim "alpha beats beta" can be read three ways.

usage: python3 studies/eval_compare.py TABLE.csv [TABLE.csv ...] [--images 12]
Standard library only.
"""
import argparse
import csv
import statistics
import sys

PARAMETERS = [("diffuse", "a_d"), ("specular", "a_s"), ("normal", "n_s"), ("lobes", "sigma"),
              ("rotation", "alpha"), ("fresnel", "F0"), ("novel_view_loss", "novel view")]


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("tables", nargs="+")
    parser.add_argument("--images", type=int, default=12, help="input count N to compare at")
    args = parser.parse_args()
    rows = {}
    for path in args.tables:
        with open(path, newline="") as f:
            for r in csv.DictReader(f):
                if int(r["images"]) != args.images:
                    continue
                rows[(r["seed"], r["set"], r["stage"])] = r
    stages = sorted({k[2] for k in rows}, key=lambda s: s != "fine-tuned")
    print(f"N = {args.images}: set alpha against set beta on the same materials\n")
    print("| stage | parameter | materials | alpha mean | beta mean | alpha median | beta median | alpha wins | beta wins |")
    print("|---|---|---|---|---|---|---|---|---|")
    for stage in stages:
        seeds = sorted({k[0] for k in rows if k[2] == stage and (k[0], "alpha", stage) in rows and (k[0], "beta", stage) in rows})
        if not seeds:
            continue
        for key, name in PARAMETERS:
            a = [float(rows[(s, "alpha", stage)][key]) for s in seeds]
            b = [float(rows[(s, "beta", stage)][key]) for s in seeds]
            wins_a = sum(x < y for x, y in zip(a, b))
            wins_b = sum(y < x for x, y in zip(a, b))
            print(f"| {stage} | {name} | {len(seeds)} | {statistics.mean(a):.4g} | {statistics.mean(b):.4g} | "
                  f"{statistics.median(a):.4g} | {statistics.median(b):.4g} | {wins_a} | {wins_b} |")
    if not rows:
        sys.exit(f"no rows with images = {args.images} in {', '.join(args.tables)}")


if __name__ == "__main__":
    main()
