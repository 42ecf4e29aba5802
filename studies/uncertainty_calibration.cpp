// Whether the per-texel standard deviations (pipeline/uncertainty.hpp) are calibrated: over
// synthetic captures with sensor noise, the share of texels whose true value lies within 1 and 2
// standard deviations of the captured one, per parameter (68% and 95% for a calibrated Gaussian).
//
// For each family (one seeded procedural material each), each image count and each light (set
// alpha's separate lamp, or a phone's flash beside the lens), the default capture with the shipped
// networks runs on renders with shot and read noise; the coverage is counted over every texel
// (alpha only where the true lobe is anisotropic, |sx - sy| > 0.2 max(sx, sy), since alpha means
// nothing on an isotropic one). Prints a markdown table; with --dump FILE it writes every counted
// texel (family, light, images, parameter, error, standard deviation, true value, remaining step)
// as CSV, for a reliability plot and for fitting the calibration of pipeline/uncertainty.hpp on one
// seed set and testing it on another (--seed). --jpeg Q stores each noisy photograph as an 8-bit
// sRGB JPEG of quality Q (exposed so that its brightest 0.5% clip) and reads it back, as a phone
// does (with the encoding a capture from such files has, so that its calibration applies); --png8 1
// stores them as 8-bit sRGB codes without JPEG, as an 8-bit PNG does.
// --raw reports the uncalibrated standard deviations (uncertainty_options::calibrated off). The
// records hold each texel's remaining Gauss-Newton step beside them (uncertainty_result::step).
//
//   anisocap_study_uncertainty_calibration [--size 96] [--images 8,12] [--shot 0.01] [--read 0.002]
//       [--families plain,twill,...] [--lights lamp,flash] [--seed 500] [--jpeg 0|Q] [--png8 0|1] [--raw 0|1]
//       [--dump FILE] [--models DIR]
#include <stb/stb_image.h>
#include <stb/stb_image_write.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <cstdlib>
#include <memory>
#include <numbers>
#include <sstream>
#include <string>
#include <vector>

#include "anisocap/brdf/canonical_maps.hpp"
#include "anisocap/core/srgb.hpp"
#include "anisocap/data/procedural.hpp"
#include "anisocap/pipeline/capture_material.hpp"
#include "anisocap/render/configurations.hpp"
#include "anisocap/render/sensor_noise.hpp"

using namespace anisocap;

namespace {

std::vector<std::string> split(const std::string& text) {
  std::vector<std::string> out;
  std::stringstream in(text);
  for (std::string item; std::getline(in, item, ',');) out.push_back(item);
  return out;
}

/// The difference of two rotations, wrapped to [-pi/2, pi/2) (alpha and alpha + pi are one lobe).
double rotation_difference(double a, double b) {
  double d = std::fmod(a - b + 0.5 * std::numbers::pi, std::numbers::pi);
  if (d < 0) d += std::numbers::pi;
  return d - 0.5 * std::numbers::pi;
}

/// Each photograph as a phone stores it: exposed so that its brightest 0.5% of values clip, sRGB
/// encoded to 8 bits, JPEG of `quality` (0: the 8-bit codes as a PNG keeps them), decoded and taken
/// back to linear at the same exposure. Returns how the files stored the photographs (stb
/// subsamples the colour at quality 90 and below).
photo_encoding eight_bit_round_trip(std::vector<image>& photos, int quality) {
  bool subsampled = false;
  for (image& photo : photos) {
    std::vector<float> values(photo.plane(0), photo.plane(0) + photo.pixel_count() * std::size_t(photo.channels()));
    std::nth_element(values.begin(), values.begin() + std::ptrdiff_t(values.size() * 995 / 1000), values.end());
    const float white = std::max(values[values.size() * 995 / 1000], 1e-6f);
    const int w = photo.width(), h = photo.height();
    std::vector<unsigned char> pixels(std::size_t(w) * h * 3);
    for (int y = 0; y < h; ++y)
      for (int x = 0; x < w; ++x)
        for (int c = 0; c < 3; ++c)
          pixels[(std::size_t(y) * w + x) * 3 + c] = (unsigned char)std::lround(255.0 * linear_to_srgb(std::clamp(photo.at(c, x, y) / white, 0.0f, 1.0f)));
    std::unique_ptr<unsigned char, void (*)(void*)> decoded(nullptr, &stbi_image_free);
    if (quality > 0) {
      std::vector<unsigned char> bytes;
      auto append = [](void* context, void* data, int size) {
        auto* out = static_cast<std::vector<unsigned char>*>(context);
        out->insert(out->end(), static_cast<unsigned char*>(data), static_cast<unsigned char*>(data) + size);
      };
      if (!stbi_write_jpg_to_func(append, &bytes, w, h, 3, pixels.data(), quality)) throw std::runtime_error("JPEG encoding failed");
      subsampled = subsampled || jpeg_colour_subsampled(bytes);
      int rw = 0, rh = 0, rc = 0;
      decoded.reset(stbi_load_from_memory(bytes.data(), int(bytes.size()), &rw, &rh, &rc, 3));
      if (!decoded || rw != w || rh != h) throw std::runtime_error("JPEG decoding failed");
    }
    const unsigned char* codes = decoded ? decoded.get() : pixels.data();  // the PNG keeps the codes as they are
    for (int y = 0; y < h; ++y)
      for (int x = 0; x < w; ++x)
        for (int c = 0; c < 3; ++c) photo.at(c, x, y) = float(srgb_to_linear(codes[(std::size_t(y) * w + x) * 3 + c] / 255.0)) * white;
  }
  return quality == 0 ? photo_encoding::eight_bit : subsampled ? photo_encoding::jpeg_subsampled : photo_encoding::jpeg;
}

}  // namespace

