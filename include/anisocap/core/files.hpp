#pragma once
/// @file
/// Files as the library reads and writes them: `io_error`, whose message starts with the file's
/// path; whole files read into memory; and `file_transaction`, which writes each file under a
/// temporary name beside its target and renames it into place only once it is complete, so that a
/// failure never leaves a half-written file under the real name.
#include <atomic>
#include <cerrno>
#include <cstdint>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <memory>
#include <mutex>
#include <random>
#include <stdexcept>
#include <string>
#include <string_view>
#include <utility>
#include <vector>

namespace anisocap {

/// A file could not be read, written or validated. `what()` starts with the file's path.
class io_error : public std::runtime_error {
 public:
  /// Message `path: problem`.
  io_error(const std::filesystem::path& path, const std::string& problem)
      : std::runtime_error(path.string() + ": " + problem), path_(path), problem_(problem) {}
  /// The file the problem is about.
  const std::filesystem::path& path() const noexcept { return path_; }
  /// The message without the path.
  const std::string& problem() const noexcept { return problem_; }

 private:
  std::filesystem::path path_;
  std::string problem_;
};

// ---- whole files and atomic writes -------------------------------------------------------------

/// Reads a whole file into memory; io_error if it is missing, not a regular file or unreadable.
inline std::vector<unsigned char> read_file_bytes(const std::filesystem::path& path) {
  std::error_code ec;
  const auto status = std::filesystem::status(path, ec);
  if (!std::filesystem::exists(status)) throw io_error(path, "file not found");
  if (!std::filesystem::is_regular_file(status)) throw io_error(path, "not a regular file");
  std::unique_ptr<std::FILE, int (*)(std::FILE*)> f(std::fopen(path.c_str(), "rb"), &std::fclose);
  if (!f) throw io_error(path, std::string("cannot open for reading: ") + std::strerror(errno));
  std::vector<unsigned char> bytes;
  unsigned char buffer[1 << 16];
  for (;;) {
    const std::size_t n = std::fread(buffer, 1, sizeof buffer, f.get());
    bytes.insert(bytes.end(), buffer, buffer + n);
    if (n < sizeof buffer) break;
  }
  if (std::ferror(f.get())) throw io_error(path, "read error");
  return bytes;
}

/// A set of files written together: `stage` writes each one completely under a temporary name in
/// the target's folder; `commit` renames them all onto their targets; files staged but not
/// committed are removed by the destructor. Nothing appears under a target name before `commit`,
/// so a failure while producing any file (bad data, full disk) leaves every target untouched.
/// Each rename is atomic (same folder), so a reader never sees a partial file; renames into one
/// folder practically never fail, but if one did, the files renamed before it would stay replaced.
class file_transaction {
 public:
  file_transaction() = default;
  file_transaction(const file_transaction&) = delete;
  file_transaction& operator=(const file_transaction&) = delete;
  /// Removes temporaries that were staged but not committed.
  ~file_transaction() { discard(); }

  /// Writes `bytes` to a temporary file that `commit` will rename to `target`. The target's folder
  /// must exist. Throws io_error (and removes the partial temporary) on failure. Threads may stage
  /// into one transaction at once (for_each_index_in_parallel encodes and stages files so).
  void stage(const std::filesystem::path& target, const void* bytes, std::size_t size) {
    const std::filesystem::path temporary = temporary_name(target);
    std::FILE* f = std::fopen(temporary.c_str(), "wb");
    if (!f) throw io_error(target, std::string("cannot create file: ") + std::strerror(errno));
    const bool written = size == 0 || std::fwrite(bytes, 1, size, f) == size;
    const bool flushed = std::fflush(f) == 0;
    const bool closed = std::fclose(f) == 0;
    if (!(written && flushed && closed)) {
      std::error_code ec;
      std::filesystem::remove(temporary, ec);
      throw io_error(target, "write failed (disk full?)");
    }
    const std::lock_guard lock(mutex_);
    pending_.emplace_back(temporary, target);
  }
  /// `stage` for a string's bytes.
  void stage(const std::filesystem::path& target, std::string_view text) { stage(target, text.data(), text.size()); }

  /// Renames every staged file onto its target (replacing existing files).
  void commit() {
    for (std::size_t i = 0; i < pending_.size(); ++i) {
      std::error_code ec;
      std::filesystem::rename(pending_[i].first, pending_[i].second, ec);
      if (ec) {
        pending_.erase(pending_.begin(), pending_.begin() + std::ptrdiff_t(i));
        throw io_error(pending_.front().second, "cannot rename the temporary file into place: " + ec.message());
      }
    }
    pending_.clear();
  }

  /// Removes every staged temporary without touching the targets.
  void discard() noexcept {
    for (auto& [temporary, target] : pending_) {
      std::error_code ec;
      std::filesystem::remove(temporary, ec);
    }
    pending_.clear();
  }

  /// Number of files staged and not yet committed.
  std::size_t staged() const noexcept { return pending_.size(); }

  /// Marker inside every temporary name (".<name>.anisocap-tmp-<random>"), e.g. for tests and cleanup.
  static constexpr std::string_view temporary_marker = ".anisocap-tmp-";

 private:
  /// A hidden, unique name in the target's folder (same file system, so rename is atomic).
  static std::filesystem::path temporary_name(const std::filesystem::path& target) {
    static std::atomic<std::uint64_t> counter{std::random_device{}()};
    const std::uint64_t id = counter.fetch_add(0x9E3779B97F4A7C15ull);
    char hex[17];
    std::snprintf(hex, sizeof hex, "%016llx", static_cast<unsigned long long>(id));
    std::string name(1, '.');  // appended piecewise: GCC 12 warns falsely (-Wrestrict) on "." + string
    name.append(target.filename().string()).append(temporary_marker).append(hex);
    return target.parent_path() / name;
  }

  std::vector<std::pair<std::filesystem::path, std::filesystem::path>> pending_;
  std::mutex mutex_;  // guards pending_ while threads stage
};

/// Writes `bytes` to `target` atomically (temporary file, then rename).
inline void write_file_atomically(const std::filesystem::path& target, std::string_view bytes) {
  file_transaction t;
  t.stage(target, bytes);
  t.commit();
}

}  // namespace anisocap
