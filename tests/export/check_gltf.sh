#!/usr/bin/env bash
# The glTF export of `anisocap export` passes the Khronos glTF validator (npm gltf-validator) with
# no errors. Exit 77 (a ctest skip) only when node or the validator is not installed.
# Usage: check_gltf.sh ANISOCAP_PROGRAM
set -euo pipefail
program=$1
here=$(cd "$(dirname "$0")" && pwd)
command -v node >/dev/null || { echo "check_gltf: node is not installed (scripts/install-deps.sh installs it); skipped"; exit 77; }
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
"$program" synthesize -o "$work/syn" --width 40 --height 24 --images 4 --seed 7 --kind satin
"$program" export "$work/syn/truth" --format gltf -o "$work/material.gltf" --width 0.1
node "$here/validate_gltf.mjs" "$work/material.gltf"
