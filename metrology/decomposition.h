#pragma once
// Systematic / random decomposition of a deviation field (spec/metrology.md §7, §8).
//
// Models of increasing complexity — tensor Legendre polynomials of total degree 0, 1, 2, ... in the
// normalised surface parameters — are fitted by least squares; after each, the residual Moran's I
// (Cliff–Ord, exact moments) tests whether the residual is still spatially correlated. The
// simplest model whose residual is spatially independent (z ≤ 2.326) is the systematic field d_s;
// the residual is the random part d_u. (Spatial block cross-validation against over-fitting and
// B-spline fields come with the metrology issue.)
//
// Evaluation: form error = max |d_s| + k·σ(d_u) with coverage factor k = 2.

#include <vector>

#include <Eigen/Core>
#include <nlohmann/json.hpp>

#include "core/status.h"
#include "metrology/deviations.h"
#include "metrology/morans_i.h"
#include "reconstruction/analytic_surface.h"

namespace formloop::metrology {

// d_s(u, v) = Σ c_ij P_i(ū) P_j(v̄), i + j ≤ degree, ū, v̄ ∈ [−1, 1] over `domain`. Values in mm.
struct PolynomialField {
  int degree = 0;
  recon::ParamDomain domain;
  Eigen::VectorXd coefficients;  // in the order of Basis()
  double Evaluate(double u, double v) const;
  // Basis row for (u, v): number of terms = (degree + 1)(degree + 2)/2.
  static Eigen::VectorXd Basis(int degree, const recon::ParamDomain& domain, double u, double v);
  nlohmann::json ToJson() const;
};

struct DecompositionOptions {
  int max_degree = 4;           // highest total degree tried
  int neighbours = 8;           // k of the k-NN weights in (u, v)
  double coverage_factor = 2.0; // k in form error = max|d_s| + k σ(d_u)
  Status Validate() const;
};

struct DecompositionStep {
  int degree = 0;
  int terms = 0;
  double residual_rms_um = 0;
  double residual_moran_i = 0;
  double residual_moran_z = 0;
};

struct Decomposition {
  MoranResult raw;                      // Moran's I of the deviations themselves
  std::vector<DecompositionStep> steps;
  bool independent = false;             // the chosen model's residual passed the test
  PolynomialField systematic;           // d_s
  std::vector<double> systematic_mm;    // d_s at each point
  std::vector<double> random_mm;        // d_u at each point
  double deviation_rms_um = 0, deviation_peak_um = 0;
  double systematic_peak_um = 0, systematic_rms_um = 0;
  double random_sigma_um = 0;
  double form_error_um = 0;             // max|d_s| + k σ(d_u)
  double coverage_factor = 2.0;
  nlohmann::json ToJson() const;
};

Result<Decomposition> Decompose(const std::vector<Deviation>& deviations, const recon::ParamDomain& domain,
                                const DecompositionOptions& options);

}  // namespace formloop::metrology
