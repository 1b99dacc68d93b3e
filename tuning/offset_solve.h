#pragma once
// The offset solve of spec/tuning-and-link.md §4 and the rounding of §5.1 (seed 000's weighted bounded
// model and its "correction of the optimised value by the model parameters").
//
// Model. n COMPENSATE dimensions, k offsets, deviations e = m − s (block-corrected measured minus
// nominal). Unknowns c (k, the offset error the part shows) and t (n, where each dimension lands
// relative to nominal once corrected):
//   e = K·c + t,   c ∈ [−δmax, −δmin],   t_i ∈ band_i (the tolerance band [l_i, u_i], optionally shrunk
//   about its centre by β ≤ 1),   minimise Σ w_c,j c_j² + Σ w_t,i (t_i − τ_i)²
// with τ_i = 0 (NOMINAL) or (u_i + l_i)/2 (BAND_CENTRE). The delta written back is δ = −c; the next part
// is predicted at m + K·δ = s + t. The equality is enforced by a penalty ρ (§4.2): in µm,
//   A = [ρΩK ρΩ; √W_c 0; 0 √W_t],  b = [ρΩe; 0; √W_t τ],  Ω = diag(√w_t),  weights w_t normalised so the
//   largest is 1, w_c,j = 1e-4 by default,
// solved by tuning/trust_region_lsq.h. A dimension whose equality residual r_eq = e − K·c − t exceeds
// 1e-3 µm is NOT_REACHABLE (the model is infeasible for it); the solution is then the weighted best
// compromise, reported as such, never silently.
//
// Minimum-norm rule (rank-deficient K). When offsets move the same dimensions in the same proportions
// (K·z = 0 for some z ≠ 0, e.g. two tools that cut the same walls), the dimensions cannot tell them
// apart. The regulariser then decides: of all offset vectors that give the same predicted dimensions,
// the solve returns the one with the smallest Σ w_c,j c_j², i.e. the minimum W_c-weighted norm (the
// pseudo-inverse split; with equal w_c two identical columns share the correction equally). To prefer
// one offset, give the other a larger `weight`. The rank and the groups of indistinguishable offsets are
// reported.
//
// Before solving: offsets with δmin = δmax are fixed at that value and removed, offsets whose K column
// is zero over the COMPENSATE dimensions get δ = 0 and are removed.
//
// Rounding (§5.1). δq_j = q_j·round(δ_j/q_j) with halves away from zero; a value beyond [δmin, δmax]
// goes to the nearest multiple of q_j inside (the bounds contain 0, so one exists). Predicted deviation
// e + K·δq. When rounding turns a dimension that the continuous solution predicts OK into NG, the floor
// and ceiling of the offsets acting on it are tried (every combination when at most 10 offsets are
// involved, otherwise one offset at a time) and the feasible choice (inside the offset bounds, every
// dimension OK that was OK before rounding) with the smallest objective kept. Each offset reports the
// rule that produced its value.

#include <string>
#include <vector>

#include <Eigen/Core>
#include <Eigen/SparseCore>
#include <nlohmann/json.hpp>

#include "core/status.h"
#include "tuning/trust_region_lsq.h"

namespace formloop::tuning {

// The numeric problem (mm at this interface). Rows are the COMPENSATE dimensions, columns the offsets.
struct OffsetProblem {
  std::vector<std::string> dimension_ids;  // n, for messages
  std::vector<std::string> offset_ids;     // k
  Eigen::SparseMatrix<double> k;           // n × k, K_ij (no unit)
  Eigen::VectorXd deviation_mm;            // e = m − s
  Eigen::VectorXd tol_lower_mm;            // l (signed, l < u)
  Eigen::VectorXd tol_upper_mm;            // u
  Eigen::VectorXd target_mm;               // τ (0 or (u + l)/2)
  Eigen::VectorXd weight;                  // importance w > 0 (normalised by the solve)
  Eigen::VectorXd delta_min_mm;            // δmin ≤ 0
  Eigen::VectorXd delta_max_mm;            // δmax ≥ 0
  Eigen::VectorXd offset_weight;           // w_c,j > 0 (1e-4 by default)
  Eigen::VectorXd resolution_mm;           // q_j > 0
  // BadInput naming the dimension or offset: sizes, l < u, w > 0, δmin ≤ 0 ≤ δmax, q > 0, finite values.
  Status Validate() const;
};

struct OffsetSolveOptions {
  double rho = 1e3;                  // penalty on the equality e = K·c + t (µm units)
  double band_shrink = 1.0;          // β ∈ (0, 1]: aim inside the band, not at its edge
  double reach_tolerance_um = 1e-3;  // |r_eq| above this: NOT_REACHABLE
  int exhaustive_rounding_max = 10;  // offsets on broken dimensions up to which every floor/ceil mix is tried
  BoundedLsqOptions lsq;
  Status Validate() const;
};

// The rounded change of §5.1 for a continuous change δ (from the solve or the averaging strategy).
struct RoundedOffsets {
  Eigen::VectorXd delta_mm;                    // k: the continuous δ rounded from
  Eigen::VectorXd delta_rounded_mm;            // k: δq
  std::vector<std::string> rule;               // k: how δq came about
  Eigen::VectorXd predicted_mm;                // n: e + K·δq, the predicted deviation after the change
  std::vector<bool> predicted_ok;              // n: inside [l, u] (ε = 1e-9 mm)
  std::vector<std::string> ng_after_rounding;  // ids OK with δ but NG with δq (no feasible repair)
};
// Offsets with δmin = δmax keep that value; offsets no dimension depends on (zero K column) get 0.
Result<RoundedOffsets> RoundOffsets(const OffsetProblem& problem, const Eigen::VectorXd& delta_mm,
                                    const OffsetSolveOptions& options = {});

struct OffsetSolution {
  std::vector<std::string> dimension_ids, offset_ids;       // copies of the problem's, for reports
  Eigen::VectorXd t_mm;                                     // n: where each dimension lands (continuous solution)
  Eigen::VectorXd r_eq_mm;                                  // n: e − K·c − t
  std::vector<bool> not_reachable;                          // n
  RoundedOffsets rounded;                                   // δ = −c and its rounding
  int k_rank = 0;                                           // numerical rank of K over the solved offsets
  std::vector<std::vector<std::string>> indistinguishable;  // offset groups K cannot tell apart
  std::vector<std::string> fixed_offsets, zero_offsets;     // removed before solving
  BoundedLsqReport solver;
  std::vector<int> kept;  // the offset columns solved for (x = [c(kept); t])
  double objective = 0;   // the §4.2 objective at the continuous solution (µm², penalty form)
  nlohmann::json ToJson() const;
  bool reachable() const;
};

// Errors: invalid problem or options; solver failures propagate (MAX_ITER is not an error here: the
// caller blocks write-back on solver.status == kMaxIter).
Result<OffsetSolution> SolveOffsets(const OffsetProblem& problem, const OffsetSolveOptions& options = {});

// The (A, b, lb, ub) of §4.2 in µm for the solved offsets (fixed and zero columns removed); exposed for
// the cross-checks in tests and the benchmark. `kept` receives the original index of each offset column.
struct PenaltyForm {
  Eigen::SparseMatrix<double> a;
  Eigen::VectorXd b, lb, ub;
  std::vector<int> kept;  // offset columns kept, in order (x = [c(kept); t])
};
Result<PenaltyForm> BuildPenaltyForm(const OffsetProblem& problem, const OffsetSolveOptions& options = {});

}  // namespace formloop::tuning
