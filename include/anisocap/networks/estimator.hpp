#pragma once
/// @file
/// The estimation network of the paper (docs/method.md section 7, after Deschaintre 2018/2019):
/// multi-image, with compile-time width presets `estimator_paper` (the paper's widths) and
/// `estimator_compact` (trains on 2 CPU cores; the shipped weights in models/compact/). It works on
/// NHWC tensors in network space (networks/network_space.hpp).
#include <cstring>
#include <filesystem>
#include <numbers>
#include <utility>
#include <vector>

#include "anisocap/core/parallel.hpp"
#include "anisocap/networks/network_layers.hpp"

namespace anisocap {

/// The paper's estimator widths: 6 encoder layers up to 1024 channels, track 1 (a_d, a'_s, sigma,
/// F0) from 512 down to 64, track 2 (n_s, alpha) from 256 down to 32 (docs/method.md section 7).
struct estimator_paper {
  static constexpr std::array<int, 6> encoder{64, 128, 256, 512, 1024, 1024};  ///< encoder widths
  static constexpr std::array<int, 6> track1{512, 512, 256, 128, 64, 64};      ///< track 1 decoder widths
  static constexpr std::array<int, 6> track2{256, 256, 128, 64, 32, 32};       ///< track 2 decoder widths
  static constexpr const char* name = "paper";                                  ///< preset name in files
};

/// The compact estimator: about 1/16 of the paper's widths, so that training makes progress on
/// 2 CPU cores (bench/README.md "## Networks" has its step time).
struct estimator_compact {
  static constexpr std::array<int, 6> encoder{16, 32, 64, 64, 64, 64};  ///< encoder widths
  static constexpr std::array<int, 6> track1{64, 64, 64, 32, 16, 16};   ///< track 1 decoder widths
  static constexpr std::array<int, 6> track2{32, 32, 32, 16, 8, 8};     ///< track 2 decoder widths
  static constexpr const char* name = "compact";                         ///< preset name in files
};

/// The compact widths with the rotation read from a doubled-angle vector (c, s) = direction of
/// 2 alpha instead of a tanh output for alpha / (pi/2) (network_detail::normals_and_doubled_angle):
/// the last reducing convolution of track 2 has 4 outputs (n_x, n_y, c, s). The network values,
/// losses and weight names are otherwise those of `estimator_compact`.
struct estimator_compact_doubled_angle : estimator_compact {
  static constexpr bool doubled_angle = true;                         ///< rotation as a doubled-angle vector
  static constexpr const char* name = "compact-doubled-angle";        ///< preset name in files
};

/// The compact widths with three more input channels per photograph: the image's local
/// orientation and contrast from its structure tensor (network_space::orientation_channels), so the
/// rotation's evidence reaches the network without having to be learnt from pixels. Only the first
/// encoder layer's weights differ from `estimator_compact`'s (experimental; docs/model-card.md).
struct estimator_compact_orientation : estimator_compact {
  static constexpr int input_channels = 6;                         ///< RGB and 3 orientation channels
  static constexpr const char* name = "compact-orientation";       ///< preset name in files
};

/// The orientation inputs of `estimator_compact_orientation` with the doubled-angle rotation output
/// of `estimator_compact_doubled_angle`: the structure tensor gives each photo's orientation as a
/// doubled angle, and the head can pass it on through the wrap at alpha = +-pi/2, which a tanh
/// output of alpha / (pi/2) cannot. The shipped estimator's preset (docs/model-card.md).
struct estimator_compact_orientation_doubled_angle : estimator_compact {
  static constexpr int input_channels = 6;                                    ///< RGB and 3 orientation channels
  static constexpr bool doubled_angle = true;                                 ///< rotation as a doubled-angle vector
  static constexpr const char* name = "compact-orientation-doubled-angle";    ///< preset name in files
};

/// Input channels per photograph of a preset (presets without the member: 3, RGB).
template <class P>
consteval int input_channels() {
  if constexpr (requires { P::input_channels; })
    return P::input_channels;
  else
    return 3;
}

/// Whether a preset reads the rotation from a doubled-angle vector (presets without the member: no).
template <class P>
consteval bool has_doubled_angle() {
  if constexpr (requires { P::doubled_angle; })
    return P::doubled_angle;
  else
    return false;
}

namespace network_detail {

/// One decoder track of the estimator: 6 transposed convolutions from the bottleneck (H/64) to
/// full size, each after the first fed by the matching encoder skip (concatenated), each followed
/// by instance normalisation, the global feature vector as a per-channel bias, and leaky ReLU.
template <class P, const std::array<int, 6>& D, class T>
class decoder_track {
  static constexpr auto E = P::encoder;

