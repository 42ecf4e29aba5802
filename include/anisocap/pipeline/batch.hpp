#pragma once
// Batches of captures (`anisocap batch`, docs/batch.md): a manifest names the samples, one line
// each, and every sample is one independent, idempotent unit of work. A unit whose outputs are
// complete for the same inputs and options is skipped; one that was interrupted resumes from the
// capture's check-point; one that another process is running is left to it (a lock file in the
// sample's output folder, with the holder's host and pid, refreshed while it runs, so that a
// holder that died is recognised and its lock taken over). Each unit appends to its own log and
// ends with its own report; the batch ends with a summary.
//
// Units are independent so that many processes can share one manifest: a Slurm job array task or
// a GNU parallel job runs one sample (select_batch_samples), and any number of batches over the
// same manifest divide its samples between them through the locks. The capture itself runs as a
// child process (run_logged_process): a crash, or a kill, of one sample's capture ends only that
// unit, and the unit's log holds all its output.
#include <fcntl.h>
#include <signal.h>
#include <sys/prctl.h>
#include <sys/stat.h>
#include <sys/wait.h>
#include <unistd.h>

#include <nlohmann/json.hpp>

#include <algorithm>
#include <atomic>
#include <cctype>
#include <cerrno>
#include <chrono>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <functional>
#include <optional>
#include <sstream>
#include <stdexcept>
#include <string>
#include <string_view>
#include <vector>

#include "anisocap/core/text.hpp"
#include "anisocap/data/capture_io.hpp"
#include "anisocap/data/image_io.hpp"

namespace anisocap {

/// Bad batch input (the manifest, a sample's capture description or photographs, a selection):
/// `what()` names the file and line ("manifest.txt:4: ...") and the problem. Thrown before any
/// unit runs, so that bad input leaves no output behind.
class batch_input_error : public std::invalid_argument {
 public:
  using std::invalid_argument::invalid_argument;
};

/// One sample of a batch manifest: one line `NAME CAPTURE OUT [capture options...]`.
struct batch_sample {
  std::string name;                  ///< unique in the manifest: letters, digits, '.', '_', '-'
  std::filesystem::path capture;     ///< the capture description (a folder in the manifest means its capture.json)
  std::filesystem::path out;         ///< the capture's output folder, the unit's log, report and lock
  std::vector<std::string> options;  ///< `anisocap capture` options of this sample, as written
  int line = 0;                      ///< the manifest line it was read from (1-based)
};

/// A parsed batch manifest: its samples in file order.
struct batch_manifest {
  std::filesystem::path file;  ///< the manifest file (relative paths in it are resolved against its folder)
  std::vector<batch_sample> samples;  ///< in file order

