#include "reconstruction/quadric_fit.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <limits>
#include <locale>
#include <numeric>
#include <sstream>
#include <utility>

#include <Eigen/Dense>

#include "core/random.h"
#include "reconstruction/point_checks.h"

namespace formloop::recon {
namespace {

using Eigen::Vector3d;

constexpr const char* kAxisName[3] = {"x", "y", "z"};

std::string Num(double value, int precision = 6) { return FormatSignificant(value, precision); }

std::string TupleText(const Vector3d& v, int precision) {
  return "(" + Num(v.x(), precision) + ", " + Num(v.y(), precision) + ", " + Num(v.z(), precision) + ")";
}

// Checks shared by both fits: enough points, finite, pairwise distinct, spanning 3-D.
Status ValidatePoints(const std::vector<Vector3d>& points) {
  const std::size_t n = points.size();
  if (n < 6) {
    return Status::BadInput(
        Where{.field = "points"},
        "a quadric fit needs at least 6 points for its 6 coefficients a..f, got " + std::to_string(n),
        "measure more points over the surface");
  }
  FL_RETURN_IF_ERROR(CheckFiniteAndDistinct(points));
  // Spread about the centroid from the singular values of the centred n × 3 matrix (not of its
  // covariance, which would square the ratio and hide flatness below ~1e-8).
  Vector3d centroid = Vector3d::Zero();
  for (const Vector3d& p : points) centroid += p;
  centroid /= static_cast<double>(n);
  Eigen::MatrixX3d centred(static_cast<Eigen::Index>(n), 3);
  for (std::size_t k = 0; k < n; ++k) centred.row(static_cast<Eigen::Index>(k)) = (points[k] - centroid).transpose();
  const Eigen::JacobiSVD<Eigen::MatrixX3d> svd(centred, Eigen::ComputeFullV);
  const Vector3d sv = svd.singularValues();  // descending
  // Flatter than 1e-9 of the largest extent is flat to rounding (1e-7 mm over 100 mm).
  constexpr double kFlatRatio = 1e-9;
  if (sv(1) <= kFlatRatio * sv(0)) {
    return Status::BadInput(Where{.field = "points"},
                            "the " + std::to_string(n) + " points are collinear (through " + PointText(centroid) +
                                " along " + TupleText(svd.matrixV().col(0), 6) +
                                "); a line does not determine a quadric",
                            "measure points spread over the surface in both directions");
  }
  if (sv(2) <= kFlatRatio * sv(0)) {
    const Vector3d normal = svd.matrixV().col(2);
    return Status::BadInput(Where{.field = "points"},
                            "the " + std::to_string(n) + " points are coplanar (plane through " + PointText(centroid) +
                                " with normal " + TupleText(normal, 6) + ", out-of-plane RMS " +
                                Num(sv(2) / std::sqrt(static_cast<double>(n))) +
                                " mm); a plane does not determine a quadric",
                            "measure a curved surface, or fit a plane instead");
  }
  return Status::Ok();
}

struct Spread {
  Vector3d centroid;
  double rms_radius_mm;  // sqrt(mean |p − centroid|²)
  double max_radius_mm;
};

Spread SpreadOf(const std::vector<Vector3d>& points) {
  Spread s{Vector3d::Zero(), 0, 0};
  for (const Vector3d& p : points) s.centroid += p;
  s.centroid /= static_cast<double>(points.size());
  double sum2 = 0;
  for (const Vector3d& p : points) {
    const double r2 = (p - s.centroid).squaredNorm();
    sum2 += r2;
    s.max_radius_mm = std::max(s.max_radius_mm, std::sqrt(r2));
  }
  s.rms_radius_mm = std::sqrt(sum2 / static_cast<double>(points.size()));
  return s;
}

// The centre form of a fitted quadric, if it exists and stays within kMaxCentreFormScale of the data.
std::optional<QuadricCentreForm> CentreFormWithinData(const Quadric& quadric, const Spread& spread,
                                                      std::vector<std::string>* notes) {
  const Result<QuadricCentreForm> form = quadric.CentreForm();
  if (!form.ok()) {
    notes->push_back("no centre form: " + form.status().message());
    return std::nullopt;
  }
  const double limit = kMaxCentreFormScale * spread.max_radius_mm;
  const double far = std::max((form->centre - spread.centroid).norm(), form->semi_axes.maxCoeff());
  if (far > limit) {
    notes->push_back("no centre form reported: the fitted " + form->kind + " has its centre or a semi-axis " +
                     Num(far) + " mm away, more than " + Num(kMaxCentreFormScale) +
                     " times the radius of the points (" + Num(spread.max_radius_mm) +
                     " mm); over these points it cannot be told from a paraboloid or cylinder, so the "
                     "general form is the result");
    return std::nullopt;
  }
  return *form;
}

// True orthogonal distances of the points to the quadric.
Status FillDistances(const Quadric& quadric, const std::vector<Vector3d>& points, QuadricFit* fit) {
  double sum2 = 0, sum2_alg = 0, max = -1;
  for (std::size_t k = 0; k < points.size(); ++k) {
    const Result<QuadricFoot> foot = QuadricFootPoint(quadric, points[k]);
    if (!foot.ok()) return foot.status();
    const double dist = std::abs(foot->distance_mm);
    sum2 += dist * dist;
    if (dist > max) {
      max = dist;
      fit->max_at = points[k];
    }
    const double alg = quadric.Evaluate(points[k]);
    sum2_alg += alg * alg;
  }
  const double n = static_cast<double>(points.size());
  fit->rms_distance_mm = std::sqrt(sum2 / n);
  fit->max_distance_mm = max;
  fit->rms_algebraic = std::sqrt(sum2_alg / n);
  fit->n_points = static_cast<int>(points.size());
  return Status::Ok();
}

}  // namespace

// ---------------------------------------------------------------------------------------------
// Algebraic fit

Result<QuadricFit> FitQuadricAlgebraic(const std::vector<Vector3d>& points) {
  FL_RETURN_IF_ERROR(ValidatePoints(points).WithContext("quadric-algebraic"));
  const Spread spread = SpreadOf(points);
  const Vector3d& m = spread.centroid;
  const double s = spread.rms_radius_mm;

  // Conditioning: in part coordinates x² ≈ 2 x̄ x − x̄² over a patch far from the origin, so the columns
  // x², x and 1 are nearly dependent and differ in size by |x̄|². In u = (x − x̄)/s (s = RMS radius) the
  // columns are O(1) and centred. The map between the coefficients is a bijection (a, b unchanged, c..f
  // affine) and the residuals scale by s², so the least-squares solution maps back exactly: this is the
  // same estimator, only better conditioned.
  const Eigen::Index n = static_cast<Eigen::Index>(points.size());
  Eigen::MatrixXd design(n, 6);
  Eigen::VectorXd rhs(n);
  for (Eigen::Index k = 0; k < n; ++k) {
    const Vector3d u = (points[static_cast<std::size_t>(k)] - m) / s;
    design.row(k) << u.y() * u.y(), u.z() * u.z(), u.x(), u.y(), u.z(), 1.0;
    rhs(k) = -u.x() * u.x();
  }
  Eigen::ColPivHouseholderQR<Eigen::MatrixXd> qr(design);
  // With O(1) columns a pivot below 1e-10 of the largest is a linear dependence of the columns, not noise.
  qr.setThreshold(1e-10);
  if (qr.rank() < 6) {
    const Eigen::JacobiSVD<Eigen::MatrixXd> svd(design, Eigen::ComputeThinV);
    const Eigen::VectorXd null = svd.matrixV().col(5);
    const char* names[6] = {"y²", "z²", "x", "y", "z", "1"};
    std::string relation;
    for (int i = 0; i < 6; ++i) {
      if (std::abs(null(i)) < 1e-6) continue;
      relation += (relation.empty() ? (null(i) < 0 ? "−" : "") : (null(i) < 0 ? " − " : " + ")) +
                  Num(std::abs(null(i)), 3) + (i == 5 ? "" : std::string(" ") + names[i]);
    }
    return Status::BadInput(
        Where{.field = "points"},
        "quadric-algebraic: the design matrix has rank " + std::to_string(qr.rank()) + " < 6: the points satisfy " +
            relation +
            " = 0 (in coordinates centred on the centroid and scaled by the RMS radius), a relation without x², "
            "e.g. a cylinder or paraboloid along x, which the form x² + a y² + ... = 0 cannot represent",
        "relabel the axes so that x is not the surface's axis, or use a B-spline fit");
  }
  const Eigen::VectorXd sol = qr.solve(rhs);
  if (!sol.allFinite()) return Status::Internal("quadric-algebraic: the QR solve gave non-finite coefficients");

  QuadricFit fit;
  fit.method = "quadric-algebraic";
  Quadric& q = fit.quadric;
  q.a = sol(0);
  q.b = sol(1);
  // Back to part coordinates: with x = x̄ + s u, G(x)/s² = u² + a v² + b w² + c' u + d' v + e' w + f'.
  q.c = s * sol(2) - 2 * m.x();
  q.d = s * sol(3) - 2 * q.a * m.y();
  q.e = s * sol(4) - 2 * q.b * m.z();
  q.f = s * s * sol(5) - (m.x() * m.x() + q.a * m.y() * m.y() + q.b * m.z() * m.z()) -
        (q.c * m.x() + q.d * m.y() + q.e * m.z());
  fit.centre_form = CentreFormWithinData(q, spread, &fit.notes);
  const Status distances = FillDistances(q, points, &fit);
  if (!distances.ok()) {
    return Status::Failed("quadric-algebraic: the least-squares quadric has no real points near the data (" +
                          distances.message() + "); the points are not a quadric of this axis-aligned form");
  }
  return fit;
}

// ---------------------------------------------------------------------------------------------
// Geometric fit

Status GeometricFitOptions::Validate() const {
  if (max_iterations < 1 || max_iterations > 10000) {
    return Status::BadInput(Where{.field = "max_iterations"}, std::to_string(max_iterations) + " is out of range",
                            "use 1..10000 (default 50)");
  }
  if (!(tolerance > 0) || !(tolerance < 1e-2)) {
    return Status::BadInput(Where{.field = "tolerance"}, "tolerance " + Num(tolerance) + " is not in (0, 0.01)",
                            "use e.g. 1e-12");
  }
  return Status::Ok();
}

namespace {

using Vector6d = Eigen::Matrix<double, 6, 1>;

// Residuals (signed orthogonal distances, positive where F > 0) and their Jacobian for centre-form
// parameters θ = (x0, y0, z0, A, B, C) with fixed signs.
struct OdfState {
  Vector6d theta;
  Eigen::VectorXd r;
  Eigen::MatrixXd jac;
  double cost = 0;  // ½ Σ r²
};

Status EvaluateOdf(const std::vector<Vector3d>& points, const Vector6d& theta, const Eigen::Vector3i& signs,
                   OdfState* state) {
  QuadricCentreForm form;
  form.centre = theta.head<3>();
  form.semi_axes = theta.tail<3>();
  form.signs = signs;
  FL_ASSIGN_OR_RETURN(const Quadric quadric, Quadric::FromCentreForm(form));
  const Eigen::Index n = static_cast<Eigen::Index>(points.size());
  state->theta = theta;
  state->r.resize(n);
  state->jac.resize(n, 6);
  const Vector3d sgn = signs.cast<double>();
  const Vector3d inv_a2 = theta.tail<3>().cwiseAbs2().cwiseInverse();
  for (Eigen::Index k = 0; k < n; ++k) {
    const Vector3d& p = points[static_cast<std::size_t>(k)];
    FL_ASSIGN_OR_RETURN(const QuadricFoot foot, QuadricFootPoint(quadric, p));
    // F(x; θ) = Σ s_i (x_i − x0_i)²/A_i² − 1 at the foot q.
    const Vector3d y = foot.foot - form.centre;
    const Vector3d grad_x = 2 * sgn.cwiseProduct(y).cwiseProduct(inv_a2);  // ∇ₓF(q)
    const double grad_norm = grad_x.norm();
    if (!(grad_norm > 0)) {
      return Status::Failed("quadric-geometric: the foot point of " + PointText(p) + " is singular");
    }
    state->r(k) = (p - foot.foot).dot(grad_x) / grad_norm;
    // ∂d/∂θ = (∂F/∂θ)(q)/|∇ₓF(q)|: ∂F/∂x0_i = −∂F/∂x_i, ∂F/∂A_i = −2 s_i y_i²/A_i³.
    for (int i = 0; i < 3; ++i) {
      state->jac(k, i) = -grad_x(i) / grad_norm;
      state->jac(k, 3 + i) = -2 * sgn(i) * y(i) * y(i) * inv_a2(i) / theta(3 + i) / grad_norm;
    }
  }
  state->cost = 0.5 * state->r.squaredNorm();
  return Status::Ok();
}

}  // namespace

Result<QuadricFit> FitQuadricGeometric(const std::vector<Vector3d>& points, const QuadricFit& start,
                                       const GeometricFitOptions& options) {
  FL_RETURN_IF_ERROR(options.Validate().WithContext("quadric-geometric options"));
  FL_RETURN_IF_ERROR(ValidatePoints(points).WithContext("quadric-geometric"));
  if (!start.centre_form) {
    std::string why;
    for (const std::string& note : start.notes) why += " " + note;
    return Status::BadInput(Where{.field = "start"},
                            "quadric-geometric: the start fit has no centre form to iterate on." + why,
                            "the data are nearer a paraboloid or cylinder than a central quadric; use the "
                            "algebraic fit's general form, or a B-spline fit");
  }
  const Eigen::Vector3i signs = start.centre_form->signs;
  Vector6d theta;
  theta << start.centre_form->centre, start.centre_form->semi_axes;

  OdfState cur;
  FL_RETURN_IF_ERROR(EvaluateOdf(points, theta, signs, &cur).WithContext("quadric-geometric start"));
  const double start_rms = std::sqrt(2 * cur.cost / static_cast<double>(points.size()));

  // Levenberg–Marquardt: minimise ‖[J; √μ·D] δ + [r; 0]‖ by column-pivoting QR (not the normal equations,
  // which would square the condition number: on a partial cap the centre and the semi-axis along the cap's
  // normal are strongly correlated). D holds the largest column norms of J seen so far (Moré 1978).
  Vector6d scale = Vector6d::Zero();
  double mu = 1e-3;
  constexpr double kMaxMu = 1e12;
  const double tol = options.tolerance;
  int iterations = 0;
  bool converged = false;
  std::string stop = "reached max_iterations = " + std::to_string(options.max_iterations);
  const Eigen::Index n = static_cast<Eigen::Index>(points.size());
  while (iterations < options.max_iterations) {
    if (cur.cost == 0) {
      converged = true;
      stop = "zero residual";
      break;
    }
    ++iterations;
    for (int i = 0; i < 6; ++i) scale(i) = std::max(scale(i), cur.jac.col(i).norm());
    Eigen::MatrixXd aug(n + 6, 6);
    aug.topRows(n) = cur.jac;
    aug.bottomRows(6) = (std::sqrt(mu) * scale.cwiseMax(1e-300)).asDiagonal();
    Eigen::VectorXd rhs = Eigen::VectorXd::Zero(n + 6);
    rhs.head(n) = -cur.r;
    const Vector6d step = aug.colPivHouseholderQr().solve(rhs);
    const bool tiny_step = step.norm() <= tol * (cur.theta.norm() + tol);
    const Vector6d trial_theta = cur.theta + step;
    OdfState trial;
    const bool valid = step.allFinite() && trial_theta.tail<3>().minCoeff() > 0 &&
                       EvaluateOdf(points, trial_theta, signs, &trial).ok();
    if (valid && trial.cost < cur.cost) {
      const double cost_drop = (cur.cost - trial.cost) / cur.cost;
      cur = std::move(trial);
      mu = std::max(mu / 10, 1e-15);
      if (tiny_step) {
        converged = true;
        stop = "relative step " + Num(step.norm() / cur.theta.norm(), 3) + " <= tolerance";
        break;
      }
      if (cost_drop <= tol) {
        converged = true;
        stop = "relative cost decrease " + Num(cost_drop, 3) + " <= tolerance";
        break;
      }
    } else {
      // No decrease: more damping. A rejected step that is already below the step tolerance means the
      // cost is flat to rounding here: the minimum is reached.
      if (valid && tiny_step) {
        converged = true;
        stop = "relative step " + Num(step.norm() / cur.theta.norm(), 3) + " <= tolerance (cost flat to rounding)";
        break;
      }
      mu *= 10;
      if (mu > kMaxMu) {
        converged = true;
        stop = "no decrease possible (damping " + Num(mu) + "): the minimum is reached to rounding";
        break;
      }
    }
  }

  QuadricFit fit;
  fit.method = "quadric-geometric";
  fit.iterations = iterations;
  fit.converged = converged;
  QuadricCentreForm form;
  form.centre = cur.theta.head<3>();
  form.semi_axes = cur.theta.tail<3>();
  form.signs = signs;
  form.kind = start.centre_form->kind;
  form.sign_flipped = signs.x() < 0;
  FL_ASSIGN_OR_RETURN(fit.quadric, Quadric::FromCentreForm(form));
  const Spread spread = SpreadOf(points);
  if (CentreFormWithinData(fit.quadric, spread, &fit.notes)) fit.centre_form = form;
  // Distances: the minimised residuals are the orthogonal distances.
  fit.n_points = static_cast<int>(points.size());
  fit.rms_distance_mm = std::sqrt(2 * cur.cost / static_cast<double>(n));
  Eigen::Index k_max = 0;
  fit.max_distance_mm = cur.r.cwiseAbs().maxCoeff(&k_max);
  fit.max_at = points[static_cast<std::size_t>(k_max)];
  double sum2_alg = 0;
  for (const Vector3d& p : points) sum2_alg += fit.quadric.Evaluate(p) * fit.quadric.Evaluate(p);
  fit.rms_algebraic = std::sqrt(sum2_alg / static_cast<double>(n));

  fit.notes.push_back("Levenberg-Marquardt stopped after " + std::to_string(iterations) + " iteration(s): " + stop);
  const Vector3d d_centre_um = 1e3 * (form.centre - start.centre_form->centre);
  const Vector3d d_axes_um = 1e3 * (form.semi_axes - start.centre_form->semi_axes);
  fit.notes.push_back("change from the start (algebraic) fit: centre by (" + Num(d_centre_um.x(), 4) + ", " +
                      Num(d_centre_um.y(), 4) + ", " + Num(d_centre_um.z(), 4) + ") um, semi-axes by (" +
                      Num(d_axes_um.x(), 4) + ", " + Num(d_axes_um.y(), 4) + ", " + Num(d_axes_um.z(), 4) +
                      ") um; RMS orthogonal distance " + Num(1e3 * start_rms, 4) + " -> " +
                      Num(1e3 * fit.rms_distance_mm, 4) + " um");
  return fit;
}

// ---------------------------------------------------------------------------------------------
// B-spline patch of the fitted quadric

namespace {

// Height of the quadric over (x_i, x_j) along axis k: the roots of D h² + l h + R = 0 with D = D_k, l = l_k
// and R = G(x with x_k = 0). Branch σ = ±1 is the root c_k + σ·sqrt(disc)/(2|D|) (the +k or −k side of the
// centre plane). Each root is taken in the form without cancellation (−l + s with s of the sign of −l, else
// Vieta's 2R/(−l − s)), which matters for the near root of a near-paraboloid (|D| tiny, c_k huge).
// D = 0 exactly: the single root −R/l.
struct HeightFunction {
  Quadric q;
  int k = 2, i = 0, j = 1;
  bool linear = false;  // D_k == 0: one root

