// PointGrid (reconstruction/point_grid.h): its nearest and within-radius answers are those of a search
// over every point, for queries on the sheet of points and far from it (where the kd-tree answers), with
// ties broken by the lower index.

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <utility>
#include <vector>

#include "core/random.h"
#include "reconstruction/point_grid.h"

namespace formloop::recon {
namespace {

using Eigen::Vector3d;

// A curved sheet of samples like a projector's start grid: z = 4 sin(x / 9) cos(y / 7) over 60 × 50 mm,
// 0.5 mm apart, with every 97th sample repeated (exact ties).
std::vector<Vector3d> Sheet() {
  std::vector<Vector3d> out;
  for (int j = 0; j <= 100; ++j) {
    for (int i = 0; i <= 120; ++i) {
      const double x = 0.5 * i, y = 0.5 * j;
      out.emplace_back(x, y, 4 * std::sin(x / 9) * std::cos(y / 7));
      if (out.size() % 97 == 0) out.push_back(out.back());
    }
  }
  return out;
}

std::pair<int, double> BruteNearest(const std::vector<Vector3d>& points, const Vector3d& p) {
  int best = -1;
  double best_d2 = std::numeric_limits<double>::infinity();
  for (std::size_t k = 0; k < points.size(); ++k) {
    const double d2 = (points[k] - p).squaredNorm();
    if (d2 < best_d2) {  // ascending index: the first of equals is kept
      best_d2 = d2;
      best = static_cast<int>(k);
    }
  }
  return {best, std::sqrt(best_d2)};
}

std::vector<std::pair<double, int>> BruteWithin(const std::vector<Vector3d>& points, const Vector3d& p, double r) {
  std::vector<std::pair<double, int>> out;
  for (std::size_t k = 0; k < points.size(); ++k) {
    const double d2 = (points[k] - p).squaredNorm();
    if (d2 <= r * r) out.emplace_back(std::sqrt(d2), static_cast<int>(k));
  }
  std::sort(out.begin(), out.end());
  return out;
}

// Queries at heights from on the sheet to 40 mm off it (and beyond its edges), each checked bit for bit.
TEST(PointGridTest, NearestAndWithinRadiusAreTheExhaustiveSearchsNearAndFarFromThePoints) {
  const std::vector<Vector3d> points = Sheet();
  const PointGrid grid(points, 1.0);
  ASSERT_EQ(grid.size(), points.size());
  Rng rng(20261128);
  int far = 0, ties = 0;
  std::vector<std::pair<double, int>> within;
  for (int q = 0; q < 600; ++q) {
    const double height = q % 3 == 0 ? rng.Uniform(-0.3, 0.3) : rng.Uniform(-40, 40);
    const Vector3d on(rng.Uniform(-10, 70), rng.Uniform(-10, 60), 0);
    const Vector3d p(on.x(), on.y(), 4 * std::sin(on.x() / 9) * std::cos(on.y() / 7) + height);
    const auto [want, want_d] = BruteNearest(points, p);
    double got_d = -1;
    const int got = grid.Nearest(p, &got_d);
    ASSERT_EQ(got, want) << "query " << q;
    ASSERT_EQ(got_d, want_d) << "query " << q;  // the same sqrt of the same squared norm
    far += want_d > 4.0;
    // The projector's follow-up: every point within the nearest distance plus a margin.
    const double r = want_d + (q % 2 == 0 ? 0.7 : 6.0);
    grid.WithinRadius(p, r, &within);
    ASSERT_EQ(within, BruteWithin(points, p, r)) << "query " << q;
  }
  // A query on a repeated sample's normal, on it and 25 mm off it to either side (where the kd-tree answers):
  // the lower index of the two, where that sample is the nearest.
  for (std::size_t k = 96; k + 1 < points.size(); k += 97) {
    ASSERT_EQ(points[k], points[k + 1]) << k;
    const double x = points[k].x(), y = points[k].y();
    const Vector3d n =
        Vector3d(-4 / 9.0 * std::cos(x / 9) * std::cos(y / 7), 4 / 7.0 * std::sin(x / 9) * std::sin(y / 7), 1)
            .normalized();
    for (const double lift : {0.0, 25.0, -25.0}) {
      const Vector3d p = points[k] + lift * n;
      const auto want = BruteNearest(points, p);
      double d = -1;
      EXPECT_EQ(grid.Nearest(p, &d), want.first) << k;
      ties += lift != 0 && want.first == static_cast<int>(k);
    }
  }
  EXPECT_GT(far, 200);  // the kd-tree's queries were exercised
  EXPECT_GT(ties, 50);  // of the 2 × 127 off the sheet (85: where that sample is the nearest)
}

// A copy keeps answering (the points and the tree are shared, never changed), also after the original is gone.
TEST(PointGridTest, ACopyAnswersAfterTheOriginalIsGone) {
  const std::vector<Vector3d> points = Sheet();
  PointGrid copy;
  {
    const PointGrid grid(points, 1.0);
    double d = 0;
    ASSERT_GE(grid.Nearest(Vector3d(30, 25, 30), &d), 0);  // builds the tree
    copy = grid;
  }
  const Vector3d p(12, 40, -25);
  double d = -1;
  EXPECT_EQ(copy.Nearest(p, &d), BruteNearest(points, p).first);
  EXPECT_EQ(d, BruteNearest(points, p).second);
}

}  // namespace
}  // namespace formloop::recon
