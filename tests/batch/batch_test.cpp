// Batches of captures (pipeline/batch.hpp): the manifest and its errors, the selection of one
// task's samples, the lock and its takeover, the unit's states, and a unit run end to end with a
// stand-in for the capture. The program with real captures, GNU parallel and the Slurm script:
// tests/batch/check_batch_program.sh and check_batch_parallel.sh.
#include <doctest/doctest.h>

#include <sys/wait.h>
#include <unistd.h>

#include <filesystem>
#include <fstream>
#include <random>
#include <string>

#include "anisocap/pipeline/batch.hpp"

namespace fs = std::filesystem;
using namespace anisocap;

namespace {

struct temp_dir {
  fs::path path;
  temp_dir() {
    std::random_device rd;
    path = fs::temp_directory_path() / ("anisocap_batch_" + std::to_string(rd()));
    fs::create_directories(path);
  }
  ~temp_dir() {
    std::error_code ec;
    fs::remove_all(path, ec);
  }
};

void write(const fs::path& p, const std::string& text) {
  fs::create_directories(p.parent_path());
  std::ofstream(p) << text;
}

/// The message parse_batch_manifest throws for `text` ("" when it does not throw).
std::string manifest_error(const std::string& text) {
  try {
    parse_batch_manifest(text, "/data/m.txt");
  } catch (const batch_input_error& e) {
    return e.what();
  }
  return "";
}

/// A selection: these names, or an index with an optional count.
batch_selection pick(std::vector<std::string> names, std::optional<long> index = std::nullopt, std::optional<long> count = std::nullopt) {
  batch_selection s;
  s.names = std::move(names);
  s.index = index;
  s.count = count;
  return s;
}

/// A capture description with two photographs in `folder` (the files exist, empty: the batch only checks them).
void write_capture_folder(const fs::path& folder) {
  write(folder / "capture.json",
        R"({"images": [{"file": "a.exr", "camera": [0, 0, 1], "light": [0.3, 0, 1], "intensity": 1},
                       {"file": "b.exr", "camera": [0, 0, 1], "light": [-0.3, 0, 1], "intensity": 1}]})");
  write(folder / "a.exr", "");
  write(folder / "b.exr", "");
}

}  // namespace

TEST_CASE("batch manifest: fields, quotes, comments, paths resolved against the manifest's folder") {
  const batch_manifest m = parse_batch_manifest(
      "# samples\n"
      "\n"
      "wool-01  photos/wool-01  out/wool-01   # the default options\n"
      "brushed.2 \"my photos/brushed/capture.json\" /abs/out --schedule thorough --lr 3e-3\n",
      "/data/m.txt");
  REQUIRE(m.samples.size() == 2);
  CHECK(m.samples[0].name == "wool-01");
  CHECK(m.samples[0].line == 3);
  CHECK(m.samples[0].capture == fs::path("/data/photos/wool-01"));
  CHECK(m.samples[0].out == fs::path("/data/out/wool-01"));
  CHECK(m.samples[0].options.empty());
  CHECK(m.samples[1].capture == fs::path("/data/my photos/brushed/capture.json"));
  CHECK(m.samples[1].out == fs::path("/abs/out"));
  CHECK(m.samples[1].options == std::vector<std::string>{"--schedule", "thorough", "--lr", "3e-3"});
  CHECK(m.where(1) == "/data/m.txt:4");
  CHECK(m.find("brushed.2") == 1);
  CHECK(m.find("nope") == -1);
}

TEST_CASE("batch manifest: every malformed line is refused naming the file, the line and the problem") {
  CHECK(manifest_error("a p o\nb p\n").find("/data/m.txt:2: expected NAME CAPTURE OUT") == 0);
  CHECK(manifest_error("a p o\n\na q r\n") == "/data/m.txt:3: duplicate sample name 'a' (first on line 1)");
  CHECK(manifest_error("a p o\nb q ./o/\n").find("/data/m.txt:2: sample 'b': output folder ./o/ is also sample 'a''s (line 1)") == 0);
  CHECK(manifest_error("a/b p o\n").find("/data/m.txt:1: 'a/b' is not a sample name") == 0);
  CHECK(manifest_error("-a p o\n").find("is not a sample name") != std::string::npos);
  CHECK(manifest_error("a p o --resume\n").find("/data/m.txt:1: sample 'a': --resume is set by the batch") == 0);
  CHECK(manifest_error("a p o --out=x\n").find("--out is set by the batch") != std::string::npos);
  CHECK(manifest_error("a p o -o x\n").find("-o is set by the batch") != std::string::npos);
  CHECK(manifest_error("a p o extra\n").find("/data/m.txt:1: sample 'a': expected capture options after the output folder, got 'extra'") == 0);
  CHECK(manifest_error("a \"p o\n").find("/data/m.txt:1: a quoted field is not closed") == 0);
  CHECK(manifest_error("# nothing\n\n") .find("/data/m.txt: no samples") == 0);
  CHECK(manifest_error("a p o\n").empty());
}