 public:
  /// The track's six widths.
  static constexpr std::array<int, 6> widths = D;
  nn::conv_transpose2d<E[5], D[0], T> up0;  ///< transposed convolution 0 (4x4, stride 2)
  nn::conv_transpose2d<D[0] + E[4], D[1], T> up1;  ///< transposed convolution 1 (4x4, stride 2)
  nn::conv_transpose2d<D[1] + E[3], D[2], T> up2;  ///< transposed convolution 2 (4x4, stride 2)
  nn::conv_transpose2d<D[2] + E[2], D[3], T> up3;  ///< transposed convolution 3 (4x4, stride 2)
  nn::conv_transpose2d<D[3] + E[1], D[4], T> up4;  ///< transposed convolution 4 (4x4, stride 2)
  nn::conv_transpose2d<D[4] + E[0], D[5], T> up5;  ///< transposed convolution 5 (4x4, stride 2)
  nn::instance_norm<D[0], T> n0;  ///< instance norm after up0
  nn::instance_norm<D[1], T> n1;  ///< instance norm after up1
  nn::instance_norm<D[2], T> n2;  ///< instance norm after up2
  nn::instance_norm<D[3], T> n3;  ///< instance norm after up3
  nn::instance_norm<D[4], T> n4;  ///< instance norm after up4
  nn::instance_norm<D[5], T> n5;  ///< instance norm after up5
  nn::linear<E[5], D[0], T> g0;  ///< global vector -> bias of layer 0
  nn::linear<E[5], D[1], T> g1;  ///< global vector -> bias of layer 1
  nn::linear<E[5], D[2], T> g2;  ///< global vector -> bias of layer 2
  nn::linear<E[5], D[3], T> g3;  ///< global vector -> bias of layer 3
  nn::linear<E[5], D[4], T> g4;  ///< global vector -> bias of layer 4
  nn::linear<E[5], D[5], T> g5;  ///< global vector -> bias of layer 5

  /// Layers named prefix + "up0" ... ; weights seeded from `seed`.
  decoder_track(const std::string& p, std::uint64_t seed)
      : up0(p + "up0"), up1(p + "up1"), up2(p + "up2"), up3(p + "up3"), up4(p + "up4"), up5(p + "up5"),
        n0(p + "norm0"), n1(p + "norm1"), n2(p + "norm2"), n3(p + "norm3"), n4(p + "norm4"), n5(p + "norm5"),
        g0(p + "global0", seed), g1(p + "global1", seed), g2(p + "global2", seed), g3(p + "global3", seed),
        g4(p + "global4", seed), g5(p + "global5", seed) {}

  /// Full-size track features from the encoder activations a[0..5] and the global vector g.
  template <class A>
  auto operator()(ad::tape& t, const A& a, const ad::variable<E[5], T>& g) {
    // Each layer's output feeds only its norm, which may then work in place; the skip connections
    // are concatenated inside the transposed convolutions (of_concat).
    auto finish = [&](auto& norm, auto& glob, auto&& h) {
      return norm.with_channel_bias(t, std::move(h), glob(t, g), nn::leaky_relu_activation<T>{T(leaky_slope)});
    };
    auto d0 = finish(n0, g0, up0(t, std::get<5>(a)));
    auto d1 = finish(n1, g1, up1.of_concat(t, d0, std::get<4>(a)));
    auto d2 = finish(n2, g2, up2.of_concat(t, d1, std::get<3>(a)));
    auto d3 = finish(n3, g3, up3.of_concat(t, d2, std::get<2>(a)));
    auto d4 = finish(n4, g4, up4.of_concat(t, d3, std::get<1>(a)));
    return finish(n5, g5, up5.of_concat(t, d4, std::get<0>(a)));
  }

