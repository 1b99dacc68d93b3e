#include "metrology/feature_fit.h"

#include <algorithm>
#include <cmath>
#include <string>

#include <Eigen/Dense>

namespace formloop::metrology {
namespace {

// Two unit vectors completing `axis` (unit) to a right-handed frame.
void Complete(const Eigen::Vector3d& axis, Eigen::Vector3d* e1, Eigen::Vector3d* e2) {
  const Eigen::Vector3d helper = std::abs(axis.x()) < 0.9 ? Eigen::Vector3d::UnitX() : Eigen::Vector3d::UnitY();
  *e1 = axis.cross(helper).normalized();
  *e2 = axis.cross(*e1);
}

}  // namespace

Result<CircleFit> FitCircle(const std::vector<Eigen::Vector2d>& points, double step_tolerance_mm, int max_iterations) {
  const int n = static_cast<int>(points.size());
  if (n < 3) {
    return Status::BadInput("circle fit: " + std::to_string(n) +
                            " points (DIM_INSUFFICIENT_POINTS); a circle needs at least 3, 4 or more give redundancy");
  }
  Eigen::Vector2d mean = Eigen::Vector2d::Zero();
  for (const auto& p : points) mean += p;
  mean /= n;
  double scale = 0;
  for (const auto& p : points) scale = std::max(scale, (p - mean).norm());
  if (!(scale > 0)) return Status::BadInput("circle fit: all points coincide");
  // Algebraic start on coordinates about the centroid, scaled to O(1).
  Eigen::MatrixXd m(n, 3);
  Eigen::VectorXd rhs(n);
  for (int i = 0; i < n; ++i) {
    const Eigen::Vector2d q = (points[i] - mean) / scale;
    m.row(i) << q.x(), q.y(), 1.0;
    rhs(i) = -q.squaredNorm();
  }
  Eigen::ColPivHouseholderQR<Eigen::MatrixXd> qr(m);
  qr.setThreshold(1e-10);
  if (qr.rank() < 3) return Status::BadInput("circle fit: the points lie on one line");
  const Eigen::Vector3d abc = qr.solve(rhs);
  double r2 = 0.25 * (abc(0) * abc(0) + abc(1) * abc(1)) - abc(2);
  if (!(r2 > 0)) return Status::BadInput("circle fit: the algebraic start has no real radius");
  CircleFit fit;
  Eigen::Vector3d theta(-0.5 * abc(0), -0.5 * abc(1), std::sqrt(r2));  // scaled units about the centroid
  // Geometric refinement (Gauss–Newton) in the scaled frame.
  Eigen::MatrixXd j(n, 3);
  Eigen::VectorXd rho(n);
  const double tol = step_tolerance_mm / scale;
  for (int it = 0; it < max_iterations; ++it) {
    for (int i = 0; i < n; ++i) {
      const Eigen::Vector2d q = (points[i] - mean) / scale - theta.head<2>();
      const double d = q.norm();
      rho(i) = d - theta(2);
      if (d > 0) {
        j.row(i) << -q.x() / d, -q.y() / d, -1.0;
      } else {
        j.row(i) << 0.0, 0.0, -1.0;
      }
    }
    const Eigen::Vector3d step = j.colPivHouseholderQr().solve(-rho);
    theta += step;
    ++fit.iterations;
    if (!step.allFinite()) return Status::Internal("circle fit: Gauss-Newton diverged");
    if (step.norm() < tol) break;
  }
  fit.centre = mean + scale * theta.head<2>();
  fit.radius = scale * std::abs(theta(2));
  fit.residuals.resize(n);
  for (int i = 0; i < n; ++i) fit.residuals[i] = (points[i] - fit.centre).norm() - fit.radius;
  return fit;
}

Result<PlaneFit> FitPlane(const std::vector<Eigen::Vector3d>& points) {
  const int n = static_cast<int>(points.size());
  if (n < 3) {
    return Status::BadInput("plane fit: " + std::to_string(n) +
                            " points (DIM_INSUFFICIENT_POINTS); a plane needs 3 that are not on one line");
  }
  PlaneFit fit;
  for (const auto& p : points) fit.centroid += p;
  fit.centroid /= n;
  Eigen::MatrixXd rows(n, 3);
  for (int i = 0; i < n; ++i) rows.row(i) = (points[i] - fit.centroid).transpose();
  Eigen::JacobiSVD<Eigen::MatrixXd> svd(rows, Eigen::ComputeFullV);
  const Eigen::Vector3d s = svd.singularValues();
  if (!(s(0) > 0) || s(1) <= 1e-9 * s(0)) return Status::BadInput("plane fit: the points lie on one line");
  fit.normal = svd.matrixV().col(2).normalized();
  fit.heights.resize(n);
  for (int i = 0; i < n; ++i) fit.heights[i] = fit.normal.dot(points[i] - fit.centroid);
  return fit;
}

Result<LineFit2d> FitLine2d(const std::vector<Eigen::Vector2d>& points) {
  const int n = static_cast<int>(points.size());
  if (n < 2)
    return Status::BadInput("line fit: " + std::to_string(n) + " points (DIM_INSUFFICIENT_POINTS); a line needs 2");
  LineFit2d fit;
  for (const auto& p : points) fit.centroid += p;
  fit.centroid /= n;
  Eigen::MatrixXd rows(n, 2);
  for (int i = 0; i < n; ++i) rows.row(i) = (points[i] - fit.centroid).transpose();
  Eigen::JacobiSVD<Eigen::MatrixXd> svd(rows, Eigen::ComputeFullV);
  if (!(svd.singularValues()(0) > 0)) return Status::BadInput("line fit: all points coincide");
  fit.direction = svd.matrixV().col(0).normalized();
  if (fit.direction.dot(points.back() - points.front()) < 0) fit.direction = -fit.direction;
  return fit;
}

Result<CylinderFit> FitCylinder(const std::vector<Eigen::Vector3d>& points, const Eigen::Vector3d& axis_in,
                                double step_tolerance_mm, int max_iterations) {
  const int n = static_cast<int>(points.size());
  if (n < 5) {
    return Status::BadInput("cylinder fit: " + std::to_string(n) +
                            " points (DIM_INSUFFICIENT_POINTS); a cylinder needs at least 5 at two or more heights");
  }
  if (!(axis_in.norm() > 0)) return Status::Internal("cylinder fit: zero nominal axis");
  const Eigen::Vector3d e3 = axis_in.normalized();
  Eigen::Vector3d e1, e2;
  Complete(e3, &e1, &e2);
  Eigen::Vector3d centroid = Eigen::Vector3d::Zero();
  for (const auto& p : points) centroid += p;
  centroid /= n;
  double h_min = 1e300, h_max = -1e300;
  std::vector<Eigen::Vector2d> projected(n);
  for (int i = 0; i < n; ++i) {
    const Eigen::Vector3d w = points[i] - centroid;
    projected[i] = Eigen::Vector2d(w.dot(e1), w.dot(e2));
    h_min = std::min(h_min, w.dot(e3));
    h_max = std::max(h_max, w.dot(e3));
  }
  FL_ASSIGN_OR_RETURN(const CircleFit start, FitCircle(projected));
  if (h_max - h_min <= 1e-3 * start.radius) {
    return Status::BadInput(
        "cylinder fit: the points lie at one height along the axis, so its tilt is not determined; probe at two or "
        "more heights or use method CIRCLE");
  }
  // θ = (x0, y0, α, β, r): axis through centroid + x0 e1 + y0 e2 along normalise(e3 + α e1 + β e2).
  Eigen::Matrix<double, 5, 1> theta;
  theta << start.centre.x(), start.centre.y(), 0, 0, start.radius;
  auto residuals = [&](const Eigen::Matrix<double, 5, 1>& t) {
    const Eigen::Vector3d p0 = centroid + t(0) * e1 + t(1) * e2;
    const Eigen::Vector3d a = (e3 + t(2) * e1 + t(3) * e2).normalized();
    Eigen::VectorXd r(n);
    for (int i = 0; i < n; ++i) {
      const Eigen::Vector3d w = points[i] - p0;
      r(i) = (w - w.dot(a) * a).norm() - t(4);
    }
    return r;
  };
  CylinderFit fit;
  const double scale = std::max(start.radius, h_max - h_min);
  Eigen::MatrixXd jac(n, 5);
  for (int it = 0; it < max_iterations; ++it) {
    const Eigen::VectorXd r = residuals(theta);
    for (int k = 0; k < 5; ++k) {
      const double h = 1e-7 * (k == 2 || k == 3 ? 1.0 : scale);
      Eigen::Matrix<double, 5, 1> tp = theta, tm = theta;
      tp(k) += h;
      tm(k) -= h;
      jac.col(k) = (residuals(tp) - residuals(tm)) / (2 * h);
    }
    Eigen::ColPivHouseholderQR<Eigen::MatrixXd> qr(jac);
    qr.setThreshold(1e-10);
    if (qr.rank() < 5) return Status::BadInput("cylinder fit: the points do not determine a cylinder (rank-deficient)");
    const Eigen::Matrix<double, 5, 1> step = qr.solve(-r);
    theta += step;
    ++fit.iterations;
    if (!step.allFinite()) return Status::Internal("cylinder fit: Gauss-Newton diverged");
    const double step_mm = std::hypot(std::hypot(step(0), step(1)), step(4)) + scale * std::hypot(step(2), step(3));
    if (step_mm < step_tolerance_mm) break;
  }
  const Eigen::Vector3d p0 = centroid + theta(0) * e1 + theta(1) * e2;
  fit.axis = (e3 + theta(2) * e1 + theta(3) * e2).normalized();
  fit.axis_point = p0 + (centroid - p0).dot(fit.axis) * fit.axis;
  fit.radius = std::abs(theta(4));
  const Eigen::VectorXd r = residuals(theta);
  fit.residuals.assign(r.data(), r.data() + n);
  return fit;
}

}  // namespace formloop::metrology
