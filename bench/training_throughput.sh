#!/bin/sh
# Training throughput (samples/s) of `anisocap train-estimator` and `train-autoencoder` with and
# without sample prefetching, at 1 and 2 OpenMP threads: the median of REPEATS runs of STEPS steps
# each (the rate of the final progress line: every step of the run, the first included), the runs
# of one row interleaved with the other rows' so that a change in the machine's load hits all alike.
#   sh bench/training_throughput.sh [PROGRAM] [STEPS] [REPEATS] [VARIANTS]
# PROGRAM defaults to build/anisocap; VARIANTS is a list of name=options pairs (options joined by
# commas; a first word that is not an option names another program for that variant), default
# "serial=--prefetch,false prefetch=--prefetch,true".
program=${1:-build/anisocap}
steps=${2:-30}
repeats=${3:-3}
variants=${4:-"serial=--prefetch,false prefetch=--prefetch,true"}
out=$(mktemp -d)
trap 'rm -rf "$out"' EXIT
for network in estimator autoencoder; do
  for threads in 1 2; do
    for r in $(seq "$repeats"); do
      for v in $variants; do
        name=${v%%=*}
        options=$(echo "${v#*=}" | tr ',' ' ')
        run=$program
        case $options in -*|'') ;; *) run=${options%% *}; options=${options#"$run"} ;; esac
        # shellcheck disable=SC2086
        OMP_NUM_THREADS=$threads "$run" train-$network --out "$out/run" --steps "$steps" --size 128 --batch 2 \
          --validate-every 1000000 --validation-count 1 --checkpoint-minutes 1000 $options 2> "$out/log" ||
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
  for threads in 1 2; do
    for v in $variants; do
      name=${v%%=*}
      f="$out/$network-$threads-$name"
      median=$(sort -n "$f" | awk '{a[NR]=$1} END {print (NR % 2) ? a[(NR + 1) / 2] : (a[NR / 2] + a[NR / 2 + 1]) / 2}')
      echo "| $network | $threads | $name | $median | $(tr '\n' ' ' < "$f")|"
    done
  done
done
