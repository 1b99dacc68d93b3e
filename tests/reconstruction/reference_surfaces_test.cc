// The analytic reference surfaces: exact derivatives against finite differences, orientation,
// principal curvatures against finite-difference fundamental forms and known values, and the
// machinability bound (no concave radius below 10 mm).

#include <cmath>
#include <numbers>
#include <string>
#include <vector>

#include <gtest/gtest.h>
#include <Eigen/Dense>

#include "reconstruction/analytic_surface.h"

namespace formloop::recon {
namespace {

using Eigen::Vector3d;

std::unique_ptr<AnalyticSurface> Make(const std::string& name) {
  auto made = MakeReferenceSurface(name);
  EXPECT_TRUE(made.ok()) << made.status().ToString();
  return std::move(made).value();
}

// (u, v) on an n × n grid slightly inside the domain (finite differences step outside by h).
std::vector<std::pair<double, double>> Grid(const ParamDomain& d, int n, double margin) {
  std::vector<std::pair<double, double>> out;
  for (int j = 0; j < n; ++j) {
    for (int i = 0; i < n; ++i) {
      out.emplace_back(d.u_min + margin + (d.u_span() - 2 * margin) * i / (n - 1),
                       d.v_min + margin + (d.v_span() - 2 * margin) * j / (n - 1));
    }
  }
  return out;
}

// Derivatives from central finite differences of Point alone.
SurfaceDerivatives FiniteDifferenceDerivatives(const AnalyticSurface& s, double u, double v, double h) {
  SurfaceDerivatives d;
  const Vector3d p = s.Point(u, v);
  const Vector3d pu_plus = s.Point(u + h, v), pu_minus = s.Point(u - h, v);
  const Vector3d pv_plus = s.Point(u, v + h), pv_minus = s.Point(u, v - h);
  d.p = p;
  d.su = (pu_plus - pu_minus) / (2 * h);
  d.sv = (pv_plus - pv_minus) / (2 * h);
  d.suu = (pu_plus - 2 * p + pu_minus) / (h * h);
  d.svv = (pv_plus - 2 * p + pv_minus) / (h * h);
  d.suv = (s.Point(u + h, v + h) - s.Point(u + h, v - h) - s.Point(u - h, v + h) + s.Point(u - h, v - h)) / (4 * h * h);
  return d;
}

class AnalyticSurfaceTest : public ::testing::TestWithParam<std::string> {};

TEST_P(AnalyticSurfaceTest, NameDomainAndSize) {
  const auto s = Make(GetParam());
  EXPECT_EQ(s->name(), GetParam());
  EXPECT_FALSE(s->description().empty());
  EXPECT_EQ(s->description().find('\n'), std::string::npos);
  const ParamDomain d = s->domain();
  EXPECT_GE(d.u_span(), 60);
  EXPECT_LE(d.u_span(), 120);
  EXPECT_GE(d.v_span(), 60);
  EXPECT_LE(d.v_span(), 120);
  for (const auto& [u, v] : Grid(d, 41, 0)) {
    const Vector3d p = s->Point(u, v);
    ASSERT_TRUE(p.allFinite()) << "at (" << u << ", " << v << ")";
    EXPECT_LE(std::abs(p.z()), 50) << "at (" << u << ", " << v << ")";
    if (s->is_graph()) {
      EXPECT_DOUBLE_EQ(p.x(), u);
      EXPECT_DOUBLE_EQ(p.y(), v);
    }
  }
}

TEST_P(AnalyticSurfaceTest, FirstAndSecondDerivativesMatchFiniteDifferences) {
  const auto s = Make(GetParam());
  const double h = 1e-3;  // mm
  for (const auto& uv : Grid(s->domain(), 21, 0)) {
    const double u = uv.first, v = uv.second;  // plain variables: the lambda below captures them (clang 14)
    const SurfaceDerivatives d = s->Derivatives(u, v);
    const SurfaceDerivatives du_plus = s->Derivatives(u + h, v), du_minus = s->Derivatives(u - h, v);
    const SurfaceDerivatives dv_plus = s->Derivatives(u, v + h), dv_minus = s->Derivatives(u, v - h);
    auto check = [&](const Vector3d& exact, const Vector3d& fd, const char* what) {
      EXPECT_LE((exact - fd).norm(), 1e-6 * std::max(1.0, exact.norm()))
          << what << " at (" << u << ", " << v << "): exact " << exact.transpose() << " fd " << fd.transpose();
    };
    check(d.su, (du_plus.p - du_minus.p) / (2 * h), "S_u");
    check(d.sv, (dv_plus.p - dv_minus.p) / (2 * h), "S_v");
    check(d.suu, (du_plus.su - du_minus.su) / (2 * h), "S_uu");
    check(d.suv, (dv_plus.su - dv_minus.su) / (2 * h), "S_uv (from S_u)");
    check(d.suv, (du_plus.sv - du_minus.sv) / (2 * h), "S_uv (from S_v)");
    check(d.svv, (dv_plus.sv - dv_minus.sv) / (2 * h), "S_vv");
  }
}

TEST_P(AnalyticSurfaceTest, NormalsAreUnitAndPointUp) {
  const auto s = Make(GetParam());
  for (const auto& [u, v] : Grid(s->domain(), 51, 0)) {
    const Vector3d n = s->Normal(u, v);
    EXPECT_NEAR(n.norm(), 1, 1e-14);
    EXPECT_GT(n.z(), 0.5) << "at (" << u << ", " << v << ")";
    const SurfaceDerivatives d = s->Derivatives(u, v);
    EXPECT_NEAR(n.dot(d.su), 0, 1e-12);
    EXPECT_NEAR(n.dot(d.sv), 0, 1e-12);
  }
}

TEST_P(AnalyticSurfaceTest, PrincipalCurvaturesMatchFiniteDifferenceFundamentalForms) {
  const auto s = Make(GetParam());
  const double h = 1e-2;  // mm; second differences: truncation ~h²·S''''/12, round-off ~1e-16·|S|/h²
  for (const auto& [u, v] : Grid(s->domain(), 21, h)) {
    const PrincipalCurvatures exact = s->Curvatures(u, v);
    const PrincipalCurvatures fd = CurvaturesFromDerivatives(FiniteDifferenceDerivatives(*s, u, v, h));
    EXPECT_NEAR(exact.k1, fd.k1, 1e-5) << "k1 at (" << u << ", " << v << ")";
    EXPECT_NEAR(exact.k2, fd.k2, 1e-5) << "k2 at (" << u << ", " << v << ")";
    EXPECT_GE(exact.k1, exact.k2);
  }
}

// Independent of the eigen-solver: mean and Gaussian curvature from the classical closed forms
// H = (E N - 2 F M + G L) / (2 (E G - F²)), K = (L N - M²) / (E G - F²), with formloop's sign
// (positive = bends away from n) flipping H but not K. Principal directions are unit, tangent,
// orthogonal and carry the normal curvatures k1, k2.
TEST_P(AnalyticSurfaceTest, CurvaturesAgreeWithClosedFormsAndDirections) {
  const auto s = Make(GetParam());
  for (const auto& [u, v] : Grid(s->domain(), 15, 0)) {
    const SurfaceDerivatives d = s->Derivatives(u, v);
    const Vector3d n = NormalFromDerivatives(d);
    const double e = d.su.dot(d.su), f = d.su.dot(d.sv), g = d.sv.dot(d.sv);
    const double l = d.suu.dot(n), m = d.suv.dot(n), nn = d.svv.dot(n);
    const double det = e * g - f * f;
    const double mean = -(e * nn - 2 * f * m + g * l) / (2 * det);
    const double gauss = (l * nn - m * m) / det;
    const PrincipalCurvatures k = CurvaturesFromDerivatives(d);
    EXPECT_NEAR(k.mean(), mean, 1e-12);
    EXPECT_NEAR(k.gaussian(), gauss, 1e-12);
    EXPECT_NEAR(k.dir1.norm(), 1, 1e-12);
    EXPECT_NEAR(k.dir2.norm(), 1, 1e-12);
    EXPECT_NEAR(k.dir1.dot(n), 0, 1e-12);
    EXPECT_NEAR(k.dir2.dot(n), 0, 1e-12);
    EXPECT_NEAR(k.dir1.dot(k.dir2), 0, 1e-12);
    // Normal curvature along a tangent t = a S_u + b S_v: -(II(a,b)) / I(a,b).
    auto normal_curvature = [&](const Vector3d& t) {
      Eigen::Matrix<double, 3, 2> jac;
      jac << d.su, d.sv;
      const Eigen::Vector2d ab = jac.colPivHouseholderQr().solve(t);
      const double first = e * ab(0) * ab(0) + 2 * f * ab(0) * ab(1) + g * ab(1) * ab(1);
      const double second = l * ab(0) * ab(0) + 2 * m * ab(0) * ab(1) + nn * ab(1) * ab(1);
      return -second / first;
    };
    EXPECT_NEAR(normal_curvature(k.dir1), k.k1, 1e-12);
    EXPECT_NEAR(normal_curvature(k.dir2), k.k2, 1e-12);
  }
}

TEST_P(AnalyticSurfaceTest, NoConcaveRadiusBelowTenMillimetres) {
  const auto s = Make(GetParam());
  double min_k2 = 0;
  for (const auto& [u, v] : Grid(s->domain(), 201, 0)) min_k2 = std::min(min_k2, s->Curvatures(u, v).k2);
  EXPECT_GE(min_k2, -1.0 / 10) << "smallest concave radius " << -1 / min_k2 << " mm";
}

INSTANTIATE_TEST_SUITE_P(ReferenceSurfaces, AnalyticSurfaceTest, ::testing::ValuesIn(ReferenceSurfaceNames()),
                         [](const auto& test_param) { return test_param.param; });

TEST(ReferenceSurfaces, RegistryOrderAndUnknownName) {
  const std::vector<std::string> expected = {"plane",   "sphere_cap", "cylinder", "ellipsoid_cap",    "saddle",
                                             "egg_box", "franke",     "blade",    "tilted_paraboloid"};
  EXPECT_EQ(ReferenceSurfaceNames(), expected);
  const auto missing = MakeReferenceSurface("torus");
  ASSERT_FALSE(missing.ok());
  EXPECT_EQ(missing.status().code(), StatusCode::kNotFound);
  EXPECT_NE(missing.status().message().find("torus"), std::string::npos);
  for (const auto& name : expected) EXPECT_NE(missing.status().message().find(name), std::string::npos) << name;
  EXPECT_FALSE(Make("blade")->is_graph());
  EXPECT_FALSE(Make("tilted_paraboloid")->is_graph());
}

TEST(ReferenceSurfaces, KnownCurvatures) {
  const auto plane = Make("plane");
  const auto sphere = Make("sphere_cap");
  const auto cylinder = Make("cylinder");
  const auto paraboloid = Make("tilted_paraboloid");
  for (const auto& [u, v] : Grid(plane->domain(), 7, 0)) {
    EXPECT_NEAR(plane->Curvatures(u, v).k1, 0, 1e-15);
    EXPECT_NEAR(plane->Curvatures(u, v).k2, 0, 1e-15);
  }
  for (const auto& [u, v] : Grid(sphere->domain(), 7, 0)) {
    EXPECT_NEAR(sphere->Curvatures(u, v).k1, 1.0 / 100, 1e-14);  // convex: bends away from the upward normal
    EXPECT_NEAR(sphere->Curvatures(u, v).k2, 1.0 / 100, 1e-14);
  }
  for (const auto& [u, v] : Grid(cylinder->domain(), 7, 0)) {
    const PrincipalCurvatures k = cylinder->Curvatures(u, v);
    EXPECT_NEAR(k.k1, 1.0 / 80, 1e-14);
    EXPECT_NEAR(k.k2, 0, 1e-14);
    EXPECT_NEAR(std::abs(k.dir2.y()), 1, 1e-12);  // straight along the axis
  }
  const PrincipalCurvatures saddle = Make("saddle")->Curvatures(0, 0);
  EXPECT_NEAR(saddle.k1, 1.0 / 150, 1e-15);  // along y: z = -y²/300 bends away from n
  EXPECT_NEAR(saddle.k2, -1.0 / 150, 1e-15);
  EXPECT_NEAR(std::abs(saddle.dir1.y()), 1, 1e-12);
  const PrincipalCurvatures bowl = paraboloid->Curvatures(0, 0);  // concave bowl, vertex
  EXPECT_NEAR(bowl.k1, -1.0 / 150, 1e-15);
  EXPECT_NEAR(bowl.k2, -1.0 / 150, 1e-15);
  const PrincipalCurvatures crest = Make("egg_box")->Curvatures(10, 10);  // sin·sin = 1: a convex crest
  const double w = 2 * std::numbers::pi / 40;
  EXPECT_NEAR(crest.k1, 2 * w * w, 1e-12);
  EXPECT_NEAR(crest.k2, 2 * w * w, 1e-12);
}

}  // namespace
}  // namespace formloop::recon
