#include "metrology/spatial_filter.h"

#include <Eigen/Eigenvalues>
#include <Eigen/QR>
#include <algorithm>
#include <cmath>
#include <limits>

namespace formloop::metrology {
namespace {

// x ↦ M C M x with M the projector off the columns of q (orthonormal) and C = (W + Wᵀ)/2.
class FilterOperator {
 public:
  FilterOperator(const Eigen::MatrixXd& q, const SpatialWeights& weights)
      : q_(q), w_(weights.w), wt_(weights.w.transpose()) {}

  Eigen::VectorXd Project(const Eigen::VectorXd& x) const { return x - q_ * (q_.transpose() * x); }
  Eigen::VectorXd Symmetric(const Eigen::VectorXd& x) const { return 0.5 * (w_ * x + wt_ * x); }
  Eigen::VectorXd Apply(const Eigen::VectorXd& x) const { return Project(Symmetric(Project(x))); }

 private:
  const Eigen::MatrixXd& q_;
  const Eigen::SparseMatrix<double, Eigen::RowMajor>& w_;
  const Eigen::SparseMatrix<double, Eigen::RowMajor> wt_;
};

}  // namespace

nlohmann::json SpatialFilter::ToJson() const {
  return {{"method",
           "Moran eigenvector spatial filter (Tiefelsdorf & Griffith 2007): Ritz vectors of M C M from a Lanczos run "
           "started at the field's residual, added one at a time (the one lowering Moran's I most) until the residual "
           "Moran z of the augmented design is <= the critical value"},
          {"vectors", vectors},
          {"candidates", candidates},
          {"moran_coefficients", moran_coefficients},
          {"z_before", z_before},
          {"z_after", z_after},
          {"residual_moran_z", final.z},
          {"residual_moran_I", final.i},
          {"residual_moran_expected", final.expected},
          {"independent", independent},
          {"stop_reason", stop_reason}};
}

Result<SpatialFilter> FilterResidual(const Eigen::VectorXd& y, const Eigen::MatrixXd& design,
                                     const SpatialWeights& weights, const SpatialFilterOptions& options) {
  const Eigen::Index n = y.size();
  if (design.rows() != n || weights.n() != n) {
    return Status::Internal("FilterResidual: values, design and weights differ in size");
  }
  if (options.max_vectors < 0 || options.krylov_dimension < 1 || !(options.min_relative_mc > 0) ||
      !(options.min_relative_mc <= 1)) {
    return Status::BadInput(Where{.field = "spatial_filter"},
                            "needs max_vectors >= 0, krylov_dimension >= 1 and 0 < min_relative_mc <= 1");
  }
  SpatialFilter filter;
  FL_ASSIGN_OR_RETURN(filter.final, ResidualMoranI(y, design, weights));
  filter.z_before = filter.final.z;
  filter.fitted = Eigen::VectorXd::Zero(n);
  filter.independent = filter.final.z <= options.z_critical;
  if (filter.independent) {
    filter.stop_reason = "the residual is already independent";
    return filter;
  }
  const int p = filter.final.p;
  if (p < design.cols()) return Status::Internal("FilterResidual: the design is rank-deficient");
  const Eigen::VectorXd e = filter.final.residuals;
  const double e_norm = e.norm();
  const double s0 = weights.w.sum();

  // Orthonormal basis of the design's columns.
  Eigen::HouseholderQR<Eigen::MatrixXd> qr(design);
  const Eigen::MatrixXd q = qr.householderQ() * Eigen::MatrixXd::Identity(n, p);
  const FilterOperator op(q, weights);

  // Lanczos with full reorthogonalisation, started at e.
  const int m_max = static_cast<int>(std::min<Eigen::Index>(options.krylov_dimension, n - p - 4));
  if (m_max < 1) {
    filter.stop_reason =
        "no degrees of freedom left for a filter vector (n = " + std::to_string(n) + ", p = " + std::to_string(p) + ")";
    return filter;
  }
  Eigen::MatrixXd v(n, m_max);
  std::vector<double> alpha, beta;
  v.col(0) = e / e_norm;
  int m = 0;
  for (int j = 0; j < m_max; ++j) {
    Eigen::VectorXd w = op.Apply(v.col(j));
    alpha.push_back(v.col(j).dot(w));
    for (int pass = 0; pass < 2; ++pass) {
      w -= v.leftCols(j + 1) * (v.leftCols(j + 1).transpose() * w);
      w = op.Project(w);
    }
    m = j + 1;
    const double b = w.norm();
    const double scale = std::max(1.0, std::abs(alpha.back()));
    if (j + 1 == m_max || !(b > 1e-10 * scale)) break;  // the Krylov space is exhausted or invariant
    beta.push_back(b);
    v.col(j + 1) = w / b;
  }
  Eigen::VectorXd diag = Eigen::Map<const Eigen::VectorXd>(alpha.data(), m);
  Eigen::VectorXd sub = Eigen::VectorXd::Zero(std::max(0, m - 1));
  for (int j = 0; j + 1 < m; ++j) sub[j] = beta[static_cast<std::size_t>(j)];
  Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd> tri;
  tri.computeFromTridiagonal(diag, sub, Eigen::ComputeEigenvectors);
  const Eigen::VectorXd theta = tri.eigenvalues();
  const Eigen::MatrixXd& s = tri.eigenvectors();
  // a_j = y_jᵀ e = ‖e‖ s_{0j}, since e = ‖e‖ v_0.
  const Eigen::VectorXd a = e_norm * s.row(0).transpose();
  const double theta_max = theta.maxCoeff();
  std::vector<int> candidates;
  for (int j = 0; j < m; ++j) {
    if (theta_max > 0 && theta[j] > 0 && theta[j] >= options.min_relative_mc * theta_max) candidates.push_back(j);
  }
  filter.candidates = static_cast<int>(candidates.size());

  double numerator = e.dot(op.Symmetric(e));
  double denominator = e.squaredNorm();
  const int budget = static_cast<int>(std::min<Eigen::Index>(options.max_vectors, n - p - 4));
  std::vector<char> used(static_cast<std::size_t>(m), 0);
  Eigen::MatrixXd augmented = design;
  filter.stop_reason = "no candidate vector was left";
  while (true) {
    if (filter.vectors >= budget) {
      filter.stop_reason = "the budget of " + std::to_string(budget) + " filter vectors is spent";
      break;
    }
    int best = -1;
    double best_ratio = numerator / denominator;
    for (int j : candidates) {
      if (used[static_cast<std::size_t>(j)]) continue;
      const double den = denominator - a[j] * a[j];
      if (!(den > 1e-12 * e.squaredNorm())) continue;
      const double ratio = (numerator - theta[j] * a[j] * a[j]) / den;
      if (ratio < best_ratio) {
        best_ratio = ratio;
        best = j;
      }
    }
    if (best < 0) {
      filter.stop_reason = "no candidate vector lowers Moran's I further";
      break;
    }
    used[static_cast<std::size_t>(best)] = 1;
    numerator -= theta[best] * a[best] * a[best];
    denominator -= a[best] * a[best];
    augmented.conservativeResize(Eigen::NoChange, augmented.cols() + 1);
    augmented.rightCols(1) = v.leftCols(m) * s.col(best);
    FL_ASSIGN_OR_RETURN(filter.final, ResidualMoranI(y, augmented, weights));
    ++filter.vectors;
    filter.moran_coefficients.push_back(static_cast<double>(n) / s0 * theta[best]);
    filter.z_after.push_back(filter.final.z);
    if (filter.final.z <= options.z_critical) {
      filter.independent = true;
      filter.stop_reason = "the residual is independent after " + std::to_string(filter.vectors) + " vector" +
                           (filter.vectors == 1 ? "" : "s");
      break;
    }
  }
  filter.fitted = e - filter.final.residuals;
  filter.basis = augmented.rightCols(filter.vectors);
  return filter;
}

}  // namespace formloop::metrology
