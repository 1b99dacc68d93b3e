// Regression runs on reference surfaces (`formloop regress`), one ctest test per surface so they
// spread over the cores. Each must end within tolerance with a fit error far below it.

#include <array>
#include <cstdio>
#include <filesystem>

#include <unistd.h>
#include <sys/wait.h>

#include <gtest/gtest.h>

#include "core/json_io.h"
#include "reconstruction/analytic_surface.h"

namespace formloop {
namespace {

namespace fs = std::filesystem;

class RegressTest : public ::testing::TestWithParam<std::string> {};

TEST_P(RegressTest, EndsWithinToleranceAfterCompensation) {
  const fs::path out = fs::temp_directory_path() / ("formloop-regress-" + std::to_string(::getpid()) + "-" + GetParam());
  const std::string command = std::string(FORMLOOP_BINARY) + " --quiet regress --base " + FORMLOOP_SOURCE_DIR +
                              "/data/parts/demo-saddle.json --surfaces " + GetParam() + " --out " + out.string();
  FILE* pipe = ::popen(command.c_str(), "r");
  ASSERT_NE(pipe, nullptr);
  std::string text;
  std::array<char, 4096> buffer{};
  std::size_t n;
  while ((n = std::fread(buffer.data(), 1, buffer.size(), pipe)) > 0) text.append(buffer.data(), n);
  const int status = ::pclose(pipe);
  fs::remove_all(out);
  ASSERT_TRUE(WIFEXITED(status));
  EXPECT_EQ(WEXITSTATUS(status), 0) << text;
  const auto table = ParseJson(text, "regress stdout");
  ASSERT_TRUE(table.ok()) << text;
  const Json& row = (*table)["surfaces"][0];
  EXPECT_EQ(row["surface"], GetParam());
  EXPECT_TRUE(row["pass"].get<bool>()) << row.dump();
  EXPECT_GT(row["form_error_first_um"].get<double>(), row["tolerance_um"].get<double>()) << "the loop must have work to do";
  EXPECT_LE(row["form_error_final_um"].get<double>(), row["tolerance_um"].get<double>());
  EXPECT_LE(row["fit_check_max_um"].get<double>(), 0.5);
}

INSTANTIATE_TEST_SUITE_P(AllReferenceSurfaces, RegressTest, ::testing::ValuesIn(recon::ReferenceSurfaceNames()),
                         [](const auto& test_param) { return test_param.param; });

}  // namespace
}  // namespace formloop
