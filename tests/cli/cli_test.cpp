// The anisocap program end to end: a small synthesize -> capture -> render round, and bad input
// that must give one clear message naming the file, a non-zero exit, and no output.
#include <doctest/doctest.h>

#include <algorithm>
#include <cctype>
#include <cmath>
#include <cstring>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <map>
#include <random>
#include <sstream>
#include <string>

#include <nlohmann/json.hpp>
#include <stb/stb_image_write.h>

#include "anisocap/data/capture_io.hpp"
#include "anisocap/data/image_io.hpp"
#include "anisocap/data/map_io.hpp"
#include "anisocap/export/tileable.hpp"
#include "anisocap/brdf/canonical_maps.hpp"
#include "anisocap/networks/presets.hpp"
#include "anisocap/nn/safetensors.hpp"
#include "commands/field_flags.hpp"

namespace fs = std::filesystem;

namespace {

const fs::path program = fs::path(ANISOCAP_BINARY_DIR) / "anisocap";

struct run_result {
  int status;
  std::string output;
};

run_result run(const std::string& args, const fs::path& dir) {
  const fs::path log = dir / "log.txt";
  const std::string cmd = "cd '" + dir.string() + "' && OMP_NUM_THREADS=2 '" + program.string() + "' " + args + " > '" + log.string() + "' 2>&1";
  const int status = std::system(cmd.c_str());
  std::ifstream in(log);
  std::stringstream s;
  s << in.rdbuf();
  return {status, s.str()};
}

struct temp_dir {
  fs::path path;
  temp_dir() {
    std::random_device rd;
    path = fs::temp_directory_path() / ("anisocap_cli_" + std::to_string(rd()));
    fs::create_directories(path);
  }
  ~temp_dir() { std::error_code ec; fs::remove_all(path, ec); }
};

void write(const fs::path& p, const std::string& text) { std::ofstream(p) << text; }

/// Runs `args` in `dir` and checks that it is refused: a non-zero exit, `message` in the output,
/// and nothing at `dir / out`.
void check_refused(const std::string& args, const fs::path& dir, const std::string& message, const fs::path& out) {
  const run_result r = run(args, dir);
  INFO(args << "\n" << r.output);
  CHECK(r.status != 0);
  CHECK(r.output.find(message) != std::string::npos);
  CHECK_FALSE(fs::exists(dir / out));
}

std::string read_text(const fs::path& p) {
  std::ifstream in(p, std::ios::binary);
  std::stringstream s;
  s << in.rdbuf();
  return s.str();
}

}  // namespace

TEST_CASE("synthesize, capture with truth, render: outputs and report") {
  temp_dir t;
  auto r = run("synthesize -o syn --width 40 --height 24 --images 6 --seed 3", t.path);
  INFO(r.output);
  REQUIRE(r.status == 0);
  CHECK(fs::exists(t.path / "syn/capture.json"));
  CHECK(fs::exists(t.path / "syn/input_05.exr"));
  CHECK(fs::exists(t.path / "syn/input_05.png"));
  CHECK(fs::exists(t.path / "syn/truth/lobes.exr"));
  r = run("capture syn/capture.json -o out --steps 30 --truth syn/truth", t.path);
  INFO(r.output);
  REQUIRE(r.status == 0);
  CHECK(r.output.find("refine step") != std::string::npos);  // progress is shown
  for (const char* f : {"diffuse.exr", "specular.exr", "lobes.exr", "fresnel.exr", "normal.exr", "rotation.exr", "report.json",
                        "renders/input_00.exr", "diffuse.png"})
    CHECK_MESSAGE(fs::exists(t.path / "out" / f), f);
  std::ifstream rep(t.path / "out/report.json");
  std::stringstream s;
  s << rep.rdbuf();
  CHECK(s.str().find("\"errors\"") != std::string::npos);
  CHECK(s.str().find("\"stages\"") != std::string::npos);
  CHECK(s.str().find("\"novel_view_image_loss\"") != std::string::npos);
  CHECK(fs::exists(t.path / "out/contact_sheet.png"));
  CHECK(fs::exists(t.path / "out/material.html"));  // the viewer page, by default
  CHECK(fs::exists(t.path / "out/novel/novel_02.exr"));
  {  // the written maps are canonical: sigma_x >= sigma_y, alpha in [-pi/2, pi/2)
    using namespace anisocap;
    const material_maps written = read_maps(t.path / "out");
    for (std::size_t i = 0; i < written.texel_count(); ++i)
      REQUIRE(is_canonical(written.plane(lobe_x)[i], written.plane(lobe_y)[i], written.plane(rotation)[i]));
  }
  CHECK(s.str().find("\"exposure_scale\"") != std::string::npos);
  // The time/accuracy options run and are reported.
  r = run("capture syn/capture.json -o fast --stages refine --steps 60 --freeze 0.01 --refine-stop 1e-3 --precision double "
          "--kernel auto --cull 1e-3 --no-view",
          t.path);
  INFO(r.output);
  REQUIRE(r.status == 0);
  CHECK_FALSE(fs::exists(t.path / "fast/material.html"));
  // A kernel without the Fresnel term chosen by hand: F0 is the prior, and the message says why.
  r = run("capture syn/capture.json -o nofresnel --stages refine --steps 5 --kernel no-fresnel --no-view", t.path);
  REQUIRE_MESSAGE(r.status == 0, r.output);
  CHECK_MESSAGE(r.output.find("no Fresnel term (--kernel)") != std::string::npos, r.output);
  CHECK(r.output.find("within 0 of 1") == std::string::npos);
  // view and export from the program; a missing map set is one clear error and no output.
  r = run("view out -o out/page.html", t.path);
  CHECK(r.status == 0);
  CHECK(fs::exists(t.path / "out/page.html"));
  for (const char* format : {"gltf", "mitsuba", "blender", "mtlx"}) {
    r = run(std::string("export out --format ") + format + " -o exported_" + format + (std::string(format) == "gltf" ? ".gltf" : ""), t.path);
    CHECK_MESSAGE(r.status == 0, r.output);
  }
  CHECK(fs::exists(t.path / "exported_mitsuba/scene.xml"));
  for (const char* choice : {"on", "off"}) {  // the glTF anisotropy choice forced either way
    r = run(std::string("export out --format gltf --gltf-anisotropy ") + choice + " -o forced_" + choice + ".gltf", t.path);
    REQUIRE_MESSAGE(r.status == 0, r.output);
    std::ifstream in(t.path / (std::string("forced_") + choice + ".gltf"));
    std::stringstream text;
    text << in.rdbuf();
    CHECK((text.str().find("KHR_materials_anisotropy") != std::string::npos) == (std::string(choice) == "on"));
  }
  r = run("export out --format gltf --gltf-anisotropy sometimes -o bad.gltf", t.path);
  CHECK(r.status != 0);
  CHECK_FALSE(fs::exists(t.path / "bad.gltf"));
  r = run("export nowhere --format gltf -o bad.gltf", t.path);
  CHECK(r.status != 0);
  CHECK(r.output.find("nowhere") != std::string::npos);
  CHECK_FALSE(fs::exists(t.path / "bad.gltf"));
  r = run("view nowhere -o bad.html", t.path);
  CHECK(r.status != 0);
  CHECK_FALSE(fs::exists(t.path / "bad.html"));
  std::ifstream rep2(t.path / "fast/report.json");
  std::stringstream s2;
  s2 << rep2.rdbuf();
  CHECK(s2.str().find("\"precision\": \"double\"") != std::string::npos);
  CHECK(s2.str().find("\"kernel_used\"") != std::string::npos);
  CHECK(s2.str().find("\"evaluated_fraction\"") != std::string::npos);
  // The network stages with the fine-tune's schedule and crop options (shipped compact weights;
  // 72 x 40 pads to 96 x 64: 3 x 2 latent cells, crops of 1 x 1).
  r = run("synthesize -o syn2 --width 72 --height 40 --images 6 --seed 4", t.path);
  REQUIRE(r.status == 0);
  r = run("capture syn2/capture.json -o nets --stages all --finetune-steps 6 --finetune-crop 1 --finetune-warmup 3 "
          "--finetune-half-life 100 --finetune-lr 4e-3 --steps 5",
          t.path);
  INFO(r.output);
  REQUIRE(r.status == 0);
  std::ifstream rep3(t.path / "nets/report.json");
  std::stringstream s3;
  s3 << rep3.rdbuf();
  CHECK(s3.str().find("\"crop.cells\": 1") != std::string::npos);
  CHECK(s3.str().find("\"warmup\": 3") != std::string::npos);
  CHECK(s3.str().find("\"half_life\": 100") != std::string::npos);
  CHECK(s3.str().find("\"window\": 256") != std::string::npos);  // the estimate's default window
  // The estimate's windows: smaller windows are reported; a stride past the window is one clear
  // error, before any output.
  r = run("capture syn2/capture.json -o nets64 --stages all --estimate-window 64 --estimate-stride 16 --finetune-steps 2 --steps 2 --no-view",
          t.path);
  INFO(r.output);
  REQUIRE(r.status == 0);
  const std::string report64 = read_text(t.path / "nets64/report.json");
  CHECK(report64.find("\"window\": 64") != std::string::npos);
  CHECK(report64.find("\"stride\": 16") != std::string::npos);
  r = run("capture syn2/capture.json -o nets_bad --stages all --estimate-window 64 --estimate-stride 65", t.path);
  CHECK(r.status != 0);
  CHECK(r.output.find("--estimate-stride (65) is larger than --estimate-window (64)") != std::string::npos);
  CHECK_FALSE(fs::exists(t.path / "nets_bad"));
  r = run("render --maps syn/truth --capture syn/capture.json -o again", t.path);
  REQUIRE(r.status == 0);
  // Rendering the true maps reproduces the inputs exactly (same renderer, same configuration).
  const auto a = anisocap::read_exr(t.path / "again/input_02.exr");
  const auto b = anisocap::read_exr(t.path / "syn/input_02.exr");
  for (std::size_t i = 0; i < a.pixel_count(); ++i) REQUIRE(a.plane(1)[i] == b.plane(1)[i]);
}

TEST_CASE("capture: every option field report.json lists (the field visitors' names) has a flag in --help, or is set only by --schedule or --kernel") {
  temp_dir t;
  REQUIRE(run("synthesize -o syn --width 32 --height 32 --images 5 --seed 6", t.path).status == 0);
  REQUIRE(run("capture syn/capture.json -o out --stages all --finetune-steps 2 --steps 2 --no-view", t.path).status == 0);
  std::ifstream in(t.path / "out" / "report.json");
  const nlohmann::json report = nlohmann::json::parse(in);
  const std::string help = run("capture --help", t.path).output;
  auto in_help = [&](std::string_view flag) {  // the flag as a whole word of --help
    for (std::size_t at = help.find(flag); at != std::string::npos; at = help.find(flag, at + 1)) {
      const std::size_t end = at + flag.size();
      if (end == help.size() || !(std::isalnum(static_cast<unsigned char>(help[end])) || help[end] == '-')) return true;
    }
    return false;
  };
  // Fields no flag sets: the schedules' (--schedule) and the automatic kernel's (--kernel auto)
  // constants, Adam's, and the networks' second prior (chosen by --also-models / --no-also-models).
  const std::vector<std::string> unbound = {
      "finetune_options::patience", "finetune_options::min_steps", "finetune_options::guard.every", "finetune_options::crop.seed",
      "refine_options::beta1", "refine_options::beta2", "refine_options::epsilon", "refine_options::patience", "refine_options::min_steps",
      "refine_options::freeze_every", "kernel_options::auto_tolerance", "kernel_options::prior_f0", "capture_options::second_run.second_prior"};
  // report.json's sections and the prefixes of their fields in the library's messages.
  const std::vector<std::pair<std::string, std::string>> sections = {{"finetune", "finetune_options::"}, {"refine", "refine_options::"},
                                                                     {"estimate", "estimate_options::"}, {"second_run", "capture_options::second_run."},
                                                                     {"kernel_options", "kernel_options::"}};
  std::vector<std::string> seen;
  for (const auto& [section, prefix] : sections) {
    REQUIRE(report.contains(section));
    for (const auto& [key, value] : report[section].items()) {
      if (section == "finetune" && key == "preset") continue;       // the auto-encoder's preset, not an option
      if (section == "refine" && key == "neighbour_restarts") continue;  // capture_options', checked below
      const std::string field = section == "kernel_options" && key == "features" ? "kernel_options" : prefix + key;
      CAPTURE(field);
      seen.push_back(field);
      const auto& table = anisocap::commands::capture_field_flags;
      const auto entry = std::find_if(std::begin(table), std::end(table), [&](const anisocap::option_name& e) { return e.field == field; });
      const bool bound = entry != std::end(table);
      const bool listed = std::find(unbound.begin(), unbound.end(), field) != unbound.end();
      CHECK(bound != listed);  // a flag, or listed above: a new field must be given one or the other
      if (bound) CHECK(in_help(entry->name));
    }
  }
  for (const std::string& field : unbound) CHECK_MESSAGE(std::find(seen.begin(), seen.end(), field) != seen.end(), field);  // no stale entry
  CHECK(report["refine"].contains("neighbour_restarts"));
  for (const anisocap::option_name& e : anisocap::commands::capture_field_flags) CHECK_MESSAGE(in_help(e.name), e.name);  // every flag bound
}

