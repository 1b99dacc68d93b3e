// Level 1 cutting-parameter optimisation (spec/process-optimization.md §1, acceptance checks 5.1):
// the exact log-space LP against the reference optima of §1.9, the grid, the adaptive GA (seeds 0-29,
// determinism, stopping), Taylor's closed forms, the adaptive rates, infeasibility, fusion, and the GA
// against an independent NLP optimum (NLopt COBYLA on the model itself) on 24 random constrained cases.

#include "planning/cutting_optimisation.h"

#include <gtest/gtest.h>
#include <nlopt.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <string>
#include <vector>

#include "core/random.h"
#include "planning/cutting_model.h"

namespace formloop::planning {
namespace {

struct Reference {
  const char* name;
  double f_z, n, q, t;
  std::vector<std::string> active;
};

// The §1.9 table was computed with T_min = 48.8, T_c rounded (T_c = 48.8108: Q_A = 14710.98, -0.007 %).
CuttingCase CaseOf(char name) {
  CuttingCase c = CuttingCase::S1();
  c.t_min_min = 48.8;
  if (name == 'B') c.max_feed_mm_per_min = 2000;
  if (name == 'C') c.rated_power_kw = 1.0;
  if (name == 'D') c.a_e_mm = 3;
  return c;
}

// §1.9.
const Reference kReferences[] = {
    {"A", 0.123355, 5963.28, 14712.0, 48.80, {"T_min", "F_max"}},
    {"B", 0.133757, 3738.14, 10000.0, 162.89, {"v_f_max", "F_max"}},
    {"C", 0.126775, 5092.96, 12913.2, 73.32, {"F_max", "P"}},
    {"D", 0.035131, 6350.36, 13385.5, 48.80, {"T_min", "F_max"}},
};

std::vector<std::string> Sorted(std::vector<std::string> v) {
  std::sort(v.begin(), v.end());
  return v;
}

TEST(CuttingModel, S1MatchesTheSpecsCaseAFigures) {
  const CuttingCase c = CuttingCase::S1();
  ASSERT_TRUE(c.Validate().ok());
  EXPECT_TRUE(c.Warnings().empty());
  const CuttingState s = EvaluateCutting(c, 0.123355, 5963.28);
  EXPECT_NEAR(s.v_m_per_min, 187.3, 0.05);
  EXPECT_NEAR(s.v_f_mm_per_min, 2942, 0.5);
  EXPECT_NEAR(s.force_n, 300, 0.05);
  EXPECT_NEAR(s.power_kw, 0.94, 0.005);
  EXPECT_NEAR(s.tool_life_min, 48.80, 0.01);
}

TEST(CuttingModel, ExactOptimumMatchesTheReferenceOptimaWithKkt) {
  for (const Reference& ref : kReferences) {
    SCOPED_TRACE(ref.name);
    auto opt = CuttingOptimumExact(CaseOf(ref.name[0]));
    ASSERT_TRUE(opt.ok()) << opt.status().ToString();
    EXPECT_NEAR(opt->state.f_z_mm, ref.f_z, 1e-4 * ref.f_z);
    EXPECT_NEAR(opt->state.n_rpm, ref.n, 1e-4 * ref.n);
    EXPECT_NEAR(opt->state.q_mm3_per_min, ref.q, 0.1);
    EXPECT_NEAR(opt->state.tool_life_min, ref.t, 0.006);
    EXPECT_EQ(Sorted(opt->active), Sorted(ref.active));
    EXPECT_TRUE(opt->kkt_passed) << "residual " << opt->kkt_residual;
    for (double lambda : opt->kkt_multipliers) EXPECT_GE(lambda, 0);
    EXPECT_TRUE(SatisfiesConstraints(CaseOf(ref.name[0]), opt->state));
  }
}

TEST(CuttingModel, CaseBTieRulePicksTheLowSpeedEndOfTheFeedEdge) {
  const CuttingCase c = CaseOf('B');
  auto opt = CuttingOptimumExact(c);
  ASSERT_TRUE(opt.ok());
  // The other end of the v_f,max edge: same Q, T = T_min.
  const CuttingState other = EvaluateCutting(c, 0.07321, 6829.6);
  EXPECT_NEAR(other.q_mm3_per_min, 10000, 1.0);
  EXPECT_NEAR(other.tool_life_min, 48.8, 0.1);
  EXPECT_GT(opt->state.tool_life_min, 3 * other.tool_life_min);
}

class CuttingGrid : public ::testing::TestWithParam<char> {};

TEST_P(CuttingGrid, BestOfA1001x1001GridIsWithinHalfAPercentBelowTheOptimum) {
  const CuttingCase c = CaseOf(GetParam());
  const CuttingOptimum exact = CuttingOptimumExact(c).value();
  const CuttingOptimum grid = CuttingOptimumGrid(c, 1001);
  EXPECT_GE(grid.state.q_mm3_per_min, 0.995 * exact.state.q_mm3_per_min);
  EXPECT_LE(grid.state.q_mm3_per_min, exact.state.q_mm3_per_min * (1 + 1e-9));
  EXPECT_TRUE(SatisfiesConstraints(c, grid.state));
}

INSTANTIATE_TEST_SUITE_P(ReferenceCases, CuttingGrid, ::testing::Values('A', 'B', 'C', 'D'));

class CuttingGa : public ::testing::TestWithParam<char> {};

TEST_P(CuttingGa, Seeds0To29ReachTheOptimumAndSatisfyEveryConstraint) {
  const CuttingCase c = CaseOf(GetParam());
  const CuttingOptimum exact = CuttingOptimumExact(c).value();
  std::vector<double> errors;
  for (std::uint64_t seed = 0; seed < 30; ++seed) {
    auto ga = CuttingOptimumGa(c, seed);
    ASSERT_TRUE(ga.ok()) << ga.status().ToString();
    const double q = ga->state.q_mm3_per_min, q_opt = exact.state.q_mm3_per_min;
    EXPECT_GE(q, 0.995 * q_opt) << "seed " << seed;
    EXPECT_TRUE(SatisfiesConstraints(c, ga->state, 1e-9)) << "seed " << seed;
    EXPECT_LE(ga->generations, 100);
    EXPECT_GE(ga->generations, 20) << "stall stop before generation 20, seed " << seed;
    errors.push_back((q_opt - q) / q_opt);
  }
  std::sort(errors.begin(), errors.end());
  const double median = 0.5 * (errors[14] + errors[15]);
  EXPECT_LE(median, 5e-4);
  std::printf("case %c, seeds 0-29: median shortfall %.5f %%, worst %.5f %%\n", GetParam(), 100 * median,
              100 * errors.back());
}

INSTANTIATE_TEST_SUITE_P(ReferenceCases, CuttingGa, ::testing::Values('A', 'C', 'D'));

TEST(CuttingGaCaseB, EveryseedIsOnTheFeedEdgeWithALongToolLife) {
  const CuttingCase c = CaseOf('B');
  for (std::uint64_t seed = 0; seed < 30; ++seed) {
    auto ga = CuttingOptimumGa(c, seed);
    ASSERT_TRUE(ga.ok());
    EXPECT_NEAR(ga->state.q_mm3_per_min, 10000, 0.01) << "seed " << seed;
    EXPECT_GE(ga->state.tool_life_min, 0.9 * 162.89) << "seed " << seed;
    EXPECT_TRUE(SatisfiesConstraints(c, ga->state, 1e-9));
  }
}

TEST(CuttingGaRules, SameSeedSameAnswerBitForBit) {
  const CuttingCase c = CaseOf('A');
  const std::string a = CuttingOptimumGa(c, 0)->ToJson().dump(), b = CuttingOptimumGa(c, 0)->ToJson().dump();
  EXPECT_EQ(a, b);
  EXPECT_NE(a, CuttingOptimumGa(c, 1)->ToJson().dump());
}

TEST(CuttingGaRules, AdaptiveProbabilitiesFollowTheSpec) {
  const double f_max = 1.0, f_avg = 0.5;
  EXPECT_DOUBLE_EQ(AgaCrossoverProbability(f_max, f_avg, 0.4), 0.9);  // below average
  EXPECT_DOUBLE_EQ(AgaMutationProbability(f_max, f_avg, 0.4), 0.1);
  EXPECT_DOUBLE_EQ(AgaCrossoverProbability(f_max, f_avg, f_max), 0.6);
  EXPECT_DOUBLE_EQ(AgaMutationProbability(f_max, f_avg, f_avg), 0.001);
  EXPECT_DOUBLE_EQ(AgaMutationProbability(f_max, f_avg, f_max), 0.1);
  // Degenerate population.
  EXPECT_DOUBLE_EQ(AgaCrossoverProbability(0.7, 0.7, 0.7), 0.9);
  EXPECT_DOUBLE_EQ(AgaMutationProbability(0.7, 0.7, 0.7), 0.1);
}

TEST(CuttingInfeasible, GaAndOracleBothNameToolLife) {
  CuttingCase c = CuttingCase::S1();
  c.t_min_min = 5000;
  c.n_min_rpm = 3000;
  ASSERT_TRUE(c.Validate().ok());
  auto exact = CuttingOptimumExact(c);
  auto ga = CuttingOptimumGa(c, 0);
  ASSERT_FALSE(exact.ok());
  ASSERT_FALSE(ga.ok());
  for (const Status& s : {exact.status(), ga.status()}) {
    EXPECT_EQ(s.code(), StatusCode::kBadInput);
    EXPECT_NE(s.message().find("L1-INFEASIBLE"), std::string::npos) << s.message();
    EXPECT_NE(s.message().find("g1 tool life"), std::string::npos) << s.message();
  }
}

// Golden-section minimum of f over [lo, hi].
template <typename F>
double GoldenMin(F f, double lo, double hi) {
  const double g = (std::sqrt(5.0) - 1) / 2;
  double a = lo, b = hi, c = b - g * (b - a), d = a + g * (b - a);
  for (int i = 0; i < 200; ++i) {
    if (f(c) < f(d)) {
      b = d;
    } else {
      a = c;
    }
    c = b - g * (b - a);
    d = a + g * (b - a);
  }
  return 0.5 * (a + b);
}

TEST(CuttingTaylor, ClosedFormsAndTheirNumericalMinimaAgree) {
  const CuttingCase c = CuttingCase::S1();
  EXPECT_NEAR(MaxProductionToolLifeMin(c), 3.405, 3.405e-3);
  EXPECT_NEAR(MinCostToolLifeMin(c), 48.81, 48.81e-3);
  EXPECT_NEAR(c.TMinMin(), MinCostToolLifeMin(c), 0);
  // Minimise time and cost per unit volume over the speed at a fixed feed per tooth (Q ∝ v, T ∝ v^(-1/m)).
  const double f_z = 0.08;
  auto state = [&](double ln_n) { return EvaluateCutting(c, f_z, std::exp(ln_n)); };
  auto time_per_volume = [&](double ln_n) {
    const CuttingState s = state(ln_n);
    return (1 + c.tool_change_min / s.tool_life_min) / s.q_mm3_per_min;
  };
  auto cost_per_volume = [&](double ln_n) {
    const CuttingState s = state(ln_n);
    return c.machine_cost_per_min / s.q_mm3_per_min * (1 + c.tool_change_min / s.tool_life_min) +
           c.cost_per_edge / (s.q_mm3_per_min * s.tool_life_min);
  };
  const double t_p = state(GoldenMin(time_per_volume, 0, 20)).tool_life_min;
  const double t_c = state(GoldenMin(cost_per_volume, 0, 20)).tool_life_min;
  EXPECT_NEAR(t_p, MaxProductionToolLifeMin(c), 1e-6 * t_p);
  EXPECT_NEAR(t_c, MinCostToolLifeMin(c), 1e-6 * t_c);
  // A minimum life below T_p is refused, naming the parameter.
  CuttingCase fast = c;
  fast.t_min_min = 3.0;
  const Status s = fast.Validate();
  ASSERT_FALSE(s.ok());
  EXPECT_NE(s.message().find("t_min_min"), std::string::npos) << s.message();
}

TEST(CuttingFusion, WeightsAndFusedPointFollowTheRules) {
  const CuttingCase c = CuttingCase::S1();
  const CuttingState model = CuttingOptimumExact(c)->state;
  // No record: the model optimum, w_m = 1.
  const FusedCuttingPoint none = FuseWithDatabase(c, model, std::nullopt, 0.3);
  EXPECT_EQ(none.w_m, 1);
  EXPECT_EQ(none.state.f_z_mm, model.f_z_mm);
  EXPECT_EQ(none.state.n_rpm, model.n_rpm);
  EXPECT_DOUBLE_EQ(ModelWeight(0.5, 1.0), 0.3);
  // Monotone on an 11 x 11 grid: up in c_model, down in c_db.
  for (int i = 0; i <= 10; ++i) {
    for (int j = 0; j <= 10; ++j) {
      const double w = ModelWeight(i / 10.0, j / 10.0);
      if (i < 10) {
        EXPECT_LE(w, ModelWeight((i + 1) / 10.0, j / 10.0) + 1e-15);
      }
      if (j < 10) {
        EXPECT_GE(w, ModelWeight(i / 10.0, (j + 1) / 10.0) - 1e-15);
      }
    }
  }
  // The fused point is always feasible, whatever the record says.
  Rng rng(5);
  for (int k = 0; k < 200; ++k) {
    CuttingDataMatch m;
    m.record.v_c_nom_m_per_min = rng.Uniform(20, 600);
    m.record.f_z_nom_mm = rng.Uniform(0.005, 0.4);
    m.credibility = rng.Uniform();
    const FusedCuttingPoint f = FuseWithDatabase(c, model, m, rng.Uniform());
    EXPECT_TRUE(SatisfiesConstraints(c, f.state, 1e-9)) << k;
  }
}

TEST(CuttingFusion, MatchLevelsAndModelCredibility) {
  ToolDescription tool{
      .family = "solid-carbide-end-mill", .grade = "K20F", .material = "C45", .iso_group = "P", .hardness_hb = 200};
  CuttingDataRecord exact{.tool_family = "solid-carbide-end-mill",
                          .grade = "K20F",
                          .material = "C45",
                          .iso_group = "P",
                          .operation = "side_milling",
                          .d_min_mm = 8,
                          .d_max_mm = 12,
                          .hardness_hb = 200,
                          .v_c_nom_m_per_min = 180,
                          .f_z_nom_mm = 0.05};
  CuttingDataRecord family = exact, group = exact;
  family.grade = "P40";
  family.hardness_hb = 215;
  group.tool_family = "indexable";
  EXPECT_EQ(MatchCuttingData({group, family, exact}, tool, 10, "side_milling")->level, "exact");
  EXPECT_DOUBLE_EQ(MatchCuttingData({group, family}, tool, 10, "side_milling")->credibility, 0.7);
  EXPECT_DOUBLE_EQ(MatchCuttingData({group}, tool, 10, "side_milling")->credibility, 0.4);
  EXPECT_FALSE(MatchCuttingData({group}, tool, 10, "slotting").has_value());
  EXPECT_DOUBLE_EQ(ModelCredibility({1, 2}, {1, 2}), 0.3);  // fewer than 20 blocks: uncalibrated
  std::vector<double> predicted(20, 8.0), measured(20, 8.0 / 1.06);
  EXPECT_NEAR(ModelCredibility(predicted, measured), 0.8, 1e-12);  // 6 % error
}

// ------------------------------------------------------------------ independent NLP optimum (NLopt)

struct NloptData {
  const CuttingCase* c;
  int index;
};

double NloptObjective(unsigned, const double* x, double*, void*) { return x[0] + x[1]; }  // ln Q + const

double NloptConstraint(unsigned, const double* x, double*, void* data) {
  const auto* d = static_cast<const NloptData*>(data);
  const CuttingState s = EvaluateCutting(*d->c, std::exp(x[0]), std::exp(x[1]));
  return CuttingConstraints(*d->c, s)[static_cast<std::size_t>(d->index)].relative;
}

// COBYLA (derivative-free, Powell 1994) on (ln f_z, ln n) with the model's own constraints: nothing of
// the LP rows or of the GA's feed cap.
CuttingState NloptOptimum(const CuttingCase& c) {
  nlopt_opt opt = nlopt_create(NLOPT_LN_COBYLA, 2);
  const double lb[2] = {std::log(c.f_z_min_mm), std::log(c.n_min_rpm)};
  const double ub[2] = {std::log(c.f_z_max_mm), std::log(c.n_max_rpm)};
  nlopt_set_lower_bounds(opt, lb);
  nlopt_set_upper_bounds(opt, ub);
  nlopt_set_max_objective(opt, NloptObjective, nullptr);
  std::vector<NloptData> data;
  const std::vector<ConstraintValue> names = CuttingConstraints(c, EvaluateCutting(c, c.f_z_min_mm, c.n_min_rpm));
  for (int k = 0; k < static_cast<int>(names.size()); ++k) data.push_back({&c, k});
  for (NloptData& d : data) nlopt_add_inequality_constraint(opt, NloptConstraint, &d, 1e-12);
  nlopt_set_xtol_abs1(opt, 1e-12);
  nlopt_set_maxeval(opt, 200000);
  double best_obj = -1e300;
  std::vector<double> best(2);
  for (double start_f : {0.1, 0.5, 0.9}) {  // three starts across the box
    double x[2] = {lb[0] + start_f * (ub[0] - lb[0]), lb[1] + 0.5 * (ub[1] - lb[1])};
    double obj = 0;
    nlopt_optimize(opt, x, &obj);
    const CuttingState s = EvaluateCutting(c, std::exp(x[0]), std::exp(x[1]));
    if (SatisfiesConstraints(c, s, 1e-9) && obj > best_obj) {
      best_obj = obj;
      best = {x[0], x[1]};
    }
  }
  nlopt_destroy(opt);
  return EvaluateCutting(c, std::exp(best[0]), std::exp(best[1]));
}

// Random coefficient sets and process windows around S1 (log-uniform where the scale matters), kept
// only when some point is feasible.
std::vector<CuttingCase> RandomCases(int count) {
  Rng rng(2024);
  std::vector<CuttingCase> out;
  while (static_cast<int>(out.size()) < count) {
    CuttingCase c = CuttingCase::S1();
    c.coefficient_set = "random-" + std::to_string(out.size());
    c.life.C_v *= rng.Uniform(0.7, 1.3);
    c.life.m = rng.Uniform(0.25, 0.45);
    c.life.y_v = rng.Uniform(0.2, 0.4);
    c.life.x_v = rng.Uniform(0.05, c.life.y_v - 0.05);
    c.force.C_F *= rng.Uniform(0.6, 1.6);
    c.force.y_F = rng.Uniform(0.6, 0.85);
    c.force.w_F = rng.Uniform(-0.2, 0.05);
    c.a_p_mm = rng.Uniform(1, 10);
    c.a_e_mm = rng.Uniform(0.3, 5);
    c.max_force_n = std::exp(rng.Uniform(std::log(120.0), std::log(900.0)));
    c.rated_power_kw = std::exp(rng.Uniform(std::log(0.6), std::log(12.0)));
    c.max_feed_mm_per_min = rng.Uniform(1500, 8000);
    c.base_speed_rpm = rng.Uniform() < 0.5 ? 0 : rng.Uniform(1000, 6000);
    if (rng.Uniform() < 0.5) c.t_min_min = rng.Uniform(1.5 * MaxProductionToolLifeMin(c), 120);
    if (!c.Validate().ok() || !CuttingOptimumExact(c).ok()) continue;
    out.push_back(c);
  }
  return out;
}

TEST(CuttingRandomCases, GaMatchesAnIndependentNloptOptimumOn24ConstrainedCases) {
  const std::vector<CuttingCase> cases = RandomCases(24);
  int vertex_kinds = 0;
  double worst = 0;
  std::vector<std::string> seen;
  for (const CuttingCase& c : cases) {
    SCOPED_TRACE(c.coefficient_set);
    const CuttingState nlp = NloptOptimum(c);
    const CuttingOptimum exact = CuttingOptimumExact(c).value();
    auto ga = CuttingOptimumGa(c, 7);
    ASSERT_TRUE(ga.ok()) << ga.status().ToString();
    // The two independent references agree, and the GA lies within 0.5 % of them.
    EXPECT_NEAR(nlp.q_mm3_per_min, exact.state.q_mm3_per_min, 1e-4 * exact.state.q_mm3_per_min);
    EXPECT_GE(ga->state.q_mm3_per_min, 0.995 * nlp.q_mm3_per_min);
    EXPECT_LE(ga->state.q_mm3_per_min, exact.state.q_mm3_per_min * (1 + 1e-9));
    EXPECT_TRUE(SatisfiesConstraints(c, ga->state, 1e-9));
    worst = std::max(worst, 1 - ga->state.q_mm3_per_min / nlp.q_mm3_per_min);
    std::string key;
    for (const std::string& a : Sorted(exact.active)) key += a + " ";
    if (std::find(seen.begin(), seen.end(), key) == seen.end()) {
      seen.push_back(key);
      ++vertex_kinds;
    }
  }
  // The cases bind different constraints (not 24 copies of one vertex).
  EXPECT_GE(vertex_kinds, 4);
  std::printf("24 random cases: GA shortfall against NLopt at most %.5f %%, %d kinds of optimum vertex\n", 100 * worst,
              vertex_kinds);
}

}  // namespace
}  // namespace formloop::planning
