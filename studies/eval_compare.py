#!/usr/bin/env python3
"""Material-by-material comparisons of `anisocap eval` table.csv files.

The eval's table gives means over materials; a handful of hard materials can dominate a mean (one
spun metal whose F0 is off by 0.3 outweighs ten good fabrics). This script pairs two sides on the
same materials and prints, per parameter and stage, the means, the medians and how many materials
each side wins, so a claim "A beats B" can be read three ways. The two sides are

- set alpha against set beta, from the rows of all the tables given (the default), or
- with --weights, the first table against the second (two evals of one protocol with different
  weights, or different options), on the materials both have finished, for one --set.

With --weights --select, a third side is added: per material, the result of whichever table's
refined stage fits the input photographs better (the lower photo_loss column, which evals write
since photo_loss was added), i.e. what a capture that ran both weight sets and kept the better fit
would get without knowing the truth. It is compared with the first table, and the choices are
counted per family. With --above L the second table counts only for the materials whose first
refined photo_loss is above L (what `--also-models-above L` does: the second weights run only
after a poor first fit); the number of such second runs is printed. With --ratio R it counts
only where, besides, the first table's auto-encoder projection of the estimate fits the photographs
at least R times worse than the estimate itself (encode_photo_loss / estimate_photo_loss >= R,
columns evals write since they were added): the condition the residual start's second run
(`--also-residual-ratio`) adds to the loss threshold, one that noise hardly moves.

With --weights --second-above L, the second table may hold only the materials whose first refined
photo_loss is above L: an `eval --also-models DIR` run on just the materials where the second folder
is tried (`--first-seed S --count 1` each). Under `--also-models-above L` a capture whose first fit
ends at or below L keeps that fit, so the materials the second table lacks take the first table's
rows; a lacking material whose first photo_loss is above L is an error, since its second run is
missing. This sizes `--also-models` on a whole sample at the cost of its second runs alone, and is
exact where the first run is reproducible (the eval's log prints the first fit's loss to compare).

usage: python3 studies/eval_compare.py TABLE.csv [TABLE.csv ...] [--images 12]
       python3 studies/eval_compare.py --weights OLD.csv NEW.csv [--set alpha] [--images 12] [--select [--above L] [--ratio R]]
       python3 studies/eval_compare.py --weights OLD.csv TRIED.csv --second-above L [--set alpha] [--images 12]
Standard library only.
"""
import argparse
import csv
import statistics
import sys

PARAMETERS = [("diffuse", "a_d"), ("specular", "a_s"), ("normal", "n_s"), ("lobes", "sigma"),
              ("rotation", "alpha"), ("fresnel", "F0"), ("novel_view_loss", "novel view")]


def read_rows(path, images):
    """{(seed, set, stage): row} of one table at input count `images`."""
    rows = {}
    with open(path, newline="") as f:
        for r in csv.DictReader(f):
            if int(r["images"]) == images:
                rows[(r["seed"], r["set"], r["stage"])] = r
    return rows


def print_comparison(side_a, side_b, name_a, name_b):
    """side_x: {(seed, stage): row}; one Markdown row per stage and parameter on the shared seeds."""
    stages = sorted({k[1] for k in side_a}, key=lambda s: s != "fine-tuned")
    print(f"| stage | parameter | materials | {name_a} mean | {name_b} mean | {name_a} median | {name_b} median | "
          f"{name_a} wins | {name_b} wins |")
    print("|---|---|---|---|---|---|---|---|---|")
    for stage in stages:
        seeds = sorted(s for s, st in side_a if st == stage and (s, stage) in side_b)
        if not seeds:
            continue
        for key, name in PARAMETERS:
            a = [float(side_a[(s, stage)][key]) for s in seeds]
            b = [float(side_b[(s, stage)][key]) for s in seeds]
            wins_a = sum(x < y for x, y in zip(a, b))
            wins_b = sum(y < x for x, y in zip(a, b))
            print(f"| {stage} | {name} | {len(seeds)} | {statistics.mean(a):.4g} | {statistics.mean(b):.4g} | "
                  f"{statistics.median(a):.4g} | {statistics.median(b):.4g} | {wins_a} | {wins_b} |")


def projection_ratio(row):
    """How many times worse the auto-encoder projection of the estimate fits the photographs than
    the estimate itself, from one row of a table with the estimate_photo_loss and encode_photo_loss
    columns."""
    if not row.get("estimate_photo_loss") or not row.get("encode_photo_loss"):
        sys.exit("--ratio needs the estimate_photo_loss and encode_photo_loss columns in the first table")
    return float(row["encode_photo_loss"]) / float(row["estimate_photo_loss"])


