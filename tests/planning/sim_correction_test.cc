// The simulation-correction loop (planning/sim_correction.h): the plan GA against the brute-force oracle of
// spec/process-optimization.md §4.4, and the loop on a part whose concave region is tighter than the
// case's tool, on a model whose systematic error exceeds the tolerance, and with a magazine that has no
// gouge-free tool.

#include "planning/sim_correction.h"

#include <cmath>
#include <cstdio>

#include <gtest/gtest.h>

#include "metrology/probe.h"
#include "reconstruction/surface_family.h"

namespace formloop::planning {
namespace {

// ---------------------------------------------------------------- the reference instance (§4.4)

TEST(SimCorrectionSurrogate, BruteForceMatchesReferenceInstance) {
  const SurrogateInputs in = SurrogateInputs::ReferenceInstance();
  const SurrogateResult bf = SurrogateBruteForce(in);
  std::printf("brute force: r %.3f s %.4f f_z %.4f c_pc %.3f t %.3f min e_pred %.5f J %.5f\n", bf.r, bf.s, bf.f_z,
              bf.c_pc, bf.time_min, bf.e_pred, bf.J);
  // J is what is minimised and the spec prints it to 4 figures: ±0.0005. The optimum is a flat ridge in
  // (s, f_z): at the spec's printed point (s 0.456, f_z 0.066) the surrogate gives J = 1.04145 and
  // t = 13.62 min, at the grid optimum J = 1.04141 and t = 13.59 min, so s, f_z and t are only as good as
  // the ridge is flat: s within 1.5 %, f_z within 2.5 %, t within 0.15 min (the spec's own point gives
  // 13.62, printed "~13.7"). e_pred to the printed digit.
  EXPECT_EQ(bf.r, 4.0);
  EXPECT_NEAR(bf.s, 0.456, 0.007);
  EXPECT_NEAR(bf.f_z, 0.066, 0.0016);
  EXPECT_DOUBLE_EQ(bf.c_pc, 1.0);
  EXPECT_NEAR(bf.time_min, 13.7, 0.15);
  EXPECT_NEAR(bf.e_pred, 0.045, 0.0005);
  EXPECT_NEAR(bf.J, 1.041, 0.0005);
  const SurrogateResult printed = EvaluateSurrogate(in, 4, 0.456, 0.066, 1.0);
  EXPECT_GE(printed.J, bf.J);           // the grid finds the minimum...
  EXPECT_LE(printed.J, 1.0001 * bf.J);  // ...on the ridge the spec's point lies on
  EXPECT_LE(bf.e_pred, in.t_form_mm);
  EXPECT_LE(bf.scallop_mm, in.h_tol_mm + 1e-15);
}

TEST(SimCorrectionSurrogate, GaReachesBruteForceForSeeds0To9) {
  const SurrogateInputs in = SurrogateInputs::ReferenceInstance();
  const SurrogateResult bf = SurrogateBruteForce(in);
  for (std::uint64_t seed = 0; seed < 10; ++seed) {
    nlohmann::json history;
    const SurrogateResult ga = SurrogateGa(in, seed, &history);
    std::printf("seed %d: r %.1f s %.4f f_z %.4f c_pc %.4f J %.5f (%.3f %% above brute force), %d generations\n",
                static_cast<int>(seed), ga.r, ga.s, ga.f_z, ga.c_pc, ga.J, 100 * (ga.J / bf.J - 1), ga.generations);
    EXPECT_LE(ga.J, 1.005 * bf.J) << "seed " << seed;
    EXPECT_EQ(ga.r, 4.0) << "seed " << seed;  // r = 5, 6 gouge; they are never decoded
    EXPECT_LE(ga.scallop_mm, in.h_tol_mm + 1e-15) << "seed " << seed;
    EXPECT_LE(ga.e_pred, in.t_form_mm) << "seed " << seed;
    ASSERT_TRUE(history.contains("best_J"));
    EXPECT_EQ(history["best_J"].size(), static_cast<std::size_t>(ga.generations + 1));
  }
  nlohmann::json h1, h2;
  const SurrogateResult a = SurrogateGa(in, 7, &h1), b = SurrogateGa(in, 7, &h2);
  EXPECT_EQ(a.ToJson().dump(), b.ToJson().dump());
  EXPECT_EQ(h1.dump(), h2.dump());
}

TEST(SimCorrectionSurrogate, NoGougeFreeToolGivesNoPlan) {
  SurrogateInputs in = SurrogateInputs::ReferenceInstance();
  in.rho_cc_min_mm = 1.0;  // §5.4 check 25: every tool r ≥ 1.5 > 0.9 mm
  EXPECT_TRUE(GougeFreeRadii(in).empty());
  EXPECT_EQ(SurrogateGa(in, 1, nullptr).tool_index, -1);
  EXPECT_EQ(SurrogateBruteForce(in, 11, 11, 5).tool_index, -1);
}

// ---------------------------------------------------------------- the loop on a part

// A 40 mm Gaussian pocket: 10 mm deep, 8 mm wide; at the bottom the concave radius is w²/(2d) = 3.2 mm.
const recon::BSplineSurface& Pocket() {
  static const recon::BSplineSurface q =
      recon::FitParametric("gaussian_pocket", {{"size_mm", 40}, {"depth_ratio", 0.25}, {"width_ratio", 0.2}}, 41)
          .value();
  return q;
}

SimCorrectionInput BaseInput(double case_tool_radius_mm) {
  SimCorrectionInput in;
  in.surface = &Pocket();
  in.tools = {{1, 1.5}, {2, 2}, {3, 3}, {4, 4}, {5, 6}};  // the magazine
  in.case_plan.tool = {9, case_tool_radius_mm};
  for (const nc::BallEndTool& t : in.tools) {
    if (t.radius_mm == case_tool_radius_mm) in.case_plan.tool = t;
  }
  in.case_plan.scallop_um = 2.0;
  in.case_plan.max_point_spacing_mm = 2.0;  // coarse: the tests stay fast
  in.case_plan.feed_mm_per_min = 2000;
  in.case_plan.spindle_rpm = 12000;
  in.similarity = 0.9;
  in.tolerance_mm = 0.010;
  in.random_um = 2.0;
  in.probing_plan = metrology::PlanProbingGrid(Pocket(), 10, 10, 0.05).value();
  in.seed = 11;
  return in;
}

bool HasDefect(const std::vector<Defect>& d, const std::string& kind) {
  for (const Defect& x : d) {
    if (x.kind == kind) return true;
  }
  return false;
}

// One line per run (the full JSON is long: it holds the GA's best J per generation).
void Print(const char* name, const SimCorrectionResult& r) {
  std::string before, after;
  for (const Defect& d : r.defects_before) before += d.kind + " ";
  for (const Defect& d : r.defects_after) after += d.kind + " ";
  std::printf(
      "%s: corrected %d rounds %d | before [%s] e_pred %.3f um | after [%s] e_pred %.3f um | r %.2f mm s %.4f mm "
      "scallop %.3f um f_z %.4f mm %.0f mm/min %.0f rpm c_pc %.4f\n",
      name, r.corrected, r.rounds, before.c_str(), r.predicted_form_error_before_um, after.c_str(),
      r.predicted_form_error_after_um, r.chosen.tool_radius_mm, r.chosen.step_over_mm, r.chosen.scallop_um,
      r.chosen.feed_per_tooth_mm, r.chosen.feed_mm_per_min, r.chosen.spindle_rpm, r.precompensation_scale);
}

TEST(SimCorrectionLoop, MeasuresThePocket) {
  const double rho = SmallestConcaveRadiusMm(Pocket());
  const double kappa = LargestConvexCurvature(Pocket());
  std::printf("pocket: rho_cc,min %.4f mm, kappa_cvx,max %.5f 1/mm\n", rho, kappa);
  EXPECT_NEAR(rho, 3.2, 0.1);  // w²/(2d) at the bottom, to the 1 mm grid and the fit
  // Convex rim: the Gaussian's largest convex curvature is 2d/w²·2e^{-3/2}/(1 + slope²)^{3/2} order,
  // well below the bottom's; only its sign and size class are checked.
  EXPECT_GT(kappa, 0.0);
  EXPECT_LT(kappa, 1 / rho);
}

// Model of the case: the ball 8 µm smaller than programmed and a little deflection on the walls.
sim::Model SmallModel(double delta_r_um, double k_d_um) {
  sim::Model m;
  EXPECT_TRUE(m.Set("tool_radius", {delta_r_um}).ok());
  if (k_d_um > 0) {
    EXPECT_TRUE(m.Set("tool_deflection", {k_d_um}).ok());
  }
  EXPECT_TRUE(m.Set("noise", {1.0, 0.5}).ok());  // dropped by the prediction (no noise in a forecast)
  return m;
}

TEST(SimCorrectionLoop, TightConcaveRegionChangesTheTool) {
  const double rho = SmallestConcaveRadiusMm(Pocket());
  SimCorrectionInput in = BaseInput(4.0);  // the case's r = 4 mm is above ρ ≈ 3.3 mm: the planner lifts
  ASSERT_GT(in.case_plan.tool.radius_mm, rho);
  in.model = SmallModel(8, 3);
  const auto r = RunSimulationCorrection(in);
  ASSERT_TRUE(r.ok()) << r.status().ToString();
  Print("tight concave", *r);
  ASSERT_TRUE(HasDefect(r->defects_before, "gouge"));
  EXPECT_NE(r->defects_before.front().detail.find("CL points lifted"), std::string::npos);
  EXPECT_TRUE(r->corrected) << r->why_not;
  EXPECT_TRUE(r->defects_after.empty());
  EXPECT_LE(r->chosen.tool_radius_mm, 0.9 * rho);
  EXPECT_EQ(r->plan.tool.radius_mm, r->chosen.tool_radius_mm);
  EXPECT_LE(r->predicted_form_error_after_um, 1000 * in.tolerance_mm);
  EXPECT_TRUE(r->why_not.empty());
}

TEST(SimCorrectionLoop, PrecompensationBringsASystematicErrorIntoTolerance) {
  SimCorrectionInput in = BaseInput(2.0);  // a gouge-free case tool: only the form error is wrong
  in.model = SmallModel(15, 3);            // 15 µm left everywhere > α = 10 µm
  in.similarity = 0.9;
  const auto r = RunSimulationCorrection(in);
  ASSERT_TRUE(r.ok()) << r.status().ToString();
  Print("precompensation", *r);
  EXPECT_GT(r->predicted_form_error_before_um, 1000 * in.tolerance_mm);
  EXPECT_TRUE(HasDefect(r->defects_before, "form_error"));
  EXPECT_FALSE(HasDefect(r->defects_before, "gouge"));
  EXPECT_TRUE(r->corrected) << r->why_not;
  EXPECT_GT(r->precompensation_scale, 0.5);
  EXPECT_LE(r->predicted_form_error_after_um, 1000 * in.tolerance_mm);
  // Same input, same result, byte for byte.
  const auto again = RunSimulationCorrection(in);
  ASSERT_TRUE(again.ok());
  EXPECT_EQ(r->ToJson().dump(), again->ToJson().dump());
}

TEST(SimCorrectionLoop, NoGougeFreeToolIsPlanNoTool) {
  SimCorrectionInput in = BaseInput(6.0);
  in.tools = {{5, 6}, {6, 8}, {7, 4}};  // all above 0.9 ρ ≈ 2.9 mm
  in.model = SmallModel(8, 0);
  const auto r = RunSimulationCorrection(in);
  ASSERT_TRUE(r.ok()) << r.status().ToString();
  Print("no tool", *r);
  std::printf("  why_not: %s\n", r->why_not.c_str());
  EXPECT_FALSE(r->corrected);
  EXPECT_TRUE(HasDefect(r->defects_before, "gouge"));
  EXPECT_NE(r->why_not.find("PLAN-NO-TOOL"), std::string::npos) << r->why_not;
  EXPECT_NE(r->why_not.find("{4.00, 6.00, 8.00}"), std::string::npos) << r->why_not;
  EXPECT_NE(r->why_not.find("smallest concave radius 3."), std::string::npos) << r->why_not;
  EXPECT_TRUE(r->ToJson()["plan"].is_null());
}

TEST(SimCorrectionLoop, ImpossibleToleranceEscalatesAfterThreeRounds) {
  SimCorrectionInput in = BaseInput(2.0);
  in.model = SmallModel(8, 0);
  in.random_um = 9.5;  // e_rand alone is 9.5 µm; with (1 − A)·8 µm left after any c_pc, α = 10 µm is out of reach
  const auto r = RunSimulationCorrection(in);
  ASSERT_TRUE(r.ok()) << r.status().ToString();
  Print("impossible", *r);
  std::printf("  why_not: %s\n", r->why_not.c_str());
  EXPECT_FALSE(r->corrected);
  EXPECT_EQ(r->rounds, 3);
  ASSERT_EQ(r->history.size(), 3u);
  for (const auto& h : r->history) EXPECT_TRUE(h["check"]["defects"].size() > 0);
  EXPECT_TRUE(HasDefect(r->defects_after, "form_error"));
  EXPECT_GT(r->predicted_form_error_after_um, 1000 * in.tolerance_mm);
  EXPECT_NE(r->why_not.find("form_error"), std::string::npos) << r->why_not;
  EXPECT_NE(r->why_not.find("escalate"), std::string::npos) << r->why_not;
  // Step 4 works: round 1's surrogate (force-model deflection as a prior) is far from the simulation, the
  // rescaled surrogate of round 3 predicts what the simulation then measures.
  const auto gap_um = [&](int round) {
    const auto& h = r->history[static_cast<std::size_t>(round - 1)];
    return 1000 * std::abs(h["ga"]["best"]["e_pred_mm"].get<double>() - h["check"]["e_pred_mm"].get<double>());
  };
  std::printf("surrogate vs simulation e_pred gap: round 1 %.3f um, round 3 %.3f um\n", gap_um(1), gap_um(3));
  EXPECT_GT(gap_um(1), 5.0);
  EXPECT_LT(gap_um(3), 0.5);
}

TEST(SimCorrectionLoop, TravelLimitIsReportedAndNotCorrectable) {
  SimCorrectionInput in = BaseInput(2.0);
  in.model = SmallModel(8, 0);
  in.limits.travel_min_mm = {-15, -300, -200};  // the part is 40 mm wide in x
  const auto r = RunSimulationCorrection(in);
  ASSERT_TRUE(r.ok()) << r.status().ToString();
  Print("travel", *r);
  std::printf("  why_not: %s\n", r->why_not.c_str());
  EXPECT_TRUE(HasDefect(r->defects_before, "axis_limit"));
  EXPECT_FALSE(r->corrected);
  EXPECT_EQ(r->rounds, 1);
  EXPECT_TRUE(HasDefect(r->defects_after, "axis_limit"));
  EXPECT_NE(r->why_not.find("machine's limits"), std::string::npos) << r->why_not;
}

}  // namespace
}  // namespace formloop::planning
