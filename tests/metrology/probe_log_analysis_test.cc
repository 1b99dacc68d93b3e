// The one analysis of a probe log (metrology/probe_log_analysis.h): on a synthetic log over the saddle
// (a smooth field along the normal plus seeded noise), far points and points past the edge of Q are
// flagged and left out, the per-point table has its one set of names with d = d_s + d_f + d_u at every
// point, its lag and local Moran columns are those of the statistics computed directly, and a log with
// an id the plan does not have is refused naming the id.

#include "metrology/probe_log_analysis.h"

#include <cmath>
#include <memory>
#include <string>
#include <vector>

#include <gtest/gtest.h>

#include "core/log.h"
#include "core/random.h"
#include "reconstruction/analytic_surface.h"

namespace formloop::metrology {
namespace {

constexpr double kBallMm = 1.0;

struct Scene {
  recon::BSplineSurface q;
  ProbingPlan plan;
  ProbeLog log;
};

// 20 × 20 planned points; each contact point lies `field + noise` along the normal of Q, the ball centre
// one radius further out, approached along −n. `far_id` (if > 0) is moved 3 mm off the surface.
Scene MakeScene(std::int64_t far_id) {
  Scene s;
  auto reference = recon::MakeReferenceSurface("saddle");
  EXPECT_TRUE(reference.ok());
  recon::FitReport report;
  auto q = recon::FitAnalytic(**reference, 41, 41, {}, 0, 1, &report);
  EXPECT_TRUE(q.ok());
  s.q = std::move(q).value();
  auto plan = PlanProbingGrid(s.q, 20, 20, 0.05);
  EXPECT_TRUE(plan.ok());
  s.plan = std::move(plan).value();
  const recon::ParamDomain d = s.q.domain();
  Rng rng(42);
  for (const ProbePoint& p : s.plan.points) {
    const double x = (p.u - d.u_min) / d.u_span(), y = (p.v - d.v_min) / d.v_span();
    double deviation_mm = 1e-3 * (8 * x * x - 5 * y + 3 * std::sin(3 * x) * y) + 1e-3 * rng.Normal();
    if (p.id == far_id) deviation_mm = 3.0;
    ProbeRecord r;
    r.id = p.id;
    r.approach = -p.normal;
    r.centre = p.point + (deviation_mm + kBallMm) * p.normal;
    r.t_s = static_cast<double>(p.id);
    r.line = p.id + 1;
    s.log.records.push_back(r);
  }
  s.log.source = "synthetic.csv";
  return s;
}

ProbeLogAnalysisOptions Options() {
  ProbeLogAnalysisOptions o;
  o.decomposition.tolerance_mm = 0.010;
  o.lisa_permutations = 99;
  o.lisa_seed = 7;
  return o;
}

TEST(ProbeLogAnalysisTest, FlagsTheFarPointAndGivesOneConsistentTable) {
  log::SetLevel(log::Level::kError);
  const Scene s = MakeScene(/*far_id=*/57);
  const ProbeModel probe{.ball_radius_mm = kBallMm};
  auto a = AnalyseProbeLog(s.q, s.log, probe, &s.plan, Options());
  ASSERT_TRUE(a.ok()) << a.status().ToString();
  EXPECT_EQ(a->records, 400u);
  ASSERT_EQ(a->flagged.size(), 1u);
  EXPECT_EQ(a->flagged[0].id, 57);
  EXPECT_EQ(a->flagged[0].line, 58);
  EXPECT_NE(a->flagged[0].reason.find("search distance"), std::string::npos);
  EXPECT_TRUE(a->not_measured.empty());
  ASSERT_EQ(a->deviations.size(), 399u);
  ASSERT_TRUE(a->decomposition.evaluation.has_value());
  EXPECT_EQ(a->DeviationSummaryJson()["n_flagged"], 1);

  const PointSet table = a->PerPointTable();
  std::vector<std::string> names;
  for (const auto& column : table.scalars) names.push_back(column.name);
  const std::vector<std::string> expected = {"u",
                                             "v",
                                             "foot_x",
                                             "foot_y",
                                             "foot_z",
                                             "deviation_um",
                                             "on_boundary",
                                             "systematic_um",
                                             "fine_scale_um",
                                             "random_um",
                                             "lag_um",
                                             "lisa_cluster",
                                             "local_moran",
                                             "local_moran_random",
                                             "lisa_cluster_random"};
  EXPECT_EQ(names, expected);
  EXPECT_EQ(ProbeLogAnalysis::PerPointColumns().size(), expected.size());
  const auto& d = *table.FindScalar("deviation_um");
  const auto& ds = *table.FindScalar("systematic_um");
  const auto& df = *table.FindScalar("fine_scale_um");
  const auto& du = *table.FindScalar("random_um");
  for (std::size_t i = 0; i < d.size(); ++i) EXPECT_NEAR(d[i], ds[i] + df[i] + du[i], 1e-9) << i;

  // lag_um: Σ_j w_ij (d_j − mean d) on the k-NN weights in (u, v), computed here from the weights.
  auto w = UvKnnWeights(a->deviations, Options().decomposition.neighbours);
  ASSERT_TRUE(w.ok());
  double mean = 0;
  for (double x : d) mean += x;
  mean /= static_cast<double>(d.size());
  const auto& lag = *table.FindScalar("lag_um");
  for (int i = 0; i < w->w.outerSize(); ++i) {
    double sum = 0;
    for (Eigen::SparseMatrix<double, Eigen::RowMajor>::InnerIterator it(w->w, i); it; ++it) {
      sum += it.value() * (d[static_cast<std::size_t>(it.col())] - mean);
    }
    EXPECT_NEAR(lag[static_cast<std::size_t>(i)], sum, 1e-9) << i;
  }
  // local_moran: the LISA of the deviations itself; the field clusters the deviations.
  const auto& lm = *table.FindScalar("local_moran");
  for (std::size_t i = 0; i < lm.size(); ++i) EXPECT_DOUBLE_EQ(lm[i], a->lisa.i[static_cast<long>(i)]);
  EXPECT_GT(a->decomposition.raw.z_normality, 2.326);
  ASSERT_TRUE(a->lisa_random.has_value());
  EXPECT_EQ(a->LisaRandomJson()["n"], 399);
}

TEST(ProbeLogAnalysisTest, WithoutAPlanAPointPastTheEdgeIsFlagged) {
  log::SetLevel(log::Level::kError);
  Scene s = MakeScene(/*far_id=*/0);
  // Record 1 (a corner of the plan) moved 0.4 mm beyond the edge of Q in x, within 1 mm of Q's
  // boundary curve in height: its foot point is held at the boundary.
  const recon::ParamDomain dom = s.q.domain();
  const Eigen::Vector3d corner = s.q.Point(dom.u_min, dom.v_min);
  s.log.records[0].centre = corner + Eigen::Vector3d(-0.4, 0, 0) + kBallMm * s.q.Normal(dom.u_min, dom.v_min);
  s.log.records[0].approach = -s.q.Normal(dom.u_min, dom.v_min);
  const ProbeModel probe{.ball_radius_mm = kBallMm};
  auto a = AnalyseProbeLog(s.q, s.log, probe, nullptr, Options());
  ASSERT_TRUE(a.ok()) << a.status().ToString();
  ASSERT_EQ(a->flagged.size(), 1u);
  EXPECT_EQ(a->flagged[0].id, 1);
  EXPECT_NE(a->flagged[0].reason.find("edge of Q"), std::string::npos) << a->flagged[0].reason;
  EXPECT_EQ(a->deviations.size(), 399u);
}

TEST(ProbeLogAnalysisTest, AnIdThePlanDoesNotHaveIsRefusedNamingIt) {
  log::SetLevel(log::Level::kError);
  Scene s = MakeScene(0);
  s.log.records[3].id = 9999;
  const ProbeModel probe{.ball_radius_mm = kBallMm};
  auto a = AnalyseProbeLog(s.q, s.log, probe, &s.plan, Options());
  ASSERT_FALSE(a.ok());
  EXPECT_EQ(a.status().code(), StatusCode::kBadInput);
  EXPECT_NE(a.status().message().find("9999"), std::string::npos) << a.status().message();
}

}  // namespace
}  // namespace formloop::metrology
