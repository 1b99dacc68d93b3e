#pragma once
// Moran's I (Moran 1950; Cliff & Ord 1981), spec/metrology.md §6.
//
// MoranI: raw values with moments under normality and randomisation.
// ResidualMoranI: least-squares residuals e = M y, M = I − X(XᵀX)⁻¹Xᵀ, with the exact moments of
// Cliff & Ord (1981, §8.3). The traces tr(MW), tr(MWMWᵀ), tr((MW)²) are computed from a thin
// orthonormal basis Q of X (H = QQᵀ) in O(n·k·p + n·p²) time and O(n·p) memory; no n × n dense
// matrix is ever formed.

#include <Eigen/Core>
#include <nlohmann/json.hpp>

#include "core/status.h"
#include "metrology/spatial_weights.h"

namespace formloop::metrology {

// One-sided critical value at significance 0.01 (the seed rounds it to 2.33).
inline constexpr double kMoranZCritical = 2.326;

struct MoranResult {
  int n = 0;
  double i = 0;
  double expected = 0;                  // E[I] = −1/(n − 1)
  double variance_normality = 0;
  double variance_randomisation = 0;
  double z_normality = 0;
  double z_randomisation = 0;
  double p_normality = 0;               // one-sided, upper tail
  double p_randomisation = 0;
  nlohmann::json ToJson() const;
};

// values: n; weights: n × n without islands.
Result<MoranResult> MoranI(const Eigen::VectorXd& values, const SpatialWeights& weights);

struct ResidualMoranResult {
  int n = 0;
  int p = 0;                            // rank of the design
  double i = 0;
  double expected = 0;
  double variance = 0;
  double z = 0;
  double p_value = 0;                   // one-sided, upper tail
  Eigen::VectorXd coefficients;         // least-squares coefficients of the design columns
  Eigen::VectorXd residuals;            // e = y − Xβ
  nlohmann::json ToJson() const;
};

// y: n; design: n × p (include a constant column for a mean); weights without islands.
Result<ResidualMoranResult> ResidualMoranI(const Eigen::VectorXd& y, const Eigen::MatrixXd& design,
                                           const SpatialWeights& weights);

// Upper-tail probability of the standard normal.
double NormalUpperTail(double z);

}  // namespace formloop::metrology
