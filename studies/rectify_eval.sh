#!/usr/bin/env bash
# End to end without a camera: synthetic perspective photographs (8-bit sRGB JPEG, clipped
# highlights, sensor noise) of procedural materials -> `anisocap rectify` -> `anisocap capture`,
# against the same material and configurations captured directly in texture space (EXR, same
# noise), and clipped at white as the photographs are (direct-clipped/: what a perfect rectification
# of the 8-bit photographs would give). Per-parameter MSE and novel-view loss, co-located flash and
# separate light, N = 8 and 12.
# Usage: studies/rectify_eval.sh [build/anisocap] [output folder]; SEEDS, SIZE, PHOTO ("960x720"),
# CAPTURE (the capture options) and RECTIFY (extra rectify options) override the defaults;
# LINEAR_EXR=1 photographs in linear EXR clipped at 1 instead of JPEG (rectified with --saturation 1);
# LIGHTS ("separate flash") picks the lights. A run
# whose three report.json files exist is skipped, so the study resumes where it stopped.
set -euo pipefail
bin=${1:-build/anisocap}
out=${2:-rectify-eval}
seeds=${SEEDS:-"900001 900002 900003 900004"}
size=${SIZE:-128}
photo=${PHOTO:-960x720}
# Both captures of a row run the same pipeline: by default the whole of it (estimate, encode,
# decoder fine-tune, refine).
read -r -a capture_options <<< "${CAPTURE:-}"
read -r -a rectify_options <<< "${RECTIFY:-}"
read -r -a lights <<< "${LIGHTS:-separate flash}"
photo_format=()
if [[ -n ${LINEAR_EXR:-} ]]; then
  photo_format=(--linear-exr)
  rectify_options+=(--saturation 1)
fi
mkdir -p "$out"
for seed in $seeds; do
  for n in 8 12; do
    for light in "${lights[@]}"; do
      dir="$out/$seed-$n-$light"
      [[ -f $dir/direct-result/report.json && -f $dir/clipped-result/report.json && -f $dir/rectified-result/report.json ]] && continue
      rm -rf "$dir"
      flag=()
      [[ $light == flash ]] && flag=(--flash)
      "$bin" photograph -o "$dir" --seed "$seed" --size "$size" --images "$n" --lookup nearest \
        --photo-width "${photo%x*}" --photo-height "${photo#*x}" --shot-noise 0.01 --read-noise 0.002 "${flag[@]}" "${photo_format[@]}"
      "$bin" rectify "$dir/photos/photos.json" -o "$dir/rectified" --resolution "$size" "${rectify_options[@]}"
      "$bin" capture "$dir/direct/capture.json" -o "$dir/direct-result" --truth "$dir/truth" "${capture_options[@]}"
      "$bin" capture "$dir/direct-clipped/capture.json" -o "$dir/clipped-result" --truth "$dir/truth" "${capture_options[@]}"
      "$bin" capture "$dir/rectified/capture.json" -o "$dir/rectified-result" --truth "$dir/truth" "${capture_options[@]}"
    done
  done
done
python3 "$(dirname "$0")/rectify_table.py" "$out" | tee "$out/table.md"
