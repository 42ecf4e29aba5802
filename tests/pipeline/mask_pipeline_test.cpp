// Masks through the whole capture (first guess, encode, fine-tune with and without crops, refine,
// exposure normalisation): whatever the masked pixels of the photographs hold, the maps and every
// stage's loss come out bit-identical; without the masks they do not.
#include <doctest/doctest.h>
#include <omp.h>

#include <algorithm>
#include <random>

#include "../networks/tiny_presets.hpp"
#include "../render/render_reference.hpp"
#include "anisocap/pipeline/capture.hpp"
#include "support/two_threads.hpp"

using namespace anisocap;
using namespace anisocap::testing;

namespace {

capture_result run(const capture& cap, const std::vector<image>& photos, const std::vector<image>& masks, int crop_cells) {
  estimation_network<estimator_tiny> estimator(1);
  auto_encoder<autoencoder_tiny> autoencoder(2);
  capture_options o;
  o.stages.estimate = false;  // the first guess: the estimator sees whole photographs by design
  o.finetune.steps = 4;
  o.finetune.crop.cells = crop_cells;
  o.refine.steps = 6;
  return capture_once(cap, photos, estimator, autoencoder, o, nullptr, masks);
}

}  // namespace

TEST_CASE("capture_once: masked pixels never reach the maps or the losses") {
  const two_threads threads;
  const int w = 40, h = 24;
  const capture cap = random_capture(5, 4);
  const std::vector<image> photos = render(random_maps(w, h, 3), cap);
  std::mt19937_64 gen(7);
  std::bernoulli_distribution out(0.2);
  std::vector<image> masks;
  for (std::size_t k = 0; k < photos.size(); ++k) {
    image m(w, h, 1);
    for (std::size_t i = 0; i < m.pixel_count(); ++i) m.plane(0)[i] = out(gen) ? 0.0f : 1.0f;
    masks.push_back(std::move(m));
  }
  // Masked pixels clipped to a bright constant, as an over-exposed photograph would have them.
  std::vector<image> clipped = photos;
  for (std::size_t k = 0; k < clipped.size(); ++k)
    for (int c = 0; c < 3; ++c)
      for (std::size_t i = 0; i < clipped[k].pixel_count(); ++i)
        if (masks[k].plane(0)[i] == 0.0f) clipped[k].plane(c)[i] = 50.0f;

  for (const int crop_cells : {0, 1}) {  // the whole tile, and random one-cell crops
    INFO("fine-tune crop cells " << crop_cells);
    const capture_result a = run(cap, photos, masks, crop_cells);
    const capture_result b = run(cap, clipped, masks, crop_cells);
    REQUIRE(a.stages.size() == b.stages.size());
    REQUIRE(a.stages.size() == 4);  // first guess, encode, fine-tune, refine
    for (std::size_t s = 0; s < a.stages.size(); ++s) {
      INFO("stage " << a.stages[s].name);
      CHECK(a.stages[s].loss == b.stages[s].loss);
    }
    CHECK(a.loss == b.loss);
    CHECK(same_bits(a.maps, b.maps));
    REQUIRE(a.after_finetune);
    CHECK(same_bits(*a.after_finetune, *b.after_finetune));
    // Without the masks the bright pixels are fitted and the maps change.
    const capture_result c = run(cap, clipped, {}, crop_cells);
    CHECK_FALSE(same_bits(a.maps, c.maps));
  }
}
