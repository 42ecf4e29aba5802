#!/usr/bin/env python3
"""studies/eval_compare.py --weights --second-above: a second table holding only the materials whose
first fit ends above the threshold is compared as if it held all of them, the others taking the
first table's rows; a missing material above the threshold is refused.

usage: check_eval_compare.py SOURCE_DIR   (standard library only)
"""
import csv
import os
import subprocess
import sys
import tempfile

HEADER = ["material", "seed", "width", "height", "images", "set", "stage", "diffuse", "specular", "normal", "lobes",
          "rotation", "rotation_anisotropic", "fresnel", "novel_view_loss", "seconds", "family", "photo_loss",
          "estimate_photo_loss", "encode_photo_loss"]


def write_table(path, materials):
    """materials: [(seed, novel_view_loss, photo_loss)]; one fine-tuned and one refined row each."""
    with open(path, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(HEADER)
        for i, (seed, novel, photo) in enumerate(materials):
            for stage, scale in (("fine-tuned", 2.0), ("refined", 1.0)):
                w.writerow([i, seed, 256, 256, 12, "alpha", stage, 0.001, 0.002, 0.003, 0.004, 0.005, 0.005, 0.006,
                            novel * scale, 10.0, "twill", photo * scale, 1.0, 1.2])


def run(script, *args):
    return subprocess.run([sys.executable, script, *args], capture_output=True, text=True)


def novel_view_means(output, stage):
    """(materials, first mean, second mean, first wins, second wins) of the novel-view row of `stage`
    in the comparison table."""
    for line in output.splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if len(cells) == 9 and cells[0] == stage and cells[1] == "novel view":
            return int(cells[2]), float(cells[3]), float(cells[4]), int(cells[7]), int(cells[8])
    raise AssertionError(f"no {stage} novel-view row in:\n{output}")


def main():
    script = os.path.join(sys.argv[1], "studies", "eval_compare.py")
    failures = []

    def check(condition, what):
        if not condition:
            failures.append(what)

    with tempfile.TemporaryDirectory() as folder:
        first, tried, incomplete = (os.path.join(folder, n) for n in ("first.csv", "tried.csv", "incomplete.csv"))
        # Four materials; two fit above 0.1 and were run again, one of them better.
        write_table(first, [(1, 0.02, 0.05), (2, 0.08, 0.20), (3, 0.04, 0.09), (4, 0.06, 0.15)])
        write_table(tried, [(2, 0.05, 0.16), (4, 0.06, 0.15)])
        write_table(incomplete, [(2, 0.05, 0.16)])

        r = run(script, "--weights", first, tried, "--second-above", "0.1")
        check(r.returncode == 0, f"--second-above 0.1 failed: {r.stderr}")
        if r.returncode == 0:
            count, mean_a, mean_b, wins_a, wins_b = novel_view_means(r.stdout, "refined")
            check(count == 4, f"compared {count} materials, not all 4")
            check(abs(mean_a - 0.05) < 1e-9, f"first mean {mean_a}, expected 0.05")
            check(abs(mean_b - (0.02 + 0.05 + 0.04 + 0.06) / 4) < 1e-9, f"second mean {mean_b}, expected 0.0425")
            check((wins_a, wins_b) == (0, 1), f"wins {wins_a}, {wins_b}: expected 0 and 1")
            check("holds 2 materials; 2 with a first refined photo_loss at most 0.1" in r.stdout,
                  f"no count of the filled materials in:\n{r.stdout}")

        # Without the option the comparison stays on the shared materials.
        r = run(script, "--weights", first, tried)
        check(r.returncode == 0 and novel_view_means(r.stdout, "refined")[0] == 2, "without --second-above: not 2 materials")

        # Material 4 fits to 0.15 > 0.1 and its second run is missing: refused, naming it.
        r = run(script, "--weights", first, incomplete, "--second-above", "0.1")
        check(r.returncode != 0 and "material 4" in r.stderr, f"a missing material above L was not refused: {r.stderr}")

        # With a higher threshold it is not expected to have run.
        r = run(script, "--weights", first, incomplete, "--second-above", "0.15")
        check(r.returncode == 0 and novel_view_means(r.stdout, "refined")[0] == 4, f"--second-above 0.15: {r.stderr}")

        r = run(script, "--weights", first, tried, "--second-above", "0.1", "--select")
        check(r.returncode != 0 and "--second-above" in r.stderr, "--second-above with --select was not refused")

    for f in failures:
        print("FAIL:", f)
    print("eval_compare --second-above: " + ("passed" if not failures else f"{len(failures)} checks failed"))
    return 1 if failures else 0


if __name__ == "__main__":
    sys.exit(main())