  /// Visits every trainable parameter.
  template <class F>
  void for_each_parameter(F&& f) {
    visit(f, up0, up1, up2, up3, up4, up5, n0, n1, n2, n3, n4, n5, g0, g1, g2, g3, g4, g5);
  }
};

/// The three reducing convolutions after the max-pool over images: 3x3 D -> D (plus the pooled
/// global vector as a bias), 3x3 D -> D, 1x1 D -> Out, then tanh (lands in network space); with
/// DoubledAngle (Out = 4 only), normals_and_doubled_angle instead of tanh, to 3 channels.
template <int G, int D, int Out, class T, bool DoubledAngle = false>
class reducing_head {
  static_assert(!DoubledAngle || Out == 4, "the doubled-angle head has 4 raw outputs: n_x, n_y, c, s");

 public:
  /// Channels of the head's output in network space.
  static constexpr int channels = DoubledAngle ? Out - 1 : Out;
  nn::conv2d<D, D, 3, 1, 1, T> c0;  ///< reducing convolution 0
  nn::conv2d<D, D, 3, 1, 1, T> c1;  ///< reducing convolution 1
  nn::conv2d<D, Out, 1, 1, 0, T> c2;  ///< reducing convolution 2
  nn::linear<G, D, T> global;  ///< pooled global vector -> bias of c0

  /// Layers named prefix + "reduce0" ... .
  reducing_head(const std::string& p, std::uint64_t seed)
      : c0(p + "reduce0"), c1(p + "reduce1"), c2(p + "reduce2"), global(p + "reduce_global", seed) {}

  /// `channels` channels in [-1, 1].
  ad::variable<channels, T> operator()(ad::tape& t, const ad::variable<D, T>& x, const ad::variable<G, T>& g) {
    auto h = nn::add_channel_bias(t, c0(t, x), global(t, g), nn::leaky_relu_activation<T>{T(leaky_slope)});
    h = c1(t, h, nn::leaky_relu_activation<T>{T(leaky_slope)});
    if constexpr (DoubledAngle)
      return normals_and_doubled_angle(t, c2(t, h));
    else
      return c2(t, h, nn::tanh_activation<T>{});
  }

  /// Visits every trainable parameter.
  template <class F>
  void for_each_parameter(F&& f) {
    visit(f, c0, c1, c2, global);
  }
};

}  // namespace network_detail

/// The estimation network (docs/method.md section 7): one single-image U-Net with a global-feature track,
/// applied with shared weights to every input image (the images are batch entries), its two
/// decoder tracks and global vectors max-pooled over the images of each set, then three reducing
/// convolutions per track to 9 (a_d, a'_s, sigma, F0) + 3 (n_s.xy, alpha) channels in network space.
///
/// forward() takes sizes that are multiples of 64 (six stride-2 layers); estimate() pads any size.
template <class Preset, class T = float>
class estimation_network {
  static constexpr auto E = Preset::encoder;

 public:
  using preset = Preset;  ///< the widths
  /// Side lengths forward() accepts are multiples of this.
  static constexpr int size_multiple = 64;

