#include "metrology/morans_i.h"

#include <cmath>

#include <Eigen/QR>

namespace formloop::metrology {
namespace {

struct WeightSums {
  double s0 = 0, s1 = 0, s2 = 0;
};

// S0 = Σ w_ij; S1 = ½ Σ (w_ij + w_ji)² over the union of (i, j) and (j, i); S2 = Σ (w_i. + w_.i)².
WeightSums ComputeSums(const SpatialWeights& weights) {
  WeightSums s;
  const auto& w = weights.w;
  const Eigen::SparseMatrix<double, Eigen::RowMajor> wt = w.transpose();
  const Eigen::SparseMatrix<double, Eigen::RowMajor> sym = w + wt;
  s.s0 = w.sum();
  s.s1 = 0.5 * sym.squaredNorm();
  const Eigen::VectorXd row = w * Eigen::VectorXd::Ones(w.cols());
  const Eigen::VectorXd col = wt * Eigen::VectorXd::Ones(w.cols());
  s.s2 = (row + col).squaredNorm();
  return s;
}

Status CheckWeights(const SpatialWeights& weights, long n) {
  if (weights.w.rows() != n || weights.w.cols() != n) {
    return Status::Internal("Moran's I: weights are " + std::to_string(weights.w.rows()) + " × " +
                            std::to_string(weights.w.cols()) + " for " + std::to_string(n) + " values");
  }
  if (weights.islands > 0) {
    return Status::BadInput("Moran's I: " + std::to_string(weights.islands) +
                            " point(s) have no neighbours (islands). Fix: drop them or use more neighbours");
  }
  if (n < 4) return Status::BadInput("Moran's I needs at least 4 values, got " + std::to_string(n));
  return Status::Ok();
}

}  // namespace

double NormalUpperTail(double z) { return 0.5 * std::erfc(z / std::sqrt(2.0)); }

Result<MoranResult> MoranI(const Eigen::VectorXd& values, const SpatialWeights& weights) {
  const long n_long = values.size();
  FL_RETURN_IF_ERROR(CheckWeights(weights, n_long));
  const double n = static_cast<double>(n_long);
  const Eigen::VectorXd z = values.array() - values.mean();
  const double m2 = z.squaredNorm();
  if (!(m2 > 0)) return Status::BadInput("Moran's I: all values are equal; spatial correlation is undefined");
  const WeightSums s = ComputeSums(weights);
  MoranResult r;
  r.n = static_cast<int>(n_long);
  r.i = (n / s.s0) * z.dot(weights.w * z) / m2;
  r.expected = -1.0 / (n - 1.0);
  const double e2 = r.expected * r.expected;
  r.variance_normality = (n * n * s.s1 - n * s.s2 + 3.0 * s.s0 * s.s0) / ((n * n - 1.0) * s.s0 * s.s0) - e2;
  const double b2 = n * z.array().pow(4).sum() / (m2 * m2);
  r.variance_randomisation =
      (n * ((n * n - 3.0 * n + 3.0) * s.s1 - n * s.s2 + 3.0 * s.s0 * s.s0) -
       b2 * ((n * n - n) * s.s1 - 2.0 * n * s.s2 + 6.0 * s.s0 * s.s0)) /
          ((n - 1.0) * (n - 2.0) * (n - 3.0) * s.s0 * s.s0) -
      e2;
  r.z_normality = (r.i - r.expected) / std::sqrt(r.variance_normality);
  r.z_randomisation = (r.i - r.expected) / std::sqrt(r.variance_randomisation);
  r.p_normality = NormalUpperTail(r.z_normality);
  r.p_randomisation = NormalUpperTail(r.z_randomisation);
  return r;
}

Result<ResidualMoranResult> ResidualMoranI(const Eigen::VectorXd& y, const Eigen::MatrixXd& design,
                                           const SpatialWeights& weights) {
  const long n_long = y.size();
  FL_RETURN_IF_ERROR(CheckWeights(weights, n_long));
  if (design.rows() != n_long) return Status::Internal("ResidualMoranI: design rows differ from values");
  Eigen::ColPivHouseholderQR<Eigen::MatrixXd> qr(design);
  const int p = static_cast<int>(qr.rank());
  if (n_long - p < 3) {
    return Status::BadInput("residual Moran's I: " + std::to_string(n_long) + " values cannot support " +
                            std::to_string(p) + " regressors. Fix: use a simpler model or more points");
  }
  ResidualMoranResult r;
  r.n = static_cast<int>(n_long);
  r.p = p;
  r.coefficients = qr.solve(y);
  r.residuals = y - design * r.coefficients;
  // Thin orthonormal basis of the column space (first p columns of the Householder Q).
  const Eigen::MatrixXd q = qr.householderQ() * Eigen::MatrixXd::Identity(n_long, p);
  const auto& w = weights.w;
  const Eigen::MatrixXd wq = w * q;                 // n × p
  const Eigen::MatrixXd wtq = w.transpose() * q;    // n × p
  const Eigen::MatrixXd b = q.transpose() * wq;     // p × p = QᵀWQ
  const double n = static_cast<double>(n_long);
  const double s0 = w.sum();
  const double tr_w = w.diagonal().sum();
  const double tr_mw = tr_w - b.trace();
  double tr_wwt = w.squaredNorm();
  // tr(WW) = Σ_ij w_ij w_ji
  const Eigen::SparseMatrix<double, Eigen::RowMajor> wt = w.transpose();
  const double tr_ww = w.cwiseProduct(wt).sum();
  const double tr_mwmwt = tr_wwt - wq.squaredNorm() - wtq.squaredNorm() + b.squaredNorm();
  const double tr_mwmw = tr_ww - 2.0 * wtq.cwiseProduct(wq).sum() + (b * b).trace();
  const double ete = r.residuals.squaredNorm();
  if (!(ete > 0)) return Status::BadInput("residual Moran's I: the model fits the values exactly; no residual left");
  const double scale = n / s0;
  r.i = scale * r.residuals.dot(w * r.residuals) / ete;
  const double dof = n - p;
  r.expected = scale * tr_mw / dof;
  r.variance = scale * scale * (tr_mwmwt + tr_mwmw + tr_mw * tr_mw) / (dof * (dof + 2.0)) - r.expected * r.expected;
  r.z = (r.i - r.expected) / std::sqrt(r.variance);
  r.p_value = NormalUpperTail(r.z);
  return r;
}

nlohmann::json MoranResult::ToJson() const {
  return {{"n", n},
          {"I", i},
          {"expected", expected},
          {"variance_normality", variance_normality},
          {"variance_randomisation", variance_randomisation},
          {"z_normality", z_normality},
          {"z_randomisation", z_randomisation},
          {"p_normality", p_normality},
          {"p_randomisation", p_randomisation},
          {"systematic", z_normality > kMoranZCritical}};
}

nlohmann::json ResidualMoranResult::ToJson() const {
  return {{"n", n}, {"p", p}, {"I", i}, {"expected", expected}, {"variance", variance}, {"z", z}, {"p_value", p_value}};
}

}  // namespace formloop::metrology
