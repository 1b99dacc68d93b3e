#pragma once
// Level 1 of the self-optimising NC (spec/process-optimization.md §1): the milling model, its
// constraints and their independent optima.
//
// Model (§1.3, the standard power-law milling model; Taylor 1907 generalised):
//   Q   = a_e a_p f_z z n                      metal-removal rate, mm³/min
//   v   = π d n / 1000                         cutting speed, m/min
//   v_f = f_z z n                              feed rate, mm/min
//   T   = (C_v d^q_v K_v / (v a_p^x_v f_z^y_v a_e^u_v z^p_v))^(1/m)    tool life, min
//   F_c = K_F C_F a_p^x_F f_z^y_F a_e^u_F z / (d^q_F n^w_F)             cutting force, N
//   P_c = F_c v / 60000                        cutting power, kW
// Problem (§1.4): maximise Q over x = (f_z, n) subject to
//   g1 T ≥ T_min,  g2 n_min ≤ n ≤ n_max,  g3 v_f ≤ v_f,max,  g4 F_c ≤ F_max,
//   g5 P_c ≤ η P_rated min(1, n/n_base),  g6 f_z,min ≤ f_z ≤ f_z,max;
// T_min defaults to the minimum-cost tool life T_c (§1.7, Taylor's economics):
//   T_p = (1/m − 1) t_ct                 maximum production rate,
//   T_c = (1/m − 1)(t_ct + C_t / C_m)    minimum cost per part.
// Among optima with Q equal within 1e-9 (relative) the longer tool life wins.
//
// Every constraint is log-linear in (u, w) = (ln f_z, ln n), so the optimum is a vertex of a
// two-variable LP: CuttingOptimumExact enumerates the vertices (§1.7) and certifies the optimum by its
// KKT multipliers. CuttingFeedCap is the largest admissible f_z at a spindle speed (§1.6), the
// feasibility-preserving decoding of the GA (planning/cutting_optimisation.h).
//
// Units: lengths mm, f_z mm/tooth, n rev/min, v m/min, v_f mm/min, force N, power kW, times min.

#include <limits>
#include <nlohmann/json.hpp>
#include <string>
#include <vector>

#include "core/status.h"

namespace formloop::planning {

// Generalised Taylor law: v T^m = C_v d^q_v K_v / (a_p^x_v f_z^y_v a_e^u_v z^p_v).
struct ToolLifeLaw {
  double C_v = 0, q_v = 0, x_v = 0, y_v = 0, u_v = 0, p_v = 0, m = 0, K_v = 1;
};

// Cutting force: F_c = K_F C_F a_p^x_F f_z^y_F a_e^u_F z / (d^q_F n^w_F).
struct ForceLaw {
  double C_F = 0, x_F = 0, y_F = 0, u_F = 0, q_F = 0, w_F = 0, K_F = 1;
};

// One optimisation problem of §1.4: a tool with its coefficient set on one machine at fixed a_p, a_e.
struct CuttingCase {
  std::string coefficient_set = "S1";
  ToolLifeLaw life;
  ForceLaw force;
  double diameter_mm = 10;
  int flutes = 4;
  double a_p_mm = 5, a_e_mm = 1;
  double f_z_min_mm = 0.02, f_z_max_mm = 0.15;
  double n_min_rpm = 500, n_max_rpm = 12000;
  double max_feed_mm_per_min = 5000;  // v_f,max
  double max_force_n = 300;           // F_max: shank strength, deflection, edge load
  double rated_power_kw = 7.5;
  double base_speed_rpm = 0;          // n_base: constant torque below it; 0 = none
  double efficiency = 0.8;            // η
  double tool_change_min = 2;         // t_ct
  double cost_per_edge = 40;          // C_t
  double machine_cost_per_min = 1.5;  // C_m
  // T_min; NaN: the minimum-cost tool life T_c. Below T_p (faster than max-production wear) it is refused.
  double t_min_min = std::numeric_limits<double>::quiet_NaN();

