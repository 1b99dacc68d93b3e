#include "reconstruction/bspline_basis.h"

#include <Eigen/Householder>
#include <Eigen/QR>
#include <algorithm>
#include <cmath>
#include <limits>
#include <locale>
#include <numbers>
#include <numeric>
#include <sstream>
#include <string>

#include "reconstruction/point_checks.h"

namespace formloop::recon {
namespace {

// OpenCASCADE's limit (Geom_BSplineSurface::MaxDegree()); nothing here needs more.
constexpr int kMaxDegree = 25;

std::string Num(double value) { return FormatSignificant(value, 12); }

Status CheckDegree(int degree) {
  if (degree < 1 || degree > kMaxDegree) {
    return Status::BadInput(Where{.field = "degree"}, "degree " + std::to_string(degree) + " is out of range",
                            "use a degree between 1 and " + std::to_string(kMaxDegree) + " (3 = cubic)");
  }
  return Status::Ok();
}

Status CheckInterval(double lo, double hi) {
  if (!std::isfinite(lo) || !std::isfinite(hi) || !(hi > lo)) {
    return Status::BadInput(Where{.field = "knot range"}, "[" + Num(lo) + ", " + Num(hi) + "] is not an interval",
                            "give finite ends with lo < hi");
  }
  return Status::Ok();
}

}  // namespace

// ---------------------------------------------------------------------------------------------
// KnotVector

Result<KnotVector> KnotVector::Uniform(int degree, int n_poles, double lo, double hi) {
  FL_RETURN_IF_ERROR(CheckDegree(degree));
  FL_RETURN_IF_ERROR(CheckInterval(lo, hi));
  if (n_poles < degree + 1) {
    return Status::BadInput(
        Where{.field = "n_poles"},
        std::to_string(n_poles) + " basis functions are too few for degree " + std::to_string(degree),
        "use at least degree + 1 = " + std::to_string(degree + 1));
  }
  const int n_spans = n_poles - degree;
  std::vector<double> interior;
  interior.reserve(static_cast<std::size_t>(n_spans - 1));
  for (int k = 1; k < n_spans; ++k) interior.push_back(lo + (hi - lo) * k / n_spans);
  return WithInteriorKnots(degree, lo, hi, std::move(interior));
}

Result<KnotVector> KnotVector::WithInteriorKnots(int degree, double lo, double hi, std::vector<double> interior) {
  FL_RETURN_IF_ERROR(CheckDegree(degree));
  FL_RETURN_IF_ERROR(CheckInterval(lo, hi));
  std::sort(interior.begin(), interior.end());
  for (std::size_t k = 0; k < interior.size(); ++k) {
    if (!(interior[k] > lo && interior[k] < hi)) {
      return Status::BadInput(Where{.field = "interior knots"},
                              "knot " + Num(interior[k]) + " is not strictly inside (" + Num(lo) + ", " + Num(hi) + ")",
                              "keep interior knots between the end knots");
    }
    std::size_t run = 1;
    while (k + run < interior.size() && interior[k + run] == interior[k]) ++run;
    if (run > static_cast<std::size_t>(degree)) {
      return Status::BadInput(Where{.field = "interior knots"},
                              "knot " + Num(interior[k]) + " is repeated " + std::to_string(run) + " times; a degree-" +
                                  std::to_string(degree) + " basis allows at most " + std::to_string(degree) +
                                  " (more would make the spline discontinuous)",
                              "remove the extra copies");
    }
  }
  std::vector<double> knots(static_cast<std::size_t>(degree + 1), lo);
  knots.insert(knots.end(), interior.begin(), interior.end());
  knots.insert(knots.end(), static_cast<std::size_t>(degree + 1), hi);
  return KnotVector(degree, std::move(knots));
}

Result<KnotVector> KnotVector::FromSequence(int degree, std::vector<double> knots) {
  FL_RETURN_IF_ERROR(CheckDegree(degree));
  const std::size_t ends = static_cast<std::size_t>(degree + 1);
  if (knots.size() < 2 * ends) {
    return Status::BadInput(
        Where{.field = "knots"},
        std::to_string(knots.size()) + " knots are too few for a clamped degree-" + std::to_string(degree) + " vector",
        "give at least 2 (degree + 1) = " + std::to_string(2 * ends) + " knots");
  }
  for (std::size_t k = 0; k < knots.size(); ++k) {
    if (!std::isfinite(knots[k])) {
      return Status::BadInput(Where{.field = "knots[" + std::to_string(k) + "]"}, "knot is not finite");
    }
    if (k > 0 && knots[k] < knots[k - 1]) {
      return Status::BadInput(Where{.field = "knots[" + std::to_string(k) + "]"},
                              "knots decrease (" + Num(knots[k - 1]) + " then " + Num(knots[k]) + ")",
                              "sort the knot sequence");
    }
  }
  const double lo = knots.front(), hi = knots.back();
  for (std::size_t k = 0; k < ends; ++k) {
    if (knots[k] != lo || knots[knots.size() - 1 - k] != hi) {
      return Status::BadInput(
          Where{.field = "knots"},
          "the sequence is not clamped: the first and last " + std::to_string(ends) + " knots must be equal",
          "repeat each end knot degree + 1 times");
    }
  }
  return WithInteriorKnots(degree, lo, hi,
                           std::vector<double>(knots.begin() + static_cast<std::ptrdiff_t>(ends),
                                               knots.end() - static_cast<std::ptrdiff_t>(ends)));
}

std::vector<double> KnotVector::InteriorKnots() const {
  if (knots_.empty()) return {};
  return {knots_.begin() + degree_ + 1, knots_.end() - degree_ - 1};
}

void KnotVector::Distinct(std::vector<double>* values, std::vector<int>* multiplicities) const {
  values->clear();
  multiplicities->clear();
  for (double t : knots_) {
    if (!values->empty() && values->back() == t) {
      ++multiplicities->back();
    } else {
      values->push_back(t);
      multiplicities->push_back(1);
    }
  }
}

int KnotVector::n_spans() const {
  int spans = 0;
  for (std::size_t k = 1; k < knots_.size(); ++k) spans += knots_[k] > knots_[k - 1] ? 1 : 0;
  return spans;
}

int KnotVector::FindSpan(double x) const {
  // A2.1 by bisection; std::upper_bound is the same search and copes with repeated knots.
  const int last = n_poles() - 1;
  if (x >= knots_[static_cast<std::size_t>(last + 1)]) return last;
  if (x <= knots_[static_cast<std::size_t>(degree_)]) return degree_;
  const auto it = std::upper_bound(knots_.begin(), knots_.end(), x);
  return std::clamp(static_cast<int>(it - knots_.begin()) - 1, degree_, last);
}

void KnotVector::BasisFunctions(int span, double x, double* out) const {
  // A2.2 (Cox–de Boor triangle, no division by zero for a non-empty span).
  const int p = degree_;
  double left[kMaxDegree + 1], right[kMaxDegree + 1];
  out[0] = 1.0;
  for (int j = 1; j <= p; ++j) {
    left[j] = x - knots_[static_cast<std::size_t>(span + 1 - j)];
    right[j] = knots_[static_cast<std::size_t>(span + j)] - x;
    double saved = 0.0;
    for (int r = 0; r < j; ++r) {
      const double temp = out[r] / (right[r + 1] + left[j - r]);
      out[r] = saved + right[r + 1] * temp;
      saved = left[j - r] * temp;
    }
    out[j] = saved;
  }
}

void KnotVector::BasisDerivatives(int span, double x, int n, Eigen::MatrixXd* ders) const {
  // A2.3, with ndu holding the basis functions (upper triangle) and the knot differences (lower).
  const int p = degree_;
  n = std::clamp(n, 0, p);
  Eigen::MatrixXd ndu(p + 1, p + 1);
  double left[kMaxDegree + 1], right[kMaxDegree + 1];
  ndu(0, 0) = 1.0;
  for (int j = 1; j <= p; ++j) {
    left[j] = x - knots_[static_cast<std::size_t>(span + 1 - j)];
    right[j] = knots_[static_cast<std::size_t>(span + j)] - x;
    double saved = 0.0;
    for (int r = 0; r < j; ++r) {
      ndu(j, r) = right[r + 1] + left[j - r];
      const double temp = ndu(r, j - 1) / ndu(j, r);
      ndu(r, j) = saved + right[r + 1] * temp;
      saved = left[j - r] * temp;
    }
    ndu(j, j) = saved;
  }
  ders->resize(n + 1, p + 1);
  for (int j = 0; j <= p; ++j) (*ders)(0, j) = ndu(j, p);
  Eigen::MatrixXd a(2, p + 1);
  for (int r = 0; r <= p; ++r) {
    int s1 = 0, s2 = 1;
    a(0, 0) = 1.0;
    for (int k = 1; k <= n; ++k) {
      double d = 0.0;
      const int rk = r - k, pk = p - k;
      if (r >= k) {
        a(s2, 0) = a(s1, 0) / ndu(pk + 1, rk);
        d = a(s2, 0) * ndu(rk, pk);
      }
      const int j1 = rk >= -1 ? 1 : -rk;
      const int j2 = r - 1 <= pk ? k - 1 : p - r;
      for (int j = j1; j <= j2; ++j) {
        a(s2, j) = (a(s1, j) - a(s1, j - 1)) / ndu(pk + 1, rk + j);
        d += a(s2, j) * ndu(rk + j, pk);
      }
      if (r <= pk) {
        a(s2, k) = -a(s1, k - 1) / ndu(pk + 1, r);
        d += a(s2, k) * ndu(r, pk);
      }
      (*ders)(k, r) = d;
      std::swap(s1, s2);
    }
  }
  double factor = p;
  for (int k = 1; k <= n; ++k) {
    ders->row(k) *= factor;
    factor *= p - k;
  }
}

Result<KnotVector> KnotVector::Inserted(const std::vector<double>& added) const {
  if (knots_.empty()) return Status::Internal("knot insertion into an empty knot vector");
  std::vector<double> interior = InteriorKnots();
  interior.insert(interior.end(), added.begin(), added.end());
  return WithInteriorKnots(degree_, lo(), hi(), std::move(interior));
}

// ---------------------------------------------------------------------------------------------
// Quadrature and Gram matrices

void GaussLegendre(int n, std::vector<double>* nodes, std::vector<double>* weights) {
  nodes->assign(static_cast<std::size_t>(std::max(n, 0)), 0.0);
  weights->assign(static_cast<std::size_t>(std::max(n, 0)), 0.0);
  for (int i = 0; i < n; ++i) {
    // Tricomi's initial guess for the i-th root, then Newton on P_n (three-term recurrence).
    double z = std::cos(std::numbers::pi * (i + 0.75) / (n + 0.5));
    double derivative = 1;
    for (int iter = 0; iter < 100; ++iter) {
      double p1 = 1, p2 = 0;
      for (int j = 1; j <= n; ++j) {
        const double p3 = p2;
        p2 = p1;
        p1 = ((2.0 * j - 1.0) * z * p2 - (j - 1.0) * p3) / j;
      }
      derivative = n * (z * p1 - p2) / (z * z - 1);
      const double step = p1 / derivative;
      z -= step;
      if (std::abs(step) <= 1e-16) break;
    }
    (*nodes)[static_cast<std::size_t>(n - 1 - i)] = z;  // ascending
    (*weights)[static_cast<std::size_t>(n - 1 - i)] = 2 / ((1 - z * z) * derivative * derivative);
  }
}

Eigen::MatrixXd GramMatrix(const KnotVector& knots, int derivative) {
  return GramMatrix(knots, derivative, knots.lo(), knots.hi());
}

Eigen::MatrixXd GramMatrix(const KnotVector& knots, int derivative, double from, double to) {
  const int n = knots.n_poles(), p = knots.degree();
  Eigen::MatrixXd gram = Eigen::MatrixXd::Zero(n, n);
  if (derivative > p || n <= 0) return gram;
  // N_i^(k) N_j^(k) has degree 2 (p − k) ≤ 2p on a span: p + 1 Gauss points integrate it exactly.
  std::vector<double> nodes, weights;
  GaussLegendre(p + 1, &nodes, &weights);
  const std::vector<double>& t = knots.knots();
  Eigen::MatrixXd ders;
  for (int s = p; s < n; ++s) {
    const double a = std::max(from, t[static_cast<std::size_t>(s)]);
    const double b = std::min(to, t[static_cast<std::size_t>(s + 1)]);
    if (!(b > a)) continue;
    const double half = 0.5 * (b - a);
    for (std::size_t q = 0; q < nodes.size(); ++q) {
      const double x = a + half * (nodes[q] + 1);
      knots.BasisDerivatives(s, x, derivative, &ders);
      const Eigen::RowVectorXd row = ders.row(derivative);
      gram.block(s - p, s - p, p + 1, p + 1).noalias() += (weights[q] * half) * row.transpose() * row;
    }
  }
  return gram;
}

// ---------------------------------------------------------------------------------------------
// 1-D least squares

double CurveFit1d::Evaluate(double x) const {
  const int p = knots.degree();
  double basis[kMaxDegree + 1];
  const int s = knots.FindSpan(x);
  knots.BasisFunctions(s, x, basis);
  double f = 0;
  for (int j = 0; j <= p; ++j) f += basis[j] * coefficients(s - p + j);
  return f;
}

Result<CurveFit1d> FitCurve1d(const std::vector<double>& x, const std::vector<double>& y, const KnotVector& knots) {
  const int n = knots.n_poles(), p = knots.degree();
  if (n <= 0) return Status::BadInput(Where{.field = "knots"}, "the knot vector is empty", "build one first");
  if (x.size() != y.size()) {
    return Status::BadInput(Where{.field = "y"},
                            std::to_string(y.size()) + " values for " + std::to_string(x.size()) + " abscissae",
                            "give one y per x");
  }
  const int m = static_cast<int>(x.size());
  if (m < n) {
    return Status::BadInput(Where{.field = "x"},
                            std::to_string(m) + " points cannot determine " + std::to_string(n) + " coefficients",
                            "give at least " + std::to_string(n) + " points or use fewer basis functions");
  }
  for (int i = 0; i < m; ++i) {
    const std::size_t k = static_cast<std::size_t>(i);
    if (!std::isfinite(x[k]) || !std::isfinite(y[k])) {
      return Status::BadInput(Where{.field = "point " + std::to_string(i)},
                              "(x, y) = (" + Num(x[k]) + ", " + Num(y[k]) + ") is not finite",
                              "remove or repair the point");
    }
    if (x[k] < knots.lo() || x[k] > knots.hi()) {
      return Status::BadInput(
          Where{.field = "point " + std::to_string(i)},
          "x = " + Num(x[k]) + " lies outside the knot range [" + Num(knots.lo()) + ", " + Num(knots.hi()) + "]",
          "widen the knot vector to cover every abscissa");
    }
  }

  std::vector<int> order(static_cast<std::size_t>(m));
  std::iota(order.begin(), order.end(), 0);
  std::stable_sort(order.begin(), order.end(),
                   [&](int a, int b) { return x[static_cast<std::size_t>(a)] < x[static_cast<std::size_t>(b)]; });

  // Schoenberg–Whitney (de Boor ch. XIII–XIV): A has full column rank iff one can pick strictly
  // increasing abscissae ξ_0 < ... < ξ_{n−1} with N_i(ξ_i) > 0. Greedy assignment of the smallest
  // usable abscissa is optimal because both ends of the supports increase with i.
  {
    const std::vector<double>& t = knots.knots();
    auto positive = [&](int i, double xi) {
      const bool after_start = xi > t[static_cast<std::size_t>(i)] || (i == 0 && xi >= knots.lo());
      const bool before_end = xi < t[static_cast<std::size_t>(i + p + 1)] || (i == n - 1 && xi <= knots.hi());
      return after_start && before_end;
    };
    std::size_t j = 0;
    double previous = -std::numeric_limits<double>::infinity();
    for (int i = 0; i < n; ++i) {
      while (j < order.size() && (x[static_cast<std::size_t>(order[j])] <= previous ||
                                  !(x[static_cast<std::size_t>(order[j])] > t[static_cast<std::size_t>(i)] ||
                                    (i == 0 && x[static_cast<std::size_t>(order[j])] >= knots.lo())))) {
        ++j;
      }
      if (j == order.size() || !positive(i, x[static_cast<std::size_t>(order[j])])) {
        return Status::BadInput(Where{.field = "x"},
                                "rank deficient: basis function " + std::to_string(i) + " (support [" +
                                    Num(t[static_cast<std::size_t>(i)]) + ", " +
                                    Num(t[static_cast<std::size_t>(i + p + 1)]) +
                                    "]) has no abscissa of its own, so the Schoenberg–Whitney condition fails",
                                "add points in that interval or remove knots there");
      }
      previous = x[static_cast<std::size_t>(order[j])];
      ++j;
    }
  }

  // Sequential Householder accumulation (Lawson–Hanson ch. 27). R is upper triangular with
  // bandwidth p + 1, stored by rows: band(i, j) = R(i, i + j); rhs = Qᵀy restricted to R's rows.
  // A block of rows whose span gives first column c touches columns c .. c + p only; the rows of R
  // accumulated so far reach at most column c + p too (earlier blocks started at columns ≤ c), so
  // the block is triangularised together with R rows c .. c + p in a (p + 1 + k) × (p + 2) work
  // matrix (last column = right-hand side).
  Eigen::MatrixXd band = Eigen::MatrixXd::Zero(n, p + 1);
  Eigen::VectorXd rhs = Eigen::VectorXd::Zero(n);
  std::vector<int> spans(static_cast<std::size_t>(m));
  for (int k = 0; k < m; ++k)
    spans[static_cast<std::size_t>(k)] = knots.FindSpan(x[static_cast<std::size_t>(order[k])]);
  double basis[kMaxDegree + 1];
  Eigen::MatrixXd work;
  for (int begin = 0; begin < m;) {
    int end = begin;
    const int span = spans[static_cast<std::size_t>(begin)];
    while (end < m && spans[static_cast<std::size_t>(end)] == span) ++end;
    const int c = span - p, rows = end - begin;
    work.setZero(p + 1 + rows, p + 2);
    for (int r = 0; r <= p; ++r) {
      for (int col = r; col <= p; ++col) work(r, col) = band(c + r, col - r);
      work(r, p + 1) = rhs(c + r);
    }
    for (int k = 0; k < rows; ++k) {
      const std::size_t index = static_cast<std::size_t>(order[begin + k]);
      knots.BasisFunctions(span, x[index], basis);
      for (int col = 0; col <= p; ++col) work(p + 1 + k, col) = basis[col];
      work(p + 1 + k, p + 1) = y[index];
    }
    const Eigen::HouseholderQR<Eigen::MatrixXd> qr(work);
    const Eigen::MatrixXd& packed = qr.matrixQR();  // R in the upper triangle
    for (int r = 0; r <= p; ++r) {
      for (int col = r; col <= p; ++col) band(c + r, col - r) = packed(r, col);
      rhs(c + r) = packed(r, p + 1);
    }
    begin = end;
  }

  double diag_max = 0, diag_min = std::numeric_limits<double>::infinity();
  for (int i = 0; i < n; ++i) {
    diag_max = std::max(diag_max, std::abs(band(i, 0)));
    diag_min = std::min(diag_min, std::abs(band(i, 0)));
  }
  // Backstop for near-coincident abscissae that pass the exact Schoenberg–Whitney test.
  const double rank_tol = 16 * std::numeric_limits<double>::epsilon() * std::max(m, n) * diag_max;
  for (int i = 0; i < n; ++i) {
    if (!(std::abs(band(i, 0)) > rank_tol)) {
      const std::vector<double>& t = knots.knots();
      return Status::BadInput(Where{.field = "x"},
                              "numerically rank deficient at basis function " + std::to_string(i) + " (support [" +
                                  Num(t[static_cast<std::size_t>(i)]) + ", " +
                                  Num(t[static_cast<std::size_t>(i + p + 1)]) + "], |R_ii| = " + Num(band(i, 0)) + ")",
                              "spread the abscissae or remove knots in that interval");
    }
  }

  CurveFit1d fit;
  fit.knots = knots;
  fit.coefficients.resize(n);
  for (int i = n - 1; i >= 0; --i) {
    double s = rhs(i);
    for (int j = 1; j <= p && i + j < n; ++j) s -= band(i, j) * fit.coefficients(i + j);
    fit.coefficients(i) = s / band(i, 0);
  }
  fit.diagonal_ratio = diag_min / diag_max;
  fit.residuals.resize(m);
  fit.rss = 0;
  for (int i = 0; i < m; ++i) {
    const std::size_t k = static_cast<std::size_t>(i);
    fit.residuals(i) = y[k] - fit.Evaluate(x[k]);
    fit.rss += fit.residuals(i) * fit.residuals(i);
  }
  return fit;
}

}  // namespace formloop::recon
