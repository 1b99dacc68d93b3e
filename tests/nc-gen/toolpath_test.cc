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

#include <fmt/format.h>
#include <gtest/gtest.h>
#include <GeomConvert.hxx>
#include <Geom_BSplineSurface.hxx>
#include <Geom_CylindricalSurface.hxx>
#include <Geom_RectangularTrimmedSurface.hxx>
#include <TColStd_Array1OfInteger.hxx>
#include <TColStd_Array1OfReal.hxx>
#include <TColgp_Array2OfPnt.hxx>
#include <gp_Ax3.hxx>
#include <gp_Pnt.hxx>

#include "nc-gen/cutter_locations.h"
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
  EXPECT_EQ(path->UncutRegionText(), "");
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
  // The warning `formloop run` and `nc path` give: the counts, the ball and the box of the lifted region.
  const std::string uncut = path->UncutRegionText();
  for (const std::string& part :
       {std::to_string(path->lifted_points) + " CL points are lifted", std::string("ball radius (3 mm)"),
        fmt::format("x {:.2f} to", path->lifted_box_min.x()), std::string("left uncut")}) {
    EXPECT_NE(uncut.find(part), std::string::npos) << part << " in: " << uncut;
  }

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

  // Per raster pass: one plane (CC·m constant), cut along +d or −d, leads at both ends. The boundary
  // contour (edges met at a slant) comes last, on no plane.
  double previous_plane = -1e300;
  int reversed = 0, forward = 0;
  for (std::size_t k = 0; k < path->points.size();) {
    std::size_t end = k;
    while (end < path->points.size() && path->points[end].pass == path->points[k].pass) ++end;
    if (path->points[k].pass >= path->passes - path->contour_passes) break;
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

// A first or last plane that runs along a straight edge of the domain is one pass along the whole edge,
// also when S·m varies along that edge by rounding, as on a CAD face whose poles were written in
// decimals (here the boundary poles moved by ±3e-14 mm, two units in the last place of 100). Before the
// planner counted samples within 1e-9 mm of the plane as on it, only the samples exactly on the extreme
// plane were, and the edge's pass shrank to one point or to pieces between them.
TEST(ToolpathEdgeTest, ThePlaneAlongAnEdgeWithRoundingIsOnePassAlongTheWholeEdge) {
  const auto analytic = recon::MakeReferenceSurface("egg_box");
  ASSERT_TRUE(analytic.ok());
  recon::FitReport report;
  const auto fitted = recon::FitAnalytic(*analytic.value(), 30, 30, {}, 0, 1, &report);
  ASSERT_TRUE(fitted.ok());
  Handle(Geom_BSplineSurface) geom = Handle(Geom_BSplineSurface)::DownCast(fitted->geom()->Copy());
  const int nu = geom->NbUPoles(), nv = geom->NbVPoles();
  for (int j = 1; j <= nv; ++j) {
    for (int i = 1; i <= nu; ++i) {
      if (i != 1 && i != nu && j != 1 && j != nv) continue;
      gp_Pnt p = geom->Pole(i, j);
      const double wiggle = ((i + j) % 2 == 0 ? 3e-14 : -3e-14);
      if (j == 1 || j == nv) p.SetY(p.Y() + wiggle);
      if (i == 1 || i == nu) p.SetX(p.X() + wiggle);
      geom->SetPole(i, j, p);
    }
  }
  const recon::BSplineSurface q(geom);
  const recon::ParamDomain dom = q.domain();
  for (const double angle : {0.0, 90.0}) {
    SCOPED_TRACE("raster angle " + std::to_string(angle));
    ToolpathOptions o = Options();
    o.raster_angle_deg = angle;
    o.max_point_spacing_mm = 2;
    const auto path = PlanRaster(q, o);
    ASSERT_TRUE(path.ok()) << path.status().ToString();
    // The cut points' extent along the edge (x for planes of constant y, y for planes of constant x).
    const auto along = [&](const ClPoint& cl) { return angle == 0.0 ? cl.cc.x() : cl.cc.y(); };
    const double lo = angle == 0.0 ? dom.u_min : dom.v_min, hi = angle == 0.0 ? dom.u_max : dom.v_max;
    for (const int pass : {0, path->passes - 1}) {
      double first = 1e300, last = -1e300;
      int cuts = 0;
      for (const ClPoint& cl : path->points) {
        if (cl.pass != pass || cl.kind != ClKind::kCut) continue;
        first = std::min(first, along(cl));
        last = std::max(last, along(cl));
        ++cuts;
      }
      EXPECT_GT(cuts, 20) << "pass " << pass;
      EXPECT_NEAR(first, lo, 1e-6) << "pass " << pass;
      EXPECT_NEAR(last, hi, 1e-6) << "pass " << pass;
    }
  }
}

// A 3-axis ball-end job cuts Q from above. A face whose normal (away from the material) points down is
// refused before any section is traced, and so is a face that folds over part of it, naming where; before
// this check the first was planned under the face (exit 0, no warning) and the second failed part-way
// with an internal error.
recon::BSplineSurface FoldedSurface(double wiggle) {
  // x(t) = 60 t − wiggle · sin(2π t) over t ∈ [0, 1]: where x decreases with u, n_z < 0.
  recon::GridSamples g;
  g.nu = 25;
  g.nv = 13;
  g.domain = {0, 60, 0, 60};
  for (int j = 0; j < g.nv; ++j) {
    for (int i = 0; i < g.nu; ++i) {
      const double t = static_cast<double>(i) / (g.nu - 1);
      g.points.emplace_back(60 * t - wiggle * std::sin(2 * M_PI * t), 60.0 * j / (g.nv - 1), 10 + 3 * t);
    }
  }
  recon::FitReport report;
  auto q = recon::FitGrid(g, recon::GridFitOptions{}, &report);
  EXPECT_TRUE(q.ok()) << q.status().ToString();
  return *q;
}

TEST(ToolpathFacingTest, AFaceThatFacesDownIsRefused) {
  const auto analytic = recon::MakeReferenceSurface("egg_box");
  ASSERT_TRUE(analytic.ok());
  recon::FitReport report;
  const auto fitted = recon::FitAnalytic(*analytic.value(), 20, 20, {}, 0, 1, &report);
  ASSERT_TRUE(fitted.ok());
  ASSERT_TRUE(PlanRaster(*fitted, Options()).ok());
  Handle(Geom_BSplineSurface) turned = Handle(Geom_BSplineSurface)::DownCast(fitted->geom()->Copy());
  turned->UReverse();  // the same points, the normal into what was the air side
  const auto path = PlanRaster(recon::BSplineSurface(turned), Options());
  ASSERT_EQ(path.status().code(), StatusCode::kBadInput) << path.status().ToString();
  EXPECT_NE(path.status().message().find("surface"), std::string::npos) << path.status().message();
  EXPECT_NE(path.status().message().find("Q faces down"), std::string::npos) << path.status().message();
  EXPECT_NE(path.status().message().find("\"reverse\": true"), std::string::npos) << path.status().message();
}

TEST(ToolpathFacingTest, AFaceThatFoldsOverIsRefusedNamingWhere) {
  // A plain graph (wiggle 5: x increases everywhere) is planned ...
  ASSERT_TRUE(PlanRaster(FoldedSurface(5), Options()).ok());
  // ... a fold over about a quarter of the face (dx/dt < 0 where cos 2πt > 60 / (30 π)) is refused.
  const auto path = PlanRaster(FoldedSurface(15), Options());
  ASSERT_EQ(path.status().code(), StatusCode::kBadInput) << path.status().ToString();
  const std::string& m = path.status().message();
  EXPECT_NE(m.find("turns under itself"), std::string::npos) << m;
  EXPECT_NE(m.find(" mm at (u, v) = ("), std::string::npos) << m;
  EXPECT_NE(m.find("--list-faces"), std::string::npos) << m;
}

// A separating experiment's next part planned at a raster angle Q cannot be cut at is not proposed, with
// the reason; the diagnosis goes on (before, the planner's error aborted `formloop diagnose` and the
// run's diagnosis).
TEST(ToolpathFacingTest, ANextPartThatCannotBePlannedIsSkippedWithTheReason) {
  std::string skipped;
  const auto cls = ReplannedCutterLocations(FoldedSurface(15), Options(), 90, 0.5, &skipped);
  ASSERT_TRUE(cls.ok()) << cls.status().ToString();
  EXPECT_TRUE(cls->empty());
  EXPECT_NE(skipped.find("raster angle 90.0 deg, feed x 0.50"), std::string::npos) << skipped;
  EXPECT_NE(skipped.find("turns under itself"), std::string::npos) << skipped;
  skipped.clear();
  const auto fine = ReplannedCutterLocations(FoldedSurface(5), Options(), 90, 1, &skipped);
  ASSERT_TRUE(fine.ok());
  EXPECT_FALSE(fine->empty());
  EXPECT_TRUE(skipped.empty()) << skipped;
}

// A face narrower than a step-over across the planes, whose outline meets the first and the last plane
// only at corners (a flat parallelogram 10 mm long, 0.3 mm across the planes; the step-over is 0.35
// mm): one pass half-way between them. Before, the first and last planes touched a corner each, two
// one-point passes, and nothing between them was cut.
TEST(ToolpathEdgeTest, AFaceNarrowerThanAStepOverGetsAPassAcrossIt) {
  TColgp_Array2OfPnt poles(1, 2, 1, 2);
  poles(1, 1) = gp_Pnt(0, 0, 0);
  poles(2, 1) = gp_Pnt(10, 0.1, 0);
  poles(1, 2) = gp_Pnt(0, 0.2, 0);
  poles(2, 2) = gp_Pnt(10, 0.3, 0);
  TColStd_Array1OfReal knots(1, 2);
  knots(1) = 0;
  knots(2) = 1;
  TColStd_Array1OfInteger mults(1, 2);
  mults(1) = mults(2) = 2;
  const recon::BSplineSurface q(new Geom_BSplineSurface(poles, knots, knots, mults, mults, 1, 1));
  const ToolpathOptions o = Options();
  const auto path = PlanRaster(q, o);
  ASSERT_TRUE(path.ok()) << path.status().ToString();
  int cuts = 0;
  for (const ClPoint& cl : path->points) cuts += cl.kind == ClKind::kCut;
  EXPECT_GT(cuts, 20);
  // Every point of the strip within the scallop target of what the ball leaves (0.15 mm from the pass at
  // the far corners: 0.15² / (2 · 3) mm = 3.75 µm).
  const CheckResult c = Check(q, *path, 1, 1.0, 1.0, 0.005, 0.02, 0.0);
  std::printf("[checker] strip 10 x 0.3 mm: %d passes, %d cut points, max scallop %.2f um, max gouge %.3f um\n",
              path->passes, cuts, c.max_scallop_um, c.max_gouge_um);
  EXPECT_EQ(c.uncovered, 0);
  EXPECT_LE(c.max_scallop_um, o.scallop_um + o.chord_tolerance_um);
  EXPECT_LE(c.max_gouge_um, 1.0);
}

// The edges and corners of Q keep the scallop target at any raster angle. Where the passes meet an edge
// at a slant, neighbouring pass ends lie farther apart along it than the step-over and the first and last
// planes only touch corners: one contour pass along the parameter box's boundary. Checked in the four
// corner windows (3 × 3 mm, no margin). Before it (main of 2026-11-28), 5 µm target + 1 µm chord: franke
// 8.59 µm at 30°, 6.86 at 45°; sphere cap 10.90 and 9.45 µm.
TEST(ToolpathEdgeTest, EdgesMetAtASlantKeepTheScallopTarget) {
  for (const char* name : {"franke", "sphere_cap"}) {
    for (const double angle : {0.0, 30.0, 45.0}) {
      SCOPED_TRACE(std::string(name) + " at " + std::to_string(angle) + " deg");
      const auto analytic = recon::MakeReferenceSurface(name);
      ASSERT_TRUE(analytic.ok());
      recon::FitReport report;
      const auto q = recon::FitAnalytic(*analytic.value(), 50, 50, {}, 0, 1, &report);
      ASSERT_TRUE(q.ok());
      ToolpathOptions o = Options();
      o.raster_angle_deg = angle;
      const auto path = PlanRaster(*q, o);
      ASSERT_TRUE(path.ok()) << path.status().message();
      const CheckResult c = Check(*q, *path, 2, 3.0, 3.0, 0.02, path->min_step_over_mm / 10, 0.0);
      std::printf("[checker] %-10s angle %4.0f: %d passes, %d contour, corners: max scallop %.2f um, gouge %.2f um\n",
                  name, angle, path->passes, path->contour_passes, c.max_scallop_um, c.max_gouge_um);
      EXPECT_EQ(path->contour_passes, angle == 0.0 ? 0 : 1);
      EXPECT_EQ(path->boundary_contour, angle != 0.0);
      EXPECT_EQ(path->ReportJson().contains("boundary_contour"), angle != 0.0);
      EXPECT_EQ(c.uncovered, 0);
      EXPECT_LE(c.max_scallop_um, o.scallop_um + o.chord_tolerance_um);
      EXPECT_LE(c.max_gouge_um, 1.0);
    }
  }
}

// Q tangent to the first plane: a half cylinder lying along x (radius 10 mm), its edges vertical, so along
// the first and last planes (y = ∓10) the normal is along m and no point of them bounds the step. The
// next plane comes a little further, and the passes cover the cylinder. Before, the first plane set no
// bound and the next one went as far as the planes allowed: the cylinder between its first edge and the
// middle was not cut (bands y = −9 to 0 mm empty), exit 0; on OCCT's hammer.iges face 9, 2,989 mm
// across, the next plane was the last: two one-point passes.
TEST(ToolpathEdgeTest, AFaceTangentToTheFirstPlaneIsCutAcross) {
  const Handle(Geom_CylindricalSurface) cylinder =
      new Geom_CylindricalSurface(gp_Ax3(gp_Pnt(0, 0, 0), gp_Dir(1, 0, 0), gp_Dir(0, 1, 0)), 10.0);
  const Handle(Geom_RectangularTrimmedSurface) half =
      new Geom_RectangularTrimmedSurface(cylinder, 0.0, M_PI, 0.0, 20.0);
  const recon::BSplineSurface q(GeomConvert::SurfaceToBSplineSurface(half));
  ASSERT_GT(q.Derivatives(0.5 * M_PI, 10).p.z(), 9.9) << "the cylinder's top is up";
  ToolpathOptions o = Options();
  const auto path = PlanRaster(q, o);
  ASSERT_TRUE(path.ok()) << path.status().ToString();
  // A flat step-over is 0.35 mm: at least 20 / 0.35 planes across y ∈ [−10, 10], and every 1 mm band of
  // y holds cut points.
  EXPECT_GT(path->passes, 57);
  std::vector<int> band(20, 0);
  for (const ClPoint& cl : path->points) {
    if (cl.kind == ClKind::kCut) ++band[static_cast<std::size_t>(std::clamp(cl.cc.y() + 10.0, 0.0, 19.999))];
  }
  for (std::size_t b = 0; b < band.size(); ++b) EXPECT_GT(band[b], 0) << "y band " << b;
  std::printf("[measured] half cylinder r = 10 mm: %d passes, %d contour\n", path->passes, path->contour_passes);
}

}  // namespace
}  // namespace formloop::nc
