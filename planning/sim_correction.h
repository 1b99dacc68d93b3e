#pragma once
// The simulation-correction loop (spec/simulation.md §4; route 0.80 ≤ A ≤ 0.95 of the per-part pipeline).
//
// The retrieved case is close but not equal: its plan and its learned model are tried on the NEW part in
// the virtual machine, the defects are predicted, and the plan is corrected by the plan GA of
// spec/process-optimization.md §4 (AGA of §1.6 on a fast surrogate, §4.3) until the full simulation
// shows no defect, or the result says exactly why not. A case plan with no predicted defect is not
// corrected at all (no GA round, no candidate): it stands as it is.
//
// Defects of a plan (the "full check"):
//   gouge       the planner lifted CL points (a concave radius below the ball): that region is left uncut;
//               or the tool is above the GA's gouge-free bound margin · ρ_cc,min (no lift yet, no margin)
//   scallop     the scallop (the planner's target, and the peak the virtual machine leaves at the probe
//               points) above h_tol
//   axis_limit  the move list fails nc::CheckMoveList (travel, feed, spindle)
//   form_error  predicted form error above the tolerance α. The plan is machined on the virtual machine
//               with the case's model without its noise; per probe point the prediction splits into the
//               scallop (geometry, not compensable by moving the path), the model's tool_deflection (it
//               depends on the new plan, the stored field was learned with the case's plan, so it is not
//               pre-compensated, like δ in the surrogate) and the rest `sys`, which pre-compensation by
//               c_pc removes in proportion to A:  residual = sys·(1 − c_pc) + (1 − A)·|sys|·c_pc
//               + deflection + scallop;  e_pred = max |residual| + e_rand.
//
// Rounds (at most ga.max_rounds): GA on the surrogate → full check; when the check fails, the surrogate's
// terms are rescaled from what the simulation measured (E_sys, deflection, scallop), a tool that was
// lifted is struck, and the GA runs again. Everything is seeded from input.seed (formloop::Rng), so the
// same input gives the same result and the same JSON.

#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "core/status.h"
#include "metrology/probe.h"
#include "nc-gen/post.h"
#include "nc-gen/toolpath.h"
#include "planning/plan_ga.h"
#include "reconstruction/bspline_surface.h"
#include "simulation/model.h"

namespace formloop::planning {

struct Defect {
  std::string kind;    // "gouge", "scallop", "form_error", "axis_limit"
  std::string detail;  // one sentence with the figures
  double value = 0;    // gouge: tool r; scallop: scallop height; form_error: e_pred (mm); axis_limit: 0
  double limit = 0;    // gouge: margin · ρ_cc,min; scallop: h_tol; form_error: α (mm); axis_limit: 0
  nlohmann::json ToJson() const;
};

// The decoded plan: what the GA chose, in machine terms.
struct PlanGenes {
  int tool_number = 0;
  double tool_radius_mm = 0;
  double step_over_mm = 0;
  double scallop_um = 0;  // target handed to the planner: h = s²/8 · (1/r + κ_cvx,max)
  double feed_per_tooth_mm = 0;
  double feed_mm_per_min = 0;
  double spindle_rpm = 0;
  double precompensation_scale = 0;  // c_pc
  nlohmann::json ToJson() const;
};

// Plan GA settings (spec/process-optimization.md §1.6, §4.2–4.4 defaults).
struct GaOptions {
  int population = 60;
  int generations = 100;
  int elites = 2;
  int max_rounds = 3;
  double w_e = 0.7, w_t = 0.3;
  double f_z_min_mm = 0.02, f_z_max_mm = 0.15;
  double cutting_speed_m_per_min = 200;  // v_c
  double n_max_rpm = 18000;              // further capped by MachineLimits::max_spindle_rpm
  double finish_depth_mm = 0.3;          // a_p,fin
  double t_link_min = 0.02;              // per pass
  double youngs_modulus_n_per_mm2 = 6e5;
  double k_n = 2500;  // N·mm^-1.75
  double s_min_mm = 0.05;
  double c_pc_max = 1.2;
  double gouge_margin = 0.9;  // gouge-free: r ≤ margin · ρ_cc,min
  nlohmann::json ToJson() const;
};

struct SimCorrectionInput {
  const recon::BSplineSurface* surface = nullptr;  // ideal surface Q of the NEW part
  nc::ToolpathOptions case_plan;                   // the retrieved case's plan as given
  std::vector<nc::BallEndTool> tools;              // the machine's magazine
  int flutes = 2;
  sim::Model model;               // the case's learned model (may be empty)
  double similarity = 0.9;        // A of the retrieval
  double tolerance_mm = 0.010;    // α (t_form)
  double scallop_limit_mm = 0.0;  // h_tol; 0 → 0.3 · tolerance
  double random_um = 2.0;         // e_rand = 2σ of the random error
  nc::MachineLimits limits;
  metrology::ProbingPlan probing_plan;  // where the predicted form error is evaluated
  std::uint64_t seed = 1;
  GaOptions ga;
};

struct SimCorrectionResult {
  bool corrected = false;
  std::vector<Defect> defects_before, defects_after;
  // The GA's candidate: the last plan it proposed (null in JSON when none: PLAN-NO-TOOL). It is the plan the
  // part is cut with only when `corrected`; otherwise the caller keeps the case's plan (see `applied`).
  PlanGenes chosen;
  nc::ToolpathOptions plan;  // the candidate, ready for nc::PlanRaster
  // Set by the caller (planning::ChoosePlan): the plan the run actually uses and why, so the written result
  // never shows the candidate as the plan when the case's plan was kept. Null until set.
  nlohmann::json applied;
  double predicted_form_error_before_um = 0, predicted_form_error_after_um = 0;
  double precompensation_scale = 0;  // c_pc applied to the model's predicted field before the first cut
  int rounds = 0;
  nlohmann::json history = nlohmann::json::array();  // per round: GA best J per generation, genes, check
  std::string why_not;                               // when !corrected
  // The tool path the full check planned for the plan the run will use when the check passed it (the case's
  // plan when it had no defect, else the GA's corrected plan), so the caller can cut it without planning it
  // again (a million-point path is about a second); null otherwise.
  std::shared_ptr<nc::Toolpath> path;
  nlohmann::json ToJson() const;
};

// Errors (Status) are for bad input and failures of the planner or the virtual machine; a plan that
// cannot be corrected is a result with corrected = false and why_not.
Result<SimCorrectionResult> RunSimulationCorrection(const SimCorrectionInput& input);

// ---- Pieces exposed for tests ----

// ρ_cc,min: the smallest concave principal radius (−1/k over k < 0) on a grid of about grid_mm spacing
// on Q; +inf when Q has no concave point.
double SmallestConcaveRadiusMm(const recon::BSplineSurface& q, double grid_mm = 1.0);
// κ_cvx,max: the largest convex principal curvature (≥ 0) on the same grid, 1/mm.
double LargestConvexCurvature(const recon::BSplineSurface& q, double grid_mm = 1.0);

}  // namespace formloop::planning
