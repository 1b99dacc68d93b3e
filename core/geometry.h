#pragma once
// Small geometric helpers shared by several layers (mm, any frame).

#include <algorithm>

#include <Eigen/Core>

namespace formloop {

// Distance from p to the segment [a, b] (to a when a = b).
inline double SegmentDistance(const Eigen::Vector3d& p, const Eigen::Vector3d& a, const Eigen::Vector3d& b) {
  const Eigen::Vector3d ab = b - a;
  const double len2 = ab.squaredNorm();
  const double t = len2 > 0 ? std::clamp((p - a).dot(ab) / len2, 0.0, 1.0) : 0.0;
  return (a + t * ab - p).norm();
}

}  // namespace formloop
