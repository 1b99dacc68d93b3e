// Surfaces given as files in the part description (app/surface_source.h): the bad inputs named with
// their field before a run starts (missing file, face index out of range, face name that does not
// exist with the faces listed, too few scan points, unit-less IGES, changed file), and Q built from
// one trimmed face, a region of three faces and a scan, with the copy kept in a run folder.

#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <string>

#include <gtest/gtest.h>

#include "app/surface_fit.h"
#include "app/surface_source.h"
#include "core/atomic_file.h"
#include "core/file_hash.h"
#include "core/json_io.h"
#include "core/point_io.h"
#include "core/random.h"
#include "reconstruction/occt_support.h"
#include "reconstruction/trim.h"
#include "tests/support/cad_fixtures.h"
#include "tests/support/test_dir.h"

namespace formloop::app {
namespace {

namespace fs = std::filesystem;

class SurfaceSourceTest : public ::testing::Test {
 protected:
  void SetUp() override {
    recon::occt::KeepStdoutClean();
    dir_ = formloop::testing::FreshTestDir("formloop_surface_source");
    ASSERT_TRUE(formloop::testing::WriteStepFaces(
        dir_ / "holed.step", {formloop::testing::MakeHoledFace(), formloop::testing::MakePin()}, {"top", "pin"}));
    ASSERT_TRUE(formloop::testing::WriteStepFaces(dir_ / "strips.step", formloop::testing::MakeThreeStrips(),
                                                  {"left", "middle", "right"}));
  }
  void TearDown() override { fs::remove_all(dir_); }
  Result<SurfaceFile> Parse(const std::string& surface_json) {
    const Json surface = Json::parse(surface_json);
    return ParseSurfaceFile(JsonFields(surface, part_, "surface."), part_);
  }
  // The message of a parse that must fail with bad input.
  std::string Refused(const std::string& surface_json) {
    const auto parsed = Parse(surface_json);
    EXPECT_FALSE(parsed.ok()) << surface_json;
    if (parsed.ok()) return "";
    EXPECT_EQ(parsed.status().code(), StatusCode::kBadInput) << parsed.status().ToString();
    return parsed.status().ToString();
  }
  fs::path dir_;
  std::string part_;
};

TEST_F(SurfaceSourceTest, BadInputsAreRefusedNamingTheField) {
  part_ = (dir_ / "part.json").string();
  std::string m = Refused(R"({"cad": "absent.step"})");
  EXPECT_NE(m.find("field 'surface.cad'"), std::string::npos) << m;
  EXPECT_NE(m.find("absent.step"), std::string::npos) << m;
  m = Refused(R"({"cad": "holed.step", "faces": [0, 7]})");
  EXPECT_NE(m.find("surface.faces"), std::string::npos) << m;
  EXPECT_NE(m.find("out of range"), std::string::npos) << m;
  m = Refused(R"({"cad": "holed.step", "face_names": ["lid"]})");
  EXPECT_NE(m.find("surface.face_names"), std::string::npos) << m;
  EXPECT_NE(m.find("'top'"), std::string::npos) << "the faces are listed: " << m;
  EXPECT_NE(m.find("'pin'"), std::string::npos) << m;
  m = Refused(R"({"cad": "holed.step"})");
  EXPECT_NE(m.find("has 2 faces"), std::string::npos) << "several faces and none chosen: " << m;
  m = Refused(R"({"cad": "holed.step", "face_names": ["top"], "sha256": "00"})");
  EXPECT_NE(m.find("surface.sha256"), std::string::npos) << m;
  m = Refused(R"({"cad": "holed.step", "face_names": ["top"], "colour": "red"})");
  EXPECT_NE(m.find("colour"), std::string::npos) << m;

  // Too few points for the fit.
  formloop::testing::WriteNinePoints(dir_ / "few.csv");
  m = Refused(R"({"points": "few.csv"})");
  EXPECT_NE(m.find("field 'surface.points'"), std::string::npos) << m;
  EXPECT_NE(m.find("holds 9 points"), std::string::npos) << m;
  EXPECT_NE(m.find("at least 16"), std::string::npos) << m;
  m = Refused(R"({"points": "few.csv", "method": "spline"})");
  EXPECT_NE(m.find("surface.method"), std::string::npos) << m;

  // A unit-less IGES file (the global section's unit flag and name blanked).
  ASSERT_TRUE(formloop::testing::WriteIgesWithAndWithoutUnit(dir_ / "with_unit.igs", dir_ / "no_unit.igs"));
  ASSERT_TRUE(Parse(R"({"cad": "with_unit.igs"})").ok());
  m = Refused(R"({"cad": "no_unit.igs"})");
  EXPECT_NE(m.find("surface.cad"), std::string::npos) << m;
  EXPECT_NE(m.find("units"), std::string::npos) << m;
}

TEST_F(SurfaceSourceTest, OneTrimmedFaceIsItsOwnQAndTheRunKeepsACopy) {
  part_ = (dir_ / "part.json").string();
  const auto file = Parse(R"({"cad": "holed.step", "face_names": ["top"]})");
  ASSERT_TRUE(file.ok()) << file.status().ToString();
  EXPECT_EQ(file->sha256, Sha256OfFile(dir_ / "holed.step").value());
  const auto built = BuildSurfaceFromFile(*file, 0.01);
  ASSERT_TRUE(built.ok()) << built.status().ToString();
  ASSERT_NE(built->q.trim(), nullptr);
  EXPECT_FALSE(built->q.trim()->natural());
  EXPECT_EQ(built->fit_check_max_mm, 0.0);
  EXPECT_EQ(built->description["trim"]["holes"], 1);
  // The copy in a run folder, named by the resolved description, parses to the same file.
  fs::create_directories(dir_ / "run" / "inputs");
  ASSERT_TRUE(CopySurfaceFile(*file, dir_ / "run" / "inputs").ok());
  const Json resolved = file->ToJson(file->CopyName());
  const std::string inputs_part = (dir_ / "run" / "inputs" / "part.json").string();
  const auto again = ParseSurfaceFile(JsonFields(resolved, inputs_part, "surface."), inputs_part);
  ASSERT_TRUE(again.ok()) << again.status().ToString();
  EXPECT_EQ(again->sha256, file->sha256);
  EXPECT_EQ(again->path, dir_ / "run" / "inputs" / "holed.step");
}

TEST_F(SurfaceSourceTest, ThreeFacesBecomeOneQAndAScanIsFittedWithinItsBox) {
  part_ = (dir_ / "part.json").string();
  const auto region = Parse(R"({"cad": "strips.step", "faces": [0, 1, 2]})");
  ASSERT_TRUE(region.ok()) << region.status().ToString();
  const auto q = BuildSurfaceFromFile(*region, 0.01);
  ASSERT_TRUE(q.ok()) << q.status().ToString();
  EXPECT_LT(q->fit_check_max_mm, 0.1 * 0.01);
  EXPECT_EQ(q->description["region"]["faces"], 3);
  // A deviation limit nothing meets is refused with the figure and the field.
  const auto strict = Parse(R"({"cad": "strips.step", "faces": [0, 1, 2], "sample_spacing_mm": 8,
                                "max_deviation_fraction": 0.0001})");
  ASSERT_TRUE(strict.ok());
  const auto refused = BuildSurfaceFromFile(*strict, 0.01);
  ASSERT_FALSE(refused.ok());
  EXPECT_NE(refused.status().ToString().find("max_deviation_fraction"), std::string::npos)
      << refused.status().ToString();
  EXPECT_NE(refused.status().ToString().find(" um"), std::string::npos);

