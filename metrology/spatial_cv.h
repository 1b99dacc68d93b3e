#pragma once
// Spatial block cross-validation (Roberts et al. 2017, "Cross-validation strategies for data with
// temporal, spatial, hierarchical, or phylogenetic structure", Ecography 40:913–929), the one
// implementation behind the decomposition's over-fitting guard (metrology/decomposition.h) and the
// diagnosis's held-out gain (simulation/diagnose.h).
//
// The bounding box of the points is cut into B × B blocks (GridBlocks); the blocks, not the points, are
// the held-out units: each its own fold (leave one block out), or dealt to fewer folds so that no two
// neighbouring blocks share one (DealBlocksToFolds). SpatialBlockCv fits on every fold's complement
// through the caller's fit, predicts the fold, and returns each point's squared held-out error and their
// RMS. The fit is the caller's (a penalised sparse normal-equation fit, a dense QR, ...), so the
// held-out loop and its bookkeeping exist once while each model keeps its own solver.

#include <cstdint>
#include <functional>
#include <limits>
#include <optional>
#include <vector>

#include <Eigen/Core>

namespace formloop::metrology {

// Block of each point (row-major: bx · blocks + by) in the blocks × blocks grid over the bounding box
// of (x_i, y_i); a zero-width extent puts every point in block 0 along it.
std::vector<int> GridBlocks(const Eigen::VectorXd& x, const Eigen::VectorXd& y, int blocks);

// Fold of each of the blocks × blocks blocks: visited in an order shuffled with `seed`, each block goes
// to the least-filled fold that none of its 8 neighbouring blocks holds yet (ties broken at random),
// so with folds ≥ 9 every held-out region is a single block.
std::vector<int> DealBlocksToFolds(int blocks, int folds, std::uint64_t seed);

struct HeldOutErrors {
  double rms = std::numeric_limits<double>::infinity();  // over the held-out points; +inf: a fit failed
  std::vector<double> squared;  // (y_i − ŷ_i)², ŷ_i from the fit without point i's fold; empty on failure
};

// Predicts point i from a fit; returned by a FitOnTraining.
using HeldOutPredictor = std::function<double(int i)>;
// Fits on the training points (indices ascending); nothing when the fit cannot be made.
using FitOnTraining = std::function<std::optional<HeldOutPredictor>(const std::vector<int>& training)>;

// fold[i] ∈ [0, folds) for every point; folds that hold no point are skipped.
HeldOutErrors SpatialBlockCv(const std::vector<int>& fold, int folds, const Eigen::VectorXd& y,
                             const FitOnTraining& fit);

// Paired comparison of two models' held-out errors (rich minus current), in mean square over the
// points: Δ = (Σ_i e²_rich,i − Σ_i e²_cur,i) / n and its standard error from the spread of the per-unit
// sums D_u = Σ_{i ∈ u} (e²_rich,i − e²_cur,i) over the units u (blocks or folds) that hold points:
// SE(Δ) = √(U/(U − 1) · Σ_u (D_u − D̄)²) / n. The units are treated as independent replicates, as in the
// one-standard-error rule of Breiman et al. (1984, Classification and Regression Trees, §3.4.3) and
// Hastie, Tibshirani & Friedman (2009, Elements of Statistical Learning, §7.10). Δ = +inf when either
// model's CV failed.
struct PairedCvDifference {
  double difference = 0;  // Δ, in the square of y's unit
  double standard_error = 0;
};
PairedCvDifference ComparePaired(const HeldOutErrors& rich, const HeldOutErrors& current, const std::vector<int>& unit,
                                 int units);

}  // namespace formloop::metrology
