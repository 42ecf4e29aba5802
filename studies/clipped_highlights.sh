#!/usr/bin/env bash
# Clipped highlights on the demo capture: the same synthetic material captured from its linear EXR
# inputs, from the 8-bit sRGB PNG previews beside them (highlights above 1 clip at code 255) with
# the clipped pixels fitted (--fit-clipped), and from the same PNGs with them left out of the loss
# (the default). Prints one table row per run from each report.json.
# CAPTURE_OPTIONS (default: the per-texel refine alone, 1000 steps from the first guess, minutes on
# two cores) are passed to every capture, e.g. CAPTURE_OPTIONS="--stages all --finetune-steps 800
# --finetune-lr 8e-3 --finetune-warmup 200" for the demo's network pipeline.
# SYNTHESIZE_OPTIONS (default: none, the demo's 256 x 256 material) go to synthesize.
# Usage: [CAPTURE_OPTIONS=...] [SYNTHESIZE_OPTIONS=...] studies/clipped_highlights.sh [ANISOCAP_BINARY] [WORK_DIR] [SEED...]
set -euo pipefail
bin=${1:-build/anisocap}
work=${2:-clipped-highlights}
shift $(( $# > 2 ? 2 : $# ))
seeds=("${@:-1}")
read -r -a schedule <<< "${CAPTURE_OPTIONS:---stages refine}"
read -r -a synthesize_options <<< "${SYNTHESIZE_OPTIONS:-}"
for seed in "${seeds[@]}"; do
  dir=$work/seed$seed
  "$bin" synthesize -o "$dir/input" --seed "$seed" ${synthesize_options[@]+"${synthesize_options[@]}"}
  sed 's/\.exr"/.png"/' "$dir/input/capture.json" > "$dir/input/capture_png.json"
  "$bin" capture "$dir/input/capture.json" --truth "$dir/input/truth" -o "$dir/exr" "${schedule[@]}"
  "$bin" capture "$dir/input/capture_png.json" --truth "$dir/input/truth" -o "$dir/png_fitted" --fit-clipped "${schedule[@]}"
  "$bin" capture "$dir/input/capture_png.json" --truth "$dir/input/truth" -o "$dir/png_masked" "${schedule[@]}"
done
python3 - "$work" "${seeds[@]}" <<'PY'
import json, sys
work, seeds = sys.argv[1], sys.argv[2:]
keys = ["diffuse", "specular", "normal", "lobes", "rotation", "fresnel", "novel_view_image_loss"]
print("| seed | input | clipped pixels (mean over images) | a_d | a'_s | n_s | sigma | alpha | F0 | novel-view loss |")
print("|---|---|---|---|---|---|---|---|---|---|")
for seed in seeds:
    for run, name in [("exr", "EXR (linear)"), ("png_fitted", "8-bit PNG, clipped pixels fitted"), ("png_masked", "8-bit PNG, clipped pixels masked")]:
        r = json.load(open(f"{work}/seed{seed}/{run}/report.json"))
        clipped = sum(p["clipped_fraction"] for p in r["photos"]) / len(r["photos"])
        e = r["errors"]
        print(f"| {seed} | {name} | {100 * clipped:.1f}% | " + " | ".join(f"{e[k]:.5f}" if k != "rotation" else f"{e[k]:.3f}" for k in keys) + " |")
PY