TEST_CASE("batch manifest: a missing file is refused naming it") {
  temp_dir t;
  CHECK_THROWS_WITH_AS(read_batch_manifest(t.path / "none.txt"), ((t.path / "none.txt").string() + ": no such manifest file").c_str(),
                       batch_input_error);
  CHECK_THROWS_AS(read_batch_manifest(t.path), batch_input_error);
}

TEST_CASE("batch selection: one sample by name or index, one task's share with --count, errors") {
  const batch_manifest m = parse_batch_manifest("a p a\nb p b\nc p c\nd p d\ne p e\n", "/m.txt");
  using v = std::vector<std::size_t>;
  CHECK(select_batch_samples(m, pick({})) == v{0, 1, 2, 3, 4});
  CHECK(select_batch_samples(m, pick({"d", "b", "d"})) == v{1, 3});
  CHECK(select_batch_samples(m, pick({}, 2, std::nullopt)) == v{2});
  CHECK(select_batch_samples(m, pick({}, 0, 2)) == v{0, 2, 4});
  CHECK(select_batch_samples(m, pick({}, 1, 2)) == v{1, 3});
  CHECK(select_batch_samples(m, pick({}, 4, 8)) == v{4});
  CHECK(select_batch_samples(m, pick({}, 6, 8)).empty());  // more tasks than samples: nothing to do
  CHECK_THROWS_WITH(select_batch_samples(m, pick({"x"})), doctest::Contains("no sample named 'x' (its samples: a, b, c, d, e)"));
  CHECK_THROWS_WITH(select_batch_samples(m, pick({}, 5, std::nullopt)), doctest::Contains("batch_selection::index 5 is out of range: the manifest has 5 samples, indices 0 to 4"));
  CHECK_THROWS_WITH(select_batch_samples(m, pick({}, 3, 3)), doctest::Contains("with batch_selection::count 3 the tasks are 0 to 2"));
  CHECK_THROWS_WITH(select_batch_samples(m, pick({}, std::nullopt, 3)), doctest::Contains("give this task's batch_selection::index too"));
  CHECK_THROWS_WITH(select_batch_samples(m, pick({"a"}, 1, std::nullopt)), doctest::Contains("give one of them"));
}

TEST_CASE("batch inputs: the capture description and every photograph must exist; the record follows them") {
  temp_dir t;
  write_capture_folder(t.path / "photos");
  write(t.path / "m.txt", "a photos out/a\nb photos/capture.json out/b --steps 5\nc nothing out/c\n");
  const batch_manifest m = read_batch_manifest(t.path / "m.txt");
  const batch_record a = check_batch_sample(m, 0);
  CHECK(a.json["capture"] == (t.path / "photos/capture.json").string());
  CHECK(a.json["inputs"].size() == 3);
  CHECK(check_batch_sample(m, 1).json["options"] == nlohmann::json({"--steps", "5"}));
  CHECK_THROWS_WITH_AS(check_batch_sample(m, 2), doctest::Contains(((t.path / "m.txt").string() + ":3: sample 'c': ").c_str()), batch_input_error);
  CHECK_THROWS_WITH(check_batch_sample(m, 2), doctest::Contains("no such capture description"));
  fs::remove(t.path / "photos/b.exr");
  CHECK_THROWS_WITH(check_batch_sample(m, 0), doctest::Contains(((t.path / "photos/b.exr").string() + ": no such photograph").c_str()));
  write(t.path / "photos/b.exr", "changed");
  const batch_record again = check_batch_sample(m, 0);
  CHECK(again.differences(a.json) == (t.path / "photos/b.exr").string());
  CHECK(again.differences(again.json).empty());
  nlohmann::json other_options = a.json;
  other_options["options"] = nlohmann::json({"--steps", "5"});
  CHECK(again.differences(other_options) == "options, " + (t.path / "photos/b.exr").string());
  nlohmann::json no_inputs = again.json;
  no_inputs["inputs"].push_back(nlohmann::json({"gone.exr", 1, 2}));  // one more input before: no file of this record differs
  CHECK(again.differences(no_inputs) == "inputs");
  write(t.path / "photos/capture.json", "{\"images\": 3}");
  CHECK_THROWS_WITH(check_batch_sample(m, 0), doctest::Contains("\"images\" must be an array"));
}

