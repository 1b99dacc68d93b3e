#pragma once
// Moran eigenvector spatial filtering of a least-squares residual (Griffith 2003, Spatial
// Autocorrelation and Spatial Filtering, Springer; Tiefelsdorf & Griffith 2007, "Semiparametric
// filtering of spatial autocorrelation: the eigenvector approach", Environment and Planning A
// 39:1193–1221; R spdep's SpatialFiltering).
//
// What it is for. The decomposition (metrology/decomposition.h) fits a smooth field d_s by a ladder of
// models guarded by spatial block cross-validation. When the field the guard accepts still leaves a
// residual whose Moran z exceeds 2.326, the correlated part is structure the smooth models cannot
// carry without predicting worse between the points: chance (at significance 0.01 about 1 % of
// independent residuals test as correlated) or a real error finer than the probe spacing. The filter
// takes it out of the residual as its own component d_f, so that what is left, d_u, is independent,
// and says how large it was. d_f is defined at the probe points only and is never compensated.
//
// The method. The eigenvectors of M C M (M = I − X(XᵀX)⁻¹Xᵀ for the field's design X, C = (W + Wᵀ)/2
// the symmetrised weights) are the patterns orthogonal to the field with the largest Moran
// coefficients MC = (n / S0) λ. Adding some of them to the design as regressors leaves the field's
// coefficients unchanged (they are orthogonal to X) and removes their share of the residual. Here
// they are approximated by the Ritz vectors of a Lanczos run (full reorthogonalisation) on M C M
// started from the residual e itself, so e lies in the Krylov space and, for Ritz vectors y_j with
// values θ_j and a_j = y_jᵀe, the Moran numerator after removing a set S is exactly
//   eᵀCe − Σ_S θ_j a_j²  over  eᵀe − Σ_S a_j².
// Candidates are the Ritz vectors with θ_j ≥ 0.25 θ_max (Tiefelsdorf & Griffith's threshold on
// MC / MC_max: positive, substantial autocorrelation). They are added one at a time, each time the
// candidate that lowers I most; after each addition the residual Moran z is recomputed with the
// exact Cliff–Ord moments of the augmented design [X, Y_S] (metrology/morans_i.h), so the test
// accounts for the regressors spent. The filter stops when z ≤ z_critical, when no candidate lowers
// I, or when the vector budget is spent; it says which.
// Cost: k Lanczos steps of O(n · (neighbours + p + k)) each, one k × k tridiagonal eigenproblem and one
// residual Moran per added vector; never an n × n matrix.

#include <Eigen/Core>
#include <nlohmann/json.hpp>
#include <string>
#include <vector>

#include "core/status.h"
#include "metrology/morans_i.h"
#include "metrology/spatial_weights.h"

namespace formloop::metrology {

struct SpatialFilterOptions {
  double z_critical = 2.326;      // stop when the residual Moran z is at or below this
  int max_vectors = 20;           // the budget of filter vectors
  int krylov_dimension = 150;     // Lanczos steps (at most n − p − 1)
  double min_relative_mc = 0.25;  // candidates: θ_j ≥ this · θ_max
};

struct SpatialFilter {
  int vectors = 0;                         // filter vectors added (s)
  std::vector<double> moran_coefficients;  // MC of each added vector, in the order added
  std::vector<double> z_after;             // residual Moran z after each addition
  double z_before = 0;                     // the field's residual z
  ResidualMoranResult final;               // residual Moran of the augmented design [X, Y_S]
  Eigen::VectorXd fitted;                  // d_f at the points (n), 0 when no vector was added
  Eigen::MatrixXd basis;                   // the filter vectors as columns (n × vectors), orthonormal, ⟂ the design
  bool independent = false;                // final.z ≤ z_critical
  int candidates = 0;                      // Ritz vectors that passed the MC threshold
  std::string stop_reason;
  nlohmann::json ToJson() const;  // without the per-point values
};

// y: n values; design: the field's n × p design (full column rank); weights: the n × n spatial
// weights of the test. BadInput when the sizes disagree or there is no residual to filter.
Result<SpatialFilter> FilterResidual(const Eigen::VectorXd& y, const Eigen::MatrixXd& design,
                                     const SpatialWeights& weights, const SpatialFilterOptions& options = {});

}  // namespace formloop::metrology
