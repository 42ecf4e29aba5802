#pragma once
/// @file
/// A training run's files: the network's weights, the check-point that resumes it bit for bit
/// (weights, buffers, Adam's moments, the step), validation.csv, and the checks that a resumed run is
/// the run its checkpoint.json describes.
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <functional>
#include <sstream>
#include <stdexcept>
#include <string>

#include "anisocap/core/files.hpp"
#include "anisocap/core/json_parse.hpp"
#include "anisocap/nn/nn.hpp"
#include "anisocap/training/validation.hpp"

namespace anisocap::training {

/// Weights of the network alone (what is shipped), with metadata.
template <class Net>
void save_network(const std::filesystem::path& file, Net& net, const std::string& kind) {
  nn::save_weights(file, net, {{"network", kind}, {"preset", Net::preset::name}});
}

/// Writes a checkpoint: weights, buffers, Adam moments and step counts in one safetensors file
/// (written to a temporary name and renamed), then checkpoint.json naming it (same), then removes
/// the previous checkpoint file. A crash at any point leaves a complete earlier checkpoint.
template <class Net>
void save_checkpoint(const std::filesystem::path& dir, Net& net, nn::adam& opt, long step, json info) {
  nn::safetensors_file contents;
  nn::detail::visit_weights(net, [&](auto& p) {
    contents.add_view<float>(p.name, std::vector<std::int64_t>(p.shape.begin(), p.shape.end()), p.value.data(), p.size());
  });
  opt.save_state(contents);
  const std::string file = "checkpoint-" + std::to_string(step) + ".safetensors";
  nn::write_safetensors(dir / file, contents);
  std::string previous;
  if (std::filesystem::exists(dir / "checkpoint.json")) {
    try {
      std::ifstream in(dir / "checkpoint.json");
      std::stringstream text;
      text << in.rdbuf();
      previous = parse_json(text.str(), (dir / "checkpoint.json").string()).at("file").get<std::string>();
    } catch (const std::exception&) {
    }
  }
  info["step"] = step;
  info["optimizer_steps"] = opt.steps();
  info["file"] = file;
  info["rng"] = "all randomness is a function of (seed, step): the step is the RNG state";
  write_file_atomically(dir / "checkpoint.json", info.dump(2) + "\n");
  if (!previous.empty() && previous != file) std::filesystem::remove(dir / previous);
}

/// The contents of dir/checkpoint.json (written by save_checkpoint). Throws std::runtime_error
/// naming the file when it is missing, malformed or lacks "file", "step" or "optimizer_steps".
inline json read_checkpoint_description(const std::filesystem::path& dir) {
  const auto description = dir / "checkpoint.json";
  std::ifstream in(description);
  if (!in) throw std::runtime_error(description.string() + ": no checkpoint to resume from");
  std::stringstream text;
  text << in.rdbuf();
  json object = parse_json(text.str(), description.string());
  if (!object.is_object()) throw std::runtime_error(description.string() + ": not a checkpoint description (a JSON object)");
  for (const char* key : {"file", "step", "optimizer_steps"})
    if (!object.contains(key) || (std::string_view(key) == "file" ? !object.at(key).is_string() : !object.at(key).is_number()))
      throw std::runtime_error(description.string() + ": missing or malformed \"" + key + "\"");
  return object;
}

/// Restores the checkpoint that `object` (dir/checkpoint.json, read_checkpoint_description)
/// describes; returns its step. Throws std::runtime_error naming the file when it is missing,
/// malformed or does not match the network.
template <class Net>
long load_checkpoint(const std::filesystem::path& dir, const json& object, Net& net, nn::adam& opt) {
  const auto file = dir / object.at("file").get<std::string>();
  nn::load_weights(file, net);
  const nn::safetensors_file contents = nn::read_safetensors(file);
  opt.load_state(contents, file.string());
  opt.set_steps(object.at("optimizer_steps").get<long>());
  return object.at("step").get<long>();
}

namespace detail {

/// Keeps the rows of a CSV whose first field (a step) is at most `step` (a resumed run rewrites
/// the validations a killed run made after its last checkpoint).
inline void truncate_csv(const std::filesystem::path& file, long step) {
  std::ifstream in(file);
  if (!in) return;
  std::string line, kept;
  bool header = true;
  while (std::getline(in, line)) {
    if (header || (!line.empty() && std::stol(line.substr(0, line.find(','))) <= step)) kept += line + "\n";
    header = false;
  }
  in.close();
  std::ofstream(file) << kept;
}

/// Appends one validation row (writing the header first when the file is new).
inline void append_validation(const std::filesystem::path& file, long step, double train_loss, const validation_result& v) {
  const bool fresh = !std::filesystem::exists(file);
  std::ofstream out(file, std::ios::app);
  if (fresh)
    out << "step,train_loss,val_loss,val_l1,val_render,mse_diffuse,mse_specular,mse_normal,mse_lobes,mse_rotation,"
           "mse_fresnel,mse_rotation_anisotropic\n";
  char row[512];
  std::snprintf(row, sizeof row, "%ld,%.6g,%.6g,%.6g,%.6g,%.6g,%.6g,%.6g,%.6g,%.6g,%.6g,%.6g\n", step, train_loss, v.loss.total,
                v.loss.l1, v.loss.render, v.errors.diffuse, v.errors.specular, v.errors.normal, v.errors.lobes,
                v.errors.rotation, v.errors.fresnel, v.errors.rotation_anisotropic);
  out << row;
}

/// A setting as a checkpoint writes it: strings as they are, whole numbers without a fraction.
inline std::string setting_text(const json& value) {
  if (value.is_string()) return value.get<std::string>();
  if (value.is_number()) {
    const double v = value.get<double>();
    char text[64];
    if (v == std::nearbyint(v) && std::abs(v) < 1e18) std::snprintf(text, sizeof text, "%lld", static_cast<long long>(v));
    else std::snprintf(text, sizeof text, "%g", v);
    return text;
  }
  return value.dump();
}

/// One optional part of a resumed run's learning-rate schedule, saved in checkpoint.json (`file`) as
/// `key`: an array of `size` numbers whose first `integers` are step numbers. Without a `given` one
/// (null) the saved one goes on: it is returned after a check of its shape (null when there is none).
/// A given one that differs from the saved one is logged as `change` (the caller records it), and
/// null is returned.
inline json resumed_schedule_part(const json& saved, const std::string& key, std::size_t size, std::size_t integers, const json& given,
                                  const std::filesystem::path& file, const std::string& change,
                                  const std::function<void(const std::string&)>& log) {
  if (!given.is_null()) {
    if (!saved.contains(key) || saved.at(key) != given) log(change);
    return nullptr;
  }
  if (!saved.contains(key)) return nullptr;
  const json& part = saved.at(key);
  bool ok = part.is_array() && part.size() == size;
  for (std::size_t i = 0; ok && i < size; ++i) ok = i < integers ? part[i].is_number_integer() : part[i].is_number();
  if (!ok) throw std::runtime_error(file.string() + ": malformed \"" + key + "\"");
  return part;
}

/// Throws std::runtime_error naming `file` when the settings a resumed run was given (`given`,
/// checkpoint.json's entries for this run) differ from those its checkpoint was trained with
/// (`saved`) in the network, preset, seed, size, batch, materials, a loss weight, emphasis or input
/// noise or the learning-rate warm-up: such a run would silently continue as another one. The
/// message names the setting to resume with as a host sets it (train_options::render_weight 1,
/// train_autoencoder, the preset compact). Older checkpoints lack "materials" (the original mix),
/// "render_weight", "lobe_weight", "diffuse_weight" and "normal_weight" (1), "sigma_weight" and
/// "mse_weight" (0), "emphasis" ("": none), "emphasis_share" (0), "trainable" ("all"), "inputs"
/// ("truth"), "shot_noise", "read_noise" and "lr_warmup" (0); other entries a checkpoint lacks are
/// not compared.
inline void check_resume_settings(const json& saved, const json& given, const std::filesystem::path& file) {
  if (saved.contains("network") && setting_text(saved.at("network")) != setting_text(given.at("network")))
    throw std::runtime_error(file.string() + ": the run in this folder trains the " + setting_text(saved.at("network")) + ", not the " +
                             setting_text(given.at("network")) + "; resume it with train_" + setting_text(saved.at("network")));
  // Each entry and the train_options field it records (the preset is the trainer's template argument).
  static const std::pair<const char*, const char*> options[] = {
      {"preset", "the preset"},
      {"seed", "train_options::seed"},
      {"size", "train_options::size"},
      {"batch", "train_options::batch"},
      {"materials", "train_options::mix"},
      {"render_weight", "train_options::render_weight"},
      {"lobe_weight", "train_options::lobe_weight"},
      {"sigma_weight", "train_options::sigma_weight"},
      {"mse_weight", "train_options::mse_weight"},
      {"diffuse_weight", "train_options::diffuse_weight"},
      {"normal_weight", "train_options::normal_weight"},
      {"emphasis", "train_options::emphasis"},
      {"emphasis_share", "train_options::emphasis_share"},
      {"trainable", "train_options::encoder_only"},
      {"inputs", "train_options::inputs_are_estimates"},
      {"shot_noise", "train_options::input_noise.shot"},
      {"read_noise", "train_options::input_noise.read"},
      {"lr_warmup", "train_options::lr_warmup"}};
  // The field's value that an entry's saved value stands for ("trainable" and "inputs" save words for flags).
  auto field_value = [](std::string_view key, const json& value) -> std::string {
    if (key == "trainable") return value == "encoder" ? "true" : "false";
    if (key == "inputs") return value == "estimates" ? "true" : "false";
    return setting_text(value);
  };
  // What a description that lacks an entry meant: older versions wrote no materials, loss weights or emphasis.
  auto entry = [](const json& description, std::string_view key) {
    if (description.contains(std::string(key))) return description.at(std::string(key));
    if (key == "materials") return json("original");
    if (key == "render_weight" || key == "lobe_weight" || key == "diffuse_weight" || key == "normal_weight") return json(1.0);
    if (key == "sigma_weight" || key == "mse_weight") return json(0.0);
    if (key == "emphasis") return json("");
    if (key == "emphasis_share" || key == "shot_noise" || key == "read_noise" || key == "lr_warmup") return json(0.0);
    if (key == "trainable") return json("all");
    if (key == "inputs") return json("truth");
    return json();
  };
  for (const auto& [key, option] : options) {
    const json value = entry(saved, key), now = entry(given, key);
    if (value.is_null()) continue;
    if (value.is_number() != now.is_number() || (!value.is_number() && !value.is_string()))
      throw std::runtime_error(file.string() + ": malformed \"" + key + "\"");
    const bool same = value.is_number() ? value.get<double>() == now.get<double>() : value == now;
    if (!same) {
      auto shown = [](const json& v) { return v == "" ? std::string("(none)") : setting_text(v); };
      throw std::runtime_error(file.string() + ": the run was trained with " + key + " " + shown(value) + ", not " + shown(now) +
                               "; resume it " +
                               (value == "" ? std::string("without ") + option : std::string("with ") + option + " " + field_value(key, value)));
    }
  }
}

}  // namespace detail

}  // namespace anisocap::training
