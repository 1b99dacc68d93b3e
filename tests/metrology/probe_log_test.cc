// Bad input in probe logs (issue 5, "what it must show" 5): missing columns, zero or non-unit approach
// vectors, duplicated ids, ids not in the plan, fewer points than the model needs. Every case is a clear
// error that names the file, the line and the field.

#include <cstdio>
#include <filesystem>
#include <numbers>
#include <string>
#include <vector>

#include <gtest/gtest.h>
#include <Eigen/Geometry>

#include "core/log.h"
#include "metrology/probe.h"
#include "metrology/probe_calibration.h"

namespace formloop::metrology {
namespace {

namespace fs = std::filesystem;

class ProbeLogTest : public ::testing::Test {
 protected:
  void SetUp() override {
    log::SetLevel(log::Level::kError);
    dir_ = fs::temp_directory_path() /
           ("formloop-probelog-" + std::string(::testing::UnitTest::GetInstance()->current_test_info()->name()));
    fs::remove_all(dir_);
    fs::create_directories(dir_);
  }
  void TearDown() override { fs::remove_all(dir_); }
  fs::path Write(const std::string& text) {
    const fs::path path = dir_ / "log.csv";
    std::FILE* f = std::fopen(path.c_str(), "w");
    std::fputs(text.c_str(), f);
    std::fclose(f);
    return path;
  }
  // Reads `text` as a log and expects a bad-input error whose message holds every piece of `want`.
  void ExpectError(const std::string& text, const std::vector<std::string>& want) {
    const fs::path path = Write(text);
    Result<ProbeLog> log = ReadProbeLog(path);
    ASSERT_FALSE(log.ok()) << text;
    EXPECT_EQ(log.status().code(), StatusCode::kBadInput);
    const std::string& m = log.status().message();
    EXPECT_NE(m.find(path.string()), std::string::npos) << m;
    for (const std::string& w : want) EXPECT_NE(m.find(w), std::string::npos) << "want '" << w << "' in: " << m;
    EXPECT_NE(m.find("Fix:"), std::string::npos) << m;
  }
  fs::path dir_;
};

const std::string kHeader = "id,x,y,z,ax,ay,az,t\n";

TEST_F(ProbeLogTest, ReadsAValidLogWithLineNumbersAndRenormalises) {
  // Comments and blank lines count for the line numbers; 1e-7 off unit length is rounding: rescaled.
  const fs::path path =
      Write("# probe log\n" + kHeader + "1,0,0,1,0,0,-1,0\n\n# a comment\n" + "2,1,0,1,-0.6,0,-0.8000001,2\n");
  Result<ProbeLog> log = ReadProbeLog(path);
  ASSERT_TRUE(log.ok()) << log.status().ToString();
  ASSERT_EQ(log->records.size(), 2u);
  EXPECT_EQ(log->records[0].line, 3);
  EXPECT_EQ(log->records[1].line, 6);
  EXPECT_EQ(log->source, path.string());
  EXPECT_NEAR(log->records[1].approach.norm(), 1.0, 1e-15);
  // WriteProbeLog output reads back (9 decimals on the approach).
  const fs::path again = dir_ / "again.csv";
  ASSERT_TRUE(WriteProbeLog(again, *log).ok());
  Result<ProbeLog> back = ReadProbeLog(again);
  ASSERT_TRUE(back.ok()) << back.status().ToString();
  EXPECT_EQ(back->records[1].id, 2);
  EXPECT_TRUE(back->records[1].approach.isApprox(log->records[1].approach, 1e-9));
}

TEST_F(ProbeLogTest, MissingColumnsAreNamed) {
  ExpectError("id,x,y,z,ax,ay,t\n1,0,0,0,0,0,0\n", {"field 'az'", "missing", "id,x,y,z,ax,ay,az,t"});
  ExpectError("id,x,y,z,t\n1,0,0,0,0\n", {"field 'ax, ay, az'", "columns are missing"});
}

// The missing-column error names the file, the header's line number (after comments and blank
// lines), the column and what the header holds, and says what to add where.
TEST_F(ProbeLogTest, MissingColumnNamesTheHeaderLine) {
  ExpectError("# probe log of part 7\n\n# machine M3\nid,x,y,z,ax,ay,t\n1,0,0,0,0,0,0\n",
              {"log.csv:4: field 'az'", "column is missing from the header row on line 4: az",
               "the header reads \"id,x,y,z,ax,ay,t\"", "Fix: add the missing column (az) to the header on line 4",
               "a value for every row"});
  ExpectError("\nid,x,y,z,ax,ay,az\r\n1,0,0,0,0,0,-1\r\n",
              {"log.csv:2: field 't'", "on line 2: t", "header reads \"id,x,y,z,ax,ay,az\"", "header on line 2"});
  ExpectError("x,y,z,ax,ay,az\n0,0,0,0,0,-1\n",
              {"log.csv:1: field 'id, t'", "columns are missing from the header row on line 1: id, t",
               "add the missing columns (id, t)"});
  ExpectError("x,y,z,ax,ay,az,t\n0,0,0,0,0,-1,0\n", {"field 'id'"});
  ExpectError("id,x,y,z,ax,ay,az\n1,0,0,0,0,0,-1\n", {"field 't'"});
  ExpectError("id,x,y,ax,ay,az,t\n1,0,0,0,0,-1,0\n", {"'z'"});   // core/point_io.h: x, y, z required
  ExpectError(kHeader + "1,0,0,0,0,-1,0\n", {":2:", "fields"});  // a short row
}

TEST_F(ProbeLogTest, ZeroApproachVectorNamesTheLine) {
  ExpectError(kHeader + "1,0,0,0,0,0,-1,0\n2,0,0,0,0,0,0,1\n", {":3:", "field 'ax,ay,az'", "id 2", "is zero"});
}

TEST_F(ProbeLogTest, NonUnitApproachVectorNamesTheLine) {
  // 0.99 long: beyond kApproachUnitTolerance (1e-5), so an error rather than a silent rescale.
  ExpectError(kHeader + "1,0,0,0,0,0,-1,0\n\n7,0,0,0,0,0,-0.99,1\n",
              {":4:", "field 'ax,ay,az'", "id 7", "length 0.990000000", "unit vector"});
  // A direction written in mm (a normal scaled by the ball radius, say).
  ExpectError(kHeader + "1,0,0,0,0,0,-2,0\n", {":2:", "length 2.000000000"});
  // Just beyond the tolerance.
  ExpectError(kHeader + "1,0,0,0,0,0,-1.00002,0\n", {":2:", "length 1.000020000"});
}

TEST_F(ProbeLogTest, DuplicatedIdNamesBothLines) {
  ExpectError(kHeader + "1,0,0,0,0,0,-1,0\n2,0,0,0,0,0,-1,1\n1,0,0,0,0,0,-1,2\n",
              {":4:", "field 'id'", "id 1 appears again", "first on line 2"});
}

TEST_F(ProbeLogTest, IdsNotInThePlanAreErrorsAndMissingPlanIdsAreReturned) {
  ProbingPlan plan;
  for (std::int64_t id : {1, 2, 3}) plan.points.push_back({.id = id});
  const fs::path path = Write(kHeader + "1,0,0,0,0,0,-1,0\n3,0,0,0,0,0,-1,1\n");
  Result<ProbeLog> log = ReadProbeLog(path);
  ASSERT_TRUE(log.ok());
  Result<std::vector<std::int64_t>> missing = CheckProbeLogAgainstPlan(*log, plan);
  ASSERT_TRUE(missing.ok());
  EXPECT_EQ(*missing, std::vector<std::int64_t>{2});

  const fs::path stray = Write(kHeader + "1,0,0,0,0,0,-1,0\n# comment\n9,0,0,0,0,0,-1,1\n");
  log = ReadProbeLog(stray);
  ASSERT_TRUE(log.ok());
  const Status s = CheckProbeLogAgainstPlan(*log, plan).status();
  EXPECT_EQ(s.code(), StatusCode::kBadInput);
  for (const std::string& w :
       std::vector<std::string>{stray.string() + ":4:", "field 'id'", "id 9 is not in the probing plan", "Fix:"}) {
    EXPECT_NE(s.message().find(w), std::string::npos) << "want '" << w << "' in: " << s.message();
  }
}

TEST_F(ProbeLogTest, FewerPointsThanTheModelNeedsIsAnErrorWithTheCount) {
  SphereLogOptions o;
  o.points = 10;
  Result<ProbeLog> generated = GenerateSphereProbeLog(o);
  ASSERT_TRUE(generated.ok());
  const fs::path path = dir_ / "short.csv";
  ASSERT_TRUE(WriteProbeLog(path, *generated).ok());
  Result<ProbeLog> log = ReadProbeLog(path);
  ASSERT_TRUE(log.ok());
  SphereCalibrationOptions c;
  c.sphere_radius_mm = 12.5;
  c.ball_radius_mm = 1.0;
  c.elevation_degree = 1;
  // K = 3, D = 1: centre 3 + R_eff 1 + k = 0: none, k = 2, 3: 2 · 2 · 2 = 8 → 12 unknowns, 13 points needed.
  const Status s = CalibrateOnSphere(*log, c).status();
  EXPECT_EQ(s.code(), StatusCode::kBadInput);
  for (const std::string& w :
       std::vector<std::string>{path.string(), "has 10 points", "12 unknowns", "at least 13", "25 points"}) {
    EXPECT_NE(s.message().find(w), std::string::npos) << "want '" << w << "' in: " << s.message();
  }
  // 24 points are enough for the 12 unknowns but fewer than ISO 10360-5 asks for: a warning, not silence.
  o.points = 24;
  generated = GenerateSphereProbeLog(o);
  ASSERT_TRUE(generated.ok());
  Result<SphereCalibrationReport> ok = CalibrateOnSphere(*generated, c);
  ASSERT_TRUE(ok.ok()) << ok.status().ToString();
  ASSERT_FALSE(ok->warnings.empty());
  EXPECT_NE(ok->warnings[0].find("ISO 10360-5 asks for 25 points"), std::string::npos);
}

TEST_F(ProbeLogTest, SingleElevationDropsTheElevationTermsAndSaysSo) {
  SphereLogOptions o;
  o.points = 25;  // the pole and one ring: the pole separates the centre's z from R_eff
  o.elevations_deg = {20.0};
  o.ring_weights = {};
  Result<ProbeLog> log = GenerateSphereProbeLog(o);
  ASSERT_TRUE(log.ok());
  SphereCalibrationOptions c;
  c.sphere_radius_mm = 12.5;
  c.ball_radius_mm = 1.0;
  c.elevation_degree = 2;
  Result<SphereCalibrationReport> cal = CalibrateOnSphere(*log, c);
  ASSERT_TRUE(cal.ok()) << cal.status().ToString();
  EXPECT_EQ(cal->elevation_degree_used, 0);
  bool said = false;
  for (const std::string& w : cal->warnings) said = said || w.find("1 elevation(s)") != std::string::npos;
  EXPECT_TRUE(said) << cal->ToJson().dump(2);
  for (const FittedLobingTerm& t : cal->terms) EXPECT_EQ(t.j, 0);

  // One ring without the pole: the centre's z moves every ball centre radially by the same Δz·sin φ,
  // exactly as R_eff does; named, not guessed.
  o.pole = false;
  o.points = 24;
  Result<ProbeLog> ring = GenerateSphereProbeLog(o);
  ASSERT_TRUE(ring.ok());
  Status s = CalibrateOnSphere(*ring, c).status();
  EXPECT_EQ(s.code(), StatusCode::kBadInput);
  EXPECT_TRUE(s.message().find("centre z") != std::string::npos || s.message().find("R_eff") != std::string::npos)
      << s.message();

  // Only the pole: no centre at all.
  o.pole = true;
  o.points = 5;
  o.elevations_deg = {20.0};
  Result<ProbeLog> poles = GenerateSphereProbeLog(o);
  ASSERT_TRUE(poles.ok());
  for (ProbeRecord& r : poles->records) r.approach = Eigen::Vector3d(0, 0, -1);
  s = CalibrateOnSphere(*poles, c).status();
  EXPECT_EQ(s.code(), StatusCode::kBadInput);
  EXPECT_NE(s.message().find("pole"), std::string::npos) << s.message();
}

TEST_F(ProbeLogTest, TooFewAzimuthsForTheHarmonicsIsARankError) {
  // 3 azimuths per ring cannot carry k = 2 and k = 3 harmonics together.
  SphereLogOptions o;
  o.points = 13;
  o.elevations_deg = {0.0, 22.5, 45.0, 67.5};
  o.ring_weights = {};
  Result<ProbeLog> log = GenerateSphereProbeLog(o);
  ASSERT_TRUE(log.ok());
  SphereCalibrationOptions c;
  c.sphere_radius_mm = 12.5;
  c.ball_radius_mm = 1.0;
  c.elevation_degree = 0;
  const Status s = CalibrateOnSphere(*log, c).status();
  EXPECT_EQ(s.code(), StatusCode::kBadInput);
  EXPECT_NE(s.message().find("do not identify"), std::string::npos) << s.message();
}

TEST_F(ProbeLogTest, TouchesOffTheSphereNormalAndOutliersAreNamed) {
  SphereLogOptions o;
  Result<ProbeLog> log = GenerateSphereProbeLog(o);
  ASSERT_TRUE(log.ok());
  SphereCalibrationOptions c;
  c.sphere_radius_mm = 12.5;
  c.ball_radius_mm = 1.0;
  // id 7 touched 3° off the normal and id 12 with a 10 µm bump: warnings that name them.
  ProbeRecord& tilted = log->records[6];
  tilted.approach = Eigen::AngleAxisd(3.0 * std::numbers::pi / 180, Eigen::Vector3d::UnitZ()) * tilted.approach;
  log->records[11].centre += 0.010 * (log->records[11].centre - o.centre_mm).normalized();
  Result<SphereCalibrationReport> cal = CalibrateOnSphere(*log, c);
  ASSERT_TRUE(cal.ok()) << cal.status().ToString();
  std::string all;
  for (const std::string& w : cal->warnings) all += w + "\n";
  EXPECT_NE(all.find("off the sphere normal"), std::string::npos) << all;
  EXPECT_NE(all.find("id 7:"), std::string::npos) << all;
  EXPECT_NE(all.find("id 12:"), std::string::npos) << all;
  // 20° off: an error naming the row.
  tilted.approach = Eigen::AngleAxisd(20.0 * std::numbers::pi / 180, Eigen::Vector3d::UnitZ()) * tilted.approach;
  tilted.line = 9;
  log->source = "sphere.csv";
  const Status s = CalibrateOnSphere(*log, c).status();
  EXPECT_EQ(s.code(), StatusCode::kBadInput);
  EXPECT_NE(s.message().find("sphere.csv:9:"), std::string::npos) << s.message();
  EXPECT_NE(s.message().find("off the sphere normal"), std::string::npos) << s.message();
}

}  // namespace
}  // namespace formloop::metrology
