#pragma once
// Level 1 by the adaptive GA (spec/process-optimization.md §1.6) and the fusion of the model optimum
// with the case library's recommended cutting data (§1.8).
//
// GA encoding (feasibility-preserving decoding is the constraint handling): genes (ξ_n, ξ_f) ∈ [0, 1]²,
// n = n_min (n_max/n_min)^ξ_n; f_z = f_z,min (cap(n)/f_z,min)^ξ_f with cap(n) of CuttingFeedCap, so a
// decoded individual satisfies g1–g6; fitness Q/Q̄ (Q̄ = a_e a_p z f_z,max n_max). Where cap(n) < f_z,min
// the fitness is −(f_z,min/cap(n) − 1) < 0, graded below every feasible point. Ties: the longer tool
// life. The GA itself is planning/aga.h (N = 40, G_max = 100, 2 elites by default).
//
// Fusion (§1.8): the database point n_db = 1000 v_c,nom/(π d), f_z,db = f_z,nom K_ct (radial chip
// thinning K_ct = d/(2 sqrt(a_e (d − a_e))) below a_e = d/2, at most 3), clamped to the box. The model
// weight w_m is a zero-order Sugeno/Mamdani table over the model's credibility c_model and the
// record's c_db (sets L = tri(0,0,0.5), M = tri(0,0.5,1), H = tri(0.5,1,1); rows c_model, columns c_db:
// [0.5 0.3 0.1; 0.7 0.5 0.3; 0.9 0.7 0.5]; rule strength = min of the memberships, w_m their weighted
// average). The fused point ln x = (1 − w_m) ln x_db + w_m ln x_model is decoded like a GA individual.

#include <cstdint>
#include <nlohmann/json.hpp>
#include <optional>
#include <string>
#include <vector>

#include "core/status.h"
#include "planning/aga.h"
#include "planning/cutting_model.h"

namespace formloop::planning {

// The GA defaults of §1.6 for Level 1.
AgaOptions CuttingGaDefaults();

// The AGA optimum; L1-INFEASIBLE (BadInput, InfeasibleStatus) when no individual is feasible. The
// case and the options must Validate (checked here).
Result<CuttingOptimum> CuttingOptimumGa(const CuttingCase& c, std::uint64_t seed,
                                        const AgaOptions& options = CuttingGaDefaults());

// One record of recommended cutting data (tool makers' values kept with a case in the library:
// manufacturing.cutting_data[], or a JSON file of such records).
struct CuttingDataRecord {
  std::string tool_family, grade, material, iso_group, operation;  // operation: side_milling | slotting
  double d_min_mm = 0, d_max_mm = 0, hardness_hb = 0;
  double v_c_nom_m_per_min = 0, f_z_nom_mm = 0, a_p_max_mm = 0, a_e_max_mm = 0;
  std::string source;  // where it came from ("case blade-017", "cutting.json[2]")
  nlohmann::json ToJson() const;
};
// Reads an array of records; errors name `source`, the index and the member.
Result<std::vector<CuttingDataRecord>> CuttingDataFromJson(const nlohmann::json& array, const std::string& source);

// The best record for a tool and material and its credibility c_db: 1.0 for the exact tool family, grade,
// material and diameter range with the same operation; 0.7 for the same family and ISO group with the
// hardness within ±10 %; 0.4 for the ISO group alone. None: no record of the ISO group.
struct CuttingDataMatch {
  CuttingDataRecord record;
  double credibility = 0;
  std::string level;  // "exact", "family", "iso_group"
};
std::optional<CuttingDataMatch> MatchCuttingData(const std::vector<CuttingDataRecord>& records,
                                                 const ToolDescription& tool, double diameter_mm,
                                                 const std::string& operation);

// c_model = clamp(1 − RMSE_rel / 0.3, 0, 1) from Level-2 block logs (predicted and measured load current,
// ≥ 20 blocks); fewer blocks: the uncalibrated default 0.3.
double ModelCredibility(const std::vector<double>& predicted_a, const std::vector<double>& measured_a);

// The model weight w_m of the fuzzy table above.
double ModelWeight(double c_model, double c_db);

struct FusedCuttingPoint {
  double w_m = 1;
  CuttingState state;          // the fused, decoded point
  bool database_used = false;  // false: no record, x_model
  std::optional<CuttingDataMatch> match;
  double f_z_db_mm = 0, n_db_rpm = 0;
  std::vector<std::string> warnings;  // L1-DB-DISAGREE
  nlohmann::json ToJson() const;
};
FusedCuttingPoint FuseWithDatabase(const CuttingCase& c, const CuttingState& model,
                                   const std::optional<CuttingDataMatch>& match, double c_model);

}  // namespace formloop::planning
