#pragma once
// Checks and message text shared by the fits and projections of reconstruction/: every fit refuses
// non-finite and repeated points with the index named, and every message prints numbers and points
// the same way, whatever the global locale.

#include <string>
#include <vector>

#include <Eigen/Core>

#include "core/number_text.h"
#include "core/status.h"

namespace formloop::recon {

// "(x, y, z) mm" with 10 significant digits.
std::string PointText(const Eigen::Vector3d& p);

// BadInput naming the first non-finite coordinate (field "points[i].x") or the first pair of exactly
// repeated points (both indices, the point, and how many repeats there are in all). A repeated point
// counts twice in a least-squares fit and is usually a logging error, so the fits refuse it.
// O(n log n): a lexicographic sort of the indices.
Status CheckFiniteAndDistinct(const std::vector<Eigen::Vector3d>& points);

// BadInput when the points span less than a plane: all coincident, or collinear (the second principal
// extent below 1e-6 of the first). Such points determine no surface.
Status CheckSpansASurface(const std::vector<Eigen::Vector3d>& points);

}  // namespace formloop::recon
