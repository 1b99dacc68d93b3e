#pragma once
// Bounded linear least squares by a trust-region reflective method (spec/tuning-and-link.md §4.3).
//
//   minimise f(x) = ½‖A·x − b‖²   subject to lb ≤ x ≤ ub        A  m×N (full column rank expected)
//
// The method. Coleman–Li affine scaling with a two-dimensional subspace (Branch–Coleman–Li):
//  - Start: the unconstrained solution x_u; when lb ≤ x_u ≤ ub it is returned (kUnconstrained).
//    Otherwise every violating component is mirrored about the bound it crosses and pulled strictly
//    inside (0.1 of the range when both bounds are finite); Δ0 = ‖x0 ./ d(x0)‖ (1 when that is 0).
//  - Scaling: v_i = u_i − x_i when g_i < 0 and u_i is finite, x_i − l_i when g_i > 0 and l_i is finite,
//    1 otherwise; d = √v, ĝ = d ⊙ g, C = diag(g ⊙ dv) ≥ 0, Ĥ = D·AᵀA·D + C. The optimality measure
//    o = ‖v ⊙ g‖∞ is zero exactly at a KKT point.
//  - Subspace: span{ĝ, p} with p the Newton direction Ĥ·p = −ĝ. p comes from a Cholesky factorisation
//    (see "Structure" below); when Ĥ is not positive definite (a rank-deficient A with free
//    components) from preconditioned conjugate gradients on Ĥ (preconditioner diag Ĥ), which stops at
//    a direction of non-positive curvature and uses it instead. The 2-D trust-region problem
//    min aᵀy + ½yᵀBy, ‖y‖ ≤ Δ is solved exactly: the interior Newton point when B ≻ 0 and it lies inside,
//    otherwise the best point of the circle, from the real roots of the quartic in t = tan(θ/2) that
//    d/dθ = 0 gives, and θ = π.
//  - Reflection: a step that leaves the box competes with the reflected step (continue from the first
//    bound along the direction with the hit components negated, length minimising the model) and the
//    scaled Cauchy step, all kept θ_s = max(0.995, 1 − o) inside; the smallest model value wins.
//  - Acceptance when ared > 0; Δ ← ¼‖ŝ‖ when ratio < ¼, 2Δ when ratio > ¾ and ‖ŝ‖ ≥ 0.95Δ.
//  - Termination: GTOL o ≤ gtol·max(1, ‖Aᵀb‖∞); FTOL ared < ftol·f with ratio > ¼; XTOL
//    ‖s‖ < xtol·(xtol + ‖x‖); MAXIT after 200·N iterations (kMaxIter, which callers treat as a failure).
//    gtol is 1e-15, not the spec's 1e-10: in the offset problem ‖Aᵀb‖∞ carries ρ² ≈ 1e6 while the
//    multipliers of the tolerance bounds are O(1e-4..1), so 1e-10 stopped up to 7e-5 (relative) above the
//    optimum on the SciPy fixtures (tests/tuning/trust_region_lsq_test.cc).
//  - Active-set polish (not in the papers): the iterates stay strictly inside, so a component whose bound
//    is active ends o/g_i away from it. The components within a small fraction of their range of a bound
//    the gradient pushes against are fixed on it and the rest solved exactly (Newton on the free set,
//    refined twice on the true residual); up to four corrections release a fixed component whose gradient
//    pulls it inside or fix a free one that leaves the box. The result replaces the iterate only when it is
//    feasible, satisfies the KKT conditions (free |g_i| ≤ ε_g = 1e-8·max(1, ‖Aᵀb‖∞), multipliers of the
//    right sign within 1e-14·max(1, ‖Aᵀb‖∞)) and does not raise f; it is tried
//    at termination (MAX_ITER included) and, during the iteration, whenever an accepted step gains less
//    than 1e-6 of f (at most every 5 iterations), which then ends it (kActiveSet). The latter matters when
//    the Newton step drives a component towards a bound its current gradient points away from: the
//    Coleman–Li scaling does not slow that component, every step stops after ~1e-4 of its length at that
//    bound and the iteration crawls (255 iterations on the 200 × 60 bench problem, where SciPy's trf stops
//    at its 100-iteration limit 6e-6 above the optimum). The polish makes the active set exact (components
//    sit on their bounds) and f equal to an active-set solver's to rounding (2e-15 relative on the
//    fixtures, x within 1e-8 µm of SciPy's bvls; without it f is within 3e-13 but x only within 0.02 µm
//    along weakly weighted directions).
//
// Structure. The Newton systems use the block form of Ĥ: columns of A whose row supports are pairwise
// disjoint ("separable", found automatically, greedily from the last column) have a diagonal block in
// AᵀA, and are eliminated; what is left is a dense Schur complement over the other ("coupled") columns,
// assembled row by row without forming AᵀA (so no cancellation between ρ²-sized terms) and factored by
// Cholesky. For the offset problem of §4.2 the n tolerance unknowns t are separable and the k offsets
// coupled: one iteration costs O(k³/3 + Σ nnz(K row)²) instead of O((n + k)³). A dense problem with no
// separable columns is a plain dense Cholesky of Ĥ.
//
// The unconstrained start solves the normal equations with the same factorisation plus two steps of
// iterative refinement on the true residual (the spec's Householder QR of the m×N matrix costs
// O(m·N²), 5·10¹⁰ flops at N = 2600).
//
// References: T. F. Coleman, Y. Li, "An interior trust region approach for nonlinear minimization subject
// to bounds", SIAM J. Optim. 6(2):418-445, 1996; M. A. Branch, T. F. Coleman, Y. Li, "A subspace,
// interior, and conjugate gradient method for large-scale bound-constrained minimization problems",
// SIAM J. Sci. Comput. 21(1):1-23, 1999; J. J. Moré, D. C. Sorensen, "Computing a trust region step",
// SIAM J. Sci. Stat. Comput. 4(3):553-572, 1983.