TEST_CASE("capture --schedule thorough fine-tunes for 2000 steps; options beside it override its values") {
  temp_dir t;
  REQUIRE(run("synthesize -o syn --width 32 --height 32 --images 5 --seed 6", t.path).status == 0);
  auto report = [&](const char* folder) {
    std::ifstream in(t.path / folder / "report.json");
    return nlohmann::json::parse(in);
  };
  auto finetune_stage_steps = [](const nlohmann::json& r) {
    for (const auto& st : r["stages"])
      if (st["name"] == "finetune") return st["steps"].get<int>();
    return -1;
  };
  auto r = run("capture syn/capture.json -o thorough --stages all --schedule thorough --no-view", t.path);
  INFO(r.output);
  REQUIRE(r.status == 0);
  const nlohmann::json a = report("thorough");
  CHECK(a["finetune"]["steps"] == 2000);
  CHECK(finetune_stage_steps(a) == 2000);
  CHECK(a["finetune"]["warmup"] == 200);
  CHECK(a["finetune"]["guard.factor"] == 1.5);  // fields under the names finetune_options::visit_fields gives them
  CHECK(a["finetune"]["crop.cells"] == 0);
  CHECK(a["refine"]["steps"] == 1000);
  CHECK(a["refine"]["min_relative_improvement"] == 0.0);
  // The second runs' and the kernel's options, under the names their visit_fields give them.
  CHECK(a["second_run"] == nlohmann::json{{"residual", true}, {"second_prior", true}, {"above", 0.1}, {"residual_ratio", 1.4}});
  CHECK(a["kernel_options"]["features"] == "anisotropic, Fresnel, normal map");
  CHECK(a["kernel_options"]["auto_tolerance"] == 1e-3);
  CHECK(a["kernel_options"]["prior_f0"].get<double>() == doctest::Approx(0.04));
  // --help reads the schedules' numbers from the options the capture ran with.
  const std::string help = run("capture --help", t.path).output;
  CHECK(help.find("thorough: fine-tune " + std::to_string(a["finetune"]["steps"].get<int>()) + " at 0.008, refine " +
                  std::to_string(a["refine"]["steps"].get<int>()) + " at 0.003 ") != std::string::npos);
  r = run("capture syn/capture.json -o short --stages all --schedule thorough --finetune-steps 7 --steps 2 --no-view", t.path);
  REQUIRE(r.status == 0);
  const nlohmann::json b = report("short");
  CHECK(finetune_stage_steps(b) == 7);
  CHECK(b["refine"]["steps"] == 2);
  r = run("capture syn/capture.json -o flags --stages all --finetune-steps 3 --steps 2 --no-view --no-uncertainty --kernel isotropic "
          "--no-also-residual --also-models-above 0.25 --also-residual-ratio 2",
          t.path);
  INFO(r.output);
  REQUIRE(r.status == 0);
  const nlohmann::json c = report("flags");
  CHECK(c["second_run"]["residual"] == false);
  CHECK(c["second_run"]["above"] == 0.25);
  CHECK(c["second_run"]["residual_ratio"] == 2.0);
  CHECK(c["kernel_options"]["features"] == "isotropic, Fresnel, normal map");
  CHECK(c["kernel_options"]["auto_tolerance"] == 0.0);
  r = run("capture syn/capture.json -o bad --schedule slow", t.path);
  CHECK(r.status != 0);
  CHECK(r.output.find("slow") != std::string::npos);
  CHECK_FALSE(fs::exists(t.path / "bad"));
}

TEST_CASE("capture --network-precision bf16: the networks' convolutions in bf16, the fit as good as fp32's; refused where the build lacks it") {
  temp_dir t;
  REQUIRE(run("synthesize -o syn --width 64 --height 64 --images 6 --seed 8", t.path).status == 0);
  auto report = [&](const char* folder) {
    std::ifstream in(t.path / folder / "report.json");
    return nlohmann::json::parse(in);
  };
  const std::string common = " --stages all --finetune-steps 150 --steps 50 --no-view --no-uncertainty";
  auto r = run("capture syn/capture.json -o fp32" + common, t.path);
  INFO(r.output);
  REQUIRE(r.status == 0);
  const nlohmann::json a = report("fp32");
  CHECK(a["network_precision"] == "fp32");
  const bool has_bf16 = run("--version", t.path).output.find(", bf16)") != std::string::npos;
  if (has_bf16) {
    r = run("capture syn/capture.json -o bf16 --network-precision bf16" + common, t.path);
    INFO(r.output);
    REQUIRE(r.status == 0);
    const nlohmann::json b = report("bf16");
    CHECK(b["network_precision"] == "bf16");
    // The same fit to the photographs: bf16 moves the fine-tune's path, not where it ends.
    CHECK(b["loss"].get<double>() <= 1.05 * a["loss"].get<double>());
    CHECK(b["loss"].get<double>() != a["loss"].get<double>());  // and it did run in bf16
  } else {
    check_refused("capture syn/capture.json -o bf16 --network-precision bf16" + common, t.path, "AVX-512 BF16", "bf16");
  }
  check_refused("capture syn/capture.json -o fp16 --network-precision fp16", t.path, "fp16", "fp16");
}

TEST_CASE("--preset paper: taken where the build has the paper's widths, else refused naming the build option") {
  temp_dir t;
  REQUIRE(run("synthesize -o syn --width 16 --height 16 --images 4 --seed 5", t.path).status == 0);
  const std::string models = " --models '" + (fs::path(ANISOCAP_SOURCE_DIR) / "models").string() + "'";
#ifdef ANISOCAP_EXPERIMENTAL_PRESETS
  // The option is taken, and the loader then names the paper weights the folder lacks.
  check_refused("capture syn/capture.json -o paper --preset paper" + models, t.path, "paper/estimator.safetensors", "paper");
#else
  for (const char* command : {"capture syn/capture.json -o paper --preset paper", "demo -o paper --preset paper",
                              "train-estimator -o paper --preset paper", "train-autoencoder -o paper --preset paper"})
    check_refused(command + models, t.path, "-DANISOCAP_EXPERIMENTAL_PRESETS=ON", "paper");
#endif
}

TEST_CASE("capture --tileable: the maps and a seamless tile of them, its seam in report.json; a sample too small is refused first") {
  temp_dir t;
  REQUIRE(run("synthesize -o syn --width 48 --height 40 --images 5 --seed 3", t.path).status == 0);
  auto r = run("capture syn/capture.json -o tiled --stages refine --steps 5 --tileable --tile-overlap 0.25 --no-view", t.path);
  INFO(r.output);
  REQUIRE(r.status == 0);
  CHECK(r.output.find("tileable: 48x40 maps made into a") != std::string::npos);
  using namespace anisocap;
  const material_maps maps = read_maps(t.path / "tiled");
  const material_maps tile = read_maps(t.path / "tiled" / "tileable");
  CHECK(maps.width() == 48);
  CHECK(maps.height() == 40);
  // The overlap is searched between 0.5 and 1.5 times 0.25 of each side.
  CHECK(tile.width() >= 48 - 18);
  CHECK(tile.width() <= 48 - 6);
  CHECK(tile.height() >= 40 - 15);
  CHECK(tile.height() <= 40 - 5);
  CHECK(fs::exists(t.path / "tiled" / "tileable" / "rotation.png"));
  std::ifstream in(t.path / "tiled" / "report.json");
  const nlohmann::json report = nlohmann::json::parse(in);
  REQUIRE(report.contains("tileable"));
  CHECK(report["tileable"]["width"] == tile.width());
  CHECK(report["tileable"]["seam_ratio_after"].get<double>() < report["tileable"]["seam_ratio_before"].get<double>());
  CHECK(report["tileable"]["seam_ratio_after"].get<double>() == doctest::Approx(measure_seam(tile).mean_seam_ratio()).epsilon(1e-3));
  // Without --tileable no tile and no report entry.
  REQUIRE(run("capture syn/capture.json -o plain --stages refine --steps 5 --no-view", t.path).status == 0);
  CHECK_FALSE(fs::exists(t.path / "plain" / "tileable"));
  // 48 x 40 texels leave fewer than 2 to blend at a 2% overlap: refused before any work or output.
  check_refused("capture syn/capture.json -o small --stages refine --steps 5 --tileable --tile-overlap 0.02", t.path,
                "--tileable: map set of 48x40 is too small", "small");
}

TEST_CASE("capture --neighbour-restarts: one refine per radius after the refine, the loss never above the single start's") {
  temp_dir t;
  REQUIRE(run("synthesize -o syn --width 64 --height 64 --images 6 --seed 8 --kind spun --materials extended", t.path).status == 0);
  auto report = [&](const char* folder) { return nlohmann::json::parse(read_text(t.path / folder / "report.json")); };
  auto r = run("capture syn/capture.json -o one --stages refine --steps 60 --no-view", t.path);
  INFO(r.output);
  REQUIRE(r.status == 0);
  r = run("capture syn/capture.json -o restarted --stages refine --steps 60 --neighbour-restarts 8,4 --no-view", t.path);
  REQUIRE(r.status == 0);
  CHECK(r.output.find("restart step") != std::string::npos);  // the rounds report progress
  const nlohmann::json a = report("one"), b = report("restarted");
  CHECK(a["refine"]["neighbour_restarts"].empty());
  CHECK(b["refine"]["neighbour_restarts"] == nlohmann::json::array({8, 4}));
  const nlohmann::json& refine_a = a["stages"].back();
  const nlohmann::json& refine_b = b["stages"].back();
  REQUIRE(refine_b["name"] == "refine");
  CHECK(refine_a["steps"] == 60);
  CHECK(refine_b["steps"] == 3 * 60);
  REQUIRE(refine_b["restart_replaced_fractions"].size() == 2);
  for (const auto& f : refine_b["restart_replaced_fractions"]) {
    CHECK(f.get<double>() >= 0.0);
    CHECK(f.get<double>() <= 1.0);
  }
  // The first 60 steps are the single start's; the rounds only ever keep a lower loss.
  CHECK(refine_b["loss"].get<double>() <= refine_a["loss"].get<double>() * (1 + 1e-6));
  // "none" is no restarts: the single start's result.
  r = run("capture syn/capture.json -o none --stages refine --steps 60 --neighbour-restarts none --no-view", t.path);
  REQUIRE(r.status == 0);
  CHECK(report("none")["stages"].back()["loss"] == refine_a["loss"]);
  // The default: one round at radius 8 after the network stages; none with --schedule paper (and,
  // above, none for the refine alone).
  r = run("capture syn/capture.json -o networks --stages all --finetune-steps 4 --steps 5 --no-view", t.path);
  REQUIRE(r.status == 0);
  const nlohmann::json n = report("networks");
  CHECK(n["refine"]["neighbour_restarts"] == nlohmann::json::array({8}));
  CHECK(n["stages"].back()["steps"] == 2 * 5);
  CHECK(n["stages"].back()["restart_replaced_fractions"].size() == 1);
  r = run("capture syn/capture.json -o paper --stages all --schedule paper --finetune-steps 4 --steps 5 --no-view", t.path);
  REQUIRE(r.status == 0);
  CHECK(report("paper")["refine"]["neighbour_restarts"].empty());
  CHECK(report("paper")["stages"].back()["steps"] == 5);
}

