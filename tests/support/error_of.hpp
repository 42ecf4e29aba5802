#pragma once
// The message of the std::runtime_error a call throws, for tests of error messages.
#include <doctest/doctest.h>

#include <stdexcept>
#include <string>

namespace anisocap::testing {

/// Runs `f` and returns the message of the std::runtime_error it throws; fails the test when it
/// throws nothing.
template <class F>
std::string error_of(F&& f) {
  try {
    f();
  } catch (const std::runtime_error& e) {
    return e.what();
  }
  FAIL("expected an error");
  return {};
}

}  // namespace anisocap::testing
