#!/bin/sh
# Writes include/anisocap/anisocap.hpp: every public header, folder by folder in layer order.
cd "$(dirname "$0")/.." || exit 1
{
  echo '#pragma once'
  echo '/// @file'
  echo '/// The umbrella header: every public header of anisocap (scripts/umbrella.sh writes it). Including'
  echo '/// single headers (for instance `anisocap/render/renderer.hpp`) compiles faster when only a part is'
  echo '/// needed. Folders, each including only those before it: core, ad, nn, brdf, render, data,'
  echo '/// networks, training, pipeline, calibration, export (docs/architecture.md).'
  for folder in core ad nn brdf render data networks training pipeline calibration export; do
    [ -d include/anisocap/$folder ] || continue
    echo
    find include/anisocap/$folder -name '*.hpp' -not -path '*/detail/*' | sort | sed 's|^include/\(.*\)$|#include "\1"|'
  done
} > include/anisocap/anisocap.hpp
