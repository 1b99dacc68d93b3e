#include "tuning/trust_region_lsq.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <complex>
#include <limits>
#include <numbers>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include <Eigen/Cholesky>
#include <Eigen/Eigenvalues>

namespace formloop::tuning {
namespace {

using Eigen::MatrixXd;
using Eigen::VectorXd;
using ColMatrix = Eigen::SparseMatrix<double, Eigen::ColMajor>;
using RowMatrix = Eigen::SparseMatrix<double, Eigen::RowMajor>;
constexpr double kInf = std::numeric_limits<double>::infinity();

// The problem with its columns reordered (coupled first, separable last) and the pieces the Newton
// systems need. See the header, "Structure".
class Structured {
 public:
  Structured(const ColMatrix& a, const VectorXd& b) : m_(a.rows()), n_(a.cols()) {
    // Greedy from the last column: a column with at least one entry whose rows no separable column has
    // claimed yet becomes separable.
    std::vector<char> claimed(m_, 0);
    std::vector<char> separable(n_, 0);
    for (int j = n_ - 1; j >= 0; --j) {
      if (a.col(j).nonZeros() == 0) continue;
      bool free = true;
      for (ColMatrix::InnerIterator it(a, j); it; ++it) {
        if (it.value() != 0 && claimed[it.row()]) free = false;
      }
      if (!free) continue;
      separable[j] = 1;
      for (ColMatrix::InnerIterator it(a, j); it; ++it) claimed[it.row()] = 1;
    }
    for (int j = 0; j < n_; ++j) {
      if (!separable[j]) order_.push_back(j);
    }
    kc_ = static_cast<int>(order_.size());
    for (int j = 0; j < n_; ++j) {
      if (separable[j]) order_.push_back(j);
    }
    nt_ = n_ - kc_;
    std::vector<Eigen::Triplet<double>> triplets;
    triplets.reserve(a.nonZeros());
    for (int jn = 0; jn < n_; ++jn) {
      for (ColMatrix::InnerIterator it(a, order_[jn]); it; ++it) {
        if (it.value() != 0) triplets.emplace_back(it.row(), jn, it.value());
      }
    }
    a_.resize(m_, n_);
    a_.setFromTriplets(triplets.begin(), triplets.end());
    a_.makeCompressed();
    ac_rows_ = RowMatrix(a_.leftCols(kc_));
    ac_rows_.makeCompressed();
    col_norm2_ = VectorXd::Zero(n_);
    for (int j = 0; j < n_; ++j) col_norm2_(j) = a_.col(j).squaredNorm();
    std::vector<char> in_sep(m_, 0);
    sep_.resize(nt_);
    for (int j = 0; j < nt_; ++j) {
      for (ColMatrix::InnerIterator it(a_, kc_ + j); it; ++it) {
        Entry e{static_cast<int>(it.row()), it.value(),
                ac_rows_.outerIndexPtr()[it.row() + 1] > ac_rows_.outerIndexPtr()[it.row()]};
        sep_[j].push_back(e);
        in_sep[it.row()] = 1;
      }
    }
    s0_ = MatrixXd::Zero(kc_, kc_);
    for (int r = 0; r < m_; ++r) {
      if (!in_sep[r]) AddRowProduct(r, r, 1.0, &s0_);
    }
    atb_ = a_.transpose() * b;
  }

  int rows() const { return m_; }
  int cols() const { return n_; }
  int coupled() const { return kc_; }
  int separable() const { return nt_; }
  int factorizations() const { return factorizations_; }
  const std::vector<int>& order() const { return order_; }
  const ColMatrix& a() const { return a_; }
  const VectorXd& atb() const { return atb_; }
  const VectorXd& col_norm2() const { return col_norm2_; }

  // Ĥ·v with Ĥ = D·AᵀA·D + C.
  VectorXd HatTimes(const VectorXd& d, const VectorXd& c, const VectorXd& v) const {
    const VectorXd av = a_ * d.cwiseProduct(v);
    return d.cwiseProduct(a_.transpose() * av) + c.cwiseProduct(v);
  }

