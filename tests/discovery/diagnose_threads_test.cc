// Diagnose on one thread and on two (issue 26: --threads; core/parallel.h): the candidate fits, the
// exchange steps, the τ grids and the profile intervals run in fixed parallel chunks, each into its own
// slot, so the diagnosis must be the same bytes for any thread count.

#include <string>
#include <vector>

#include <gtest/gtest.h>

#include "core/parallel.h"
#include "tests/support/multi_effect.h"

namespace formloop::testing {
namespace {

// Three parts of one machine, as bench/discovery_bench.cc pools them (thermal drift: the nonlinear
// term whose τ grid, golden section and interval bisections run in parallel), 3 × 196 points.
std::vector<Scenario> PooledParts() {
  sim::Model machine;
  EXPECT_TRUE(machine.Set("thermal_drift_z", {12.0, 900.0}).ok());
  EXPECT_TRUE(machine.Set("tool_wear", {2.0}).ok());
  EXPECT_TRUE(machine.Set("tool_radius", {5.0}).ok());
  EXPECT_TRUE(machine.Set("noise", {0.8, 0.6}).ok());
  const std::vector<std::vector<double>> setups = {{10, -6, 0}, {-4, 8, 5}, {3, 3, -7}};
  const std::vector<PartLayout> layouts = {{"franke", 0, 14}, {"saddle", 45, 14}, {"egg_box", 90, 14}};
  std::vector<Scenario> parts;
  for (std::size_t p = 0; p < layouts.size(); ++p) {
    sim::Model truth = machine;
    EXPECT_TRUE(truth.Set("setup_offset", setups[p]).ok());
    parts.push_back(ProbePart(layouts[p], truth, 100 + p));
  }
  return parts;
}

TEST(DiagnoseThreadsTest, PooledDiagnosisIsTheSameBytesOnOneAndTwoThreads) {
  const std::vector<Scenario> parts = PooledParts();
  std::vector<sim::ProbeDataInput> inputs;
  for (const Scenario& part : parts) inputs.push_back(InputOf(part));
  sim::DiagnoseOptions options;
  options.plausible = StarterPlausibleRanges();
  std::vector<std::string> pooled, single;
  for (int threads : {1, 2}) {
    SetThreadCount(threads);
    const auto d = sim::DiagnosePooled(inputs, parts[0].baseline, options);
    ASSERT_TRUE(d.ok()) << d.status().message();
    pooled.push_back(d->ToJson().dump());
    const auto one = sim::Diagnose(inputs[0], parts[0].baseline, options);
    ASSERT_TRUE(one.ok()) << one.status().message();
    single.push_back(one->ToJson().dump());
  }
  SetThreadCount(0);
  // Not a vacuous comparison: the pooled diagnosis names the shared thermal drift.
  EXPECT_NE(pooled[0].find("thermal_drift_z"), std::string::npos) << pooled[0];
  for (std::size_t k = 1; k < pooled.size(); ++k) {
    EXPECT_EQ(pooled[k], pooled[0]) << "pooled, 1 and 2 threads";
    EXPECT_EQ(single[k], single[0]) << "one part, 1 and 2 threads";
  }
}

}  // namespace
}  // namespace formloop::testing
