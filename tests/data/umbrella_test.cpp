// The umbrella header compiles on its own (the first include of this file) and gives every
// public name, the data API among them.
#include "anisocap/anisocap.hpp"

#include <doctest/doctest.h>

TEST_CASE("data umbrella: every data header is reachable") {
  CHECK(anisocap::map_file_names.size() == 7);
  CHECK(anisocap::srgb_to_linear(1.0) == doctest::Approx(1.0));
  anisocap::capture c;
  CHECK_THROWS_AS(anisocap::capture_to_json(c), anisocap::io_error);  // empty capture
}