  // Factorises the Schur complement for scaling d and diagonal C. False when it is not positive
  // definite (or a separable pivot vanishes).
  bool Factor(const VectorXd& d, const VectorXd& c) {
    ++factorizations_;
    d_ = d;
    c_ = c;
    tt_.resize(nt_);
    for (int j = 0; j < nt_; ++j) {
      const int col = kc_ + j;
      tt_(j) = d(col) * d(col) * col_norm2_(col) + c(col);
      if (!(tt_(j) > 0)) return false;
    }
    if (kc_ == 0) return true;
    MatrixXd s = s0_;
    for (int j = 0; j < nt_; ++j) {
      const int col = kc_ + j;
      const double dj2 = d(col) * d(col);
      const double den = tt_(j);
      const auto& entries = sep_[j];
      for (std::size_t p = 0; p < entries.size(); ++p) {
        if (!entries[p].coupled) continue;
        for (std::size_t q = 0; q < entries.size(); ++q) {
          if (!entries[q].coupled) continue;
          double coef;
          if (p == q) {
            // 1 − λ a_r² = (d²·Σ_{r'≠r} a_r'² + C)/(d²·h + C), without cancellation.
            double others = 0;
            for (std::size_t o = 0; o < entries.size(); ++o) {
              if (o != p) others += entries[o].value * entries[o].value;
            }
            coef = (dj2 * others + c(col)) / den;
          } else {
            coef = -dj2 / den * entries[p].value * entries[q].value;
          }
          AddRowProduct(entries[p].row, entries[q].row, coef, &s);
        }
      }
    }
    const VectorXd dc = d.head(kc_);
    s = dc.asDiagonal() * s * dc.asDiagonal();
    s.diagonal() += c.head(kc_);
    llt_.compute(s);
    return llt_.info() == Eigen::Success;
  }

  // Solves Ĥ·p = rhs with the factorisation of the last successful Factor().
  VectorXd Solve(const VectorXd& rhs) const {
    VectorXd p(n_);
    const VectorXd rhs_t = rhs.tail(nt_);
    const VectorXd y_t = rhs_t.cwiseQuotient(tt_);
    if (kc_ > 0) {
      // rhs_c − Ĥ_ct·y_t, Ĥ_ct = D_c A_cᵀ A_t D_t.
      VectorXd w = VectorXd::Zero(m_);
      for (int j = 0; j < nt_; ++j) {
        const double scale = d_(kc_ + j) * y_t(j);
        for (const Entry& e : sep_[j]) w(e.row) += e.value * scale;
      }
      VectorXd rc = rhs.head(kc_) - d_.head(kc_).cwiseProduct(ac_rows_.transpose() * w);
      p.head(kc_) = llt_.solve(rc);
      // p_t = Ĥ_tt⁻¹ (rhs_t − Ĥ_tc p_c)
      const VectorXd u = ac_rows_ * d_.head(kc_).cwiseProduct(p.head(kc_));
      for (int j = 0; j < nt_; ++j) {
        double dot = 0;
        for (const Entry& e : sep_[j]) dot += e.value * u(e.row);
        p(kc_ + j) = (rhs_t(j) - d_(kc_ + j) * dot) / tt_(j);
      }
    } else {
      p = y_t;
    }
    return p;
  }

 private:
  struct Entry {
    int row;
    double value;
    bool coupled;  // the row has entries in coupled columns
  };

  // s += coef · A_c[r1]ᵀ A_c[r2] (+ the transpose when r1 ≠ r2 is added by the symmetric call).
  void AddRowProduct(int r1, int r2, double coef, MatrixXd* s) const {
    for (RowMatrix::InnerIterator i1(ac_rows_, r1); i1; ++i1) {
      const double v1 = coef * i1.value();
      for (RowMatrix::InnerIterator i2(ac_rows_, r2); i2; ++i2) (*s)(i1.col(), i2.col()) += v1 * i2.value();
    }
  }

