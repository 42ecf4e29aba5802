// The `anisocap._anisocap` extension module: the library's calls on NumPy arrays (pybind11).
//
// One translation unit, since the capture pipeline for the shipped presets is most of the compile
// time (docs/library.md) and would be paid again in every unit that loads networks. The pure-Python
// package (package/anisocap/__init__.py) documents the calls and adds what reads better in
// Python (paths, defaults, the weights' search beside the installed package).
//
// Arrays: a map set is H x W x 12 float32 (the planes in parameter_index order), a photograph or a
// rendering H x W x 3, a mask H x W. The library stores images planar with padded planes, so every
// array is copied once on the way in and once on the way out; any strides are accepted. Inputs of
// another dtype, shape or with a NaN or infinite value raise TypeError or ValueError naming the
// argument. Long calls release the GIL; `capture` and `rectify` report progress through an optional
// callback, and a pending signal (Ctrl-C) or an exception raised by the callback stops them.
#include <pybind11/functional.h>
#include <pybind11/numpy.h>
#include <pybind11/pybind11.h>
#include <pybind11/stl.h>
#include <pybind11/stl/filesystem.h>

#include <cmath>
#include <filesystem>
#include <list>
#include <mutex>
#include <optional>
#include <string>
#include <vector>

#include "anisocap/brdf/canonical_maps.hpp"
#include "anisocap/calibration/markers.hpp"
#include "anisocap/calibration/rectify.hpp"
#include "anisocap/core/option_names.hpp"
#include "anisocap/data/capture_io.hpp"
#include "anisocap/data/map_io.hpp"
#include "anisocap/data/photo_io.hpp"
#include "anisocap/data/procedural.hpp"
#include "anisocap/export/export.hpp"
#include "anisocap/pipeline/capture_material.hpp"
#include "anisocap/render/configurations.hpp"
#include "anisocap/render/renderer.hpp"
#include "anisocap/render/sensor_noise.hpp"

namespace py = pybind11;
namespace fs = std::filesystem;
using namespace anisocap;

