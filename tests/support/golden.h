#pragma once
// Test support: where the post golden files live and how they are read (tests/nc-gen/*dialects_test.cc).

#include <filesystem>
#include <string>

#include "core/atomic_file.h"
#include "nc-gen/post.h"

namespace formloop::testing {

// tests/nc-gen/golden/<stem>_<dialect><the dialect's extension>.
inline std::filesystem::path GoldenPath(const std::string& stem, const std::string& dialect) {
  return std::filesystem::path(FORMLOOP_SOURCE_DIR) / "tests" / "nc-gen" / "golden" /
         (stem + "_" + dialect + std::string(nc::FindPost(dialect)->FileExtension()));
}

// The golden file's text, or "" when it is missing (the comparison then fails and says so).
inline std::string ReadGoldenText(const std::filesystem::path& path) {
  auto text = ReadFile(path);
  return text.ok() ? *text : std::string();
}

}  // namespace formloop::testing
