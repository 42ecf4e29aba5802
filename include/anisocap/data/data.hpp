#pragma once
/// @file
/// Umbrella header for data/: image files, capture descriptions, map sets, procedural materials and
/// errors by family.
#include "anisocap/data/image_io.hpp"    // EXR / PNG in and out, atomic file transactions, pixel checks
#include "anisocap/data/capture_io.hpp"  // capture.json
#include "anisocap/data/map_io.hpp"      // map sets: diffuse, specular, lobes, fresnel, normal, rotation, height
#include "anisocap/data/photo_io.hpp"    // photographs for the loss: any format, exposure, clipped pixels and masks
#include "anisocap/data/procedural.hpp"  // seeded procedural fabrics, metals, leather, coated, printed and foil
#include "anisocap/data/family_errors.hpp"  // evaluation errors grouped by procedural family
