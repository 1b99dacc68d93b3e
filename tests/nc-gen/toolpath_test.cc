// Independent check of PlanRaster (spec/nc-gen.md §1-2): the machined surface is computed from the cutter
// locations alone and compared with the surface the planner was given. The checker (swept capsules of the
// ball centres, lower envelope, normal distance to Q) lives in tests/support/swept_ball.h, where
// bench/checker_bench.cc measures its cost too.

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <sstream>
#include <string>
#include <vector>

#include <unistd.h>

#include <gtest/gtest.h>

#include "nc-gen/toolpath.h"
#include "nc-gen/toolpath_io.h"
#include "reconstruction/analytic_surface.h"
#include "reconstruction/bspline_surface.h"
#include "tests/support/swept_ball.h"

namespace formloop::nc {
namespace {

using Eigen::Vector3d;

constexpr double kInf = formloop::testing::kNoMaterialRemoved;

using formloop::testing::Capsule;
using formloop::testing::CapsuleBottom;
using formloop::testing::Check;
using formloop::testing::CheckResult;

ToolpathOptions Options() {
  ToolpathOptions o;
  o.tool.radius_mm = 3.0;  // 6 mm ball
  o.scallop_um = 5.0;
  o.chord_tolerance_um = 1.0;
  o.max_point_spacing_mm = 0.5;
  return o;
}

TEST(ToolpathCheckerTest, CapsuleBottomMatchesBruteForce) {
  const Capsule c{Vector3d(0, 0, 1), Vector3d(0.4, 0.1, 1.3)};
  const double r = 3;
  for (double x : {-2.0, -0.3, 0.2, 0.35, 1.5}) {
    for (double y : {-1.0, 0.05, 0.8}) {
      double brute = kInf;
      for (int i = 0; i <= 20000; ++i) {
        const Vector3d m = c.a + (c.b - c.a) * (i / 20000.0);
        const double d2 = (x - m.x()) * (x - m.x()) + (y - m.y()) * (y - m.y());
        if (d2 <= r * r) brute = std::min(brute, m.z() - std::sqrt(r * r - d2));
      }
      EXPECT_NEAR(CapsuleBottom(c, r, x, y), brute, 1e-7) << x << " " << y;
    }
  }
}

class ReferenceSurfaceToolpathTest : public ::testing::TestWithParam<std::string> {};

TEST_P(ReferenceSurfaceToolpathTest, ScallopWithinTargetPlusChordAndNoGouge) {
  const auto analytic = recon::MakeReferenceSurface(GetParam());
  ASSERT_TRUE(analytic.ok());
  recon::FitReport report;
  const auto q = recon::FitAnalytic(*analytic.value(), 50, 50, {}, 0, 1, &report);
  ASSERT_TRUE(q.ok()) << q.status().message();
  const ToolpathOptions o = Options();
  const auto path = PlanRaster(*q, o);
  ASSERT_TRUE(path.ok()) << path.status().message();
  // Across the passes the grid is a tenth of the smallest step-over; along them 0.05 mm.
  const double dv = path->min_step_over_mm / 10;
  const CheckResult c = Check(*q, *path, 4, 4.0, 3.0, 0.05, dv, 1.0);
  std::printf(
      "[checker] %-18s CL %6zu passes %4d step-over %.4f..%.4f mm  max scallop %.3f um  max gouge %.3f um"
      "  (%d samples, %d uncovered) lifted %d\n",
      GetParam().c_str(), path->points.size(), path->passes, path->min_step_over_mm, path->max_step_over_mm,
      c.max_scallop_um, c.max_gouge_um, c.samples, c.uncovered, path->lifted_points);
  EXPECT_EQ(c.uncovered, 0);
  EXPECT_LE(c.max_scallop_um, o.scallop_um + o.chord_tolerance_um);
  EXPECT_LE(c.max_gouge_um, 1.0);
  EXPECT_GT(c.max_scallop_um, 0.5 * o.scallop_um) << "the windows must catch scallop peaks";
  EXPECT_EQ(path->gouge_risk_points, 0);
  EXPECT_EQ(path->lifted_points, 0);
  // Per plane the step-over follows the curvature across it (egg_box's bumps repeat along every plane,
  // so its per-plane minimum hardly varies; franke's and the sphere cap's do).
  if (GetParam() == "sphere_cap" || GetParam() == "franke") {
    EXPECT_LT(path->min_step_over_mm, 0.97 * path->max_step_over_mm) << "step-over follows the curvature per pass";
  }
}

INSTANTIATE_TEST_SUITE_P(AllReferenceSurfaces, ReferenceSurfaceToolpathTest,
                         ::testing::ValuesIn(recon::ReferenceSurfaceNames()),
                         [](const ::testing::TestParamInfo<std::string>& param_info) { return param_info.param; });

// A paraboloid bowl z = (x² + y²)/(2R), R = 2 mm: concave, radius 2 mm at the bottom (< r = 3 mm).
class Bowl final : public recon::AnalyticSurface {
 public:
  std::string name() const override { return "bowl"; }
  std::string description() const override { return "bowl z = (x^2 + y^2)/(2R), R = 2 mm"; }
  recon::ParamDomain domain() const override { return {-3, 3, -3, 3}; }
  bool is_graph() const override { return true; }
  recon::SurfaceDerivatives Derivatives(double x, double y) const override {
    recon::SurfaceDerivatives d;
    d.p = Vector3d(x, y, (x * x + y * y) / (2 * kR));
    d.su = Vector3d(1, 0, x / kR);
    d.sv = Vector3d(0, 1, y / kR);
    d.suu = Vector3d(0, 0, 1 / kR);
    d.suv = Vector3d::Zero();
    d.svv = Vector3d(0, 0, 1 / kR);
    return d;
  }
  static constexpr double kR = 2.0;
};

TEST(ToolpathGougeTest, ConcaveBowlBelowTheBallRadiusIsLiftedFlaggedAndNotGouged) {
  const Bowl bowl;
  ASSERT_LT(bowl.Curvatures(0, 0).k2, -1.0 / 3.0);
  recon::FitReport report;
  const auto q = recon::FitAnalytic(bowl, 40, 40, {}, 0, 1, &report);
  ASSERT_TRUE(q.ok()) << q.status().message();
  const ToolpathOptions o = Options();
  const auto path = PlanRaster(*q, o);
  ASSERT_TRUE(path.ok()) << path.status().message();
  EXPECT_GT(path->gouge_risk_points, 0);
  EXPECT_GT(path->lifted_points, 0);
  EXPECT_EQ(static_cast<int>(path->lifted_indices.size()), path->lifted_points);
  EXPECT_GT(path->max_lift_mm, 0.0);
  // The bottom of the bowl lies inside the flagged (never cut) box.
  EXPECT_LE(path->lifted_box_min.x(), 0.0);
  EXPECT_GE(path->lifted_box_max.x(), 0.0);
  EXPECT_LE(path->lifted_box_min.y(), 0.0);
  EXPECT_GE(path->lifted_box_max.y(), 0.0);
  for (int k : path->lifted_indices) {
    const ClPoint& cl = path->points[static_cast<std::size_t>(k)];
    EXPECT_GT(cl.lift_mm, 0.0);
    EXPECT_NEAR(cl.centre.z(), cl.cc.z() + 3.0 * cl.normal.z() + cl.lift_mm, 1e-9);
  }
  // The whole bowl, densely: nothing inside the swept balls by more than 1 µm.
  const double dv = path->min_step_over_mm / 10;
  const CheckResult c = Check(*q, *path, 1, 5.8, 5.8, 0.04, std::min(dv, 0.04), 0.1);
  std::printf(
      "[checker] bowl R=2: CL %zu passes %d gouge-risk %d lifted %d (max lift %.4f mm, box x %.2f..%.2f y "
      "%.2f..%.2f)  max gouge %.3f um  max material left %.1f um (%d samples)\n",
      path->points.size(), path->passes, path->gouge_risk_points, path->lifted_points, path->max_lift_mm,
      path->lifted_box_min.x(), path->lifted_box_max.x(), path->lifted_box_min.y(), path->lifted_box_max.y(),
      c.max_gouge_um, c.max_scallop_um, c.samples);
  EXPECT_EQ(c.uncovered, 0);
  EXPECT_LE(c.max_gouge_um, 1.0);
  const nlohmann::json j = path->ReportJson();
  EXPECT_EQ(j.at("lifted_points").get<int>(), path->lifted_points);

  // The tool-path file keeps every CL point exactly and rebuilds the lifted region from lift_mm.
  std::ostringstream name;
  name << "formloop-bowl-" << ::getpid() << ".csv";
  const std::filesystem::path file = std::filesystem::temp_directory_path() / name.str();
  ASSERT_TRUE(WriteToolpathFile(file, *path).ok());
  const auto back = ReadToolpathFile(file);
  std::filesystem::remove(file);
  ASSERT_TRUE(back.ok()) << back.status().message();
  ASSERT_EQ(back->points.size(), path->points.size());
  for (std::size_t k = 0; k < path->points.size(); ++k) {
    ASSERT_EQ(back->points[k].tip, path->points[k].tip) << k;
    ASSERT_EQ(back->points[k].kind, path->points[k].kind) << k;
  }
  EXPECT_EQ(back->lifted_indices, path->lifted_indices);
  EXPECT_EQ(back->max_lift_mm, path->max_lift_mm);
  EXPECT_EQ(back->lifted_box_min, path->lifted_box_min);
  EXPECT_EQ(back->lifted_box_max, path->lifted_box_max);
  EXPECT_EQ(back->passes, path->passes);
  EXPECT_EQ(back->safe_z_mm, path->safe_z_mm);
}

// Section planes at other raster angles, zig-zag and one-way: the same independent scallop/gouge check,
// and the geometry of the passes (every CC point on its plane, planes in increasing order, direction
// ±d, tangential arc leads that stay clear of Q).
struct AngleCase {
  std::string surface;
  double angle_deg;
  bool zigzag;
};

class RasterAngleTest : public ::testing::TestWithParam<AngleCase> {};

TEST_P(RasterAngleTest, PassesLieInTheirPlanesAndMeetTheScallopTarget) {
  const AngleCase& param = GetParam();
  const auto analytic = recon::MakeReferenceSurface(param.surface);
  ASSERT_TRUE(analytic.ok());
  recon::FitReport report;
  const auto q = recon::FitAnalytic(*analytic.value(), 50, 50, {}, 0, 1, &report);
  ASSERT_TRUE(q.ok()) << q.status().message();
  ToolpathOptions o = Options();
  o.raster_angle_deg = param.angle_deg;
  o.zigzag = param.zigzag;
  const auto path = PlanRaster(*q, o);
  ASSERT_TRUE(path.ok()) << path.status().message();
  const double a = param.angle_deg * M_PI / 180;
  const Vector3d d(std::cos(a), std::sin(a), 0), m(-std::sin(a), std::cos(a), 0);

  // Per pass: one plane (CC·m constant), cut along +d or −d, leads at both ends.
  double previous_plane = -1e300;
  int reversed = 0, forward = 0;
  for (std::size_t k = 0; k < path->points.size();) {
    std::size_t end = k;
    while (end < path->points.size() && path->points[end].pass == path->points[k].pass) ++end;
    std::vector<const ClPoint*> cut;
    for (std::size_t i = k; i < end; ++i) {
      if (path->points[i].kind == ClKind::kCut) cut.push_back(&path->points[i]);
    }
    ASSERT_FALSE(cut.empty());
    EXPECT_EQ(path->points[k].kind, ClKind::kLeadIn);
    EXPECT_EQ(path->points[end - 1].kind, ClKind::kLeadOut);
    const double plane = cut.front()->cc.dot(m);
    for (const ClPoint* cl : cut) EXPECT_NEAR(cl->cc.dot(m), plane, 1e-9) << "pass " << cl->pass;
    EXPECT_GE(plane, previous_plane - 1e-9);
    previous_plane = plane;
    if (cut.size() > 2) {
      const double along = (cut.back()->cc - cut.front()->cc).dot(d);
      (along > 0 ? forward : reversed)++;
      // The lead-in arrives tangentially: its last chord is within 15° (one arc step) of the first cut chord.
      const Vector3d lead = (cut[0]->tip - path->points[cut[0] - &path->points[0] - 1].tip).normalized();
      const Vector3d first = (cut[1]->tip - cut[0]->tip).normalized();
      EXPECT_GT(lead.dot(first), std::cos(16.0 * M_PI / 180)) << "pass " << cut[0]->pass;
    }
    k = end;
  }
  EXPECT_GT(forward, 10);
  if (param.zigzag) {
    EXPECT_GT(reversed, 10);
  } else {
    EXPECT_EQ(reversed, 0);
  }

  const double dv = path->min_step_over_mm / 10;
  const CheckResult c = Check(*q, *path, 3, 4.0, 4.0, 0.05, dv, 1.0);
  std::printf(
      "[checker] %-18s angle %5.1f %-8s CL %6zu passes %4d  max scallop %.3f um  max gouge %.3f um  (%d "
      "samples, %d uncovered)\n",
      param.surface.c_str(), param.angle_deg, param.zigzag ? "zig-zag" : "one-way", path->points.size(), path->passes,
      c.max_scallop_um, c.max_gouge_um, c.samples, c.uncovered);
  EXPECT_EQ(c.uncovered, 0);
  EXPECT_LE(c.max_scallop_um, o.scallop_um + o.chord_tolerance_um);
  EXPECT_LE(c.max_gouge_um, 1.0);
  EXPECT_GT(c.max_scallop_um, 0.5 * o.scallop_um) << "the windows must catch scallop peaks";
}

INSTANTIATE_TEST_SUITE_P(Angles, RasterAngleTest,
                         ::testing::Values(AngleCase{"franke", 30, true}, AngleCase{"saddle", 45, false},
                                           AngleCase{"blade", 90, true}, AngleCase{"tilted_paraboloid", 60, true},
                                           AngleCase{"sphere_cap", 135, false}, AngleCase{"egg_box", -20, true}),
                         [](const ::testing::TestParamInfo<AngleCase>& case_info) {
                           return case_info.param.surface + "_" + std::to_string(static_cast<int>(case_info.index));
                         });

TEST(ToolpathOptionsTest, BadRasterAngleAndLeadAreRefusedNamingTheField) {
  const auto analytic = recon::MakeReferenceSurface("plane");
  recon::FitReport report;
  const auto q = recon::FitAnalytic(*analytic.value(), 10, 10, {}, 0, 1, &report);
  ASSERT_TRUE(q.ok());
  ToolpathOptions o = Options();
  o.raster_angle_deg = std::nan("");
  auto path = PlanRaster(*q, o);
  EXPECT_EQ(path.status().code(), StatusCode::kBadInput);
  EXPECT_NE(path.status().message().find("raster_angle_deg"), std::string::npos);
  o = Options();
  o.lead_mm = -1;
  path = PlanRaster(*q, o);
  EXPECT_EQ(path.status().code(), StatusCode::kBadInput);
  EXPECT_NE(path.status().message().find("lead_mm"), std::string::npos);
  // No leads: every point is a cut point.
  o = Options();
  o.lead_mm = 0;
  o.max_point_spacing_mm = 5;
  path = PlanRaster(*q, o);
  ASSERT_TRUE(path.ok());
  for (const ClPoint& cl : path->points) EXPECT_EQ(cl.kind, ClKind::kCut);
}

}  // namespace
}  // namespace formloop::nc
