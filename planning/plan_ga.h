#pragma once
// The plan GA of the simulation-correction step (spec/process-optimization.md §4): the fast surrogate of
// §4.3 (machining time, tool deflection, scallop and the predicted form error of a plan r, s, f_z, c_pc)
// and formloop's one adaptive genetic algorithm (planning/aga.h, spec §1.6; Srinivas & Patnaik 1994) with
// the §4.2 decoding of genes into a gouge-free tool, a step-over below the scallop bound and a feed per
// tooth within the machine's feed. A brute-force grid over the same space is the oracle the tests hold
// the GA to (§4.4). Everything is seeded (formloop::Rng), so the same input gives the same plan.

#include <cstdint>
#include <limits>
#include <vector>

#include <nlohmann/json.hpp>

namespace formloop::planning {

// The §4.3 surrogate's constants.
struct SurrogateInputs {
  double area_mm2 = 10000;  // S
  double width_mm = 100;    // W_y: extent across the passes
  double t_link_min = 0.02;
  double finish_depth_mm = 0.3;  // a_p,fin
  double cutting_speed_m_per_min = 200;
  double n_max_rpm = 18000;
  int flutes = 2;  // z
  double youngs_modulus_n_per_mm2 = 6e5;
  double k_n = 2500;
  double rho_cc_min_mm = 5;
  double kappa_cvx_max_per_mm = 0.05;
  double h_tol_mm = 0.010;
  double t_form_mm = 0.050;
  double e_sys_mm = 0.040;
  double e_rand_mm = 0.006;
  double similarity = 0.88;  // A
  double w_e = 0.7, w_t = 0.3;
  double t_ref_min = 10;
  double f_z_min_mm = 0.02, f_z_max_mm = 0.15;
  double s_min_mm = 0.05;
  double c_pc_max = 1.2;
  double gouge_margin = 0.9;
  double max_feed_mm_per_min = std::numeric_limits<double>::infinity();  // caps f_z at each n
  // Rescaling from the full simulation (1 and 0: the surrogate as printed): δ is multiplied by
  // deflection_scale, h gets scallop_offset_mm added (see RescaleSurrogate in the .cc).
  double deflection_scale = 1, scallop_offset_mm = 0;
  std::vector<double> tool_radii_mm = {1.5, 2, 3, 4, 5, 6};
  // AGA settings.
  int population = 60, generations = 100, elites = 2;
  // The reference instance of spec/process-optimization.md §4.4.
  static SurrogateInputs ReferenceInstance() { return {}; }
  nlohmann::json ToJson() const;
};

struct SurrogateResult {
  double r = 0, s = 0, f_z = 0, c_pc = 0;
  double n_rpm = 0, v_f_mm_per_min = 0;
  double time_min = 0, deflection_mm = 0, scallop_mm = 0, e_pred = 0, J = 0;
  double fitness = -std::numeric_limits<double>::infinity();  // −J, minus the penalty when e_pred > t_form
  int tool_index = -1;  // into the sorted gouge-free radii; −1: none (PLAN-NO-TOOL)
  int generations = 0;  // GA only: generations run
  nlohmann::json ToJson() const;
};

// The gouge-free radii (r ≤ margin · ρ_cc,min), sorted ascending, duplicates kept once.
std::vector<double> GougeFreeRadii(const SurrogateInputs& in);
// The surrogate at one plan (no decoding; f_z is taken as given).
SurrogateResult EvaluateSurrogate(const SurrogateInputs& in, double r, double s, double f_z, double c_pc);
// AGA of §1.6 with the §4.2 decoding; history (optional) gets {"best_J": [...per generation]}.
SurrogateResult SurrogateGa(const SurrogateInputs& in, std::uint64_t seed, nlohmann::json* history);
// Every gouge-free tool × n_s step-overs × n_f log-spaced f_z × n_c values of c_pc in [0, c_pc_max].
SurrogateResult SurrogateBruteForce(const SurrogateInputs& in, int n_s = 301, int n_f = 301, int n_c = 25);

// The surrogate's tool deflection δ (mm) at one plan, before deflection_scale: a cantilever of length
// max(25, 8r) and shank diameter 1.6 r under the normal cutting force k_n f_z^0.75 sqrt(s a_p,fin).
double SurrogateDeflectionMm(const SurrogateInputs& in, double r, double s, double f_z);

}  // namespace formloop::planning
