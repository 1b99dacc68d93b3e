// Independent check of PlanRaster (spec/nc-gen.md §1-2): the machined surface is computed from the cutter
// locations alone and compared with the surface the planner was given.
//
// Checker (uses nothing of the planner but Toolpath::points[].centre and .pass): a 3-axis ball-end tool
// (vertical axis, radius r) sweeps a capsule between the ball centres of consecutive feed CLs of a pass
// (a single ball at each CL). The machined surface is the lower envelope of these capsules: at (x, y)
// its height is the minimum over the capsules of the capsule's lowest point on the vertical line
// through (x, y) (closed form: the two end balls and the lower root of the lateral cylinder). The
// surface Q is sampled on dense windows of its (u, v) grid; at each sample P = Q(u, v) with unit normal
// n, Δz = machined height − P.z, and the normal distance is Δz · n_z: scallop = max(Δz n_z, 0),
// gouge = max(−Δz n_z, 0). This holds for every surface that is a graph over the xy plane in space
// (n_z > 0 and a one-to-one projection), which covers all nine reference surfaces (blade and
// tilted_paraboloid are not graphs over (u, v), but are over (x, y)) and the concave bowl below.
// Capsules sit in a uniform xy hash (cell 1 mm) for speed.

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <limits>
#include <string>
#include <unordered_map>
#include <vector>

#include <gtest/gtest.h>

#include "nc-gen/toolpath.h"
#include "reconstruction/analytic_surface.h"
#include "reconstruction/bspline_surface.h"

namespace formloop::nc {
namespace {

using Eigen::Vector3d;

constexpr double kInf = std::numeric_limits<double>::infinity();

struct Capsule {
  Vector3d a, b;
};

// Lowest z of the capsule {p : dist(p, [a, b]) ≤ r} on the vertical line through (x, y); +inf if missed.
double CapsuleBottom(const Capsule& c, double r, double x, double y) {
  double best = kInf;
  for (const Vector3d* e : {&c.a, &c.b}) {
    const double dx = x - e->x(), dy = y - e->y();
    const double d2 = dx * dx + dy * dy;
    if (d2 <= r * r) best = std::min(best, e->z() - std::sqrt(r * r - d2));
  }
  const Vector3d ab = c.b - c.a;
  const double len = ab.norm();
  if (len < 1e-12) return best;
  const Vector3d w = ab / len;
  // Point P = (x, y, a.z + s): D = D0 + s ẑ with D0 = (x − a.x, y − a.y, 0).
  const Vector3d d0(x - c.a.x(), y - c.a.y(), 0);
  const Vector3d p0 = d0 - d0.dot(w) * w;
  const Vector3d pe = Vector3d::UnitZ() - w.z() * w;
  const double qa = pe.squaredNorm();
  if (qa < 1e-14) return best;  // vertical segment: the end balls cover it
  const double qb = 2 * p0.dot(pe), qc = p0.squaredNorm() - r * r;
  const double disc = qb * qb - 4 * qa * qc;
  if (disc < 0) return best;
  const double s = (-qb - std::sqrt(disc)) / (2 * qa);
  const double t = (d0 + s * Vector3d::UnitZ()).dot(w) / len;
  if (t >= 0 && t <= 1) best = std::min(best, c.a.z() + s);
  return best;
}

class MachinedSurface {
 public:
  MachinedSurface(const Toolpath& path, double r) : r_(r) {
    for (std::size_t k = 0; k < path.points.size(); ++k) {
      const Vector3d& c = path.points[k].centre;
      if (k > 0 && path.points[k - 1].pass == path.points[k].pass) {
        Add({path.points[k - 1].centre, c});
      } else {
        Add({c, c});
      }
    }
  }
  // Machined height at (x, y), +inf where no capsule reaches.
  double Height(double x, double y) const {
    const auto it = cells_.find(Key(Cell(x), Cell(y)));
    if (it == cells_.end()) return kInf;
    double z = kInf;
    for (int i : it->second) z = std::min(z, CapsuleBottom(capsules_[i], r_, x, y));
    return z;
  }

