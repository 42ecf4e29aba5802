#!/usr/bin/env bash
# Capture time per program and instruction set: each LABEL=COMMAND captures the same synthetic
# material (anisocap demo's fabric), REPEATS rounds interleaved so that the machine's load falls on
# every variant alike; prints the median seconds of the estimate, fine-tune and refine stages and of
# all stages, each variant's ratio to the first, and the median final loss.
#   bench/kernel_isas.sh SIZE REPEATS LABEL=COMMAND [LABEL=COMMAND ...]
# e.g. bench/kernel_isas.sh 128 5 "native=build/anisocap" "v4 module=build-pkg/anisocap --kernel-isa x86-64-v4"
set -euo pipefail
size=$1 repeats=$2
shift 2
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
first_program=${1#*=}
first_program=${first_program%% *}
"$first_program" synthesize --width "$size" --height "$size" -o "$work/input" >/dev/null
for ((round = 0; round < repeats; ++round)); do
  index=0
  for variant in "$@"; do
    command=${variant#*=}
    # shellcheck disable=SC2086  # COMMAND is a program and its options
    $command capture "$work/input/capture.json" --no-also-models --no-view -o "$work/out-$index-$round" >/dev/null 2>&1 ||
      { echo "the capture of '$variant' failed"; exit 1; }
    index=$((index + 1))
  done
done
python3 - "$work" "$repeats" "$@" <<'EOF'
import json, statistics, sys
work, repeats, variants = sys.argv[1], int(sys.argv[2]), sys.argv[3:]
def stage_seconds(report, name):
    return sum(s["seconds"] for s in report["stages"] if s["name"] == name)
rows = []
for index, variant in enumerate(variants):
    runs = [json.load(open(f"{work}/out-{index}-{r}/report.json")) for r in range(repeats)]
    median = lambda f: statistics.median(f(r) for r in runs)
    rows.append((variant.split("=")[0], median(lambda r: stage_seconds(r, "estimate")),
                 median(lambda r: stage_seconds(r, "finetune")), median(lambda r: stage_seconds(r, "refine")),
                 median(lambda r: r["timings"]["stages"]), median(lambda r: r["loss"])))
print(f"| variant | estimate s | fine-tune s | refine s | all stages s | ratio to {rows[0][0]} | final loss |")
print("|---|---|---|---|---|---|---|")
for name, e, f, r, t, loss in rows:
    print(f"| {name} | {e:.2f} | {f:.2f} | {r:.2f} | {t:.2f} | {t / rows[0][4]:.3f} | {loss:.5f} |")
EOF
