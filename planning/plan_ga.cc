#include "planning/plan_ga.h"

#include <algorithm>
#include <cmath>
#include <numbers>

#include "planning/aga.h"

namespace formloop::planning {
namespace {

// ---------------------------------------------------------------- surrogate (§4.3)

double SpindleRpm(const SurrogateInputs& in, double r) {
  const double ap = std::min(in.finish_depth_mm, r);
  const double d_eff = 2 * std::sqrt(ap * (2 * r - ap));  // effective cutting diameter at a_p,fin
  return std::min(in.n_max_rpm, 1000 * in.cutting_speed_m_per_min / (std::numbers::pi * d_eff));
}

// Largest step-over that keeps the scallop at h_tol on the most convex part (§4.2), less the floor the
// simulation measured (scallop_offset_mm; 0 in the printed surrogate).
double MaxStepOverMm(const SurrogateInputs& in, double r) {
  const double h_mm = std::max(in.h_tol_mm - in.scallop_offset_mm, 1e-3 * in.h_tol_mm);
  return std::sqrt(8 * h_mm / (1 / r + in.kappa_cvx_max_per_mm));
}

// Largest f_z: the range's top, capped by the machine's feed at this tool's spindle speed.
double MaxFeedPerToothMm(const SurrogateInputs& in, double r) {
  return std::min(in.f_z_max_mm, in.max_feed_mm_per_min / (in.flutes * SpindleRpm(in, r)));
}

// ---------------------------------------------------------------- decoding (§4.2)

SurrogateResult Decode(const SurrogateInputs& in, const std::vector<double>& radii, const std::vector<double>& xi) {
  const int k_ok = static_cast<int>(radii.size());
  const int i = std::min(k_ok - 1, static_cast<int>(std::floor(xi[0] * k_ok)));
  const double r = radii[static_cast<std::size_t>(i)];
  const double s_max = MaxStepOverMm(in, r);
  const double s_lo = std::min(in.s_min_mm, s_max);
  const double s = s_lo + xi[1] * (s_max - s_lo);
  const double f_hi = std::max(in.f_z_min_mm, MaxFeedPerToothMm(in, r));
  const double f_z = in.f_z_min_mm * std::pow(f_hi / in.f_z_min_mm, xi[2]);
  SurrogateResult out = EvaluateSurrogate(in, r, s, f_z, in.c_pc_max * xi[3]);
  out.tool_index = i;
  return out;
}

}  // namespace

double SurrogateDeflectionMm(const SurrogateInputs& in, double r, double s, double f_z) {
  const double force_n = in.k_n * std::pow(f_z, 0.75) * std::sqrt(s * in.finish_depth_mm);
  const double length_mm = std::max(25.0, 8 * r);
  const double inertia_mm4 = std::numbers::pi * std::pow(1.6 * r, 4) / 64;  // shank ≈ 1.6 r
  const double stiffness = 3 * in.youngs_modulus_n_per_mm2 * inertia_mm4 / std::pow(length_mm, 3);
  return force_n / stiffness;
}

std::vector<double> GougeFreeRadii(const SurrogateInputs& in) {
  std::vector<double> r;
  for (double x : in.tool_radii_mm) {
    if (x > 0 && x <= in.gouge_margin * in.rho_cc_min_mm) r.push_back(x);
  }
  std::sort(r.begin(), r.end());
  r.erase(std::unique(r.begin(), r.end()), r.end());
  return r;
}

SurrogateResult EvaluateSurrogate(const SurrogateInputs& in, double r, double s, double f_z, double c_pc) {
  SurrogateResult out;
  out.r = r;
  out.s = s;
  out.f_z = f_z;
  out.c_pc = c_pc;
  out.n_rpm = SpindleRpm(in, r);
  out.v_f_mm_per_min = f_z * in.flutes * out.n_rpm;
  out.time_min = in.area_mm2 / (s * out.v_f_mm_per_min) + in.width_mm / s * in.t_link_min;
  out.deflection_mm = in.deflection_scale * SurrogateDeflectionMm(in, r, s, f_z);
  out.scallop_mm = in.scallop_offset_mm + s * s / 8 * (1 / r + in.kappa_cvx_max_per_mm);
  out.e_pred = in.e_sys_mm * std::abs(1 - c_pc) + (1 - in.similarity) * in.e_sys_mm * c_pc + out.deflection_mm +
               out.scallop_mm + in.e_rand_mm;
  out.J = in.w_e * out.e_pred / in.t_form_mm + in.w_t * out.time_min / in.t_ref_min;
  out.fitness = -out.J - (out.e_pred > in.t_form_mm ? 10 * (out.e_pred / in.t_form_mm - 1) : 0.0);
  return out;
}

SurrogateResult SurrogateGa(const SurrogateInputs& in, std::uint64_t seed, nlohmann::json* history) {
  const std::vector<double> radii = GougeFreeRadii(in);
  if (radii.empty()) return {};  // PLAN-NO-TOOL: tool_index −1
  // Fitness −J (penalised); among equal fitness the shorter machining time wins.
  const AgaObjective objective = [&](const std::vector<double>& xi) {
    const SurrogateResult e = Decode(in, radii, xi);
    return AgaScore{e.fitness, -e.time_min};
  };
  const AgaOptions options{.population = in.population, .generations = in.generations, .elites = in.elites};
  const AgaResult run = RunAga(4, objective, options, seed);
  SurrogateResult out = Decode(in, radii, run.genes);
  out.generations = run.generations;
  if (history != nullptr) {
    std::vector<double> best_j;
    for (const std::vector<double>& xi : run.best_genes) best_j.push_back(Decode(in, radii, xi).J);
    (*history)["best_J"] = best_j;
  }
  return out;
}

SurrogateResult SurrogateBruteForce(const SurrogateInputs& in, int n_s, int n_f, int n_c) {
  SurrogateResult best;
  const std::vector<double> radii = GougeFreeRadii(in);
  for (std::size_t i = 0; i < radii.size(); ++i) {
    const double r = radii[i], s_max = MaxStepOverMm(in, r), s_lo = std::min(in.s_min_mm, s_max);
    const double f_hi = std::max(in.f_z_min_mm, MaxFeedPerToothMm(in, r));
    for (int a = 0; a < n_s; ++a) {
      const double s = s_lo + (s_max - s_lo) * a / std::max(1, n_s - 1);
      for (int b = 0; b < n_f; ++b) {
        const double f_z =
            in.f_z_min_mm * std::pow(f_hi / in.f_z_min_mm, static_cast<double>(b) / std::max(1, n_f - 1));
        for (int c = 0; c < n_c; ++c) {
          const double c_pc = in.c_pc_max * c / std::max(1, n_c - 1);
          SurrogateResult e = EvaluateSurrogate(in, r, s, f_z, c_pc);
          if (e.fitness > best.fitness) {
            best = e;
            best.tool_index = static_cast<int>(i);
          }
        }
      }
    }
  }
  return best;
}

nlohmann::json SurrogateInputs::ToJson() const {
  return {{"area_mm2", area_mm2},
          {"width_mm", width_mm},
          {"t_link_min", t_link_min},
          {"finish_depth_mm", finish_depth_mm},
          {"cutting_speed_m_per_min", cutting_speed_m_per_min},
          {"n_max_rpm", n_max_rpm},
          {"flutes", flutes},
          {"youngs_modulus_n_per_mm2", youngs_modulus_n_per_mm2},
          {"k_n", k_n},
          {"rho_cc_min_mm", std::isfinite(rho_cc_min_mm) ? nlohmann::json(rho_cc_min_mm) : nullptr},
          {"kappa_cvx_max_per_mm", kappa_cvx_max_per_mm},
          {"h_tol_mm", h_tol_mm},
          {"t_form_mm", t_form_mm},
          {"e_sys_mm", e_sys_mm},
          {"e_rand_mm", e_rand_mm},
          {"similarity", similarity},
          {"w_e", w_e},
          {"w_t", w_t},
          {"t_ref_min", t_ref_min},
          {"f_z_min_mm", f_z_min_mm},
          {"f_z_max_mm", f_z_max_mm},
          {"s_min_mm", s_min_mm},
          {"c_pc_max", c_pc_max},
          {"gouge_margin", gouge_margin},
          {"max_feed_mm_per_min", std::isfinite(max_feed_mm_per_min) ? nlohmann::json(max_feed_mm_per_min) : nullptr},
          {"deflection_scale", deflection_scale},
          {"scallop_offset_mm", scallop_offset_mm},
          {"tool_radii_mm", tool_radii_mm}};
}

nlohmann::json SurrogateResult::ToJson() const {
  return {{"r_mm", r},
          {"s_mm", s},
          {"f_z_mm", f_z},
          {"c_pc", c_pc},
          {"n_rpm", n_rpm},
          {"v_f_mm_per_min", v_f_mm_per_min},
          {"time_min", time_min},
          {"deflection_mm", deflection_mm},
          {"scallop_mm", scallop_mm},
          {"e_pred_mm", e_pred},
          {"J", J},
          {"fitness", std::isfinite(fitness) ? nlohmann::json(fitness) : nullptr},
          {"tool_index", tool_index},
          {"generations", generations}};
}

}  // namespace formloop::planning
