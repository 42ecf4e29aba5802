#!/bin/sh
# Seconds per fine-tune step of one capture over MPI ranks against threads alone (docs/scaling.md).
# A SIZE x SIZE synthetic capture (default 1024) is captured with FEW and MANY fine-tune steps; the
# difference of the fine-tune stage's seconds (report.json) over MANY - FEW steps is the time per
# step, free of the stage's fixed costs (the last whole decode, the loss). Rows: the program without
# mpirun (threads alone: one whole-tile decode per step, and the same with --finetune-shards 16),
# and mpirun -np 1, 2, 4 with OMP_NUM_THREADS so that ranks x threads = CORES, then oversubscribed.
#   sh bench/mpi_finetune_steps.sh [PROGRAM] [SIZE] [FEW] [MANY] [CORES]
# Defaults: build/anisocap 1024 2 6 2. MPIEXEC in the environment: the launcher (default mpirun).
program=${1:-build/anisocap}
size=${2:-1024}
few=${3:-2}
many=${4:-6}
cores=${5:-2}
mpiexec=${MPIEXEC:-mpirun}
out=$(mktemp -d)
trap 'rm -rf "$out"' EXIT
"$program" synthesize -o "$out/syn" --width "$size" --height "$size" --images 5 --seed 3 > /dev/null 2>&1 || exit 1
# Encode and fine-tune from the first guess (no estimate, no refine), no second runs: the fine-tune
# is what is timed.
args="capture $out/syn/capture.json --stages encode,finetune --no-also-residual --no-also-models --no-uncertainty --no-view"
seconds() {  # seconds of the fine-tune stage in report.json
  python3 -c "import json,sys; print([s['seconds'] for s in json.load(open(sys.argv[1]))['stages'] if s['name']=='finetune'][0])" "$1"
}
row() {  # name ranks threads extra-options
  name=$1 ranks=$2 threads=$3
  shift 3
  t=""
  for steps in "$few" "$many"; do
    rm -rf "$out/run"
    if [ "$ranks" = 0 ]; then
      # shellcheck disable=SC2086
      OMP_NUM_THREADS=$threads "$program" $args --finetune-steps "$steps" -o "$out/run" "$@" 2> "$out/log" || { cat "$out/log"; exit 1; }
    else
      # shellcheck disable=SC2086
      OMP_NUM_THREADS=$threads "$mpiexec" --allow-run-as-root --oversubscribe -np "$ranks" "$program" $args --finetune-steps "$steps" \
        -o "$out/run" "$@" 2> "$out/log" || { cat "$out/log"; exit 1; }
    fi
    t="$t $(seconds "$out/run/report.json")"
  done
  echo "$t" | awk -v name="$name" -v d=$((many - few)) '{ printf "%-44s %.3f s/step\n", name, ($2 - $1) / d }'
}
row "threads alone, $cores threads, whole tile" 0 "$cores"
row "threads alone, $cores threads, shards 16" 0 "$cores" --finetune-shards 16
row "mpirun -np 1 x $cores threads" 1 "$cores"
row "mpirun -np 2 x $((cores / 2)) threads" 2 $((cores / 2 > 0 ? cores / 2 : 1))
row "mpirun -np 4 x 1 thread (oversubscribed)" 4 1