  /// Channels per input photograph (3, or 6 with the orientation channels).
  static constexpr int inputs = input_channels<Preset>();
  nn::conv2d<inputs, E[0], 4, 2, 1, T> enc0;  ///< encoder layer 0 (4x4, stride 2)
  nn::conv2d<E[0], E[1], 4, 2, 1, T> enc1;  ///< encoder layer 1 (4x4, stride 2)
  nn::conv2d<E[1], E[2], 4, 2, 1, T> enc2;  ///< encoder layer 2 (4x4, stride 2)
  nn::conv2d<E[2], E[3], 4, 2, 1, T> enc3;  ///< encoder layer 3 (4x4, stride 2)
  nn::conv2d<E[3], E[4], 4, 2, 1, T> enc4;  ///< encoder layer 4 (4x4, stride 2)
  nn::conv2d<E[4], E[5], 4, 2, 1, T> enc5;  ///< encoder layer 5 (4x4, stride 2)
  nn::instance_norm<E[1], T> norm1;  ///< instance norm of encoder layer 1
  nn::instance_norm<E[2], T> norm2;  ///< instance norm of encoder layer 2
  nn::instance_norm<E[3], T> norm3;  ///< instance norm of encoder layer 3
  nn::instance_norm<E[4], T> norm4;  ///< instance norm of encoder layer 4
  nn::instance_norm<E[5], T> norm5;  ///< instance norm of encoder layer 5
  // Global-feature track (Deschaintre 2018): g_i = selu(W [g_{i-1}, mean(h_i)]), and g_{i-1} enters
  // layer i as a per-channel bias.
  nn::linear<E[0], E[0], T> global0;  ///< global track after encoder layer 0
  nn::linear<E[0] + E[1], E[1], T> global1;  ///< global track after encoder layer 1
  nn::linear<E[1] + E[2], E[2], T> global2;  ///< global track after encoder layer 2
  nn::linear<E[2] + E[3], E[3], T> global3;  ///< global track after encoder layer 3
  nn::linear<E[3] + E[4], E[4], T> global4;  ///< global track after encoder layer 4
  nn::linear<E[4] + E[5], E[5], T> global5;  ///< global track after encoder layer 5
  nn::linear<E[0], E[1], T> bias1;  ///< global vector -> bias of encoder layer 1
  nn::linear<E[1], E[2], T> bias2;  ///< global vector -> bias of encoder layer 2
  nn::linear<E[2], E[3], T> bias3;  ///< global vector -> bias of encoder layer 3
  nn::linear<E[3], E[4], T> bias4;  ///< global vector -> bias of encoder layer 4
  nn::linear<E[4], E[5], T> bias5;  ///< global vector -> bias of encoder layer 5
  network_detail::decoder_track<Preset, Preset::track1, T> track1;  ///< decoder track 1
  network_detail::decoder_track<Preset, Preset::track2, T> track2;  ///< decoder track 2
  network_detail::reducing_head<E[5], Preset::track1[5], 9, T> head1;  ///< reducing convolutions of track 1
  /// Reducing convolutions of track 2 (n_s.xy and alpha; 4 raw outputs with a doubled-angle preset).
  network_detail::reducing_head<E[5], Preset::track2[5], has_doubled_angle<Preset>() ? 4 : 3, T, has_doubled_angle<Preset>()> head2;

  /// A network with seeded He-uniform weights (the same on every machine for the same seed).
  explicit estimation_network(std::uint64_t seed = 1)
      : enc0("enc0"), enc1("enc1"), enc2("enc2"), enc3("enc3"), enc4("enc4"), enc5("enc5"), norm1("enc_norm1"),
        norm2("enc_norm2"), norm3("enc_norm3"), norm4("enc_norm4"), norm5("enc_norm5"), global0("global0", seed),
        global1("global1", seed), global2("global2", seed), global3("global3", seed), global4("global4", seed),
        global5("global5", seed), bias1("global_bias1", seed), bias2("global_bias2", seed),
        bias3("global_bias3", seed), bias4("global_bias4", seed), bias5("global_bias5", seed),
        track1("track1.", seed), track2("track2.", seed), head1("track1.", seed), head2("track2.", seed) {
    using network_detail::init_conv;
    init_conv(enc0, 16 * inputs, seed);
    init_conv(enc1, 16 * E[0], seed);
    init_conv(enc2, 16 * E[1], seed);
    init_conv(enc3, 16 * E[2], seed);
    init_conv(enc4, 16 * E[3], seed);
    init_conv(enc5, 16 * E[4], seed);
    init_track(track1, seed);
    init_track(track2, seed);
    init_head(head1, seed);
    init_head(head2, seed);
  }

  /// Network-space maps (sets x H x W x 12) from the images x (sets * images_per_set entries,
  /// H x W x `inputs` as network_space::photo_to_network writes them, H and W multiples of 64; the
  /// images of set s are entries s * images_per_set ... s * images_per_set + images_per_set - 1).
  ad::variable<parameter_count, T> forward(ad::tape& t, const ad::variable<inputs, T>& x, int images_per_set) {
    if (x.value.height() % size_multiple != 0 || x.value.width() % size_multiple != 0 || x.value.height() == 0 ||
        x.value.width() == 0)
      throw std::invalid_argument("estimation_network::forward: image size " + std::to_string(x.value.height()) + "x" +
                                  std::to_string(x.value.width()) + " is not a positive multiple of 64 (use estimate())");
    const T s = T(network_detail::leaky_slope);
    auto h0 = enc0(t, x);
    auto g0 = nn::selu(t, global0(t, nn::spatial_mean(t, h0)));
    auto a0 = nn::leaky_relu(t, h0, s);
    auto layer = [&](auto& conv, auto& norm, auto& bias, auto& global, const auto& a, const auto& g) {
      auto h = conv(t, a);
      auto m = nn::spatial_mean(t, h);
      h = norm.with_channel_bias(t, std::move(h), bias(t, g), nn::leaky_relu_activation<T>{s});
      auto gn = nn::selu(t, global(t, nn::concat(t, g, m)));
      return std::pair{h, gn};
    };
    auto [a1, g1] = layer(enc1, norm1, bias1, global1, a0, g0);
    auto [a2, g2] = layer(enc2, norm2, bias2, global2, a1, g1);
    auto [a3, g3] = layer(enc3, norm3, bias3, global3, a2, g2);
    auto [a4, g4] = layer(enc4, norm4, bias4, global4, a3, g3);
    auto [a5, g5] = layer(enc5, norm5, bias5, global5, a4, g4);
    const auto skips = std::tie(a0, a1, a2, a3, a4, a5);
    auto f1 = nn::max_over_images(t, track1(t, skips, g5), images_per_set);
    auto f2 = nn::max_over_images(t, track2(t, skips, g5), images_per_set);
    auto g = nn::max_over_images(t, g5, images_per_set);
    return nn::concat(t, head1(t, f1, g), head2(t, f2, g));
  }

