#pragma once
// The quadric "certainty surface" (spec/reconstruction.md §3; seed 002, step 3 (3) 1), eq. 11):
//
//   general form  G(x) = x² + a y² + b z² + c x + d y + e z + f = 0          (axis-aligned, normalised on x²)
//   centre form   s_x (x − x0)²/A² + s_y (y − y0)²/B² + s_z (z − z0)²/C² = 1,  s_i ∈ {+1, −1}
//
// Completing the squares gives x0 = −c/2, y0 = −d/(2a), z0 = −e/(2b) and
// (x − x0)² + a (y − y0)² + b (z − z0)² = g with g = x0² + a y0² + b z0² − f. For g > 0 dividing by g gives
// A² = g, B² = g/|a|, C² = g/|b|, signs (+1, sign a, sign b). For g < 0 the equation is multiplied by −1 first
// (the "overall sign flip"): A² = |g|, B² = |g|/|a|, C² = |g|/|b|, signs (−1, −sign a, −sign b);
// QuadricCentreForm::sign_flipped says so. The signs name the surface: three + an ellipsoid, two + a
// hyperboloid of one sheet, one + a hyperboloid of two sheets (no + would be an empty "imaginary ellipsoid").
// The centre form does not exist for a ≈ 0 or b ≈ 0 (paraboloids, cylinders) nor for g ≈ 0 (cones).
//
// All coordinates are in the part frame, mm; a and b are dimensionless, c..e are mm, f is mm².
//
// Fits:
// - FitQuadricAlgebraic: the seed's method, linear least squares on the algebraic residual
//   e_i = G(p_i) (mm²), solved by column-pivoting Householder QR in centred and scaled coordinates.
// - FitQuadricGeometric: orthogonal-distance fit (ODF), Levenberg–Marquardt in the centre-form parameters
//   (x0, y0, z0, A, B, C) with the signs held fixed, started from the algebraic fit. The Jacobian is the
//   exact derivative of the orthogonal distance: at the foot point q, ∂d/∂θ = (∂F/∂θ)(q) / |∇ₓF(q)| for the
//   centre-form function F(x; θ) = Σ s_i (x_i − x0_i)²/A_i² − 1 (the foot point's own motion is tangential
//   and drops out). This is the "distance-based" Jacobian of
//     S. J. Ahn, W. Rauh, H. S. Cho, H.-J. Warnecke, "Orthogonal distance fitting of implicit curves and
//     surfaces", IEEE Trans. PAMI 24(5):620–638, 2002, §3 (and, for conics, S. J. Ahn, W. Rauh,
//     H.-J. Warnecke, "Least-squares orthogonal distances fitting of circle, sphere, ellipse, hyperbola,
//     and parabola", Pattern Recognition 34(12):2283–2303, 2001);
//   damping after D. W. Marquardt, J. SIAM 11(2):431–441, 1963, with the scaling of J. J. Moré, "The
//   Levenberg–Marquardt algorithm: implementation and theory", LNM 630, 1978.
//
// The algebraic fit weights each point's squared distance by |∇G(p_i)|² (G(p) ≈ |∇G|·d near the surface),
// which varies along an elongated surface; the geometric fit weights all points alike (maximum likelihood
// for Gaussian noise along the normal). With µm noise both are consistent (the algebraic fit's bias is
// O(σ²), far below the noise); the difference is efficiency: where |∇G| varies ~5× over the data the
// geometric fit's errors are 2–2.5× smaller (tests/reconstruction/quadric_fit_test.cc). Report both and
// their difference (QuadricFit::notes of the geometric fit states it).

#include <optional>
#include <string>
#include <vector>

#include <Eigen/Core>
#include <nlohmann/json.hpp>

#include "core/status.h"
#include "reconstruction/bspline_surface.h"

