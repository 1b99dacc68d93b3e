#pragma once
// B-spline basis functions on a clamped knot vector, their Gram matrices, and 1-D least squares
// (spec/reconstruction.md §2: "solve with QR on the banded matrix; never form monomial bases").
//
// Sources:
// - L. Piegl, W. Tiller, The NURBS Book, 2nd ed., Springer 1997: A2.1 FindSpan, A2.2 BasisFuns,
//   A2.3 DersBasisFuns (implemented here as written there, with the book's index conventions).
// - C. L. Lawson, R. J. Hanson, Solving Least Squares Problems, Prentice-Hall 1974, ch. 27
//   (sequential Householder accumulation of a banded least-squares problem, BNDACC/BNDSOL), and
//   C. de Boor, A Practical Guide to Splines, rev. ed., Springer 2001, ch. XIV (least-squares splines,
//   the Schoenberg–Whitney condition).
//
// Conventions: a clamped knot vector of degree p has p + 1 equal knots at each end; the spline
// f(x) = Σ_i c_i N_i,p(x) has n_poles = #knots − p − 1 coefficients and is defined on [lo, hi] =
// [first knot, last knot]. The last span is closed on the right, so f(hi) is the limit from the left.

#include <Eigen/Core>
#include <vector>

#include "core/status.h"

namespace formloop::recon {

class KnotVector {
 public:
  KnotVector() = default;  // empty: degree 0, no basis functions; only a placeholder

  // Clamped knot vector with n_poles basis functions of `degree` on [lo, hi] and equally spaced
  // interior knots (n_poles − degree − 1 of them; none when n_poles = degree + 1, i.e. one span:
  // the Bernstein basis on [lo, hi]).
  static Result<KnotVector> Uniform(int degree, int n_poles, double lo, double hi);
  // Clamped knot vector on [lo, hi] with the given interior knots: strictly inside (lo, hi), any
  // order (they are sorted), each value repeated at most `degree` times (so the basis stays
  // continuous).
  static Result<KnotVector> WithInteriorKnots(int degree, double lo, double hi, std::vector<double> interior);
  // From a full knot sequence (degree + 1 equal knots at each end, non-decreasing).
  static Result<KnotVector> FromSequence(int degree, std::vector<double> knots);

  int degree() const { return degree_; }
  int n_poles() const { return static_cast<int>(knots_.size()) - degree_ - 1; }
  const std::vector<double>& knots() const { return knots_; }
  double lo() const { return knots_.empty() ? 0 : knots_.front(); }
  double hi() const { return knots_.empty() ? 0 : knots_.back(); }
  std::vector<double> InteriorKnots() const;
  // The distinct knot values and their multiplicities (OpenCASCADE's form: ends have degree + 1).
  void Distinct(std::vector<double>* values, std::vector<int>* multiplicities) const;
  // Number of non-empty knot spans.
  int n_spans() const;

  // A2.1: the span index s (degree ≤ s ≤ n_poles − 1) with knots[s] ≤ x < knots[s + 1]; x = hi
  // gives the last non-empty span; x outside [lo, hi] is clamped to it. Basis functions
  // N_{s−p} ... N_s are the ones that can be non-zero at x.
  int FindSpan(double x) const;
  // A2.2: the degree + 1 basis functions N_{s−p}(x) ... N_s(x) into out[0 .. degree].
  void BasisFunctions(int span, double x, double* out) const;
  // A2.3: derivatives up to order n (≤ degree; higher orders are zero and left out):
  // (*ders)(k, j) = d^k N_{s−p+j}(x) / dx^k, resized to (n + 1) × (degree + 1).
  void BasisDerivatives(int span, double x, int n, Eigen::MatrixXd* ders) const;

  // The knot vector with `added` inserted (each strictly inside (lo, hi); the multiplicity limit of
  // WithInteriorKnots applies). Every spline on *this is also a spline on the result.
  Result<KnotVector> Inserted(const std::vector<double>& added) const;

 private:
  KnotVector(int degree, std::vector<double> knots) : degree_(degree), knots_(std::move(knots)) {}
  int degree_ = 0;
  std::vector<double> knots_;
};

// Gauss–Legendre rule with n points on [-1, 1] (exact for polynomials of degree ≤ 2n − 1), by
// Newton's method on the Legendre polynomial P_n.
void GaussLegendre(int n, std::vector<double>* nodes, std::vector<double>* weights);

// Gram matrix of the k-th derivatives, G(i, j) = ∫_a^b N_i^(k)(x) N_j^(k)(x) dx, n_poles × n_poles
// (banded: zero for |i − j| > degree), over [a, b] = [lo, hi] or the given sub-interval of it.
// Exact: Gauss–Legendre with degree + 1 points on each span's part inside [a, b].
Eigen::MatrixXd GramMatrix(const KnotVector& knots, int derivative);
Eigen::MatrixXd GramMatrix(const KnotVector& knots, int derivative, double a, double b);

// Least-squares B-spline function y ≈ f(x) = Σ_i c_i N_i(x).
struct CurveFit1d {
  KnotVector knots;
  Eigen::VectorXd coefficients;  // n_poles
  Eigen::VectorXd residuals;     // y_i − f(x_i), in input order
  double rss = 0;                // Σ residuals², summed from the residuals themselves
  // min_i |R_ii| / max_i |R_ii| of the triangular factor: near 0 = nearly rank deficient. A cheap
  // indicator of conditioning, not a condition number.
  double diagonal_ratio = 0;
  double Evaluate(double x) const;
};

// Least squares of y(x) on the given basis, by sequential Householder QR of the banded collocation
// matrix (Lawson–Hanson ch. 27): the points are sorted by x, each block of rows sharing a knot span
// is triangularised together with the (degree + 1) rows of R it overlaps, so the work is
// O(m (p + 1)²) and memory O(n_poles (p + 1)) whatever the number m of points. The normal equations
// are never formed, so the accuracy follows cond(A), not cond(A)².
// BadInput when x and y differ in length, a value is not finite, an x lies outside [lo, hi], there
// are fewer points than coefficients, or the problem is rank deficient (the abscissae fail the
// Schoenberg–Whitney condition: some basis function has no abscissa of its own).
Result<CurveFit1d> FitCurve1d(const std::vector<double>& x, const std::vector<double>& y, const KnotVector& knots);

}  // namespace formloop::recon