  int m_, n_, kc_ = 0, nt_ = 0, factorizations_ = 0;
  std::vector<int> order_;  // order_[new column] = original column
  ColMatrix a_;
  RowMatrix ac_rows_;
  VectorXd col_norm2_, atb_;
  std::vector<std::vector<Entry>> sep_;
  MatrixXd s0_;
  VectorXd d_, c_, tt_;
  Eigen::LLT<MatrixXd> llt_;
};

double Scale(double lo, double hi) {
  if (std::isfinite(lo) && std::isfinite(hi)) return hi - lo;
  if (std::isfinite(lo)) return std::max(1.0, std::abs(lo));
  if (std::isfinite(hi)) return std::max(1.0, std::abs(hi));
  return 1.0;
}

// Coleman–Li scaling vector v and its derivative dv.
void ScalingVector(const VectorXd& x, const VectorXd& g, const VectorXd& lb, const VectorXd& ub, VectorXd* v,
                   VectorXd* dv) {
  const int n = x.size();
  v->setOnes(n);
  dv->setZero(n);
  for (int i = 0; i < n; ++i) {
    if (g(i) < 0 && std::isfinite(ub(i))) {
      (*v)(i) = ub(i) - x(i);
      (*dv)(i) = -1;
    } else if (g(i) > 0 && std::isfinite(lb(i))) {
      (*v)(i) = x(i) - lb(i);
      (*dv)(i) = 1;
    }
  }
}

// Largest α ≥ 0 with x + α·s inside [lb, ub] (∞ when s never meets a bound) and the components that
// meet their bound at that α.
double StepToBound(const VectorXd& x, const VectorXd& s, const VectorXd& lb, const VectorXd& ub,
                   std::vector<char>* hits) {
  const int n = x.size();
  double alpha = kInf;
  VectorXd steps = VectorXd::Constant(n, kInf);
  for (int i = 0; i < n; ++i) {
    if (s(i) > 0 && std::isfinite(ub(i))) steps(i) = std::max(0.0, (ub(i) - x(i)) / s(i));
    if (s(i) < 0 && std::isfinite(lb(i))) steps(i) = std::max(0.0, (lb(i) - x(i)) / s(i));
    alpha = std::min(alpha, steps(i));
  }
  if (hits) {
    hits->assign(n, 0);
    if (std::isfinite(alpha)) {
      for (int i = 0; i < n; ++i) (*hits)[i] = steps(i) <= alpha * (1 + 1e-12) ? 1 : 0;
    }
  }
  return alpha;
}

bool StrictlyInside(const VectorXd& x, const VectorXd& lb, const VectorXd& ub) {
  for (int i = 0; i < x.size(); ++i) {
    if (!(x(i) > lb(i) && x(i) < ub(i))) return false;
  }
  return true;
}

// Moves components that rounding put on or beyond a bound one ulp inside.
void MakeStrictlyFeasible(const VectorXd& lb, const VectorXd& ub, VectorXd* x) {
  for (int i = 0; i < x->size(); ++i) {
    double& xi = (*x)(i);
    if (xi <= lb(i)) xi = std::nextafter(lb(i), ub(i));
    if (xi >= ub(i)) xi = std::nextafter(ub(i), lb(i));
  }
}

// Minimiser of q(β) = c1·β + ½c2·β² over [lo, hi] and its value.
std::pair<double, double> MinimiseQuadratic1d(double c1, double c2, double lo, double hi) {
  auto q = [&](double t) { return c1 * t + 0.5 * c2 * t * t; };
  double best = lo, best_value = q(lo);
  if (q(hi) < best_value) {
    best = hi;
    best_value = q(hi);
  }
  if (c2 > 0) {
    const double t = -c1 / c2;
    if (t > lo && t < hi && q(t) < best_value) {
      best = t;
      best_value = q(t);
    }
  }
  return {best, best_value};
}

// Real roots of c[0]·t⁴ + c[1]·t³ + ... + c[4] (highest power first) by the companion matrix, after
// dropping negligible leading coefficients.
std::vector<double> RealRoots(std::vector<double> c) {
  double scale = 0;
  for (double v : c) scale = std::max(scale, std::abs(v));
  if (scale == 0) return {};
  while (!c.empty() && std::abs(c.front()) <= 1e-14 * scale) c.erase(c.begin());
  const int degree = static_cast<int>(c.size()) - 1;
  if (degree < 1) return {};
  MatrixXd companion = MatrixXd::Zero(degree, degree);
  for (int i = 0; i < degree; ++i) companion(0, i) = -c[i + 1] / c[0];
  for (int i = 1; i < degree; ++i) companion(i, i - 1) = 1;
  Eigen::EigenSolver<MatrixXd> solver(companion, false);
  std::vector<double> roots;
  for (int i = 0; i < degree; ++i) {
    const std::complex<double> z = solver.eigenvalues()(i);
    if (std::abs(z.imag()) <= 1e-6 * (1 + std::abs(z))) roots.push_back(z.real());
  }
  return roots;
}

// min aᵀy + ½yᵀBy over ‖y‖ ≤ Δ in two dimensions (spec §4.3).
Eigen::Vector2d SolveTrustRegion2d(const Eigen::Matrix2d& b, const Eigen::Vector2d& a, double delta) {
  Eigen::LLT<Eigen::Matrix2d> llt(b);
  if (llt.info() == Eigen::Success && b(0, 0) > 0 && b(1, 1) > 0) {
    const Eigen::Vector2d y = -llt.solve(a);
    if (y.norm() <= delta) return y;
  }
  const double b11 = b(0, 0), b12 = b(0, 1), b22 = b(1, 1), a1 = a(0), a2 = a(1);
  auto model_at = [&](double theta) {
    const Eigen::Vector2d y(delta * std::cos(theta), delta * std::sin(theta));
    return std::make_pair(a.dot(y) + 0.5 * y.dot(b * y), y);
  };
  // dφ/dθ = 0 with t = tan(θ/2), multiplied by (1 + t²)²/Δ.
  const std::vector<double> coefficients = {delta * b12 - a2, 2 * (delta * (b11 - b22) - a1), -6 * delta * b12,
                                            2 * (delta * (b22 - b11) - a1), a2 + delta * b12};
  auto best = model_at(std::numbers::pi);  // θ = π is not reachable through t
  for (double t : RealRoots(coefficients)) {
    double theta = 2 * std::atan(t);
    // A few Newton steps on dφ/dθ sharpen a root the eigenvalue solver left inexact.
    for (int k = 0; k < 3; ++k) {
      const double cs = std::cos(theta), sn = std::sin(theta);
      const double d1 =
          delta * (-a1 * sn + a2 * cs) + delta * delta * ((b22 - b11) * sn * cs + b12 * (cs * cs - sn * sn));
      const double d2 =
          delta * (-a1 * cs - a2 * sn) + delta * delta * ((b22 - b11) * (cs * cs - sn * sn) - 4 * b12 * sn * cs);
      if (!(d2 > 0)) break;
      theta -= d1 / d2;
    }
    const auto candidate = model_at(theta);
    if (candidate.first < best.first) best = candidate;
  }
  return best.second;
}

// Newton direction from preconditioned conjugate gradients on Ĥ·p = −ĝ (spec §4.3): stops at the
// residual test or after N iterations; a direction of non-positive curvature is returned instead.
VectorXd ConjugateGradientDirection(const Structured& problem, const VectorXd& d, const VectorXd& c,
                                    const VectorXd& g_hat) {
  const int n = g_hat.size();
  VectorXd precond = d.cwiseProduct(d).cwiseProduct(problem.col_norm2()) + c;
  for (int i = 0; i < n; ++i) {
    if (!(precond(i) > 0)) precond(i) = 1;
  }
  const double g_norm = g_hat.norm();
  const double tol = std::min(0.1, std::sqrt(g_norm)) * g_norm;
  VectorXd p = VectorXd::Zero(n);
  VectorXd r = -g_hat;
  VectorXd z = r.cwiseQuotient(precond);
  VectorXd q = z;
  double rz = r.dot(z);
  for (int it = 0; it < n; ++it) {
    const VectorXd hq = problem.HatTimes(d, c, q);
    const double curvature = q.dot(hq);
    if (curvature <= 1e-14 * q.squaredNorm() * std::max(1.0, precond.maxCoeff())) {
      return q;  // non-positive curvature: q itself spans the second direction
    }
    const double alpha = rz / curvature;
    p += alpha * q;
    r -= alpha * hq;
    if (r.norm() <= tol) break;
    z = r.cwiseQuotient(precond);
    const double rz_new = r.dot(z);
    q = z + (rz_new / rz) * q;
    rz = rz_new;
  }
  return p;
}

struct StepChoice {
  VectorXd s_hat;  // scaled step
  double psi = 0;  // model value ψ(ŝ)
};

}  // namespace

Status BoundedLsqOptions::Validate() const {
  if (!(gtol > 0) || !(ftol > 0) || !(xtol > 0)) {
    return Status::BadInput(Where{.field = "gtol/ftol/xtol"}, "tolerances must be > 0", "use the defaults");
  }
  if (max_iterations < 0) {
    return Status::BadInput(Where{.field = "max_iterations"}, "must be >= 0", "0 means 200·N");
  }
  if (!(active_tolerance >= 0)) {
    return Status::BadInput(Where{.field = "active_tolerance"}, "must be >= 0", "use the default 1e-10");
  }
  return Status::Ok();
}

const char* BoundedLsqStatusName(BoundedLsqStatus status) {
  switch (status) {
    case BoundedLsqStatus::kUnconstrained:
      return "UNCONSTRAINED";
    case BoundedLsqStatus::kGtol:
      return "GTOL";
    case BoundedLsqStatus::kFtol:
      return "FTOL";
    case BoundedLsqStatus::kXtol:
      return "XTOL";
    case BoundedLsqStatus::kMaxIter:
      return "MAX_ITER";
    case BoundedLsqStatus::kActiveSet:
      return "ACTIVE_SET";
  }
  return "?";
}

nlohmann::json BoundedLsqReport::ToJson() const {
  int lower = 0, upper = 0;
  for (int a : active) {
    lower += a < 0;
    upper += a > 0;
  }
  return {{"status", BoundedLsqStatusName(status)},
          {"cost", cost},
          {"optimality", optimality},
          {"iterations", iterations},
          {"active_lower", lower},
          {"active_upper", upper},
          {"polished", polished},
          {"separable_columns", separable_columns},
          {"cg_directions", cg_directions}};
}

Result<BoundedLsqReport> SolveBoundedLsq(const Eigen::SparseMatrix<double>& a_in, const VectorXd& b_in,
                                         const VectorXd& lb_in, const VectorXd& ub_in,
                                         const BoundedLsqOptions& options) {
  FL_RETURN_IF_ERROR(options.Validate());
  const int m = a_in.rows(), n = a_in.cols();
  if (n == 0) return Status::BadInput("bounded least squares: no unknowns");
  if (b_in.size() != m || lb_in.size() != n || ub_in.size() != n) {
    return Status::Internal("bounded least squares: sizes of A (" + std::to_string(m) + "x" + std::to_string(n) +
                            "), b, lb, ub disagree");
  }
  for (int j = 0; j < n; ++j) {
    for (Eigen::SparseMatrix<double>::InnerIterator it(a_in, j); it; ++it) {
      if (!std::isfinite(it.value())) {
        return Status::BadInput("bounded least squares: A(" + std::to_string(it.row()) + "," + std::to_string(j) +
                                ") is not finite");
      }
    }
  }
  for (int i = 0; i < m; ++i) {
    if (!std::isfinite(b_in(i)))
      return Status::BadInput("bounded least squares: b(" + std::to_string(i) + ") is not finite");
  }
  for (int j = 0; j < n; ++j) {
    if (std::isnan(lb_in(j)) || std::isnan(ub_in(j)) || !(lb_in(j) < ub_in(j))) {
      return Status::BadInput("bounded least squares: bounds of unknown " + std::to_string(j) +
                              " must satisfy lb < ub (fixed unknowns are removed before solving)");
    }
  }

  using Clock = std::chrono::steady_clock;
  auto since = [](Clock::time_point t0) { return std::chrono::duration<double>(Clock::now() - t0).count(); };
  auto phase = Clock::now();
  BoundedLsqReport report;
  Structured problem(a_in, b_in);
  const auto& order = problem.order();
  VectorXd b = b_in, lb(n), ub(n);
  for (int j = 0; j < n; ++j) {
    lb(j) = lb_in(order[j]);
    ub(j) = ub_in(order[j]);
  }
  const auto& a = problem.a();
  const double gtol_abs = options.gtol * std::max(1.0, problem.atb().lpNorm<Eigen::Infinity>());
  const int max_iterations = options.max_iterations > 0 ? options.max_iterations : 200 * n;

  report.separable_columns = problem.separable();
  report.timing.setup_s = since(phase);
  phase = Clock::now();
  const VectorXd ones = VectorXd::Ones(n), zeros = VectorXd::Zero(n);

  auto residual = [&](const VectorXd& x) {
    VectorXd r = a * x - b;
    return r;
  };
  auto finish = [&](VectorXd x) -> BoundedLsqReport {
    const VectorXd r = residual(x);
    const VectorXd g = a.transpose() * r;
    VectorXd v, dv;
    ScalingVector(x, g, lb, ub, &v, &dv);
    report.cost = 0.5 * r.squaredNorm();
    report.optimality = v.cwiseProduct(g).lpNorm<Eigen::Infinity>();
    report.x.resize(n);
    report.active.assign(n, 0);
    for (int j = 0; j < n; ++j) {
      report.x(order[j]) = x(j);
      const double tol = options.active_tolerance * Scale(lb(j), ub(j));
      if (x(j) - lb(j) <= tol) report.active[order[j]] = -1;
      if (ub(j) - x(j) <= tol) report.active[order[j]] = 1;
    }
    return report;
  };

  // Unconstrained start: normal equations through the structured factorisation, refined twice.
  VectorXd x_u;
  if (problem.Factor(ones, zeros)) {
    x_u = problem.Solve(problem.atb());
    for (int k = 0; k < 2; ++k) x_u += problem.Solve(a.transpose() * (b - a * x_u));
  } else {
    x_u = ConjugateGradientDirection(problem, ones, zeros, -problem.atb());
    ++report.cg_directions;
  }
  bool inside = true;
  for (int j = 0; j < n; ++j) inside = inside && x_u(j) >= lb(j) && x_u(j) <= ub(j);
  if (inside) {
    report.status = BoundedLsqStatus::kUnconstrained;
    report.timing.start_s = since(phase);
    report.timing.factorizations = problem.factorizations();
    return finish(x_u);
  }

  // Mirror the violating components and pull every component strictly inside.
  VectorXd x = x_u;
  for (int j = 0; j < n; ++j) {
    const double lo = lb(j), hi = ub(j);
    double& xj = x(j);
    if (std::isfinite(lo) && std::isfinite(hi)) {
      const double range = hi - lo;
      if (xj < lo || xj > hi) {
        // Reflect about the bounds until inside: the period is 2·range.
        double t = std::fmod(xj - lo, 2 * range);
        if (t < 0) t += 2 * range;
        xj = t <= range ? lo + t : hi - (t - range);
      }
      const double eta = 0.1 * range;
      xj = std::clamp(xj, lo + eta, hi - eta);
    } else if (std::isfinite(lo)) {
      if (xj < lo) xj = 2 * lo - xj;
      xj = std::max(xj, lo + 0.1 * std::max(1.0, std::abs(lo)));
    } else if (std::isfinite(hi)) {
      if (xj > hi) xj = 2 * hi - xj;
      xj = std::min(xj, hi - 0.1 * std::max(1.0, std::abs(hi)));
    }
  }

  VectorXd r = residual(x);
  VectorXd g = a.transpose() * r;
  double f = 0.5 * r.squaredNorm();
  VectorXd v, dv;
  ScalingVector(x, g, lb, ub, &v, &dv);
  double delta = x.cwiseQuotient(v.cwiseSqrt()).norm();
  if (!(delta > 0) || !std::isfinite(delta)) delta = 1;

  // Active-set polish: fix the components the gradient holds against a bound, solve the rest exactly; at
  // most a few corrections of the guessed set (a fixed component whose gradient pulls it inside is
  // released, a free one that leaves the box is fixed on the bound it crosses). True when *out holds a
  // point that is feasible, meets the KKT conditions within eps_g and is not worse than f.
  // Free components: |g| ≤ eps_g (the certificate's tolerance; the free set is solved exactly, so this only
  // absorbs rounding). Fixed components: the multiplier's sign within eps_sign, far tighter, because in the
  // offset problem ‖Aᵀb‖∞ carries ρ² and a wrongly signed multiplier of 0.1 would pass eps_g and leave x
  // 1 µm off (measured on the SciPy fixtures).
  const double eps_g = 1e-8 * std::max(1.0, problem.atb().lpNorm<Eigen::Infinity>());
  const double eps_sign = 1e-14 * std::max(1.0, problem.atb().lpNorm<Eigen::Infinity>());
  auto TryPolish = [&](const VectorXd& x0, const VectorXd& g0, double f0, const std::vector<double>& thresholds,
                       VectorXd* out) {
    for (double threshold : thresholds) {
      std::vector<int> fixed(n, 0);
      for (int j = 0; j < n; ++j) {
        const double tol = threshold * Scale(lb(j), ub(j));
        if (g0(j) > 0 && x0(j) - lb(j) <= tol) fixed[j] = -1;
        if (g0(j) < 0 && ub(j) - x0(j) <= tol) fixed[j] = 1;
      }
      for (int round = 0; round < 4; ++round) {
        VectorXd xp = x0, dmask = ones, cmask = zeros;
        for (int j = 0; j < n; ++j) {
          if (fixed[j] == 0) continue;
          xp(j) = fixed[j] < 0 ? lb(j) : ub(j);
          dmask(j) = 0;
          cmask(j) = 1;
        }
        if (!problem.Factor(dmask, cmask)) return false;
        // Newton on the free set, refined twice on the true residual (normal equations lose accuracy
        // along the weakly weighted directions).
        for (int k = 0; k < 3; ++k) xp -= problem.Solve(dmask.cwiseProduct(a.transpose() * residual(xp)));
        bool changed = false;
        for (int j = 0; j < n; ++j) {
          if (fixed[j] != 0) continue;
          const double slack = 1e-12 * Scale(lb(j), ub(j));
          if (xp(j) < lb(j) - slack) {
            fixed[j] = -1;
            changed = true;
          } else if (xp(j) > ub(j) + slack) {
            fixed[j] = 1;
            changed = true;
          }
          xp(j) = std::clamp(xp(j), lb(j), ub(j));
        }
        if (changed) continue;
        const VectorXd rp = residual(xp);
        const VectorXd gp = a.transpose() * rp;
        bool ok = true, released = false;
        for (int j = 0; j < n; ++j) {
          if ((fixed[j] < 0 && gp(j) < -eps_sign) || (fixed[j] > 0 && gp(j) > eps_sign)) {
            fixed[j] = 0;
            ok = false;
            released = true;
          } else if (fixed[j] == 0 && std::abs(gp(j)) > eps_g) {
            ok = false;
          }
        }
        if (ok && 0.5 * rp.squaredNorm() <= f0 * (1 + 1e-12) + 1e-300) {
          *out = xp;
          return true;
        }
        if (!released) break;
      }
    }
    return false;
  };

  report.timing.start_s = since(phase);
  phase = Clock::now();
  report.status = BoundedLsqStatus::kMaxIter;
  int iteration = 0;
  int last_polish_attempt = -1000;
  for (; iteration < max_iterations; ++iteration) {
    ScalingVector(x, g, lb, ub, &v, &dv);
    const double optimality = v.cwiseProduct(g).lpNorm<Eigen::Infinity>();
    if (optimality <= gtol_abs) {
      report.status = BoundedLsqStatus::kGtol;
      break;
    }
    const VectorXd d = v.cwiseSqrt();
    const VectorXd c = g.cwiseProduct(dv);
    const VectorXd g_hat = d.cwiseProduct(g);

    VectorXd newton;
    if (problem.Factor(d, c)) {
      newton = problem.Solve(-g_hat);
    } else {
      newton = ConjugateGradientDirection(problem, d, c, g_hat);
      ++report.cg_directions;
    }

    // Subspace basis.
    const double g_norm = g_hat.norm();
    MatrixXd q(n, 2);
    int dims = 1;
    q.col(0) = g_hat / g_norm;
    VectorXd k2 = newton - newton.dot(q.col(0)) * q.col(0);
    const double k2_norm = k2.norm();
    if (newton.allFinite() && k2_norm > 1e-12 * newton.norm() && k2_norm > 0) {
      q.col(1) = k2 / k2_norm;
      dims = 2;
    }
    const VectorXd h_q0 = problem.HatTimes(d, c, q.col(0));
    VectorXd s_hat;
    if (dims == 2) {
      const VectorXd h_q1 = problem.HatTimes(d, c, q.col(1));
      Eigen::Matrix2d bm;
      bm << q.col(0).dot(h_q0), q.col(0).dot(h_q1), q.col(1).dot(h_q0), q.col(1).dot(h_q1);
      bm(0, 1) = bm(1, 0) = 0.5 * (bm(0, 1) + bm(1, 0));
      const Eigen::Vector2d a2(q.col(0).dot(g_hat), q.col(1).dot(g_hat));
      const Eigen::Vector2d y = SolveTrustRegion2d(bm, a2, delta);
      s_hat = q.leftCols(2) * y;
    } else {
      const double b1 = q.col(0).dot(h_q0), a1 = q.col(0).dot(g_hat);
      const double y = MinimiseQuadratic1d(a1, b1, -delta, delta).first;
      s_hat = y * q.col(0);
    }

    // Model value ψ(ŝ) = ĝᵀŝ + ½ŝᵀĤŝ.
    auto psi = [&](const VectorXd& sh, const VectorXd& h_sh) { return g_hat.dot(sh) + 0.5 * sh.dot(h_sh); };
    const double theta = std::max(0.995, 1 - optimality);
    StepChoice choice;
    {
      const VectorXd h_s = problem.HatTimes(d, c, s_hat);
      const VectorXd s = d.cwiseProduct(s_hat);
      if (StrictlyInside(x + s, lb, ub)) {
        choice = {s_hat, psi(s_hat, h_s)};
      } else {
        std::vector<char> hits;
        const double alpha = StepToBound(x, s, lb, ub, &hits);
        // (a) truncated
        choice = {theta * alpha * s_hat, psi(theta * alpha * s_hat, theta * alpha * h_s)};
        // (b) reflected
        VectorXd r_hat = s_hat;
        for (int j = 0; j < n; ++j) {
          if (hits[j]) r_hat(j) = -r_hat(j);
        }
        const VectorXd x_b = x + alpha * s;
        const double beta_bound = StepToBound(x_b, d.cwiseProduct(r_hat), lb, ub, nullptr);
        const VectorXd s0 = alpha * s_hat;
        // ‖s0 + β r̂‖ ≤ Δ
        const double rr = r_hat.squaredNorm(), sr = s0.dot(r_hat), ss = s0.squaredNorm();
        double beta_trust = kInf;
        if (rr > 0) {
          const double disc = sr * sr - rr * (ss - delta * delta);
          beta_trust = disc > 0 ? (-sr + std::sqrt(disc)) / rr : 0;
        }
        const double hi = std::min(theta * beta_bound, beta_trust);
        const double lo = std::isfinite(beta_bound) ? std::min((1 - theta) * beta_bound, hi) : 0;
        if (hi > 0 && std::isfinite(hi) && rr > 0) {
          const VectorXd h_r = problem.HatTimes(d, c, r_hat);
          const double psi0 = psi(s0, alpha * h_s);
          const double c1 = g_hat.dot(r_hat) + s0.dot(h_r);
          const double c2 = r_hat.dot(h_r);
          const auto [beta, value] = MinimiseQuadratic1d(c1, c2, lo, hi);
          if (psi0 + value < choice.psi) choice = {s0 + beta * r_hat, psi0 + value};
        }
        // (c) Cauchy along −ĝ
        const VectorXd dir = -g_hat;
        const double tau_bound = StepToBound(x, d.cwiseProduct(dir), lb, ub, nullptr);
        const double tau_hi = std::min(delta / g_norm, theta * tau_bound);
        if (tau_hi > 0 && std::isfinite(tau_hi)) {
          const VectorXd h_dir = problem.HatTimes(d, c, dir);
          const auto [tau, value] = MinimiseQuadratic1d(g_hat.dot(dir), dir.dot(h_dir), 0, tau_hi);
          if (value < choice.psi) choice = {tau * dir, value};
        }
      }
    }

    const VectorXd step = d.cwiseProduct(choice.s_hat);
    const VectorXd a_step = a * step;
    const double ared = -(g.dot(step) + 0.5 * a_step.squaredNorm());
    const double pred = -choice.psi;
    double ratio;
    if (pred == 0 && ared == 0) {
      ratio = 1;
    } else if (pred <= 0) {
      ratio = 0;
    } else {
      ratio = ared / pred;
    }
    const double s_hat_norm = choice.s_hat.norm();
    if (ratio < 0.25) {
      delta = 0.25 * s_hat_norm;
    } else if (ratio > 0.75 && s_hat_norm >= 0.95 * delta) {
      delta = 2 * delta;
    }
    const double step_norm = step.norm();
    if (ared > 0) {
      const double f_old = f;
      x += step;
      MakeStrictlyFeasible(lb, ub, &x);
      r = residual(x);
      g = a.transpose() * r;
      f = 0.5 * r.squaredNorm();
      if (ared < options.ftol * f_old && ratio > 0.25) {
        report.status = BoundedLsqStatus::kFtol;
        ++iteration;
        break;
      }
      // Stalling (a step that gains less than 1e-6 of f; at most every 5 iterations): try the polish. When a
      // component is driven by the Newton step towards a bound its gradient points away from, the scaling
      // does not slow it and each step stops after a tiny fraction at that bound; the iteration crawls
      // (255 iterations on the 200 × 60 bench problem) although the active set is already clear.
      if (options.polish && ared < 1e-6 * f_old && iteration - last_polish_attempt >= 5) {
        last_polish_attempt = iteration;
        if (TryPolish(x, g, f, {1e-3}, &x)) {
          report.polished = true;
          report.status = BoundedLsqStatus::kActiveSet;
          ++iteration;
          break;
        }
      }
    }
    if (step_norm < options.xtol * (options.xtol + x.norm()) || !(delta > 0)) {
      report.status = BoundedLsqStatus::kXtol;
      ++iteration;
      break;
    }
  }
  report.iterations = iteration;
  report.timing.iterations_s = since(phase);
  phase = Clock::now();

  // A last polish when the iteration stopped without one (MAX_ITER included: a polished point passes the KKT
  // conditions, so it is a solution whatever the iteration count).
  if (options.polish && !report.polished) {
    ScalingVector(x, g, lb, ub, &v, &dv);
    if (TryPolish(x, g, f, {1e-9, 1e-6, 1e-3}, &x)) {
      report.polished = true;
      report.status = BoundedLsqStatus::kActiveSet;
    }
  }
  BoundedLsqReport out = finish(x);
  out.timing.polish_s = since(phase);
  out.timing.factorizations = problem.factorizations();
  return out;
}

}  // namespace formloop::tuning
