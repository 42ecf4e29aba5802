#!/usr/bin/env bash
# Fresh machine to green tests: installs dependencies, then builds and runs the whole test suite
# for -march=native (with the experimental network presets, which the CLI tests train and capture
# with), and the SIMD-dependent suites (core, ad, brdf, render, nn, conv, networks) again for an
# AVX2-only target (x86-64-v3), since users run on both and only those suites take a different code
# path there; then the SIMD-dependent suites with Clang (Debian's clang and libomp), warnings as
# errors, since host projects build the headers with either compiler (ANISOCAP_TEST_CLANG=0 skips it); and the
# program with one module per instruction set, as the Debian package ships it (ANISOCAP_TEST_DISPATCH=0 skips it). ANISOCAP_TEST_ARCHS overrides the list of architectures (e.g.
# ANISOCAP_TEST_ARCHS=native); ANISOCAP_TEST_FULL=1 runs the whole suite on every architecture.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/install-deps.sh --web --clang --blender
archs=${ANISOCAP_TEST_ARCHS:-"native x86-64-v3"}
simd_suites=(core ad brdf render nn conv networks)
jobs=$(nproc)
first=1
for arch in $archs; do
  dir=build-test-$arch
  echo "== building tests for -march=$arch in $dir"
  cmake -S . -B "$dir" -DCMAKE_BUILD_TYPE=Release -DANISOCAP_ARCH="$arch" -DANISOCAP_BUILD_BENCH=OFF -DANISOCAP_BUILD_STUDIES=OFF \
        -DANISOCAP_EXPERIMENTAL_PRESETS=ON >/dev/null
  if ((first)) || [[ "${ANISOCAP_TEST_FULL:-0}" == 1 ]]; then
    cmake --build "$dir" -j"$jobs"
    echo "== running tests for -march=$arch"
    (cd "$dir" && ctest --output-on-failure -j1)
  else
    cmake --build "$dir" -j"$jobs" --target "${simd_suites[@]/#/test_}"
    echo "== running the SIMD-dependent tests for -march=$arch"
    (cd "$dir" && ctest --output-on-failure -j1 -R "^($(IFS='|'; echo "${simd_suites[*]}"))\$")
  fi
  first=0
done
if [[ "${ANISOCAP_TEST_DISPATCH:-1}" == 1 ]]; then
  # The program as a Debian package ships it: a launcher and one module per instruction set (only the
  # program is built; installing skips the rest of the build, so cpack packs what is there).
  # x86-64-v4-bf16 stands for both AVX-512 modules: the plain one differs by one compiler flag.
  echo "== building the program with one module per instruction set (x86-64-v3, x86-64-v4-bf16) in build-test-dispatch"
  cmake -S . -B build-test-dispatch -DCMAKE_BUILD_TYPE=Release -DANISOCAP_KERNEL_ISAS="x86-64-v3;x86-64-v4-bf16" -DANISOCAP_MPI=OFF \
        -DANISOCAP_BUILD_BENCH=OFF -DANISOCAP_BUILD_STUDIES=OFF -DANISOCAP_BUILD_PYTHON=OFF -DCMAKE_SKIP_INSTALL_ALL_DEPENDENCY=ON >/dev/null
  cmake --build build-test-dispatch -j"$jobs" --target anisocap_program
  echo "== running the dispatching program's tests"
  (cd build-test-dispatch && ctest --output-on-failure -j1 -R "^(kernel_isas|debian_package)\$")
fi
if [[ "${ANISOCAP_TEST_CLANG:-1}" == 1 ]]; then
  echo "== building the SIMD-dependent tests with clang++ in build-test-clang"
  CXX=clang++ cmake -S . -B build-test-clang -DCMAKE_BUILD_TYPE=Release -DANISOCAP_ARCH=native -DCMAKE_CXX_FLAGS=-Werror \
        -DANISOCAP_BUILD_BENCH=OFF -DANISOCAP_BUILD_STUDIES=OFF -DANISOCAP_BUILD_EXAMPLES=OFF >/dev/null
  cmake --build build-test-clang -j"$jobs" --target "${simd_suites[@]/#/test_}"
  echo "== running the SIMD-dependent tests built with clang++"
  (cd build-test-clang && ctest --output-on-failure -j1 -R "^($(IFS='|'; echo "${simd_suites[*]}"))\$")
fi