  // The illustrative set S1 of §1.5 (solid carbide 4-flute end mill d = 10 in C45; tests only).
  static CuttingCase S1();
  // Every parameter finite and in range, T_min ≥ T_p; BadInput names the parameter. The loader's
  // warning 1 > y_v > x_v (the source's ranking v > f_z > a_p) is Warnings().
  Status Validate() const;
  std::vector<std::string> Warnings() const;
  double TMinMin() const;  // T_min in effect (T_c when t_min_min is NaN)
  nlohmann::json ToJson() const;
};

double MaxProductionToolLifeMin(const CuttingCase& c);  // T_p
double MinCostToolLifeMin(const CuttingCase& c);        // T_c

// The model at one point. P_avail = η P_rated min(1, n/n_base).
struct CuttingState {
  double f_z_mm = 0, n_rpm = 0;
  double q_mm3_per_min = 0, v_m_per_min = 0, v_f_mm_per_min = 0;
  double tool_life_min = 0, force_n = 0, power_kw = 0, power_available_kw = 0;
  nlohmann::json ToJson() const;
};
CuttingState EvaluateCutting(const CuttingCase& c, double f_z_mm, double n_rpm);

// The constraints g1–g6 as relative values g/limit − 1 (≤ 0 satisfied), named as in §1.9:
// "T_min", "n_min", "n_max", "v_f_max", "F_max", "P", "f_z_min", "f_z_max".
struct ConstraintValue {
  std::string name;
  std::string label;  // "g1 tool life T >= T_min" ...
  double relative = 0;
};
std::vector<ConstraintValue> CuttingConstraints(const CuttingCase& c, const CuttingState& s);
// Names of the constraints within `tolerance` (relative) of their bound.
std::vector<std::string> ActiveConstraints(const CuttingCase& c, const CuttingState& s, double tolerance = 1e-3);
// True when every constraint holds with relative slack ≥ −slack.
bool SatisfiesConstraints(const CuttingCase& c, const CuttingState& s, double slack = 1e-9);

// cap(n) = min(f_z,max, v_f,max/(z n), f_T(n), f_F(n), f_P(n)) of §1.6: the largest f_z meeting every
// constraint at n. `limiting` (optional) gets the name of the constraint that sets it.
double CuttingFeedCap(const CuttingCase& c, double n_rpm, std::string* limiting = nullptr);

// The L1-INFEASIBLE refusal: names the constraint with the largest relative violation at (f_z,min, n_min).
Status InfeasibleStatus(const CuttingCase& c);

struct CuttingOptimum {
  CuttingState state;
  std::vector<std::string> active;  // within 0.1 % of the bound
  std::string method;               // "lp", "ga", "grid"
  // KKT certificate (lp): (1, 1) = Σ λ_k (α_k, β_k) over the active rows by non-negative least squares.
  bool kkt_passed = false;
  double kkt_residual = 0;
  std::vector<double> kkt_multipliers;  // one per `active` name
  int generations = 0;                  // ga
  nlohmann::json ToJson() const;
};

// The exact optimum of §1.7: vertices of the log-space LP (pair intersections of the boundary lines,
// feasible within 1e-9 relative), the largest u + w, ties to the largest T; KKT-certified. L1-INFEASIBLE
// (BadInput) when no vertex is feasible; the case must Validate.
Result<CuttingOptimum> CuttingOptimumExact(const CuttingCase& c);

// The best feasible point of a points_per_axis² log-spaced grid over the box (§1.7 "Grid"), evaluated
// through EvaluateCutting and CuttingConstraints only. state.q_mm3_per_min = 0 when no grid point is feasible.
CuttingOptimum CuttingOptimumGrid(const CuttingCase& c, int points_per_axis = 1001);

// The JSON coefficient file of `formloop optimise cutting` (data/cutting/s1.json is the S1 example):
//   {"id": "S1",
//    "tool": {"diameter_mm", "flutes", "flute_length_mm", "f_z_min_mm", "f_z_max_mm", "tool_change_min",
//             "cost_per_edge", "family", "grade"},
//    "material": {"name", "iso_group", "hardness_hb", "k_ap_side_milling", "k_ap_slotting"},
//    "tool_life": {"C_v", "q_v", "x_v", "y_v", "u_v", "p_v", "m", "K_v"},
//    "force": {"C_F", "x_F", "y_F", "u_F", "q_F", "w_F", "K_F"},
//    "machine": {"n_min_rpm", "n_max_rpm", "max_feed_mm_per_min", "rated_power_kw", "base_speed_rpm",
//                "efficiency", "cost_per_min"},
//    "limits": {"max_force_n", "t_min_min" (optional: default T_c)}}
// Every member is required unless marked optional (K_v, K_F default 1; base_speed_rpm 0; family, grade,
// material name and hardness are used only to match the case library's cutting data). A missing or bad
// member is BadInput naming the file and the member ("s1.json: field 'tool_life.m': ...").
struct ToolDescription {
  std::string family, grade;
  double flute_length_mm = 0;
  double k_ap_side_milling = 0, k_ap_slotting = 0;  // a_p,max = min(0.9 L_c, k_ap d), §1.2
  std::string material, iso_group;
  double hardness_hb = 0;
};
struct CuttingCoefficients {
  CuttingCase base;  // a_p, a_e set per block group
  ToolDescription tool;
  nlohmann::json ToJson() const;
};
Result<CuttingCoefficients> CuttingCoefficientsFromJson(const nlohmann::json& json, const std::string& source);

}  // namespace formloop::planning
