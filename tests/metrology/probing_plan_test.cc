// Curvature-weighted probing plans (spec/nc-gen.md §5): count and ids, points on Q inside the inset
// domain, denser points where Q is curved, near-uniform spacing at weight 0, determinism, bad input.

#include <algorithm>
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <cstdio>
#include <limits>
#include <set>
#include <string>
#include <vector>

#include <gtest/gtest.h>
#include <Eigen/Core>

#include "core/log.h"
#include "metrology/probe.h"
#include "metrology/probing_plan.h"
#include "reconstruction/analytic_surface.h"
#include "reconstruction/bspline_surface.h"

namespace formloop::metrology {
namespace {

using Eigen::Vector3d;

// A Gaussian bump on a flat plate: z = h·exp(−r²/(2s²)), h = 2 mm, s = 1.5 mm on [−10, 10]² mm.
// Curved for r ≲ 3 mm (κ = h/s² ≈ 0.89/mm at the top), flat (κ < 1e-3/mm) beyond r ≈ 6 mm.
class Bump final : public recon::AnalyticSurface {
 public:
  std::string name() const override { return "bump"; }
  std::string description() const override { return "z = 2 exp(-(x^2 + y^2)/(2 * 1.5^2))"; }
  recon::ParamDomain domain() const override { return {-10, 10, -10, 10}; }
  bool is_graph() const override { return true; }
  recon::SurfaceDerivatives Derivatives(double x, double y) const override {
    const double s2 = kS * kS;
    const double f = kH * std::exp(-(x * x + y * y) / (2 * s2));
    const double fx = -x / s2 * f, fy = -y / s2 * f;
    const double fxx = (x * x / s2 - 1) / s2 * f, fyy = (y * y / s2 - 1) / s2 * f, fxy = x * y / (s2 * s2) * f;
    recon::SurfaceDerivatives d;
    d.p = Vector3d(x, y, f);
    d.su = Vector3d(1, 0, fx);
    d.sv = Vector3d(0, 1, fy);
    d.suu = Vector3d(0, 0, fxx);
    d.suv = Vector3d(0, 0, fxy);
    d.svv = Vector3d(0, 0, fyy);
    return d;
  }
  static constexpr double kH = 2.0, kS = 1.5;
};

class ProbingPlanTest : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    log::SetLevel(log::Level::kError);
    recon::FitReport report;
    auto fitted = recon::FitAnalytic(Bump(), 41, 41, {}, 0, 1, &report);
    ASSERT_TRUE(fitted.ok()) << fitted.status().message();
    q_ = new recon::BSplineSurface(*fitted);
  }
  static void TearDownTestSuite() {
    delete q_;
    q_ = nullptr;
  }
  static const recon::BSplineSurface& Q() { return *q_; }

  // Number of plan points within `radius` (in x, y) of the bump's centre.
  static int CountNearCentre(const ProbingPlan& plan, double radius) {
    int n = 0;
    for (const ProbePoint& p : plan.points) n += std::hypot(p.point.x(), p.point.y()) < radius ? 1 : 0;
    return n;
  }
  // 3-D nearest-neighbour distance of every plan point.
  static std::vector<double> NearestNeighbourDistances(const ProbingPlan& plan) {
    std::vector<double> d(plan.points.size(), std::numeric_limits<double>::infinity());
    for (std::size_t i = 0; i < plan.points.size(); ++i) {
      for (std::size_t j = 0; j < plan.points.size(); ++j) {
        if (i != j) d[i] = std::min(d[i], (plan.points[i].point - plan.points[j].point).norm());
      }
    }
    return d;
  }
  static double CoefficientOfVariation(const std::vector<double>& x) {
    double mean = 0;
    for (double v : x) mean += v;
    mean /= static_cast<double>(x.size());
    double var = 0;
    for (double v : x) var += (v - mean) * (v - mean);
    var /= static_cast<double>(x.size());
    return std::sqrt(var) / mean;
  }

  static recon::BSplineSurface* q_;
};

recon::BSplineSurface* ProbingPlanTest::q_ = nullptr;

TEST_F(ProbingPlanTest, CountIdsAndPointsOnQInsideTheInsetDomain) {
  constexpr double kInset = 0.1;
  for (int count : {1, 2, 7, 50, 200}) {
    const auto plan = PlanProbingCurvatureWeighted(Q(), count, kInset, 1.0);
    ASSERT_TRUE(plan.ok()) << plan.status().message();
    ASSERT_EQ(static_cast<int>(plan->points.size()), count);
    std::set<std::int64_t> ids;
    const recon::ParamDomain dom = Q().domain();
    for (std::size_t i = 0; i < plan->points.size(); ++i) {
      const ProbePoint& p = plan->points[i];
      EXPECT_EQ(p.id, static_cast<std::int64_t>(i) + 1);  // 1..count in selection order
      ids.insert(p.id);
      EXPECT_GE(p.u, dom.u_min + kInset * dom.u_span() - 1e-12);
      EXPECT_LE(p.u, dom.u_max - kInset * dom.u_span() + 1e-12);
      EXPECT_GE(p.v, dom.v_min + kInset * dom.v_span() - 1e-12);
      EXPECT_LE(p.v, dom.v_max - kInset * dom.v_span() + 1e-12);
      EXPECT_LT((Q().Point(p.u, p.v) - p.point).norm(), 1e-9);
      EXPECT_LT((Q().Normal(p.u, p.v) - p.normal).norm(), 1e-12);
      EXPECT_NEAR(p.normal.norm(), 1.0, 1e-12);
    }
    EXPECT_EQ(static_cast<int>(ids.size()), count);
    EXPECT_EQ(*ids.begin(), 1);
    EXPECT_EQ(*ids.rbegin(), count);
  }
}