int main(int argc, char** argv) {
  int size = 96;
  std::string images = "8,12", families = "plain,basket,twill,herringbone,satin,velvet,brushed,spun", lights = "lamp,flash";
  std::string models = ANISOCAP_SWEEP_MODELS;
  sensor_noise noise{0.01, 0.002};
  std::uint64_t seed_base = 500;
  int jpeg = 0;
  bool raw = false, png8 = false;
  std::string dump;
  for (int i = 1; i + 1 < argc; i += 2) {
    const std::string a = argv[i], v = argv[i + 1];
    if (a == "--size") size = std::atoi(v.c_str());
    else if (a == "--images") images = v;
    else if (a == "--families") families = v;
    else if (a == "--lights") lights = v;
    else if (a == "--models") models = v;
    else if (a == "--shot") noise.shot = std::atof(v.c_str());
    else if (a == "--read") noise.read = std::atof(v.c_str());
    else if (a == "--seed") seed_base = std::strtoull(v.c_str(), nullptr, 10);
    else if (a == "--jpeg") jpeg = std::atoi(v.c_str());
    else if (a == "--raw") raw = std::atoi(v.c_str()) != 0;
    else if (a == "--png8") png8 = std::atoi(v.c_str()) != 0;
    else if (a == "--dump") dump = v;
    else { std::fprintf(stderr, "uncertainty_calibration: unknown option %s\n", a.c_str()); return 2; }
  }
  if (argc % 2 == 0) { std::fprintf(stderr, "uncertainty_calibration: an option without its value\n"); return 2; }
  try {
    const networks nets = load_networks(models);
    std::ofstream records;
    if (!dump.empty()) {
      records.open(dump);
      if (!records) throw std::runtime_error("cannot write " + dump);
      records << "family,light,images,parameter,error,sd,truth,step\n";
    }
    capture_options options;
    options.uncertainty->calibrated = !raw;
    std::array<double, parameter_count> within1{}, within2{}, counted{};
    int run = 0;
    for (const material_kind kind : material_kinds_from_names(families))
      for (const std::string& count_text : split(images))
        for (const std::string& light : split(lights)) {
          const int count = std::atoi(count_text.c_str());
          const std::uint64_t seed = seed_base + std::uint64_t(run++);
          procedural_options po;
          po.kind = kind;
          material_maps truth = generate_material(seed, size, size, po);
          canonicalise(truth);
          capture cap = set_alpha(count, seed, size, size);
          if (light == "flash")
            for (capture_image& im : cap.images) {
              im.light = im.camera;
              im.light[0] += 0.05f;
            }
          else if (light != "lamp") throw std::invalid_argument("--lights takes lamp and flash");
          std::vector<image> photos = render(truth, cap);
          add_sensor_noise(photos, noise, seed);
          if (jpeg > 0 || png8) {
            const photo_encoding encoding = eight_bit_round_trip(photos, png8 ? 0 : jpeg);
            for (capture_image& im : cap.images) im.encoding = encoding;  // as capture reads such files
          }
          const capture_result r = capture_material(cap, photos, nets, options);
          const material_maps& sd = r.uncertainty->sd;
          std::array<double, parameter_count> in1{}, in2{}, n{};
          for (std::size_t i = 0; i < truth.texel_count(); ++i) {
            const float sx = truth.plane(lobe_x)[i], sy = truth.plane(lobe_y)[i];
            for (int k = 0; k < parameter_count; ++k) {
              if (k == rotation && !(std::abs(sx - sy) > 0.2f * std::max(sx, sy))) continue;
              const double error = k == rotation ? rotation_difference(r.maps.plane(k)[i], truth.plane(k)[i])
                                                 : double(r.maps.plane(k)[i]) - truth.plane(k)[i];
              const double s = sd.plane(k)[i];
              n[std::size_t(k)] += 1;
              in1[std::size_t(k)] += std::abs(error) <= s;
              in2[std::size_t(k)] += std::abs(error) <= 2 * s;
              if (records)
                records << material_kind_name(kind) << ',' << light << ',' << count << ',' << parameter_name(k) << ',' << error << ','
                        << s << ',' << truth.plane(k)[i] << ',' << r.uncertainty->step.plane(k)[i] << '\n';
            }
          }
          std::printf("%-12s N=%-2d %-5s", material_kind_name(kind), count, light.c_str());
          for (int k = 0; k < parameter_count; ++k) {
            within1[std::size_t(k)] += in1[std::size_t(k)];
            within2[std::size_t(k)] += in2[std::size_t(k)];
            counted[std::size_t(k)] += n[std::size_t(k)];
            if (n[std::size_t(k)] > 0) std::printf(" %s %.0f/%.0f", parameter_name(k), 100 * in1[std::size_t(k)] / n[std::size_t(k)],
                                                   100 * in2[std::size_t(k)] / n[std::size_t(k)]);
          }
          std::printf("\n");
          std::fflush(stdout);
        }
    std::printf("\n| parameter | within 1 sd (68%%) | within 2 sd (95%%) |\n|---|---|---|\n");
    for (int k = 0; k < parameter_count; ++k)
      if (counted[std::size_t(k)] > 0)
        std::printf("| %s | %.0f%% | %.0f%% |\n", parameter_name(k), 100 * within1[std::size_t(k)] / counted[std::size_t(k)],
                    100 * within2[std::size_t(k)] / counted[std::size_t(k)]);
  } catch (const std::exception& e) {
    std::fprintf(stderr, "uncertainty_calibration: %s\n", e.what());
    return 1;
  }
}
