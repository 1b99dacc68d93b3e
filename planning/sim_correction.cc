#include "planning/sim_correction.h"

#include <algorithm>
#include <cmath>
#include <numbers>

#include <Eigen/Geometry>

#include "core/number_text.h"
#include "core/random.h"
#include "nc-gen/cutter_locations.h"
#include "nc-gen/moves.h"
#include "reconstruction/analytic_surface.h"
#include "simulation/virtual_machine.h"

namespace formloop::planning {
namespace {

constexpr double kInf = std::numeric_limits<double>::infinity();

// ---------------------------------------------------------------- surface measures

// A (u, v) grid whose spacing on Q is about grid_mm: the counts follow the 3-D lengths of the middle
// iso-lines (the surfaces here are graphs or close to it, so that is a fair measure of the spacing).
struct ParamGrid {
  recon::ParamDomain dom;
  int nu = 2, nv = 2;
  double u(int i) const { return dom.u_min + (dom.u_max - dom.u_min) * i / (nu - 1); }
  double v(int j) const { return dom.v_min + (dom.v_max - dom.v_min) * j / (nv - 1); }
};

double IsoLineLengthMm(const recon::BSplineSurface& q, bool along_u) {
  const recon::ParamDomain d = q.domain();
  constexpr int kSteps = 200;
  double length = 0;
  Eigen::Vector3d prev;
  for (int k = 0; k <= kSteps; ++k) {
    const double t = static_cast<double>(k) / kSteps;
    const Eigen::Vector3d p = along_u ? q.Point(d.u_min + t * (d.u_max - d.u_min), 0.5 * (d.v_min + d.v_max))
                                      : q.Point(0.5 * (d.u_min + d.u_max), d.v_min + t * (d.v_max - d.v_min));
    if (k > 0) length += (p - prev).norm();
    prev = p;
  }
  return length;
}

ParamGrid GridOn(const recon::BSplineSurface& q, double grid_mm) {
  ParamGrid g;
  g.dom = q.domain();
  const double step = grid_mm > 0 ? grid_mm : 1.0;
  g.nu = std::max(2, static_cast<int>(std::ceil(IsoLineLengthMm(q, true) / step)) + 1);
  g.nv = std::max(2, static_cast<int>(std::ceil(IsoLineLengthMm(q, false) / step)) + 1);
  return g;
}

// Calls f(k1, k2) for the principal curvatures at every grid node (finite ones only).
template <typename F>
void ForEachCurvature(const recon::BSplineSurface& q, double grid_mm, F&& f) {
  const ParamGrid g = GridOn(q, grid_mm);
  for (int j = 0; j < g.nv; ++j) {
    for (int i = 0; i < g.nu; ++i) {
      const recon::PrincipalCurvatures c = recon::CurvaturesFromDerivatives(q.Derivatives(g.u(i), g.v(j)));
      if (std::isfinite(c.k1) && std::isfinite(c.k2)) f(c.k1, c.k2);
    }
  }
}

// Area S and the width W across the passes (range of S·m, m the plane normal of the raster) from a
// grid of cells: what the surrogate's time model needs.
struct SurfaceExtent {
  double area_mm2 = 0, width_mm = 0;
};

SurfaceExtent ExtentOf(const recon::BSplineSurface& q, double raster_angle_deg) {
  const ParamGrid g = GridOn(q, 2.0);
  const double a = raster_angle_deg * std::numbers::pi / 180;
  const Eigen::Vector3d m(-std::sin(a), std::cos(a), 0);
  const double du = (g.dom.u_max - g.dom.u_min) / (g.nu - 1), dv = (g.dom.v_max - g.dom.v_min) / (g.nv - 1);
  SurfaceExtent e;
  double c_lo = kInf, c_hi = -kInf;
  for (int j = 0; j < g.nv; ++j) {
    for (int i = 0; i < g.nu; ++i) {
      const recon::SurfaceDerivatives d = q.Derivatives(g.u(i), g.v(j));
      c_lo = std::min(c_lo, d.p.dot(m));
      c_hi = std::max(c_hi, d.p.dot(m));
      // Trapezoid weights on the nodes.
      const double w = ((i == 0 || i == g.nu - 1) ? 0.5 : 1.0) * ((j == 0 || j == g.nv - 1) ? 0.5 : 1.0);
      e.area_mm2 += w * d.su.cross(d.sv).norm() * du * dv;
    }
  }
  e.width_mm = c_hi - c_lo;
  return e;
}

// ---------------------------------------------------------------- full check

double HTolMm(const SimCorrectionInput& in) {
  return in.scallop_limit_mm > 0 ? in.scallop_limit_mm : 0.3 * in.tolerance_mm;
}

// Constants of the problem that do not change between rounds.
struct Problem {
  double rho_cc_min_mm = kInf, kappa_cvx_max = 0;
  SurfaceExtent extent;
  double n_max_rpm = 0;
  sim::Model model_without_noise;
  bool has_deflection = false;
};

struct CheckResult {
  std::vector<Defect> defects;
  double e_pred_mm = 0;
  double peak_sys_mm = 0, peak_deflection_mm = 0, peak_scallop_mm = 0;  // what the simulation measured
  int lifted_points = 0, cutter_locations = 0;
  std::shared_ptr<nc::Toolpath> path;  // the tool path checked
  nlohmann::json ToJson() const {
    nlohmann::json d = nlohmann::json::array();
    for (const Defect& x : defects) d.push_back(x.ToJson());
    return {{"defects", d},
            {"e_pred_mm", e_pred_mm},
            {"peak_systematic_mm", peak_sys_mm},
            {"peak_deflection_mm", peak_deflection_mm},
            {"peak_scallop_mm", peak_scallop_mm},
            {"lifted_points", lifted_points},
            {"cutter_locations", cutter_locations}};
  }
};

// Predicted residual at one probe point after pre-compensation (see the header).
double ResidualUm(double sys_um, double deflection_um, double scallop_um, double c_pc, double similarity) {
  return sys_um * (1 - c_pc) + (1 - similarity) * std::abs(sys_um) * c_pc + deflection_um + scallop_um;
}

Status PredictFormError(const SimCorrectionInput& in, const Problem& pb, const nc::Toolpath& path, double c_pc,
                        CheckResult* out) {
  sim::VirtualMachineOptions vm;
  vm.tool_radius_mm = path.options.tool.radius_mm;
  vm.model = pb.model_without_noise;
  vm.seed = in.seed;
  FL_ASSIGN_OR_RETURN(const sim::VirtualMachineResult r,
                      sim::MachineAndProbe(nc::CutterLocationsOf(path), in.probing_plan, vm));
  std::size_t k_defl = r.model.effects.size();
  for (std::size_t k = 0; k < r.model.effects.size(); ++k) {
    if (r.model.effects[k].effect->name() == "tool_deflection") k_defl = k;
  }
  double worst_um = 0;
  for (const sim::InjectedTruth& t : r.truth) {
    const double pred_um = t.surface_um + t.measurement_um;
    const double defl_um = k_defl < t.effect_um.size() ? t.effect_um[k_defl] : 0.0;
    const double sys_um = pred_um - t.scallop_um - defl_um;
    worst_um = std::max(worst_um, std::abs(ResidualUm(sys_um, defl_um, t.scallop_um, c_pc, in.similarity)));
    out->peak_sys_mm = std::max(out->peak_sys_mm, std::abs(sys_um) / 1000);
    out->peak_deflection_mm = std::max(out->peak_deflection_mm, std::abs(defl_um) / 1000);
    out->peak_scallop_mm = std::max(out->peak_scallop_mm, t.scallop_um / 1000);
  }
  out->e_pred_mm = worst_um / 1000 + in.random_um / 1000;
  return Status::Ok();
}

Result<CheckResult> FullCheck(const SimCorrectionInput& in, const Problem& pb, const nc::ToolpathOptions& options,
                              double c_pc) {
  CheckResult out;
  out.path = std::make_shared<nc::Toolpath>();
  FL_ASSIGN_OR_RETURN(*out.path, nc::PlanRaster(*in.surface, options));
  const nc::Toolpath& path = *out.path;
  out.lifted_points = path.lifted_points;
  out.cutter_locations = static_cast<int>(path.points.size());
  const double r = options.tool.radius_mm;
  // Gouge: the planner lifted CL points (that region is left uncut), or the tool is above the gouge-free
  // bound the GA decodes with (r ≤ margin · ρ_cc,min; the margin covers what the 1 mm grid misses).
  const double bound_mm = in.ga.gouge_margin * pb.rho_cc_min_mm;
  if (path.lifted_points > 0 || r > bound_mm) {
    const std::string lifted = path.lifted_points > 0
                                   ? std::to_string(path.lifted_points) + " CL points lifted (largest lift " +
                                         FormatFixed(path.max_lift_mm, 3) + " mm), region left uncut"
                                   : "no CL point lifted, but inside the gouge margin";
    out.defects.push_back({"gouge",
                           lifted + ": tool r " + FormatFixed(r, 2) + " mm, gouge-free bound " +
                               FormatFixed(in.ga.gouge_margin, 2) + " x smallest concave radius " +
                               FormatFixed(pb.rho_cc_min_mm, 2) + " mm = " + FormatFixed(bound_mm, 2) + " mm",
                           r, bound_mm});
  }
  {  // the limit check over the moves as they are made (a million on a large part; never held as a list)
    FL_ASSIGN_OR_RETURN(const nc::ToolpathMoves moves, nc::ToolpathMoves::Of(path));
    if (const Status s = nc::CheckMoveList(moves, in.limits); !s.ok()) {
      out.defects.push_back({"axis_limit", s.message(), 0, 0});
    }
  }
  FL_RETURN_IF_ERROR(PredictFormError(in, pb, path, c_pc, &out));
  // Scallop: the planner's target, and what the virtual machine left at the probe points. A lifted
  // region is material left by the gouge, reported there, not as scallop.
  const double h_tol = HTolMm(in);
  const double scallop_mm = std::max(options.scallop_um / 1000, path.lifted_points > 0 ? 0.0 : out.peak_scallop_mm);
  if (scallop_mm > h_tol) {
    out.defects.push_back(
        {"scallop",
         "scallop " + FormatFixed(scallop_mm * 1000, 2) + " um > h_tol " + FormatFixed(h_tol * 1000, 2) + " um",
         scallop_mm, h_tol});
  }
  if (out.e_pred_mm > in.tolerance_mm) {
    out.defects.push_back({"form_error",
                           "predicted form error " + FormatFixed(out.e_pred_mm * 1000, 2) + " um > tolerance " +
                               FormatFixed(in.tolerance_mm * 1000, 2) + " um (c_pc " + FormatFixed(c_pc, 3) + ")",
                           out.e_pred_mm, in.tolerance_mm});
  }
  return out;
}

// ---------------------------------------------------------------- plans ⇄ surrogate

SurrogateInputs SurrogateFor(const SimCorrectionInput& in, const Problem& pb, const std::vector<double>& radii) {
  SurrogateInputs s;
  s.area_mm2 = pb.extent.area_mm2;
  s.width_mm = pb.extent.width_mm;
  s.t_link_min = in.ga.t_link_min;
  s.finish_depth_mm = in.ga.finish_depth_mm;
  s.cutting_speed_m_per_min = in.ga.cutting_speed_m_per_min;
  s.n_max_rpm = pb.n_max_rpm;
  s.flutes = in.flutes;
  s.youngs_modulus_n_per_mm2 = in.ga.youngs_modulus_n_per_mm2;
  s.k_n = in.ga.k_n;
  s.rho_cc_min_mm = pb.rho_cc_min_mm;
  s.kappa_cvx_max_per_mm = pb.kappa_cvx_max;
  s.h_tol_mm = HTolMm(in);
  s.t_form_mm = in.tolerance_mm;
  s.e_rand_mm = in.random_um / 1000;
  s.similarity = in.similarity;
  s.w_e = in.ga.w_e;
  s.w_t = in.ga.w_t;
  s.f_z_min_mm = in.ga.f_z_min_mm;
  s.f_z_max_mm = in.ga.f_z_max_mm;
  s.s_min_mm = in.ga.s_min_mm;
  s.c_pc_max = in.ga.c_pc_max;
  s.gouge_margin = in.ga.gouge_margin;
  s.max_feed_mm_per_min = in.limits.max_feed_mm_per_min;
  s.tool_radii_mm = radii;
  s.population = in.ga.population;
  s.generations = in.ga.generations;
  s.elites = in.ga.elites;
  return s;
}

// The case plan in surrogate terms: its step-over from its scallop target on the most convex part, its
// f_z from its feed and spindle speed.
struct CasePlanTerms {
  double r = 0, s = 0, f_z = 0;
};

CasePlanTerms CaseTerms(const SimCorrectionInput& in, const Problem& pb) {
  CasePlanTerms c;
  c.r = in.case_plan.tool.radius_mm;
  c.s = std::sqrt(8 * in.case_plan.scallop_um / 1000 / (1 / c.r + pb.kappa_cvx_max));
  c.f_z = in.case_plan.feed_mm_per_min / (in.flutes * std::max(1.0, in.case_plan.spindle_rpm));
  return c;
}

PlanGenes GenesOf(const SimCorrectionInput& in, const Problem& pb, const SurrogateResult& best) {
  PlanGenes g;
  for (const nc::BallEndTool& t : in.tools) {
    if (t.radius_mm == best.r) {
      g.tool_number = t.number;
      break;
    }
  }
  g.tool_radius_mm = best.r;
  g.step_over_mm = best.s;
  g.scallop_um = 1000 * best.s * best.s / 8 * (1 / best.r + pb.kappa_cvx_max);
  g.feed_per_tooth_mm = best.f_z;
  g.spindle_rpm = best.n_rpm;
  g.feed_mm_per_min = best.v_f_mm_per_min;
  g.precompensation_scale = best.c_pc;
  return g;
}

nc::ToolpathOptions PlanOf(const SimCorrectionInput& in, const PlanGenes& g) {
  nc::ToolpathOptions o = in.case_plan;
  o.tool = {g.tool_number, g.tool_radius_mm};
  o.scallop_um = g.scallop_um;
  o.feed_mm_per_min = g.feed_mm_per_min;
  o.spindle_rpm = g.spindle_rpm;
  return o;
}

std::string RadiiText(const std::vector<nc::BallEndTool>& tools) {
  std::vector<double> r;
  for (const nc::BallEndTool& t : tools) r.push_back(t.radius_mm);
  std::sort(r.begin(), r.end());
  std::string s;
  for (double x : r) s += (s.empty() ? "" : ", ") + FormatFixed(x, 2);
  return "{" + s + "}";
}

std::string DefectKinds(const std::vector<Defect>& d) {
  std::string s;
  for (const Defect& x : d) s += (s.empty() ? "" : "; ") + x.kind + ": " + x.detail;
  return s;
}

// The surrogate's terms from what the full simulation of `best` measured (§4.1 "rescale the surrogate
// terms from the simulation"):
//  - E_sys: the peak systematic deviation of the model at this plan;
//  - deflection: scaled so the surrogate's δ at `best` equals the model's peak tool_deflection there
//    (0 when the model has none: then the force model was only a prior, the case's data show no
//    deflection);
//  - scallop: the part of the simulated peak scallop the formula misses (the cusp left between CL points
//    along a pass, the path's chord error) is a floor that does not shrink with s², so it is added as an
//    offset, not a factor (a factor would blow up at small step-overs);
//  - a tool the planner had to lift is struck.
void RescaleSurrogate(const SurrogateResult& best, const CheckResult& check, SurrogateInputs* sur) {
  sur->e_sys_mm = check.peak_sys_mm;
  if (best.deflection_mm > 0) sur->deflection_scale *= check.peak_deflection_mm / best.deflection_mm;
  if (check.lifted_points == 0) sur->scallop_offset_mm += std::max(0.0, check.peak_scallop_mm - best.scallop_mm);
  if (check.lifted_points > 0) std::erase(sur->tool_radii_mm, best.r);
}

std::string NoToolText(const Problem& pb, const SurrogateInputs& sur, const std::vector<nc::BallEndTool>& magazine) {
  return "no tool in the magazine is gouge-free: smallest concave radius " + FormatFixed(pb.rho_cc_min_mm, 2) +
         " mm, gouge-free needs r <= " + FormatFixed(sur.gouge_margin * pb.rho_cc_min_mm, 2) + " mm, magazine radii " +
         RadiiText(magazine) + " mm" +
         (sur.tool_radii_mm.size() < magazine.size() ? " (tools the planner had to lift struck)" : "") +
         " -> PLAN-NO-TOOL";
}

// 2. The surrogate for this part, its terms from the case plan's simulation: E_sys, the deflection scale
// (when the model has tool_deflection: its peak at the case plan over the force model's δ there) and
// t_ref (the case plan's surrogate time).
SurrogateInputs InitialSurrogate(const SimCorrectionInput& in, const Problem& pb, const CheckResult& before) {
  std::vector<double> radii;
  for (const nc::BallEndTool& t : in.tools) radii.push_back(t.radius_mm);
  SurrogateInputs sur = SurrogateFor(in, pb, radii);
  const CasePlanTerms cp = CaseTerms(in, pb);
  sur.e_sys_mm = before.peak_sys_mm;
  if (pb.has_deflection)
    sur.deflection_scale = before.peak_deflection_mm / SurrogateDeflectionMm(sur, cp.r, cp.s, cp.f_z);
  sur.t_ref_min = EvaluateSurrogate(sur, cp.r, cp.s, cp.f_z, 0).time_min;
  return sur;
}

Status ValidateInput(const SimCorrectionInput& in) {
  if (in.surface == nullptr || !in.surface->valid()) return Status::BadInput("sim-correction: no surface Q");
  if (in.tools.empty()) return Status::BadInput("sim-correction: the magazine (tools) is empty");
  if (in.probing_plan.points.empty()) return Status::BadInput("sim-correction: the probing plan is empty");
  if (!(in.tolerance_mm > 0)) return Status::BadInput("sim-correction: tolerance_mm must be > 0");
  if (!(in.similarity >= 0 && in.similarity <= 1)) return Status::BadInput("sim-correction: similarity not in [0, 1]");
  if (in.flutes < 1) return Status::BadInput("sim-correction: flutes must be >= 1");
  if (in.ga.population < 4 || in.ga.generations < 1 || in.ga.max_rounds < 1) {
    return Status::BadInput("sim-correction: GA needs population >= 4, generations >= 1, max_rounds >= 1");
  }
  FL_RETURN_IF_ERROR(in.limits.Validate());
  return in.case_plan.Validate();
}

Problem ProblemOf(const SimCorrectionInput& in) {
  Problem pb;
  pb.rho_cc_min_mm = SmallestConcaveRadiusMm(*in.surface);
  pb.kappa_cvx_max = LargestConvexCurvature(*in.surface);
  pb.extent = ExtentOf(*in.surface, in.case_plan.raster_angle_deg);
  pb.n_max_rpm = std::min(in.ga.n_max_rpm, in.limits.max_spindle_rpm);
  pb.model_without_noise = in.model.WithoutNoise();
  pb.has_deflection = pb.model_without_noise.Has("tool_deflection");
  return pb;
}

}  // namespace

// ---------------------------------------------------------------- public pieces

double SmallestConcaveRadiusMm(const recon::BSplineSurface& q, double grid_mm) {
  double k_min = 0;
  ForEachCurvature(q, grid_mm, [&](double, double k2) { k_min = std::min(k_min, k2); });
  return k_min < 0 ? -1 / k_min : kInf;
}

double LargestConvexCurvature(const recon::BSplineSurface& q, double grid_mm) {
  double k_max = 0;
  ForEachCurvature(q, grid_mm, [&](double k1, double) { k_max = std::max(k_max, k1); });
  return k_max;
}

Result<SimCorrectionResult> RunSimulationCorrection(const SimCorrectionInput& input) {
  FL_RETURN_IF_ERROR(ValidateInput(input));
  const Problem pb = ProblemOf(input);
  SimCorrectionResult res;
  Rng rng(input.seed);

  // 1. The case plan on the new part, without pre-compensation (what would happen if it ran as given).
  FL_ASSIGN_OR_RETURN(CheckResult before, FullCheck(input, pb, input.case_plan, 0.0));
  res.defects_before = before.defects;
  res.predicted_form_error_before_um = before.e_pred_mm * 1000;
  if (before.defects.empty()) {
    // Nothing to correct: the case's plan stands (the caller keeps it). The GA is not run, so no candidate is
    // reported that the part would never be cut with (issue 17: reg-blade-a's report named the GA's tool 7,
    // r = 6 mm, while the program used the case's tool 3, r = 2 mm).
    res.corrected = true;
    res.predicted_form_error_after_um = res.predicted_form_error_before_um;
    res.path = std::move(before.path);
    return res;
  }
  before.path.reset();  // not cut: gone before the candidates are planned

  SurrogateInputs sur = InitialSurrogate(input, pb, before);
  std::vector<Defect> remaining = before.defects;
  SurrogateResult last_surrogate;
  for (int round = 1; round <= input.ga.max_rounds; ++round) {
    res.rounds = round;
    nlohmann::json h = {{"round", round}, {"surrogate", sur.ToJson()}};
    if (GougeFreeRadii(sur).empty()) {
      res.why_not = NoToolText(pb, sur, input.tools);
      res.history.push_back(h);
      break;
    }
    nlohmann::json ga_history;
    const SurrogateResult best = SurrogateGa(sur, rng.Fork(), &ga_history);
    h["ga"] = ga_history;
    h["ga"]["best"] = best.ToJson();
    res.chosen = GenesOf(input, pb, best);
    res.plan = PlanOf(input, res.chosen);
    res.precompensation_scale = best.c_pc;
    h["genes"] = res.chosen.ToJson();
    // 3. The full check of the GA's plan.
    FL_ASSIGN_OR_RETURN(CheckResult check, FullCheck(input, pb, res.plan, best.c_pc));
    h["check"] = check.ToJson();
    res.history.push_back(h);
    res.defects_after = check.defects;
    res.predicted_form_error_after_um = check.e_pred_mm * 1000;
    remaining = check.defects;
    if (check.defects.empty()) {
      res.corrected = true;
      res.path = std::move(check.path);
      return res;
    }
    for (const Defect& d : check.defects) {
      if (d.kind == "axis_limit") {  // travel does not depend on the genes; feed and spindle are capped
        res.why_not = "the plan leaves the machine's limits whatever the GA chooses: " + d.detail;
        return res;
      }
    }
    // 4. Rescale the surrogate from what the simulation measured.
    RescaleSurrogate(best, check, &sur);
    last_surrogate = best;
  }
  if (res.why_not.empty()) {
    res.why_not = "after " + std::to_string(res.rounds) +
                  " rounds the simulated plan still has: " + DefectKinds(remaining) +
                  " (the GA's best surrogate e_pred " + FormatFixed(last_surrogate.e_pred * 1000, 2) +
                  " um, tolerance " + FormatFixed(input.tolerance_mm * 1000, 2) + " um) -> escalate to a planner";
  }
  return res;
}

// ---------------------------------------------------------------- JSON

nlohmann::json Defect::ToJson() const {
  return {{"kind", kind}, {"detail", detail}, {"value", value}, {"limit", limit}};
}

nlohmann::json PlanGenes::ToJson() const {
  return {{"tool_number", tool_number},
          {"tool_radius_mm", tool_radius_mm},
          {"step_over_mm", step_over_mm},
          {"scallop_um", scallop_um},
          {"feed_per_tooth_mm", feed_per_tooth_mm},
          {"feed_mm_per_min", feed_mm_per_min},
          {"spindle_rpm", spindle_rpm},
          {"precompensation_scale", precompensation_scale}};
}

nlohmann::json GaOptions::ToJson() const {
  return {{"population", population},
          {"generations", generations},
          {"elites", elites},
          {"max_rounds", max_rounds},
          {"w_e", w_e},
          {"w_t", w_t},
          {"f_z_min_mm", f_z_min_mm},
          {"f_z_max_mm", f_z_max_mm},
          {"cutting_speed_m_per_min", cutting_speed_m_per_min},
          {"n_max_rpm", n_max_rpm},
          {"finish_depth_mm", finish_depth_mm},
          {"t_link_min", t_link_min},
          {"youngs_modulus_n_per_mm2", youngs_modulus_n_per_mm2},
          {"k_n", k_n},
          {"s_min_mm", s_min_mm},
          {"c_pc_max", c_pc_max},
          {"gouge_margin", gouge_margin}};
}

nlohmann::json SimCorrectionResult::ToJson() const {
  const bool has_plan = chosen.tool_radius_mm > 0;
  auto list = [](const std::vector<Defect>& d) {
    nlohmann::json a = nlohmann::json::array();
    for (const Defect& x : d) a.push_back(x.ToJson());
    return a;
  };
  return {{"corrected", corrected},
          {"defects_before", list(defects_before)},
          {"defects_after", list(defects_after)},
          {"applied", applied},
          {"candidate", has_plan ? chosen.ToJson() : nlohmann::json(nullptr)},
          {"candidate_plan", !has_plan ? nlohmann::json(nullptr)
                                       : nlohmann::json{{"tool_number", plan.tool.number},
                                                        {"tool_radius_mm", plan.tool.radius_mm},
                                                        {"scallop_um", plan.scallop_um},
                                                        {"feed_mm_per_min", plan.feed_mm_per_min},
                                                        {"spindle_rpm", plan.spindle_rpm},
                                                        {"max_point_spacing_mm", plan.max_point_spacing_mm},
                                                        {"raster_angle_deg", plan.raster_angle_deg}}},
          {"predicted_form_error_before_um", predicted_form_error_before_um},
          {"predicted_form_error_after_um", predicted_form_error_after_um},
          {"precompensation_scale", precompensation_scale},
          {"rounds", rounds},
          {"history", history},
          {"why_not", why_not}};
}

}  // namespace formloop::planning