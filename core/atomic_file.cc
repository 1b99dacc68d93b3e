#include "core/atomic_file.h"

#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <cerrno>
#include <cstring>

namespace formloop {
namespace {

std::filesystem::path MakeTempPath(const std::filesystem::path& target) {
  static std::atomic<unsigned> counter{0};
  std::filesystem::path temp = target;
  temp += ".tmp-" + std::to_string(::getpid()) + "-" + std::to_string(counter++);
  return temp;
}

}  // namespace

AtomicFile::AtomicFile(std::filesystem::path target, bool binary)
    : target_(std::move(target)), temp_(MakeTempPath(target_)) {
  std::ios::openmode mode = std::ios::out | std::ios::trunc;
  if (binary) mode |= std::ios::binary;
  stream_.open(temp_, mode);
  if (!stream_) {
    open_status_ = Status::IoError("cannot create '" + temp_.string() + "' to write '" + target_.string() +
                                   "': " + std::strerror(errno) + ". Check that the folder exists and is writable");
  }
  stream_.imbue(std::locale::classic());
}

AtomicFile::~AtomicFile() {
  if (!committed_) {
    if (stream_.is_open()) stream_.close();
    std::error_code ignored;
    std::filesystem::remove(temp_, ignored);
  }
}

Status AtomicFile::Commit() {
  if (!open_status_.ok()) return open_status_;
  if (committed_) return Status::Internal("AtomicFile::Commit called twice for '" + target_.string() + "'");
  stream_.flush();
  const bool write_ok = static_cast<bool>(stream_);
  stream_.close();
  if (!write_ok || stream_.fail()) {
    return Status::IoError("writing '" + target_.string() + "' failed (disk full?); the old file is unchanged");
  }
  std::error_code ec;
  std::filesystem::rename(temp_, target_, ec);
  if (ec) {
    return Status::IoError("cannot rename '" + temp_.string() + "' to '" + target_.string() + "': " + ec.message());
  }
  committed_ = true;
  return Status::Ok();
}

Status WriteFileAtomic(const std::filesystem::path& path, std::string_view content, bool binary) {
  AtomicFile file(path, binary);
  FL_RETURN_IF_ERROR(file.open_status());
  file.stream().write(content.data(), static_cast<std::streamsize>(content.size()));
  return file.Commit();
}

Result<std::string> ReadFile(const std::filesystem::path& path) {
  std::error_code ec;
  if (!std::filesystem::exists(path, ec)) {
    return Status::NotFound("file '" + path.string() + "' does not exist. Check the path");
  }
  if (std::filesystem::is_directory(path, ec)) {
    return Status::BadInput("'" + path.string() + "' is a folder, expected a file");
  }
  std::ifstream in(path, std::ios::binary | std::ios::ate);
  if (!in) return Status::IoError("cannot open '" + path.string() + "': " + std::strerror(errno));
  const std::streamoff size = in.tellg();
  in.seekg(0);
  std::string content(static_cast<std::size_t>(std::max<std::streamoff>(size, 0)), '\0');
  in.read(content.data(), static_cast<std::streamsize>(content.size()));
  if (in.bad() || in.gcount() != static_cast<std::streamsize>(content.size())) {
    return Status::IoError("reading '" + path.string() + "' failed");
  }
  return content;
}

Status MakeDirectories(const std::filesystem::path& dir) {
  std::error_code ec;
  std::filesystem::create_directories(dir, ec);
  if (ec) return Status::IoError("cannot create folder '" + dir.string() + "': " + ec.message());
  return Status::Ok();
}

}  // namespace formloop