  /// The map set estimated from one set of photographs (any size >= 1 x 1, all the same size; at
  /// least one image). The images are mirrored out to a multiple of 64 and the maps cropped back.
  material_maps estimate(const std::vector<image>& photos) {
    if (photos.empty()) throw std::invalid_argument("estimation_network::estimate: no input images");
    const int W = photos[0].width(), H = photos[0].height();
    for (const auto& p : photos)
      if (p.width() != W || p.height() != H)
        throw std::invalid_argument("estimation_network::estimate: the input images differ in size");
    const int Hp = padded_size(H), Wp = padded_size(W);
    // The tape is kept across calls: every window of a sliding-window estimate after the first
    // reuses its memory instead of faulting in fresh pages (release_scratch() frees it).
    ad::tape& t = scratch_.fresh();
    ad::tape::no_grad_guard guard(t);
    auto x = t.make_variable<inputs, T>(int(photos.size()), Hp, Wp, false);
    // One photograph per thread: each writes its own batch entry.
    for_each_index_in_parallel(photos.size(), [&](std::size_t i) { padded_photo(photos[i], x.value, int(i)); });
    auto y = forward(t, x, int(photos.size()));
    auto c = network_detail::crop(t, y, H, W);
    return network_space::network_to_maps(c.value, 0);
  }

  /// Frees the memory estimate() keeps between calls (its inference tape: the activations of the
  /// largest window it ran). A copy of the network does not share it; one network must not run
  /// estimate() on two threads at once.
  void release_scratch() noexcept { scratch_.release(); }
  /// Bytes estimate() keeps between calls.
  std::size_t scratch_bytes() const noexcept { return scratch_.capacity_bytes(); }

  /// The size forward() runs an n-texel side at: n rounded up to a multiple of 64.
  static int padded_size(int n) { return (n + size_multiple - 1) / size_multiple * size_multiple; }

  /// Visits every trainable parameter (for optimisers and weight files): calls f(basic_parameter<T>&).
  template <class F>
  void for_each_parameter(F&& f) {
    visit_parameters(network_detail::erase_visitor<T>(f));
  }
  /// for_each_parameter with the visitor's type erased (the one listing of the layers).
  void visit_parameters(const network_detail::parameter_visitor<T>& f) {
    network_detail::visit(f, enc0, enc1, enc2, enc3, enc4, enc5, norm1, norm2, norm3, norm4, norm5, global0, global1,
                          global2, global3, global4, global5, bias1, bias2, bias3, bias4, bias5, track1, track2, head1,
                          head2);
  }

 private:
  ad::retained_tape scratch_;  ///< estimate()'s inference tape, kept across calls

