#!/usr/bin/env bash
# The spread of a capture under another draw of the same sensor noise: for each run folder of
# studies/rectify_eval.sh (or those named), photograph the same material and configurations with
# `--noise-seed DRAW` and capture its texture-space images (direct/) into RUN/redrawn-result, which
# rectify_table.py then shows beside the others.
# Usage: studies/rectify_noise_draw.sh build/anisocap OUTPUT_FOLDER DRAW [RUN ...]; SIZE, PHOTO and
# CAPTURE as for rectify_eval.sh (they must match the runs').
set -euo pipefail
bin=$1
out=$2
draw=$3
shift 3
size=${SIZE:-128}
photo=${PHOTO:-960x720}
read -r -a capture_options <<< "${CAPTURE:-}"
runs=("$@")
[[ ${#runs[@]} -gt 0 ]] || runs=($(cd "$out" && ls -d */ | tr -d /))
for run in "${runs[@]}"; do
  dir="$out/$run"
  [[ -f $dir/redrawn-result/report.json ]] && continue
  IFS=- read -r seed n light <<< "$run"
  flag=()
  [[ $light == flash ]] && flag=(--flash)
  rm -rf "$dir/redrawn" "$dir/redrawn-result"
  "$bin" photograph -o "$dir/redrawn" --seed "$seed" --noise-seed "$draw" --size "$size" --images "$n" --lookup nearest \
    --photo-width "${photo%x*}" --photo-height "${photo#*x}" --shot-noise 0.01 --read-noise 0.002 "${flag[@]}"
  "$bin" capture "$dir/redrawn/direct/capture.json" -o "$dir/redrawn-result" --truth "$dir/truth" "${capture_options[@]}"
done
python3 "$(dirname "$0")/rectify_table.py" "$out"
