// Spatial weights: Delaunay (CGAL) against a brute-force empty-circumcircle triangulation, distance
// band against brute force, k nearest neighbours against brute force (ties broken by index: lattices,
// coincident and collinear points, clusters, 3-D; the grid and the kd-tree paths), the same weights for
// 1 and 2 threads, GAL write/read round trip, island policies.

#include <algorithm>
#include <filesystem>
#include <map>
#include <set>
#include <utility>

#include <unistd.h>

#include <gtest/gtest.h>
#include <Eigen/Dense>

#include "core/parallel.h"
#include "core/random.h"
#include "metrology/spatial_weights.h"

namespace formloop::metrology {
namespace {

using Edges = std::set<std::pair<int, int>>;

Edges EdgesOf(const SpatialWeights& w) {
  Edges edges;
  const auto nb = w.Neighbours();
  for (int i = 0; i < static_cast<int>(nb.size()); ++i) {
    for (int j : nb[static_cast<std::size_t>(i)]) edges.emplace(i, j);
  }
  return edges;
}

// Delaunay edges by definition: (i, j, k) is a Delaunay triangle when no other point lies strictly
// inside its circumcircle (points in general position). O(n⁴), for small n.
Edges BruteForceDelaunay(const Eigen::MatrixXd& p) {
  const int n = static_cast<int>(p.cols());
  Edges edges;
  for (int i = 0; i < n; ++i) {
    for (int j = i + 1; j < n; ++j) {
      for (int k = j + 1; k < n; ++k) {
        const Eigen::Vector2d a = p.col(i), b = p.col(j), c = p.col(k);
        const double d = 2 * (a.x() * (b.y() - c.y()) + b.x() * (c.y() - a.y()) + c.x() * (a.y() - b.y()));
        if (std::abs(d) < 1e-12) continue;
        const double ux = (a.squaredNorm() * (b.y() - c.y()) + b.squaredNorm() * (c.y() - a.y()) +
                           c.squaredNorm() * (a.y() - b.y())) /
                          d;
        const double uy = (a.squaredNorm() * (c.x() - b.x()) + b.squaredNorm() * (a.x() - c.x()) +
                           c.squaredNorm() * (b.x() - a.x())) /
                          d;
        const Eigen::Vector2d centre(ux, uy);
        const double r2 = (a - centre).squaredNorm();
        bool empty = true;
        for (int m = 0; m < n && empty; ++m) {
          if (m != i && m != j && m != k && (p.col(m) - centre).squaredNorm() < r2 * (1 - 1e-12)) empty = false;
        }
        if (!empty) continue;
        for (auto [s, t] : {std::pair{i, j}, std::pair{j, k}, std::pair{i, k}}) {
          edges.emplace(s, t);
          edges.emplace(t, s);
        }
      }
    }
  }
  return edges;
}

TEST(SpatialWeightsTest, DelaunayOfASquareWithItsCentre) {
  Eigen::MatrixXd p(2, 5);
  p << 0, 1, 1, 0, 0.5,  //
      0, 0, 1, 1, 0.5;
  const auto w = DelaunayWeights(p, WeightStyle::kBinary);
  ASSERT_TRUE(w.ok()) << w.status().message();
  const auto nb = w->Neighbours();
  EXPECT_EQ(nb[4], (std::vector<int>{0, 1, 2, 3}));
  EXPECT_EQ(nb[0], (std::vector<int>{1, 3, 4}));  // no diagonal through the centre
  EXPECT_EQ(nb[2], (std::vector<int>{1, 3, 4}));
  EXPECT_EQ(w->islands, 0);
  const auto rs = DelaunayWeights(p, WeightStyle::kRowStandardised);
  ASSERT_TRUE(rs.ok());
  EXPECT_DOUBLE_EQ(rs->w.coeff(4, 0), 0.25);
  EXPECT_DOUBLE_EQ(rs->w.coeff(0, 4), 1.0 / 3.0);
}

TEST(SpatialWeightsTest, DelaunayMatchesBruteForceEmptyCircles) {
  Rng rng(21);
  for (int trial = 0; trial < 5; ++trial) {
    const int n = 25 + 5 * trial;
    Eigen::MatrixXd p(2, n);
    for (int i = 0; i < n; ++i) p.col(i) << rng.Uniform(0, 10), rng.Uniform(-3, 4);
    const auto w = DelaunayWeights(p, WeightStyle::kBinary);
    ASSERT_TRUE(w.ok());
    const Edges got = EdgesOf(w.value());
    EXPECT_EQ(got, BruteForceDelaunay(p)) << "trial " << trial;
    const Eigen::MatrixXd dense = Eigen::MatrixXd(w->w);
    EXPECT_EQ((dense - dense.transpose()).cwiseAbs().maxCoeff(), 0.0);
  }
}

TEST(SpatialWeightsTest, DelaunayOfCollinearPointsIsTheChain) {
  Eigen::MatrixXd p(2, 4);
  p << 3, 0, 2, 1,  //
      6, 0, 4, 2;
  const auto w = DelaunayWeights(p, WeightStyle::kBinary);
  ASSERT_TRUE(w.ok()) << w.status().message();
  const auto nb = w->Neighbours();
  EXPECT_EQ(nb[1], (std::vector<int>{3}));
  EXPECT_EQ(nb[3], (std::vector<int>{1, 2}));
  EXPECT_EQ(nb[2], (std::vector<int>{0, 3}));
  EXPECT_EQ(nb[0], (std::vector<int>{2}));
}

TEST(SpatialWeightsTest, DelaunayRefusesCoincidentPoints) {
  Eigen::MatrixXd p(2, 4);
  p << 0, 1, 0, 1,  //
      0, 0, 1, 0;
  const auto w = DelaunayWeights(p, WeightStyle::kBinary);
  ASSERT_FALSE(w.ok());
  EXPECT_EQ(w.status().code(), StatusCode::kBadInput);
  EXPECT_NE(w.status().message().find("points 1 and 3"), std::string::npos) << w.status().message();
}

TEST(SpatialWeightsTest, DistanceBandMatchesBruteForce) {
  Rng rng(4);
  for (int dim : {2, 3}) {
    const int n = 300;
    Eigen::MatrixXd p(dim, n);
    for (int i = 0; i < n; ++i) {
      for (int d = 0; d < dim; ++d) p(d, i) = rng.Uniform(100, 110);  // offset: float rounding in PCL
    }
    const double radius = 1.1;
    const auto w = DistanceBandWeights(p, radius, WeightStyle::kRowStandardised);
    ASSERT_TRUE(w.ok());
    Edges expected;
    std::vector<int> islands;
    for (int i = 0; i < n; ++i) {
      bool any = false;
      for (int j = 0; j < n; ++j) {
        if (j != i && (p.col(i) - p.col(j)).norm() <= radius) {
          expected.emplace(i, j);
          any = true;
        }
      }
      if (!any) islands.push_back(i);
    }
    EXPECT_EQ(EdgesOf(w.value()), expected) << dim << "-D";
    EXPECT_EQ(w->island_indices, islands);
    for (int i = 0; i < n; ++i) {
      if (w->w.row(i).nonZeros() > 0) {
        EXPECT_NEAR(w->w.row(i).sum(), 1.0, 1e-15);
      }
    }
  }
}

TEST(SpatialWeightsTest, DistanceBandIsInclusiveOnALattice) {
  // 4 × 4 integer lattice: band 1 = rook neighbours, band √2 = queen neighbours.
  Eigen::MatrixXd p(2, 16);
  for (int i = 0; i < 16; ++i) p.col(i) << i % 4, i / 4;
  const auto rook = DistanceBandWeights(p, 1.0, WeightStyle::kBinary);
  const auto queen = DistanceBandWeights(p, std::sqrt(2.0), WeightStyle::kBinary);
  ASSERT_TRUE(rook.ok() && queen.ok());
  EXPECT_EQ(rook->w.nonZeros(), 2 * (2 * 4 * 3));               // 24 rook pairs, both directions
  EXPECT_EQ(queen->w.nonZeros(), 2 * (2 * 4 * 3 + 2 * 3 * 3));  // + 18 diagonal pairs
  EXPECT_EQ(rook->Neighbours()[5], (std::vector<int>{1, 4, 6, 9}));
  EXPECT_EQ(DistanceBandWeights(p, 0, WeightStyle::kBinary).status().code(), StatusCode::kBadInput);
}

// k-NN rows by definition: the k smallest (‖p_j − p_i‖², j), j ≠ i, as the weights list them (ascending),
// for every k in `ks` from one ordering of each row (the first k of a total order are the k smallest).
std::map<int, std::vector<std::vector<int>>> BruteForceKnn(const Eigen::MatrixXd& p, const std::vector<int>& ks) {
  const int n = static_cast<int>(p.cols());
  const int most = *std::max_element(ks.begin(), ks.end());
  std::map<int, std::vector<std::vector<int>>> rows;
  for (int k : ks) rows[k].resize(static_cast<std::size_t>(n));
  std::vector<std::pair<double, int>> all;
  for (int i = 0; i < n; ++i) {
    all.clear();
    for (int j = 0; j < n; ++j) {
      if (j != i) all.emplace_back((p.col(j) - p.col(i)).squaredNorm(), j);
    }
    std::partial_sort(all.begin(), all.begin() + most, all.end());
    for (int k : ks) {
      auto& row = rows[k][static_cast<std::size_t>(i)];
      for (int m = 0; m < k; ++m) row.push_back(all[static_cast<std::size_t>(m)].second);
      std::sort(row.begin(), row.end());
    }
  }
  return rows;
}

void ExpectKnnIsBruteForce(const Eigen::MatrixXd& p, const std::string& what) {
  const std::vector<int> ks = {1, 3, 5, 8, 12};
  const auto expected = BruteForceKnn(p, ks);
  for (int k : ks) {
    const auto w = KnnWeights(p, k, WeightStyle::kRowStandardised);
    ASSERT_TRUE(w.ok()) << what << ": " << w.status().ToString();
    EXPECT_EQ(w->w.nonZeros(), static_cast<long>(p.cols()) * k) << what;
    EXPECT_EQ(w->islands, 0) << what;
    const auto got = w->Neighbours();
    long wrong = 0;
    for (std::size_t i = 0; i < got.size(); ++i) wrong += got[i] != expected.at(k)[i];
    EXPECT_EQ(wrong, 0) << what << ", k = " << k << ": rows differing from brute force";
    for (int i = 0; i < w->n(); ++i) EXPECT_DOUBLE_EQ(w->w.row(i).sum(), 1.0);
  }
}

TEST(SpatialWeightsTest, KnnMatchesBruteForceWithTiesBrokenByIndex) {
  Rng rng(11);
  Eigen::MatrixXd uniform(2, 2000);
  for (int i = 0; i < uniform.cols(); ++i) uniform.col(i) << rng.Uniform(), rng.Uniform();
  // A lattice: every point has 4 neighbours at 1, 4 at √2, 4 at 2, 8 at √5 (ties across any k).
  Eigen::MatrixXd lattice(2, 40 * 30);
  for (int i = 0; i < 40 * 30; ++i) lattice.col(i) << i % 40, i / 40;
  // Coincident points (each site three times) and points on one line (the grid cannot be used).
  Eigen::MatrixXd coincident(2, 600);
  for (int i = 0; i < 600; ++i) coincident.col(i) << (i % 200) % 17, (i % 200) / 17;
  Eigen::MatrixXd collinear(2, 500);
  for (int i = 0; i < 500; ++i) collinear.col(i) << 0.5 * (i % 250), 2.0 * (i % 250);
  // Two tight clusters far apart and a thin strip (cells far from uniform).
  Eigen::MatrixXd clusters(2, 1000);
  for (int i = 0; i < 1000; ++i) {
    const double c = i < 900 ? 0 : 1000;
    clusters.col(i) << c + 1e-3 * rng.Uniform(), c + 1e-3 * rng.Uniform();
  }
  Eigen::MatrixXd strip(2, 1000);
  for (int i = 0; i < 1000; ++i) strip.col(i) << 100 * rng.Uniform(), 1e-4 * rng.Uniform();
  Eigen::MatrixXd space(3, 1000);
  for (int i = 0; i < space.cols(); ++i) space.col(i) << rng.Uniform(), rng.Uniform(), rng.Uniform();
  Eigen::MatrixXd cube(3, 6 * 6 * 6);
  for (int i = 0; i < 216; ++i) cube.col(i) << i % 6, (i / 6) % 6, i / 36;
  ExpectKnnIsBruteForce(uniform, "uniform");
  ExpectKnnIsBruteForce(lattice, "lattice");
  ExpectKnnIsBruteForce(coincident, "coincident");
  ExpectKnnIsBruteForce(collinear, "collinear");
  ExpectKnnIsBruteForce(clusters, "clusters");
  ExpectKnnIsBruteForce(strip, "strip");
  ExpectKnnIsBruteForce(space, "3-D uniform");
  ExpectKnnIsBruteForce(cube, "3-D lattice");
}

TEST(SpatialWeightsTest, KnnAndBandWeightsAreTheSameForOneAndTwoThreads) {
  Rng rng(5);
  Eigen::MatrixXd p(2, 20000);
  for (int i = 0; i < p.cols(); ++i) p.col(i) << rng.Uniform(), rng.Uniform();
  SetThreadCount(1);
  const auto knn1 = KnnWeights(p, 8, WeightStyle::kRowStandardised);
  const auto band1 = DistanceBandWeights(p, 0.01, WeightStyle::kBinary);
  SetThreadCount(2);
  const auto knn2 = KnnWeights(p, 8, WeightStyle::kRowStandardised);
  const auto band2 = DistanceBandWeights(p, 0.01, WeightStyle::kBinary);
  SetThreadCount(0);
  ASSERT_TRUE(knn1.ok() && knn2.ok() && band1.ok() && band2.ok());
  for (const auto* pair : {&knn1, &band1}) {
    const auto& a = (*pair)->w;
    const auto& b = (pair == &knn1 ? knn2 : band2)->w;
    ASSERT_EQ(a.nonZeros(), b.nonZeros());
    EXPECT_TRUE(std::equal(a.outerIndexPtr(), a.outerIndexPtr() + a.rows() + 1, b.outerIndexPtr()));
    EXPECT_TRUE(std::equal(a.innerIndexPtr(), a.innerIndexPtr() + a.nonZeros(), b.innerIndexPtr()));
    EXPECT_TRUE(std::equal(a.valuePtr(), a.valuePtr() + a.nonZeros(), b.valuePtr()));
  }
}

TEST(SpatialWeightsTest, GalRoundTripKeepsAsymmetricNeighboursAndIslands) {
  Rng rng(9);
  const int n = 40;
  Eigen::MatrixXd p(2, n);
  for (int i = 0; i < n; ++i) p.col(i) << rng.Uniform(0, 10), rng.Uniform(0, 10);
  p.col(7) << 50, 50;  // far away: an island of the band weights
  std::vector<std::string> ids;
  for (int i = 0; i < n; ++i) ids.push_back("P" + std::to_string(1000 + 7 * i));
  const auto dir = std::filesystem::temp_directory_path() / ("formloop-gal-" + std::to_string(::getpid()));
  std::filesystem::create_directories(dir);
  const auto knn = KnnWeights(p, 4, WeightStyle::kBinary);
  const auto band = DistanceBandWeights(p, 2.0, WeightStyle::kRowStandardised);
  ASSERT_TRUE(knn.ok() && band.ok());
  ASSERT_NE(std::find(band->island_indices.begin(), band->island_indices.end(), 7), band->island_indices.end());
  for (const SpatialWeights* w : {&knn.value(), &band.value()}) {
    const auto path = dir / "w.gal";
    ASSERT_TRUE(WriteGal(path, *w, ids).ok());
    const auto back = ReadGal(path, ids, w->style);
    ASSERT_TRUE(back.ok()) << back.status().message();
    EXPECT_EQ(Eigen::MatrixXd(back->w), Eigen::MatrixXd(w->w));
    EXPECT_EQ(back->island_indices, w->island_indices);
    // Rows in another order: the ids carry the pairing.
    std::vector<std::string> reversed(ids.rbegin(), ids.rend());
    const auto permuted = ReadGal(path, reversed, w->style);
    ASSERT_TRUE(permuted.ok());
    EXPECT_EQ(permuted->w.coeff(n - 1 - 0, n - 1 - w->Neighbours()[0][0]), w->w.coeff(0, w->Neighbours()[0][0]));
  }
  EXPECT_FALSE(WriteGal(dir / "bad.gal", knn.value(), std::vector<std::string>(n, "a b")).ok());
  // Duplicated data ids cannot be paired with GAL ids.
  std::vector<std::string> twice = ids;
  twice[5] = twice[2];
  const auto duplicate = ReadGal(dir / "w.gal", twice, WeightStyle::kBinary);
  ASSERT_FALSE(duplicate.ok());
  EXPECT_NE(duplicate.status().message().find("rows 3 and 6"), std::string::npos) << duplicate.status().message();
  std::filesystem::remove_all(dir);
}

TEST(SpatialWeightsTest, IslandPoliciesRefuseDropCascadeOrKeepZeroRows) {
  // 1 has no neighbours; dropping it empties 0's row, so 0 goes too.
  const std::vector<std::vector<int>> nb = {{1}, {}, {0, 3}, {2}, {2, 3}};
  const auto w = WeightsFromNeighbours(nb, WeightStyle::kRowStandardised);
  ASSERT_TRUE(w.ok());
  EXPECT_EQ(w->island_indices, std::vector<int>{1});
  const auto refused = ResolveIslands(w.value(), IslandPolicy::kRefuse);
  ASSERT_FALSE(refused.ok());
  EXPECT_NE(refused.status().message().find("rows 1"), std::string::npos) << refused.status().message();
  EXPECT_NE(refused.status().message().find("Fix:"), std::string::npos);
  const auto dropped = ResolveIslands(w.value(), IslandPolicy::kDrop);
  ASSERT_TRUE(dropped.ok());
  EXPECT_EQ(dropped->dropped, (std::vector<int>{0, 1}));
  EXPECT_EQ(dropped->kept, (std::vector<int>{2, 3, 4}));
  EXPECT_EQ(dropped->weights.islands, 0);
  Eigen::MatrixXd expected(3, 3);
  expected << 0, 1, 0,  //
      1, 0, 0,          //
      0.5, 0.5, 0;
  EXPECT_EQ(Eigen::MatrixXd(dropped->weights.w), expected);
  const auto zero = ResolveIslands(w.value(), IslandPolicy::kZero);
  ASSERT_TRUE(zero.ok());
  EXPECT_EQ(zero->kept.size(), 5u);
  EXPECT_EQ(zero->islands, 1);
  EXPECT_EQ(zero->weights.w.row(1).sum(), 0.0);
}

TEST(SpatialWeightsTest, ParsesStylesAndPolicies) {
  EXPECT_EQ(*ParseWeightStyle("W"), WeightStyle::kRowStandardised);
  EXPECT_EQ(*ParseWeightStyle("b"), WeightStyle::kBinary);
  EXPECT_EQ(ParseWeightStyle("X").status().code(), StatusCode::kBadInput);
  EXPECT_EQ(*ParseIslandPolicy("drop"), IslandPolicy::kDrop);
  EXPECT_EQ(*ParseIslandPolicy("ZERO"), IslandPolicy::kZero);
  EXPECT_NE(ParseIslandPolicy("keep").status().message().find("refuse, drop or zero"), std::string::npos);
}

}  // namespace
}  // namespace formloop::metrology