namespace {

using farray = py::array_t<float, py::array::c_style>;

/// The array `obj` as float32 with `ndim` dimensions, the last `channels` long (0: any), else a
/// TypeError (dtype) or ValueError (shape) naming `what`.
py::array checked_array(const py::handle& obj, const std::string& what, int ndim, int channels) {
  if (!py::isinstance<py::array>(obj)) throw py::type_error(what + ": expected a numpy array, got " + std::string(py::str(py::type::of(obj))));
  auto a = py::reinterpret_borrow<py::array>(obj);
  if (!a.dtype().is(py::dtype::of<float>()))
    throw py::type_error(what + ": expected dtype float32, got " + std::string(py::str(a.dtype())));
  if (a.ndim() != ndim)
    throw py::value_error(what + ": expected " + std::to_string(ndim) + " dimensions (" + (ndim == 3 ? "height x width x channels" : "height x width") +
                          "), got " + std::to_string(a.ndim()));
  if (channels > 0 && a.shape(ndim - 1) != channels)
    throw py::value_error(what + ": expected " + std::to_string(channels) + " channels in the last dimension, got " + std::to_string(a.shape(ndim - 1)));
  if (a.shape(0) <= 0 || a.shape(1) <= 0) throw py::value_error(what + ": empty array");
  return a;
}

/// Reads element (y, x, c) of a float32 array of any strides.
inline float element(const py::array& a, py::ssize_t y, py::ssize_t x, py::ssize_t c) {
  const auto* base = static_cast<const char*>(a.data());
  return *reinterpret_cast<const float*>(base + y * a.strides(0) + x * a.strides(1) + (a.ndim() == 3 ? c * a.strides(2) : 0));
}

[[noreturn]] void not_finite(const std::string& what, py::ssize_t y, py::ssize_t x, py::ssize_t c) {
  throw py::value_error(what + ": NaN or infinite value at row " + std::to_string(y) + ", column " + std::to_string(x) +
                        (c >= 0 ? ", channel " + std::to_string(c) : std::string()));
}

/// H x W x 12 array to a map set (planes in parameter_index order).
material_maps to_maps(const py::handle& obj, const std::string& what = "maps") {
  const py::array a = checked_array(obj, what, 3, parameter_count);
  material_maps m(int(a.shape(1)), int(a.shape(0)));
  for (py::ssize_t y = 0; y < a.shape(0); ++y)
    for (py::ssize_t x = 0; x < a.shape(1); ++x)
      for (int k = 0; k < parameter_count; ++k) {
        const float v = element(a, y, x, k);
        if (!std::isfinite(v)) not_finite(what, y, x, k);
        m.at(k, int(x), int(y)) = v;
      }
  return m;
}

farray from_maps(const material_maps& m) {
  farray out({py::ssize_t(m.height()), py::ssize_t(m.width()), py::ssize_t(parameter_count)});
  auto r = out.mutable_unchecked<3>();
  for (int y = 0; y < m.height(); ++y)
    for (int x = 0; x < m.width(); ++x)
      for (int k = 0; k < parameter_count; ++k) r(y, x, k) = m.at(k, x, y);
  return out;
}

/// H x W x C (ndim 3) or H x W (ndim 2, one channel) array to an image.
image to_image(const py::handle& obj, const std::string& what, int ndim, int channels) {
  const py::array a = checked_array(obj, what, ndim, channels);
  const int c_count = ndim == 3 ? int(a.shape(2)) : 1;
  image im(int(a.shape(1)), int(a.shape(0)), c_count);
  for (py::ssize_t y = 0; y < a.shape(0); ++y)
    for (py::ssize_t x = 0; x < a.shape(1); ++x)
      for (int c = 0; c < c_count; ++c) {
        const float v = element(a, y, x, c);
        if (!std::isfinite(v)) not_finite(what, y, x, ndim == 3 ? c : -1);
        im.at(c, int(x), int(y)) = v;
      }
  return im;
}

farray from_image(const image& im) {
  if (im.channels() == 1) {
    farray out({py::ssize_t(im.height()), py::ssize_t(im.width())});
    auto r = out.mutable_unchecked<2>();
    for (int y = 0; y < im.height(); ++y)
      for (int x = 0; x < im.width(); ++x) r(y, x) = im.at(0, x, y);
    return out;
  }
  farray out({py::ssize_t(im.height()), py::ssize_t(im.width()), py::ssize_t(im.channels())});
  auto r = out.mutable_unchecked<3>();
  for (int y = 0; y < im.height(); ++y)
    for (int x = 0; x < im.width(); ++x)
      for (int c = 0; c < im.channels(); ++c) r(y, x, c) = im.at(c, x, y);
  return out;
}

/// A sequence of arrays (a list, or an N x H x W x C array) to images of the same size.
std::vector<image> to_images(const py::handle& obj, const std::string& what, int ndim, int channels) {
  if (py::isinstance<py::str>(obj) || !py::isinstance<py::sequence>(obj))
    throw py::type_error(what + ": expected a list of numpy arrays or one array with the images along the first axis");
  std::vector<image> out;
  std::size_t i = 0;
  for (const py::handle item : obj) {
    out.push_back(to_image(item, what + "[" + std::to_string(i) + "]", ndim, channels));
    if (out.back().width() != out.front().width() || out.back().height() != out.front().height())
      throw py::value_error(what + "[" + std::to_string(i) + "]: " + std::to_string(out.back().height()) + " x " +
                            std::to_string(out.back().width()) + ", the first is " + std::to_string(out.front().height()) + " x " +
                            std::to_string(out.front().width()));
    ++i;
  }
  if (out.empty()) throw py::value_error(what + ": no images");
  return out;
}

py::array from_images(const std::vector<image>& images) {
  py::list l;
  for (const image& im : images) l.append(from_image(im));
  return py::module_::import("numpy").attr("stack")(l);
}

capture to_capture(const std::vector<capture_image>& configurations, const std::string& what = "configurations") {
  if (configurations.empty()) throw py::value_error(what + ": no configurations");
  for (std::size_t i = 0; i < configurations.size(); ++i) {
    const capture_image& c = configurations[i];
    for (float v : {c.camera[0], c.camera[1], c.camera[2], c.light[0], c.light[1], c.light[2], c.intensity[0], c.intensity[1], c.intensity[2]})
      if (!std::isfinite(v)) throw py::value_error(what + "[" + std::to_string(i) + "]: NaN or infinite camera, light or intensity");
  }
  return capture{configurations};
}

/// The features of a kernel name (full, isotropic, no-fresnel, flat, isotropic-flat, lambert-like).
brdf_features features_of(const std::string& name) {
  if (name == "auto") throw py::value_error("features: 'auto' chooses a kernel inside capture only; name one of full, isotropic, no-fresnel, flat, isotropic-flat, lambert-like");
  return kernel_options::parse(name).features;
}

render_options render_options_of(const std::string& precision, float cull) {
  if (precision != "float" && precision != "double") throw py::value_error("precision: float or double, got '" + precision + "'");
  if (!(cull >= 0 && cull <= 1)) throw py::value_error("cull: a tolerance in [0, 1]");
  render_options o;
  o.double_precision = precision == "double";
  o.cull_tolerance = cull;
  return o;
}

void check_size(const material_maps& m, int width, int height, const std::string& what) {
  if (m.width() != width || m.height() != height)
    throw py::value_error("maps are " + std::to_string(m.height()) + " x " + std::to_string(m.width()) + " but " + what + " are " +
                          std::to_string(height) + " x " + std::to_string(width));
}

/// Calls a Python progress callback from a long call with the GIL released: takes the GIL, checks
/// for a pending signal (Ctrl-C) and calls the callback; a Python exception from either propagates
/// out of the C++ call as py::error_already_set, which stops it.
struct progress_hook {
  py::object callback;
  void operator()(const std::string& stage, int step, int steps, double loss) const {
    py::gil_scoped_acquire gil;
    if (PyErr_CheckSignals() != 0) throw py::error_already_set();
    if (!callback.is_none()) callback(stage, step, steps, loss);
  }
};

/// The precomputed loss targets of photographs (max(B, floor) + 0.01, masks, floors), reused across calls.
struct py_targets {
  loss_targets targets;
};

py_targets make_targets(const py::handle& photos, const py::object& masks, const std::optional<std::vector<float>>& floors) {
  std::vector<image> p = to_images(photos, "photos", 3, 3);
  std::vector<image> m;
  if (!masks.is_none()) m = to_images(masks, "masks", 2, 0);
  py_targets t;
  py::gil_scoped_release release;
  t.targets = make_loss_targets(p, m, floors ? *floors : std::vector<float>{});
  return t;
}

py::tuple loss_and_gradient_py(const py::handle& maps_obj, const std::vector<capture_image>& configurations, const py_targets& t,
                               const std::string& features, const std::string& precision, float cull, bool gradient) {
  const material_maps maps = to_maps(maps_obj);
  const capture cap = to_capture(configurations);
  check_size(maps, t.targets.width, t.targets.height, "the photographs");
  if (cap.images.size() != t.targets.images.size())
    throw py::value_error(std::to_string(cap.images.size()) + " configurations for " + std::to_string(t.targets.images.size()) + " photographs");
  const brdf_features f = features_of(features);
  const render_options o = render_options_of(precision, cull);
  std::optional<material_maps> grad;
  if (gradient) grad.emplace(maps.width(), maps.height());
  double loss = 0;
  {
    py::gil_scoped_release release;
    loss = with_features(f, [&]<brdf_features F>() {
      return loss_and_gradient<F>(maps, cap, t.targets, grad ? &*grad : nullptr, {}, o);
    });
  }
  if (!grad) return py::make_tuple(loss, py::none());
  return py::make_tuple(loss, from_maps(*grad));
}

py::array render_py(const py::handle& maps_obj, const std::vector<capture_image>& configurations, const std::string& features,
                    const std::string& precision) {
  const material_maps maps = to_maps(maps_obj);
  const capture cap = to_capture(configurations);
  const brdf_features f = features_of(features);
  if (precision != "float" && precision != "double") throw py::value_error("precision: float or double, got '" + precision + "'");
  std::vector<image> images;
  {
    py::gil_scoped_release release;
    images = with_features(f, [&]<brdf_features F>() {
      return precision == "double" ? render<F, simd::batch<double>>(maps, cap) : render<F>(maps, cap);
    });
  }
  return from_images(images);
}

py::dict synthesize_py(int width, int height, int images, const std::string& set, std::uint64_t seed, const std::string& kind,
                       const std::string& mix, int fresnel_count, double shot_noise, double read_noise) {
  if (width < 1 || height < 1) throw py::value_error("width and height must be positive");
  if (images < 4) throw py::value_error("images must be at least 4 (set alpha needs 2 Fresnel and 2 independent)");
  procedural_options options;
  const auto m = material_mix_from_name(mix);
  if (!m) throw py::value_error("unknown mix '" + mix + "' (original, extended or training)");
  options.mix = *m;
  if (!kind.empty()) {
    options.kind = material_kind_from_name(kind);
    if (!options.kind) throw py::value_error("unknown kind '" + kind + "'");
  }
  if (set != "alpha" && set != "beta") throw py::value_error("set must be alpha or beta, got '" + set + "'");
  if (fresnel_count < 0) throw py::value_error("fresnel: the number of Fresnel configurations must be >= 0");
  sensor_noise noise;
  noise.shot = shot_noise;
  noise.read = read_noise;
  noise.validate();
  material_maps truth;
  capture cap;
  std::vector<image> photos;
  {
    py::gil_scoped_release release;
    truth = generate_material(seed, width, height, options);
    canonicalise(truth);
    fresnel_options fresnel;
    fresnel.count = fresnel_count;
    cap = set == "alpha" ? set_alpha(images, seed, width, height, fresnel) : set_beta(images, seed, width, height);
    photos = render(truth, cap);
    add_sensor_noise(photos, noise, seed);
  }
  py::dict out;
  out["maps"] = from_maps(truth);
  out["configurations"] = cap.images;
  out["photos"] = from_images(photos);
  out["kind"] = std::string(material_kind_name(draw_procedural_parameters(seed, options).kind));
  return out;
}

py::dict read_capture_py(const fs::path& file, float saturation, bool exclude_clipped) {
  photo_options po;
  po.saturation = saturation;
  po.exclude_clipped = exclude_clipped;
  capture_photographs c;
  {
    py::gil_scoped_release release;
    c = read_capture_photographs(file, po);
  }
  py::dict out;
  out["configurations"] = c.description.images;
  out["photos"] = from_images(c.pixels());
  out["masks"] = from_images(c.masks());
  return out;
}

/// A capture's configurations with its photographs and optional masks, checked to match in count.
struct capture_input {
  capture cap;
  std::vector<image> photos, masks;
};

capture_input capture_input_py(const std::vector<capture_image>& configurations, const py::handle& photos_obj, const py::object& masks_obj) {
  capture_input in{to_capture(configurations), to_images(photos_obj, "photos", 3, 3), {}};
  if (!masks_obj.is_none()) in.masks = to_images(masks_obj, "masks", 2, 0);
  if (in.photos.size() != in.cap.images.size())
    throw py::value_error(std::to_string(in.photos.size()) + " photographs for " + std::to_string(in.cap.images.size()) + " configurations");
  if (!in.masks.empty() && in.masks.size() != in.photos.size())
    throw py::value_error(std::to_string(in.masks.size()) + " masks for " + std::to_string(in.photos.size()) + " photographs");
  return in;
}

void write_capture_py(const std::vector<capture_image>& configurations, const py::handle& photos_obj, const py::object& masks_obj,
                      const fs::path& folder) {
  const capture_input in = capture_input_py(configurations, photos_obj, masks_obj);
  const capture& cap = in.cap;
  const std::vector<image>& photos = in.photos;
  const std::vector<image>& masks = in.masks;
  for (std::size_t i = 0; i < cap.images.size(); ++i) {
    const fs::path f(cap.images[i].file);
    if (f.empty() || f.is_absolute() || f.extension() != ".exr" || *f.begin() == "..")
      throw py::value_error("configurations[" + std::to_string(i) + "].file: a relative .exr name inside the folder, got '" + f.string() + "'");
    if (!masks.empty() && (cap.images[i].mask.empty() || fs::path(cap.images[i].mask).extension() != ".png"))
      throw py::value_error("configurations[" + std::to_string(i) + "].mask: a relative .png name for its mask");
  }
  py::gil_scoped_release release;
  fs::create_directories(folder);
  file_transaction files;
  for (std::size_t i = 0; i < photos.size(); ++i) {
    write_exr(photos[i], folder / cap.images[i].file, files);
    if (!masks.empty()) write_png(masks[i], folder / cap.images[i].mask, files, 0.0f, png_encoding::linear);
  }
  files.stage(folder / "capture.json", capture_to_json(cap, folder / "capture.json"));
  files.commit();
}

/// Networks loaded once per folder and preset (loading costs about a second; captures reuse them),
/// with a lock: captures from several Python threads share them one at a time.
struct loaded_networks {
  fs::path folder;
  std::string preset;
  std::optional<fs::path> also;
  networks nets;
  std::mutex in_use;
};

/// The cached networks of a folder, loaded on first use (called with the GIL held; a std::list keeps
/// every entry in place while others are added).
loaded_networks& cached_networks(const fs::path& folder, const std::string& preset, const std::optional<fs::path>& also) {
  static std::list<loaded_networks> cache;
  for (loaded_networks& e : cache)
    if (e.folder == folder && e.preset == preset && e.also == also) return e;
  network_options no;
  no.preset = preset;
  no.second_prior = also;
  networks nets = load_networks(folder, no);
  loaded_networks& e = cache.emplace_back();
  e.folder = folder;
  e.preset = preset;
  e.also = also;
  e.nets = std::move(nets);
  return e;
}

py::dict stage_to_dict(const stage_report& s) {
  py::dict d;
  d["name"] = s.name;
  d["ran"] = s.ran;
  d["steps"] = s.steps;
  d["loss"] = s.loss;
  d["seconds"] = s.seconds;
  return d;
}

std::string feature_name(const brdf_features& f) {
  for (const char* name : {"full", "isotropic", "no-fresnel", "flat", "isotropic-flat", "lambert-like"})
    if (kernel_options::parse(name).features == f) return name;
  return "full";
}

/// The capture_options fields that capture() sets by its arguments, named as its users give them.
constexpr option_name capture_argument_names[] = {
    {"finetune_options::steps", "finetune_steps"},
    {"finetune_options::learning_rate", "finetune_lr"},
    {"refine_options::steps", "steps"},
    {"refine_options::learning_rate", "lr"},
    {"refine_options::min_relative_improvement", "refine_stop"},
    {"estimate_options::window", "estimate_window"},
    {"estimate_options::stride", "estimate_stride"},
    {"capture_options::neighbour_restarts", "neighbour_restarts"},
    {"capture_options::network_precision", "network_precision"},
    {"pipeline_stages", "stages"},
    {"kernel_options", "kernel"},
};

/// The capture_options capture() builds from its arguments: the schedule, then each override
/// given, validated; messages name the arguments (capture_argument_names).
capture_options capture_options_py(const std::string& stages, const std::string& schedule, std::optional<int> estimate_window,
                                   std::optional<int> estimate_stride, std::optional<int> finetune_steps,
                                   std::optional<float> finetune_lr, std::optional<int> steps, std::optional<float> lr,
                                   std::optional<double> refine_stop, const std::optional<std::vector<int>>& neighbour_restarts,
                                   const std::string& kernel, const std::string& precision, const std::string& network_precision,
                                   std::optional<bool> second_run) {
  capture_options o;
  o.apply_schedule(schedule);
  if (estimate_window) o.estimate.window = *estimate_window;
  if (estimate_stride) o.estimate.stride = *estimate_stride;
  if (finetune_steps) o.finetune.steps = *finetune_steps;
  if (finetune_lr) o.finetune.learning_rate = *finetune_lr;
  if (steps) o.refine.steps = o.refine_alone.steps = *steps;
  if (lr) o.refine.learning_rate = o.refine_alone.learning_rate = *lr;
  if (refine_stop) o.refine.min_relative_improvement = o.refine_alone.min_relative_improvement = *refine_stop;
  if (neighbour_restarts) o.neighbour_restarts = o.neighbour_restarts_alone = *neighbour_restarts;
  o.render = render_options_of(precision, o.render.cull_tolerance);
  if (second_run) o.second_run.residual = o.second_run.second_prior = *second_run;
  naming_options(capture_argument_names, [&] {
    o.network_precision = nn::parse_precision(network_precision, "capture_options::network_precision");
    o.kernel = kernel_options::parse(kernel);
    if (stages != "auto") o.stages = pipeline_stages::parse(stages);
    o.validate();
  });
  return o;
}

/// The networks capture() runs, as the program chooses them: the weights where they are found
/// ("auto" stages run the refine alone without them), those `models` names, none with
/// models=False (an empty path) or when the network stages do not run (null).
loaded_networks* capture_networks_py(const capture_options& o, bool has_start, const std::string& stages,
                                     const std::optional<fs::path>& models, const std::string& preset,
                                     const std::optional<fs::path>& also_models) {
  const bool explicit_stages = stages != "auto";
  if (has_start && explicit_stages && o.stages.networks())
    throw py::value_error("start replaces the network stages: use it with stages='refine'");
  if (has_start || !o.stages.networks()) return nullptr;
  if (models && models->empty()) {
    if (explicit_stages) throw py::value_error("stages '" + stages + "' need the networks, and models=False turns them off");
    return nullptr;
  }
  // Empty folder with stages named: load_networks searches and says where it looked.
  const fs::path folder = models ? *models : find_models_folder(preset);
  return !folder.empty() || explicit_stages ? &cached_networks(folder, preset, also_models) : nullptr;
}

/// The encoding `name` names; ValueError otherwise.
photo_encoding encoding_from_py(const std::string& name) {
  const std::optional<photo_encoding> e = photo_encoding_from_name(name);
  if (!e) throw py::value_error("encoding: " + photo_encoding_choices('\'') + ", got '" + name + "'");
  return *e;
}

/// capture()'s per-texel uncertainty: the standard deviations and the remaining Gauss-Newton steps
/// as map sets, the noise, the share of texels each parameter is determined on, and the encoding
/// whose calibration applied.
py::object uncertainty_py(const std::optional<uncertainty_result>& u) {
  if (!u) return py::none();
  py::dict out;
  out["sd"] = from_maps(u->sd);
  out["step"] = from_maps(u->step);
  out["noise"] = u->noise;
  py::dict determined;
  for (int k = 0; k < parameter_count; ++k) determined[parameter_name(k)] = u->determined_share[std::size_t(k)];
  out["determined_share"] = determined;
  out["calibration"] = u->calibration ? py::object(py::str(photo_encoding_name(*u->calibration))) : py::object(py::none());
  return out;
}

/// capture()'s answer: the maps and how they were made.
py::dict capture_result_py(const capture_result& result, const loaded_networks* nets) {
  py::dict out;
  out["maps"] = from_maps(result.maps);
  out["loss"] = result.loss;
  py::list st;
  for (const auto& s : result.stages) st.append(stage_to_dict(s));
  out["stages"] = st;
  out["networks_ran"] = result.networks_ran;
  out["networks"] = nets ? nets->nets.describe() : std::string("none");
  out["kernel"] = feature_name(result.features);
  out["exposure_scale"] = result.exposure_scale;
  out["uncertainty"] = uncertainty_py(result.uncertainty);
  return out;
}

py::dict capture_py(const py::handle& photos_obj, const std::vector<capture_image>& configurations, const py::object& masks_obj,
                    const std::optional<fs::path>& models, const std::string& preset, const std::optional<fs::path>& also_models,
                    const std::string& stages, const std::string& schedule, std::optional<int> estimate_window,
                    std::optional<int> estimate_stride, std::optional<int> finetune_steps, std::optional<float> finetune_lr,
                    std::optional<int> steps, std::optional<float> lr, std::optional<double> refine_stop,
                    std::optional<std::vector<int>> neighbour_restarts,
                    const std::string& kernel, const std::string& precision, const std::string& network_precision,
                    std::optional<bool> second_run,
                    const py::object& start_obj, const py::object& progress, const py::object& log) {
  const capture_input in = capture_input_py(configurations, photos_obj, masks_obj);
  const capture& cap = in.cap;
  const std::vector<image>& photos = in.photos;
  const std::vector<image>& masks = in.masks;
  std::optional<material_maps> start;
  if (!start_obj.is_none()) {
    start = to_maps(start_obj, "start");
    check_size(*start, photos[0].width(), photos[0].height(), "the photographs");
  }
  capture_options o = capture_options_py(stages, schedule, estimate_window, estimate_stride, finetune_steps, finetune_lr, steps, lr,
                                         refine_stop, neighbour_restarts, kernel, precision, network_precision, second_run);
  loaded_networks* nets = capture_networks_py(o, start.has_value(), stages, models, preset, also_models);
  static const networks none;
  // Every step reports, so that Ctrl-C stops the capture within a step.
  o.finetune.progress_every = o.refine.progress_every = o.refine_alone.progress_every = 1;
  const progress_hook hook{progress};
  o.progress = [hook](const std::string& stage, const optimisation_progress& p) { hook(stage, p.step, p.steps, p.loss); };
  if (!log.is_none())
    o.log = [log](const std::string& message) {
      py::gil_scoped_acquire gil;
      log(message);
    };
  capture_result result;
  {
    py::gil_scoped_release release;  // before the lock: a capture holding it takes the GIL to report progress
    std::unique_lock<std::mutex> lock;
    if (nets) lock = std::unique_lock<std::mutex>(nets->in_use);
    result = naming_options(capture_argument_names,
                            [&] { return capture_material(cap, photos, nets ? nets->nets : none, o, masks, start ? &*start : nullptr); });
  }
  return capture_result_py(result, nets);
}

void export_py(const py::handle& maps_obj, const std::string& format, const fs::path& out, double width) {
  const auto f = exports::export_format_from_name(format);
  if (!f) throw py::value_error("format: gltf, mitsuba, blender or mtlx, got '" + format + "'");
  if (!(width >= 0 && std::isfinite(width))) throw py::value_error("width: a finite number of metres >= 0");
  material_maps maps = to_maps(maps_obj);
  exports::export_options o;
  o.width = width;
  py::gil_scoped_release release;
  exports::export_material(std::move(maps), *f, out, o);
}

py::dict rectify_py(const fs::path& photos_json, const std::optional<fs::path>& out, int resolution, float saturation, float floor,
                    double margin_px, const std::string& footprint, double dark_level, double full_confidence_px, double tag_mm,
                    double gap_mm, const py::object& progress) {
  rectify_options o;
  o.resolution = resolution;
  o.saturation = saturation;
  o.floor = floor;
  o.resampling.margin_px = margin_px;
  if (footprint == "auto") o.resampling.statistic = footprint_statistic::automatic;
  else if (footprint == "mean") o.resampling.statistic = footprint_statistic::mean;
  else if (footprint == "median") o.resampling.statistic = footprint_statistic::median;
  else throw py::value_error("footprint: auto, mean or median, got '" + footprint + "'");
  o.resampling.dark_level = dark_level;
  o.resampling.full_confidence_px = full_confidence_px;
  const progress_hook hook{progress};
  o.progress = [hook](std::size_t done, std::size_t total, const std::string& line) { hook(line, int(done), int(total), 0.0); };
  if (!(tag_mm >= 0) || !(gap_mm >= 0)) throw py::value_error("tag_mm and gap_mm must be >= 0");
  marker_frame_options frame_options;
  frame_options.tag_mm = tag_mm;
  frame_options.gap_mm = gap_mm;
  rectified_capture r;
  {
    py::gil_scoped_release release;
    const photos_description d = read_photos_description(photos_json);
    const marker_frame frame = make_marker_frame(d.width_mm, d.height_mm, frame_options);
    const corner_finder markers = [&](const photo& picture, const photos_description&, const std::string& name) {
      return find_corners_from_markers(picture, frame, name);
    };
    r = rectify(d, photos_json.parent_path(), o, markers);
    if (out) write_rectified_capture(r, *out);
  }
  std::vector<image> photos, masks;
  for (const auto& p : r.photos) {
    photos.push_back(p.radiance);
    masks.push_back(mask_weights(p));
  }
  py::dict d;
  d["configurations"] = r.configurations.images;
  d["photos"] = from_images(photos);
  d["masks"] = from_images(masks);
  return d;
}

}  // namespace

