#pragma once
// A fresh, empty folder per test under the system's temp directory, named by a prefix, the process
// and the test (so parallel ctest processes never share one). Tests remove it in TearDown.

#include <filesystem>
#include <string>

#include <unistd.h>

#include <gtest/gtest.h>

namespace formloop::testing {

inline std::filesystem::path FreshTestDir(const std::string& prefix) {
  const std::filesystem::path dir =
      std::filesystem::temp_directory_path() / (prefix + "-" + std::to_string(::getpid()) + "-" +
                                                ::testing::UnitTest::GetInstance()->current_test_info()->name());
  std::filesystem::remove_all(dir);
  std::filesystem::create_directories(dir);
  return dir;
}

}  // namespace formloop::testing
