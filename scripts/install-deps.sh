#!/usr/bin/env bash
# Installs everything anisocap's build, tests and examples need, from Debian 12 packages.
# `--studies` (also accepted as `--bench`) adds what the studies' PyTorch peer comparisons and
# plots need (PyTorch CPU, matplotlib; studies/README.md), and with it what the Python package's
# PyTorch tests (python_torch: a skip without it) and bench/python_speed.py need.
# `--web` adds what the export and viewer tests need: headless Chromium (the viewer page is
# screenshotted in a real browser) and Node.js with the Khronos glTF validator from npm
# (gltf-validator, which checks the glTF export) and three.js (npm three, pinned: the ctest
# threejs_fidelity renders the glTF export with it). scripts/test.sh passes it.
# `--blender` adds Debian's Blender (3.4.1 on Debian 12; about 150 packages, ~1 minute to install),
# which renders the Blender export with Cycles in the ctest blender_render. scripts/test.sh passes it.
# `--clang` adds what a Clang build needs: clang, and libomp-dev, LLVM's OpenMP runtime with the
# omp.h clang reads (GCC's libgomp serves only GCC; without it CMake finds no OpenMP for clang).
set -euo pipefail
web=0
for arg in "$@"; do [[ "$arg" == "--web" ]] && web=1; done
packages=(build-essential cmake pkg-config git libxsimd-dev libeigen3-dev libstb-dev libtinyexr-dev
          doctest-dev libbenchmark-dev nlohmann-json3-dev libcli11-dev
          libapriltag-dev   # AprilTag marker frames: anisocap markers, corner detection in rectify
          libopenmpi-dev openmpi-bin   # MPI: one capture or training over several processes (mpirun), and its ctests
          parallel   # GNU parallel: batches of captures, one job per sample (docs/batch.md), and the ctest batch_parallel
          python3-dev pybind11-dev python3-numpy python3-pytest)  # the Python package and its tests (examples/python/)
if [[ " $* " == *" --studies "* || " $* " == *" --bench "* ]]; then packages+=(python3-torch python3-matplotlib python3-numpy); fi
if [[ " $* " == *" --clang "* ]]; then packages+=(clang libomp-dev); fi
if [[ " $* " == *" --blender "* ]]; then packages+=(blender); fi
if ((web)); then
  packages+=(chromium)
  command -v npm >/dev/null || packages+=(nodejs npm)
fi
missing=()
for p in "${packages[@]}"; do dpkg -s "$p" >/dev/null 2>&1 || missing+=("$p"); done
if ((${#missing[@]})); then
  SUDO=""; [[ $(id -u) -ne 0 ]] && SUDO=sudo
  $SUDO apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq --no-install-recommends "${missing[@]}"
fi
if ((web)) && ! (cd "$(npm root -g)" && [[ -f gltf-validator/package.json ]]); then
  SUDO=""; [[ $(id -u) -ne 0 ]] && SUDO=sudo
  $SUDO npm install -g --no-fund --no-audit gltf-validator
fi
if ((web)) && ! (cd "$(npm root -g)" && [[ -f three/package.json ]] && grep -q '"version": "0.187.0"' three/package.json); then
  SUDO=""; [[ $(id -u) -ne 0 ]] && SUDO=sudo
  $SUDO npm install -g --no-fund --no-audit three@0.187.0
fi
