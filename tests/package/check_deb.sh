#!/usr/bin/env bash
# The Debian package as a user gets it: `cpack -G DEB` in the build folder BINARY_DIR, unpacked
# with dpkg -x into a clean folder, and `anisocap demo` run from there, finding the packaged
# weights beside the program (no ANISOCAP_MODELS, no build or source tree).
#   check_deb.sh BINARY_DIR
set -euo pipefail
binary_dir=$(cd "$1" && pwd)
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
(cd "$binary_dir" && cpack -G DEB -B "$work/deb" >"$work/cpack.log" 2>&1) || { cat "$work/cpack.log"; exit 1; }
deb=$(ls "$work"/deb/anisocap_*.deb)
echo "package: $(basename "$deb") ($(du -h "$deb" | cut -f1))"
dpkg-deb --info "$deb" | grep -E "Package|Version|Depends" || true
contents=$(dpkg-deb --contents "$deb")
for path in ./usr/bin/anisocap ./usr/share/anisocap/models/compact/estimator.safetensors \
            ./usr/share/anisocap/models/also/compact/autoencoder.safetensors ./usr/include/anisocap/anisocap.hpp \
            ./usr/lib/cmake/anisocap/anisocapConfig.cmake ./usr/share/pkgconfig/anisocap.pc; do
  grep -q " $path\$" <<<"$contents" || { echo "the package lacks $path"; exit 1; }
done
# A dispatching build (ANISOCAP_KERNEL_ISAS) ships its modules, and the packaged launcher finds them.
if [[ -d "$binary_dir/anisocap-kernels" ]]; then
  for module in "$binary_dir"/anisocap-kernels/anisocap-*.so; do
    grep -qE " ./usr/lib/([^/]+/)?anisocap/$(basename "$module")\$" <<<"$contents" || { echo "the package lacks $(basename "$module")"; exit 1; }
  done
fi
dpkg -x "$deb" "$work/root"
"$work/root/usr/bin/anisocap" --version
unset ANISOCAP_MODELS
(cd "$work" && OMP_NUM_THREADS=2 "$work/root/usr/bin/anisocap" demo --size 64 -o "$work/demo" >"$work/demo.log" 2>&1) ||
  { cat "$work/demo.log"; exit 1; }
grep -q "$work/root/usr/share/anisocap/models" "$work/demo/result/report.json" ||
  { echo "the demo did not run the packaged weights:"; grep networks "$work/demo/result/report.json"; exit 1; }
echo "the unpacked package runs anisocap demo with its own weights"
