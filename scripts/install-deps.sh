#!/usr/bin/env bash
# Installs everything anisocap's build, tests and examples need, from Debian 12 packages.
# `--studies` (also accepted as `--bench`) adds what the studies' PyTorch peer comparisons and
# plots need (PyTorch CPU, matplotlib; studies/README.md).
set -euo pipefail
packages=(build-essential cmake pkg-config git libxsimd-dev libeigen3-dev libstb-dev libtinyexr-dev
          doctest-dev libbenchmark-dev nlohmann-json3-dev libcli11-dev)
if [[ "${1:-}" == "--studies" || "${1:-}" == "--bench" ]]; then packages+=(python3-torch python3-matplotlib python3-numpy); fi
missing=()
for p in "${packages[@]}"; do dpkg -s "$p" >/dev/null 2>&1 || missing+=("$p"); done
if ((${#missing[@]})); then
  SUDO=""; [[ $(id -u) -ne 0 ]] && SUDO=sudo
  $SUDO apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq --no-install-recommends "${missing[@]}"
fi
