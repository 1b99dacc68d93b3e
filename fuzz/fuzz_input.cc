#include "fuzz/fuzz_input.h"

#include <unistd.h>

#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <system_error>

#include "core/log.h"

namespace formloop::fuzz {
namespace {

// Never destroyed (the exit handler that removes it runs after static destructors may have run).
const std::filesystem::path& Folder() {
  static const std::filesystem::path* folder = [] {
    log::SetLevel(log::Level::kOff);
    std::error_code ec;
    auto dir = std::filesystem::temp_directory_path(ec);
    if (ec) dir = "/tmp";
    dir /= "formloop-fuzz-" + std::to_string(::getpid());
    std::filesystem::create_directories(dir, ec);
    if (ec) {
      std::fprintf(stderr, "fuzz harness: cannot create %s: %s\n", dir.c_str(), ec.message().c_str());
      std::abort();
    }
    return new std::filesystem::path(dir);
  }();
  static const bool cleanup = [] {
    return std::atexit([] {
             std::error_code ignored;
             std::filesystem::remove_all(*folder, ignored);
           }) == 0;
  }();
  (void)cleanup;
  return *folder;
}

}  // namespace

std::filesystem::path WriteInput(const std::string& name, const std::uint8_t* data, std::size_t size) {
  const auto path = Folder() / name;
  std::ofstream out(path, std::ios::binary | std::ios::trunc);
  out.write(reinterpret_cast<const char*>(data), static_cast<std::streamsize>(size));
  out.close();
  if (!out) {
    std::fprintf(stderr, "fuzz harness: cannot write %s\n", path.c_str());
    std::abort();
  }
  return path;
}

}  // namespace formloop::fuzz
