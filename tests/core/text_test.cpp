// Tests for core/text.hpp: lists of names, views and paths joined for messages.
#include <doctest/doctest.h>

#include <array>
#include <filesystem>
#include <string>
#include <string_view>
#include <vector>

#include "anisocap/core/text.hpp"

using anisocap::join_names;

TEST_CASE("join_names puts the separator between items only") {
  CHECK(join_names({"compact", "paper"}, ",") == "compact,paper");
  CHECK(join_names({"compact", "paper", "paper-fine"}, ", ") == "compact, paper, paper-fine");
  CHECK(join_names({"compact"}, ", ") == "compact");
  CHECK(join_names({}, ", ").empty());
  // An empty item still takes its place in the list.
  CHECK(join_names({"a", "", "b"}, "; ") == "a; ; b");
}

TEST_CASE("join_names takes views, C strings and paths") {
  const std::array<std::string_view, 2> views{"diffuse.exr", "normal.exr"};
  CHECK(join_names(views, ", ") == "diffuse.exr, normal.exr");
  const std::vector<const char*> c_strings{"--steps", "--lr"};
  CHECK(join_names(c_strings, " ") == "--steps --lr");
  const std::vector<std::filesystem::path> folders{"/usr/share/anisocap/models", "models"};
  CHECK(join_names(folders, ", ") == "/usr/share/anisocap/models, models");
  CHECK(join_names(std::vector<std::filesystem::path>{}, ", ").empty());
}
