#pragma once
// Writing files so that a reader never sees half of one.
//
// Content goes to a temporary file next to the target ("<target>.tmp-<pid>-<n>"), is flushed and
// closed, and is renamed over the target only on Commit(). A writer that fails or is destroyed
// without Commit() removes its temporary file, so the target is either the old file or the new one.

#include <filesystem>
#include <fstream>
#include <string>
#include <string_view>

#include "core/status.h"

namespace formloop {

class AtomicFile {
 public:
  // binary: open the stream in binary mode (PLY, PCD).
  explicit AtomicFile(std::filesystem::path target, bool binary = false);
  ~AtomicFile();
  AtomicFile(const AtomicFile&) = delete;
  AtomicFile& operator=(const AtomicFile&) = delete;

  // Non-ok when the temporary file could not be created (directory missing, no permission).
  const Status& open_status() const { return open_status_; }
  std::ostream& stream() { return stream_; }
  const std::filesystem::path& temp_path() const { return temp_; }
  const std::filesystem::path& target() const { return target_; }

  // Flushes, closes and renames onto the target. Non-ok (and nothing renamed) on any write error.
  Status Commit();

 private:
  std::filesystem::path target_;
  std::filesystem::path temp_;
  std::ofstream stream_;
  Status open_status_;
  bool committed_ = false;
};

// Writes text (or bytes) to path atomically.
Status WriteFileAtomic(const std::filesystem::path& path, std::string_view content, bool binary = false);

// Reads a whole file; NotFound / IoError name the path.
Result<std::string> ReadFile(const std::filesystem::path& path);

// Creates a folder and its parents (nothing to do when it exists); IoError names the folder.
Status MakeDirectories(const std::filesystem::path& dir);

}  // namespace formloop