TEST_CASE("batch lock: exclusive while held, released at the end, a dead holder's lock taken over") {
  temp_dir t;
  const fs::path file = t.path / "batch.lock";
  {
    batch_lock first(file, 600);
    REQUIRE(first.held());
    batch_lock second(file, 600);
    CHECK_FALSE(second.held());
    CHECK(second.holder().pid == ::getpid());
    CHECK(second.holder().describe().find("pid " + std::to_string(::getpid())) != std::string::npos);
  }
  CHECK_FALSE(fs::exists(file));
  // A process of this host that is gone: its lock is stale and taken over.
  const pid_t child = ::fork();
  if (child == 0) ::_exit(0);
  ::waitpid(child, nullptr, 0);
  write(file, "host=" + batch_detail::host_name() + " pid=" + std::to_string(child) + " start=1\n");
  CHECK(batch_lock_holder::read(file)->stale(600));
  std::optional<batch_lock_holder> taken;
  {
    batch_lock third(file, 600, &taken);
    CHECK(third.held());
    REQUIRE(taken);
    CHECK(taken->pid == child);
  }
  // Another host's lock: stale only when not refreshed for the stale time.
  write(file, "host=elsewhere.invalid pid=1 start=1\n");
  CHECK_FALSE(batch_lock_holder::read(file)->stale(600));
  CHECK(batch_lock_holder::read(file)->stale(-1));
  batch_lock fourth(file, 600);
  CHECK_FALSE(fourth.held());
  CHECK(fourth.holder().host == "elsewhere.invalid");
}

TEST_CASE("batch unit: captured, then skipped; a failure keeps the check-point and the next run resumes; a change captures again") {
  temp_dir t;
  write_capture_folder(t.path / "photos");
  write(t.path / "m.txt", "a photos out/a --steps 5\n");
  batch_manifest m = read_batch_manifest(t.path / "m.txt");
  // A stand-in for `anisocap capture`: writes report.json, or fails leaving a check-point when FAIL exists.
  write(t.path / "capture.sh",
        "#!/bin/sh\n"
        "out=$4; echo \"args: $*\"\n"
        "if [ -e \"" + (t.path / "FAIL").string() + "\" ]; then mkdir -p \"$out/.checkpoint\"; echo 'capture: error: broken'; exit 3; fi\n"
        "echo '{}' > \"$out/report.json\"; rm -rf \"$out/.checkpoint\"\n");
  fs::permissions(t.path / "capture.sh", fs::perms::owner_all);
  batch_options o;
  o.program = "/bin/sh";
  o.program_arguments = {(t.path / "capture.sh").string()};
  const batch_unit_files f{t.path / "out/a"};
  // "capture CAPTURE -o OUT": the stand-in reads OUT as its fourth argument.
  write(t.path / "FAIL", "");
  batch_record r = check_batch_sample(m, 0);
  batch_outcome first = run_batch_unit(m, 0, r, o);
  CHECK(first.result == batch_result::failed);
  CHECK(first.exit_status == 3);
  CHECK(first.message.find("check-point is kept") != std::string::npos);
  CHECK(first.message.find("capture: error: broken") != std::string::npos);
  CHECK_FALSE(fs::exists(f.lock()));
  CHECK(inspect_batch_unit(f, r, 600) == batch_state::interrupted);
  fs::remove(t.path / "FAIL");
  const batch_outcome second = run_batch_unit(m, 0, r, o);
  CHECK(second.result == batch_result::captured);
  CHECK(second.state == batch_state::interrupted);
  const std::string log = batch_detail::read_text(f.log());
  CHECK(log.find("--resume --steps 5") != std::string::npos);
  CHECK(nlohmann::json::parse(batch_detail::read_text(f.marker()))["state"] == "done");
  CHECK(run_batch_unit(m, 0, r, o).result == batch_result::skipped);
  // Other options: captured again from the start.
  write(t.path / "m.txt", "a photos out/a --steps 6\n");
  m = read_batch_manifest(t.path / "m.txt");
  r = check_batch_sample(m, 0);
  std::string reason;
  CHECK(inspect_batch_unit(f, r, 600, &reason) == batch_state::changed);
  CHECK(reason == "options");
  const batch_outcome third = run_batch_unit(m, 0, r, o);
  CHECK(third.result == batch_result::captured);
  CHECK(third.state == batch_state::changed);
  // A live holder: busy.
  {
    batch_lock held(f.lock(), 600);
    REQUIRE(held.held());
    const batch_outcome busy = run_batch_unit(m, 0, check_batch_sample(m, 0), o);
    CHECK(busy.result == batch_result::skipped);  // done: the skip needs no lock
    write(t.path / "m.txt", "a photos out/a --steps 7\n");
    m = read_batch_manifest(t.path / "m.txt");
    CHECK(run_batch_unit(m, 0, check_batch_sample(m, 0), o).result == batch_result::busy);
  }
  const batch_summary s = run_batch(m, {0}, o);
  CHECK(s.count(batch_result::captured) == 1);
  CHECK(s.to_json()["samples"][0]["name"] == "a");
}