TEST_CASE("synthesize --shot-noise: inputs are the exact renders plus non-negative noise of the stated size") {
  temp_dir t;
  REQUIRE(run("synthesize -o syn --width 24 --height 20 --images 4 --seed 3 --shot-noise 0.05", t.path).status == 0);
  REQUIRE(run("render --maps syn/truth --capture syn/capture.json -o exact", t.path).status == 0);
  const auto noisy = anisocap::read_exr(t.path / "syn/input_01.exr");
  const auto exact = anisocap::read_exr(t.path / "exact/input_01.exr");
  double sum2 = 0, expected = 0;
  int differ = 0;
  for (int c = 0; c < 3; ++c)
    for (std::size_t i = 0; i < exact.pixel_count(); ++i) {
      CHECK(noisy.plane(c)[i] >= 0.0f);
      differ += noisy.plane(c)[i] != exact.plane(c)[i];
      sum2 += std::pow(double(noisy.plane(c)[i]) - exact.plane(c)[i], 2);
      expected += 0.05 * 0.05 * exact.plane(c)[i];
    }
  CHECK(differ > int(exact.pixel_count()));
  CHECK(sum2 == doctest::Approx(expected).epsilon(0.3));
}

TEST_CASE("capture from JPEG photographs with clipped highlights: clipping reported, excluded, bad masks refused") {
  temp_dir t;
  REQUIRE(run("synthesize -o syn --width 32 --height 24 --images 6 --seed 3", t.path).status == 0);
  // The renders as camera JPEGs, four times over-exposed (so that highlights clip at 255), with
  // "exposure": 0.25 in the description to bring them back to the renders' units. The first three
  // at quality 90, where stb stores the colour at half resolution, the others at 95, in full.
  anisocap::capture cap = anisocap::read_capture(t.path / "syn/capture.json");
  for (auto& im : cap.images) {
    const int quality = &im - cap.images.data() < 3 ? 90 : 95;
    const anisocap::image img = anisocap::read_exr(t.path / "syn" / im.file);
    std::vector<unsigned char> codes(img.pixel_count() * 3);
    for (std::size_t i = 0; i < img.pixel_count(); ++i)
      for (int c = 0; c < 3; ++c)
        codes[i * 3 + std::size_t(c)] = static_cast<unsigned char>(
            std::lround(255.0 * anisocap::linear_to_srgb(std::min(1.0, 4.0 * double(img.plane(c)[i])))));
    im.file = fs::path(im.file).replace_extension(".jpg").string();
    REQUIRE(stbi_write_jpg((t.path / "syn" / im.file).c_str(), img.width(), img.height(), 3, codes.data(), quality));
    im.exposure = 0.25f;
  }
  anisocap::write_capture(cap, t.path / "syn/photos.json");
  auto r = run("capture syn/photos.json -o out --stages refine --steps 20", t.path);
  INFO(r.output);
  REQUIRE(r.status == 0);
  CHECK(r.output.find("(input_00.jpg): ") != std::string::npos);
  CHECK(r.output.find("% of pixels clipped, excluded from the loss") != std::string::npos);
  std::ifstream rep(t.path / "out/report.json");
  std::stringstream s;
  s << rep.rdbuf();
  CHECK(s.str().find("\"clipped_fraction\"") != std::string::npos);
  CHECK(s.str().find("\"input_05.jpg\"") != std::string::npos);
  // The subsampled colour is found in the files, said once, and the uncertainty calibrated for it.
  CHECK(r.output.find("capture: 3 of 6 photographs store their colour at a lower resolution than their brightness") != std::string::npos);
  const auto report = nlohmann::json::parse(s.str());
  CHECK(report["uncertainty"]["calibration"] == "jpeg_subsampled");
  CHECK(report["photos"][0]["encoding"] == "jpeg_subsampled");
  CHECK(report["photos"][5]["encoding"] == "jpeg");
  // --fit-clipped fits them, and says so.
  r = run("capture syn/photos.json -o fitted --stages refine --steps 5 --fit-clipped", t.path);
  CHECK(r.status == 0);
  CHECK(r.output.find("FITTED (--fit-clipped)") != std::string::npos);

  // A mask of the wrong size: one error naming the mask file, nothing written.
  const unsigned char ones[16 * 16] = {1};
  REQUIRE(stbi_write_png((t.path / "syn/mask_02.png").c_str(), 16, 16, 1, ones, 16));
  cap.images[2].mask = "mask_02.png";
  anisocap::write_capture(cap, t.path / "syn/masked.json");
  r = run("capture syn/masked.json -o bad --stages refine --steps 5", t.path);
  CHECK(r.status != 0);
  CHECK(r.output.find("mask_02.png: the mask is 16x16 but its photograph is 32x24") != std::string::npos);
  CHECK(std::count(r.output.begin(), r.output.end(), '\n') == 1);
  CHECK_FALSE(fs::exists(t.path / "bad"));
}

TEST_CASE("bad input: one clear message naming the file, non-zero exit, no output") {
  temp_dir t;
  REQUIRE(run("synthesize -o syn --width 16 --height 16 --images 4 --seed 5", t.path).status == 0);

  SUBCASE("missing capture file") {
    auto r = run("capture nowhere/capture.json -o out", t.path);
    CHECK(r.status != 0);
    CHECK(r.output.find("nowhere/capture.json") != std::string::npos);
    CHECK_FALSE(fs::exists(t.path / "out"));
  }
  SUBCASE("malformed capture description") {
    write(t.path / "syn/bad.json", "{\"images\": [{\"file\": \"input_00.exr\", \"camera\": [0, 0], \"light\": [0,0,1], \"intensity\": 1}]}");
    auto r = run("capture syn/bad.json -o out", t.path);
    CHECK(r.status != 0);
    CHECK(r.output.find("bad.json") != std::string::npos);
    CHECK(r.output.find("camera") != std::string::npos);
    CHECK_FALSE(fs::exists(t.path / "out"));
  }
  SUBCASE("an input image with NaN pixels") {
    anisocap::image img = anisocap::read_exr(t.path / "syn/input_01.exr");
    img.at(1, 3, 4) = std::nanf("");
    anisocap::write_exr(img, t.path / "syn/input_01.exr");
    auto r = run("capture syn/capture.json -o out", t.path);
    CHECK(r.status != 0);
    CHECK(r.output.find("input_01.exr") != std::string::npos);
    CHECK_FALSE(fs::exists(t.path / "out"));
  }
  SUBCASE("an unreadable image") {
    write(t.path / "syn/input_02.exr", "this is not an EXR file");
    auto r = run("capture syn/capture.json -o out", t.path);
    CHECK(r.status != 0);
    CHECK(r.output.find("input_02.exr") != std::string::npos);
    CHECK_FALSE(fs::exists(t.path / "out"));
  }
  SUBCASE("a map set with a missing file") {
    fs::remove(t.path / "syn/truth/fresnel.exr");
    auto r = run("render --maps syn/truth --capture syn/capture.json -o out", t.path);
    CHECK(r.status != 0);
    CHECK(r.output.find("fresnel.exr") != std::string::npos);
    CHECK_FALSE(fs::exists(t.path / "out"));
  }
  SUBCASE("network stages without weights") {
    fs::create_directories(t.path / "empty_models");
    auto r = run("capture syn/capture.json -o out --stages all --models empty_models", t.path);
    CHECK(r.status != 0);
    CHECK(r.output.find("estimator.safetensors") != std::string::npos);
    CHECK(run("eval -o ev --models empty_models", t.path).status != 0);
    CHECK(run("capture syn/capture.json -o out --stages estimate,polish", t.path).output.find("polish") != std::string::npos);
    CHECK_FALSE(fs::exists(t.path / "out"));
    CHECK_FALSE(fs::exists(t.path / "ev"));
  }
  SUBCASE("impossible options") {
    CHECK(run("capture syn/capture.json -o out --steps -3", t.path).status != 0);
    CHECK(run("capture syn/capture.json -o out --kernel fancy", t.path).output.find("--kernel") != std::string::npos);
    CHECK(run("synthesize -o s2 --set gamma", t.path).output.find("--set") != std::string::npos);
    CHECK(run("capture syn/capture.json -o out --precision quad", t.path).output.find("--precision") != std::string::npos);
    CHECK(run("capture syn/capture.json -o out --freeze 2", t.path).output.find("--freeze") != std::string::npos);
    CHECK(run("capture syn/capture.json -o out --refine-stop -1", t.path).output.find("--refine-stop") != std::string::npos);
    CHECK(run("eval -o ev --finetune-lr 0", t.path).output.find("--finetune-lr") != std::string::npos);
    CHECK(run("capture syn/capture.json -o out --finetune-crop -2", t.path).output.find("--finetune-crop") != std::string::npos);
    CHECK(run("capture syn/capture.json -o out --finetune-warmup -1", t.path).output.find("--finetune-warmup") != std::string::npos);
    CHECK(run("eval -o ev --finetune-half-life -5", t.path).output.find("--finetune-half-life") != std::string::npos);
    CHECK(run("eval -o ev --read-noise -1", t.path).output.find("--read-noise") != std::string::npos);
    CHECK(run("synthesize -o s2 --shot-noise -0.1", t.path).output.find("--shot-noise") != std::string::npos);
    CHECK_FALSE(fs::exists(t.path / "ev"));
    CHECK_FALSE(fs::exists(t.path / "out"));
    CHECK_FALSE(fs::exists(t.path / "s2"));
  }
}

namespace {
std::string replaced(std::string text, const std::string& from, const std::string& to) {
  const auto at = text.find(from);
  REQUIRE(at != std::string::npos);
  return text.replace(at, from.size(), to);
}
}  // namespace

/// Every regular file under `folder` (relative path -> contents).
std::map<std::string, std::string> files_under(const fs::path& folder) {
  std::map<std::string, std::string> files;
  for (const auto& entry : fs::recursive_directory_iterator(folder))
    if (entry.is_regular_file()) {
      std::ifstream in(entry.path(), std::ios::binary);
      files[fs::relative(entry.path(), folder).string()] = std::string((std::istreambuf_iterator<char>(in)), {});
    }
  return files;
}

TEST_CASE("a capture that fails part-way through writing its results leaves the earlier results as they were") {
  temp_dir t;
  REQUIRE(run("synthesize -o syn --width 16 --height 16 --images 4 --seed 5", t.path).status == 0);
  auto r = run("capture syn/capture.json -o out --stages refine --steps 5", t.path);
  INFO(r.output);
  REQUIRE(r.status == 0);
  // The novel views are written after the maps, the renders and the contact sheet: a file where
  // their folder goes makes the second run fail there, with every earlier output already produced.
  fs::remove_all(t.path / "out/novel");
  write(t.path / "out/novel", "in the way");
  const auto before = files_under(t.path / "out");
  REQUIRE(before.count("diffuse.exr") == 1);
  REQUIRE(before.count("renders/input_00.exr") == 1);
  REQUIRE(before.count("report.json") == 1);
  r = run("capture syn/capture.json -o out --stages refine --steps 9", t.path);  // other maps than the first run's
  INFO(r.output);
  CHECK(r.status != 0);
  CHECK(r.output.find("out/novel: cannot create the output folder") != std::string::npos);
  // Nothing of the failed run is left: the same files with the same bytes, no temporaries.
  const auto after = files_under(t.path / "out");
  CHECK(after.size() == before.size());
  for (const auto& file : before) {
    const auto& name = file.first;  // not a structured binding: Clang 14 cannot capture one in CAPTURE's lambda
    CAPTURE(name);
    CHECK(after.count(name) == 1);
    CHECK((after.count(name) == 1 && after.at(name) == file.second));
  }
  for (const auto& entry : fs::recursive_directory_iterator(t.path / "out")) {
    CAPTURE(entry.path());
    CHECK(entry.path().filename().string().find(".anisocap-tmp-") == std::string::npos);
  }
  // The same run with the way cleared replaces the results.
  fs::remove(t.path / "out/novel");
  r = run("capture syn/capture.json -o out --stages refine --steps 9", t.path);
  INFO(r.output);
  REQUIRE(r.status == 0);
  CHECK(files_under(t.path / "out").at("diffuse.exr") != before.at("diffuse.exr"));
  CHECK(fs::exists(t.path / "out/novel"));
}

