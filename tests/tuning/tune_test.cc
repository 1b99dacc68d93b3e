// `formloop tune` as a library (tuning/tune.h): the measurement model's validation, the safety ladder
// (spec/tuning-and-link.md §5, §9.10), seed 004's averaging (§6, §9.11), the worked bracket in
// data/tuning/bracket, and the output folder's safety rules.

#include <filesystem>
#include <fstream>
#include <iterator>
#include <string>
#include <vector>

#include <gtest/gtest.h>

#include "core/atomic_file.h"
#include "core/json_io.h"
#include "tests/support/test_dir.h"
#include "tuning/measurement_model.h"
#include "tuning/tune.h"
#include "tuning/wear_average.h"
#include "tuning/write_plan.h"

namespace formloop::tuning {
namespace {

namespace fs = std::filesystem;

const fs::path kBracket = fs::path(FORMLOOP_SOURCE_DIR) / "data/tuning/bracket";

std::string Slurp(const fs::path& p) {
  std::ifstream in(p, std::ios::binary);
  return {std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>()};
}

// The worked bracket of data/tuning/bracket with its standard block and current offsets.
TuneOptions BracketOptions() {
  TuneOptions o;
  o.model = kBracket / "model.json";
  o.points = kBracket / "points.csv";
  o.block = kBracket / "block.csv";
  o.current_offsets = kBracket / "offsets.json";
  return o;
}

// A model with one slot along X (walls at ±6, K = −2 on T3's radius wear, ±0.005) and T3 current 0.085.
Json SlotModel() {
  return Json::parse(R"({
    "format": "formloop.measurement_model", "version": 1,
    "part": {"code": "SLOT-1"},
    "points": [
      {"id": 1, "reference_mm": [6, 0, -2], "approach": [1, 0, 0], "axes": "X"},
      {"id": 2, "reference_mm": [-6, 0, -2], "approach": [-1, 0, 0], "axes": "X"}],
    "offsets": [{"id": "T3_radius_wear", "kind": "TOOL_RADIUS_WEAR", "tool": 3}],
    "dimensions": [{"id": "S1", "type": "LENGTH", "axis": "X", "nominal_mm": 12, "tol_upper_mm": 0.005,
                    "tol_lower_mm": -0.005, "points": [{"id": 1, "role": "WALL_A"}, {"id": 2, "role": "WALL_B"}],
                    "k_row": {"T3_radius_wear": -2}}]
  })");
}

struct Files {
  fs::path dir, model, points, block, block2, offsets;
};

// Raw walls at ±6.005; block errors ∓e at ±6 (so the corrected width is 12.010 + 2e).
Files WriteSlot(const fs::path& dir, double block_error, double recheck_error) {
  Files f{dir, dir / "model.json", dir / "points.csv", dir / "block.csv", dir / "block2.csv", dir / "offsets.json"};
  EXPECT_TRUE(WriteJsonFile(f.model, SlotModel()).ok());
  EXPECT_TRUE(WriteFileAtomic(f.points, "id,x,y,z,t\n1,6.005,0,-2,100\n2,-6.005,0,-2,102\n").ok());
  auto block = [](double e) {
    return "axis,reference_mm,measured_mm,t\nX,6," + Json(6 - e).dump() + ",90\nX,-6," + Json(-6 + e).dump() + ",91\n";
  };
  EXPECT_TRUE(WriteFileAtomic(f.block, block(block_error)).ok());
  EXPECT_TRUE(WriteFileAtomic(f.block2, block(recheck_error)).ok());
  EXPECT_TRUE(WriteJsonFile(
                  f.offsets,
                  {{"format", "formloop.current_offsets"}, {"version", 1}, {"values_mm", {{"T3_radius_wear", 0.085}}}})
                  .ok());
  return f;
}

TuneOptions Options(const Files& f, const std::string& out) {
  TuneOptions o;
  o.model = f.model;
  o.points = f.points;
  o.block = f.block;
  o.current_offsets = f.offsets;
  o.out = f.dir / out;
  return o;
}

class TuneTest : public ::testing::Test {
 protected:
  void SetUp() override { dir_ = testing::FreshTestDir("tune"); }
  void TearDown() override { fs::remove_all(dir_); }
  fs::path dir_;
};

// §9.10: o_prev = 0.085 and δ = +0.020 → 0.105 > 0.1: no write, RECHECK, then INTERVENE. δ = +0.010 →
// 0.095: SAFE, waiting for confirmation.
TEST_F(TuneTest, SafetyLadder) {
  // Block errors ∓0.015: corrected width 12.040, δ = +0.020.
  Files f = WriteSlot(dir_, 0.015, 0.015);
  auto r = RunTune(Options(f, "first"));
  ASSERT_TRUE(r.ok()) << r.status().ToString();
  EXPECT_EQ(r->plan.status, PlanStatus::kRecheck);
  ASSERT_EQ(r->first.changes.size(), 1u);
  EXPECT_DOUBLE_EQ(r->first.changes[0].delta_mm, 0.020);
  EXPECT_DOUBLE_EQ(r->first.changes[0].new_mm, 0.105);
  auto plan = ReadJsonFile(f.dir / "first/offsets.json");
  ASSERT_TRUE(plan.ok());
  EXPECT_EQ((*plan)["status"], "RECHECK");
  EXPECT_TRUE((*plan)["writes"].empty());  // an offset beyond its limit is never in the write plan
  EXPECT_FALSE((*plan)["confirmed"].get<bool>());
  const std::string reasons = (*plan)["blocked_reasons"].dump();
  EXPECT_NE(reasons.find("offset T3_radius_wear: new value 0.105 mm"), std::string::npos) << reasons;
  EXPECT_NE(reasons.find("beyond its limit 0.1 mm"), std::string::npos);
  EXPECT_NE(reasons.find("--recheck-block"), std::string::npos);
  EXPECT_FALSE((*plan)["proposed"][0]["within_limits"].get<bool>());

  // The block probed again gives the same errors: INTERVENE, still nothing written, even with --confirm.
  TuneOptions o = Options(f, "second");
  o.recheck_block = f.block2;
  o.confirm = true;
  r = RunTune(o);
  ASSERT_TRUE(r.ok());
  EXPECT_EQ(r->plan.status, PlanStatus::kIntervene);
  EXPECT_FALSE(r->plan.confirmed);
  plan = ReadJsonFile(f.dir / "second/offsets.json");
  EXPECT_TRUE((*plan)["writes"].empty());
  EXPECT_NE((*plan)["blocked_reasons"].dump().find("INTERVENE"), std::string::npos);
  const std::string audit = Slurp(f.dir / "second/audit.jsonl");
  EXPECT_NE(audit.find("\"decision\":\"RECHECK\""), std::string::npos);

  // The re-probed block shows the first one was off (errors ∓0.003 → width 12.016, δ = +0.008 → 0.093): SAFE
  // after the re-check.
  f = WriteSlot(dir_, 0.015, 0.003);
  o = Options(f, "third");
  o.recheck_block = f.block2;
  r = RunTune(o);
  ASSERT_TRUE(r.ok());
  EXPECT_EQ(r->plan.status, PlanStatus::kSafe);
  EXPECT_TRUE(r->recheck.has_value());
  EXPECT_DOUBLE_EQ(r->final_attempt().changes[0].delta_mm, 0.008);

  // Block errors ∓0.005: width 12.020, δ = +0.010 → 0.095: SAFE, waiting for confirmation; --confirm marks it.
  f = WriteSlot(dir_, 0.005, 0.005);
  r = RunTune(Options(f, "fourth"));
  ASSERT_TRUE(r.ok());
  EXPECT_EQ(r->plan.status, PlanStatus::kSafe);
  EXPECT_FALSE(r->plan.confirmed);
  EXPECT_DOUBLE_EQ(r->first.changes[0].new_mm, 0.095);
  o = Options(f, "fifth");
  o.confirm = true;
  r = RunTune(o);
  ASSERT_TRUE(r.ok());
  EXPECT_TRUE(r->plan.confirmed);
  plan = ReadJsonFile(f.dir / "fifth/offsets.json");
  ASSERT_EQ((*plan)["writes"].size(), 1u);
  const Json& w = (*plan)["writes"][0];
  EXPECT_EQ(w["offset"], "T3_radius_wear");
  EXPECT_EQ(w["kind"], "TOOL_RADIUS_WEAR");
  EXPECT_EQ(w["tool"], 3);
  EXPECT_EQ(w["previous_mm"].get<double>(), 0.085);
  EXPECT_EQ(w["delta_mm"].get<double>(), 0.010);
  EXPECT_EQ(w["new_mm"].get<double>(), 0.095);
  EXPECT_EQ(w["limit_mm"].get<double>(), 0.1);
  EXPECT_TRUE(w["step_limit_mm"].is_null());
  EXPECT_EQ((*plan)["format"], "formloop.offset_write_plan");
  EXPECT_EQ((*plan)["version"], 1);
}

TEST_F(TuneTest, OtherReasonsBlockTheWrite) {
  Files f = WriteSlot(dir_, 0.005, 0.005);
  // No current offsets: nothing can be written.
  TuneOptions o = Options(f, "no-offsets");
  o.current_offsets.clear();
  auto r = RunTune(o);
  ASSERT_TRUE(r.ok());
  EXPECT_EQ(r->plan.status, PlanStatus::kBlocked);
  EXPECT_NE(r->plan.blocked_reasons[0].find("current offsets unknown"), std::string::npos);
  // A stale block (probed an hour before the points).
  ASSERT_TRUE(WriteFileAtomic(f.block, "axis,reference_mm,measured_mm,t\nX,6,5.995,-3600\nX,-6,-5.995,-3600\n").ok());
  r = RunTune(Options(f, "stale"));
  ASSERT_TRUE(r.ok());
  EXPECT_EQ(r->plan.status, PlanStatus::kBlocked);
  EXPECT_NE(r->plan.blocked_reasons[0].find("BLOCK_STALE"), std::string::npos);
  // A missing point: the dimension is NOT_MEASURED and the write blocked.
  f = WriteSlot(dir_, 0.005, 0.005);
  ASSERT_TRUE(WriteFileAtomic(f.points, "id,x,y,z\n1,6.005,0,-2\n").ok());
  r = RunTune(Options(f, "missing"));
  ASSERT_TRUE(r.ok());
  EXPECT_EQ(r->plan.status, PlanStatus::kBlocked);
  EXPECT_EQ(r->first.dimensions[0].state, "NOT_MEASURED");
  EXPECT_NE(r->plan.blocked_reasons[0].find("point(s) 2 missing"), std::string::npos);
  // A point 0.8 mm off its reference: invalid measurement.
  ASSERT_TRUE(WriteFileAtomic(f.points, "id,x,y,z\n1,6.805,0,-2\n2,-6.005,0,-2\n").ok());
  r = RunTune(Options(f, "invalid"));
  ASSERT_TRUE(r.ok());
  EXPECT_EQ(r->first.dimensions[0].state, "INVALID");
  EXPECT_NE(r->plan.blocked_reasons[0].find("point 1, axis X"), std::string::npos) << r->plan.blocked_reasons[0];
  // Not reachable within the offset bounds (δ limited to ±0.002): stays NG until acknowledged.
  Json model = SlotModel();
  model["offsets"][0]["delta_min_mm"] = -0.002;
  model["offsets"][0]["delta_max_mm"] = 0.002;
  ASSERT_TRUE(WriteJsonFile(f.model, model).ok());
  ASSERT_TRUE(WriteFileAtomic(f.points, "id,x,y,z\n1,6.005,0,-2\n2,-6.005,0,-2\n").ok());
  r = RunTune(Options(f, "unreachable"));
  ASSERT_TRUE(r.ok());
  EXPECT_EQ(r->plan.status, PlanStatus::kBlocked);
  EXPECT_TRUE(r->first.dimensions[0].not_reachable);
  EXPECT_NE(r->plan.blocked_reasons[0].find("--acknowledge-ng S1"), std::string::npos);
  o = Options(f, "acknowledged");
  o.acknowledge_ng = {"S1"};
  r = RunTune(o);
  ASSERT_TRUE(r.ok());
  EXPECT_EQ(r->plan.status, PlanStatus::kSafe);
  EXPECT_EQ(r->plan.not_reachable_acknowledged, std::vector<std::string>{"S1"});
}

// §9.11 and §6: seed 004's examples.
TEST(WearAverage, SeedExamples) {
  OffsetProblem p;
  p.dimension_ids = {"L", "W", "A", "S"};
  p.offset_ids = {"T3", "T4", "T5"};
  Eigen::MatrixXd k = Eigen::MatrixXd::Zero(4, 3);
  k(0, 0) = k(1, 0) = 1;  // length 50.000 → 49.995, width 30.000 → 29.993 on T3 (RADIUS_OUTER, f = +1)
  k(2, 1) = 1;            // 10.000 +0.010/0 measured 9.998 on T4
  k(3, 2) = -1;           // a deviation of 0.001 (inside the 0.002 band) on T5
  p.k = k.sparseView();
  p.deviation_mm = Eigen::Vector4d(-0.005, -0.007, -0.002, 0.001);
  p.tol_lower_mm = Eigen::Vector4d(-0.02, -0.02, 0.0, -0.02);
  p.tol_upper_mm = Eigen::Vector4d(0.02, 0.02, 0.010, 0.02);
  p.target_mm = Eigen::Vector4d::Zero();
  p.weight = Eigen::Vector4d::Ones();
  p.delta_min_mm = Eigen::Vector3d::Constant(-0.05);
  p.delta_max_mm = Eigen::Vector3d::Constant(0.05);
  p.offset_weight = Eigen::Vector3d::Constant(1e-4);
  p.resolution_mm = Eigen::Vector3d::Constant(0.001);
  auto r = AverageWearCompensation(p);
  ASSERT_TRUE(r.ok());
  EXPECT_NEAR(r->delta_mm(0), 0.006, 1e-15);  // subs 0.005 and 0.007
  EXPECT_NEAR(r->dimensions[0].sub_mm, 0.005, 1e-15);
  EXPECT_NEAR(r->dimensions[1].sub_mm, 0.007, 1e-15);
  EXPECT_NEAR(r->delta_mm(1), 0.007, 1e-15);  // a = +0.005, s* − m = 0.007
  EXPECT_FALSE(r->dimensions[3].used);        // |0.001| < 0.002
  EXPECT_NE(r->dimensions[3].reason.find("skip band"), std::string::npos);
  EXPECT_EQ(r->delta_mm(2), 0.0);
  EXPECT_FALSE(r->alarm);
  // 0.025 beyond the allowed 0.020: ALARM.
  p.deviation_mm(0) = p.deviation_mm(1) = -0.025;
  r = AverageWearCompensation(p);
  ASSERT_TRUE(r.ok());
  EXPECT_TRUE(r->alarm);
  EXPECT_TRUE(r->cells[0].alarm);
  // The weighted solve with band-centre targets, equal weights, wide bounds and a negligible regulariser gives
  // the same average.
  p.deviation_mm = Eigen::Vector4d(-0.005, -0.007, -0.002, 0.0);
  p.target_mm = 0.5 * (p.tol_lower_mm + p.tol_upper_mm);
  p.offset_weight = Eigen::Vector3d::Constant(1e-12);
  p.delta_min_mm = Eigen::Vector3d::Constant(-1);
  p.delta_max_mm = Eigen::Vector3d::Constant(1);
  auto wls = SolveOffsets(p);
  ASSERT_TRUE(wls.ok());
  EXPECT_NEAR(wls->rounded.delta_mm(0), 0.006, 1e-9);
  EXPECT_NEAR(wls->rounded.delta_mm(1), 0.007, 1e-9);
}

// The average strategy through the job: an ALARM blocks until the operator accepts it, which is logged.
TEST_F(TuneTest, AverageStrategyAlarmNeedsTheOperator) {
  Files f = WriteSlot(dir_, 0.0, 0.0);
  // Walls at ±6.025: slot 12.050, sub = (0 − 0.050)/(−2) = +0.025 > 0.020.
  ASSERT_TRUE(WriteFileAtomic(f.points, "id,x,y,z\n1,6.025,0,-2\n2,-6.025,0,-2\n").ok());
  Json offsets = {{"format", "formloop.current_offsets"}, {"version", 1}, {"values_mm", {{"T3_radius_wear", 0.0}}}};
  ASSERT_TRUE(WriteJsonFile(f.offsets, offsets).ok());
  TuneOptions o = Options(f, "alarm");
  o.strategy = Strategy::kAverage;
  auto r = RunTune(o);
  ASSERT_TRUE(r.ok()) << r.status().ToString();
  EXPECT_EQ(r->plan.status, PlanStatus::kBlocked);
  EXPECT_NE(r->plan.blocked_reasons[0].find("ALARM: T3_radius_wear 0.025 mm"), std::string::npos)
      << r->plan.blocked_reasons[0];
  o.out = f.dir / "accepted";
  o.accept_alarm = true;
  o.confirm = true;
  r = RunTune(o);
  ASSERT_TRUE(r.ok());
  EXPECT_EQ(r->plan.status, PlanStatus::kSafe);
  EXPECT_TRUE(r->plan.confirmed);
  EXPECT_DOUBLE_EQ(r->first.changes[0].delta_mm, 0.025);
  EXPECT_NE(Slurp(f.dir / "accepted/audit.jsonl").find("\"accepted_by_operator\":true"), std::string::npos);
}

// The worked example: seed 000's two-point diameter (−118.000 / −142.000 → 24.002 through the standard block)
// in a bracket with a boss, a slot, a pocket depth and a hole position.
TEST_F(TuneTest, BracketExampleEndToEndAndByteIdentical) {
  TuneOptions o = BracketOptions();
  o.out = dir_ / "a";
  o.measured_at = "2026-11-26 12:00";  // no time zone, no T
  auto bad = RunTune(o);
  ASSERT_FALSE(bad.ok());
  EXPECT_NE(bad.status().message().find("--measured-at"), std::string::npos);
  o.measured_at = "2026-11-26T12:00:00+01:00";
  auto r = RunTune(o);
  ASSERT_TRUE(r.ok()) << r.status().ToString();
  EXPECT_EQ(r->plan.status, PlanStatus::kSafe);
  const auto& dims = r->first.dimensions;
  ASSERT_EQ(dims.size(), 8u);
  EXPECT_NEAR(dims[0].evaluation.value, 24.002, 1e-9);  // D1
  EXPECT_EQ(r->ng_count, 4);
  for (const auto& d : dims) {
    ASSERT_TRUE(d.predicted_ok_after.has_value()) << d.dimension->id;
    EXPECT_TRUE(*d.predicted_ok_after) << d.dimension->id;
  }
  EXPECT_DOUBLE_EQ(r->first.changes[0].delta_mm, -0.004);
  EXPECT_DOUBLE_EQ(r->first.changes[1].delta_mm, 0.012);
  EXPECT_DOUBLE_EQ(r->first.changes[2].delta_mm, -0.014);
  for (const char* file : {"report.json", "report.csv", "offsets.json", "audit.jsonl", "summary.txt"}) {
    EXPECT_TRUE(fs::exists(o.out / file)) << file;
  }
  EXPECT_FALSE(fs::exists(o.out / ".formloop-tune-partial"));
  // Same inputs → byte-identical outputs.
  o.out = dir_ / "b";
  ASSERT_TRUE(RunTune(o).ok());
  for (const char* file : {"report.json", "report.csv", "offsets.json", "audit.jsonl", "summary.txt"}) {
    EXPECT_EQ(Slurp(dir_ / "a" / file), Slurp(dir_ / "b" / file)) << file;
  }
  // The report records carry seed 000's fields.
  auto report = ReadJsonFile(dir_ / "a/report.json");
  ASSERT_TRUE(report.ok());
  const Json& d1 = (*report)["dimensions"][0];
  for (const char* key : {"measured_at", "part_code", "machine_serial", "nominal", "tol_upper", "tol_lower", "actual",
                          "judgement", "deviation", "excess", "points", "block_mode", "session", "u"}) {
    EXPECT_TRUE(d1.contains(key)) << key;
  }
  EXPECT_EQ(d1["block_mode"], "NEAREST");
}

// The bracket with seed 004's averaging: T3 moves by the mean of D1/D4/D5 (-0.009 mm), which leaves D1 NG and
// takes the TOLERANCE_ONLY bore D2 (K = -2 on T3) from 23.997 (OK) to 24.015 (NG). Neither may be written
// without the operator naming both.
TEST_F(TuneTest, AChangeThatMakesAToleranceOnlyDimensionNgNeedsAnAcknowledgement) {
  TuneOptions o = BracketOptions();
  o.strategy = Strategy::kAverage;
  o.confirm = true;
  o.out = dir_ / "average";
  auto r = RunTune(o);
  ASSERT_TRUE(r.ok()) << r.status().ToString();
  const DimensionResult& d2 = r->first.dimensions[1];
  ASSERT_EQ(d2.dimension->id, "D2");
  EXPECT_TRUE(d2.judgement.ok);
  EXPECT_NEAR(*d2.predicted_value_after, d2.evaluation.value + 0.018, 1e-9);
  EXPECT_FALSE(*d2.predicted_ok_after);
  EXPECT_EQ(r->plan.status, PlanStatus::kBlocked);
  EXPECT_FALSE(r->plan.confirmed);
  const std::string reasons = Json(r->plan.blocked_reasons).dump();
  EXPECT_NE(reasons.find("TOLERANCE_ONLY dimension(s) D2 are OK now and NG after the change"), std::string::npos)
      << reasons;
  EXPECT_NE(reasons.find("dimension(s) D1 will stay NG"), std::string::npos) << reasons;
  // Naming only D1 is not enough; naming both lets the confirmed plan through.
  o.acknowledge_ng = {"D1"};
  o.out = dir_ / "d1";
  r = RunTune(o);
  ASSERT_TRUE(r.ok());
  EXPECT_EQ(r->plan.status, PlanStatus::kBlocked);
  o.acknowledge_ng = {"D1", "D2"};
  o.out = dir_ / "both";
  r = RunTune(o);
  ASSERT_TRUE(r.ok());
  EXPECT_EQ(r->plan.status, PlanStatus::kSafe) << Json(r->plan.blocked_reasons).dump();
  EXPECT_TRUE(r->plan.confirmed);
  EXPECT_EQ(r->plan.not_reachable_acknowledged, (std::vector<std::string>{"D1", "D2"}));
}

TEST_F(TuneTest, OutputFolderRules) {
  TuneOptions o;
  o.model = kBracket / "model.json";
  o.points = kBracket / "points.csv";
  o.out = dir_ / "out";
  ASSERT_TRUE(RunTune(o).ok());
  // Exists: refused without --force; replaced with it (it holds a tune output).
  auto r = RunTune(o);
  ASSERT_FALSE(r.ok());
  EXPECT_NE(r.status().message().find("--force"), std::string::npos);
  o.force = true;
  EXPECT_TRUE(RunTune(o).ok());
  // A folder formloop did not write is never replaced, even with --force.
  fs::create_directories(dir_ / "mine");
  ASSERT_TRUE(WriteFileAtomic(dir_ / "mine/keep.txt", "keep\n").ok());
  o.out = dir_ / "mine";
  r = RunTune(o);
  ASSERT_FALSE(r.ok());
  EXPECT_NE(r.status().message().find("replaces only what it wrote"), std::string::npos);
  EXPECT_TRUE(fs::exists(dir_ / "mine/keep.txt"));
  // An input inside the output folder is refused.
  fs::copy_file(kBracket / "points.csv", dir_ / "mine/points.csv");
  o.points = dir_ / "mine/points.csv";
  o.force = false;
  o.out = dir_ / "mine";
  r = RunTune(o);
  ASSERT_FALSE(r.ok());
  EXPECT_NE(r.status().message().find("inside the output folder"), std::string::npos);
}

// The model's validation names the dimension or offset and the fix.
TEST(MeasurementModel, ValidationMessages) {
  auto expect_error = [](const std::function<void(Json&)>& edit, const std::string& needle) {
    Json model = SlotModel();
    edit(model);
    auto r = ParseMeasurementModel(model, "m.json");
    ASSERT_FALSE(r.ok()) << needle;
    EXPECT_NE(r.status().message().find(needle), std::string::npos) << r.status().message();
  };
  ASSERT_TRUE(ParseMeasurementModel(SlotModel(), "m.json").ok());
  expect_error([](Json& m) { m["dimensions"][0]["type"] = "FLATNESS"; }, "dimensions[S1].");
  expect_error(
      [](Json& m) {
        m["dimensions"][0] = Json::parse(R"({"id": "F1", "type": "FLATNESS", "tolerance_mm": 0.01,
      "points": [{"id": 1, "role": "FEATURE"}, {"id": 2, "role": "FEATURE"}]})");
      },
      "TOLERANCE_ONLY");
  expect_error([](Json& m) { m["dimensions"][0]["k_row"] = {{"T9", 1}}; }, "offset 'T9' is not in the model's offsets");
  expect_error([](Json& m) { m["dimensions"][0]["points"][0]["role"] = "FEATURE"; }, "role 'FEATURE' does not belong");
  expect_error([](Json& m) { m["dimensions"][0]["points"].erase(1); }, "no point has the role WALL_B");
  expect_error([](Json& m) { m["dimensions"][0].erase("k_row"); }, "no offset moves it");
  expect_error([](Json& m) { m["dimensions"][0]["tol_lower_mm"] = 0.01; }, "is not below upper");
  expect_error([](Json& m) { m["dimensions"][0]["tolerence_mm"] = 0.01; }, "unknown field");
  expect_error([](Json& m) { m["dimensions"][0]["points"][0]["id"] = 7; }, "point 7 is not in the model's points");
  expect_error([](Json& m) { m["offsets"][0]["delta_min_mm"] = 0.01; }, "offsets[T3_radius_wear].delta_min_mm");
  expect_error([](Json& m) { m["offsets"][0]["kind"] = "WORK_OFFSET"; }, "offsets[T3_radius_wear].wcs");
  expect_error(
      [](Json& m) {
        m["offsets"][0] = {{"id", "W1"}, {"kind", "WORK_OFFSET"}, {"wcs", "G54.1P1"}, {"axis", "X"}};
      },
      "value 'G54.1P1' is not a work coordinate system the link can write");
  expect_error([](Json& m) { m["dimensions"][0]["k_row"]["T3_radius_wear"] = "2"; }, "k_row.T3_radius_wear");
  expect_error(
      [](Json& m) {
        m["points"][0]["reference_mm"] = {1, 2};
      },
      "points[id 1].reference_mm': expected 3 numbers, got 2");
  expect_error([](Json& m) { m["offsets"].push_back(m["offsets"][0]); }, "id is given twice");
  expect_error([](Json& m) { m["dimensions"][0]["nominal_deg"] = 3; }, "values are in mm");
}

}  // namespace
}  // namespace formloop::tuning