  // A scan of the strips' bump with 5 um noise along z, 61 x 49 points over [-50, 50] x [-40, 40].
  {
    Rng rng(3);
    std::ofstream scan(dir_ / "scan.xyz");
    for (int j = 0; j < 49; ++j) {
      for (int i = 0; i < 61; ++i) {
        const double x = -50 + 100.0 * i / 60, y = -40 + 80.0 * j / 48;
        scan << FormatExact(x) << " " << FormatExact(y) << " "
             << FormatExact(formloop::testing::StripHeight(x, y) + 0.005 * rng.Normal()) << "\n";
      }
    }
  }
  const auto scan = Parse(R"({"points": "scan.xyz"})");
  ASSERT_TRUE(scan.ok()) << scan.status().ToString();
  const auto fitted = BuildSurfaceFromFile(*scan, 0.01);
  ASSERT_TRUE(fitted.ok()) << fitted.status().ToString();
  EXPECT_TRUE(std::isnan(fitted->fit_check_max_mm)) << "a scan's true surface is unknown";
  // Q ends at the points' parameter box: its corners lie near the scanned rectangle's (the box is taken in
  // the plane of the points' principal components, onto which the curved, tilted outline projects as a
  // slightly curved quadrilateral, so the box's corners may sit a fraction of a millimetre off it).
  const recon::ParamDomain d = fitted->q.domain();
  double worst_corner = 0, worst_inside = 0;
  for (const double u : {d.u_min, d.u_max}) {
    for (const double v : {d.v_min, d.v_max}) {
      const Eigen::Vector3d p = fitted->q.Point(u, v);
      worst_corner = std::max(
          worst_corner, std::min(std::abs(std::abs(p.x()) - 50), 1.0) + std::min(std::abs(std::abs(p.y()) - 40), 1.0));
    }
  }
  for (int k = 0; k < 400; ++k) {
    const Eigen::Vector3d p =
        fitted->q.Point(d.u_min + d.u_span() * (k % 20 + 0.5) / 20, d.v_min + d.v_span() * (k / 20 + 0.5) / 20);
    worst_inside = std::max(worst_inside, std::abs(p.z() - formloop::testing::StripHeight(p.x(), p.y())));
  }
  std::printf(
      "[measured] scan of the bump (2989 points, 5 um noise): corners within %.4f mm of the scanned rectangle's, "
      "Q within %.2f um of the truth at 400 points\n",
      worst_corner, worst_inside * 1e3);
  EXPECT_LT(worst_corner, 0.5);
  EXPECT_LT(worst_inside, 5e-3);
}

TEST_F(SurfaceSourceTest, ProjectFlagsFootPointsOutsideTheTrim) {
  // Three points 0.2 mm above the holed face: over the hole, over the face, past the ellipse's edge.
  {
    std::ofstream points(dir_ / "points.csv");
    points << "x,y,z\n";
    for (const auto& [x, y] : std::vector<std::pair<double, double>>{{10, -5}, {-20, 10}, {40, 20}}) {
      points << x << "," << y << "," << formloop::testing::BezierTop::Height(x, y) + 0.2 << "\n";
    }
  }
  ProjectRequest request;
  request.surface = (dir_ / "holed.step").string();
  request.face.name = "top";
  request.points = (dir_ / "points.csv").string();
  request.out = (dir_ / "deviations.csv").string();
  const auto outcome = ProjectPoints(request);
  ASSERT_TRUE(outcome.ok()) << outcome.status().ToString();
  const std::vector<double>* outside = outcome->deviations.FindScalar("outside_trim");
  ASSERT_NE(outside, nullptr);
  EXPECT_EQ(*outside, (std::vector<double>{1, 0, 1}));
  EXPECT_EQ(outcome->summary["n_outside_trim"], 2);
}

}  // namespace
}  // namespace formloop::app