TEST_CASE("train --network-precision bf16: recorded in checkpoint.json, and a run may resume in fp32 (the master weights are FP32)") {
  temp_dir t;
  const std::string run_options = " --size 32 --batch 2 --validate-every 1 --validation-count 1 --checkpoint-minutes 100";
  const bool has_bf16 = run("--version", t.path).output.find(", bf16)") != std::string::npos;
  if (!has_bf16) {
    check_refused("train-autoencoder --out ae --steps 1 --network-precision bf16" + run_options, t.path, "AVX-512 BF16", "ae");
    return;
  }
  auto r = run("train-autoencoder --out ae --steps 1 --network-precision bf16" + run_options, t.path);
  INFO(r.output);
  REQUIRE(r.status == 0);
  std::ifstream in(t.path / "ae/checkpoint.json");
  const nlohmann::json saved = nlohmann::json::parse(in);
  CHECK(saved["precision"] == "bf16");
  r = run("train-autoencoder --out ae --steps 2 --resume" + run_options, t.path);
  INFO(r.output);
  CHECK(r.status == 0);
}

TEST_CASE("train --resume: another batch is refused naming checkpoint.json; without a checkpoint no folder is left") {
  temp_dir t;
  const std::string run_options = " --size 32 --validate-every 1 --validation-count 1 --checkpoint-minutes 100";
  auto r = run("train-autoencoder --out ae --steps 1 --batch 2" + run_options, t.path);
  INFO(r.output);
  REQUIRE(r.status == 0);
  r = run("train-autoencoder --out ae --steps 2 --batch 3 --resume" + run_options, t.path);
  INFO(r.output);
  CHECK(r.status != 0);
  CHECK(r.output.find("ae/checkpoint.json") != std::string::npos);
  CHECK(r.output.find("resume it with --batch 2") != std::string::npos);
  r = run("train-autoencoder --out ae --steps 2 --batch 2 --resume --lr 3e-4" + run_options, t.path);
  INFO(r.output);
  CHECK(r.status == 0);
  CHECK(r.output.find("learning rate 0.001 -> 0.0003 from step 1") != std::string::npos);
  r = run("train-autoencoder --out nothing_here --steps 2 --resume" + run_options, t.path);
  INFO(r.output);
  CHECK(r.status != 0);
  CHECK(r.output.find("nothing_here/checkpoint.json") != std::string::npos);
  CHECK_FALSE(fs::exists(t.path / "nothing_here"));
}

TEST_CASE("outputs stay inside -o and never overwrite the command's inputs") {
  temp_dir t;
  REQUIRE(run("synthesize -o syn --width 16 --height 16 --images 4 --seed 5", t.path).status == 0);
  const std::string description = read_text(t.path / "syn/capture.json");
  const std::string name = "anisocap_escaped_" + std::to_string(std::random_device{}()) + ".exr";

  SUBCASE("a file name that climbs out of -o") {
    write(t.path / "syn/up.json", replaced(description, "input_00.exr", "../../" + name));
    const auto r = run("render --maps syn/truth --capture syn/up.json -o r", t.path);
    CHECK(r.status != 0);
    CHECK(r.output.find("outside the output folder") != std::string::npos);
    CHECK(r.output.find("../../" + name) != std::string::npos);
    CHECK_FALSE(fs::exists(t.path.parent_path() / name));
    CHECK_FALSE(fs::exists(t.path / "r"));
  }
  SUBCASE("an absolute file name") {
    const fs::path target = fs::temp_directory_path() / name;
    write(t.path / "syn/abs.json", replaced(description, "input_00.exr", target.string()));
    const auto r = run("render --maps syn/truth --capture syn/abs.json -o r", t.path);
    CHECK(r.status != 0);
    CHECK(r.output.find("outside the output folder") != std::string::npos);
    CHECK_FALSE(fs::exists(target));
    CHECK_FALSE(fs::exists(t.path / "r"));
  }
  SUBCASE("-o is the inputs' folder, or the maps' folder") {
    const std::string before = read_text(t.path / "syn/input_01.exr");
    auto r = run("render --maps syn/truth --capture syn/capture.json -o syn", t.path);
    CHECK(r.status != 0);
    CHECK(r.output.find("overwrite") != std::string::npos);
    CHECK(read_text(t.path / "syn/input_01.exr") == before);
    // Named after a map file, a render into the maps' folder would replace that map.
    write(t.path / "syn/maps.json", replaced(description, "input_00.exr", "diffuse.exr"));
    const std::string diffuse = read_text(t.path / "syn/truth/diffuse.exr");
    r = run("render --maps syn/truth --capture syn/maps.json -o syn/truth", t.path);
    CHECK(r.status != 0);
    CHECK(r.output.find("diffuse.exr") != std::string::npos);
    CHECK(read_text(t.path / "syn/truth/diffuse.exr") == diffuse);
    // capture's maps into the folder of its --truth maps would replace them.
    r = run("capture syn/capture.json -o syn/truth --truth syn/truth --stages refine --steps 2", t.path);
    CHECK(r.status != 0);
    CHECK(r.output.find("overwrite") != std::string::npos);
    CHECK(read_text(t.path / "syn/truth/diffuse.exr") == diffuse);
  }
}

TEST_CASE("impossible options and broken weights are refused before any output") {
  temp_dir t;
  REQUIRE(run("synthesize -o syn --width 16 --height 16 --images 4 --seed 5", t.path).status == 0);
  struct refused { std::string args, names; };
  const refused cases[] = {
      {"capture syn/capture.json -o out --stages refine --lr inf", "--lr"},
      {"capture syn/capture.json -o out --stages refine --freeze nan", "--freeze"},
      {"capture syn/capture.json -o out --stages refine --refine-stop nan", "--refine-stop"},
      {"capture syn/capture.json -o out --finetune-lr inf", "--finetune-lr"},
      {"capture syn/capture.json -o out --stages refine --finetune-guard 0.5", "--finetune-guard must be 0 (off) or above 1"},
      {"capture syn/capture.json -o out --stages refine,finetune", "--stages: finetune needs encode"},
      {"eval -o out --count 1 --stages refine,polish", "--stages: unknown stage 'polish'"},
      {"capture syn/capture.json -o out --stages refine --neighbour-restarts 0", "--neighbour-restarts"},
      {"capture syn/capture.json -o out --stages refine --neighbour-restarts 8,x", "'x' is not a radius"},
      {"eval -o out --count 1 --neighbour-restarts 4,", "--neighbour-restarts"},
      {"capture syn/capture.json -o out --preset huge", "--preset"},
      {"capture syn/capture.json -o out --models nowhere_models", "nowhere_models"},
      {"train-estimator --out out --steps -1", "--steps"},
      {"train-autoencoder --out out --batch 0", "--batch"},
      {"train-estimator --out out --lr nan", "--lr"},
      {"train-autoencoder --out out --render-weight -0.5", "--render-weight"},
      {"train-estimator --out out --lobe-weight 0", "--lobe-weight"},
      {"train-estimator --out out --sigma-weight -1", "--sigma-weight"},
      {"train-autoencoder --out out --diffuse-weight 0", "--diffuse-weight"},
      {"train-estimator --out out --normal-weight inf", "--normal-weight"},
      {"train-estimator --out out --emphasis brushed,linen", "linen"},
      {"train-estimator --out out --emphasis leather", "held-out family 'leather'"},
      {"train-autoencoder --out out --emphasis spun --emphasis-share 1.5", "--emphasis-share"},
      {"train-estimator --out out --shot-noise -0.01", "--shot-noise"},
      {"train-estimator --out out --read-noise nan", "--read-noise"},
      {"train-autoencoder --out out --shot-noise 0.01", "--shot-noise"},
      {"eval-networks --read-noise -1", "--read-noise"},
  };
  for (const auto& c : cases) {
    CAPTURE(c.args);
    const auto r = run(c.args, t.path);
    INFO(r.output);
    CHECK(r.status != 0);
    CHECK(r.output.find(c.names) != std::string::npos);
    CHECK_FALSE(fs::exists(t.path / "out"));
  }
  // Weights with a NaN: refused at load, naming the weights file, before any stage ran.
  const fs::path models = fs::path(ANISOCAP_SOURCE_DIR) / "models/compact";
  fs::create_directories(t.path / "bad_models/compact");
  fs::copy_file(models / "autoencoder.safetensors", t.path / "bad_models/compact/autoencoder.safetensors");
  anisocap::nn::safetensors_file weights = anisocap::nn::read_safetensors(models / "estimator.safetensors");
  anisocap::nn::safetensors_file broken;
  broken.metadata = weights.metadata;
  for (const auto& e : weights.entries()) {
    std::vector<std::byte> bytes(weights.bytes(e).begin(), weights.bytes(e).end());
    if (broken.entries().empty()) {
      const float nan = std::nanf("");
      std::memcpy(bytes.data(), &nan, sizeof nan);
    }
    broken.add(e.name, e.dtype, e.shape, bytes.data(), bytes.size());
  }
  anisocap::nn::write_safetensors(t.path / "bad_models/compact/estimator.safetensors", broken);
  const auto r = run("capture syn/capture.json -o out --stages all --models bad_models", t.path);
  INFO(r.output);
  CHECK(r.status != 0);
  CHECK(r.output.find("bad_models/compact/estimator.safetensors") != std::string::npos);
  CHECK(r.output.find("not finite") != std::string::npos);
  CHECK_FALSE(fs::exists(t.path / "out"));
  // eval with weights that fail to load (malformed, or holding NaN): refused naming the file, and
  // the output folder it locked is removed again.
  fs::create_directories(t.path / "malformed_models/compact");
  fs::copy_file(models / "autoencoder.safetensors", t.path / "malformed_models/compact/autoencoder.safetensors");
  write(t.path / "malformed_models/compact/estimator.safetensors", "not a safetensors file");
  for (const char* folder : {"malformed_models", "bad_models"}) {
    CAPTURE(folder);
    const auto e = run(std::string("eval -o eval_out --count 1 --min-size 32 --max-size 32 --images 4 --sets beta --models ") + folder,
                       t.path);
    INFO(e.output);
    CHECK(e.status != 0);
    CHECK(e.output.find(std::string(folder) + "/compact/estimator.safetensors") != std::string::npos);
    CHECK_FALSE(fs::exists(t.path / "eval_out"));
  }
}

TEST_CASE("options that were silently wrong: threads, huge sizes, lights below the surface, one image") {
  temp_dir t;
  auto r = run("--threads 100000 synthesize -o syn --width 16 --height 16 --images 4 --seed 5", t.path);
  INFO(r.output);
  REQUIRE(r.status == 0);
  CHECK(r.output.find("hardware threads") != std::string::npos);
  r = run("synthesize --threads 1 -o syn1 --width 8 --height 8 --images 4", t.path);  // after the command too
  CHECK(r.status == 0);
  r = run("--threads -3 synthesize -o syn2", t.path);
  CHECK(r.status != 0);
  CHECK(r.output.find("--threads must be 0") != std::string::npos);
  CHECK(r.output.size() < 400);
  CHECK_FALSE(fs::exists(t.path / "syn2"));

  r = run("synthesize -o huge --width 100000 --height 100000", t.path);
  CHECK(r.status != 0);
  CHECK(r.output.find("GiB") != std::string::npos);
  CHECK_FALSE(fs::exists(t.path / "huge"));

  const std::string description = read_text(t.path / "syn/capture.json");
  const auto light = description.find("\"light\"");
  REQUIRE(light != std::string::npos);
  const auto end = description.find(']', light);
  write(t.path / "syn/below.json", description.substr(0, light) + "\"light\": [0.1, 0.2, -0.5" + description.substr(end));
  r = run("capture syn/below.json -o out --stages refine --steps 2", t.path);
  CHECK(r.status != 0);
  CHECK(r.output.find("below the material plane") != std::string::npos);
  CHECK_FALSE(fs::exists(t.path / "out"));

  // One photograph: the capture runs but says the problem is ill-posed.
  const auto first = description.find('{', description.find('['));
  const auto first_end = description.find('}', first);
  write(t.path / "syn/one.json", "{\"images\": [" + description.substr(first, first_end - first + 1) + "]}");
  r = run("capture syn/one.json -o one --stages refine --steps 2", t.path);
  INFO(r.output);
  CHECK(r.status == 0);
  CHECK(r.output.find("ill-posed") != std::string::npos);
}

