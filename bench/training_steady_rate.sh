#!/bin/sh
# Steady-state training rate (materials/s) of `anisocap train-autoencoder` at several batch sizes:
# a run of N1 steps and a run of N2 steps, both from a fresh start, and the rate
# batch x (N2 - N1) / (time of N2 - time of N1), so the start-up (reading, first touches of new
# memory: about 20 s at batch 64) cancels out. The batches' runs are
# interleaved, REPEATS rounds; compare the rows of one run of this script.
#   sh bench/training_steady_rate.sh [PROGRAM] [BATCHES] [REPEATS] [MATERIALS]
# PROGRAM: default build/anisocap. BATCHES: default "8 64". REPEATS: default 2. MATERIALS: the
# materials the steps between the two runs draw (default 384): N1 = max(3, 64 / batch),
# N2 = N1 + MATERIALS / batch. Options: those of models/README.md runs 64-65 (compact-fine-512,
# 128 x 128, their loss weights); THREADS in the environment sets --threads (default 2).
program=${1:-build/anisocap}
batches=${2:-8 64}
repeats=${3:-2}
materials=${4:-384}
threads=${THREADS:-2}
out=$(mktemp -d)
trap 'rm -rf "$out"' EXIT
seconds() {  # seconds for $2 steps at batch $1
  rm -rf "$out/run"
  start=$(date +%s.%N)
  "$program" --threads "$threads" train-autoencoder --preset compact-fine-512 --out "$out/run" \
    --render-weight 0.1 --sigma-weight 50 --mse-weight 100 --diffuse-weight 3 --normal-weight 2 \
    --materials training --size 128 --batch "$1" --lr 1e-5 --steps "$2" --seed 9 \
    --validate-every 1000000 --validation-count 1 --checkpoint-minutes 1000 2> "$out/log" ||
    { cat "$out/log" >&2; exit 1; }
  end=$(date +%s.%N)
  echo "$end - $start" | bc
}
round=0
while [ "$round" -lt "$repeats" ]; do
  round=$((round + 1))
  for b in $batches; do
    n1=$((64 / b)); [ "$n1" -lt 3 ] && n1=3
    n2=$((n1 + materials / b))
    t1=$(seconds "$b" "$n1") || exit 1
    t2=$(seconds "$b" "$n2") || exit 1
    echo "$b $(echo "scale=2; $b * ($n2 - $n1) / ($t2 - $t1)" | bc) $n1 $t1 $n2 $t2" >> "$out/rows"
  done
done
echo "| batch | materials/s, steady (median of $repeats) | runs | N1 steps, s | N2 steps, s |"
echo "|---|---|---|---|---|"
for b in $batches; do
  rates=$(awk -v b="$b" '$1 == b { print $2 }' "$out/rows")
  median=$(echo "$rates" | sort -n | awk '{ v[NR] = $1 } END { print (NR % 2) ? v[(NR + 1) / 2] : (v[NR / 2] + v[NR / 2 + 1]) / 2 }')
  times=$(awk -v b="$b" '$1 == b { printf "%s%d: %.1f", (n++ ? ", " : ""), $3, $4 }' "$out/rows")
  times2=$(awk -v b="$b" '$1 == b { printf "%s%d: %.1f", (n++ ? ", " : ""), $5, $6 }' "$out/rows")
  runs=$(awk -v b="$b" '$1 == b { printf "%s%s", (n++ ? " " : ""), $2 }' "$out/rows")
  echo "| $b | $median | $runs | $times | $times2 |"
done
