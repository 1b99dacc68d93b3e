#include "planning/plan_ga.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <numbers>
#include <numeric>

#include "core/random.h"

namespace formloop::planning {
namespace {

constexpr double kInf = std::numeric_limits<double>::infinity();

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

// ---------------------------------------------------------------- AGA (§1.6)

using Genes = std::array<double, 4>;

struct Individual {
  Genes xi{};
  SurrogateResult eval;
};

SurrogateResult Decode(const SurrogateInputs& in, const std::vector<double>& radii, const Genes& xi) {
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

// Tournament and elite order: higher fitness (equal within 1e-12 relative), then shorter time, then
// lower index.
bool Better(const std::vector<Individual>& pop, std::size_t a, std::size_t b) {
  const double fa = pop[a].eval.fitness, fb = pop[b].eval.fitness;
  if (std::abs(fa - fb) > 1e-12 * std::max(std::abs(fa), std::abs(fb))) return fa > fb;
  if (pop[a].eval.time_min != pop[b].eval.time_min) return pop[a].eval.time_min < pop[b].eval.time_min;
  return a < b;
}

std::size_t Tournament(const std::vector<Individual>& pop, Rng& rng) {
  const std::size_t a = rng.UniformIndex(pop.size()), b = rng.UniformIndex(pop.size());
  return Better(pop, a, b) ? a : b;
}

struct FitnessStats {
  double f_max = -kInf, f_avg = 0;
  bool flat = true;  // f_max − f_avg negligible: the fixed probabilities apply
};

FitnessStats StatsOf(const std::vector<Individual>& pop) {
  FitnessStats st;
  for (const Individual& ind : pop) {
    st.f_max = std::max(st.f_max, ind.eval.fitness);
    st.f_avg += ind.eval.fitness;
  }
  st.f_avg /= static_cast<double>(pop.size());
  st.flat = st.f_max - st.f_avg <= 1e-12 * std::max(std::abs(st.f_max), 1e-300);
  return st;
}

double CrossoverProbability(const FitnessStats& st, double f_parent) {
  if (st.flat || f_parent < st.f_avg) return 0.9;
  return 0.9 - 0.3 * (f_parent - st.f_avg) / (st.f_max - st.f_avg);
}

// As printed (f_max − f): the best gets the largest rate around it; elitism keeps its unmutated copy.
double MutationProbability(const FitnessStats& st, double f) {
  if (st.flat || f < st.f_avg) return 0.1;
  return 0.1 - 0.099 * (st.f_max - f) / (st.f_max - st.f_avg);
}

Individual MakeChild(const SurrogateInputs& in, const std::vector<double>& radii, const Genes& xi,
                     const FitnessStats& st, double sigma, Rng& rng) {
  Individual child{xi, Decode(in, radii, xi)};
  const double p_m = MutationProbability(st, child.eval.fitness);
  bool mutated = false;
  for (double& g : child.xi) {
    if (rng.Uniform() < p_m) {
      g = std::clamp(g + sigma * rng.Normal(), 0.0, 1.0);
      mutated = true;
    }
  }
  if (mutated) child.eval = Decode(in, radii, child.xi);
  return child;
}

std::vector<std::size_t> RankedIndices(const std::vector<Individual>& pop) {
  std::vector<std::size_t> idx(pop.size());
  std::iota(idx.begin(), idx.end(), 0);
  std::stable_sort(idx.begin(), idx.end(), [&](std::size_t a, std::size_t b) { return Better(pop, a, b); });
  return idx;
}

std::vector<Individual> NextGeneration(const SurrogateInputs& in, const std::vector<double>& radii,
                                       const std::vector<Individual>& pop, int g, Rng& rng) {
  const FitnessStats st = StatsOf(pop);
  const double sigma = 0.1 - 0.09 * g / std::max(1, in.generations - 1);
  std::vector<Individual> next;
  next.reserve(pop.size());
  const std::vector<std::size_t> ranked = RankedIndices(pop);
  for (int e = 0; e < in.elites && e < static_cast<int>(pop.size()); ++e) next.push_back(pop[ranked[e]]);
  while (next.size() < pop.size()) {
    const Individual& p1 = pop[Tournament(pop, rng)];
    const Individual& p2 = pop[Tournament(pop, rng)];
    Genes c1 = p1.xi, c2 = p2.xi;
    if (rng.Uniform() < CrossoverProbability(st, std::max(p1.eval.fitness, p2.eval.fitness))) {
      for (std::size_t k = 0; k < c1.size(); ++k) {  // blend crossover, λ ∈ [−0.25, 1.25] per gene
        const double lambda = rng.Uniform(-0.25, 1.25);
        c1[k] = std::clamp(lambda * p1.xi[k] + (1 - lambda) * p2.xi[k], 0.0, 1.0);
        c2[k] = std::clamp(lambda * p2.xi[k] + (1 - lambda) * p1.xi[k], 0.0, 1.0);
      }
    }
    next.push_back(MakeChild(in, radii, c1, st, sigma, rng));
    if (next.size() < pop.size()) next.push_back(MakeChild(in, radii, c2, st, sigma, rng));
  }
  return next;
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
  Rng rng(seed);
  std::vector<Individual> pop(static_cast<std::size_t>(in.population));
  for (Individual& ind : pop) {
    for (double& g : ind.xi) g = rng.Uniform();
    ind.eval = Decode(in, radii, ind.xi);
  }
  std::vector<double> best_fitness, best_j;
  int g = 0;
  for (;; ++g) {
    const Individual& best = pop[RankedIndices(pop).front()];
    best_fitness.push_back(best.eval.fitness);
    best_j.push_back(best.eval.J);
    const double f_now = best_fitness.back();
    // 20-generation stall window (§1.6 step 4).
    const bool stalled = g >= 20 && f_now - best_fitness[static_cast<std::size_t>(g - 20)] <= 1e-7 * std::abs(f_now);
    if (g >= in.generations || stalled) break;
    pop = NextGeneration(in, radii, pop, g, rng);
  }
  SurrogateResult out = pop[RankedIndices(pop).front()].eval;
  out.generations = g;
  if (history != nullptr) (*history)["best_J"] = best_j;
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
        const double f_z = in.f_z_min_mm * std::pow(f_hi / in.f_z_min_mm, static_cast<double>(b) / std::max(1, n_f - 1));
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
  return {{"area_mm2", area_mm2}, {"width_mm", width_mm}, {"t_link_min", t_link_min},
          {"finish_depth_mm", finish_depth_mm}, {"cutting_speed_m_per_min", cutting_speed_m_per_min},
          {"n_max_rpm", n_max_rpm}, {"flutes", flutes}, {"youngs_modulus_n_per_mm2", youngs_modulus_n_per_mm2},
          {"k_n", k_n}, {"rho_cc_min_mm", std::isfinite(rho_cc_min_mm) ? nlohmann::json(rho_cc_min_mm) : nullptr},
          {"kappa_cvx_max_per_mm", kappa_cvx_max_per_mm}, {"h_tol_mm", h_tol_mm}, {"t_form_mm", t_form_mm},
          {"e_sys_mm", e_sys_mm}, {"e_rand_mm", e_rand_mm}, {"similarity", similarity}, {"w_e", w_e},
          {"w_t", w_t}, {"t_ref_min", t_ref_min}, {"f_z_min_mm", f_z_min_mm}, {"f_z_max_mm", f_z_max_mm},
          {"s_min_mm", s_min_mm}, {"c_pc_max", c_pc_max}, {"gouge_margin", gouge_margin},
          {"max_feed_mm_per_min", std::isfinite(max_feed_mm_per_min) ? nlohmann::json(max_feed_mm_per_min) : nullptr},
          {"deflection_scale", deflection_scale}, {"scallop_offset_mm", scallop_offset_mm}, {"tool_radii_mm", tool_radii_mm}};
}

nlohmann::json SurrogateResult::ToJson() const {
  return {{"r_mm", r}, {"s_mm", s}, {"f_z_mm", f_z}, {"c_pc", c_pc}, {"n_rpm", n_rpm},
          {"v_f_mm_per_min", v_f_mm_per_min}, {"time_min", time_min}, {"deflection_mm", deflection_mm},
          {"scallop_mm", scallop_mm}, {"e_pred_mm", e_pred}, {"J", J},
          {"fitness", std::isfinite(fitness) ? nlohmann::json(fitness) : nullptr}, {"tool_index", tool_index},
          {"generations", generations}};
}

}  // namespace formloop::planning