TEST_CASE("two runs into one output folder: the second is refused while the first holds the lock") {
  temp_dir t;
  REQUIRE(run("synthesize -o syn --width 16 --height 16 --images 4 --seed 5", t.path).status == 0);
  // The first run in the background; the second starts once the first has printed its start line
  // (after taking the lock) and before it finishes (tens of thousands of refine steps).
  const fs::path first_log = t.path / "first.txt";
  const std::string background = "cd '" + t.path.string() + "' && (OMP_NUM_THREADS=1 '" + program.string() +
                                 "' capture syn/capture.json -o out --stages refine --steps 400000 --refine-stop 0 --freeze 0 > '" +
                                 first_log.string() + "' 2>&1 & echo $! > first_pid; wait $!; echo $? > first_status) &";
  REQUIRE(std::system(background.c_str()) == 0);
  for (int i = 0; i < 600 && read_text(first_log).find("capture: 4 images") == std::string::npos; ++i)
    std::system("sleep 0.1");
  REQUIRE(read_text(first_log).find("capture: 4 images") != std::string::npos);
  const auto second = run("capture syn/capture.json -o out --stages refine --steps 2", t.path);
  INFO(second.output);
  CHECK(second.status != 0);
  CHECK(second.output.find("another anisocap run") != std::string::npos);
  // The other commands that write into a folder take the same lock.
  for (const std::string command : {"synthesize -o out --width 16 --height 16 --images 4", "demo -o out --size 16",
                                    "eval -o out --count 1 --min-size 16 --max-size 16 --images 4 --sets alpha --finetune-steps 0 --steps 1",
                                    "train-estimator --out out --steps 1 --size 64 --batch 1",
                                    "train-autoencoder --out out --steps 1 --size 32 --batch 2"}) {
    const auto other = run(command, t.path);
    INFO(command << "\n" << other.output);
    CHECK(other.status != 0);
    CHECK(other.output.find("another anisocap run") != std::string::npos);
  }
  CHECK_FALSE(fs::exists(t.path / "first_status"));
  // Stop the first run (it would take long) by its process id.
  std::system(("kill -INT $(cat '" + (t.path / "first_pid").string() + "') 2>/dev/null; true").c_str());
  for (int i = 0; i < 600 && !fs::exists(t.path / "first_status"); ++i) std::system("sleep 0.1");
}

TEST_CASE("--version, a suggestion on a mistyped command, defaults in the training help") {
  temp_dir t;
  auto r = run("--version", t.path);
  CHECK(r.status == 0);
  CHECK(r.output.find("anisocap 0.") != std::string::npos);
  CHECK(r.output.find("(kernels: ") != std::string::npos);  // the instruction set the kernels run
  // An instruction set the program cannot run is refused, before or after the command, with no output.
  check_refused("--kernel-isa avx9000 synthesize -o isa --width 8 --height 8 --images 1", t.path, "avx9000", "isa");
  check_refused("synthesize --kernel-isa avx9000 -o isa --width 8 --height 8 --images 1", t.path, "avx9000", "isa");
  r = run("captur syn/capture.json", t.path);
  CHECK(r.status != 0);
  CHECK(r.output.find("did you mean 'capture'") != std::string::npos);
  r = run("train-estimator --help", t.path);
  CHECK(r.output.find("2000") != std::string::npos);  // --steps' default
  r = run("train-autoencoder --help", t.path);
  CHECK(r.output.find("0.1") != std::string::npos);  // --smoothness' default
  // Every experimental compact auto-encoder preset the trainer takes is described in its --preset help.
  const auto ae_presets = anisocap::compact_autoencoder_presets::names();
  for (std::size_t i = 1; i < ae_presets.size(); ++i) CHECK_MESSAGE(r.output.find(ae_presets[i] + " (") != std::string::npos, ae_presets[i]);
  r = run("train-estimator --help", t.path);
  const auto estimator_presets = anisocap::compact_estimator_presets::names();
  for (std::size_t i = 1; i < estimator_presets.size(); ++i)
    CHECK_MESSAGE(r.output.find(estimator_presets[i] + " (") != std::string::npos, estimator_presets[i]);
  r = run("eval-networks --help", t.path);
  CHECK(r.output.find("30") != std::string::npos);  // --count's default
}

TEST_CASE("convert-weights --half: a file of about half the size that eval-networks reads with the same errors to 1%; the input is never overwritten") {
  temp_dir t;
  const fs::path models = fs::path(ANISOCAP_SOURCE_DIR) / "models" / "compact";
  const fs::path full = models / "autoencoder.safetensors";
  auto r = run("convert-weights '" + full.string() + "' half.safetensors --half", t.path);
  INFO(r.output);
  REQUIRE(r.status == 0);
  CHECK(fs::file_size(t.path / "half.safetensors") < 0.52 * double(fs::file_size(full)));
  // The reconstruction row of eval-networks with each file, on the same materials.
  auto errors = [&](const fs::path& weights) {
    const auto e = run("--threads 1 eval-networks --count 2 --size 64 --autoencoder '" + weights.string() + "' --estimator '" +
                           (models / "estimator.safetensors").string() + "'",
                       t.path);
    REQUIRE(e.status == 0);
    const auto at = e.output.find("| auto-encoder reconstruction");
    REQUIRE(at != std::string::npos);
    std::vector<double> values;
    std::stringstream line(e.output.substr(e.output.find(") |", at) + 3, e.output.find('\n', at) - e.output.find(") |", at) - 3));
    std::string cell;
    while (std::getline(line, cell, '|'))
      if (cell.find_first_not_of(' ') != std::string::npos) values.push_back(std::stod(cell));
    return values;
  };
  const auto e_full = errors(full), e_half = errors(t.path / "half.safetensors");
  REQUIRE(e_full.size() == 7);
  REQUIRE(e_half.size() == e_full.size());
  for (std::size_t i = 0; i < e_full.size(); ++i) CHECK(e_half[i] == doctest::Approx(e_full[i]).epsilon(0.01));
  // Back to floats: the original size; the input as output is refused and left as it was.
  r = run("convert-weights half.safetensors floats.safetensors", t.path);
  REQUIRE(r.status == 0);
  CHECK(fs::file_size(t.path / "floats.safetensors") == fs::file_size(full));
  const auto before = fs::file_size(t.path / "half.safetensors");
  r = run("convert-weights half.safetensors ./half.safetensors", t.path);
  CHECK(r.status != 0);
  CHECK(r.output.find("would overwrite one of the command's inputs; choose another output file") != std::string::npos);
  CHECK(fs::file_size(t.path / "half.safetensors") == before);
  r = run("convert-weights missing.safetensors out.safetensors --half", t.path);
  CHECK(r.status != 0);
  CHECK(r.output.find("missing.safetensors") != std::string::npos);
  CHECK_FALSE(fs::exists(t.path / "out.safetensors"));
}

TEST_CASE("families: new kinds synthesize, the held-out families evaluate per family, bad names and mixes are refused") {
  temp_dir t;
  auto s = run("synthesize -o leather --width 32 --height 32 --images 8 --kind leather --fresnel 4", t.path);
  REQUIRE(s.status == 0);
  CHECK(s.output.find("leather") != std::string::npos);
  CHECK(fs::exists(t.path / "leather" / "input_07.exr"));
  const fs::path models = fs::path(ANISOCAP_SOURCE_DIR) / "models" / "compact";
  auto e = run("eval-networks --count 3 --size 64 --families leather,printed,foil --estimator '" +
                   (models / "estimator.safetensors").string() + "' --autoencoder '" + (models / "autoencoder.safetensors").string() + "'",
               t.path);
  REQUIRE(e.status == 0);
  CHECK(e.output.find("| leather (held out) | 1 | estimator |") != std::string::npos);
  CHECK(e.output.find("| printed (held out) | 1 | baseline |") != std::string::npos);
  CHECK(e.output.find("| foil | 1 | auto-encoder |") != std::string::npos);
  CHECK(run("eval -o ev --families leather,linen", t.path).output.find("linen") != std::string::npos);
  CHECK(run("eval-networks --families linen", t.path).output.find("linen") != std::string::npos);
  {  // --window: one window that covers the material is the whole estimate; smaller ones differ
    const std::string nets = " --count 2 --size 128 --estimator '" + (models / "estimator.safetensors").string() + "' --autoencoder '" +
                             (models / "autoencoder.safetensors").string() + "'";
    auto estimator_row = [](const std::string& out) {
      const auto at = out.find("| estimator (");
      return at == std::string::npos ? std::string() : out.substr(at, out.find('\n', at) - at);
    };
    const auto whole = run("eval-networks" + nets, t.path), one = run("eval-networks --window 128" + nets, t.path),
               small = run("eval-networks --window 64 --stride 32" + nets, t.path);
    REQUIRE(whole.status == 0);
    REQUIRE(one.status == 0);
    REQUIRE(small.status == 0);
    CHECK_FALSE(estimator_row(whole.output).empty());
    CHECK(estimator_row(one.output) == estimator_row(whole.output));
    CHECK(estimator_row(small.output) != estimator_row(whole.output));
    CHECK(small.output.find("64 x 64 windows (stride 32") != std::string::npos);
    // Sensor noise on the estimator's inputs changes its errors and is named in the table's heading.
    const auto noisy = run("eval-networks --shot-noise 0.05 --read-noise 0.01" + nets, t.path);
    REQUIRE(noisy.status == 0);
    CHECK(noisy.output.find("with sensor noise (shot 0.05, read 0.01)") != std::string::npos);
    CHECK(whole.output.find("sensor noise") == std::string::npos);
    CHECK_FALSE(estimator_row(noisy.output).empty());
    CHECK(estimator_row(noisy.output) != estimator_row(whole.output));
    CHECK(run("eval-networks --window 96" + nets, t.path).output.find("multiple of 64") != std::string::npos);
    CHECK(run("eval-networks --window 64 --stride 80" + nets, t.path).output.find("--stride (80) is larger than --window (64)") != std::string::npos);
  }
  CHECK(run("train-estimator --out tr --materials extended", t.path).output.find("--materials") != std::string::npos);
  CHECK(run("synthesize -o s3 --images 5 --fresnel 4", t.path).status != 0);
  CHECK_FALSE(fs::exists(t.path / "ev"));
  CHECK_FALSE(fs::exists(t.path / "tr"));
  CHECK_FALSE(fs::exists(t.path / "s3"));
}

TEST_CASE("photographs of the printed marker frame: corners left out where the tags are found, rectify finds them") {
  temp_dir t;
  auto r = run("photograph -o shoot --size 48 --images 8 --marker-frame", t.path);
  REQUIRE(r.status == 0);
  const nlohmann::json photos = nlohmann::json::parse(read_text(t.path / "shoot/photos/photos.json"));
  int without = 0;
  for (const auto& p : photos["photos"]) without += !p.contains("corners");
  CHECK(without >= 4);  // the photos from above; grazing views may keep theirs
  r = run("rectify shoot/photos/photos.json -o rect --resolution 48", t.path);
  REQUIRE(r.status == 0);
  CHECK(r.output.find("8/8") != std::string::npos);
  CHECK(fs::exists(t.path / "rect/capture.json"));
}

TEST_CASE("photograph --noise-seed: another draw of the noise, the same material, configurations and exposures") {
  temp_dir t;
  for (const char* draw : {"0", "1", "2"}) {
    auto r = run(std::string("photograph -o d") + draw + " --size 32 --images 8 --photo-width 160 --photo-height 120 --read-noise 0.01 --noise-seed " + draw, t.path);
    REQUIRE(r.status == 0);
  }
  CHECK(read_text(t.path / "d1/truth/diffuse.exr") == read_text(t.path / "d2/truth/diffuse.exr"));
  CHECK(read_text(t.path / "d0/direct/capture.json") == read_text(t.path / "d1/direct/capture.json"));  // configurations, intensities
  CHECK(read_text(t.path / "d1/direct/capture.json") == read_text(t.path / "d2/direct/capture.json"));
  CHECK(read_text(t.path / "d1/direct/input_03.exr") != read_text(t.path / "d2/direct/input_03.exr"));
  CHECK(read_text(t.path / "d0/direct/input_03.exr") != read_text(t.path / "d1/direct/input_03.exr"));
  CHECK(read_text(t.path / "d1/photos/photo_03.jpg") != read_text(t.path / "d2/photos/photo_03.jpg"));
}