  /// The index of the sample named `name`, or -1.
  int find(std::string_view name) const {
    for (std::size_t i = 0; i < samples.size(); ++i)
      if (samples[i].name == name) return int(i);
    return -1;
  }
  /// "FILE:LINE" of sample `i`, the start of every message about it.
  std::string where(std::size_t i) const { return file.string() + ":" + std::to_string(samples[i].line); }
};

/// The capture options a manifest line may not give: the batch sets them for each unit.
inline constexpr std::string_view batch_reserved_options[] = {"-o", "--out", "--resume"};

namespace batch_detail {

/// Splits one manifest line into fields: separated by blanks, a field may be "double quoted" (with
/// \" and \\ inside) to hold blanks, and '#' outside quotes starts a comment. Throws
/// batch_input_error naming `where` for an unterminated quote.
inline std::vector<std::string> split_fields(std::string_view line, const std::string& where) {
  std::vector<std::string> fields;
  std::size_t i = 0;
  while (i < line.size()) {
    const char c = line[i];
    if (c == ' ' || c == '\t' || c == '\r') {
      ++i;
      continue;
    }
    if (c == '#') break;
    std::string field;
    bool quoted_field = false;
    while (i < line.size() && line[i] != ' ' && line[i] != '\t' && line[i] != '\r') {
      if (line[i] == '"') {
        quoted_field = true;
        ++i;
        bool closed = false;
        while (i < line.size()) {
          if (line[i] == '\\' && i + 1 < line.size() && (line[i + 1] == '"' || line[i + 1] == '\\')) {
            field += line[i + 1];
            i += 2;
          } else if (line[i] == '"') {
            closed = true;
            ++i;
            break;
          } else {
            field += line[i++];
          }
        }
        if (!closed) throw batch_input_error(where + ": a quoted field is not closed (a '\"' is missing)");
      } else {
        field += line[i++];
      }
    }
    if (!field.empty() || quoted_field) fields.push_back(std::move(field));
  }
  return fields;
}

/// Whether `name` is a sample name: letters, digits, '.', '_' and '-', not first '.' or '-', at most 200 characters.
inline bool valid_name(std::string_view name) {
  if (name.empty() || name.size() > 200 || name[0] == '.' || name[0] == '-') return false;
  for (char c : name)
    if (!(std::isalnum(static_cast<unsigned char>(c)) || c == '.' || c == '_' || c == '-')) return false;
  return true;
}

/// `p` resolved against `base` and normalised (the comparison of output folders).
inline std::filesystem::path resolved(const std::filesystem::path& base, const std::filesystem::path& p) {
  std::filesystem::path r = (p.is_absolute() ? p : base / p).lexically_normal();
  if (r.filename().empty() && r.has_relative_path()) r = r.parent_path();  // "out/" is "out"
  return r;
}

/// This host's name ("localhost" when it has none).
inline std::string host_name() {
  char name[256] = {};
  if (::gethostname(name, sizeof name - 1) != 0 || name[0] == 0) return "localhost";
  return name;
}

/// The start time of process `pid` since boot, in clock ticks (/proc/PID/stat field 22), or -1
/// when the process does not exist (or /proc cannot say): a pid reused by another process has
/// another start time.
inline long long process_start(long pid) {
  std::ifstream in("/proc/" + std::to_string(pid) + "/stat");
  std::string text;
  if (!in || !std::getline(in, text)) return -1;
  const std::size_t close = text.rfind(')');  // the command name may hold blanks and parentheses
  if (close == std::string::npos) return -1;
  std::istringstream fields(text.substr(close + 1));
  std::string field;
  for (int k = 3; k <= 22; ++k)
    if (!(fields >> field)) return -1;
  try {
    return std::stoll(field);
  } catch (const std::exception&) {
    return -1;
  }
}

/// The bytes of file `p` ("" when it cannot be read).
inline std::string read_text(const std::filesystem::path& p) {
  std::ifstream in(p, std::ios::binary);
  std::stringstream s;
  s << in.rdbuf();
  return s.str();
}

/// What a failed capture said last in `log`: its last line with "error:", else its last line that
/// is not blank nor CLI11's "Run with --help" hint; at most 300 characters.
inline std::string last_line(const std::filesystem::path& log) {
  std::ifstream in(log, std::ios::binary);
  if (!in) return {};
  in.seekg(0, std::ios::end);
  const std::streamoff size = in.tellg();
  const std::streamoff from = std::max<std::streamoff>(0, size - 4096);
  in.seekg(from);
  std::string tail((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  std::string last, error;
  std::istringstream lines(tail);
  for (std::string line; std::getline(lines, line);) {
    if (const auto cr = line.find_last_of('\r'); cr != std::string::npos) line = line.substr(cr + 1);  // progress lines
    if (line.find_first_not_of(" \t") == std::string::npos || line.rfind("Run with --help", 0) == 0) continue;
    last = line;
    if (line.find("error:") != std::string::npos) error = line;
  }
  if (!error.empty()) last = error;
  return last.size() > 300 ? last.substr(0, 300) + "..." : last;
}

/// The signal that asked the batch to stop (SIGINT, SIGTERM, SIGHUP), or 0.
inline std::atomic<int>& stop_signal() {
  static std::atomic<int> signal{0};
  return signal;
}

/// The handler batch_stop_on_signals installs: records the signal.
inline void on_stop_signal(int s) { stop_signal().store(s); }

}  // namespace batch_detail

/// Parses the text of a batch manifest; `file` names it in errors and its folder resolves relative
/// paths. One sample per line, `NAME CAPTURE OUT [capture options...]`, fields separated by blanks
/// ("double quotes" around a field with blanks); blank lines and text after '#' are ignored.
/// CAPTURE is a capture description (capture.json) or a folder holding one. Throws
/// batch_input_error naming the line for a line with fewer than three fields, a bad or duplicate
/// name, an output folder that another sample also uses, a reserved option
/// (batch_reserved_options) or an option list that does not start with an option; and for a
/// manifest without samples.
inline batch_manifest parse_batch_manifest(std::string_view text, const std::filesystem::path& file) {
  namespace fs = std::filesystem;
  batch_manifest m;
  m.file = file;
  const fs::path base = fs::absolute(file).parent_path();
  std::vector<fs::path> outs;
  int line_number = 0;
  std::size_t begin = 0;
  while (begin <= text.size()) {
    const std::size_t end = std::min(text.find('\n', begin), text.size());
    const std::string_view line = text.substr(begin, end - begin);
    begin = end + 1;
    ++line_number;
    const std::string where = file.string() + ":" + std::to_string(line_number);
    std::vector<std::string> fields = batch_detail::split_fields(line, where);
    if (fields.empty()) continue;
    if (fields.size() < 3)
      throw batch_input_error(where + ": expected NAME CAPTURE OUT [capture options...], got " + std::to_string(fields.size()) +
                              " field" + (fields.size() == 1 ? "" : "s"));
    batch_sample s;
    s.name = fields[0];
    s.line = line_number;
    if (!batch_detail::valid_name(s.name))
      throw batch_input_error(where + ": '" + s.name + "' is not a sample name: use letters, digits, '.', '_' and '-', not first '.' or '-'");
    if (const int other = m.find(s.name); other >= 0)
      throw batch_input_error(where + ": duplicate sample name '" + s.name + "' (first on line " + std::to_string(m.samples[std::size_t(other)].line) + ")");
    if (fields[1].empty() || fields[2].empty()) throw batch_input_error(where + ": sample '" + s.name + "': an empty path");
    s.capture = batch_detail::resolved(base, fields[1]);
    s.out = batch_detail::resolved(base, fields[2]);
    for (std::size_t i = 0; i < outs.size(); ++i)
      if (outs[i] == s.out)
        throw batch_input_error(where + ": sample '" + s.name + "': output folder " + fields[2] + " is also sample '" + m.samples[i].name +
                                "''s (line " + std::to_string(m.samples[i].line) + "); each sample needs its own");
    s.options.assign(fields.begin() + 3, fields.end());
    if (!s.options.empty() && s.options[0].rfind("-", 0) != 0)
      throw batch_input_error(where + ": sample '" + s.name + "': expected capture options after the output folder, got '" + s.options[0] + "'");
    for (const std::string& o : s.options)
      for (std::string_view reserved : batch_reserved_options)
        if (o == reserved || (reserved.size() > 2 && o.rfind(std::string(reserved) + "=", 0) == 0))
          throw batch_input_error(where + ": sample '" + s.name + "': " + std::string(reserved) +
                                  " is set by the batch for each sample (OUT is the third field; interrupted samples resume by themselves)");
    outs.push_back(s.out);
    m.samples.push_back(std::move(s));
  }
  if (m.samples.empty()) throw batch_input_error(file.string() + ": no samples (one line per sample: NAME CAPTURE OUT [capture options...])");
  return m;
}

/// Reads and parses a batch manifest (parse_batch_manifest); batch_input_error naming the file when
/// it cannot be read.
inline batch_manifest read_batch_manifest(const std::filesystem::path& file) {
  std::error_code ec;
  if (!std::filesystem::exists(file, ec)) throw batch_input_error(file.string() + ": no such manifest file");
  if (std::filesystem::is_directory(file, ec)) throw batch_input_error(file.string() + ": is a folder, not a manifest file");
  std::ifstream in(file, std::ios::binary);
  if (!in) throw batch_input_error(file.string() + ": cannot read the manifest");
  std::stringstream text;
  text << in.rdbuf();
  return parse_batch_manifest(text.str(), file);
}

/// Which samples of a manifest one batch process runs.
struct batch_selection {
  std::vector<std::string> names;  ///< these samples (in manifest order)
  /// With `count` unset, the sample at this index (0-based, manifest order); with `count` N,
  /// every sample whose index is `index` modulo N (task `index` of N tasks).
  std::optional<long> index;
  std::optional<long> count;  ///< the number of tasks the manifest is divided between
};

/// The indices of the samples `s` selects (all without names or an index). Throws
/// batch_input_error for an unknown name, an index out of range, a count below 1 or a count
/// without an index.
inline std::vector<std::size_t> select_batch_samples(const batch_manifest& m, const batch_selection& s) {
  std::vector<std::size_t> picked;
  const std::size_t n = m.samples.size();
  if (s.count && !s.index)
    throw batch_input_error("batch_selection::count divides the samples between tasks: give this task's batch_selection::index too");
  if (s.count && *s.count < 1) throw batch_input_error("batch_selection::count must be at least 1, got " + std::to_string(*s.count));
  if (!s.names.empty() && s.index)
    throw batch_input_error("batch_selection::names and batch_selection::index both choose samples: give one of them");
  for (const std::string& name : s.names) {
    const int i = m.find(name);
    if (i < 0) {
      std::string known;  // the first few names, so that a typo shows itself
      for (std::size_t k = 0; k < m.samples.size() && k < 6; ++k) known += (k ? ", " : "") + m.samples[k].name;
      if (m.samples.size() > 6) known += ", ... (" + std::to_string(m.samples.size()) + " in all)";
      throw batch_input_error(m.file.string() + ": no sample named '" + name + "' (its samples: " + known + ")");
    }
    if (std::find(picked.begin(), picked.end(), std::size_t(i)) == picked.end()) picked.push_back(std::size_t(i));
  }
  if (s.index) {
    const long count = s.count.value_or(0);
    const long limit = count > 0 ? count : long(n);
    if (*s.index < 0 || *s.index >= limit)
      throw batch_input_error(m.file.string() + ": batch_selection::index " + std::to_string(*s.index) + " is out of range: " +
                              (count > 0 ? "with batch_selection::count " + std::to_string(count) + " the tasks are 0 to " + std::to_string(count - 1)
                                         : "the manifest has " + std::to_string(n) + " sample" + (n == 1 ? "" : "s") + ", indices 0 to " +
                                               std::to_string(long(n) - 1)));
    if (count > 0) {
      for (std::size_t i = std::size_t(*s.index); i < n; i += std::size_t(count)) picked.push_back(i);
    } else {
      picked.push_back(std::size_t(*s.index));
    }
  }
  if (s.names.empty() && !s.index)
    for (std::size_t i = 0; i < n; ++i) picked.push_back(i);
  std::sort(picked.begin(), picked.end());
  return picked;
}

/// What a unit is: its capture description, photographs and options. A unit whose outputs were
/// made for an equal record is done; another record means the inputs or options changed.
struct batch_record {
  nlohmann::json json;  ///< {"capture", "out", "options", "inputs": [[file, size, modification time], ...]}
  /// The files of `json["inputs"]` whose size or time differs from `other`'s, or "options" / "capture"; empty when equal.
  std::string differences(const nlohmann::json& other) const {
    std::vector<std::string> changed;
    for (const char* key : {"capture", "options"})
      if (!other.contains(key) || other[key] != json[key]) changed.emplace_back(key);
    if (!other.contains("inputs") || other["inputs"] != json["inputs"]) {
      const nlohmann::json& before = other.contains("inputs") ? other["inputs"] : nlohmann::json::array();
      const std::size_t listed = changed.size();
      for (const auto& f : json["inputs"])
        if (std::find(before.begin(), before.end(), f) == before.end()) changed.push_back(f[0].get<std::string>());
      if (changed.size() == listed) changed.emplace_back("inputs");
    }
    return join_names(changed, ", ");
  }
};

/// Checks that sample `i`'s capture description reads and validates and that every photograph and
/// mask it names exists; returns the unit's record. Throws batch_input_error naming the manifest
/// line, the file and the problem.
inline batch_record check_batch_sample(const batch_manifest& m, std::size_t i) {
  namespace fs = std::filesystem;
  const batch_sample& s = m.samples[i];
  const std::string where = m.where(i) + ": sample '" + s.name + "'";
  std::error_code ec;
  fs::path description = s.capture;
  if (fs::is_directory(description, ec)) description /= "capture.json";
  if (!fs::exists(description, ec))
    throw batch_input_error(where + ": " + description.string() + ": no such capture description" +
                            (fs::is_directory(s.capture, ec) ? " (the folder holds no capture.json)" : ""));
  capture cap;
  try {
    cap = read_capture(description);
  } catch (const std::exception& e) {
    throw batch_input_error(where + ": " + e.what());
  }
  batch_record r;
  r.json["capture"] = description.string();
  r.json["out"] = s.out.string();
  r.json["options"] = s.options;
  r.json["inputs"] = nlohmann::json::array();
  auto stamp = [&](const fs::path& file, const char* what) {
    struct stat st {};
    if (::stat(file.c_str(), &st) != 0)
      throw batch_input_error(where + ": " + file.string() + ": no such " + what + " (named by " + description.string() + ")");
    const long long ns = static_cast<long long>(st.st_mtim.tv_sec) * 1000000000LL + st.st_mtim.tv_nsec;
    r.json["inputs"].push_back({file.string(), static_cast<long long>(st.st_size), ns});
  };
  stamp(description, "capture description");
  for (const capture_image& im : cap.images) {
    stamp(description.parent_path() / im.file, "photograph");
    if (!im.mask.empty()) stamp(description.parent_path() / im.mask, "mask");
  }
  return r;
}

/// The files of a unit inside its output folder.
struct batch_unit_files {
  std::filesystem::path out;  ///< the sample's output folder
  std::filesystem::path marker() const { return out / "batch.json"; }   ///< the unit's state, written atomically; "done" last
  std::filesystem::path log() const { return out / "batch.log"; }       ///< every attempt's capture output, appended
  std::filesystem::path lock() const { return out / "batch.lock"; }     ///< held while a process runs the unit
  std::filesystem::path report() const { return out / "report.json"; } ///< the capture's report, written with its outputs
  std::filesystem::path checkpoint() const { return out / ".checkpoint"; }  ///< the capture's check-point (capture --resume)
};

/// A unit's state before it runs.
enum class batch_state {
  fresh,        ///< nothing to keep: capture from the start
  done,         ///< finished for the same record: skip
  interrupted,  ///< an earlier attempt left a check-point for the same record: resume it
  changed,      ///< finished or started for another record (inputs or options changed): capture again
  running,      ///< another live process holds the lock
};

/// The name of a state, as the summary and `--status` print it.
inline const char* batch_state_name(batch_state s) {
  switch (s) {
    case batch_state::fresh: return "new";
    case batch_state::done: return "done";
    case batch_state::interrupted: return "interrupted";
    case batch_state::changed: return "changed";
    case batch_state::running: return "running";
  }
  return "?";
}

/// The holder a lock file names: "host=H pid=P start=S" (S: the process's start time, process_start).
struct batch_lock_holder {
  std::string host;      ///< the holder's host name
  long pid = 0;          ///< the holder's process id on that host
  long long start = -1;  ///< the holder's start time (process_start; -1: unknown)
  double age_seconds = 0;  ///< since the holder last refreshed the lock (its modification time)

  /// "host H pid P".
  std::string describe() const { return "host " + host + " pid " + std::to_string(pid); }
  /// Whether the holder is gone: on this host, its pid does not run or runs another process (another
  /// start time); on another host, it has not refreshed the lock for `stale_seconds`.
  bool stale(double stale_seconds) const {
    if (host == batch_detail::host_name()) {
      const long long now = batch_detail::process_start(pid);
      return now < 0 || (start >= 0 && now != start);
    }
    return age_seconds > stale_seconds;
  }
  /// Reads a lock file; nullopt when it does not exist.
  static std::optional<batch_lock_holder> read(const std::filesystem::path& file) {
    struct stat st {};
    if (::stat(file.c_str(), &st) != 0) return std::nullopt;
    batch_lock_holder h;
    std::istringstream in(batch_detail::read_text(file));
    for (std::string field; in >> field;) {
      const auto eq = field.find('=');
      if (eq == std::string::npos) continue;
      const std::string key = field.substr(0, eq), value = field.substr(eq + 1);
      try {
        if (key == "host") h.host = value;
        if (key == "pid") h.pid = std::stol(value);
        if (key == "start") h.start = std::stoll(value);
      } catch (const std::exception&) {
      }
    }
    const double modified = double(st.st_mtim.tv_sec) + 1e-9 * double(st.st_mtim.tv_nsec);
    timespec now{};
    ::clock_gettime(CLOCK_REALTIME, &now);
    h.age_seconds = double(now.tv_sec) + 1e-9 * double(now.tv_nsec) - modified;
    return h;
  }
};

/// The lock of one unit: a file created with O_EXCL (atomic on local and NFS v3+ file systems)
/// holding this process's host, pid and start time, refreshed (its time touched) while the unit
/// runs and removed when it ends. A lock whose holder is gone (batch_lock_holder::stale) is taken
/// over: renamed aside atomically, so that of two processes taking it over one wins.
class batch_lock {
 public:
  /// Tries to take the lock at `file`; `held()` says whether it did, `holder()` who has it
  /// otherwise. `taken_over` receives the stale holder when its lock was taken over.
  batch_lock(std::filesystem::path file, double stale_seconds, std::optional<batch_lock_holder>* taken_over = nullptr)
      : file_(std::move(file)) {
    for (int attempt = 0; attempt < 3 && fd_ < 0; ++attempt) {
      if (create()) return;
      const auto h = batch_lock_holder::read(file_);
      if (!h) continue;  // released meanwhile: try again
      holder_ = *h;
      if (!h->stale(stale_seconds)) return;
      // Take it over: rename the stale lock aside (only one process succeeds), check that what was
      // renamed is still the stale holder's, and create ours.
      const std::filesystem::path aside = file_.string() + ".stale." + batch_detail::host_name() + "." + std::to_string(::getpid());
      if (::rename(file_.c_str(), aside.c_str()) != 0) continue;
      const auto renamed = batch_lock_holder::read(aside);
      if (renamed && (renamed->host != h->host || renamed->pid != h->pid || renamed->start != h->start)) {
        ::link(aside.c_str(), file_.c_str());  // a fresh lock taken meanwhile: put it back
        ::unlink(aside.c_str());
        if (const auto now = batch_lock_holder::read(file_)) holder_ = *now;
        return;
      }
      ::unlink(aside.c_str());
      if (create()) {
        if (taken_over) *taken_over = *h;
        return;
      }
    }
  }
  batch_lock(const batch_lock&) = delete;
  batch_lock& operator=(const batch_lock&) = delete;
  ~batch_lock() { release(); }

  /// Whether this process holds the lock.
  bool held() const { return fd_ >= 0; }
  /// Who holds it when this process does not.
  const batch_lock_holder& holder() const { return holder_; }
  /// Touches the lock's modification time: the holder is alive (other hosts judge staleness by it).
  void refresh() {
    if (fd_ >= 0) ::futimens(fd_, nullptr);
  }
  /// Removes the lock if this process holds it.
  void release() {
    if (fd_ < 0) return;
    ::close(fd_);
    fd_ = -1;
    // Only our own lock file: a process that judged ours stale (another host, no refresh for too
    // long) may have taken it over meanwhile.
    if (const auto h = batch_lock_holder::read(file_); h && h->host == batch_detail::host_name() && h->pid == ::getpid())
      ::unlink(file_.c_str());
  }

 private:
  bool create() {
    const int fd = ::open(file_.c_str(), O_WRONLY | O_CREAT | O_EXCL | O_CLOEXEC, 0644);
    if (fd < 0) return false;
    const std::string text = "host=" + batch_detail::host_name() + " pid=" + std::to_string(::getpid()) +
                             " start=" + std::to_string(batch_detail::process_start(::getpid())) + "\n";
    if (::write(fd, text.data(), text.size()) != ssize_t(text.size())) {
      ::close(fd);
      ::unlink(file_.c_str());
      return false;
    }
    fd_ = fd;
    return true;
  }

  std::filesystem::path file_;
  int fd_ = -1;
  batch_lock_holder holder_;
};

/// The state of a unit from its output folder's files (batch_unit_files) and its current record,
/// leaving its lock aside (fresh, done, interrupted or changed). `reason` receives, for `changed`,
/// what differs.
inline batch_state inspect_batch_outputs(const batch_unit_files& f, const batch_record& record, std::string* reason = nullptr) {
  namespace fs = std::filesystem;
  std::error_code ec;
  // No marker: nothing the batch made. A check-point there (a capture run by hand) cannot be
  // matched to this record, so the capture starts over, which clears it.
  if (!fs::exists(f.marker(), ec)) return batch_state::fresh;
  nlohmann::json marker;
  try {
    marker = nlohmann::json::parse(batch_detail::read_text(f.marker()));
  } catch (const std::exception&) {
    return batch_state::fresh;  // it is written atomically: only someone else's file reads so
  }
  const std::string differs = record.differences(marker.value("record", nlohmann::json::object()));
  if (!differs.empty()) {
    if (reason) *reason = differs;
    return batch_state::changed;
  }
  if (marker.value("state", "") == "done" && fs::exists(f.report(), ec)) return batch_state::done;
  if (fs::exists(f.checkpoint(), ec)) return batch_state::interrupted;
  return batch_state::fresh;
}

/// The state of a unit: `running` when a live process holds its lock (`reason`: the holder), else
/// inspect_batch_outputs.
inline batch_state inspect_batch_unit(const batch_unit_files& f, const batch_record& record, double stale_seconds, std::string* reason = nullptr) {
  if (const auto h = batch_lock_holder::read(f.lock()); h && !h->stale(stale_seconds)) {
    if (reason) *reason = h->describe();
    return batch_state::running;
  }
  return inspect_batch_outputs(f, record, reason);
}

/// Runs `argv` (argv[0]: the program's path) as a child process with its standard output and
/// error appended to `log`, and waits for it, calling `tick` about every 0.05 s meanwhile. The child
/// is killed when this process dies (PR_SET_PDEATHSIG), so that a killed batch leaves no capture
/// running; when this process is asked to stop (batch_stop_on_signals), the child gets SIGTERM.
/// Returns the child's exit status, or 128 + the signal that ended it; -1 when it cannot start.
inline int run_logged_process(const std::vector<std::string>& argv, const std::filesystem::path& log, const std::function<void()>& tick = {}) {
  const int log_fd = ::open(log.c_str(), O_WRONLY | O_CREAT | O_APPEND | O_CLOEXEC, 0644);
  if (log_fd < 0) throw io_error(log, std::string("cannot open the log: ") + std::strerror(errno));
  std::vector<char*> args;
  for (const std::string& a : argv) args.push_back(const_cast<char*>(a.c_str()));
  args.push_back(nullptr);
  const pid_t parent = ::getpid();
  std::fflush(nullptr);
  const pid_t child = ::fork();
  if (child < 0) {
    ::close(log_fd);
    return -1;
  }
  if (child == 0) {
    ::prctl(PR_SET_PDEATHSIG, SIGKILL);
    if (::getppid() != parent) ::_exit(137);  // the parent died before prctl
    ::signal(SIGINT, SIG_DFL);
    ::signal(SIGTERM, SIG_DFL);
    ::signal(SIGHUP, SIG_DFL);
    ::dup2(log_fd, 1);
    ::dup2(log_fd, 2);
    ::execv(args[0], args.data());
    const std::string message = std::string("cannot run ") + argv[0] + ": " + std::strerror(errno) + "\n";
    [[maybe_unused]] const auto written = ::write(2, message.data(), message.size());
    ::_exit(127);
  }
  ::close(log_fd);
  bool forwarded = false;
  for (;;) {
    int status = 0;
    const pid_t done = ::waitpid(child, &status, WNOHANG);
    if (done == child) {
      if (WIFEXITED(status)) return WEXITSTATUS(status);
      if (WIFSIGNALED(status)) return 128 + WTERMSIG(status);
      return -1;
    }
    if (done < 0 && errno != EINTR) return -1;
    if (batch_detail::stop_signal().load() != 0 && !forwarded) {
      ::kill(child, SIGTERM);
      forwarded = true;
    }
    if (tick) tick();
    timespec pause{0, 50'000'000};
    ::nanosleep(&pause, nullptr);
  }
}

/// From now on SIGINT, SIGTERM and SIGHUP ask the batch to stop (run_batch stops after the current
/// unit, whose capture gets SIGTERM, and keeps its check-point) instead of ending the process at
/// once. Slurm sends SIGTERM at a job's time limit and to cancelled jobs.
inline void batch_stop_on_signals() {
  struct sigaction action {};
  action.sa_handler = batch_detail::on_stop_signal;
  ::sigemptyset(&action.sa_mask);
  for (int s : {SIGINT, SIGTERM, SIGHUP}) ::sigaction(s, &action, nullptr);
}

/// The signal that asked the batch to stop (batch_stop_on_signals), or 0.
inline int batch_stop_requested() { return batch_detail::stop_signal().load(); }

/// How one unit ended.
enum class batch_result {
  captured,  ///< the capture ran (from the start or resumed) and finished
  skipped,   ///< already done for the same record
  busy,      ///< another live process holds its lock
  failed,    ///< the capture failed (its log says why); a check-point it left is resumed next time
  stopped,   ///< the batch was asked to stop (a signal) while it ran
};

/// The name of a result, as the summary prints it.
inline const char* batch_result_name(batch_result r) {
  switch (r) {
    case batch_result::captured: return "captured";
    case batch_result::skipped: return "skipped";
    case batch_result::busy: return "busy";
    case batch_result::failed: return "failed";
    case batch_result::stopped: return "stopped";
  }
  return "?";
}

/// One unit's outcome.
struct batch_outcome {
  std::string name;                            ///< the sample's name
  batch_result result = batch_result::skipped;  ///< how it ended
  batch_state state = batch_state::fresh;  ///< what it was before it ran
  double seconds = 0;                      ///< the capture's wall time (0 when it did not run)
  int exit_status = 0;                     ///< the capture's exit status (failed, stopped)
  std::string message;                     ///< one sentence: why skipped, busy or failed
  std::filesystem::path log;               ///< the unit's log (batch_unit_files::log)
};

/// A batch's outcomes, in the order the units ran.
struct batch_summary {
  std::vector<batch_outcome> outcomes;  ///< one per unit that was reached
  double seconds = 0;  ///< the whole batch's wall time
  /// The number of units with result `r`.
  int count(batch_result r) const {
    int n = 0;
    for (const auto& o : outcomes) n += o.result == r;
    return n;
  }
  /// The capture time of the units with result `r`.
  double seconds_of(batch_result r) const {
    double t = 0;
    for (const auto& o : outcomes)
      if (o.result == r) t += o.seconds;
    return t;
  }
  /// As JSON: counts, times and every outcome.
  nlohmann::json to_json() const {
    nlohmann::json j;
    j["seconds"] = seconds;
    for (batch_result r : {batch_result::captured, batch_result::skipped, batch_result::busy, batch_result::failed, batch_result::stopped})
      j[batch_result_name(r)] = count(r);
    j["samples"] = nlohmann::json::array();
    for (const auto& o : outcomes)
      j["samples"].push_back({{"name", o.name}, {"result", batch_result_name(o.result)}, {"state", batch_state_name(o.state)},
                              {"seconds", o.seconds}, {"exit_status", o.exit_status}, {"message", o.message}, {"log", o.log.string()}});
    return j;
  }
};

/// How run_batch runs the units.
struct batch_options {
  /// The program's path: each unit runs `PROGRAM [program_arguments] capture CAPTURE -o OUT
  /// [--resume] [options]` (batch_capture_arguments).
  std::filesystem::path program;
  std::vector<std::string> program_arguments;  ///< before `capture`, e.g. --threads N
  /// A lock on another host that has not been refreshed for this long is stale (seconds). On
  /// this host a lock is stale as soon as its process is gone.
  double stale_seconds = 600;
  /// Refresh the lock this often while a unit runs (seconds).
  double refresh_seconds = 30;
  /// Each event of the batch, one sentence (the program prints them with "batch: ").
  std::function<void(const std::string&)> log;
};

/// The arguments after the program that capture sample `s` (with `--resume` when `resume`).
inline std::vector<std::string> batch_capture_arguments(const batch_sample& s, const batch_record& record, bool resume) {
  std::vector<std::string> args{"capture", record.json["capture"].get<std::string>(), "-o", s.out.string()};
  if (resume) args.push_back("--resume");
  args.insert(args.end(), s.options.begin(), s.options.end());
  return args;
}

namespace batch_detail {

/// Writes the unit's batch.json atomically: `state`, the record, this host and pid, and `extra`'s fields.
inline void write_marker(const batch_unit_files& f, const std::string& name, const batch_record& record, const std::string& state,
                         const nlohmann::json& extra = nlohmann::json::object()) {
  nlohmann::json j = extra;
  j["sample"] = name;
  j["state"] = state;
  j["record"] = record.json;
  j["host"] = host_name();
  j["pid"] = ::getpid();
  write_file_atomically(f.marker(), j.dump(2) + "\n");
}

/// Appends one line to the unit's log.
inline void append(const std::filesystem::path& log, const std::string& line) {
  std::ofstream out(log, std::ios::app | std::ios::binary);
  out << line << "\n";
}


/// The second half of run_batch_unit, under the unit's lock: writes the marker (state "running"),
/// runs the capture (resuming when `resume`) with its output appended to the unit's log while
/// refreshing the lock, and writes the marker's final state ("done", "stopped" or "failed") into
/// `out` and the unit's folder.
inline void capture_unit(const batch_sample& s, const batch_unit_files& f, const batch_record& record, const batch_options& o, batch_lock& lock,
                         bool resume, batch_outcome& out) {
  namespace fs = std::filesystem;
  using clock = std::chrono::steady_clock;
  std::vector<std::string> argv{o.program.string()};
  argv.insert(argv.end(), o.program_arguments.begin(), o.program_arguments.end());
  const auto args = batch_capture_arguments(s, record, resume);
  argv.insert(argv.end(), args.begin(), args.end());
  const std::string command = join_names(argv, " ");
  write_marker(f, s.name, record, "running");
  append(f.log(), "== batch: sample " + s.name + " on host " + host_name() + " pid " + std::to_string(::getpid()) +
                      (resume ? ", resuming" : "") + ": " + command);
  const auto start = clock::now();
  auto last_refresh = start;
  const int status = run_logged_process(argv, f.log(), [&] {
    if (std::chrono::duration<double>(clock::now() - last_refresh).count() >= o.refresh_seconds) {
      lock.refresh();
      last_refresh = clock::now();
    }
  });
  out.seconds = std::chrono::duration<double>(clock::now() - start).count();
  out.exit_status = status;
  const std::string last = last_line(f.log());  // what the capture said last, before the trailer
  char took[64];
  std::snprintf(took, sizeof took, "%.1f s", out.seconds);
  append(f.log(), "== batch: sample " + s.name + ": exit status " + std::to_string(status) + " after " + took);
  std::error_code ec;
  if (status == 0 && fs::exists(f.report(), ec)) {
    write_marker(f, s.name, record, "done", {{"seconds", out.seconds}, {"resumed", resume}});
    out.result = batch_result::captured;
    return;
  }
  const int sig = batch_stop_requested();
  out.result = sig != 0 ? batch_result::stopped : batch_result::failed;
  write_marker(f, s.name, record, sig != 0 ? "stopped" : "failed", {{"seconds", out.seconds}, {"exit_status", status}});
  out.message = (sig != 0 ? "stopped by signal " + std::to_string(sig) : status == 0 ? std::string("the capture wrote no report.json")
                                                                                      : "the capture failed (exit status " + std::to_string(status) + ")") +
                (fs::exists(f.checkpoint(), ec) ? "; its check-point is kept and the next run resumes it" : "") + "; see " + f.log().string() +
                (last.empty() || sig != 0 ? "" : ": " + last);
}

}  // namespace batch_detail

/// Runs one unit, sample `i` of `m` with its record (check_batch_sample): skips it when done, leaves
/// it when another process holds its lock, else takes the lock, writes the marker (state
/// "running"), runs the capture (resuming an interrupted one) with its output appended to the
/// unit's log, and on success writes the marker with state "done" last, atomically.
inline batch_outcome run_batch_unit(const batch_manifest& m, std::size_t i, const batch_record& record, const batch_options& o) {
  namespace fs = std::filesystem;
  const batch_sample& s = m.samples[i];
  const batch_unit_files f{s.out};
  batch_outcome out;
  out.name = s.name;
  out.log = f.log();
  auto say = [&](const std::string& text) {
    if (o.log) o.log(s.name + ": " + text);
  };
  std::string reason;
  out.state = inspect_batch_outputs(f, record, &reason);  // done needs no lock: the skip check only reads
  if (out.state == batch_state::done) {
    out.result = batch_result::skipped;
    out.message = "done already (" + f.report().string() + ")";
    return out;
  }
  {
    std::error_code ec;
    fs::create_directories(s.out, ec);
    if (!fs::is_directory(s.out)) {
      out.result = batch_result::failed;
      out.message = s.out.string() + ": cannot create the output folder" + (ec ? ": " + ec.message() : std::string());
      return out;
    }
  }
  std::optional<batch_lock_holder> taken_over;
  batch_lock lock(f.lock(), o.stale_seconds, &taken_over);
  if (!lock.held()) {
    out.result = batch_result::busy;
    out.message = "running elsewhere (" + lock.holder().describe() + ", " + f.lock().string() + ")";
    return out;
  }
  if (taken_over)
    say("took over the stale lock of " + taken_over->describe() + (taken_over->host == batch_detail::host_name() ? " (that process is gone)"
                                                                                                          : " (not refreshed for " + std::to_string(long(taken_over->age_seconds)) + " s)"));
  out.state = inspect_batch_outputs(f, record, &reason);  // again under the lock: another process may have finished it
  if (out.state == batch_state::done) {
    out.result = batch_result::skipped;
    out.message = "done already (" + f.report().string() + ")";
    return out;
  }
  const bool resume = out.state == batch_state::interrupted;
  if (out.state == batch_state::changed) say("captured again: " + reason + " changed since its outputs were made");
  say(resume ? "resuming from " + f.checkpoint().string() : "capturing");
  batch_detail::capture_unit(s, f, record, o, lock, resume, out);
  return out;
}

/// The records of the samples `selected` (check_batch_sample on each): bad input throws
/// batch_input_error before any unit runs.
inline std::vector<batch_record> check_batch_samples(const batch_manifest& m, const std::vector<std::size_t>& selected) {
  std::vector<batch_record> records;
  for (std::size_t i : selected) records.push_back(check_batch_sample(m, i));
  return records;
}

/// Runs the units `selected` of `m` one after another (run_batch_unit) with their `records`
/// (check_batch_samples). Calls `done` after each unit with its outcome, its position and the
/// count. Stops after the current unit when batch_stop_requested.
inline batch_summary run_batch(const batch_manifest& m, const std::vector<std::size_t>& selected, const std::vector<batch_record>& records,
                               const batch_options& o, const std::function<void(const batch_outcome&, std::size_t, std::size_t)>& done = {}) {
  const auto start = std::chrono::steady_clock::now();
  batch_summary summary;
  for (std::size_t k = 0; k < selected.size(); ++k) {
    if (batch_stop_requested()) break;
    summary.outcomes.push_back(run_batch_unit(m, selected[k], records[k], o));
    if (done) done(summary.outcomes.back(), k, selected.size());
    if (summary.outcomes.back().result == batch_result::stopped) break;
  }
  summary.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  return summary;
}

/// run_batch after checking every selected sample's input (check_batch_samples).
inline batch_summary run_batch(const batch_manifest& m, const std::vector<std::size_t>& selected, const batch_options& o,
                               const std::function<void(const batch_outcome&, std::size_t, std::size_t)>& done = {}) {
  return run_batch(m, selected, check_batch_samples(m, selected), o, done);
}

}  // namespace anisocap
