// Trimmed CAD faces (reconstruction/trim.h, cad_io.h): the face's loops read with it, OpenCASCADE's
// classification checked against the exact domain of the fixture (an ellipse with a circular hole on a
// Bézier patch, tests/support/cad_fixtures.h), edge and neighbour distances against independent
// computations, a reversed face, the STEP round trip of a trimmed Q, foot points outside the trim, and
// the region reader's errors.

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <string>

#include <gtest/gtest.h>

#include "core/random.h"
#include "reconstruction/bspline_surface.h"
#include "reconstruction/cad_io.h"
#include "reconstruction/foot_point.h"
#include "reconstruction/occt_support.h"
#include "reconstruction/trim.h"
#include "tests/support/cad_fixtures.h"
#include "tests/support/test_dir.h"

namespace formloop::recon {
namespace {

namespace fs = std::filesystem;
using testing::BezierTop;
using testing::HoledDomain;

// Exact 3-D points of the two loops, densely sampled (for reference distances and lengths).
std::vector<Eigen::Vector3d> ExactLoop(bool hole, int n) {
  std::vector<Eigen::Vector3d> out;
  for (int k = 0; k < n; ++k) {
    const double t = 2 * M_PI * k / n;
    const double x = hole ? HoledDomain::kHoleX + HoledDomain::kHoleR * std::cos(t) : HoledDomain::kA * std::cos(t);
    const double y = hole ? HoledDomain::kHoleY + HoledDomain::kHoleR * std::sin(t) : HoledDomain::kB * std::sin(t);
    out.push_back(BezierTop::Point(x, y));
  }
  return out;
}

double PolylineLength(const std::vector<Eigen::Vector3d>& p) {
  double length = 0;
  for (std::size_t i = 0; i < p.size(); ++i) length += (p[(i + 1) % p.size()] - p[i]).norm();
  return length;
}

class TrimTest : public ::testing::Test {
 protected:
  void SetUp() override {
    occt::KeepStdoutClean();
    dir_ = formloop::testing::FreshTestDir("formloop_trim");
  }
  void TearDown() override { fs::remove_all(dir_); }
  fs::path Write(bool reversed, bool with_pin) {
    const fs::path path = dir_ / (std::string(reversed ? "reversed" : "holed") + (with_pin ? "_pin" : "") + ".step");
    std::vector<TopoDS_Face> faces{testing::MakeHoledFace(reversed)};
    std::vector<std::string> names{"top"};
    if (with_pin) {
      faces.push_back(testing::MakePin());
      names.push_back("pin");
    }
    EXPECT_TRUE(testing::WriteStepFaces(path, faces, names));
    return path;
  }
  fs::path dir_;
};

TEST_F(TrimTest, HoledFaceIsReadWithItsLoopsAreaAndNeighbour) {
  const auto face = ReadCadFace(Write(false, true), CadFaceSelector{.name = "top"});
  ASSERT_TRUE(face.ok()) << face.status().ToString();
  const Trim* trim = face->surface.trim();
  ASSERT_NE(trim, nullptr);
  EXPECT_FALSE(trim->natural());
  ASSERT_EQ(trim->loops().size(), 2u);
  EXPECT_TRUE(trim->loops()[0].outer);
  EXPECT_FALSE(trim->loops()[1].outer);
  EXPECT_EQ(trim->neighbour_count(), 1);
  // Q is the patch restricted to the face's parameter box (the ellipse's box; OpenCASCADE's box of the
  // pcurves as read may be a little larger).
  const ParamDomain d = face->surface.domain();
  EXPECT_LE(d.u_min, -HoledDomain::kA);
  EXPECT_GT(d.u_min, -HoledDomain::kA - 0.5);
  EXPECT_GE(d.u_max, HoledDomain::kA);
  EXPECT_LT(d.u_max, HoledDomain::kA + 0.5);
  EXPECT_LE(d.v_min, -HoledDomain::kB);
  EXPECT_GT(d.v_min, -HoledDomain::kB - 0.5);
  // Loop lengths against the exact loops (200,000 samples).
  const double outer = PolylineLength(ExactLoop(false, 200000)), hole = PolylineLength(ExactLoop(true, 200000));
  EXPECT_NEAR(trim->loops()[0].length_mm, outer, 1e-5 * outer);
  EXPECT_NEAR(trim->loops()[1].length_mm, hole, 1e-5 * hole);
  // Area against a midpoint-rule integral of |S_u × S_v| over the exact domain (1000 × 1000 cells).
  double area = 0;
  const int n = 1000;
  const double hx = 2 * HoledDomain::kA / n, hy = 2 * HoledDomain::kB / n, e = 1e-6;
  for (int i = 0; i < n; ++i) {
    for (int j = 0; j < n; ++j) {
      const double x = -HoledDomain::kA + (i + 0.5) * hx, y = -HoledDomain::kB + (j + 0.5) * hy;
      if (!HoledDomain::Inside(x, y)) continue;
      const double zx = (BezierTop::Height(x + e, y) - BezierTop::Height(x - e, y)) / (2 * e);
      const double zy = (BezierTop::Height(x, y + e) - BezierTop::Height(x, y - e)) / (2 * e);
      area += std::sqrt(1 + zx * zx + zy * zy) * hx * hy;
    }
  }
  std::printf("[measured] trimmed area %.4f mm2 (BRepGProp) vs %.4f mm2 (midpoint rule); outer loop %.6f vs %.6f mm\n",
              trim->area_mm2(), area, trim->loops()[0].length_mm, outer);
  EXPECT_NEAR(trim->area_mm2(), area, 1e-3 * area);
}

TEST_F(TrimTest, ClassificationMatchesTheExactDomain) {
  for (const bool reversed : {false, true}) {
    const auto face = ReadCadFace(Write(reversed, false), CadFaceSelector{});
    ASSERT_TRUE(face.ok()) << face.status().ToString();
    const BSplineSurface& q = face->surface;
    ASSERT_NE(q.trim(), nullptr);
    const ParamDomain d = q.domain();
    Rng rng(reversed ? 11 : 7);
    int checked = 0, inside = 0;
    for (int k = 0; k < 20000; ++k) {
      const double u = rng.Uniform(d.u_min, d.u_max), v = rng.Uniform(d.v_min, d.v_max);
      const Eigen::Vector3d p = q.Point(u, v);
      // Q's normal points away from the material (+z) whatever the face's orientation.
      if (k < 50) {
        ASSERT_GT(q.Normal(u, v).z(), 0.5);
      }
      EXPECT_NEAR(p.z(), BezierTop::Height(p.x(), p.y()), 1e-9);
      // Away from the boundaries by more than the edges' tolerance as read from STEP.
      if (testing::NearHoledBoundary(p.x(), p.y(), 1e-3)) continue;
      const bool truth = HoledDomain::Inside(p.x(), p.y());
      ASSERT_EQ(q.trim()->Inside(u, v), truth) << "at " << p.transpose() << (reversed ? " (reversed face)" : "");
      ++checked;
      inside += truth;
    }
    EXPECT_GT(checked, 19900);
    EXPECT_GT(inside, 10000);
    EXPECT_LT(inside, checked);
  }
}

TEST_F(TrimTest, EdgeAndNeighbourDistancesAgreeWithIndependentOnes) {
  const auto face = ReadCadFace(Write(false, true), CadFaceSelector{.name = "top"});
  ASSERT_TRUE(face.ok());
  const BSplineSurface& q = face->surface;
  const Trim& trim = *q.trim();
  std::vector<Eigen::Vector3d> loops = ExactLoop(false, 40000);
  for (const Eigen::Vector3d& p : ExactLoop(true, 20000)) loops.push_back(p);
  Rng rng(3);
  double worst = 0;
  for (int k = 0; k < 200; ++k) {
    const double x = rng.Uniform(-40, 40), y = rng.Uniform(-30, 30);
    const Eigen::Vector3d p = BezierTop::Point(x, y);
    double reference = 1e300;
    for (const Eigen::Vector3d& l : loops) reference = std::min(reference, (l - p).norm());
    worst = std::max(worst, std::abs(trim.EdgeDistanceMm(p) - reference));
    // The pin: a vertical cylinder of radius 4 from z = -10 to 40.
    const Eigen::Vector3d above(x, y, 15.0);
    const double to_pin = std::abs(HoledDomain::PinAxisDistance(x, y) - HoledDomain::kPinR);
    EXPECT_NEAR(trim.NeighbourDistanceMm(above, 1e9), to_pin, 1e-6) << x << " " << y;
    EXPECT_EQ(trim.NeighbourDistanceMm(above, 0.5 * to_pin), 0.5 * to_pin) << "capped at the reach asked for";
    // A reach just beyond the pin: its exact distance. The bound from the pin's triangulation (a polygon
    // inside the cylinder, up to its deflection nearer the axis) must not skip the exact query there.
    EXPECT_NEAR(trim.NeighbourDistanceMm(above, to_pin + 1e-4), to_pin, 1e-6) << x << " " << y;
    EXPECT_EQ(trim.NeighbourDistanceMm(above, to_pin - 1e-4), to_pin - 1e-4) << x << " " << y;
  }
  // Sampling the exact loops every ~0.007 mm leaves up to ~0.0035 mm between samples.
  std::printf("[measured] edge distance: worst difference from the exact-loop reference %.2e mm\n", worst);
  EXPECT_LT(worst, 5e-3);
}

TEST_F(TrimTest, TrimmedQSurvivesTheStepRoundTripAndFlagsFootPointsOutsideIt) {
  const auto face = ReadCadFace(Write(true, false), CadFaceSelector{});
  ASSERT_TRUE(face.ok());
  const fs::path q_path = dir_ / "Q.step";
  ASSERT_TRUE(WriteStep(q_path, face->surface, "holed").ok());
  const auto again = ReadCadFace(q_path, CadFaceSelector{});
  ASSERT_TRUE(again.ok()) << again.status().ToString();
  ASSERT_NE(again->surface.trim(), nullptr);
  const ParamDomain d = face->surface.domain();
  Rng rng(5);
  for (int k = 0; k < 2000; ++k) {
    const double u = rng.Uniform(d.u_min, d.u_max), v = rng.Uniform(d.v_min, d.v_max);
    EXPECT_LT((face->surface.Point(u, v) - again->surface.Point(u, v)).norm(), 1e-9);
    const Eigen::Vector3d p = face->surface.Point(u, v);
    if (testing::NearHoledBoundary(p.x(), p.y(), 1e-3)) continue;
    EXPECT_EQ(face->surface.trim()->Inside(u, v), again->surface.trim()->Inside(u, v));
  }
  // A point above the hole projects onto the patch inside the hole: flagged; one above the face: not.
  const auto projector = FootPointProjector::Build(again->surface);
  ASSERT_TRUE(projector.ok());
  const auto over_hole =
      projector->Project(BezierTop::Point(HoledDomain::kHoleX, HoledDomain::kHoleY) + Eigen::Vector3d(0, 0, 0.5));
  ASSERT_TRUE(over_hole.ok());
  EXPECT_TRUE(over_hole->outside_trim);
  EXPECT_FALSE(over_hole->on_boundary);
  const auto on_face = projector->Project(BezierTop::Point(-20, 10) + Eigen::Vector3d(0, 0, 0.5));
  ASSERT_TRUE(on_face.ok());
  EXPECT_FALSE(on_face->outside_trim);
  EXPECT_NEAR(on_face->deviation_mm, 0.5 * std::abs(on_face->normal.z()), 1e-3);
  // (40, 20) lies in Q's box but outside the ellipse (level 1.12).
  const auto beyond = projector->Project(BezierTop::Point(40, 20));
  ASSERT_TRUE(beyond.ok());
  EXPECT_TRUE(beyond->outside_trim);
  const auto local = ProjectFrom(again->surface, BezierTop::Point(40, 20), beyond->u, beyond->v);
  ASSERT_TRUE(local.ok());
  EXPECT_TRUE(local->outside_trim);
}

TEST_F(TrimTest, TrimmedGridSamplesOnlyTheFace) {
  const auto face = ReadCadFace(Write(false, false), CadFaceSelector{});
  ASSERT_TRUE(face.ok());
  const TrimmedGrid grid = SampleTrimmedGrid(face->surface, 61, 47);
  int truth = 0;
  for (std::size_t k = 0; k < grid.uv.size(); ++k) {
    const Eigen::Vector3d p = face->surface.Point(grid.uv[k].x(), grid.uv[k].y());
    truth += HoledDomain::Inside(p.x(), p.y());
  }
  EXPECT_EQ(grid.inside_count(), truth);
  EXPECT_LT(grid.inside_count(), 61 * 47);
}

TEST_F(TrimTest, RegionReaderNamesTheFieldAndListsTheFaces) {
  const fs::path path = Write(false, true);
  const auto both = ReadCadFaces(path, CadRegionSelector{.names = {"top", "pin"}});
  ASSERT_TRUE(both.ok()) << both.status().ToString();
  EXPECT_EQ(both->size(), 2u);
  EXPECT_FALSE(both->front().surface.trim()->has_neighbours()) << "the other chosen face is not a neighbour";
  const auto missing = ReadCadFaces(path, CadRegionSelector{.names = {"top", "lid"}});
  ASSERT_FALSE(missing.ok());
  EXPECT_NE(missing.status().ToString().find("face_names[1]"), std::string::npos) << missing.status().ToString();
  EXPECT_NE(missing.status().ToString().find("'pin'"), std::string::npos) << "lists the faces";
  const auto range = ReadCadFaces(path, CadRegionSelector{.indices = {0, 5}});
  ASSERT_FALSE(range.ok());
  EXPECT_NE(range.status().ToString().find("faces[1]"), std::string::npos) << range.status().ToString();
  EXPECT_NE(range.status().ToString().find("from 0 to 1"), std::string::npos);
  const auto twice = ReadCadFaces(path, CadRegionSelector{.indices = {1, 1}});
  ASSERT_FALSE(twice.ok());
  EXPECT_NE(twice.status().ToString().find("chosen twice"), std::string::npos);
}

}  // namespace
}  // namespace formloop::recon
