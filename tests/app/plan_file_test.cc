// Probing plans read back (app/run_folder.h ReadPlanFile): what formloop writes (ProbingPlan::ToJson,
// toolpath/probing_plan.json) must read as the same plan, including the "trim" section a plan on a trimmed
// face carries; a damaged trim section is refused naming its field.

#include <cmath>
#include <filesystem>
#include <string>

#include <gtest/gtest.h>

#include "app/run_folder.h"
#include "core/json_io.h"
#include "metrology/probe.h"
#include "tests/support/test_dir.h"

namespace formloop::app {
namespace {

namespace fs = std::filesystem;

class PlanFileTest : public ::testing::Test {
 protected:
  void SetUp() override { dir_ = formloop::testing::FreshTestDir("formloop-plan"); }
  void TearDown() override { fs::remove_all(dir_); }
  fs::path dir_;
};

// Three points on a trimmed face: ids with gaps (positions left out), normals of unit length.
metrology::ProbingPlan TrimmedPlan() {
  metrology::ProbingPlan plan;
  plan.trimmed = true;
  plan.edge_margin_mm = 2.5;
  plan.left_out = 13;
  const double s = 1 / std::sqrt(3.0);
  plan.points = {{.id = 2, .u = 0.125, .v = -3.5, .point = {1.5, -2.25, 7.0625}, .normal = {0.0, 0.0, 1.0}},
                 {.id = 7, .u = 10.1, .v = 0.3, .point = {10.1, 0.3, 4.0 / 3.0}, .normal = {s, -s, s}},
                 {.id = 19, .u = 33.0, .v = 12.0, .point = {33.0, 12.0, -0.1}, .normal = {0.0, 1.0, 0.0}}};
  return plan;
}

TEST_F(PlanFileTest, ATrimmedPlanFormloopWroteReadsBackAsTheSamePlan) {
  const metrology::ProbingPlan plan = TrimmedPlan();
  ASSERT_TRUE(WriteJsonFile(dir_ / "probing_plan.json", plan.ToJson()).ok());
  ASSERT_TRUE(ReadJsonFile(dir_ / "probing_plan.json").value().contains("trim"));
  const auto read = ReadPlanFile(dir_ / "probing_plan.json");
  ASSERT_TRUE(read.ok()) << read.status().ToString();
  EXPECT_TRUE(read->approaches.empty());
  EXPECT_TRUE(read->plan.trimmed);
  EXPECT_EQ(read->plan.edge_margin_mm, 2.5);
  EXPECT_EQ(read->plan.left_out, 13);
  ASSERT_EQ(read->plan.points.size(), plan.points.size());
  for (std::size_t k = 0; k < plan.points.size(); ++k) {
    EXPECT_EQ(read->plan.points[k].id, plan.points[k].id);
    EXPECT_EQ(read->plan.points[k].u, plan.points[k].u);
    EXPECT_EQ(read->plan.points[k].v, plan.points[k].v);
    EXPECT_EQ(read->plan.points[k].point, plan.points[k].point);
    // The reader rescales normals to unit length: within the rounding of that division.
    EXPECT_LT((read->plan.points[k].normal - plan.points[k].normal).norm(), 1e-15);
  }
  // Written again, the trim section is the same JSON.
  EXPECT_EQ(read->plan.ToJson()["trim"].dump(), plan.ToJson()["trim"].dump());

  metrology::ProbingPlan untrimmed = plan;
  untrimmed.trimmed = false;
  ASSERT_TRUE(WriteJsonFile(dir_ / "plain.json", untrimmed.ToJson()).ok());
  const auto plain = ReadPlanFile(dir_ / "plain.json");
  ASSERT_TRUE(plain.ok()) << plain.status().ToString();
  EXPECT_FALSE(plain->plan.trimmed);
}

TEST_F(PlanFileTest, ADamagedTrimSectionIsRefusedNamingItsField) {
  const auto refused = [&](const std::string& pointer, const Json& value, const std::string& field) {
    Json json = TrimmedPlan().ToJson();
    json[Json::json_pointer(pointer)] = value;
    const fs::path path = dir_ / "plan.json";
    EXPECT_TRUE(WriteJsonFile(path, json).ok());
    const auto read = ReadPlanFile(path);
    ASSERT_FALSE(read.ok()) << pointer;
    EXPECT_EQ(read.status().code(), StatusCode::kBadInput);
    EXPECT_NE(read.status().message().find(field), std::string::npos) << read.status().message();
    EXPECT_NE(read.status().message().find("plan.json"), std::string::npos) << read.status().message();
  };
  refused("/trim/edge_margin_mm", -1.0, "edge_margin_mm");
  refused("/trim/edge_margin_mm", "2", "edge_margin_mm");
  refused("/trim/left_out", -4, "left_out");
  refused("/trim/margin", 2.0, "margin");
  refused("/trim", "yes", "trim");
}

}  // namespace
}  // namespace formloop::app
