#!/bin/bash
# Trains the estimator and the auto-encoder side by side on one GPU with studies/train_torch.py,
# each fed by 7 procedural generators (anisocap_study_torch_training_data), for one device call:
#
#   bash studies/gpu_train_pair.sh EST_INIT AE_INIT FIRST MINUTES EST_BATCH AE_BATCH AE_LR SEED
#
# EST_INIT, AE_INIT: weight files to start from, relative to the repository root (their presets
# are used; AE_INIT "-" trains the estimator alone and ignores AE_BATCH and AE_LR); FIRST: the
# first material index (a continued run takes new materials); SEED: the runs use 2000 + SEED
# (estimator) and 1000 + SEED (auto-encoder). The estimator trains at 3e-4 on
# 7 generators, the auto-encoder on 7; EST_ARGS and AE_ARGS (environment) are appended to each
# run's train_torch.py options and override them (for example EST_ARGS="--size 256 --lr 3e-5
# --shot-noise 0.02 --read-noise 0.004 --workers 8"). On the lent 16-core machine the estimator at
# 256, batch 16, drew 108 materials/s alone with --workers 8, 86 with 8 beside the auto-encoder's 7,
# and 16 alone with --workers 14: keep the estimator's workers at 8 or fewer.
# Expects the statically linked generator in .gpu/ (models/README.md "Run 13") and writes
# $OUT/est/, $OUT/ae/ (weights, validation.csv, run.json) and both logs to $OUT.
set -euo pipefail
if [ $# -ne 8 ]; then sed -n 2,17p "$0" >&2; exit 2; fi
cd "$(dirname "$0")"
T=../.gpu/anisocap_study_torch_training_data
nvidia-smi --query-gpu=name --format=csv,noheader
if [ "$2" != - ]; then
    python3 train_torch.py train --network autoencoder --init "../$2" --out "$OUT/ae" \
        --tool $T --minutes "$4" --batch "$6" --lr "$7" --workers 7 --seed $((1000 + $8)) --first "$3" ${AE_ARGS:-} > "$OUT/ae.log" 2>&1 &
fi
python3 train_torch.py train --network estimator --init "../$1" --out "$OUT/est" \
    --tool $T --minutes "$4" --batch "$5" --lr 3e-4 --workers 7 --seed $((2000 + $8)) --first "$3" ${EST_ARGS:-} > "$OUT/est.log" 2>&1 &
wait
if [ "$2" != - ]; then tail -n 3 "$OUT/ae.log"; fi
tail -n 3 "$OUT/est.log"
