// The anisocap program end to end: a small synthesize -> capture -> render round, and bad input
// that must give one clear message naming the file, a non-zero exit, and no output.
#include <doctest/doctest.h>

#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <random>
#include <sstream>
#include <string>

#include "anisocap/data/image_io.hpp"

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
  CHECK(fs::exists(t.path / "out/novel/novel_02.exr"));
  CHECK(s.str().find("\"exposure_scale\"") != std::string::npos);
  // The time/accuracy options run and are reported.
  r = run("capture syn/capture.json -o fast --stages refine --steps 60 --freeze 0.01 --refine-stop 1e-3 --precision double "
          "--kernel auto --cull 1e-3",
          t.path);
  INFO(r.output);
  REQUIRE(r.status == 0);
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
  CHECK(s3.str().find("\"crop\": 1") != std::string::npos);
  CHECK(s3.str().find("\"warmup\": 3") != std::string::npos);
  CHECK(s3.str().find("\"half_life\": 100") != std::string::npos);
  r = run("render --maps syn/truth --capture syn/capture.json -o again", t.path);
  REQUIRE(r.status == 0);
  // Rendering the true maps reproduces the inputs exactly (same renderer, same configuration).
  const auto a = anisocap::read_exr(t.path / "again/input_02.exr");
  const auto b = anisocap::read_exr(t.path / "syn/input_02.exr");
  for (std::size_t i = 0; i < a.pixel_count(); ++i) REQUIRE(a.plane(1)[i] == b.plane(1)[i]);
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
  CHECK(run("train-estimator --out tr --materials extended", t.path).output.find("--materials") != std::string::npos);
  CHECK(run("synthesize -o s3 --images 5 --fresnel 4", t.path).status != 0);
  CHECK_FALSE(fs::exists(t.path / "ev"));
  CHECK_FALSE(fs::exists(t.path / "tr"));
  CHECK_FALSE(fs::exists(t.path / "s3"));
}