  // False where the line misses the surface (beyond its silhouette seen along k).
  bool Height(double xi, double xj, int branch, double* h) const {
    const Vector3d dq(1, q.a, q.b), lq(q.c, q.d, q.e);
    Vector3d x = Vector3d::Zero();
    x(i) = xi;
    x(j) = xj;
    const double r = q.Evaluate(x);
    const double dk = dq(k), lk = lq(k);
    if (linear) {
      if (lk == 0) return false;
      *h = -r / lk;
      return true;
    }
    const double disc = lk * lk - 4 * dk * r;
    if (!(disc >= 0)) return false;
    const double s = branch * (dk > 0 ? 1 : -1) * std::sqrt(disc);
    if ((s >= 0) == (-lk >= 0)) {
      *h = (-lk + s) / (2 * dk);
    } else {
      const double den = -lk - s;
      if (den == 0) return false;
      *h = 2 * r / den;
    }
    return std::isfinite(*h);
  }
  Vector3d Point(double xi, double xj, double h) const {
    Vector3d x;
    x(i) = xi;
    x(j) = xj;
    x(k) = h;
    return x;
  }
};

double NodeParam(double lo, double hi, int idx, int n) {
  // Same node placement as FitGrid (exact corners).
  if (idx == n - 1) return hi;
  return lo + (hi - lo) * static_cast<double>(idx) / (n - 1);
}

}  // namespace

Result<BSplineSurface> QuadricToBSpline(const QuadricFit& fit, const std::vector<Vector3d>& points, double tolerance_mm,
                                        FitReport* report) {
  if (!(tolerance_mm > 0) || !std::isfinite(tolerance_mm)) {
    return Status::BadInput(Where{.field = "tolerance_mm"}, "tolerance " + Num(tolerance_mm) + " mm is not positive",
                            "use e.g. 1e-3");
  }
  if (points.size() < 3) {
    return Status::BadInput(Where{.field = "points"}, "need at least 3 points to bound the cap", "");
  }
  for (std::size_t n = 0; n < points.size(); ++n) {
    if (!points[n].allFinite()) {
      return Status::BadInput(Where{.field = "points[" + std::to_string(n) + "]"}, "point is not finite", "");
    }
  }
  const Quadric& q = fit.quadric;

  // Height axis: the coordinate axis nearest the mean unit normal of the points.
  Vector3d mean_normal = Vector3d::Zero();
  for (const Vector3d& p : points) {
    const Vector3d grad = q.Gradient(p);
    if (grad.norm() > 0) mean_normal += grad.normalized();
  }
  HeightFunction hf;
  hf.q = q;
  Eigen::Index height_axis = 2;
  mean_normal.cwiseAbs().maxCoeff(&height_axis);
  hf.k = static_cast<int>(height_axis);
  hf.i = (hf.k + 1) % 3;
  hf.j = (hf.k + 2) % 3;
  const Vector3d dq(1, q.a, q.b), lq(q.c, q.d, q.e);
  hf.linear = dq(hf.k) == 0;
  if (hf.linear && lq(hf.k) == 0) {
    return Status::BadInput(Where{.field = "quadric"},
                            std::string("the quadric does not depend on ") + kAxisName[hf.k] +
                                " (a cylinder along it), so it is no graph over the other two axes",
                            "use a B-spline fit of the points");
  }

  ParamDomain dom{std::numeric_limits<double>::infinity(), -std::numeric_limits<double>::infinity(),
                  std::numeric_limits<double>::infinity(), -std::numeric_limits<double>::infinity()};
  for (const Vector3d& p : points) {
    dom.u_min = std::min(dom.u_min, p(hf.i));
    dom.u_max = std::max(dom.u_max, p(hf.i));
    dom.v_min = std::min(dom.v_min, p(hf.j));
    dom.v_max = std::max(dom.v_max, p(hf.j));
  }
  if (!(dom.u_span() > 0) || !(dom.v_span() > 0)) {
    return Status::BadInput(
        Where{.field = "points"},
        "the points' bounding rectangle over (" + std::string(kAxisName[hf.i]) + ", " + kAxisName[hf.j] + ") is empty",
        "");
  }

  // Branch: the one most points are nearer to; every point must agree, or the cap is not a graph.
  int votes_plus = 0, votes_minus = 0;
  std::size_t first_plus = 0, first_minus = 0;
  for (std::size_t n = 0; n < points.size(); ++n) {
    const Vector3d& p = points[n];
    double h_plus = 0, h_minus = 0;
    if (!hf.Height(p(hf.i), p(hf.j), 1, &h_plus) || !hf.Height(p(hf.i), p(hf.j), -1, &h_minus)) {
      return Status::BadInput(Where{.field = "points[" + std::to_string(n) + "]"},
                              "point " + PointText(p) + " lies beyond the silhouette of the quadric seen along " +
                                  kAxisName[hf.k] + ": the cap is not a graph over (" + kAxisName[hf.i] + ", " +
                                  kAxisName[hf.j] + ")",
                              "drop the points at the edge of the cap, or fit a B-spline to the points");
    }
    if (std::abs(p(hf.k) - h_plus) <= std::abs(p(hf.k) - h_minus)) {
      if (votes_plus++ == 0) first_plus = n;
    } else {
      if (votes_minus++ == 0) first_minus = n;
    }
  }
  const int branch = hf.linear ? 1 : (votes_plus >= votes_minus ? 1 : -1);
  if (!hf.linear && votes_plus > 0 && votes_minus > 0) {
    return Status::BadInput(Where{.field = "points"},
                            std::to_string(votes_plus) + " points lie on the + branch and " +
                                std::to_string(votes_minus) + " on the − branch of the quadric over (" +
                                kAxisName[hf.i] + ", " + kAxisName[hf.j] + ") (e.g. points " +
                                std::to_string(first_plus) + " and " + std::to_string(first_minus) +
                                "): the points wrap around the surface and are not one graph",
                            "split the points into caps that are each a graph, and convert each");
  }
  // Each point must also sit on that branch, not merely nearer to it than to the other (a near-cylinder
  // has both far away): its gap along k may be at most 1 % of the rectangle's diagonal plus ten times the
  // fit's largest distance (a point on a steep part is farther from the graph along k than along the normal).
  const double max_gap_mm = 0.01 * std::hypot(dom.u_span(), dom.v_span()) + 10 * fit.max_distance_mm;
  for (std::size_t n = 0; n < points.size(); ++n) {
    const Vector3d& p = points[n];
    double h = 0;
    const bool hit = hf.Height(p(hf.i), p(hf.j), branch, &h);
    if (!hit || std::abs(p(hf.k) - h) > max_gap_mm) {
      return Status::BadInput(Where{.field = "points[" + std::to_string(n) + "]"},
                              "point " + PointText(p) + " is " + (hit ? Num(std::abs(p(hf.k) - h)) : "infinitely") +
                                  " mm from the quadric's graph along " + kAxisName[hf.k] + " (allowed " +
                                  Num(max_gap_mm) + " mm): the quadric is not a graph over (" + kAxisName[hf.i] + ", " +
                                  kAxisName[hf.j] + ") near the points",
                              "check the fit, or fit a B-spline to the points");
    }
  }

  // Seeded check points inside the rectangle, on the exact quadric (same for every grid tried).
  constexpr int kCheckPoints = 400;
  constexpr std::uint64_t kCheckSeed = 0x51ad71cULL;
  Rng rng(kCheckSeed);
  struct Check {
    double u, v;
    Vector3d p;
  };
  std::vector<Check> checks;
  checks.reserve(kCheckPoints);
  for (int n = 0; n < kCheckPoints; ++n) {
    Check c;
    c.u = rng.Uniform(dom.u_min, dom.u_max);
    c.v = rng.Uniform(dom.v_min, dom.v_max);
    double h = 0;
    if (!hf.Height(c.u, c.v, branch, &h)) {
      return Status::BadInput(Where{.field = "points"},
                              "the points' bounding rectangle over (" + std::string(kAxisName[hf.i]) + ", " +
                                  kAxisName[hf.j] + ") reaches past the quadric's silhouette (at " + kAxisName[hf.i] +
                                  " = " + Num(c.u) + ", " + kAxisName[hf.j] + " = " + Num(c.v) + ")",
                              "trim the points to a rectangle inside the cap");
    }
    c.p = hf.Point(c.u, c.v, h);
    checks.push_back(c);
  }

  GridFitOptions options;
  // Half the tolerance at the nodes leaves the other half for the error between them.
  options.tolerance_mm = tolerance_mm / 2;
  nlohmann::json attempts = nlohmann::json::array();
  BSplineSurface surface;
  FitReport grid_report;
  double check_rms = 0, check_max = 0;
  Vector3d check_max_at = Vector3d::Zero();
  int grid_n = 0;
  for (const int n : {25, 49, 97}) {
    GridSamples samples;
    samples.nu = samples.nv = n;
    samples.domain = dom;
    samples.points.reserve(static_cast<std::size_t>(n) * n);
    for (int iv = 0; iv < n; ++iv) {
      const double v = NodeParam(dom.v_min, dom.v_max, iv, n);
      for (int iu = 0; iu < n; ++iu) {
        const double u = NodeParam(dom.u_min, dom.u_max, iu, n);
        double h = 0;
        if (!hf.Height(u, v, branch, &h)) {
          return Status::BadInput(Where{.field = "points"},
                                  "the points' bounding rectangle over (" + std::string(kAxisName[hf.i]) + ", " +
                                      kAxisName[hf.j] + ") reaches past the quadric's silhouette (at " +
                                      kAxisName[hf.i] + " = " + Num(u) + ", " + kAxisName[hf.j] + " = " + Num(v) + ")",
                                  "trim the points to a rectangle inside the cap");
        }
        samples.points.push_back(hf.Point(u, v, h));
      }
    }
    FL_ASSIGN_OR_RETURN(surface, FitGrid(samples, options, &grid_report));
    double sum2 = 0;
    check_max = -1;
    for (const Check& c : checks) {
      FL_ASSIGN_OR_RETURN(const FootPoint foot, ProjectFrom(surface, c.p, c.u, c.v));
      const double err = (c.p - foot.foot).norm();
      sum2 += err * err;
      if (err > check_max) {
        check_max = err;
        check_max_at = c.p;
      }
    }
    check_rms = std::sqrt(sum2 / kCheckPoints);
    grid_n = n;
    attempts.push_back({{"grid", n}, {"check_max_mm", check_max}, {"grid_max_mm", grid_report.max_mm}});
    if (check_max <= tolerance_mm) break;
  }

  if (report != nullptr) {
    *report = grid_report;
    report->method = "quadric-graph-bspline";
    report->n_check = kCheckPoints;
    report->check_rms_mm = check_rms;
    report->check_max_mm = check_max;
    report->check_max_at = check_max_at;
    report->details = {
        {"source", fit.method},
        {"quadric", q.ToJson()},
        {"height_axis", kAxisName[hf.k]},
        {"graph_over", nlohmann::json::array({kAxisName[hf.i], kAxisName[hf.j]})},
        {"branch", hf.linear ? "single" : (branch > 0 ? "+" : "-")},
        {"domain_mm", nlohmann::json::array({dom.u_min, dom.u_max, dom.v_min, dom.v_max})},
        {"grid", grid_n},
        {"tolerance_mm", tolerance_mm},
        {"occt_tolerance_mm", options.tolerance_mm},
        {"degree", nlohmann::json::array({surface.u_degree(), surface.v_degree()})},
        {"poles", nlohmann::json::array({surface.u_poles(), surface.v_poles()})},
        {"check_seed", kCheckSeed},
        {"attempts", attempts},
    };
    report->notes.clear();
    if (check_max > tolerance_mm) {
      report->notes.push_back("the B-spline patch is " + Num(check_max) +
                              " mm from the exact quadric at worst, over the "
                              "stated tolerance of " +
                              Num(tolerance_mm) + " mm even with a " + std::to_string(grid_n) + " x " +
                              std::to_string(grid_n) + " grid; the cap is probably steep near its edge");
    }
  }
  return surface;
}

}  // namespace formloop::recon