TEST_CASE("photograph --format exr: linear photographs clipped at 1 that rectify reads with --saturation 1") {
  temp_dir t;
  auto r = run("photograph -o shoot --size 32 --images 8 --photo-width 160 --photo-height 120 --read-noise 0.002 --format exr", t.path);
  REQUIRE(r.status == 0);
  CHECK(read_text(t.path / "shoot/photos/photos.json").find("photo_03.exr") != std::string::npos);
  const anisocap::image photo = anisocap::read_image(t.path / "shoot/photos/photo_03.exr");
  float largest = 0;
  std::size_t white = 0;
  for (int c = 0; c < 3; ++c)
    for (std::size_t k = 0; k < photo.pixel_count(); ++k) {
      largest = std::max(largest, photo.plane(c)[k]);
      white += photo.plane(c)[k] == 1.0f;
    }
  CHECK(largest == 1.0f);  // clipped at white, as a sensor's white level clips
  CHECK(white > 0);
  r = run("rectify shoot/photos/photos.json -o rect --resolution 32 --saturation 1", t.path);
  REQUIRE(r.status == 0);
  CHECK(r.output.find("photo_03.exr") != std::string::npos);
  CHECK(r.output.find("clipped") != std::string::npos);
}

TEST_CASE("photograph --format png: the JPEG's 8-bit sRGB codes without its compression") {
  temp_dir t;
  const std::string shoot = "--size 32 --images 8 --photo-width 160 --photo-height 120 --read-noise 0.002 --shot-noise 0.01";
  REQUIRE(run("photograph -o png " + shoot + " --format png", t.path).status == 0);
  REQUIRE(run("photograph -o exr " + shoot + " --format exr", t.path).status == 0);
  REQUIRE(run("photograph -o jpeg " + shoot, t.path).status == 0);
  CHECK(read_text(t.path / "png/photos/photos.json").find("photo_03.png") != std::string::npos);
  // The same noise draw: the PNG holds exactly the linear photo clipped to [0, 1], sRGB-encoded and
  // rounded to 8 bits; the JPEG only approximately.
  const anisocap::image linear = anisocap::read_image(t.path / "exr/photos/photo_03.exr");
  const anisocap::image png = anisocap::read_image(t.path / "png/photos/photo_03.png");
  const anisocap::image jpeg = anisocap::read_image(t.path / "jpeg/photos/photo_03.jpg");
  REQUIRE(png.pixel_count() == linear.pixel_count());
  double worst_png = 0, worst_jpeg = 0;
  for (int c = 0; c < 3; ++c)
    for (std::size_t k = 0; k < linear.pixel_count(); ++k) {
      const double x = linear.plane(c)[k];
      const double code = std::round(255.0 * anisocap::linear_to_srgb(std::clamp(x, 0.0, 1.0)));
      const double expected = anisocap::srgb_to_linear(code / 255.0);
      worst_png = std::max(worst_png, std::abs(png.plane(c)[k] - expected));
      worst_jpeg = std::max(worst_jpeg, std::abs(jpeg.plane(c)[k] - expected));
    }
  CHECK(worst_png < 1e-6);
  CHECK(worst_jpeg > 1e-3);
  const auto r = run("rectify png/photos/photos.json -o rect --resolution 32", t.path);
  REQUIRE(r.status == 0);
  CHECK(r.output.find("photo_03.png") != std::string::npos);
}

TEST_CASE("photographs to maps as the README's walkthrough runs them: photograph, rectify, capture") {
  temp_dir t;
  auto r = run("photograph -o shoot --size 48 --images 8 --photo-width 320 --photo-height 240", t.path);
  REQUIRE(r.status == 0);
  REQUIRE(fs::exists(t.path / "shoot/photos/photos.json"));
  // direct-clipped/ is direct/ clipped at white, its clipped texels masked out, as the JPEGs are.
  std::size_t clipped_texels = 0;
  for (int i = 0; i < 8; ++i) {
    const std::string n = std::string("0") + std::to_string(i);
    const anisocap::image direct = anisocap::read_image(t.path / ("shoot/direct/input_" + n + ".exr"));
    const anisocap::image clipped = anisocap::read_image(t.path / ("shoot/direct-clipped/input_" + n + ".exr"));
    const anisocap::image mask = anisocap::read_image(t.path / ("shoot/direct-clipped/mask_input_" + n + ".png"));
    for (std::size_t k = 0; k < direct.pixel_count(); ++k) {
      const bool white = std::max({direct.plane(0)[k], direct.plane(1)[k], direct.plane(2)[k]}) >= 1.0f;
      clipped_texels += white;
      REQUIRE(mask.plane(0)[k] == (white ? 0.0f : 1.0f));
      for (int c = 0; c < 3; ++c) REQUIRE(clipped.plane(c)[k] == std::min(direct.plane(c)[k], 1.0f));
    }
  }
  CHECK(clipped_texels > 0);
  CHECK(read_text(t.path / "shoot/direct-clipped/capture.json").find("\"mask\": \"mask_input_00.png\"") != std::string::npos);
  r = run("rectify shoot/photos/photos.json -o rect --resolution 48", t.path);
  REQUIRE(r.status == 0);
  CHECK(r.output.find("8/8") != std::string::npos);
  for (int i = 0; i < 8; ++i) {
    CHECK(fs::exists(t.path / ("rect/rectified_0" + std::to_string(i) + ".exr")));
    CHECK(fs::exists(t.path / ("rect/mask_0" + std::to_string(i) + ".png")));
  }
  const std::string description = read_text(t.path / "rect/capture.json");
  CHECK(description.find("\"mask\"") != std::string::npos);
  // Every photo and every texture-space image carries the same noise floor (rectify --floor,
  // photograph --floor), so that both captures run the same loss.
  const auto floors = [](const std::string& text) {
    std::vector<double> f;
    const nlohmann::json parsed = nlohmann::json::parse(text);
    for (const auto& im : parsed["images"]) f.push_back(im.value("floor", 0.0));
    return f;
  };
  CHECK(floors(description) == std::vector<double>(8, 0.005));
  CHECK(floors(read_text(t.path / "shoot/direct/capture.json")) == std::vector<double>(8, 0.005));
  CHECK(floors(read_text(t.path / "shoot/direct-clipped/capture.json")) == std::vector<double>(8, 0.005));
  r = run("capture rect/capture.json -o maps --stages refine --steps 20 --no-view", t.path);
  REQUIRE(r.status == 0);
  CHECK(fs::exists(t.path / "maps/diffuse.exr"));
  const nlohmann::json report = nlohmann::json::parse(read_text(t.path / "maps/report.json"));
  CHECK(report["photos"][3]["floor"].get<double>() == double(0.005f));
  // capture --floor replaces the description's floors, and the loss changes with them.
  r = run("capture rect/capture.json -o maps0 --stages refine --steps 20 --no-view --floor 0", t.path);
  REQUIRE(r.status == 0);
  const nlohmann::json report0 = nlohmann::json::parse(read_text(t.path / "maps0/report.json"));
  CHECK(report0["photos"][3]["floor"].get<double>() == 0.0);
  CHECK(report0["loss"].get<double>() != report["loss"].get<double>());
  r = run("rectify shoot/photos/photos.json -o rect0 --resolution 48 --floor 0", t.path);
  REQUIRE(r.status == 0);
  CHECK(read_text(t.path / "rect0/capture.json").find("floor") == std::string::npos);
  // A photo whose corners leave the texture order is one error naming the photo, and nothing is written.
  nlohmann::json photos = nlohmann::json::parse(read_text(t.path / "shoot/photos/photos.json"));
  photos["photos"][0]["corners"] = nlohmann::json::parse("[[0, 0], [0, 10], [10, 10], [10, 0]]");
  write(t.path / "shoot/photos/bad.json", photos.dump(2));
  r = run("rectify shoot/photos/bad.json -o bad", t.path);
  CHECK(r.status != 0);
  CHECK(r.output.find("photo_00") != std::string::npos);
  CHECK_FALSE(fs::exists(t.path / "bad"));
}

TEST_CASE("the loop of the walkthrough: capture, plan, photograph --plan takes the proposed photographs beside the others, rectify them all") {
  temp_dir t;
  const std::string shoot = "--size 32 --images 6 --flash --photo-width 240 --photo-height 180 --read-noise 0.002";
  REQUIRE(run("photograph -o shoot " + shoot, t.path).status == 0);
  REQUIRE(run("rectify shoot/photos/photos.json -o rect --resolution 32", t.path).status == 0);
  REQUIRE(run("capture rect/capture.json -o result --stages refine --steps 20 --no-view", t.path).status == 0);
  auto r = run("plan result --sample-mm 100 --photos 2", t.path);
  INFO(r.output);
  REQUIRE(r.status == 0);
  CHECK(r.output.find("The next 2 photographs") != std::string::npos);
  CHECK(r.output.find("Why: it ") != std::string::npos);
  const nlohmann::json plan = nlohmann::json::parse(read_text(t.path / "result/plan.json"));
  REQUIRE(plan["photos"].size() == 2);

  r = run("photograph -o shoot2 " + shoot + " --plan result/plan.json", t.path);
  INFO(r.output);
  REQUIRE(r.status == 0);
  // The set's six photographs are those taken without the plan, byte for byte (the same noise);
  // the plan's two follow, each with its own light.
  for (int i = 0; i < 6; ++i) {
    const std::string name = "/photos/photo_0" + std::to_string(i) + ".jpg";
    CHECK(read_text(t.path / ("shoot" + name)) == read_text(t.path / ("shoot2" + name)));
  }
  const nlohmann::json photos = nlohmann::json::parse(read_text(t.path / "shoot2/photos/photos.json"));
  REQUIRE(photos["photos"].size() == 8);
  for (int i = 0; i < 2; ++i) {
    const nlohmann::json& planned = plan["photos"][std::size_t(i)];
    const nlohmann::json& light = photos["photos"][std::size_t(6 + i)]["light"];
    CHECK(photos["photos"][std::size_t(6 + i)]["file"] == "photo_0" + std::to_string(6 + i) + ".jpg");
    if (planned["kind"] == "flash") {
      CHECK(light.contains("flash_offset_mm"));
    } else {
      REQUIRE(light.contains("position_mm"));
      for (std::size_t k = 0; k < 3; ++k) CHECK(light["position_mm"][k].get<double>() == doctest::Approx(planned["light_mm"][k].get<double>()).epsilon(1e-5));
    }
  }
  r = run("rectify shoot2/photos/photos.json -o rect2 --resolution 32", t.path);
  INFO(r.output);
  REQUIRE(r.status == 0);
  CHECK(r.output.find("8/8") != std::string::npos);

  // A plan that is not one: one message naming the file and the entry, and no output.
  write(t.path / "bad.json", "{\"photos\": [{\"kind\": \"lamp\", \"camera\": [0, 0, 2], \"light\": [1, 0, -1]}]}");
  check_refused("photograph -o bad " + shoot + " --plan bad.json", t.path, "bad.json: photos[0]", "bad");
  check_refused("photograph -o bad " + shoot + " --plan missing.json", t.path, "missing.json", "bad");
}

