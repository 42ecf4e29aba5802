#!/usr/bin/env bash
# End to end without a camera: synthetic perspective photographs (8-bit sRGB JPEG, clipped
# highlights, sensor noise) of procedural materials -> `anisocap rectify` -> `anisocap capture`,
# against the same material and configurations captured directly in texture space (EXR, same
# noise), and clipped at white as the photographs are (direct-clipped/: what a perfect rectification
# of the 8-bit photographs would give). Per-parameter MSE and novel-view loss, co-located flash and
# separate light, N = 8 and 12.
# Usage: studies/rectify_eval.sh [build/anisocap] [output folder]; SEEDS, SIZE, PHOTO ("960x720"),
# CAPTURE (the capture options) and RECTIFY (extra rectify options) override the defaults;
# FORMAT (jpeg, png or exr; default jpeg) is the photographs' format: png is the JPEG's 8-bit
# quantisation without its compression, exr linear float clipped to [0, 1] but not quantised (rectified with --saturation 1);
# LIGHTS ("separate flash") picks the lights. REDRAW=K adds the capture
# of another draw of the same sensor noise (`photograph --noise-seed K`, its direct/ captured into
# redrawn-result): the capture's own spread, which rectify_table.py shows beside the others. A
# capture whose report.json exists is skipped, so the study resumes where it stopped.
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
format=${FORMAT:-jpeg}
[[ $format == exr ]] && rectify_options+=(--saturation 1)
mkdir -p "$out"
for seed in $seeds; do
  for n in 8 12; do
    for light in "${lights[@]}"; do
      dir="$out/$seed-$n-$light"
      flag=()
      [[ $light == flash ]] && flag=(--flash)
      # photograph DIR [--noise-seed K]: the photographs, direct/, direct-clipped/ and truth/.
      photograph() {
        "$bin" photograph -o "$1" --seed "$seed" "${@:2}" --size "$size" --images "$n" --lookup nearest \
          --photo-width "${photo%x*}" --photo-height "${photo#*x}" --shot-noise 0.01 --read-noise 0.002 "${flag[@]}" --format "$format"
      }
      # capture NAME CAPTURE_JSON: into DIR/NAME-result unless it is there.
      capture() {
        [[ -f $dir/$1-result/report.json ]] || "$bin" capture "$2" -o "$dir/$1-result" --truth "$dir/truth" "${capture_options[@]}"
      }
      if [[ ! -f $dir/rectified/capture.json ]]; then
        rm -rf "$dir"
        photograph "$dir"
        "$bin" rectify "$dir/photos/photos.json" -o "$dir/rectified" --resolution "$size" "${rectify_options[@]}"
      fi
      capture direct "$dir/direct/capture.json"
      capture clipped "$dir/direct-clipped/capture.json"
      capture rectified "$dir/rectified/capture.json"
      if [[ -n ${REDRAW:-} ]]; then
        [[ -f $dir/redrawn/direct/capture.json ]] || { rm -rf "$dir/redrawn"; photograph "$dir/redrawn" --noise-seed "$REDRAW"; }
        capture redrawn "$dir/redrawn/direct/capture.json"
      fi
    done
  done
done
python3 "$(dirname "$0")/rectify_table.py" "$out" | tee "$out/table.md"