def fill_untried(side_a, side_b, above):
    """Gives side_b the rows of side_a for the materials side_b lacks, each of which must have a first
    refined photo_loss at most `above` (materials a `--also-models-above` run keeps without a second
    run); returns how many materials were filled."""
    filled = set()
    for (s, stage), row in side_a.items():
        if (s, stage) in side_b:
            continue
        refined = side_a.get((s, "refined"))
        if refined is None or not refined.get("photo_loss"):
            sys.exit(f"--second-above: material {s} has no refined photo_loss in the first table")
        if float(refined["photo_loss"]) > above:
            sys.exit(f"--second-above {above:g}: material {s} fits to {float(refined['photo_loss']):.4g} in the first "
                     f"table, above {above:g}, and the second table lacks its row for stage {stage}")
        side_b[(s, stage)] = row
        filled.add(s)
    return len(filled)


def print_selection(side_a, side_b, above=0.0, ratio=0.0):
    """The per-material choice by the refined stage's photo_loss, against the first side; the second
    side is tried only where the first side's refined photo_loss is above `above` and its projection
    ratio (projection_ratio) is at least `ratio`."""
    seeds = sorted(s for s, st in side_a if st == "refined" and (s, "refined") in side_b)
    if any(not side[(s, "refined")].get("photo_loss") for side in (side_a, side_b) for s in seeds):
        sys.exit("--select needs the photo_loss column in both tables (evals written since it was added)")
    chosen, picks, tried = {}, {}, 0
    for s in seeds:
        first_loss = float(side_a[(s, "refined")]["photo_loss"])
        trigger = first_loss > above and (ratio == 0.0 or projection_ratio(side_a[(s, "refined")]) >= ratio)
        tried += trigger
        second = trigger and float(side_b[(s, "refined")]["photo_loss"]) < first_loss
        source = side_b if second else side_a
        family = side_a[(s, "refined")]["family"]
        picks.setdefault(family, [0, 0])[1 if second else 0] += 1
        for stage in ("fine-tuned", "refined"):
            if (s, stage) in source:
                chosen[(s, stage)] = source[(s, stage)]
    print(f"\nChoice by the refined stage's photo_loss, the second tried where the first is above {above:g}"
          + (f" and its projection ratio at least {ratio:g}" if ratio else "") + " "
          f"({tried} of {len(seeds)} materials; per family: materials taking the first, the second):",
          ", ".join(f"{f} {a}/{b}" for f, (a, b) in sorted(picks.items())))
    print()
    print_comparison(side_a, chosen, "first", "chosen")
    print()
    print_comparison(side_b, chosen, "second", "chosen")


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("tables", nargs="+")
    parser.add_argument("--images", type=int, default=12, help="input count N to compare at")
    parser.add_argument("--weights", action="store_true", help="compare the first table against the second")
    parser.add_argument("--set", default="alpha", help="the configuration set compared with --weights")
    parser.add_argument("--select", action="store_true",
                        help="with --weights: also the per-material choice of the table whose refined stage has the lower photo_loss")
    parser.add_argument("--above", type=float, default=0.0,
                        help="with --select: try the second table only where the first's refined photo_loss is above this")
    parser.add_argument("--second-above", type=float, default=None, metavar="L",
                        help="with --weights: the materials the second table lacks take the first's rows, where the "
                             "first's refined photo_loss is at most L (an error above it)")
    parser.add_argument("--ratio", type=float, default=0.0,
                        help="with --select: try the second table only where the first's encode_photo_loss / "
                             "estimate_photo_loss is at least this (0: everywhere)")
    args = parser.parse_args()
    if (args.above != 0.0 or args.ratio != 0.0) and not args.select:
        sys.exit("--above and --ratio go with --select")
    if args.second_above is not None and (not args.weights or args.select):
        sys.exit("--second-above goes with --weights, without --select")
    if args.weights:
        if len(args.tables) != 2:
            sys.exit("--weights compares exactly two tables")
        a, b = (read_rows(p, args.images) for p in args.tables)
        side_a = {(s, st): r for (s, cs, st), r in a.items() if cs == args.set}
        side_b = {(s, st): r for (s, cs, st), r in b.items() if cs == args.set}
        if not side_a or not side_b:
            sys.exit(f"no rows with images = {args.images} and set {args.set} in one of {', '.join(args.tables)}")
        filled = fill_untried(side_a, side_b, args.second_above) if args.second_above is not None else None
        print(f"N = {args.images}, set {args.set}: {args.tables[0]} (first) against {args.tables[1]} (second) "
              f"on the materials both have\n")
        if filled is not None:
            tried = len({s for s, _ in side_b}) - filled
            print(f"The second table holds {tried} materials; {filled} with a first refined photo_loss at most "
                  f"{args.second_above:g} take the first table's rows\n")
        print_comparison(side_a, side_b, "first", "second")
        if args.select:
            print_selection(side_a, side_b, args.above, args.ratio)
        return
    rows = {}
    for path in args.tables:
        rows.update(read_rows(path, args.images))
    if not rows:
        sys.exit(f"no rows with images = {args.images} in {', '.join(args.tables)}")
    print(f"N = {args.images}: set alpha against set beta on the same materials\n")
    side = {name: {(s, st): r for (s, cs, st), r in rows.items() if cs == name} for name in ("alpha", "beta")}
    print_comparison(side["alpha"], side["beta"], "alpha", "beta")


if __name__ == "__main__":
    main()
