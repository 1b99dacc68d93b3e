// The offset solve and its rounding (tuning/offset_solve.h; spec/tuning-and-link.md §4-5.1, §9.5-9.9;
// issue 21 "what it must show" 2 and 4).

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <string>
#include <vector>

#include <gtest/gtest.h>
#include <Eigen/Dense>

#include "core/json_io.h"
#include "tests/support/bounded_lsq_check.h"
#include "tests/support/tuning_scenarios.h"
#include "tuning/offset_solve.h"
#include "tuning/wear_average.h"

namespace formloop::tuning {
namespace {

using Eigen::MatrixXd;
using Eigen::VectorXd;

// A problem with every offset bound ±bound_mm, resolution 0.001, w_c 1e-4.
OffsetProblem Problem(const MatrixXd& k, const std::vector<double>& e, const std::vector<double>& lo,
                      const std::vector<double>& hi, const std::vector<double>& weight, double bound_mm = 0.05) {
  OffsetProblem p;
  const int n = k.rows(), m = k.cols();
  for (int i = 0; i < n; ++i) p.dimension_ids.push_back("D" + std::to_string(i + 1));
  for (int j = 0; j < m; ++j) p.offset_ids.push_back("O" + std::to_string(j + 1));
  p.k = k.sparseView();
  p.deviation_mm = Eigen::Map<const VectorXd>(e.data(), n);
  p.tol_lower_mm = Eigen::Map<const VectorXd>(lo.data(), n);
  p.tol_upper_mm = Eigen::Map<const VectorXd>(hi.data(), n);
  p.target_mm = VectorXd::Zero(n);
  p.weight = Eigen::Map<const VectorXd>(weight.data(), n);
  p.delta_min_mm = VectorXd::Constant(m, -bound_mm);
  p.delta_max_mm = VectorXd::Constant(m, bound_mm);
  p.offset_weight = VectorXd::Constant(m, 1e-4);
  p.resolution_mm = VectorXd::Constant(m, 0.001);
  return p;
}

MatrixXd Column(std::initializer_list<double> v) {
  MatrixXd k(v.size(), 1);
  int i = 0;
  for (double x : v) k(i++, 0) = x;
  return k;
}

// §9.5: outer width K = +2 at 20.030, slot K = −2 at 9.970, both ±0.02.
TEST(OffsetSolve, SpecExampleA) {
  const auto p = Problem(Column({2, -2}), {0.030, -0.030}, {-0.02, -0.02}, {0.02, 0.02}, {1, 1});
  auto s = SolveOffsets(p);
  ASSERT_TRUE(s.ok()) << s.status().ToString();
  EXPECT_NEAR(-s->rounded.delta_mm(0), 0.0149998, 5e-8);  // c
  EXPECT_DOUBLE_EQ(s->rounded.delta_rounded_mm(0), -0.015);
  EXPECT_NEAR(20.0 + s->rounded.predicted_mm(0), 20.000, 1e-12);
  EXPECT_NEAR(10.0 + s->rounded.predicted_mm(1), 10.000, 1e-12);
  EXPECT_TRUE(s->reachable());
}

// §9.6: example A with δ ∈ [−0.010, 0.010]: the bound is active.
TEST(OffsetSolve, SpecExampleABounded) {
  const auto p = Problem(Column({2, -2}), {0.030, -0.030}, {-0.02, -0.02}, {0.02, 0.02}, {1, 1}, 0.010);
  auto s = SolveOffsets(p);
  ASSERT_TRUE(s.ok());
  EXPECT_DOUBLE_EQ(s->rounded.delta_mm(0), -0.010);
  EXPECT_DOUBLE_EQ(s->rounded.delta_rounded_mm(0), -0.010);
  EXPECT_EQ(s->solver.active[0], 1);  // c = +10 µm at its upper bound
  EXPECT_EQ(s->ToJson()["offsets_at_bound"], Json::array({"O1"}));
  EXPECT_NEAR(20.0 + s->rounded.predicted_mm(0), 20.010, 1e-12);
  EXPECT_NEAR(10.0 + s->rounded.predicted_mm(1), 9.990, 1e-12);
  EXPECT_TRUE(s->rounded.predicted_ok[0] && s->rounded.predicted_ok[1]);
}

// §9.7: two outer sizes (K = +2) at 30.020 (w = 3) and 40.012 (w = 1).
TEST(OffsetSolve, SpecExampleWeighted) {
  const auto p = Problem(Column({2, 2}), {0.020, 0.012}, {-0.02, -0.02}, {0.02, 0.02}, {3, 1});
  auto s = SolveOffsets(p);
  ASSERT_TRUE(s.ok());
  EXPECT_NEAR(-s->rounded.delta_mm(0), 0.0089998, 5e-8);
  EXPECT_DOUBLE_EQ(s->rounded.delta_rounded_mm(0), -0.009);
  EXPECT_NEAR(30.0 + s->rounded.predicted_mm(0), 30.002, 1e-12);
  EXPECT_NEAR(40.0 + s->rounded.predicted_mm(1), 39.994, 1e-12);
}

// §9.8: outer +2 and slot −2 both +0.030 over nominal, ±0.02: infeasible, reported, never silent.
TEST(OffsetSolve, SpecExampleInfeasible) {
  const auto p = Problem(Column({2, -2}), {0.030, 0.030}, {-0.02, -0.02}, {0.02, 0.02}, {1, 1});
  auto s = SolveOffsets(p);
  ASSERT_TRUE(s.ok());
  EXPECT_NEAR(s->rounded.delta_mm(0), 0.0, 1e-9);
  EXPECT_NEAR(s->t_mm(0), 0.02, 1e-9);
  EXPECT_NEAR(s->t_mm(1), 0.02, 1e-9);
  EXPECT_NEAR(s->r_eq_mm(0), 0.010, 1e-9);
  EXPECT_NEAR(s->r_eq_mm(1), 0.010, 1e-9);
  EXPECT_TRUE(s->not_reachable[0]);
  EXPECT_TRUE(s->not_reachable[1]);
  EXPECT_FALSE(s->reachable());
  EXPECT_EQ(s->ToJson()["not_reachable"].size(), 2u);
}

// The (A, b, lb, ub) we build equal the SciPy fixture's for examples 5-8 (built by the Python script
// from the same numbers), entry by entry.
TEST(OffsetSolve, PenaltyFormMatchesTheFixtureConstruction) {
  auto json = ReadJsonFile(std::string(FORMLOOP_SOURCE_DIR) + "/tests/tuning/fixtures/lsq_scipy.json");
  ASSERT_TRUE(json.ok());
  const std::vector<OffsetProblem> problems = {
      Problem(Column({2, -2}), {0.030, -0.030}, {-0.02, -0.02}, {0.02, 0.02}, {1, 1}),
      Problem(Column({2, -2}), {0.030, -0.030}, {-0.02, -0.02}, {0.02, 0.02}, {1, 1}, 0.010),
      Problem(Column({2, 2}), {0.020, 0.012}, {-0.02, -0.02}, {0.02, 0.02}, {3, 1}),
      Problem(Column({2, -2}), {0.030, 0.030}, {-0.02, -0.02}, {0.02, 0.02}, {1, 1}),
  };
  for (int c = 0; c < 4; ++c) {
    const auto& fixture = (*json)["cases"][c];
    SCOPED_TRACE(fixture["name"].get<std::string>());
    auto form = BuildPenaltyForm(problems[c]);
    ASSERT_TRUE(form.ok());
    MatrixXd expected = MatrixXd::Zero(fixture["shape"][0].get<int>(), fixture["shape"][1].get<int>());
    for (const auto& t : fixture["a_triplets"]) expected(t[0].get<int>(), t[1].get<int>()) = t[2].get<double>();
    EXPECT_LE((MatrixXd(form->a) - expected).cwiseAbs().maxCoeff(), 1e-12);
    for (int i = 0; i < form->b.size(); ++i) EXPECT_NEAR(form->b(i), fixture["b"][i].get<double>(), 1e-9);
    for (int i = 0; i < form->lb.size(); ++i) {
      EXPECT_NEAR(form->lb(i), fixture["lb"][i].get<double>(), 1e-12);
      EXPECT_NEAR(form->ub(i), fixture["ub"][i].get<double>(), 1e-12);
    }
  }
}

// Two offsets that move the same dimension identically: the minimum-norm rule splits the correction in
// proportion to 1/w_c, and the pair is reported as indistinguishable.
TEST(OffsetSolve, RankDeficientKFollowsTheMinimumNormRule) {
  MatrixXd k(2, 3);
  k << 2, 2, 0,  //
      0, 0, 1;
  auto p = Problem(k, {0.030, 0.004}, {-0.02, -0.02}, {0.02, 0.02}, {1, 1});
  auto s = SolveOffsets(p);
  ASSERT_TRUE(s.ok());
  EXPECT_EQ(s->k_rank, 2);
  ASSERT_EQ(s->indistinguishable.size(), 1u);
  EXPECT_EQ(s->indistinguishable[0], (std::vector<std::string>{"O1", "O2"}));
  // Minimum-norm: δ1 = δ2 = −0.030/4 (up to the tiny pull of the regulariser towards t = 0).
  EXPECT_NEAR(s->rounded.delta_mm(0), -0.0075, 1e-6);
  EXPECT_NEAR(s->rounded.delta_mm(1), -0.0075, 1e-6);
  EXPECT_NEAR(s->rounded.delta_mm(0), s->rounded.delta_mm(1), 1e-12);
  // Prefer O1: w_c(O2) four times larger → δ1 = 4·δ2, δ1 + δ2 = −0.015.
  p.offset_weight(1) = 4e-4;
  s = SolveOffsets(p);
  ASSERT_TRUE(s.ok());
  EXPECT_NEAR(s->rounded.delta_mm(0), -0.012, 1e-6);
  EXPECT_NEAR(s->rounded.delta_mm(1), -0.003, 1e-6);
}

TEST(OffsetSolve, FixedAndUnusedOffsetsAreRemovedBeforeSolving) {
  MatrixXd k(2, 3);
  k << 2, 1, 0,  //
      -2, 0, 0;
  auto p = Problem(k, {0.030, -0.030}, {-0.02, -0.02}, {0.02, 0.02}, {1, 1});
  p.delta_min_mm(1) = p.delta_max_mm(1) = 0.0;  // fixed (e.g. a work offset not to be touched)
  auto s = SolveOffsets(p);
  ASSERT_TRUE(s.ok());
  EXPECT_EQ(s->fixed_offsets, std::vector<std::string>{"O2"});
  EXPECT_EQ(s->zero_offsets, std::vector<std::string>{"O3"});
  EXPECT_EQ(s->rounded.delta_rounded_mm(1), 0.0);
  EXPECT_EQ(s->rounded.delta_rounded_mm(2), 0.0);
  EXPECT_DOUBLE_EQ(s->rounded.delta_rounded_mm(0), -0.015);
  EXPECT_NE(s->rounded.rule[2].find("no COMPENSATE dimension"), std::string::npos);
}

// Nearest rounding would push D1 out of its ±0.5 µm band; the floor/ceiling repair keeps it in.
TEST(OffsetSolve, RoundingRepairKeepsADimensionInTolerance) {
  MatrixXd k(3, 2);
  k << 1, 1,  //
      1, 0,   //
      0, 1;
  auto p = Problem(k, {0.0032, 0.0015, 0.0015}, {-0.0005, -0.02, -0.02}, {0.0005, 0.02, 0.02}, {1, 1, 1});
  auto s = SolveOffsets(p);
  ASSERT_TRUE(s.ok());
  // Continuous δ ≈ (−0.00157, −0.00157); nearest (−0.002, −0.002) gives D1 = −0.0008, NG.
  EXPECT_NEAR(s->rounded.delta_mm(0), -0.0047 / 3, 1e-6);
  EXPECT_TRUE(s->rounded.predicted_ok[0]) << s->rounded.predicted_mm(0);
  EXPECT_TRUE(s->rounded.ng_after_rounding.empty());
  const double d1 = s->rounded.delta_rounded_mm(0), d2 = s->rounded.delta_rounded_mm(1);
  EXPECT_TRUE((d1 == -0.001 && d2 == -0.002) || (d1 == -0.002 && d2 == -0.001)) << d1 << " " << d2;
  const std::string rules = s->rounded.rule[0] + s->rounded.rule[1];
  EXPECT_NE(rules.find("to keep D1 within tolerance"), std::string::npos) << rules;
  for (int j = 0; j < 2; ++j) {
    EXPECT_GE(s->rounded.delta_rounded_mm(j), p.delta_min_mm(j));
    EXPECT_LE(s->rounded.delta_rounded_mm(j), p.delta_max_mm(j));
  }
}

TEST(OffsetSolve, RoundingStaysInsideBoundsThatAreNotMultiplesOfTheResolution) {
  auto p = Problem(Column({2}), {0.030}, {-0.02}, {0.02}, {1}, 0.0125);
  auto s = SolveOffsets(p);
  ASSERT_TRUE(s.ok());
  EXPECT_DOUBLE_EQ(s->rounded.delta_mm(0), -0.0125);         // bound active
  EXPECT_DOUBLE_EQ(s->rounded.delta_rounded_mm(0), -0.012);  // nearest would be −0.013, outside
  EXPECT_NE(s->rounded.rule[0].find("inside [delta_min_mm, delta_max_mm]"), std::string::npos);
}

TEST(OffsetSolve, InvalidProblemsNameTheDimensionOrOffset) {
  auto p = Problem(Column({2, -2}), {0.03, -0.03}, {-0.02, 0.02}, {0.02, 0.02}, {1, 1});
  auto s = SolveOffsets(p);
  ASSERT_FALSE(s.ok());
  EXPECT_NE(s.status().message().find("dimension D2"), std::string::npos) << s.status().message();
  p = Problem(Column({2, -2}), {0.03, -0.03}, {-0.02, -0.02}, {0.02, 0.02}, {1, 1});
  p.delta_min_mm(0) = 0.001;
  s = SolveOffsets(p);
  ASSERT_FALSE(s.ok());
  EXPECT_NE(s.status().message().find("offset O1"), std::string::npos);
}

// Issue 21 "must show" 2: ≥ 200 random feasible scenarios (5-40 dimensions, 3-15 offsets, K like real
// parts): objective equal to the independent BVLS's to 1e-9 relative, KKT certificate, and after the
// offsets are applied in simulation every COMPENSATE dimension within tolerance in ≥ 95 % of them;
// infeasible scenarios reported as such (confirmed independently on problem (3)).
TEST(OffsetSolve, RandomScenariosAgainstBvlsAndSimulation) {
  int scenarios = 0, all_in = 0, reachable = 0, kkt_ok = 0, max_iterations = 0;
  double worst_cost = 0;
  for (int seed = 1; seed <= 220; ++seed) {
    Rng rng(1000 + seed);
    const int n = 5 + static_cast<int>(rng.UniformIndex(36));
    const int k = 3 + static_cast<int>(rng.UniformIndex(std::min(13, n - 2)));
    const auto sc = testing::MakeTuningScenario(seed, n, k);
    SCOPED_TRACE("seed " + std::to_string(seed));
    auto s = SolveOffsets(sc.problem);
    ASSERT_TRUE(s.ok()) << s.status().ToString();
    ++scenarios;
    auto form = BuildPenaltyForm(sc.problem);
    ASSERT_TRUE(form.ok());
    const MatrixXd a(form->a);
    const auto bvls = testing::Bvls(a, form->b, form->lb, form->ub);
    ASSERT_TRUE(bvls.converged);
    const double rel = std::abs(s->solver.cost - bvls.cost) / std::max(1.0, bvls.cost);
    EXPECT_LE(rel, 1e-9) << s->solver.cost << " vs " << bvls.cost;
    worst_cost = std::max(worst_cost, rel);
    kkt_ok += testing::KktCertificate(a, form->b, form->lb, form->ub, s->solver.x).ok;
    reachable += s->reachable();
    max_iterations = std::max(max_iterations, s->solver.iterations);
    const VectorXd next = testing::SimulateNextPart(sc, s->rounded.delta_rounded_mm, 7000 + seed);
    bool in = true;
    for (int i = 0; i < next.size(); ++i) {
      in = in && next(i) >= sc.problem.tol_lower_mm(i) - 1e-9 && next(i) <= sc.problem.tol_upper_mm(i) + 1e-9;
    }
    all_in += in;
  }
  std::printf(
      "%d feasible scenarios: worst |f - f_bvls|/max(1,f) = %.2e, KKT certificate %d/%d, reachable %d/%d, "
      "every COMPENSATE dimension in tolerance on the next (simulated) part in %d/%d (%.1f %%), max iterations %d\n",
      scenarios, worst_cost, kkt_ok, scenarios, reachable, scenarios, all_in, scenarios, 100.0 * all_in / scenarios,
      max_iterations);
  EXPECT_GE(scenarios, 200);
  EXPECT_EQ(kkt_ok, scenarios);
  EXPECT_EQ(reachable, scenarios);
  EXPECT_GE(all_in, 0.95 * scenarios);

  // Infeasible scenarios: NOT_REACHABLE reported; problem (3), min ‖[K I]x − e‖² over the same bounds, has
  // a positive optimum (independent BVLS), i.e. the model really is infeasible.
  int infeasible = 0, reported = 0;
  for (int seed = 1; seed <= 40; ++seed) {
    Rng rng(5000 + seed);
    const int n = 5 + static_cast<int>(rng.UniformIndex(36));
    const int k = 3 + static_cast<int>(rng.UniformIndex(std::min(13, n - 2)));
    const auto sc = testing::MakeTuningScenario(9000 + seed, n, k, {.infeasible = true});
    auto s = SolveOffsets(sc.problem);
    ASSERT_TRUE(s.ok());
    ++infeasible;
    reported += !s->reachable();
    auto form = BuildPenaltyForm(sc.problem);
    ASSERT_TRUE(form.ok());
    const int nn = sc.problem.k.rows(), kk = static_cast<int>(form->kept.size());
    MatrixXd a3(nn, kk + nn);
    const MatrixXd kd(sc.problem.k);
    for (int c = 0; c < kk; ++c) a3.col(c) = kd.col(form->kept[c]);
    a3.rightCols(nn) = MatrixXd::Identity(nn, nn);
    const auto pure = testing::Bvls(a3, sc.problem.deviation_mm * 1e3, form->lb, form->ub);
    EXPECT_GT(pure.cost, 1.0) << "seed " << seed << ": problem (3) optimum " << pure.cost << " µm²";
  }
  std::printf("%d infeasible scenarios: NOT_REACHABLE reported in %d\n", infeasible, reported);
  EXPECT_EQ(reported, infeasible);
}

// Issue 21 "must show" 4: the two strategies side by side on the same scenarios. Two families: parts whose
// every dimension hangs on one tool-wear offset (seed 004's case, where averaging applies to all of
// them) and general parts (positions on a wear and a work offset, steps between two tools).
TEST(OffsetSolve, StrategiesSideBySide) {
  struct Tally {
    int dims = 0, in = 0, parts_all_in = 0;
    double centre_distance_um = 0;
  };
  for (int family = 0; family < 2; ++family) {
    Tally wls, avg;
    int parts = 0, skipped = 0, alarms = 0;
    for (int seed = 1; seed <= 200; ++seed) {
      Rng rng(300 + seed);
      const int n = 5 + static_cast<int>(rng.UniformIndex(36));
      const int k = 3 + static_cast<int>(rng.UniformIndex(std::min(13, n - 2)));
      const auto sc = testing::MakeTuningScenario(20000 + seed, n, k, {.single_offset_rows = family == 0});
      ++parts;
      auto s = SolveOffsets(sc.problem);
      ASSERT_TRUE(s.ok());
      auto av = AverageWearCompensation(sc.problem);
      ASSERT_TRUE(av.ok());
      auto avr = RoundOffsets(sc.problem, av->delta_mm);
      ASSERT_TRUE(avr.ok());
      alarms += av->alarm;
      for (const auto& d : av->dimensions) skipped += !d.used;
      auto tally = [&](const VectorXd& delta, Tally* t) {
        const VectorXd next = testing::SimulateNextPart(sc, delta, 40000 + seed);
        bool all = true;
        for (int i = 0; i < next.size(); ++i) {
          const double lo = sc.problem.tol_lower_mm(i), hi = sc.problem.tol_upper_mm(i);
          const bool ok = next(i) >= lo - 1e-9 && next(i) <= hi + 1e-9;
          t->in += ok;
          all = all && ok;
          t->centre_distance_um += std::abs(next(i) - 0.5 * (lo + hi)) * 1e3;
          ++t->dims;
        }
        t->parts_all_in += all;
      };
      tally(s->rounded.delta_rounded_mm, &wls);
      tally(avr->delta_rounded_mm, &avg);
    }
    std::printf(
        "%s parts (%d): share of dimensions in tolerance WLS %.1f %% vs average %.1f %%; parts with all in "
        "tolerance WLS %d vs average %d; mean |d - band centre| WLS %.3f um vs average %.3f um; average skipped "
        "%d dimension(s), %d alarm(s)\n",
        family == 0 ? "single-offset" : "general", parts, 100.0 * wls.in / wls.dims, 100.0 * avg.in / avg.dims,
        wls.parts_all_in, avg.parts_all_in, wls.centre_distance_um / wls.dims, avg.centre_distance_um / avg.dims,
        skipped, alarms);
    EXPECT_GE(wls.parts_all_in, 0.95 * parts);
    if (family == 1) {
      EXPECT_GT(skipped, 0);  // averaging cannot use dimensions on several offsets
    }
  }
}

}  // namespace
}  // namespace formloop::tuning