TEST_CASE("compact variants: train-estimator --init from a compact estimator, then capture and eval-networks read the variant from its file") {
  temp_dir t;
  const fs::path models = fs::path(ANISOCAP_SOURCE_DIR) / "models" / "compact";
  REQUIRE(run("synthesize -o syn --width 32 --height 32 --images 4 --seed 3", t.path).status == 0);
  // A plain compact estimator to start from (the shipped one may be a variant itself).
  REQUIRE(run("train-estimator --preset compact --out base --steps 1 --size 64 --batch 1 --validate-every 1000 --validation-count 1",
              t.path).status == 0);
  const fs::path compact_file = t.path / "base/estimator.safetensors";
  struct variant { std::string preset, fresh; bool head_start; };
  for (const variant& v : {variant{"compact-doubled-angle", "initialised afresh: track2.reduce2.weight, track2.reduce2.bias)", true},
                           variant{"compact-orientation", "initialised afresh: enc0.weight)", false},
                           variant{"compact-orientation-doubled-angle",
                                   "initialised afresh: enc0.weight, track2.reduce2.weight, track2.reduce2.bias)", true}}) {
    CAPTURE(v.preset);
    const std::string out = "run_" + v.preset, folder = "models_" + v.preset;
    auto r = run("train-estimator --preset " + v.preset + " --out " + out + " --steps 1 --size 64 --batch 1 --validate-every 1000 "
                 "--validation-count 1 --init " + compact_file.string(), t.path);
    INFO(r.output);
    REQUIRE(r.status == 0);
    CHECK(r.output.find(v.fresh) != std::string::npos);
    // A doubled-angle head starts from the compact file's tanh head (start_doubled_angle_head).
    CHECK((r.output.find("doubled-angle head starts from the file's tanh head") != std::string::npos) == v.head_start);
    // The variant's file in a compact models folder: capture builds that variant for it (the
    // plain compact estimator would refuse the file's shapes).
    fs::create_directories(t.path / folder / "compact");
    fs::copy_file(t.path / out / "estimator.safetensors", t.path / folder / "compact/estimator.safetensors");
    fs::copy_file(models / "autoencoder.safetensors", t.path / folder / "compact/autoencoder.safetensors");
    r = run("capture syn/capture.json -o out_" + v.preset + " --stages all --models " + folder + " --finetune-steps 1 --steps 1", t.path);
    INFO(r.output);
    CHECK(r.status == 0);
    CHECK(fs::exists(t.path / ("out_" + v.preset)));
    // eval-networks too (its auto-encoder: the shipped one, found from any folder).
    r = run("eval-networks --count 1 --size 64 --estimator " + out + "/estimator.safetensors", t.path);
    INFO(r.output);
    CHECK(r.status == 0);
    CHECK(r.output.find("mean-map baseline") != std::string::npos);
  }
}

namespace {
/// Trains a one-step auto-encoder of `preset` from the shipped compact file in t/`preset`/, checks
/// the layers it reports as started afresh and the preset in its file, puts it beside the shipped
/// estimator in t/models_`preset`/compact/, runs `capture syn/capture.json` with it and
/// `capture_options`, and eval-networks on it. Returns the capture's output folder.
fs::path check_autoencoder_variant(const temp_dir& t, const std::string& preset, const std::string& afresh,
                                   const std::string& capture_options) {
  const fs::path models = fs::path(ANISOCAP_SOURCE_DIR) / "models" / "compact";
  auto r = run("train-autoencoder --preset " + preset + " --out " + preset + " --steps 1 --size 32 --batch 2 --validate-every 1000 "
               "--validation-count 1 --init " + (models / "autoencoder.safetensors").string(), t.path);
  INFO(r.output);
  REQUIRE(r.status == 0);
  CHECK(r.output.find("initialised afresh: " + afresh + ")") != std::string::npos);
  const fs::path file = t.path / preset / "autoencoder.safetensors";
  std::string written;
  for (const auto& [key, value] : anisocap::nn::read_safetensors(file).metadata)
    if (key == "preset") written = value;
  CHECK(written == preset);
  // In a compact models folder: capture builds the auto-encoder the file names (the compact one
  // would refuse the file's shapes), and so does eval-networks.
  const fs::path folder = t.path / ("models_" + preset) / "compact";
  fs::create_directories(folder);
  fs::copy_file(file, folder / "autoencoder.safetensors");
  fs::copy_file(models / "estimator.safetensors", folder / "estimator.safetensors");
  r = run("capture syn/capture.json -o out_" + preset + " --stages all --models models_" + preset + " " + capture_options, t.path);
  INFO(r.output);
  CHECK(r.status == 0);
  r = run("eval-networks --count 1 --size 64 --autoencoder " + (file).string(), t.path);
  INFO(r.output);
  CHECK(r.status == 0);
  CHECK(r.output.find("auto-encoder reconstruction (" + preset + ")") != std::string::npos);
  return t.path / ("out_" + preset);
}
}  // namespace

TEST_CASE("compact-wide auto-encoder: train-autoencoder --init from the shipped one, then capture and eval-networks read it from its file") {
  temp_dir t;
  REQUIRE(run("synthesize -o syn --width 32 --height 32 --images 4 --seed 3", t.path).status == 0);
  // The layers whose widths change start afresh; the others come from the compact file.
  const fs::path out = check_autoencoder_variant(
      t, "compact-wide", "enc3.weight, enc3.bias, enc4.weight, enc4.bias, latent_norm.weight, latent_norm.bias, dec0.weight, dec0.bias, dec1.weight, "
      "latent_norm.running_mean, latent_norm.running_var",
      "--finetune-steps 1 --steps 1");
  CHECK(fs::exists(out / "diffuse.exr"));
}

TEST_CASE("compact-fine, compact-fine-wide, compact-fine-wider and compact-fine-widest auto-encoders: a latent cell per 16 texels, trained from the compact file, in capture with crops") {
  temp_dir t;
  // 80 x 48 texels: 5 x 3 latent cells of 16 (the compact auto-encoder would pad to 96 x 64).
  REQUIRE(run("synthesize -o syn --width 80 --height 48 --images 4 --seed 5", t.path).status == 0);
  struct variant {
    std::string preset, afresh;
  };
  const variant variants[] = {
      // enc0-enc3, the batch norm and dec0 have the compact file's shapes; dec1-dec3 do not.
      {"compact-fine", "dec1.weight, dec1.bias, dec2.weight, dec2.bias, dec3.weight, dec3.bias"},
      // The 256-wide latent: only enc0-enc2 and dec0's bias have the compact file's shapes.
      {"compact-fine-wide", "enc3.weight, enc3.bias, latent_norm.weight, latent_norm.bias, dec0.weight, dec1.weight, dec1.bias, "
                            "dec2.weight, dec2.bias, dec3.weight, dec3.bias, latent_norm.running_mean, latent_norm.running_var"},
      // The levels above the latent twice as wide: dec1's bias (128) and dec2 (128 -> 64) keep compact's shapes.
      {"compact-fine-wider", "enc0.weight, enc0.bias, enc1.weight, enc1.bias, enc2.weight, enc2.bias, enc3.weight, enc3.bias, "
                             "latent_norm.weight, latent_norm.bias, dec0.weight, dec0.bias, dec1.weight, dec3.weight, dec3.bias, "
                             "latent_norm.running_mean, latent_norm.running_var"},
      // The 384-wide latent changes only layers that compact-fine-wider already had afresh.
      {"compact-fine-widest", "enc0.weight, enc0.bias, enc1.weight, enc1.bias, enc2.weight, enc2.bias, enc3.weight, enc3.bias, "
                              "latent_norm.weight, latent_norm.bias, dec0.weight, dec0.bias, dec1.weight, dec3.weight, dec3.bias, "
                              "latent_norm.running_mean, latent_norm.running_var"}};
  for (const variant& v : variants) {
    INFO(v.preset);
    const fs::path out = check_autoencoder_variant(t, v.preset, v.afresh, "--finetune-steps 3 --finetune-crop 2 --steps 1 --no-view");
    const anisocap::material_maps written = anisocap::read_maps(out);
    CHECK(written.width() == 80);
    CHECK(written.height() == 48);
  }
}

TEST_CASE("train-autoencoder --inputs estimates --trainable encoder: the encoder learns from the shipped estimator's estimates") {
  temp_dir t;
  const fs::path models = fs::path(ANISOCAP_SOURCE_DIR) / "models" / "compact";
  const std::string init = " --init " + (models / "autoencoder.safetensors").string();
  auto r = run("--threads 1 train-autoencoder --out enc --steps 1 --size 64 --batch 2 --validate-every 1000 --validation-count 1 "
               "--inputs estimates --trainable encoder" + init, t.path);
  INFO(r.output);
  REQUIRE(r.status == 0);
  const auto description = nlohmann::json::parse(std::ifstream(t.path / "enc/checkpoint.json"));
  CHECK(description.at("inputs") == "estimates");
  CHECK(description.at("trainable") == "encoder");
  // Resuming it as a run on the true maps is refused with the option that resumes it.
  r = run("--threads 1 train-autoencoder --out enc --steps 2 --size 64 --batch 2 --trainable encoder --resume", t.path);
  CHECK(r.status != 0);
  CHECK(r.output.find("resume it with --inputs estimates") != std::string::npos);
  // The estimator reads sizes that are multiples of 64; encoder-only needs weights to start from.
  r = run("train-autoencoder --out small --size 32 --inputs estimates", t.path);
  CHECK(r.status != 0);
  CHECK(r.output.find("multiple of 64") != std::string::npos);
  r = run("train-autoencoder --out none --size 64 --trainable encoder", t.path);
  CHECK(r.status != 0);
  // The library names train_options fields; the program names its flags instead.
  CHECK(r.output.find("--trainable encoder trains against") != std::string::npos);
  CHECK(r.output.find("--init") != std::string::npos);
  CHECK(r.output.find("train_options::") == std::string::npos);
  CHECK_FALSE(fs::exists(t.path / "small"));
  CHECK_FALSE(fs::exists(t.path / "none"));
  // eval-networks reports the fine-tune's start: the estimate through the auto-encoder.
  r = run("--threads 1 eval-networks --count 1 --size 64 --autoencoder enc/autoencoder.safetensors", t.path);
  INFO(r.output);
  CHECK(r.status == 0);
  CHECK(r.output.find("| estimate through the auto-encoder (the fine-tune's start) |") != std::string::npos);
}

