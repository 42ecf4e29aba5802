// Tests for core/option_names.hpp: a binding's names replace whole option fields in the library's
// messages, and errors keep their standard type.
#include <doctest/doctest.h>

#include <stdexcept>
#include <string>

#include "anisocap/core/option_names.hpp"

namespace {

using anisocap::option_name;

constexpr option_name names[] = {
    {"train_options::lr", "--lr"},
    {"train_options::lr_end", "--lr-end"},
    {"finetune_options::guard.factor", "--finetune-guard"},
    {"pipeline_stages", "--stages"},
};

}  // namespace

TEST_CASE("with_option_names: whole fields become the binding's names, everything else stays") {
  using anisocap::with_option_names;
  CHECK(with_option_names("train_options::lr must be positive", names) == "--lr must be positive");
  CHECK(with_option_names("train_options::lr_end must be below train_options::lr.", names) == "--lr-end must be below --lr.");
  CHECK(with_option_names("finetune_options::guard.factor must be 0 (off) or above 1", names) == "--finetune-guard must be 0 (off) or above 1");
  // A field that only begins like one of the names is not that name.
  CHECK(with_option_names("train_options::lr_decay_from must not be negative", names) == "train_options::lr_decay_from must not be negative");
  CHECK(with_option_names("finetune_options::guard.every must be at least 1", names) == "finetune_options::guard.every must be at least 1");
  CHECK(with_option_names("xtrain_options::lr", names) == "xtrain_options::lr");
  // A struct named alone is replaced; one of its members is not.
  CHECK(with_option_names("pipeline_stages: finetune needs encode", names) == "--stages: finetune needs encode");
  CHECK(with_option_names("pipeline_stages::parse failed", names) == "pipeline_stages::parse failed");
  CHECK(with_option_names("", names).empty());
}

TEST_CASE("naming_options: passes the result through and renames the fields of standard errors, keeping their type") {
  using anisocap::naming_options;
  CHECK(naming_options(names, [] { return 7; }) == 7);
  CHECK_THROWS_WITH_AS(naming_options(names, [] { throw std::invalid_argument("train_options::lr must be positive"); }),
                       "--lr must be positive", std::invalid_argument);
  CHECK_THROWS_WITH_AS(naming_options(names, [] { throw std::runtime_error("resume it with train_options::lr_end 0"); }),
                       "resume it with --lr-end 0", std::runtime_error);
  // An error of a derived type that names no field is thrown on as it was.
  struct file_error : std::runtime_error {
    using std::runtime_error::runtime_error;
  };
  CHECK_THROWS_AS(naming_options(names, [] { throw file_error("photo.png: unreadable"); }), file_error);
  CHECK_THROWS_AS(naming_options(names, [] { throw 3; }), int);
}