#include <string>
#include <vector>

#include <Eigen/Core>
#include <Eigen/SparseCore>
#include <nlohmann/json.hpp>

#include "core/status.h"

namespace formloop::tuning {

struct BoundedLsqOptions {
  double gtol = 1e-15;     // GTOL: o ≤ gtol·max(1, ‖Aᵀb‖∞)
  double ftol = 1e-12;     // FTOL: ared < ftol·f on a step with ratio > ¼
  double xtol = 1e-12;     // XTOL: ‖s‖ < xtol·(xtol + ‖x‖)
  int max_iterations = 0;  // 0: 200·N (spec §4.3)
  bool polish = true;      // the active-set polish of the header (off only to study the bare method)
  // Components within this fraction of their range (absolute when a bound is infinite: times
  // max(1, |bound|)) of a bound count as active in the report.
  double active_tolerance = 1e-10;
  Status Validate() const;
};

// kActiveSet: ended by the active-set polish (header), which certifies the KKT conditions.
enum class BoundedLsqStatus { kUnconstrained, kGtol, kFtol, kXtol, kMaxIter, kActiveSet };
const char* BoundedLsqStatusName(BoundedLsqStatus status);

struct BoundedLsqReport {
  Eigen::VectorXd x;      // N, the solution (inside [lb, ub]; on a bound where polished)
  double cost = 0;        // f(x) = ½‖A·x − b‖²
  double optimality = 0;  // o = ‖v ⊙ g‖∞ at x (0 when x is polished and KKT)
  int iterations = 0;     // trust-region iterations (accepted and rejected steps)
  BoundedLsqStatus status = BoundedLsqStatus::kGtol;
  std::vector<int> active;    // N: −1 at the lower bound, +1 at the upper, 0 free
  bool polished = false;      // the active-set polish replaced the last iterate
  int separable_columns = 0;  // eliminated columns (diagonal block of AᵀA)
  int cg_directions = 0;      // Newton directions that came from conjugate gradients
  // Where the time went (wall clock; for bench/tuning_bench.cc, not serialised so outputs stay identical).
  struct Timing {
    double setup_s = 0;       // structure detection, reordering, the constant part of the Schur complement
    double start_s = 0;       // unconstrained solution and the strictly feasible start
    double iterations_s = 0;  // trust-region iterations
    double polish_s = 0;      // active-set polish and the final report
    int factorizations = 0;   // Schur complement assemblies + Cholesky factorisations
  } timing;
  nlohmann::json ToJson() const;  // everything but x and timing
};

// Errors: sizes that disagree, a non-finite entry, lb_i ≥ ub_i (fixed variables are removed by the
// caller), b or bounds NaN, invalid options.
Result<BoundedLsqReport> SolveBoundedLsq(const Eigen::SparseMatrix<double>& a, const Eigen::VectorXd& b,
                                         const Eigen::VectorXd& lb, const Eigen::VectorXd& ub,
                                         const BoundedLsqOptions& options = {});

}  // namespace formloop::tuning
