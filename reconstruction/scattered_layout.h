#pragma once
// The layout of a scattered fit, internal to reconstruction/scattered_fit.cc: the frame of the parameter
// plane, the knot vectors over the data (sparse or dense coverage, de Boor's redistribution) and the
// largest hole in the points' coverage. The measurements behind the choices are in scattered_fit.h and
// beside the constants here and in scattered_layout.cc.

#include <vector>

#include <Eigen/Core>

#include "core/status.h"
#include "reconstruction/bspline_basis.h"
#include "reconstruction/bspline_surface.h"

namespace formloop::recon::scattered_internal {

// Width of the end spans inside the data, relative to the other spans (see DataKnots).
inline constexpr double kEndSpanWidth = 2;

// Frame of the parameter plane: origin, u and v axes in the plane, normal towards +z.
struct Frame {
  Eigen::Vector3d origin = Eigen::Vector3d::Zero();
  Eigen::Vector3d u_axis = Eigen::Vector3d::UnitX(), v_axis = Eigen::Vector3d::UnitY();
  Eigen::Vector3d normal = Eigen::Vector3d::UnitZ();
};

// Frame of the parameter plane (see scattered_fit.h): PCA plane, rotated to the minimum-area rectangle,
// u along its longer side, signs fixed so that the result does not depend on the eigen-solver.
Frame PcaFrame(const std::vector<Eigen::Vector3d>& points, const Eigen::Vector3d& mean, const Eigen::Matrix3d& axes);

// How the knots treat the ends of the data interval (see DataKnots; chosen in FitScattered from
// the points' coverage).
struct EdgePlan {
  bool margin_span = false;          // the end spans reach beyond the data by a margin
  double end_width = kEndSpanWidth;  // width of the end spans inside the data, relative to the others
  double rim = 0;                    // dense: uniform knots, Q's domain extends this far beyond the data
};

// Knots for n poles of degree p over the data interval [a, b].
//
// Sparse coverage (the default; always with a base surface). Inside [a, b] the spans are uniform
// except the two end spans, which are kEndSpanWidth times as wide: the piece at an edge, and above
// all at a corner, sees data from one side only and carries coefficients that only points near the
// edge determine; scattered points often leave a corner hole a few spacings wide, and a
// standard-width corner span then extrapolates a free coefficient (measured with 5,000 points on
// the reference surfaces: 2 to 36 µm of error at the corner, against < 3 µm with double width).
//
// With a margin (PCA parameters, whose box comes from the points), Q's domain reaches
// max(min_margin, h) beyond each end of [a, b] (h = interior span width), and the end spans reach
// with it: there is no knot at a or b, so beyond the data Q is the polynomial continuation of the
// end piece that the data fit. The margin lets the boundary of the sampled surface, which the
// points miss by up to a spacing (more where a curved patch's boundary projects onto a curve),
// project inside Q rather than onto its clamped edge, and moves the thin-plate energy's boundary
// (and its natural boundary conditions, see TensorLsq::Solve) off the data. Until 2026-11 the
// margin was a span of its own (a knot at a and b, one pole more at each end) decided by the
// energy alone; the continuation extrapolates better into a corner hole. Measured with 5,000
// noise-free points (the test ScatteredFitReference, degree 5): worst error over the whole domain
// egg_box 1.35 -> 1.11 µm, franke 0.52 -> 0.50 µm; degree 6: egg_box 0.13 µm both ways, franke 1.50
// -> 0.96 µm. n poles give n − p spans.
//
// Dense coverage (PCA parameters, every hole small against a span: see kDenseGapSpans): uniform
// spans over [a − rim, b + rim], rim = min_margin. Every span, the corner ones included, is then
// well filled, so neither wide end spans nor a margin is needed, and all n poles resolve the
// shape over the data (as a grid approximator's net does); the rim, a small fraction of the end
// span, still lets the sampled surface's boundary project inside Q.
Result<KnotVector> DataKnots(int p, int n, double a, double b, const EdgePlan& plan, double min_margin);

// Knots for the same number of spans in one direction of q, placed where q needs them (dense
// coverage only, see FitScattered): de Boor's NEWNOT (A Practical Guide to Splines, ch. XII) on a
// tensor product. On a degree-p piece the p-th derivative along the direction is constant; its
// jumps across the knots, divided by the distance of the span midpoints, estimate |D^(p+1) S|
// (RMS over kRedistributionSamples lines across), and spans are laid so that each holds an equal
// share of ∫ |D^(p+1) S|^(1/(p+1)): that equidistributes the approximation error, which on a span
// of width h goes as h^(p+1) |D^(p+1) S|. kRedistributionFloor × the mean density is added so that
// a flat stretch (noise-only jumps) keeps spans at most ~1/floor times the uniform width.
Result<KnotVector> RedistributedKnots(const BSplineSurface& q, const KnotVector& k, const KnotVector& other,
                                      bool along_u);

// The largest empty disc of the parameter points inside `box`: the largest distance from a node of
// a grid with the point spacing as step to its nearest point (parameter units, mm), and where.
// Beyond about two spacings from every point Q is extrapolated (typically at a corner of the
// patch), and the residuals at the points say nothing about it.
struct Gap {
  double radius_mm = 0;
  double u = 0, v = 0;
};

Gap LargestGap(const std::vector<double>& u, const std::vector<double>& v, const ParamDomain& box, double spacing);

}  // namespace formloop::recon::scattered_internal
