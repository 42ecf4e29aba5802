#!/usr/bin/env bash
# `cmake --install` of the Python package into a fresh prefix, with the weights where the whole
# install puts them (share/anisocap/models): the package imports from there, not from the build
# tree, and finds those weights beside itself.
# usage: check_install.sh BUILD_DIR PYTHON PACKAGE_DIR (ANISOCAP_PYTHON_INSTALL_DIR)
set -euo pipefail
build=$1 python=$2 package_dir=$3
"$python" -c "import numpy" 2>/dev/null || { echo "skipped: numpy not installed"; exit 77; }
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
cmake --install "$build" --prefix "$work/prefix" --component python >/dev/null
mkdir -p "$work/prefix/share/anisocap"
cp -r "$build/share/anisocap/models" "$work/prefix/share/anisocap/models"
cd "$work"
env -u ANISOCAP_MODELS PYTHONPATH="$work/prefix/$package_dir" "$python" - "$work/prefix" <<'PY'
import pathlib, sys
import anisocap
prefix = pathlib.Path(sys.argv[1]).resolve()
where = pathlib.Path(anisocap.__file__).resolve()
assert prefix in where.parents, f"imported from {where}, not from the install in {prefix}"
assert pathlib.Path(anisocap._anisocap.__file__).resolve().parent == where.parent
found = anisocap.models_folder()
assert found is not None and found.resolve() == prefix / "share" / "anisocap" / "models", f"weights found in {found}"
maps = anisocap.synthesize(width=8, height=8, images=4)["maps"]
assert maps.shape == (8, 8, 12)
print(f"installed package in {where.parent} finds the weights in {found}")
PY
