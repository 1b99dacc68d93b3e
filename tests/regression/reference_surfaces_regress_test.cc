// Regression runs. (1) The demo part on every analytic reference surface (one ctest test per surface, so
// they spread over the cores): each must end within tolerance with a fit error far below it. (2) The
// reference parts of data/regress through `formloop regress` against their goldens: no regression, and
// the issue-8 figures — ≥ 90 % of parts within tolerance after at most one compensation loop, the
// simulation-correction route removing a predicted defect, a part planned with a learned model.

#include <filesystem>

#include <unistd.h>

#include <gtest/gtest.h>

#include "app/part.h"
#include "app/pipeline.h"
#include "core/json_io.h"
#include "core/log.h"
#include "reconstruction/analytic_surface.h"
#include "tests/support/run_binary.h"

namespace formloop {
namespace {

namespace fs = std::filesystem;
const fs::path kData = fs::path(FORMLOOP_SOURCE_DIR) / "data";

class ReferenceSurfaceTest : public ::testing::TestWithParam<std::string> {};

TEST_P(ReferenceSurfaceTest, EndsWithinToleranceAfterCompensation) {
  log::SetLevel(log::Level::kWarn);
  Json json = ReadJsonFile(kData / "parts" / "demo-saddle.json").value();
  json["name"] = "demo-" + GetParam();
  json["surface"] = {{"reference", GetParam()}};
  const auto part = app::ParsePart(json, "demo-saddle.json (surface " + GetParam() + ")");
  ASSERT_TRUE(part.ok()) << part.status().ToString();
  app::RunOptions options;
  options.out = fs::temp_directory_path() / ("formloop-surface-" + std::to_string(::getpid()) + "-" + GetParam());
  options.force = true;
  options.report = false;
  const auto summary = app::RunPart(*part, options);
  fs::remove_all(options.out);
  ASSERT_TRUE(summary.ok()) << summary.status().ToString();
  EXPECT_GT(summary->loops.front().form_error_um, summary->tolerance_um) << "the loop must have work to do";
  EXPECT_TRUE(summary->within_tolerance);
  EXPECT_LE(summary->loops.back().form_error_um, summary->tolerance_um);
  // The fit must stay an order of magnitude below the tolerance, so it is never taken for machining error.
  EXPECT_LE(summary->fit_check_max_um, 0.1 * summary->tolerance_um);
}

INSTANTIATE_TEST_SUITE_P(AllReferenceSurfaces, ReferenceSurfaceTest,
                         ::testing::ValuesIn(recon::ReferenceSurfaceNames()),
                         [](const auto& test_param) { return test_param.param; });

TEST(RegressGoldens, ReferencePartsMatchTheirGoldensAndReachTolerance) {
  const fs::path out = fs::temp_directory_path() / ("formloop-regress-" + std::to_string(::getpid()));
  std::string text, err;
  const int code = testing::RunFormloop("--quiet regress --out " + out.string(), &text, &err);
  fs::remove_all(out);
  EXPECT_EQ(code, 0) << err;
  const auto result = ParseJson(text, "regress stdout");
  ASSERT_TRUE(result.ok()) << text;
  const Json& r = *result;
  EXPECT_EQ(r["regressions"], 0) << err;
  // The truth line (issue 20): effects named that the machine profile does not have. Issue 20 asks for
  // none; today reg-dome-a still names axis_scale_z beside thermal drift for the profile's 8 µm tool
  // radius error (1 of 10 parts): this bound keeps it from growing and is to become 0. True effects
  // neither named nor in an alias group (9 of 30 today, mostly tool_deflection and tool_radius) are
  // printed in the table, not asserted.
  ASSERT_TRUE(r.contains("truth")) << text;
  EXPECT_LE(r["truth"]["named_not_in_profile"].get<int>(), 1) << err;
  const int parts = r["count"].get<int>();
  EXPECT_GE(parts, 8);
  EXPECT_GE(r["within_tolerance_after_at_most_one_compensation"].get<int>() * 10, parts * 9) << err;
  int simulate_fixes = 0, precompensated = 0;
  for (const auto& row : r["parts"]) {
    const Json& f = row["figures"];
    // The regression set's machines carry 20–60 µm of systematic error: every part has work to do.
    EXPECT_GT(f["form_error_um"][0].get<double>(), 10.0 * (f["precompensated"].get<bool>() ? 0.0 : 2.0)) << row["part"];
    if (f["precompensated"].get<bool>()) ++precompensated;
    if (f["route"] == "simulate" && f["sim_correction"].is_object() && !f["sim_correction"]["defects_before"].empty() &&
        f["sim_correction"]["defects_after"].empty()) {
      ++simulate_fixes;
    }
  }
  EXPECT_GE(simulate_fixes, 1) << "the mid-similarity route must remove a predicted defect on some part";
  EXPECT_GE(precompensated, 1) << "a part planned with a model learned from an earlier part";
}

}  // namespace
}  // namespace formloop