PYBIND11_MODULE(_anisocap, m) {
  m.doc() = "anisocap's library calls on NumPy arrays (see the anisocap package for the documented interface)";
  py::register_exception<io_error>(m, "FileError", PyExc_OSError);
  py::register_exception<calibration_error>(m, "CalibrationError", PyExc_ValueError);

  py::list names;
  for (const char* n : {"diffuse_r", "diffuse_g", "diffuse_b", "specular_r", "specular_g", "specular_b", "lobe_x", "lobe_y", "fresnel_f0",
                        "normal_x", "normal_y", "rotation"})
    names.append(n);
  m.attr("PARAMETERS") = py::tuple(names);
  m.attr("LOSS_EPSILON") = loss_epsilon;

  py::class_<capture_image>(m, "Configuration", "One photograph's configuration: camera and point-light positions, light intensity")
      .def(py::init([](vec3f camera, vec3f light, vec3f intensity, std::string file, std::string mask, float exposure, float floor,
                       const std::string& encoding) {
             return capture_image{std::move(file), camera, light, intensity, std::move(mask), exposure, floor, encoding_from_py(encoding)};
           }),
           py::arg("camera") = vec3f{0, 0, 1}, py::arg("light") = vec3f{0, 0, 1}, py::arg("intensity") = vec3f{1, 1, 1},
           py::arg("file") = "", py::arg("mask") = "", py::arg("exposure") = 1.0f, py::arg("floor") = 0.0f,
           py::arg("encoding") = "lossless")
      .def_readwrite("camera", &capture_image::camera, "camera position (x, y, z), units of the material's longest side")
      .def_readwrite("light", &capture_image::light, "point-light position (x, y, z)")
      .def_readwrite("intensity", &capture_image::intensity, "light intensity per colour channel")
      .def_readwrite("file", &capture_image::file, "image file name, relative to capture.json's folder")
      .def_readwrite("mask", &capture_image::mask, "mask file name (empty: none)")
      .def_readwrite("exposure", &capture_image::exposure, "factor the photograph's values are multiplied by on loading")
      .def_readwrite("floor", &capture_image::floor, "level below which the photograph's values are not measurements (0: none)")
      .def_property(
          "encoding", [](const capture_image& c) { return std::string(photo_encoding_name(c.encoding)); },
          [](capture_image& c, const std::string& name) { c.encoding = encoding_from_py(name); },
          "how the photograph's file stored it: 'lossless', 'eight_bit', 'jpeg' or 'jpeg_subsampled' "
          "(read_capture sets it from the file); it chooses the uncertainty's calibration")
      .def("__repr__", [](const capture_image& c) {
        char s[256];
        std::snprintf(s, sizeof s, "Configuration(camera=(%g, %g, %g), light=(%g, %g, %g), intensity=(%g, %g, %g), file='%s')", c.camera[0],
                      c.camera[1], c.camera[2], c.light[0], c.light[1], c.light[2], c.intensity[0], c.intensity[1], c.intensity[2],
                      c.file.c_str());
        return std::string(s);
      });

  py::class_<py_targets>(m, "LossTargets", "max(photograph, floor) + 0.01, masks and floors, precomputed for loss_and_gradient")
      .def_property_readonly("width", [](const py_targets& t) { return t.targets.width; })
      .def_property_readonly("height", [](const py_targets& t) { return t.targets.height; })
      .def_property_readonly("count", [](const py_targets& t) { return t.targets.images.size(); });

  m.def("read_maps", [](const fs::path& folder) {
    material_maps maps;
    {
      py::gil_scoped_release release;
      maps = read_maps(folder);
    }
    return from_maps(maps);
  }, py::arg("folder"));
  m.def("write_maps", [](const py::handle& maps, const fs::path& folder, bool previews) {
    const material_maps m = to_maps(maps);
    py::gil_scoped_release release;
    write_maps(m, folder, previews);
  }, py::arg("maps"), py::arg("folder"), py::arg("previews") = true);
  m.def("read_capture", &read_capture_py, py::arg("file"), py::arg("saturation") = 0.0f, py::arg("exclude_clipped") = true);
  m.def("write_capture", &write_capture_py, py::arg("configurations"), py::arg("photos"), py::arg("masks") = py::none(), py::arg("folder"));
  m.def("render", &render_py, py::arg("maps"), py::arg("configurations"), py::arg("features") = "full", py::arg("precision") = "float");
  m.def("loss_targets", &make_targets, py::arg("photos"), py::arg("masks") = py::none(), py::arg("floors") = py::none());
  m.def("loss_and_gradient", &loss_and_gradient_py, py::arg("maps"), py::arg("configurations"), py::arg("targets"),
        py::arg("features") = "full", py::arg("precision") = "float", py::arg("cull") = 0.0f, py::arg("gradient") = true);
  m.def("synthesize", &synthesize_py, py::arg("width"), py::arg("height"), py::arg("images"), py::arg("set"), py::arg("seed"),
        py::arg("kind"), py::arg("mix"), py::arg("fresnel"), py::arg("shot_noise"), py::arg("read_noise"));
  m.def("capture", &capture_py, py::arg("photos"), py::arg("configurations"), py::arg("masks"), py::arg("models"), py::arg("preset"),
        py::arg("also_models"), py::arg("stages"), py::arg("schedule"), py::arg("estimate_window"), py::arg("estimate_stride"),
        py::arg("finetune_steps"), py::arg("finetune_lr"), py::arg("steps"), py::arg("lr"), py::arg("refine_stop"), py::arg("neighbour_restarts"),
        py::arg("kernel"), py::arg("precision"), py::arg("network_precision"), py::arg("second_run"), py::arg("start"),
        py::arg("progress"), py::arg("log"));
  m.def("has_bf16", &nn::bf16_available);
  m.def("export", &export_py, py::arg("maps"), py::arg("format"), py::arg("out"), py::arg("width"));
  m.def("rectify", &rectify_py, py::arg("photos_json"), py::arg("out"), py::arg("resolution"), py::arg("saturation"), py::arg("floor"),
        py::arg("margin_px"), py::arg("footprint"), py::arg("dark_level"), py::arg("full_confidence_px"), py::arg("tag_mm"),
        py::arg("gap_mm"), py::arg("progress"));
  m.def("models_search_path", &models_search_path);
  m.def("has_weights", &has_weights, py::arg("folder"), py::arg("preset") = "compact");
}