TEST_F(ProbingPlanTest, FirstPointIsTheMostCurvedCandidate) {
  // The bump's top (0, 0) has the largest |κ1| + |κ2|. 20 points: 800 candidates, a 28 × 28 grid over
  // [−9, 9]² with step 2/3 mm, whose nodes nearest the top are (±1/3, ±1/3), 0.471 mm away.
  const auto plan = PlanProbingCurvatureWeighted(Q(), 20, 0.05, 1.0);
  ASSERT_TRUE(plan.ok()) << plan.status().message();
  EXPECT_LT(std::hypot(plan->points[0].u, plan->points[0].v), 0.48);
}

TEST_F(ProbingPlanTest, CurvedRegionGetsDenserPointsThanAtWeightZero) {
  constexpr int kCount = 100;
  constexpr double kRadius = 3.0;  // the curved region: r < 2 s
  // The disc r < 3 mm covers ≈ 9 % of the inset plate [−9, 9]² in (x, y) (28.3 of 324 mm², a little
  // more on Q, where the bump's slope adds area), so at weight 0 it holds about a tenth of the points.
  // Measured (100 points): 13 at weight 0, 31 at weight 1 (ratio 2.38), 42 at weight 3 (ratio 3.23).
  const auto uniform = PlanProbingCurvatureWeighted(Q(), kCount, 0.05, 0.0);
  const auto weighted = PlanProbingCurvatureWeighted(Q(), kCount, 0.05, 1.0);
  const auto strong = PlanProbingCurvatureWeighted(Q(), kCount, 0.05, 3.0);
  ASSERT_TRUE(uniform.ok()) << uniform.status().message();
  ASSERT_TRUE(weighted.ok()) << weighted.status().message();
  ASSERT_TRUE(strong.ok()) << strong.status().message();
  const int n_uniform = CountNearCentre(*uniform, kRadius);
  const int n_weighted = CountNearCentre(*weighted, kRadius);
  const int n_strong = CountNearCentre(*strong, kRadius);
  const double ratio = static_cast<double>(n_weighted) / std::max(n_uniform, 1);
  const double ratio_strong = static_cast<double>(n_strong) / std::max(n_uniform, 1);
  std::printf(
      "[probing plan] bump, %d points within r < %.1f mm: %d at weight 0, %d at weight 1 (ratio %.2f), "
      "%d at weight 3 (ratio %.2f)\n",
      kCount, kRadius, n_uniform, n_weighted, ratio, n_strong, ratio_strong);
  EXPECT_GE(n_uniform, 8);
  EXPECT_LE(n_uniform, 16);
  EXPECT_GE(ratio, 2.0);
  EXPECT_GT(n_strong, n_weighted);
}

// Farthest-point sampling keeps every nearest-neighbour distance between the final covering radius
// and about twice it, so the spread is small. Measured CV: 0.172 (50 points), 0.172 (100), 0.115
// (200); for comparison, independent uniformly random points give the Rayleigh value
// sqrt(4/π − 1) ≈ 0.52. The bound 0.2 sits just above the largest measured value.
TEST_F(ProbingPlanTest, WeightZeroGivesNearUniformSpacing) {
  for (int count : {50, 100, 200}) {
    const auto plan = PlanProbingCurvatureWeighted(Q(), count, 0.05, 0.0);
    ASSERT_TRUE(plan.ok()) << plan.status().message();
    const std::vector<double> nn = NearestNeighbourDistances(*plan);
    const double cv = CoefficientOfVariation(nn);
    std::printf("[probing plan] bump, weight 0, %d points: nearest-neighbour CV %.3f\n", count, cv);
    EXPECT_LT(cv, 0.2);
  }
}

TEST_F(ProbingPlanTest, Deterministic) {
  const auto a = PlanProbingCurvatureWeighted(Q(), 80, 0.05, 2.0);
  const auto b = PlanProbingCurvatureWeighted(Q(), 80, 0.05, 2.0);
  ASSERT_TRUE(a.ok() && b.ok());
  EXPECT_EQ(a->ToJson().dump(), b->ToJson().dump());
}

TEST_F(ProbingPlanTest, BadInputIsRefusedNamingTheField) {
  struct Case {
    int count;
    double inset;
    double weight;
    const char* field;
  };
  const double nan = std::numeric_limits<double>::quiet_NaN();
  for (const Case& c :
       {Case{0, 0.05, 1.0, "probing.count"}, Case{-3, 0.05, 1.0, "probing.count"},
        Case{kMaxProbingCandidates + 1, 0.05, 1.0, "probing.count"}, Case{10, -0.01, 1.0, "probing.inset_fraction"},
        Case{10, 0.45, 1.0, "probing.inset_fraction"}, Case{10, nan, 1.0, "probing.inset_fraction"},
        Case{10, 0.05, -0.5, "probing.curvature_weight"}, Case{10, 0.05, nan, "probing.curvature_weight"}}) {
    const auto plan = PlanProbingCurvatureWeighted(Q(), c.count, c.inset, c.weight);
    ASSERT_FALSE(plan.ok()) << c.field;
    EXPECT_EQ(plan.status().code(), StatusCode::kBadInput) << c.field;
    EXPECT_NE(plan.status().message().find(c.field), std::string::npos) << plan.status().message();
  }
  EXPECT_FALSE(PlanProbingCurvatureWeighted(recon::BSplineSurface(), 10, 0.05, 1.0).ok());
  EXPECT_TRUE(PlanProbingCurvatureWeighted(Q(), 10, 0.449, 0.0).ok());
}

}  // namespace
}  // namespace formloop::metrology
