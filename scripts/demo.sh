#!/usr/bin/env bash
# Fresh machine to demo: installs dependencies, builds the anisocap program, runs `anisocap demo`.
# Extra arguments go to the demo (e.g. --steps 300 -o /tmp/demo).
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/install-deps.sh
cmake -S . -B build -DCMAKE_BUILD_TYPE=Release -DANISOCAP_BUILD_TESTS=OFF -DANISOCAP_BUILD_BENCH=OFF -DANISOCAP_BUILD_STUDIES=OFF >/dev/null
cmake --build build -j"$(nproc)" --target anisocap_program
./build/anisocap demo "$@"