 private:
  static constexpr double kCell = 1.0;
  static long long Cell(double v) { return static_cast<long long>(std::floor(v / kCell)); }
  static long long Key(long long i, long long j) { return i * 1000003LL + j; }
  void Add(const Capsule& c) {
    const int id = static_cast<int>(capsules_.size());
    capsules_.push_back(c);
    const long long i0 = Cell(std::min(c.a.x(), c.b.x()) - r_), i1 = Cell(std::max(c.a.x(), c.b.x()) + r_);
    const long long j0 = Cell(std::min(c.a.y(), c.b.y()) - r_), j1 = Cell(std::max(c.a.y(), c.b.y()) + r_);
    for (long long i = i0; i <= i1; ++i) {
      for (long long j = j0; j <= j1; ++j) cells_[Key(i, j)].push_back(id);
    }
  }
  double r_;
  std::vector<Capsule> capsules_;
  std::unordered_map<long long, std::vector<int>> cells_;
};

struct CheckResult {
  double max_scallop_um = 0, max_gouge_um = 0;
  int samples = 0, uncovered = 0;
};

// Samples Q on `windows` × `windows` parameter windows of size win_u × win_v spread over the domain (kept
// `margin` inside its edges), spacing du × dv, and compares with the machined surface.
CheckResult Check(const recon::BSplineSurface& q, const Toolpath& path, int windows, double win_u, double win_v,
                  double du, double dv, double margin) {
  const MachinedSurface machined(path, path.options.tool.radius_mm);
  const recon::ParamDomain dom = q.domain();
  CheckResult out;
  for (int wi = 0; wi < windows; ++wi) {
    for (int wj = 0; wj < windows; ++wj) {
      const double fu = windows == 1 ? 0.5 : static_cast<double>(wi) / (windows - 1);
      const double fv = windows == 1 ? 0.5 : static_cast<double>(wj) / (windows - 1);
      const double u0 = dom.u_min + margin + fu * (dom.u_span() - 2 * margin - win_u);
      const double v0 = dom.v_min + margin + fv * (dom.v_span() - 2 * margin - win_v);
      for (double v = v0; v <= v0 + win_v; v += dv) {
        for (double u = u0; u <= u0 + win_u; u += du) {
          const Vector3d p = q.Point(u, v);
          const Vector3d n = q.Normal(u, v);
          const double z = machined.Height(p.x(), p.y());
          ++out.samples;
          if (!std::isfinite(z)) {
            ++out.uncovered;
            continue;
          }
          const double normal_um = (z - p.z()) * n.z() * 1e3;
          out.max_scallop_um = std::max(out.max_scallop_um, normal_um);
          out.max_gouge_um = std::max(out.max_gouge_um, -normal_um);
        }
      }
    }
  }
  return out;
}

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
  std::printf("[checker] %-18s CL %6zu passes %4d step-over %.4f..%.4f mm  max scallop %.3f um  max gouge %.3f um"
              "  (%d samples, %d uncovered) lifted %d\n",
              GetParam().c_str(), path->points.size(), path->passes, path->min_step_over_mm, path->max_step_over_mm,
              c.max_scallop_um, c.max_gouge_um, c.samples, c.uncovered, path->lifted_points);
  EXPECT_EQ(c.uncovered, 0);
  EXPECT_LE(c.max_scallop_um, o.scallop_um + o.chord_tolerance_um);
  EXPECT_LE(c.max_gouge_um, 1.0);
  EXPECT_GT(c.max_scallop_um, 0.5 * o.scallop_um) << "the windows must catch scallop peaks";
  EXPECT_EQ(path->gouge_risk_points, 0);
  EXPECT_EQ(path->lifted_points, 0);
  if (GetParam() == "egg_box" || GetParam() == "franke") {
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
  std::printf("[checker] bowl R=2: CL %zu passes %d gouge-risk %d lifted %d (max lift %.4f mm, box x %.2f..%.2f y "
              "%.2f..%.2f)  max gouge %.3f um  max material left %.1f um (%d samples)\n",
              path->points.size(), path->passes, path->gouge_risk_points, path->lifted_points, path->max_lift_mm,
              path->lifted_box_min.x(), path->lifted_box_max.x(), path->lifted_box_min.y(),
              path->lifted_box_max.y(), c.max_gouge_um, c.max_scallop_um, c.samples);
  EXPECT_EQ(c.uncovered, 0);
  EXPECT_LE(c.max_gouge_um, 1.0);
  const nlohmann::json j = path->ReportJson();
  EXPECT_EQ(j.at("lifted_points").get<int>(), path->lifted_points);
}

}  // namespace
}  // namespace formloop::nc
