// weights_preset and the compact preset dispatch (networks/presets.hpp): the preset a file names
// selects the network type, a file without one is compact, any other preset and a missing file are
// refused with the file's name.
#include <doctest/doctest.h>

#include <unistd.h>

#include <filesystem>
#include <set>
#include <string>
#include <type_traits>
#include <utility>
#include <vector>

#include "anisocap/networks/presets.hpp"
#include "anisocap/nn/linear.hpp"

using namespace anisocap;
namespace fs = std::filesystem;

namespace {

fs::path scratch_file(const std::string& name) {
  const fs::path dir = fs::temp_directory_path() / ("anisocap_presets_test_" + std::to_string(::getpid()));
  fs::create_directories(dir);
  return dir / name;
}

/// A small weight file with the given metadata (the dispatch reads metadata only).
fs::path weights_with(const std::string& name, std::vector<std::pair<std::string, std::string>> metadata) {
  nn::linear<2, 3> layer("layer");
  const fs::path file = scratch_file(name);
  nn::save_weights(file, layer, std::move(metadata));
  return file;
}

}  // namespace

TEST_CASE("weights_preset reads the preset entry, empty when there is none") {
  CHECK(weights_preset(weights_with("orientation.safetensors", {{"network", "estimator"}, {"preset", "compact-orientation"}})) ==
        "compact-orientation");
  CHECK(weights_preset(weights_with("none.safetensors", {{"network", "estimator"}})) == "");
}

TEST_CASE("the compact estimator dispatch picks the type the file names") {
  const auto call = [](const fs::path& file) {
    return with_compact_estimator_preset(file, []<class P>() {
      if constexpr (std::is_same_v<P, estimator_compact_orientation_doubled_angle>) return 3;
      else if constexpr (std::is_same_v<P, estimator_compact_orientation>) return 2;
      else if constexpr (std::is_same_v<P, estimator_compact_doubled_angle>) return 1;
      else if constexpr (std::is_same_v<P, estimator_compact>) return 0;
      else return -1;
    });
  };
  CHECK(call(weights_with("e0.safetensors", {{"preset", "compact"}})) == 0);
  CHECK(call(weights_with("e1.safetensors", {{"preset", "compact-doubled-angle"}})) == 1);
  CHECK(call(weights_with("e2.safetensors", {{"preset", "compact-orientation"}})) == 2);
  CHECK(call(weights_with("e3.safetensors", {})) == 0);
  CHECK(call(weights_with("e4.safetensors", {{"preset", "compact-orientation-doubled-angle"}})) == 3);
  CHECK_THROWS_WITH_AS(call(weights_with("e5.safetensors", {{"preset", "paper"}})), doctest::Contains("e5.safetensors"), std::invalid_argument);
}

TEST_CASE("the compact auto-encoder dispatch picks the type the file names") {
  const auto call = [](const fs::path& file) {
    return with_compact_autoencoder_preset(file, []<class P>() {
      if constexpr (std::is_same_v<P, autoencoder_compact_wide>) return 1;
      else if constexpr (std::is_same_v<P, autoencoder_compact_fine>) return 2;
      else if constexpr (std::is_same_v<P, autoencoder_compact_fine_wide>) return 3;
      else if constexpr (std::is_same_v<P, autoencoder_compact_fine_wider>) return 4;
      else if constexpr (std::is_same_v<P, autoencoder_compact_fine_widest>) return 5;
      else if constexpr (std::is_same_v<P, autoencoder_compact_fine_512>) return 6;
      else if constexpr (std::is_same_v<P, autoencoder_compact>) return 0;
      else return -1;
    });
  };
  CHECK(call(weights_with("a0.safetensors", {{"preset", "compact"}})) == 0);
  CHECK(call(weights_with("a1.safetensors", {{"preset", "compact-wide"}})) == 1);
  CHECK(call(weights_with("a2.safetensors", {})) == 0);
  CHECK(call(weights_with("a3.safetensors", {{"preset", "compact-fine"}})) == 2);
  CHECK(call(weights_with("a4.safetensors", {{"preset", "compact-fine-wide"}})) == 3);
  CHECK(call(weights_with("a5.safetensors", {{"preset", "compact-fine-wider"}})) == 4);
  CHECK(call(weights_with("a6.safetensors", {{"preset", "compact-fine-widest"}})) == 5);
  CHECK(call(weights_with("a7.safetensors", {{"preset", "compact-fine-512"}})) == 6);
}

TEST_CASE("a preset list names its presets in order and calls the one a name picks") {
  using list = preset_list<autoencoder_compact, autoencoder_compact_fine, autoencoder_compact_fine_widest>;
  CHECK(list::names() == std::vector<std::string>{"compact", "compact-fine", "compact-fine-widest"});
  CHECK(list::joined() == "compact, compact-fine, compact-fine-widest");
  CHECK(list::contains("compact-fine"));
  CHECK_FALSE(list::contains("compact-fine-wide"));
  const auto width = []<class P>() { return P::encoder.back(); };
  const auto unknown = [] { return std::string("no such preset"); };
  CHECK(list::call("compact", width, unknown) == 128);
  CHECK(list::call("compact-fine-widest", width, unknown) == 384);
  CHECK_THROWS_WITH_AS(list::call("paper", width, unknown), "no such preset", std::invalid_argument);
  // A call whose template returns nothing.
  int called = 0;
  list::call("compact-fine", [&]<class P>() { called = P::encoder.size(); }, unknown);
  CHECK(called == 4);
  // The compact lists hold every compact preset once, the default first.
  for (const auto& names : {compact_estimator_presets::names(), compact_autoencoder_presets::names()}) {
    CHECK(names.front() == "compact");
    CHECK(std::set<std::string>(names.begin(), names.end()).size() == names.size());
  }
  CHECK(compact_autoencoder_presets::names().size() == 7);
  CHECK(compact_estimator_presets::names().size() == 4);
  CHECK_FALSE(compact_autoencoder_presets::contains("paper"));
}

TEST_CASE("a preset that is not compact, and a missing file, are refused with the file's name") {
  const fs::path paper = weights_with("paper.safetensors", {{"preset", "paper"}});
  const auto none = []<class P>() { return 0; };
  CHECK_THROWS_WITH_AS(with_compact_estimator_preset(paper, none), doctest::Contains(paper.string().c_str()), std::invalid_argument);
  CHECK_THROWS_WITH_AS(with_compact_autoencoder_preset(paper, none), doctest::Contains("\"paper\""), std::invalid_argument);
  CHECK_THROWS_WITH_AS(with_compact_autoencoder_preset(paper, none), doctest::Contains(compact_autoencoder_presets::joined().c_str()),
                       std::invalid_argument);
  const fs::path missing = scratch_file("missing.safetensors");
  CHECK_THROWS_WITH_AS(with_compact_estimator_preset(missing, none), doctest::Contains(missing.string().c_str()), nn::safetensors_error);
  fs::remove_all(missing.parent_path());
}