namespace formloop::recon {

struct QuadricCentreForm {
  Eigen::Vector3d centre = Eigen::Vector3d::Zero();     // (x0, y0, z0), mm
  Eigen::Vector3d semi_axes = Eigen::Vector3d::Ones();  // (A, B, C) > 0, mm
  Eigen::Vector3i signs = Eigen::Vector3i::Ones();      // (s_x, s_y, s_z), each +1 or −1
  // "ellipsoid", "hyperboloid_one_sheet" or "hyperboloid_two_sheets" (from the number of + signs).
  std::string kind = "ellipsoid";
  // True when g < 0 and the general form was multiplied by −1 to reach "= 1" (see the header comment).
  bool sign_flipped = false;
  nlohmann::json ToJson() const;
};

// The general form; the coefficient of x² is 1. Default: the unit sphere.
struct Quadric {
  double a = 1, b = 1;         // y², z² coefficients (dimensionless)
  double c = 0, d = 0, e = 0;  // x, y, z coefficients, mm
  double f = -1;               // constant, mm²

  // G(p), mm² (the algebraic residual of eq. 12).
  double Evaluate(const Eigen::Vector3d& p) const;
  // ∇G(p), mm; points to the side where G > 0.
  Eigen::Vector3d Gradient(const Eigen::Vector3d& p) const;
  // The centre form, or BadInput naming why it does not exist: |a| or |b| below kMinQuadraticRatio
  // (paraboloid or cylinder), g ≈ 0 (cone), every sign negative (no real points), non-finite coefficients.
  Result<QuadricCentreForm> CentreForm() const;
  // The general form of a centre form (signs ±1 with at least one +1, finite positive semi-axes).
  static Result<Quadric> FromCentreForm(const QuadricCentreForm& form);
  nlohmann::json ToJson() const;
};

// |a| or |b| at or below this (a semi-axis more than 10⁶ times another) counts as zero: no centre form.
inline constexpr double kMinQuadraticRatio = 1e-12;
// A fit's centre form is reported only while its centre and semi-axes stay within this many times the
// radius of the point set around its centroid; beyond that the data cannot tell the quadric from a
// paraboloid or cylinder and the centre form would be noise (QuadricFit::notes says so).
inline constexpr double kMaxCentreFormScale = 1e3;

struct QuadricFit {
  Quadric quadric;
  // Absent when the fitted quadric has no meaningful centre form (see kMaxCentreFormScale and
  // Quadric::CentreForm); the general form is still the least-squares answer. `notes` says why.
  std::optional<QuadricCentreForm> centre_form;
  // True orthogonal distances of the fitted points to the fitted surface (QuadricFootPoint), mm.
  double rms_distance_mm = 0;
  double max_distance_mm = 0;
  Eigen::Vector3d max_at = Eigen::Vector3d::Zero();  // the point with the largest distance
  double rms_algebraic = 0;                          // RMS of G(p_i), mm² (what the algebraic fit minimises)
  int iterations = 0;     // Levenberg–Marquardt iterations (linear solves); 0 for the algebraic fit
  bool converged = true;  // geometric fit: stopped on the step or cost criterion, not max_iterations
  std::string method;     // "quadric-algebraic" | "quadric-geometric"
  int n_points = 0;
  // Plain-language statements for the user (unavailable centre form, stopping reason, change from the
  // algebraic start).
  std::vector<std::string> notes;
  nlohmann::json ToJson() const;
};

// Algebraic least-squares fit (seed eq. 12): minimises Σ G(p_i)² over (a, b, c, d, e, f).
// points: n ≥ 6 finite, pairwise distinct, not coplanar, in mm. Errors (BadInput) name the offending
// point indices, or, for a rank-deficient design, the combination of x², y², z², x, y, z, 1 the points
// satisfy (e.g. a cylinder along x, which has no x² term and cannot be normalised on it).
Result<QuadricFit> FitQuadricAlgebraic(const std::vector<Eigen::Vector3d>& points);

struct GeometricFitOptions {
  int max_iterations = 50;  // LM iterations; the fits in the tests converge in under 15
  // Stop when the relative step |Δθ| ≤ tolerance·(|θ| + tolerance) or the relative cost decrease
  // ≤ tolerance. 1e-12 is a few hundred ulps: it lets exact data reach the truth to ~1e-12 relative.
  double tolerance = 1e-12;
  Status Validate() const;
};

// Orthogonal-distance fit started from `start` (normally FitQuadricAlgebraic's result), whose centre form
// must exist; its signs are kept. The returned fit's distances are the minimised ones.
Result<QuadricFit> FitQuadricGeometric(const std::vector<Eigen::Vector3d>& points, const QuadricFit& start,
                                       const GeometricFitOptions& options = {});

// The point of the surface G = 0 nearest to p.
struct QuadricFoot {
  Eigen::Vector3d foot = Eigen::Vector3d::Zero();  // mm
  // ∇G(foot)/|∇G(foot)|: towards G > 0. Zero at a cone's apex, where it is undefined.
  Eigen::Vector3d normal = Eigen::Vector3d::Zero();
  double distance_mm = 0;  // signed: +|p − foot| where G(p) > 0, −|p − foot| where G(p) < 0
  double lambda = 0;       // Lagrange multiplier: p = foot + (λ/2) ∇G(foot)
  // True when p lies on a symmetry plane inside the surface's focal region, where the nearest point is not
  // unique (e.g. the centre of a sphere); the foot returned is the one on the + side of the first free axis.
  bool ambiguous = false;
};

// Exact orthogonal distance from p to any real axis-aligned quadric in general form (central or not).
// Method: the Lagrange conditions give foot(λ)_i = (p_i − λ l_i/2)/(1 + λ D_i) with D = (1, a, b) and
// l = (c, d, e), so G(foot(λ)) = 0 is a 1-D secular equation φ(λ) = 0. The global minimiser is the root
// with every 1 + λ D_i ≥ 0 (J. J. Moré, "Generalizations of the trust region problem", Optimization
// Methods and Software 2:189–209, 1993, Thm. 3.2: one quadratic constraint, I + λ·diag(D) ⪰ 0); on that
// interval φ is strictly decreasing, so the root is unique. It is found by safeguarded Newton with
// bisection in the offset from the nearer pole (so a foot near a pole — a point close to a symmetry plane,
// near the centre or an axis — keeps full relative precision), and the "hard case" (p exactly on the
// symmetry plane, root at the pole) is solved in closed form as in D. Eberly, "Distance from a point to an
// ellipse, an ellipsoid, or a hyperellipsoid", Geometric Tools, 2013. Validated in the tests against a
// sphere's |p − c| − R and against brute-force sampling of ellipsoids and hyperboloids.
// Errors: non-finite p or coefficients; an empty quadric (no real points).
Result<QuadricFoot> QuadricFootPoint(const Quadric& quadric, const Eigen::Vector3d& p);

// The fitted quadric as the pipeline's ideal surface Q: the cap covering `points`, as a B-spline patch.
// The patch is the graph h(u, v) of the quadric over the two coordinate axes most transverse to the mean
// normal of the points (height axis k = the axis nearest that normal; (u, v, k) is a cyclic permutation of
// (x, y, z), so the patch normal S_u × S_v points to +k — the side the tool comes from for k = z), on the
// branch nearest the points, over the bounding rectangle of the points' (u, v). It is sampled exactly on
// an n × n grid and converted by FitGrid (approximation tolerance tolerance_mm / 2); the exact quadric is then
// compared with the patch at 400 seeded check points (distance from the quadric point to its foot point on
// the patch) and the grid is refined (n = 25, 49, 97) until that max is within tolerance_mm. If the finest grid
// does not reach it, the surface is still returned and report->notes says the figure reached.
// Errors (BadInput): a point or the rectangle reaches past the quadric's silhouette over (u, v); the points
// lie on both branches, or a point is farther from the chosen branch along k than 1 % of the rectangle's
// diagonal plus 10 × fit.max_distance_mm (not one graph); G does not depend on x_k (a cylinder along k).
// The patch's degree is chosen by OpenCASCADE (3..5).
Result<BSplineSurface> QuadricToBSpline(const QuadricFit& fit, const std::vector<Eigen::Vector3d>& points,
                                        double tolerance_mm, FitReport* report);

}  // namespace formloop::recon