  /// photo_to_network, mirroring repeatedly when the padded size is more than twice the image's.
  static void padded_photo(const image& photo, tensor<inputs, T>& out, int b) {
    if (out.width() <= 2 * photo.width() && out.height() <= 2 * photo.height()) {
      network_space::photo_to_network(photo, out, b);
      return;
    }
    auto fold = [](int i, int n) {
      if (n == 1) return 0;
      const int period = 2 * n - 2, r = i % period;
      return r < n ? r : period - r;
    };
    for (int y = 0; y < out.height(); ++y)
      for (int x = 0; x < out.width(); ++x)
        for (int c = 0; c < 3; ++c)
          out.pixel(b, y, x)[c] = T(network_space::input_value(photo.at(c, fold(x, photo.width()), fold(y, photo.height()))));
    if constexpr (inputs == 6) network_space::orientation_channels(out, b);
  }
  template <class Track>
  static void init_track(Track& tr, std::uint64_t seed) {
    using network_detail::init_conv;
    constexpr auto D = Track::widths;
    // A 4x4 stride-2 transposed convolution sums 4 taps per output pixel.
    init_conv(tr.up0, 4 * E[5], seed);
    init_conv(tr.up1, 4 * (D[0] + E[4]), seed);
    init_conv(tr.up2, 4 * (D[1] + E[3]), seed);
    init_conv(tr.up3, 4 * (D[2] + E[2]), seed);
    init_conv(tr.up4, 4 * (D[3] + E[1]), seed);
    init_conv(tr.up5, 4 * (D[4] + E[0]), seed);
  }
  template <class Head>
  static void init_head(Head& h, std::uint64_t seed) {
    network_detail::init_conv(h.c0, 9 * h.c0.weight.shape[2], seed);
    network_detail::init_conv(h.c1, 9 * h.c1.weight.shape[2], seed);
    // The last layer starts 10x smaller than Xavier: outputs begin near 0 (mid-range in network
    // space: albedos 0.5, sigma 0.01, flat normals, alpha 0) instead of in tanh's flat tails, where
    // a saturated normal (|n_xy| at the disc's edge) gets almost no gradient and stays there.
    nn::uniform_init(h.c2.weight, 0.1 * std::sqrt(6.0 / (h.c2.weight.shape[2] + h.c2.weight.shape[3])), seed);
    nn::constant_init(h.c2.bias, T(0));
    // A doubled-angle head starts at (c, s) = (1, ~0): alpha 0, and a vector of unit length.
    if (Head::channels == 3 && h.c2.bias.size() == 4) h.c2.bias.value[2] = T(1);
  }
};

/// Starts the doubled-angle head of `net` from the tanh head in `file`, a weight file of a preset
/// without the doubled angle (its "track2.reduce2" has the 3 outputs n_x, n_y, alpha / (pi/2)), so
/// that a run begun with `--init` from such a file keeps what its rotation had learnt:
/// n_x and n_y take the file's weights; s takes pi times the file's alpha weights and bias (its
/// pre-activation z), c weights 0 and bias 1. The head then outputs alpha / (pi/2) =
/// atan2(pi z, 1) / pi, which equals the file's tanh(z) to first order (within 0.003 for |z| <= 0.1,
/// 0.05 for |z| <= 0.3), has its sign beyond, and passes +-1/2 only once training turns c (a linear
/// layer cannot give c = cos(pi tanh z)). Returns false, and changes nothing, when the file has no
/// such layer (for example a file of a doubled-angle preset).
template <class P, class T>
  requires(has_doubled_angle<P>())
bool start_doubled_angle_head(const std::filesystem::path& file, estimation_network<P, T>& net) {
  const nn::safetensors_file contents = nn::read_safetensors(file);
  auto& c2 = net.head2.c2;
  const int D = c2.weight.shape[2];
  const auto* w = contents.find(c2.weight.name);
  const auto* b = contents.find(c2.bias.name);
  if (!w || !b || w->dtype != nn::safetensors_dtype<T>() || b->dtype != w->dtype ||
      w->shape != std::vector<std::int64_t>{1, 1, D, 3} || b->shape != std::vector<std::int64_t>{3})
    return false;
  std::vector<T> old_w(w->count()), old_b(3);
  std::memcpy(old_w.data(), contents.bytes(*w).data(), old_w.size() * sizeof(T));
  std::memcpy(old_b.data(), contents.bytes(*b).data(), old_b.size() * sizeof(T));
  const T pi = T(std::numbers::pi);
  for (int i = 0; i < D; ++i) {  // weight layout [1][1][D][Out]
    for (int k = 0; k < 2; ++k) c2.weight.value[i * 4 + k] = old_w[i * 3 + k];
    c2.weight.value[i * 4 + 2] = T(0);
    c2.weight.value[i * 4 + 3] = pi * old_w[i * 3 + 2];
  }
  c2.bias.value[0] = old_b[0];
  c2.bias.value[1] = old_b[1];
  c2.bias.value[2] = T(1);
  c2.bias.value[3] = pi * old_b[2];
  return true;
}

}  // namespace anisocap
