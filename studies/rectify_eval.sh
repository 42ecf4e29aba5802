#!/usr/bin/env bash
# End to end without a camera: synthetic perspective photographs (8-bit sRGB JPEG, clipped
# highlights, sensor noise) of procedural materials -> `anisocap rectify` -> `anisocap capture`,
# against the same material and configurations captured directly in texture space (EXR, same
# noise). Per-parameter MSE and novel-view loss, co-located flash and separate light, N = 8 and 12.
# Usage: studies/rectify_eval.sh [build/anisocap] [output folder]; SEEDS, SIZE override the defaults.
set -euo pipefail
bin=${1:-build/anisocap}
out=${2:-rectify-eval}
seeds=${SEEDS:-"900001 900002"}
size=${SIZE:-128}
# Estimate, encode and 300 refine steps (no decoder fine-tune), so that the whole table runs in
# about 10 minutes per material on two cores; both captures of a row run the same pipeline.
capture_options=(--finetune-steps 0 --steps 300)
mkdir -p "$out"
for seed in $seeds; do
  for n in 8 12; do
    for light in separate flash; do
      dir="$out/$seed-$n-$light"
      flag=()
      [[ $light == flash ]] && flag=(--flash)
      "$bin" photograph -o "$dir" --seed "$seed" --size "$size" --images "$n" --lookup nearest \
        --photo-width 960 --photo-height 720 --shot-noise 0.01 --read-noise 0.002 "${flag[@]}"
      "$bin" rectify "$dir/photos/photos.json" -o "$dir/rectified" --resolution "$size"
      "$bin" capture "$dir/direct/capture.json" -o "$dir/direct-result" --truth "$dir/truth" "${capture_options[@]}"
      "$bin" capture "$dir/rectified/capture.json" -o "$dir/rectified-result" --truth "$dir/truth" "${capture_options[@]}"
    done
  done
done
python3 "$(dirname "$0")/rectify_table.py" "$out" | tee "$out/table.md"
