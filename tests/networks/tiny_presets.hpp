#pragma once
// Tiny network presets for tests: the same code paths as `compact` and `paper`, cheap to run.
#include <array>

namespace anisocap::testing {

/// An estimator with 4 channels everywhere.
struct estimator_tiny {
  static constexpr std::array<int, 6> encoder{4, 4, 4, 4, 4, 8};
  static constexpr std::array<int, 6> track1{8, 4, 4, 4, 4, 4};
  static constexpr std::array<int, 6> track2{4, 4, 4, 4, 4, 4};
  static constexpr const char* name = "tiny";
};

/// The tiny estimator with the doubled-angle rotation output (like compact-doubled-angle).
struct estimator_tiny_doubled_angle : estimator_tiny {
  static constexpr bool doubled_angle = true;
  static constexpr const char* name = "tiny-doubled-angle";
};

/// The tiny estimator with the orientation input channels (like compact-orientation).
struct estimator_tiny_orientation : estimator_tiny {
  static constexpr int input_channels = 6;
  static constexpr const char* name = "tiny-orientation";
};

/// An auto-encoder with 4 to 8 channels.
struct autoencoder_tiny {
  static constexpr std::array<int, 5> encoder{4, 4, 8, 8, 8};
  static constexpr const char* name = "tiny";
};

/// The tiny auto-encoder with four levels (like compact-fine): a latent cell per 16 x 16 texels.
struct autoencoder_tiny_four_levels {
  static constexpr std::array<int, 4> encoder{4, 4, 8, 8};
  static constexpr const char* name = "tiny-four-levels";
};

}  // namespace anisocap::testing
