#!/usr/bin/env bash
# Fresh machine to green tests: installs dependencies, then builds and runs the whole test suite
# twice, for -march=native and for an AVX2-only target (x86-64-v3), since users run on both.
# ANISOCAP_TEST_ARCHS overrides the list (e.g. ANISOCAP_TEST_ARCHS=native).
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/install-deps.sh
archs=${ANISOCAP_TEST_ARCHS:-"native x86-64-v3"}
jobs=$(nproc)
for arch in $archs; do
  dir=build-test-$arch
  echo "== building tests for -march=$arch in $dir"
  cmake -S . -B "$dir" -DCMAKE_BUILD_TYPE=Release -DANISOCAP_ARCH="$arch" -DANISOCAP_BUILD_BENCH=OFF -DANISOCAP_BUILD_STUDIES=OFF >/dev/null
  cmake --build "$dir" -j"$jobs"
  echo "== running tests for -march=$arch"
  (cd "$dir" && ctest --output-on-failure -j1)
done
