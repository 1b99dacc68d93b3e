#pragma once
// Test support: one starter case library per test process (building it takes a few seconds), made with
// `kb init --starter`'s own function; tests copy it rather than change it.

#include <filesystem>
#include <string>

#include <unistd.h>

#include <gtest/gtest.h>

#include "app/kb_jobs.h"

namespace formloop::testing {

inline const std::filesystem::path& StarterLibrary() {
  static const std::filesystem::path path = [] {
    const std::filesystem::path p =
        std::filesystem::temp_directory_path() / ("formloop-starter-" + std::to_string(::getpid()) + ".sqlite");
    std::filesystem::remove(p);
    const auto made = app::CreateStarterLibrary(p.string(), std::filesystem::path(FORMLOOP_SOURCE_DIR) / "data");
    EXPECT_TRUE(made.ok()) << made.status().ToString();
    return p;
  }();
  return path;
}

}  // namespace formloop::testing
