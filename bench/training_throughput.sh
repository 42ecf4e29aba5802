#!/bin/sh
# Training throughput (samples/s) of `anisocap train-estimator` and `train-autoencoder`, 128 x 128
# materials, batch 2, at 1 and 2 OpenMP threads (THREADS in the environment: other counts, for
# example THREADS="1 2 4 8 16"), for several variants of the command: the median
# of REPEATS runs (the rate of each run's final progress line, which counts every step, the first
# included). The runs of all rows are interleaved, so that a change in the machine's load hits
# every row alike; compare rows of one run of this script.
#   sh bench/training_throughput.sh [PROGRAM] [STEPS] [REPEATS] [VARIANTS]
# PROGRAM: default build/anisocap. STEPS: estimator steps per run (default 20; the auto-encoder,
# whose steps are about 3x cheaper, runs 3x as many). VARIANTS: space-separated name=words pairs,
# the words joined by commas: leading VAR=value words go to the environment, then an optional
# program (any word not starting with '-') replaces PROGRAM, the rest are options. Default:
# "serial=--prefetch,false prefetch=--prefetch,true".
program=${1:-build/anisocap}
steps=${2:-20}
repeats=${3:-3}
variants=${4:-"serial=--prefetch,false prefetch=--prefetch,true"}
thread_counts=${THREADS:-1 2}
out=$(mktemp -d)
trap 'rm -rf "$out"' EXIT
for r in $(seq "$repeats"); do
  for network in estimator autoencoder; do
    n=$steps
    [ "$network" = autoencoder ] && n=$((3 * steps))
    for threads in $thread_counts; do
      for v in $variants; do
        name=${v%%=*}
        set -- $(echo "${v#*=}" | tr ',' ' ')
        environment=""
        while [ $# -gt 0 ] && [ "${1#*=}" != "$1" ] && [ "${1#-}" = "$1" ]; do environment="$environment $1"; shift; done
        run=$program
        if [ $# -gt 0 ] && [ "${1#-}" = "$1" ]; then run=$1; shift; fi
        # shellcheck disable=SC2086
        env OMP_NUM_THREADS="$threads" $environment "$run" train-$network --out "$out/run" --steps "$n" --size 128 --batch 2 \
          --validate-every 1000000 --validation-count 1 --checkpoint-minutes 1000 "$@" 2> "$out/log" ||
          { cat "$out/log"; exit 1; }
        grep 'samples/s' "$out/log" | tail -1 | sed 's/.*  \([0-9.]*\) samples\/s.*/\1/' >> "$out/$network-$threads-$name"
        rm -rf "$out/run"
      done
    done
  done
done
echo "| network | OpenMP threads | variant | samples/s (median of $repeats) | runs |"
echo "|---|---|---|---|---|"
for network in estimator autoencoder; do
  for threads in $thread_counts; do
    for v in $variants; do
      name=${v%%=*}
      f="$out/$network-$threads-$name"
      median=$(sort -n "$f" | awk '{a[NR] = $1} END {print (NR % 2) ? a[(NR + 1) / 2] : (a[NR / 2] + a[NR / 2 + 1]) / 2}')
      echo "| $network | $threads | $name | $median | $(tr '\n' ' ' < "$f")|"
    done
  done
done
