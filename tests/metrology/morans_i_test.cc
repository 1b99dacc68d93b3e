// Moran's I against published PySAL values and residual Moran against a dense Cliff–Ord computation.

#include <cmath>
#include <fstream>
#include <sstream>

#include <Eigen/Dense>
#include <gtest/gtest.h>

#include "core/random.h"
#include "metrology/morans_i.h"
#include "metrology/spatial_weights.h"

namespace formloop::metrology {
namespace {

const std::string kData = std::string(FORMLOOP_SHARED_DIR) + "/data/moran-pysal/";

// Reads column `column` (0-based) of a comma-separated file after `skip` header lines; ids from column 0.
void ReadTable(const std::string& path, int skip, int column, std::vector<std::string>* ids, std::vector<double>* y) {
  std::ifstream in(path);
  ASSERT_TRUE(in) << path;
  std::string line;
  for (int i = 0; i < skip; ++i) std::getline(in, line);
  while (std::getline(in, line)) {
    if (line.empty()) continue;
    std::stringstream ss(line);
    std::string cell;
    std::vector<std::string> cells;
    while (std::getline(ss, cell, ',')) cells.push_back(cell);
    ids->push_back(cells[0]);
    y->push_back(std::stod(cells[static_cast<std::size_t>(column)]));
  }
}

TEST(MoranTest, StLouisHomicidesMatchPysal) {
  std::vector<std::string> fips;
  std::vector<double> y;
  ReadTable(kData + "stl_hom.txt", 2, 2, &fips, &y);  // HR8893
  ASSERT_EQ(y.size(), 78u);
  // stl.gal numbers the units 1..78 in file order.
  std::vector<std::string> ids;
  for (int i = 1; i <= 78; ++i) ids.push_back(std::to_string(i));
  const auto w = ReadGal(kData + "stl.gal", ids, WeightStyle::kRowStandardised);
  ASSERT_TRUE(w.ok()) << w.status().message();
  const auto r = MoranI(Eigen::Map<const Eigen::VectorXd>(y.data(), 78), w.value());
  ASSERT_TRUE(r.ok());
  EXPECT_NEAR(r->i, 0.24365582621771659, 1e-12 * 0.2437);
  EXPECT_NEAR(r->p_normality, 0.00013573931385468807, 1e-9 * 0.000136);
}

TEST(MoranTest, Sids2MatchesPysal) {
  std::vector<std::string> fips;
  std::vector<double> y;
  ReadTable(kData + "sids2_sidr74.csv", 1, 2, &fips, &y);  // SIDR74, ids FIPSNO
  ASSERT_EQ(y.size(), 100u);
  const auto w = ReadGal(kData + "sids2.gal", fips, WeightStyle::kRowStandardised);
  ASSERT_TRUE(w.ok()) << w.status().message();
  const auto r = MoranI(Eigen::Map<const Eigen::VectorXd>(y.data(), 100), w.value());
  ASSERT_TRUE(r.ok());
  EXPECT_NEAR(r->i, 0.24772519320480135, 1e-12 * 0.2477);
  EXPECT_NEAR(r->p_normality, 5.7916539074498452e-05, 1e-9 * 5.79e-5);
}

TEST(MoranTest, RookLatticeVariances) {
  // 3 × 3 rook lattice, y = 1..9 row-major, binary weights.
  std::vector<std::vector<int>> nb(9);
  for (int r = 0; r < 3; ++r) {
    for (int c = 0; c < 3; ++c) {
      const int i = 3 * r + c;
      if (r > 0) nb[i].push_back(i - 3);
      if (r < 2) nb[i].push_back(i + 3);
      if (c > 0) nb[i].push_back(i - 1);
      if (c < 2) nb[i].push_back(i + 1);
    }
  }
  const auto w = WeightsFromNeighbours(nb, WeightStyle::kBinary);
  ASSERT_TRUE(w.ok());
  Eigen::VectorXd y(9);
  for (int i = 0; i < 9; ++i) y[i] = i + 1;
  const auto r = MoranI(y, w.value());
  ASSERT_TRUE(r.ok());
  EXPECT_NEAR(r->i, 0.5, 1e-14);
  EXPECT_NEAR(r->expected, -0.125, 1e-15);
  EXPECT_NEAR(r->variance_randomisation, 0.059687500000000004, 1e-12 * 0.0597);
  EXPECT_NEAR(r->variance_normality, 0.053125000000000006, 1e-12 * 0.0531);
}

// Dense Cliff–Ord moments for residuals, straight from the formulas (small n only).
struct Dense {
  double i, expected, variance;
};
Dense DenseResidualMoran(const Eigen::VectorXd& y, const Eigen::MatrixXd& x, const Eigen::MatrixXd& w) {
  const long n = y.size();
  const Eigen::MatrixXd m =
      Eigen::MatrixXd::Identity(n, n) - x * (x.transpose() * x).inverse() * x.transpose();
  const Eigen::VectorXd e = m * y;
  const double s0 = w.sum(), p = static_cast<double>(x.cols());
  const Eigen::MatrixXd mw = m * w;
  const double tr_mw = mw.trace();
  const double scale = n / s0;
  Dense d;
  d.i = scale * e.dot(w * e) / e.dot(e);
  d.expected = scale * tr_mw / (n - p);
  d.variance = scale * scale * ((m * w * m * w.transpose()).trace() + (mw * mw).trace() + tr_mw * tr_mw) /
                   ((n - p) * (n - p + 2)) -
               d.expected * d.expected;
  return d;
}

TEST(MoranTest, ResidualMoranMatchesDenseFormulasWithAsymmetricKnn) {
  Rng rng(11);
  const int n = 60;
  Eigen::MatrixXd uv(2, n);
  Eigen::VectorXd y(n);
  Eigen::MatrixXd x(n, 4);
  for (int i = 0; i < n; ++i) {
    uv(0, i) = rng.Uniform(0, 100);
    uv(1, i) = rng.Uniform(0, 80);
    x.row(i) << 1.0, uv(0, i), uv(1, i), uv(0, i) * uv(1, i) / 100.0;
    y[i] = 0.01 * uv(0, i) + std::sin(uv(1, i) / 10.0) + rng.Normal(0, 0.3);
  }
  for (WeightStyle style : {WeightStyle::kRowStandardised, WeightStyle::kBinary}) {
    const auto w = KnnWeights(uv, 5, style);
    ASSERT_TRUE(w.ok());
    const Eigen::MatrixXd dense_w = Eigen::MatrixXd(w->w);
    ASSERT_GT((dense_w - dense_w.transpose()).cwiseAbs().maxCoeff(), 0.0) << "k-NN weights should be asymmetric";
    const auto r = ResidualMoranI(y, x, w.value());
    ASSERT_TRUE(r.ok());
    const Dense d = DenseResidualMoran(y, x, dense_w);
    EXPECT_NEAR(r->i, d.i, 1e-12 * std::abs(d.i));
    EXPECT_NEAR(r->expected, d.expected, 1e-12 * std::abs(d.expected));
    EXPECT_NEAR(r->variance, d.variance, 1e-12 * std::abs(d.variance));
  }
}

TEST(MoranTest, ConstantDesignReducesToRawMoranUnderNormality) {
  Rng rng(5);
  const int n = 80;
  Eigen::MatrixXd uv(2, n);
  Eigen::VectorXd y(n);
  for (int i = 0; i < n; ++i) {
    uv(0, i) = rng.Uniform(0, 50);
    uv(1, i) = rng.Uniform(0, 50);
    y[i] = rng.Normal();
  }
  const auto w = KnnWeights(uv, 6, WeightStyle::kRowStandardised);
  ASSERT_TRUE(w.ok());
  const auto raw = MoranI(y, w.value());
  const auto res = ResidualMoranI(y, Eigen::MatrixXd::Ones(n, 1), w.value());
  ASSERT_TRUE(raw.ok() && res.ok());
  EXPECT_NEAR(res->i, raw->i, 1e-13);
  EXPECT_NEAR(res->expected, raw->expected, 1e-13);
  EXPECT_NEAR(res->variance, raw->variance_normality, 1e-12 * raw->variance_normality);
}

TEST(MoranTest, DetectsASmoothFieldAndNotNoise) {
  Rng rng(8);
  const int n = 400;
  Eigen::MatrixXd uv(2, n);
  Eigen::VectorXd smooth(n), noise(n);
  for (int i = 0; i < n; ++i) {
    uv(0, i) = rng.Uniform(0, 100);
    uv(1, i) = rng.Uniform(0, 100);
    noise[i] = rng.Normal();
    smooth[i] = std::sin(uv(0, i) / 15.0) + 0.3 * noise[i];
  }
  const auto w = KnnWeights(uv, 8, WeightStyle::kRowStandardised);
  ASSERT_TRUE(w.ok());
  EXPECT_GT(MoranI(smooth, w.value())->z_normality, kMoranZCritical);
  EXPECT_LT(MoranI(noise, w.value())->z_normality, kMoranZCritical);
}

TEST(MoranTest, IslandsAndTooFewValuesAreRefused) {
  std::vector<std::vector<int>> nb = {{1}, {0}, {}, {0}, {1}};
  const auto w = WeightsFromNeighbours(nb, WeightStyle::kBinary);
  ASSERT_TRUE(w.ok());
  EXPECT_EQ(w->islands, 1);
  Eigen::VectorXd y(5);
  y << 1, 2, 3, 4, 5;
  const auto r = MoranI(y, w.value());
  EXPECT_EQ(r.status().code(), StatusCode::kBadInput);
  EXPECT_NE(r.status().message().find("islands"), std::string::npos);
}

}  // namespace
}  // namespace formloop::metrology
