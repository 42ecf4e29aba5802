// Where rectified photographs differ from the texture-space images they stand for: synthetic
// perspective photographs of one procedural material (calibration/photo_synthesis.hpp) are
// rectified after each step of the camera model in turn (linear, + sensor noise, + clipping and
// 8-bit sRGB, + JPEG) and compared per image with the noise-free texture-space render, in the image
// loss's own measure (mean |log(R + 0.01) - log(B + 0.01)| over the texels the mask uses), beside
// the texture-space capture with the same noise. Texels are split by their sampling density (photo
// pixels across the texel's footprint, the square root of the homography's Jacobian determinant).
// studies/README.md, "Rectified photographs, step by step", has the command and the result.
#include <CLI/CLI.hpp>

#include <array>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <string>
#include <vector>

#include "anisocap/anisocap.hpp"

namespace {

using namespace anisocap;

// Mean log-domain difference over texels with mask != 0 and density in [lo, hi); also counts them.
struct tally {
  double sum = 0;
  std::size_t n = 0;
  void add(double v) { sum += v; ++n; }
  double mean() const { return n ? sum / double(n) : 0.0; }
};

double log_difference(const image& a, const image& b, std::size_t k) {
  double d = 0;
  for (int c = 0; c < 3; ++c)
    d += std::abs(std::log(std::max(a.plane(c)[k], 0.0f) + 0.01) - std::log(std::max(b.plane(c)[k], 0.0f) + 0.01));
  return d / 3;
}

image to_8bit_srgb(const image& linear, image& usable) {
  image out(linear.width(), linear.height(), 3);
  usable = image(linear.width(), linear.height(), 1);
  for (std::size_t k = 0; k < linear.pixel_count(); ++k) {
    bool clip = false;
    for (int c = 0; c < 3; ++c) {
      const long code = std::lround(255.0 * linear_to_srgb(std::clamp(double(linear.plane(c)[k]), 0.0, 1.0)));
      clip |= code == 255;
      out.plane(c)[k] = float(srgb_to_linear(code / 255.0));
    }
    usable.plane(0)[k] = clip ? 0.0f : 1.0f;
  }
  return out;
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{"rectified photographs against texture-space images, step by step"};
  std::uint64_t seed = 900001;
  int size = 128, images = 8, photo_width = 960, photo_height = 720;
  resampling_options resampling;
  std::vector<double> margins{0, 0.5, 1, 1.5};
  bool flash = false;
  std::string out = "rectify-residuals";
  app.add_option("--seed", seed, "material and configuration seed")->capture_default_str();
  app.add_option("--size", size, "material size in texels")->capture_default_str();
  app.add_option("--images", images, "photographs")->capture_default_str();
  app.add_option("--photo-width", photo_width)->capture_default_str();
  app.add_option("--photo-height", photo_height)->capture_default_str();
  app.add_option("--max-samples", resampling.max_samples_per_axis, "rectify's footprint samples per axis")->capture_default_str();
  app.add_option("--margin", resampling.margin_px, "rectify's margin in photo pixels")->capture_default_str();
  app.add_option("--margins", margins, "margins for the JPEG density table")->capture_default_str();
  app.add_option("-o", out, "scratch folder for the JPEGs")->capture_default_str();
  app.add_flag("--flash", flash, "co-located flash");
  std::string run, first = "direct-result", second = "rectified-result";
  app.add_option("--run", run, "instead: a run folder of studies/rectify_eval.sh; diffuse-albedo error per texel class");
  app.add_option("--first", first, "first result folder inside --run")->capture_default_str();
  app.add_option("--second", second, "second result folder inside --run")->capture_default_str();
  CLI11_PARSE(app, argc, argv);
  if (!run.empty()) {
    namespace fs = std::filesystem;
    const material_maps truth = read_maps(fs::path(run) / "truth");
    const material_maps a = read_maps(fs::path(run) / first), b = read_maps(fs::path(run) / second);
    const capture rc = read_capture(fs::path(run) / "rectified" / "capture.json");
    const int w = truth.width(), h = truth.height();
    std::vector<image> masks;
    for (const auto& im : rc.images) masks.push_back(read_mask(fs::path(run) / "rectified" / im.mask, w, h));
    // Classes: images leaving the texel out (0, 1, 2, 3+), the lowest weight (<0.25, <0.5, <1, 1), row band.
    std::array<tally, 4> out_a, out_b, low_a, low_b;
    std::array<tally, 8> row_a, row_b;
    for (int y = 0; y < h; ++y)
      for (int x = 0; x < w; ++x) {
        int left_out = 0;
        double lowest = 1;
        for (const auto& m : masks) {
          const float v = m.at(0, x, y);
          left_out += v == 0;
          if (v > 0) lowest = std::min(lowest, double(v));
        }
        double ea = 0, eb = 0;
        for (int c = 0; c < 3; ++c) {
          ea += std::pow(a.at(diffuse_r + c, x, y) - truth.at(diffuse_r + c, x, y), 2) / 3;
          eb += std::pow(b.at(diffuse_r + c, x, y) - truth.at(diffuse_r + c, x, y), 2) / 3;
        }
        const std::size_t o = std::size_t(std::min(left_out, 3));
        out_a[o].add(ea); out_b[o].add(eb);
        const std::size_t l = lowest < 0.25 ? 0 : lowest < 0.5 ? 1 : lowest < 1 ? 2 : 3;
        low_a[l].add(ea); low_b[l].add(eb);
        const std::size_t r = std::size_t(y * 8 / h);
        row_a[r].add(ea); row_b[r].add(eb);
      }
    std::printf("| texels | count | share of %s's squared error | %s MSE | %s MSE |\n|---|---|---|---|---|\n", second.c_str(), first.c_str(), second.c_str());
    double total_b = 0;
    for (const auto& t : out_b) total_b += t.sum;
    const char* out_names[] = {"in every image's loss", "left out of 1 image", "left out of 2", "left out of 3+"};
    for (int i = 0; i < 4; ++i)
      std::printf("| %s | %zu | %.1f%% | %.5f | %.5f |\n", out_names[i], out_b[std::size_t(i)].n, 100 * out_b[std::size_t(i)].sum / total_b,
                  out_a[std::size_t(i)].mean(), out_b[std::size_t(i)].mean());
    const char* low_names[] = {"lowest weight < 0.25", "lowest weight 0.25-0.5", "lowest weight 0.5-1", "every weight 1"};
    for (int i = 0; i < 4; ++i)
      std::printf("| %s | %zu | %.1f%% | %.5f | %.5f |\n", low_names[i], low_b[std::size_t(i)].n, 100 * low_b[std::size_t(i)].sum / total_b,
                  low_a[std::size_t(i)].mean(), low_b[std::size_t(i)].mean());
    for (int i = 0; i < 8; ++i)
      std::printf("| rows %d-%d | %zu | %.1f%% | %.5f | %.5f |\n", i * h / 8, (i + 1) * h / 8 - 1, row_b[std::size_t(i)].n,
                  100 * row_b[std::size_t(i)].sum / total_b, row_a[std::size_t(i)].mean(), row_b[std::size_t(i)].mean());
    return 0;
  }

  const material_maps truth = generate_material(seed, size, size);
  const capture configurations = set_alpha(images, seed, size, size);
  photo_synthesis_options o;
  o.width = photo_width;
  o.height = photo_height;
  o.lookup = texture_lookup::nearest;
  o.flash = flash;
  o.noise.shot = 0.01;
  o.noise.read = 0.002;
  o.seed = seed;
  const synthetic_photographs photos = photograph_capture(truth, configurations, o);
  write_synthetic_photographs(photos, out);
  const std::vector<image> reference = render(truth, photos.texture_capture);
  const double longest = o.longest_mm;
  const char* step_names[] = {"linear", "+noise", "+8-bit", "+JPEG"};
  std::printf("| image | camera z | min px/texel | texels < 1 px | direct | linear | +noise | +8-bit | +JPEG | JPEG, >= 1 px | JPEG, < 1 px | masked |\n");
  std::printf("|---|---|---|---|---|---|---|---|---|---|---|---|\n");
  // Per margin, per density bin (photo pixels across the texel along its narrower axis): the JPEG
  // rectification's mean log difference over every image, and the direct capture's.
  const double edges[] = {0, 1, 1.5, 2, 2.5, 3, 4, 6, 1e9};
  constexpr int bins = 8;
  std::vector<std::array<tally, bins>> by_margin(margins.size());
  std::array<tally, bins> direct_bins;
  for (std::size_t i = 0; i < photos.setups.size(); ++i) {
    const photo_setup& setup = photos.setups[i];
    const double e = photos.exposures[i];
    const float intensity_scale = 1.0f;
    (void)intensity_scale;
    image linear = render_photograph(truth, longest, setup, o.width, o.height, o.samples_per_axis, o.lookup);
    for (int c = 0; c < 3; ++c)
      for (std::size_t k = 0; k < linear.pixel_count(); ++k) linear.plane(c)[k] *= float(e);
    image noisy = linear;
    add_sensor_noise(noisy, o.noise, hash64(o.seed + 0x70686f746fULL * (i + 1)));
    image usable;
    const image quantised = to_8bit_srgb(noisy, usable);
    const photo jpeg = read_photo(std::filesystem::path(out) / photos.description.photos[i].file);
    // Direct: the texture-space render with the same noise model at the same exposure.
    image direct = reference[i];
    for (int c = 0; c < 3; ++c)
      for (std::size_t k = 0; k < direct.pixel_count(); ++k) direct.plane(c)[k] *= float(e);
    add_sensor_noise(direct, o.noise, hash64(seed ^ (0x646972656374ULL + i)));
    for (int c = 0; c < 3; ++c)
      for (std::size_t k = 0; k < direct.pixel_count(); ++k) direct.plane(c)[k] /= float(e);
    const image* sources[] = {&linear, &noisy, &quantised, &jpeg.pixels};
    const image empty;
    const image* masks[] = {&empty, &empty, &usable, &jpeg.mask};
    double means[4];
    tally dense, sparse;
    std::size_t masked = 0;
    rectified_photo last;
    for (int s = 0; s < 4; ++s) {
      rectified_photo r = rectify_photo(*sources[s], *masks[s], setup.camera, setup.pose, size, size, longest, resampling);
      tally t;
      for (std::size_t k = 0; k < r.mask.pixel_count(); ++k) {
        if (r.mask.plane(0)[k] == 0) continue;
        // The rectified image is in photo units (exposure x radiance): back to the renderer's.
        image one(1, 1, 3);
        for (int c = 0; c < 3; ++c) one.plane(c)[0] = r.radiance.plane(c)[k] / float(e);
        image ref(1, 1, 3);
        for (int c = 0; c < 3; ++c) ref.plane(c)[0] = reference[i].plane(c)[k];
        t.add(log_difference(one, ref, 0));
      }
      means[s] = t.mean();
      if (s == 3) last = std::move(r);
    }
    // Density per texel from the homography (finite differences across the texel).
    Eigen::Matrix3d h;
    h.col(0) = setup.pose.rotation.col(0);
    h.col(1) = setup.pose.rotation.col(1);
    h.col(2) = setup.pose.translation;
    h = setup.camera.matrix() * h;
    auto to_pixel = [&](double u, double v) {
      const Eigen::Vector3d s = texture_to_sample(u, v, size, size, longest);
      const Eigen::Vector3d q = h * Eigen::Vector3d(s.x(), s.y(), 1.0);
      return Eigen::Vector2d(q.x() / q.z(), q.y() / q.z());
    };
    double min_density = 1e30;
    std::size_t below = 0;
    tally direct_error;
    for (int y = 0; y < size; ++y)
      for (int x = 0; x < size; ++x) {
        const Eigen::Vector2d du = to_pixel(x + 1.0, y + 0.5) - to_pixel(x, y + 0.5);
        const Eigen::Vector2d dv = to_pixel(x + 0.5, y + 1.0) - to_pixel(x + 0.5, y);
        const double density = std::sqrt(std::abs(du.x() * dv.y() - du.y() * dv.x()));
        min_density = std::min(min_density, density);
        const std::size_t k = std::size_t(y) * size + x;
        below += density < 1;
        direct_error.add(log_difference(direct, reference[i], k));
        if (last.mask.plane(0)[k] == 0) {
          ++masked;
          continue;
        }
        image one(1, 1, 3);
        for (int c = 0; c < 3; ++c) one.plane(c)[0] = last.radiance.plane(c)[k] / float(e);
        image ref(1, 1, 3);
        for (int c = 0; c < 3; ++c) ref.plane(c)[0] = reference[i].plane(c)[k];
        (density >= 1 ? dense : sparse).add(log_difference(one, ref, 0));
      }
    for (std::size_t m = 0; m < margins.size(); ++m) {
      resampling_options rm = resampling;
      rm.margin_px = margins[m];
      const rectified_photo r = rectify_photo(jpeg.pixels, jpeg.mask, setup.camera, setup.pose, size, size, longest, rm);
      for (int y = 0; y < size; ++y)
        for (int x = 0; x < size; ++x) {
          const Eigen::Vector2d du = to_pixel(x + 1.0, y + 0.5) - to_pixel(x, y + 0.5);
          const Eigen::Vector2d dv = to_pixel(x + 0.5, y + 1.0) - to_pixel(x + 0.5, y);
          const double narrow = std::min(du.norm(), dv.norm());
          int b = 0;
          while (b + 1 < bins && narrow >= edges[b + 1]) ++b;
          const std::size_t k = std::size_t(y) * size + x;
          if (m == 0) direct_bins[std::size_t(b)].add(log_difference(direct, reference[i], k));
          if (r.mask.plane(0)[k] == 0) continue;
          image one(1, 1, 3);
          for (int c = 0; c < 3; ++c) one.plane(c)[0] = r.radiance.plane(c)[k] / float(e);
          image ref(1, 1, 3);
          for (int c = 0; c < 3; ++c) ref.plane(c)[0] = reference[i].plane(c)[k];
          by_margin[m][std::size_t(b)].add(log_difference(one, ref, 0));
        }
    }
    std::printf("| %zu | %.2f | %.2f | %.1f%% | %.4f | %.4f | %.4f | %.4f | %.4f | %.4f | %.4f (%zu) | %.1f%% |\n", i,
                double(photos.texture_capture.images[i].camera[2]), min_density, 100.0 * double(below) / (size * size), direct_error.mean(),
                means[0], means[1], means[2], means[3], dense.mean(), sparse.mean(), sparse.n, 100.0 * double(masked) / (size * size));
  }
  (void)step_names;
  std::printf("\n| px across the texel (narrower axis) | texels | direct |");
  for (double m : margins) std::printf(" margin %.2g px |", m);
  std::printf("\n|---|---|---|");
  for (std::size_t m = 0; m < margins.size(); ++m) std::printf("---|");
  std::printf("\n");
  for (int b = 0; b < bins; ++b) {
    if (direct_bins[std::size_t(b)].n == 0) continue;
    std::printf("| %.3g-%.3g | %zu | %.4f |", edges[b], edges[b + 1], direct_bins[std::size_t(b)].n, direct_bins[std::size_t(b)].mean());
    for (std::size_t m = 0; m < margins.size(); ++m) std::printf(" %.4f |", by_margin[m][std::size_t(b)].mean());
    std::printf("\n");
  }
  return 0;
}
