// Standard-block correction (metrology/standard_block.h; spec/tuning-and-link.md §3 and §9.2).

#include <cmath>
#include <string>

#include <gtest/gtest.h>

#include "core/atomic_file.h"
#include "metrology/dimensions.h"
#include "metrology/standard_block.h"
#include "tests/support/test_dir.h"

namespace formloop::metrology {
namespace {

CalibrationPoint Cal(int axis, double reference, double error) {
  return {axis, reference, reference + error, std::nullopt};
}

// The two-point diameter along X between two corrected points.
double Diameter(const BlockCorrector& c, double a1, double a2) {
  const std::array<bool, 3> x_only = {true, false, false};
  const Eigen::Vector3d p1 = c.Correct({a1, 0, 0}, x_only, nullptr), p2 = c.Correct({a2, 0, 0}, x_only, nullptr);
  DimensionDefinition d;
  d.type = DimensionType::kLength;
  d.axis = 0;
  ProbedPoint q1, q2;
  q1.position = p1;
  q2.position = p2;
  return *EvaluateDimensionValue(d, {{"WALL_A", {q1}}, {"WALL_B", {q2}}});
}

// §9.2 NEAREST: A1 −118.000 → −118.009, A2 −142.000 → −142.011, diameter 24.000 → 24.002.
TEST(StandardBlock, SeedExampleNearest) {
  StandardBlock block;
  block.points = {Cal(0, -117.0, 0.009), Cal(0, -142.0, 0.011)};
  auto c = BlockCorrector::Build(block, BlockMode::kNearest);
  ASSERT_TRUE(c.ok());
  const std::array<bool, 3> x_only = {true, false, false};
  EXPECT_NEAR(c->Correct({-118.0, 0, 0}, x_only, nullptr).x(), -118.009, 1e-12);
  EXPECT_NEAR(c->Correct({-142.0, 0, 0}, x_only, nullptr).x(), -142.011, 1e-12);
  EXPECT_NEAR(Diameter(*c, -118.0, -142.0), 24.002, 1e-9);
  // Y is not calibrated: untouched.
  EXPECT_EQ(c->Correct({-118.0, 5.0, 0}, {true, true, true}, nullptr).y(), 5.0);
}

// §9.2 LINEAR with the invented neighbours −117 (+0.009), −122 (+0.010), −142 (+0.011): 24.0018.
TEST(StandardBlock, SeedExampleLinear) {
  StandardBlock block;
  block.points = {Cal(0, -117.0, 0.009), Cal(0, -122.0, 0.010), Cal(0, -142.0, 0.011)};
  auto c = BlockCorrector::Build(block, BlockMode::kLinear);
  ASSERT_TRUE(c.ok());
  EXPECT_NEAR(c->ErrorAt(0, -118.0).error_mm, 0.0092, 1e-12);
  EXPECT_NEAR(Diameter(*c, -118.0, -142.0), 24.0018, 1e-9);
  // Outside the calibrated range: the end value; flagged beyond half the end interval.
  const AxisCorrection near_end = c->ErrorAt(0, -115.0);  // 2 mm beyond −117, end interval 5 mm
  EXPECT_NEAR(near_end.error_mm, 0.009, 1e-12);
  EXPECT_FALSE(near_end.extrapolated);
  EXPECT_TRUE(c->ErrorAt(0, -110.0).extrapolated);
  EXPECT_TRUE(c->ErrorAt(0, -160.0).extrapolated);  // 18 mm beyond −142, more than half the 20 mm end interval
}

TEST(StandardBlock, NearestTieTakesTheMeanAndScaleReportsTheMismatch) {
  StandardBlock block;
  block.points = {Cal(0, 0.0, 0.002), Cal(0, 10.0, 0.006)};
  auto nearest = BlockCorrector::Build(block, BlockMode::kNearest);
  ASSERT_TRUE(nearest.ok());
  EXPECT_NEAR(nearest->ErrorAt(0, 5.0).error_mm, 0.004, 1e-15);
  // SCALE: e = α + β p with errors growing 4 µm over 10 mm → β = 400 µm/m, α = 2 µm.
  block.points.push_back(Cal(0, 20.0, 0.010));
  auto scale = BlockCorrector::Build(block, BlockMode::kScale);
  ASSERT_TRUE(scale.ok());
  EXPECT_NEAR(scale->ScaleMismatchUmPerM(0), 400.0, 1e-9);
  EXPECT_NEAR(scale->ErrorAt(0, 15.0).error_mm, 0.008, 1e-12);
  EXPECT_EQ(scale->ToJson()["axes"]["X"]["scale_mismatch_um_per_m"].get<double>(), scale->ScaleMismatchUmPerM(0));
  // SCALE needs two references per axis.
  StandardBlock one;
  one.points = {Cal(1, 0.0, 0.002)};
  auto bad = BlockCorrector::Build(one, BlockMode::kScale);
  ASSERT_FALSE(bad.ok());
  EXPECT_NE(bad.status().message().find("axis Y has 1"), std::string::npos);
}

TEST(StandardBlock, StaleBlockIsFlagged) {
  StandardBlock block;
  block.points = {Cal(0, -117.0, 0.009)};
  block.points[0].time_s = 1000;
  EXPECT_FALSE(CheckBlockAge(block, {}, 1800).checked);
  const BlockAge fresh = CheckBlockAge(block, {1100, 1500}, 1800);
  EXPECT_TRUE(fresh.checked);
  EXPECT_FALSE(fresh.stale);
  const BlockAge stale = CheckBlockAge(block, {1100, 4000}, 1800);
  EXPECT_TRUE(stale.stale);
  EXPECT_DOUBLE_EQ(stale.max_gap_s, 3000);
}

TEST(StandardBlock, CsvIsReadAndBadRowsNameLineAndField) {
  const auto dir = testing::FreshTestDir("block");
  ASSERT_TRUE(WriteFileAtomic(dir / "ok.csv",
                              "\xEF\xBB\xBF# block (a byte-order mark first, as Excel "
                              "writes)\naxis,reference_mm,measured_mm,t\nX,-117.0,-116.991,60\nY,5,5.001,61\n")
                  .ok());
  auto block = ReadStandardBlockCsv(dir / "ok.csv");
  ASSERT_TRUE(block.ok()) << block.status().ToString();
  ASSERT_EQ(block->points.size(), 2u);
  EXPECT_EQ(block->points[1].axis, 1);
  EXPECT_NEAR(block->points[0].measured_mm - block->points[0].reference_mm, 0.009, 1e-12);
  EXPECT_EQ(*block->points[1].time_s, 61);
  ASSERT_TRUE(WriteFileAtomic(dir / "bad.csv", "axis,reference_mm,measured_mm\nX,-117.0,abc\n").ok());
  auto bad = ReadStandardBlockCsv(dir / "bad.csv");
  ASSERT_FALSE(bad.ok());
  EXPECT_NE(bad.status().message().find("bad.csv:2: field 'measured_mm'"), std::string::npos) << bad.status().message();
  ASSERT_TRUE(WriteFileAtomic(dir / "axis.csv", "axis,reference_mm,measured_mm\nW,1,1\n").ok());
  EXPECT_NE(ReadStandardBlockCsv(dir / "axis.csv").status().message().find("field 'axis'"), std::string::npos);
  ASSERT_TRUE(WriteFileAtomic(dir / "dup.csv", "axis,reference_mm,measured_mm\nX,1,1\nX,1,1.001\n").ok());
  EXPECT_NE(ReadStandardBlockCsv(dir / "dup.csv").status().message().find("already given on line 2"),
            std::string::npos);
  std::filesystem::remove_all(dir);
}

}  // namespace
}  // namespace formloop::metrology