TEST_CASE("capture --also-models: runs the networks with both folders' weights and keeps the better fit") {
  temp_dir t;
  const fs::path models = fs::path(ANISOCAP_SOURCE_DIR) / "models";
  REQUIRE(run("synthesize -o syn --width 32 --height 32 --images 6 --seed 3 --kind spun", t.path).status == 0);
  const std::string common = "capture syn/capture.json --finetune-steps 5 --steps 5 --no-view";
  // A complete second folder: the shipped estimator with the second prior's auto-encoder.
  const fs::path second = t.path / "second";
  fs::create_directories(second / "compact");
  fs::copy_file(models / "compact/estimator.safetensors", second / "compact/estimator.safetensors");
  fs::copy_file(models / "also/compact/autoencoder.safetensors", second / "compact/autoencoder.safetensors");
  const std::string both = " --models '" + models.string() + "' --also-models '" + second.string() + "'";
  // Without the residual start's run: a choice between the two folders' standard runs.
  auto r = run(common + " -o both --no-also-residual --also-models-above 0" + both, t.path);
  INFO(r.output);
  REQUIRE(r.status == 0);
  const nlohmann::json report = nlohmann::json::parse(read_text(t.path / "both/report.json"));
  REQUIRE(report.contains("models"));
  const nlohmann::json& m = report.at("models");
  CHECK(m.at("other_ran") == true);
  CHECK(m.at("loss").get<double>() == report.at("loss").get<double>());
  CHECK(m.at("loss").get<double>() <= m.at("other_loss").get<double>());
  CHECK(m.at("chosen") != m.at("other"));
  CHECK_FALSE(fs::exists(t.path / "both/.checkpoint"));
  // Each folder alone gives the loss the selection reported for it: the choice is of whole runs.
  for (const char* side : {"chosen", "other"}) {
    const std::string dir = std::string("alone_") + side;
    r = run(common + " -o " + dir + " --no-also-residual --no-also-models --models '" + m.at(side).get<std::string>() + "'", t.path);
    REQUIRE(r.status == 0);
    const double alone = nlohmann::json::parse(read_text(t.path / dir / "report.json")).at("loss").get<double>();
    CHECK(alone == m.at(side == std::string("chosen") ? "loss" : "other_loss").get<double>());
  }
  // With the residual start's run on the first folder's weights as well (forced here by its
  // conditions at 0), the best fit of three whole runs: the first folder with each start, then the
  // second folder.
  r = run(common + " -o three --also-residual --also-residual-ratio 0 --also-models-above 0" + both, t.path);
  INFO(r.output);
  REQUIRE(r.status == 0);
  CHECK(r.output.find("now the weights in " + models.string() + " with the residual start") != std::string::npos);
  CHECK(r.output.find("now the weights in " + second.string()) != std::string::npos);
  // Each folder's standard run alone is checked above to give the loss "both" reported for it; the
  // first folder with the residual start alone is the third run.
  r = run(common + " -o first_residual --no-also-residual --no-also-models --finetune-residual --models '" + models.string() + "'", t.path);
  REQUIRE(r.status == 0);
  const double residual_alone = nlohmann::json::parse(read_text(t.path / "first_residual/report.json")).at("loss").get<double>();
  CHECK(nlohmann::json::parse(read_text(t.path / "three/report.json")).at("loss").get<double>() ==
        std::min({m.at("loss").get<double>(), m.at("other_loss").get<double>(), residual_alone}));
  // Above a threshold the first fit already meets, the second folder is not tried.
  r = run(common + " -o first_only --also-models-above 1e9" + both, t.path);
  REQUIRE(r.status == 0);
  const nlohmann::json first_only = nlohmann::json::parse(read_text(t.path / "first_only/report.json")).at("models");
  CHECK(first_only.at("other_ran") == false);
  CHECK(first_only.at("other_loss").is_null());
  CHECK(first_only.at("chosen").get<std::string>() == fs::absolute(models).string());
  // A folder holding only an auto-encoder runs it with the first folder's estimator: the same
  // whole run as a complete folder holding that estimator and that auto-encoder.
  fs::create_directories(t.path / "decoder_only/compact");
  fs::create_directories(t.path / "complete/compact");
  fs::copy_file(models / "also/compact/autoencoder.safetensors", t.path / "decoder_only/compact/autoencoder.safetensors");
  fs::copy_file(models / "also/compact/autoencoder.safetensors", t.path / "complete/compact/autoencoder.safetensors");
  fs::copy_file(models / "compact/estimator.safetensors", t.path / "complete/compact/estimator.safetensors");
  const std::string first = " --no-also-residual --also-models-above 0 --models '" + models.string() + "'";
  r = run(common + " -o decoder_only" + first + " --also-models decoder_only", t.path);
  INFO(r.output);
  REQUIRE(r.status == 0);
  r = run(common + " -o complete" + first + " --also-models complete", t.path);
  REQUIRE(r.status == 0);
  const nlohmann::json decoder_only = nlohmann::json::parse(read_text(t.path / "decoder_only/report.json")).at("models");
  const nlohmann::json complete = nlohmann::json::parse(read_text(t.path / "complete/report.json")).at("models");
  CHECK(decoder_only.at("other_ran") == true);
  CHECK(std::min(decoder_only.at("loss").get<double>(), decoder_only.at("other_loss").get<double>()) ==
        std::min(complete.at("loss").get<double>(), complete.at("other_loss").get<double>()));
  CHECK(std::max(decoder_only.at("loss").get<double>(), decoder_only.at("other_loss").get<double>()) ==
        std::max(complete.at("loss").get<double>(), complete.at("other_loss").get<double>()));
  // The second folder's own loss differs from the first folder's: its run used its own decoder.
  CHECK(decoder_only.at("loss").get<double>() != decoder_only.at("other_loss").get<double>());
  // models/also, the second folder the README recommends, is such a folder and runs.
  CHECK_FALSE(fs::exists(models / "also/compact/estimator.safetensors"));
  r = run(common + " -o also" + first + " --also-models '" + (models / "also").string() + "'", t.path);
  INFO(r.output);
  REQUIRE(r.status == 0);
  CHECK(nlohmann::json::parse(read_text(t.path / "also/report.json")).at("models").at("other_ran") == true);
  // A folder that does not exist, and one without weights: refused, nothing written.
  r = run(common + " -o none --also-models missing_folder", t.path);
  CHECK(r.status != 0);
  CHECK(r.output.find("missing_folder") != std::string::npos);
  fs::create_directories(t.path / "empty");
  r = run(common + " -o none --also-models empty", t.path);
  CHECK(r.status != 0);
  CHECK(r.output.find("empty: no second prior there") != std::string::npos);
  r = run(common + " -o none --stages refine --also-models '" + second.string() + "'", t.path);
  CHECK(r.status != 0);
  CHECK(r.output.find("--also-models chooses between the network stages' results") != std::string::npos);
  CHECK_FALSE(fs::exists(t.path / "none/report.json"));
}

TEST_CASE("eval --first-seed redoes one material of a larger run") {
  temp_dir t;
  const std::string common = " --min-size 32 --max-size 32 --images 4 --sets alpha --finetune-steps 1 --steps 2 --materials extended";
  REQUIRE(run("--threads 1 eval -o all --count 4 --families brushed,spun,foil,coated" + common, t.path).status == 0);
  auto r = run("--threads 1 eval -o one --count 1 --first-seed 900003 --families coated" + common, t.path);
  INFO(r.output);
  REQUIRE(r.status == 0);
  // The row of material 3 (seed 900003, coated) without its index and seconds: the same material,
  // photographs and errors.
  auto row = [&](const fs::path& csv, const std::string& seed) {
    std::ifstream in(t.path / csv / "table.csv");
    for (std::string line; std::getline(in, line);) {
      std::vector<std::string> fields;
      std::stringstream cells(line);
      for (std::string cell; std::getline(cells, cell, ',');) fields.push_back(cell);
      if (fields.size() == 20 && fields[1] == seed && fields[6] == "refined") {
        fields.erase(fields.begin() + 15);  // seconds
        fields.erase(fields.begin());       // material index
        return fields;
      }
    }
    return std::vector<std::string>{};
  };
  const auto one = row("one", "900003");
  REQUIRE(one.size() == 18);
  CHECK(one[14] == "coated");
  // The refine's image loss against the photographs, and those of the fine-tune's two possible
  // starts (the estimate and its auto-encoder projection): finite positive numbers, the same in
  // both runs; the projection is not the estimate, so its loss differs.
  const double photo_loss = std::stod(one[15]), estimate_loss = std::stod(one[16]), encode_loss = std::stod(one[17]);
  CHECK(std::isfinite(photo_loss));
  CHECK(photo_loss > 0);
  CHECK(std::isfinite(estimate_loss));
  CHECK(estimate_loss > 0);
  CHECK(std::isfinite(encode_loss));
  CHECK(encode_loss != estimate_loss);
  CHECK(one == row("all", "900003"));
}

TEST_CASE("eval --stages: the auto-encoder left out gives refined rows only; unknown stages and --also-models without networks are refused") {
  temp_dir t;
  const std::string common = " --count 1 --min-size 32 --max-size 32 --images 4 --sets alpha --finetune-steps 1 --steps 2";
  auto r = run("--threads 1 eval -o all" + common, t.path);
  INFO(r.output);
  REQUIRE(r.status == 0);
  r = run("--threads 1 eval -o er" + common + " --stages estimate,refine", t.path);
  INFO(r.output);
  REQUIRE(r.status == 0);
  const std::string all = read_text(t.path / "all/table.csv"), er = read_text(t.path / "er/table.csv");
  CHECK(all.find(",fine-tuned,") != std::string::npos);
  CHECK(er.find(",fine-tuned,") == std::string::npos);
  CHECK(er.find(",refined,") != std::string::npos);
  // The refine alone starts from the first guess: the same material, another result.
  r = run("--threads 1 eval -o r" + common + " --stages refine", t.path);
  REQUIRE(r.status == 0);
  const std::string alone = read_text(t.path / "r/table.csv");
  CHECK(alone.find(",refined,") != std::string::npos);
  CHECK(alone != er);
  check_refused("eval -o bad" + common + " --stages estimate,bogus", t.path, "unknown stage 'bogus'", "bad");
  check_refused("eval -o bad" + common + " --stages refine --also-models '" + (fs::path(ANISOCAP_SOURCE_DIR) / "models/also").string() + "'",
                t.path, "--also-models chooses between the network stages' results", "bad");
}

TEST_CASE("capture --also-residual: a second run with the fine-tune started at the estimate, kept where it fits better") {
  temp_dir t;
  REQUIRE(run("synthesize -o syn --width 32 --height 32 --images 6 --seed 3 --kind spun", t.path).status == 0);
  // The second prior off: the choice here is between the two starts on the same weights.
  const std::string common = "capture syn/capture.json --finetune-steps 5 --steps 5 --no-view --no-also-models";
  auto r = run(common + " -o both --also-residual --also-models-above 0 --also-residual-ratio 0", t.path);
  INFO(r.output);
  REQUIRE(r.status == 0);
  CHECK(r.output.find("with the residual start") != std::string::npos);
  const nlohmann::json report = nlohmann::json::parse(read_text(t.path / "both/report.json"));
  const nlohmann::json& m = report.at("models");
  CHECK(m.at("other_ran") == true);
  // The projection ratio: the encode stage's loss over the estimate's, as the first run's report has them.
  const auto& stages = report.at("stages");
  const double ratio = m.at("projection_ratio").get<double>();
  CHECK(ratio > 0);
  CHECK(m.at("chosen") == m.at("other"));  // the same weights, two starts
  CHECK(m.at("chosen_residual") != m.at("other_residual"));
  CHECK(m.at("loss").get<double>() == report.at("loss").get<double>());
  CHECK(m.at("loss").get<double>() <= m.at("other_loss").get<double>());
  // Each start alone gives the loss the selection reported for it.
  for (const char* side : {"chosen", "other"}) {
    const bool residual = m.at(std::string(side) + "_residual").get<bool>();
    const std::string dir = std::string("alone_") + side;
    r = run(common + " -o " + dir + " --no-also-residual" + (residual ? " --finetune-residual" : ""), t.path);
    REQUIRE(r.status == 0);
    const nlohmann::json alone = nlohmann::json::parse(read_text(t.path / dir / "report.json"));
    CHECK(alone.at("finetune").at("residual") == residual);
    CHECK(alone.at("loss").get<double>() == m.at(side == std::string("chosen") ? "loss" : "other_loss").get<double>());
    // The residual start's encode stage renders the estimate itself.
    const auto& alone_stages = alone.at("stages");
    if (residual)
      CHECK(alone_stages.at(1).at("loss").get<double>() == doctest::Approx(alone_stages.at(0).at("loss").get<double>()).epsilon(1e-4));
    else
      CHECK(ratio == doctest::Approx(alone_stages.at(1).at("loss").get<double>() / alone_stages.at(0).at("loss").get<double>()));
  }
  CHECK(stages.at(0).at("name") == "estimate");
  // Where the projection loses less than --also-residual-ratio asks, the second start is not tried;
  // nor where the first run had the residual start already.
  r = run(common + " -o gated --also-residual --also-models-above 0 --also-residual-ratio " + std::to_string(ratio * 1.01), t.path);
  REQUIRE(r.status == 0);
  CHECK(r.output.find("the auto-encoder's projection fits") != std::string::npos);
  const nlohmann::json gated = nlohmann::json::parse(read_text(t.path / "gated/report.json")).at("models");
  CHECK(gated.at("other_ran") == false);
  CHECK(gated.at("other_loss").is_null());
  CHECK(gated.at("projection_ratio").get<double>() == doctest::Approx(ratio));
  r = run(common + " -o already --finetune-residual --also-residual --also-models-above 0 --also-residual-ratio 0", t.path);
  REQUIRE(r.status == 0);
  CHECK(r.output.find("it had the residual start already") != std::string::npos);
  CHECK(nlohmann::json::parse(read_text(t.path / "already/report.json")).at("models").at("other_ran") == false);
  // The choice is on by default: the same two runs and the same result without the flag. Off with
  // --no-also-residual, and off without a word where no fine-tune runs (asked for, it is refused below).
  r = run(common + " -o default_on --also-models-above 0 --also-residual-ratio 0", t.path);
  REQUIRE(r.status == 0);
  const nlohmann::json default_on = nlohmann::json::parse(read_text(t.path / "default_on/report.json"));
  for (const char* key : {"loss", "other_loss", "chosen_residual", "other_residual", "projection_ratio"})
    CHECK(default_on.at("models").at(key) == m.at(key));
  CHECK(default_on.at("loss").get<double>() == report.at("loss").get<double>());
  r = run(common + " -o off --also-models-above 0 --also-residual-ratio 0 --no-also-residual", t.path);
  REQUIRE(r.status == 0);
  CHECK_FALSE(nlohmann::json::parse(read_text(t.path / "off/report.json")).contains("models"));
  CHECK(r.output.find("residual start") == std::string::npos);
  r = run(common + " -o refine_only --stages refine --also-models-above 0 --also-residual-ratio 0", t.path);
  REQUIRE(r.status == 0);
  CHECK_FALSE(nlohmann::json::parse(read_text(t.path / "refine_only/report.json")).contains("models"));
  check_refused(common + " -o none --stages refine --also-residual", t.path, "--also-residual chooses between the network stages' results",
                "none/report.json");
}
