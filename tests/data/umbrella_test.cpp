// The data/ umbrella header compiles on its own and gives the whole data API.
#include <doctest/doctest.h>

#include "anisocap/data/data.hpp"

TEST_CASE("data umbrella: every data header is reachable") {
  CHECK(anisocap::map_file_names.size() == 7);
  CHECK(anisocap::srgb_to_linear(1.0) == doctest::Approx(1.0));
  anisocap::capture c;
  CHECK_THROWS_AS(anisocap::capture_to_json(c), anisocap::io_error);  // empty capture
}
