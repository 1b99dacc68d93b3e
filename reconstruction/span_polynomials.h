#pragma once
// A non-rational tensor-product B-spline surface as one power-form polynomial per knot span, for fast
// repeated evaluation of the point and its first and second derivatives together (the foot-point
// Newton of foot_point.h needs all six at each step).
//
// On span [u_i, u_i+1) × [v_j, v_j+1) with centres (c_u, c_v) and half-widths (h_u, h_v),
//   S(u, v) = Σ_a Σ_b C_ab s^a t^b,   s = (u − c_u)/h_u,  t = (v − c_v)/h_v ∈ [−1, 1],
//   C_ab = h_u^a h_v^b / (a! b!) · ∂^a_u ∂^b_v S(c_u, c_v)  (the Taylor coefficients at the centre),
// the derivatives from the basis-function derivatives (Piegl & Tiller, The NURBS Book, 2nd ed. 1997,
// A2.3) and the poles. This is the representation OpenCASCADE's BSplSLib_Cache keeps for one span
// (centred, scaled to [−1, 1] for conditioning); here every span is converted once, so an
// evaluation is a span look-up (the last span is remembered) and one pass over (p + 1)(q + 1)
// coefficients for all six outputs, with no allocation. Measured in bench/projection_bench.cc
// (EvalSpanPolynomials beside OpenCASCADE's Geom_BSplineSurface::D2 and GeomAdaptor_Surface::D2).

#include <Eigen/Core>
#include <vector>

#include "core/status.h"
#include "reconstruction/analytic_surface.h"
#include "reconstruction/bspline_basis.h"

namespace formloop::recon {

class BSplineSurface;  // reconstruction/bspline_surface.h

class SpanPolynomials {
 public:
  SpanPolynomials() = default;
  // Poles in the order a + n_u b (a along u). BadInput if the counts do not match the knot vectors.
  static Result<SpanPolynomials> Make(const KnotVector& u_knots, const KnotVector& v_knots,
                                      const std::vector<Eigen::Vector3d>& poles);
  // From an OpenCASCADE-backed surface; BadInput if it is rational or periodic (not represented here).
  static Result<SpanPolynomials> Of(const BSplineSurface& surface);
  // Bytes the coefficients of such a surface would take (to decide whether to build them).
  static double EstimateBytes(int u_degree, int v_degree, double u_spans, double v_spans);

  bool empty() const { return coefficients_.empty(); }

  // Remembers the last span looked up; one per thread (the tables are shared read-only).
  class Evaluator {
   public:
    explicit Evaluator(const SpanPolynomials& polynomials) : s_(polynomials) {}
    // S and its derivatives up to second order at (u, v); outside the domain the end span's
    // polynomial continues.
    SurfaceDerivatives D2(double u, double v);
    Eigen::Vector3d Point(double u, double v);

   private:
    const SpanPolynomials& s_;
    int i_ = 0, j_ = 0;  // last span
  };

 private:
  int Span(const std::vector<double>& knots, double x, int hint) const;

  int pu_ = 0, pv_ = 0;
  std::vector<double> u_knots_, v_knots_;  // distinct knots
  // Span (i, j) at (j · (u spans) + i) · (p_u + 1)(p_v + 1) · 3: C_ab at ((b (p_u + 1) + a) · 3).
  std::vector<double> coefficients_;
};

}  // namespace formloop::recon
