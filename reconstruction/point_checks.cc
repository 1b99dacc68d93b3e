#include "reconstruction/point_checks.h"

#include <algorithm>
#include <cmath>
#include <locale>
#include <numeric>

#include <Eigen/Eigenvalues>

namespace formloop::recon {

std::string PointText(const Eigen::Vector3d& p) {
  return "(" + FormatSignificant(p.x(), 10) + ", " + FormatSignificant(p.y(), 10) + ", " +
         FormatSignificant(p.z(), 10) + ") mm";
}

Status CheckFiniteAndDistinct(const std::vector<Eigen::Vector3d>& points) {
  constexpr const char* kAxis[3] = {"x", "y", "z"};
  const std::size_t n = points.size();
  for (std::size_t k = 0; k < n; ++k) {
    for (int axis = 0; axis < 3; ++axis) {
      if (!std::isfinite(points[k](axis))) {
        return Status::BadInput(Where{.field = "points[" + std::to_string(k) + "]." + kAxis[axis]},
                                "point " + std::to_string(k) + " has " + kAxis[axis] + " = " +
                                    FormatSignificant(points[k](axis)) + ": the point is not finite",
                                "remove or re-measure that point");
      }
    }
  }
  std::vector<std::size_t> order(n);
  std::iota(order.begin(), order.end(), std::size_t{0});
  std::sort(order.begin(), order.end(), [&](std::size_t i, std::size_t j) {
    const Eigen::Vector3d &p = points[i], &q = points[j];
    if (p.x() != q.x()) return p.x() < q.x();
    if (p.y() != q.y()) return p.y() < q.y();
    if (p.z() != q.z()) return p.z() < q.z();
    return i < j;
  });
  std::size_t first_i = 0, first_j = 0, repeats = 0;
  for (std::size_t k = 1; k < n; ++k) {
    if (points[order[k]] != points[order[k - 1]]) continue;
    const std::size_t i = std::min(order[k], order[k - 1]), j = std::max(order[k], order[k - 1]);
    if (repeats == 0 || i < first_i || (i == first_i && j < first_j)) {
      first_i = i;
      first_j = j;
    }
    ++repeats;
  }
  if (repeats > 0) {
    return Status::BadInput(Where{.field = "points"},
                            "points " + std::to_string(first_i) + " and " + std::to_string(first_j) +
                                " are identical " + PointText(points[first_i]) + " (" + std::to_string(repeats) +
                                " repeated point(s) in all)",
                            "remove repeated measurements (e.g. overlapping scan passes) or average them into one");
  }
  return Status::Ok();
}

Status CheckSpansASurface(const std::vector<Eigen::Vector3d>& points) {
  if (points.size() < 3) {
    return Status::BadInput(Where{.field = "points"},
                            "need at least 3 points to define a surface, got " + std::to_string(points.size()));
  }
  Eigen::Vector3d mean = Eigen::Vector3d::Zero();
  for (const auto& p : points) mean += p;
  mean /= static_cast<double>(points.size());
  Eigen::Matrix3d cov = Eigen::Matrix3d::Zero();
  for (const auto& p : points) cov += (p - mean) * (p - mean).transpose();
  const Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> eig(cov);
  const Eigen::Vector3d extent = eig.eigenvalues().cwiseMax(0).cwiseSqrt();  // ascending
  if (!(extent(2) > 0)) {
    return Status::BadInput(Where{.field = "points"}, "all points coincide at " + PointText(mean),
                            "the points must sample a surface");
  }
  if (extent(1) < 1e-6 * extent(2)) {
    return Status::BadInput(Where{.field = "points"},
                            "the points are collinear (principal extents " + FormatSignificant(extent(2)) + " and " +
                                FormatSignificant(extent(1)) + " mm): they determine no surface",
                            "the points must sample a surface, not a line");
  }
  return Status::Ok();
}

}  // namespace formloop::recon
