// Moran eigenvector spatial filter (metrology/spatial_filter.h): what it adds is orthogonal to the
// field, its test is the exact residual Moran of the augmented design, and it removes correlated
// structure planted in an otherwise independent residual.
#include "metrology/spatial_filter.h"

#include <gtest/gtest.h>

#include <Eigen/Dense>
#include <algorithm>
#include <cmath>

#include "core/random.h"
#include "metrology/morans_i.h"
#include "metrology/spatial_weights.h"

namespace formloop::metrology {
namespace {

struct Scene {
  Eigen::MatrixXd uv;      // 2 × n
  Eigen::MatrixXd design;  // n × 3: 1, u, v
  SpatialWeights weights;
};

Scene MakeScene(int n, std::uint64_t seed) {
  Rng rng(seed);
  Scene s;
  s.uv.resize(2, n);
  s.design.resize(n, 3);
  for (int i = 0; i < n; ++i) {
    s.uv(0, i) = rng.Uniform(0, 1);
    s.uv(1, i) = rng.Uniform(0, 1);
    s.design.row(i) << 1.0, s.uv(0, i), s.uv(1, i);
  }
  auto w = KnnWeights(s.uv, 8, WeightStyle::kRowStandardised);
  EXPECT_TRUE(w.ok());
  s.weights = *w;
  return s;
}

// Noise plus a plane plus short-range correlated structure: a smoothed noise field (each value the
// mean over its 8 neighbours of a second noise), scaled to `structure` of the noise σ = 1.
Eigen::VectorXd Values(const Scene& s, double structure, std::uint64_t seed) {
  Rng rng(seed);
  const Eigen::Index n = s.uv.cols();
  Eigen::VectorXd noise(n), hidden(n);
  for (Eigen::Index i = 0; i < n; ++i) noise[i] = rng.Normal();
  for (Eigen::Index i = 0; i < n; ++i) hidden[i] = rng.Normal();
  Eigen::VectorXd smooth = s.weights.w * hidden;
  smooth = s.weights.w * smooth;
  smooth -= Eigen::VectorXd::Constant(n, smooth.mean());
  smooth *= structure / std::sqrt(smooth.squaredNorm() / static_cast<double>(n));
  const Eigen::VectorXd plane =
      Eigen::VectorXd::Constant(n, 3.0) + 2.0 * s.uv.row(0).transpose() - s.uv.row(1).transpose();
  return plane + noise + smooth;
}

TEST(SpatialFilterTest, RemovesPlantedStructureWithVectorsOrthogonalToTheField) {
  const Scene s = MakeScene(800, 11);
  const Eigen::VectorXd y = Values(s, 0.5, 12);
  auto before = ResidualMoranI(y, s.design, s.weights);
  ASSERT_TRUE(before.ok());
  ASSERT_GT(before->z, 2.326) << "the planted structure must be detectable for this test to mean anything";

  auto f = FilterResidual(y, s.design, s.weights);
  ASSERT_TRUE(f.ok()) << f.status().message();
  EXPECT_TRUE(f->independent) << f->stop_reason;
  EXPECT_LE(f->final.z, 2.326);
  EXPECT_GT(f->vectors, 0);
  EXPECT_EQ(static_cast<int>(f->z_after.size()), f->vectors);
  EXPECT_EQ(f->z_after.back(), f->final.z);
  EXPECT_DOUBLE_EQ(f->z_before, before->z);
  EXPECT_EQ(f->final.p, 3 + f->vectors);
  // Every vector added has substantial positive autocorrelation.
  for (double mc : f->moran_coefficients) EXPECT_GT(mc, 0.2);

  // d_f is orthogonal to the field's design: the field's coefficients do not move, and the field's
  // residual is d_f + d_u exactly.
  EXPECT_LE((s.design.transpose() * f->fitted).cwiseAbs().maxCoeff(), 1e-9 * f->fitted.norm() * std::sqrt(800.0));
  EXPECT_LE((before->residuals - (f->fitted + f->final.residuals)).cwiseAbs().maxCoeff(), 1e-12);
  EXPECT_LE((f->final.coefficients.head(3) - before->coefficients).cwiseAbs().maxCoeff(), 1e-9);

  // The vectors are orthonormal and orthogonal to the design, and the filter's test is the exact
  // residual Moran of the augmented design [X, V], recomputed here from scratch.
  ASSERT_EQ(f->basis.cols(), f->vectors);
  EXPECT_LE((f->basis.transpose() * f->basis - Eigen::MatrixXd::Identity(f->vectors, f->vectors)).cwiseAbs().maxCoeff(),
            1e-10);
  EXPECT_LE((s.design.transpose() * f->basis).cwiseAbs().maxCoeff(), 1e-9);
  Eigen::MatrixXd augmented(800, 3 + f->vectors);
  augmented << s.design, f->basis;
  auto exact = ResidualMoranI(y, augmented, s.weights);
  ASSERT_TRUE(exact.ok());
  EXPECT_NEAR(exact->z, f->final.z, 1e-10);
  EXPECT_NEAR(exact->i, f->final.i, 1e-12);

  // The planted structure is what came out: d_f correlates with it.
  const Eigen::VectorXd planted = Values(s, 0.5, 12) - Values(s, 0.0, 12);
  const double corr = f->fitted.dot(planted) / (f->fitted.norm() * planted.norm());
  std::printf(
      "planted structure RMS 0.5 sigma: z %.2f -> %.2f with %d vectors; d_f RMS %.3f; corr(d_f, planted) %.2f\n",
      f->z_before, f->final.z, f->vectors, std::sqrt(f->fitted.squaredNorm() / 800.0), corr);
  EXPECT_GT(corr, 0.5);

  // Same input, same output.
  auto again = FilterResidual(y, s.design, s.weights);
  ASSERT_TRUE(again.ok());
  EXPECT_EQ(again->fitted, f->fitted);
}

TEST(SpatialFilterTest, AnIndependentResidualIsLeftAlone) {
  const Scene s = MakeScene(500, 21);
  Eigen::VectorXd y = Values(s, 0.0, 22);
  auto before = ResidualMoranI(y, s.design, s.weights);
  ASSERT_TRUE(before.ok());
  ASSERT_LE(before->z, 2.326);
  auto f = FilterResidual(y, s.design, s.weights);
  ASSERT_TRUE(f.ok());
  EXPECT_TRUE(f->independent);
  EXPECT_EQ(f->vectors, 0);
  EXPECT_EQ(f->fitted, Eigen::VectorXd::Zero(500));
  EXPECT_EQ(f->stop_reason, "the residual is already independent");
}

TEST(SpatialFilterTest, ABudgetTooSmallSaysSo) {
  const Scene s = MakeScene(800, 31);
  const Eigen::VectorXd y = Values(s, 1.5, 32);
  SpatialFilterOptions o;
  o.max_vectors = 1;
  auto f = FilterResidual(y, s.design, s.weights, o);
  ASSERT_TRUE(f.ok());
  EXPECT_FALSE(f->independent);
  EXPECT_EQ(f->vectors, 1);
  EXPECT_NE(f->stop_reason.find("budget of 1 filter vectors is spent"), std::string::npos) << f->stop_reason;
  EXPECT_GT(f->final.z, 2.326);

  // A budget of none leaves the residual as it was and says so.
  o.max_vectors = 0;
  auto none = FilterResidual(y, s.design, s.weights, o);
  ASSERT_TRUE(none.ok());
  EXPECT_EQ(none->vectors, 0);
  EXPECT_FALSE(none->independent);
  EXPECT_EQ(none->fitted, Eigen::VectorXd::Zero(800));
  EXPECT_EQ(none->final.z, none->z_before);
  EXPECT_NE(none->stop_reason.find("budget of 0 filter vectors is spent"), std::string::npos) << none->stop_reason;

  o.max_vectors = -1;
  auto bad = FilterResidual(y, s.design, s.weights, o);
  ASSERT_FALSE(bad.ok());
  EXPECT_NE(bad.status().message().find("max_vectors"), std::string::npos);
}

}  // namespace
}  // namespace formloop::metrology
