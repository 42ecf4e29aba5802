#!/usr/bin/env bash
# Data-parallel training on 1, 2 and 4 MPI ranks (mpirun --oversubscribe on one machine) ends with
# the weights of the program's --data-parallel run without mpirun, bit for bit, for both networks;
# rank 0 alone writes; a 2-rank run resumed from its check-point ends as the run that went
# straight through; a failing run ends every rank with one message and leaves no folder.
# Usage: check_training_ranks.sh PROGRAM MPIEXEC
source "$(dirname "${BASH_SOURCE[0]}")/ranks_setup.sh" "$@"

# Four materials per step: one part per rank on 4 ranks, two on 2, all four on 1.
common=(--size 64 --batch 4 --validate-every 3 --validation-count 1 --seed 9)
for network in estimator autoencoder; do
  "$program" "train-$network" "${common[@]}" --steps 3 --data-parallel true --out "alone-$network" 2> alone.log || { cat alone.log; exit 1; }
  for n in 1 2 4; do
    out="ranks$n-$network"
    mpirun -np "$n" "$program" "train-$network" "${common[@]}" --steps 3 --out "$out" 2> "$out.log" ||
      { echo "FAIL: train-$network on $n ranks"; cat "$out.log"; exit 1; }
    cmp -s "alone-$network/$network.safetensors" "$out/$network.safetensors" ||
      { echo "FAIL: train-$network on $n ranks: weights differ from the --data-parallel run without mpirun"; cat "$out.log"; exit 1; }
    # One validation row (step 3), written once.
    [[ $(grep -c '^3,' "$out/validation.csv") == 1 ]] || { echo "FAIL: validation.csv of $n ranks"; cat "$out/validation.csv"; exit 1; }
    echo "train-$network on $n ranks: the same weights, bit for bit"
  done
done

# A 2-rank run of 2 steps resumed to 4 ends with the weights of 4 steps straight.
mpirun -np 2 "$program" train-autoencoder "${common[@]}" --steps 4 --out straight 2> straight.log || { cat straight.log; exit 1; }
mpirun -np 2 "$program" train-autoencoder "${common[@]}" --steps 2 --out resumed 2> first.log || { cat first.log; exit 1; }
mpirun -np 2 "$program" train-autoencoder "${common[@]}" --steps 4 --resume --out resumed 2> second.log || { cat second.log; exit 1; }
grep -q "resumed at step 2" second.log || { echo "FAIL: the second run did not resume"; cat second.log; exit 1; }
cmp -s straight/autoencoder.safetensors resumed/autoencoder.safetensors ||
  { echo "FAIL: a resumed 2-rank run differs from the straight one"; exit 1; }
echo "a 2-rank run resumed from its check-point: the weights of the straight run, bit for bit"

# A failure (on every rank: a size the estimator cannot take) ends the job once, non-zero, without a folder.
if mpirun -np 2 "$program" train-estimator --size 65 --out failed > failed.log 2>&1; then
  echo "FAIL: a failing run exited 0"; exit 1
fi
[[ $(grep -c "anisocap: error:" failed.log) == 1 ]] || { echo "FAIL: the error printed other than once"; cat failed.log; exit 1; }
[[ ! -e failed ]] || { echo "FAIL: a failed run left its folder"; exit 1; }
echo "a failing run: one message, exit non-zero, no folder"
