#pragma once
// Least-squares features through probe points: circle, plane, 2-D line, cylinder
// (spec/tuning-and-link.md §2). All lengths in mm.
//
// Circle (geometric, not algebraic). Start from the algebraic (Kåsa) fit
//   min Σ (u_i² + v_i² + a·u_i + b·v_i + c)²,  centre (−a/2, −b/2), r = √(a²/4 + b²/4 − c)
// on coordinates taken about the centroid, then Gauss–Newton on the geometric residuals
// ρ_i = ‖p_i − centre‖ − r (column-pivoted Householder QR of the Jacobian) until a step is below
// step_tolerance_mm (1e-9 mm) or 50 iterations. The algebraic fit is biased towards small circles on
// arcs and noisy data; the geometric one is the ISO/GPS "least-squares (Gaussian) circle". Checked on
// the Gander–Golub–Strebel six points (data/reference/circle-fit-gander) to 1e-6.
//
// Plane. Centroid p̄; the normal is the right singular vector of the rows (p_i − p̄) for the smallest
// singular value; heights h_i = n·(p_i − p̄). Needs 3 points that are not collinear. The 2-D line is
// the same in the plane.
//
// Cylinder. Gauss–Newton on d_i = dist(p_i, axis) − r over 5 parameters (a point of the axis in the
// plane normal to the starting axis, two tilts of the axis, r), started from the circle fit of the points
// projected along the nominal axis. Needs 5 points spread over at least two heights along the axis.
//
// References: W. Gander, G. H. Golub, R. Strebel, "Least-squares fitting of circles and ellipses", BIT
// 34:558-578, 1994; I. Kåsa, "A circle fitting procedure and its error analysis", IEEE Trans. Instrum.
// Meas. 25:8-14, 1976; ISO 12181-1 (roundness) and ISO 12781-1 (flatness) for the Gaussian references.

#include <vector>

#include <Eigen/Core>

#include "core/status.h"

namespace formloop::metrology {

struct CircleFit {
  Eigen::Vector2d centre = Eigen::Vector2d::Zero();
  double radius = 0;
  std::vector<double> residuals;  // ρ_i = ‖p_i − centre‖ − r, in input order
  int iterations = 0;             // Gauss–Newton steps after the algebraic start
};

struct PlaneFit {
  Eigen::Vector3d centroid = Eigen::Vector3d::Zero();
  Eigen::Vector3d normal = Eigen::Vector3d::UnitZ();  // unit; sign as the SVD gives it unless oriented
  std::vector<double> heights;                        // h_i = n·(p_i − p̄)
};

struct LineFit2d {
  Eigen::Vector2d centroid = Eigen::Vector2d::Zero();
  Eigen::Vector2d direction = Eigen::Vector2d::UnitX();  // unit, oriented from the first point to the last
};

struct CylinderFit {
  Eigen::Vector3d axis_point = Eigen::Vector3d::Zero();  // the axis point nearest the points' centroid
  Eigen::Vector3d axis = Eigen::Vector3d::UnitZ();       // unit, oriented like the starting axis
  double radius = 0;
  std::vector<double> residuals;  // dist(p_i, axis) − r
  int iterations = 0;
};

// At least 3 points not on one line; BadInput otherwise (the message names the count or the collinearity).
Result<CircleFit> FitCircle(const std::vector<Eigen::Vector2d>& points, double step_tolerance_mm = 1e-9,
                            int max_iterations = 50);
// At least 3 points not on one line.
Result<PlaneFit> FitPlane(const std::vector<Eigen::Vector3d>& points);
// At least 2 distinct points.
Result<LineFit2d> FitLine2d(const std::vector<Eigen::Vector2d>& points);
// At least 5 points; `axis` is the nominal axis direction (unit or not).
Result<CylinderFit> FitCylinder(const std::vector<Eigen::Vector3d>& points, const Eigen::Vector3d& axis,
                                double step_tolerance_mm = 1e-9, int max_iterations = 50);

}  // namespace formloop::metrology
