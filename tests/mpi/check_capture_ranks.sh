#!/usr/bin/env bash
# One capture on 1, 2 and 4 MPI ranks (mpirun --oversubscribe on one machine) gives the same maps,
# bit for bit, as the program run once without mpirun with the same shards (--finetune-shards);
# a failing run ends every rank with one message, a non-zero exit and no output; a 2-rank run
# killed in its fine-tune resumes to the same maps.
# Usage: check_capture_ranks.sh PROGRAM MPIEXEC
source "$(dirname "${BASH_SOURCE[0]}")/ranks_setup.sh" "$@"

"$program" synthesize -o syn --width 1024 --height 1024 --images 5 --seed 3 > /dev/null 2>&1
# The estimate's 16 windows without overlap, three fine-tune steps in shards of 8 cells (16 shards
# of the 32 x 32 cells), two refine steps, no second runs or uncertainty: the windows dealt out,
# the fine-tune's sum over ranks and the refine's texel groups dealt out are what is tested.
args=(capture syn/capture.json --stages all --estimate-stride 256 --finetune-steps 3 --finetune-shards 8 --steps 2 --neighbour-restarts none
      --no-also-residual --no-also-models --no-uncertainty --no-view)
"$program" "${args[@]}" -o alone 2> alone.log || { cat alone.log; exit 1; }
for n in 1 2 4; do
  mpirun -np "$n" "$program" "${args[@]}" -o "ranks$n" 2> "ranks$n.log" || { echo "FAIL: $n ranks"; cat "ranks$n.log"; exit 1; }
  for map in alone/*.exr; do
    if ! cmp -s "$map" "ranks$n/$(basename "$map")"; then
      echo "FAIL: $(basename "$map") on $n ranks differs from the run without mpirun"; cat "ranks$n.log"; exit 1
    fi
  done
  grep -q '"ranks"' "ranks$n/report.json" || [[ $n == 1 ]] || { echo "FAIL: report.json of $n ranks without ranks"; exit 1; }
  echo "$n ranks: $(ls alone/*.exr | wc -l) maps equal bit for bit"
done
# Rank 0 alone writes: one report, one progress line source.
[[ $(grep -c "capture: done" ranks4.log) == 1 ]] || { echo "FAIL: the summary printed other than once"; cat ranks4.log; exit 1; }

# A failure (here on every rank: a missing capture) ends the job once, non-zero, without output.
if mpirun -np 2 "$program" capture nowhere/capture.json -o failed > failed.log 2>&1; then
  echo "FAIL: a failing run exited 0"; exit 1
fi
[[ $(grep -c "anisocap: error:" failed.log) == 1 ]] || { echo "FAIL: the error printed other than once"; cat failed.log; exit 1; }
[[ ! -e failed ]] || { echo "FAIL: a failed run left output"; exit 1; }
echo "a failing run: one message, exit non-zero, no output"

# A 2-rank capture killed during its fine-tune (check-points after every step) continues with
# --resume to the maps of the run that was never killed, bit for bit, every rank reading the
# check-point rank 0 wrote.
"$program" synthesize -o syn512 --width 512 --height 512 --images 5 --seed 4 > /dev/null 2>&1
args=(capture syn512/capture.json --stages all --estimate-stride 256 --finetune-steps 12 --finetune-shards 8 --steps 2
      --neighbour-restarts none --no-also-residual --no-also-models --no-uncertainty --no-view)
mpirun -np 2 "$program" "${args[@]}" -o whole 2> whole.log || { cat whole.log; exit 1; }
"$mpiexec" --allow-run-as-root --oversubscribe -np 2 "$program" "${args[@]}" --checkpoint-every 0 -o killed 2> killed.log &
job=$!  # mpirun itself, which passes SIGTERM on to the ranks
state=killed/.checkpoint/finetune/state.safetensors
for ((i = 0; i < 1200; ++i)); do
  [[ -e $state ]] && break
  kill -0 "$job" 2>/dev/null || break
  sleep 0.1
done
[[ -e $state ]] || { echo "FAIL: no fine-tune check-point appeared"; cat killed.log; exit 1; }
kill -TERM "$job" 2>/dev/null || true
wait "$job" 2>/dev/null || true
[[ ! -e killed/report.json ]] || { echo "FAIL: the run finished before it was killed: nothing to resume"; exit 1; }
mpirun -np 2 "$program" "${args[@]}" --resume -o killed 2> resumed.log || { echo "FAIL: --resume on 2 ranks"; cat resumed.log; exit 1; }
python3 -c 'import json, sys
stages = {s["name"]: s for s in json.load(open(sys.argv[1]))["stages"]}
sys.exit(0 if stages["finetune"]["resumed"] and stages["estimate"]["resumed"] else "FAIL: report.json says no stage resumed")' killed/report.json
for map in whole/*.exr; do
  cmp -s "$map" "killed/$(basename "$map")" || { echo "FAIL: $(basename "$map") after a resume on 2 ranks differs"; cat resumed.log; exit 1; }
done
echo "a 2-rank capture killed in its fine-tune resumes to the same maps, bit for bit"
