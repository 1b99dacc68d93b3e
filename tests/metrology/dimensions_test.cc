// Dimensions from probe points (metrology/dimensions.h, metrology/feature_fit.h): every type against hand
// computations, the spec's acceptance checks §9.1, §9.3, §9.4 (spec/tuning-and-link.md), the Gander–Golub–
// Strebel geometric circle (data/reference/circle-fit-gander) and the GUM uncertainty against Monte Carlo.

#include <cmath>
#include <fstream>
#include <numbers>
#include <sstream>
#include <string>
#include <vector>

#include <gtest/gtest.h>
#include <Eigen/Core>
#include <Eigen/Geometry>

#include "core/random.h"
#include "metrology/dimensions.h"
#include "metrology/feature_fit.h"

namespace formloop::metrology {
namespace {

constexpr double kPi = std::numbers::pi;

ProbedPoint P(double x, double y, double z, double u = 0) {
  ProbedPoint p;
  p.position = {x, y, z};
  p.u_mm = u;
  return p;
}

RolePoints Role(const std::string& role, std::vector<ProbedPoint> points) { return {role, std::move(points)}; }

// n points on a circle of radius r about (cx, cy) at height z (plane normal Z), radial error err(k).
std::vector<ProbedPoint> Ring(double cx, double cy, double r, double z, int n, double phase = 0,
                              double (*err)(int) = nullptr) {
  std::vector<ProbedPoint> out;
  for (int k = 0; k < n; ++k) {
    const double a = phase + 2 * kPi * k / n;
    const double rr = r + (err ? err(k) : 0.0);
    out.push_back(P(cx + rr * std::cos(a), cy + rr * std::sin(a), z));
  }
  return out;
}

DimensionDefinition Def(DimensionType type, int axis, DimensionMethod method = DimensionMethod::kDefault) {
  DimensionDefinition d;
  d.id = "D";
  d.type = type;
  d.axis = axis;
  d.method = method;
  return d;
}

double Value(const DimensionDefinition& d, const std::vector<RolePoints>& roles) {
  auto v = EvaluateDimensionValue(d, roles);
  EXPECT_TRUE(v.ok()) << v.status().ToString();
  return v.ok() ? *v : std::nan("");
}

TEST(FeatureFit, GanderGolubStrebelGeometricCircle) {
  std::ifstream in(std::string(FORMLOOP_REFERENCE_DIR) + "/circle-fit-gander/gander_golub_strebel_6pts.csv");
  ASSERT_TRUE(in.good());
  std::string line;
  std::getline(in, line);  // header x,y
  std::vector<Eigen::Vector2d> pts;
  while (std::getline(in, line)) {
    double x = 0, y = 0;
    char comma = 0;
    std::istringstream s(line);
    s >> x >> comma >> y;
    pts.emplace_back(x, y);
  }
  ASSERT_EQ(pts.size(), 6u);
  auto fit = FitCircle(pts);
  ASSERT_TRUE(fit.ok());
  EXPECT_NEAR(fit->centre.x(), 4.7397824, 1e-6);
  EXPECT_NEAR(fit->centre.y(), 2.9835327, 1e-6);
  EXPECT_NEAR(fit->radius, 4.7142260, 1e-6);
  double ss = 0;
  for (double r : fit->residuals) ss += r * r;
  EXPECT_NEAR(ss, 1.2275991, 1e-6);
  // The algebraic (Kåsa) start alone is far off: the geometric refinement matters.
  auto algebraic_only = FitCircle(pts, 1e-9, 0);
  ASSERT_TRUE(algebraic_only.ok());
  EXPECT_GT(std::abs(algebraic_only->centre.y() - 2.9835327), 0.5);
}

TEST(FeatureFit, DegenerateInputsAreRefused) {
  EXPECT_FALSE(FitCircle({{0, 0}, {1, 0}}).ok());
  auto line = FitCircle({{0, 0}, {1, 1}, {2, 2}, {3, 3}});
  ASSERT_FALSE(line.ok());
  EXPECT_NE(line.status().message().find("one line"), std::string::npos);
  EXPECT_FALSE(FitPlane({{0, 0, 0}, {1, 1, 1}, {2, 2, 2}}).ok());
  EXPECT_FALSE(FitCylinder({{5, 0, 0}, {0, 5, 0}, {-5, 0, 0}, {0, -5, 0}, {3, 4, 0}}, {0, 0, 1}).ok());  // one height
}

// §9.1: band 8.3 mm +0.9/−0.5.
TEST(Dimensions, JudgementOfTheSpecBand) {
  const Tolerance t{.nominal = 8.3, .upper = 0.9, .lower = -0.5};
  EXPECT_TRUE(Judge(t, 7.8).ok);
  EXPECT_TRUE(Judge(t, 9.2).ok);
  const Judgement ng = Judge(t, 9.25);
  EXPECT_FALSE(ng.ok);
  EXPECT_NEAR(ng.deviation, 0.95, 1e-12);
  EXPECT_NEAR(ng.excess, 0.05, 1e-12);
  EXPECT_FALSE(Judge(t, 8.3 - 0.5 - 2e-9).ok);
  // Ambiguous: within U of a limit (ISO 14253-1), the call itself unchanged.
  const Judgement near = Judge(t, 9.199, 0.002);
  EXPECT_TRUE(near.ok);
  EXPECT_TRUE(near.ambiguous);
  // A zone's lower limit (0) is not a specification limit.
  EXPECT_FALSE(Judge(Tolerance{.nominal = 0, .upper = 0.01, .lower = 0, .zone = true}, 0.0005, 0.002).ambiguous);
}

double Alternating(int k) { return k % 2 == 0 ? 0.002 : -0.002; }

// §9.3: the LS circle and plane acceptance checks.
TEST(Dimensions, SpecFitChecks) {
  const auto ring = Ring(0, 0, 12, 0, 8, 0, Alternating);
  EXPECT_NEAR(Value(Def(DimensionType::kDiameter, 2), {Role("FEATURE", ring)}), 24.000, 1e-9);
  EXPECT_NEAR(Value(Def(DimensionType::kRadius, 2), {Role("FEATURE", ring)}), 12.000, 1e-9);
  EXPECT_NEAR(Value(Def(DimensionType::kRoundness, 2), {Role("FEATURE", ring)}), 0.004, 1e-9);
  const std::vector<ProbedPoint> square = {P(-10, -10, 0), P(10, -10, 0), P(10, 10, 0), P(-10, 10, 0), P(0, 0, 0.005)};
  EXPECT_NEAR(Value(Def(DimensionType::kFlatness, 2), {Role("FEATURE", square)}), 0.005, 1e-12);
  std::vector<ProbedPoint> tilted;
  for (double x : {-20.0, 0.0, 15.0, 30.0}) {
    for (double y : {-10.0, 5.0, 12.0}) tilted.push_back(P(x, y, 0.01 * x + 0.02 * y));
  }
  EXPECT_LT(Value(Def(DimensionType::kFlatness, 2), {Role("FEATURE", tilted)}), 1e-9);
}

// §9.4: coaxiality, symmetry and true position.
TEST(Dimensions, SpecLocationChecks) {
  const auto co = Value(Def(DimensionType::kCoaxiality, 2),
                        {Role("DATUM_1", Ring(0, 0, 10, -5, 6)), Role("DATUM_2", Ring(0, 0, 10, -25, 6)),
                         Role("FEATURE_1", Ring(0.003, 0.004, 6, -15, 6, 0.3))});
  EXPECT_NEAR(co, 0.010, 1e-9);
  const auto sym =
      Value(Def(DimensionType::kSymmetry, 1), {Role("WALL_A", {P(0, 4.002, 0)}), Role("WALL_B", {P(0, -3.996, 0)}),
                                               Role("DATUM_A", {P(0, 20, 0)}), Role("DATUM_B", {P(0, -20, 0)})});
  EXPECT_NEAR(sym, 0.006, 1e-12);
  DimensionDefinition tp = Def(DimensionType::kTruePosition, 2);
  tp.nominal_position = {10, 20};
  EXPECT_NEAR(Value(tp, {Role("FEATURE", Ring(10.003, 19.996, 4, -3, 5))}), 0.010, 1e-9);
}

// The remaining types against hand computations.
TEST(Dimensions, EveryTypeAgainstHandComputations) {
  // Two-point length along X (seed 000's diameter): |−142.011 − (−118.009)|.
  EXPECT_NEAR(Value(Def(DimensionType::kLength, 0),
                    {Role("WALL_A", {P(-118.009, 0, -5)}), Role("WALL_B", {P(-142.011, 0, -5)})}),
              24.002, 1e-12);
  // A slot from several points per wall: mean of each wall along Y.
  EXPECT_NEAR(Value(Def(DimensionType::kLength, 1), {Role("WALL_A", {P(0, 6.001, 0), P(10, 5.999, 0)}),
                                                     Role("WALL_B", {P(0, -5.998, 0), P(10, -6.0, 0)})}),
              11.999, 1e-12);
  // Face to face: top face z = 0 (three points), floor at z = −8.012 and −8.010 → 8.011.
  EXPECT_NEAR(Value(Def(DimensionType::kLength, 2, DimensionMethod::kFaceToFace),
                    {Role("FACE_A", {P(0, 0, 0), P(10, 0, 0), P(0, 10, 0)}),
                     Role("FACE_B", {P(3, 3, -8.012), P(5, 5, -8.010)})}),
              8.011, 1e-12);
  // Position of a hole centre from a datum edge along X: −49.994 − (−160.0).
  DimensionDefinition pos = Def(DimensionType::kPosition, 0, DimensionMethod::kCircle);
  pos.feature_axis = 2;
  EXPECT_NEAR(Value(pos, {Role("FEATURE", Ring(-49.994, 30, 5, -3, 4)), Role("DATUM", {P(-160.0, 0, -10)})}), 110.006,
              1e-9);
  // Position of a face (plane height) from the WCS origin: mean z.
  EXPECT_NEAR(Value(Def(DimensionType::kPosition, 2), {Role("FEATURE", {P(0, 0, 5.002), P(10, 0, 5.004)})}), 5.003,
              1e-12);
  // Parallelism: datum z = 0 plane, feature points at 10, 10.003, 9.999 → 0.004.
  EXPECT_NEAR(
      Value(Def(DimensionType::kParallelism, 2), {Role("DATUM", {P(0, 0, 0), P(50, 0, 0), P(0, 50, 0)}),
                                                  Role("FEATURE", {P(0, 0, 10), P(20, 0, 10.003), P(0, 20, 9.999)})}),
      0.004, 1e-12);
  // Perpendicularity of a wall x ≈ 0 leaning 0.001 per mm of height over 20 mm (z 0..20): w is +X, the
  // zone is the spread of x, 0.020.
  EXPECT_NEAR(Value(Def(DimensionType::kPerpendicularity, 2),
                    {Role("DATUM", {P(0, 0, 0), P(50, 0, 0), P(0, 50, 0)}),
                     Role("FEATURE", {P(0, 0, 0), P(0, 30, 0), P(0.020, 0, 20), P(0.020, 30, 20)})}),
              0.020, 1e-12);
  // Perpendicularity of an axis: centres (0,0) at z = 0 and (0.003, 0.004) at z = 20 → 0.005.
  EXPECT_NEAR(Value(Def(DimensionType::kPerpendicularity, 2, DimensionMethod::kAxis),
                    {Role("DATUM", {P(-30, -30, -1), P(30, -30, -1), P(0, 30, -1)}),
                     Role("LEVEL_1", Ring(0, 0, 8, 0, 5)), Role("LEVEL_2", Ring(0.003, 0.004, 8, 20, 5))}),
              0.005, 1e-9);
  // Angle between outward normals: top face (approach −Z) and a wall at x = 0 probed from −X (approach +X,
  // outward normal −X) → 90°; a chamfer at 45° → 45° from the top face.
  auto with_approach = [](std::vector<ProbedPoint> pts, Eigen::Vector3d a) {
    for (auto& p : pts) p.approach = a;
    return pts;
  };
  const auto top = with_approach({P(0, 0, 0), P(10, 0, 0), P(0, 10, 0)}, {0, 0, -1});
  const auto wall = with_approach({P(0, 0, -1), P(0, 10, -1), P(0, 0, -5)}, {1, 0, 0});
  EXPECT_NEAR(Value(Def(DimensionType::kAngle, 2), {Role("FACE_A", top), Role("FACE_B", wall)}), 90.0, 1e-9);
  const double s = std::sqrt(0.5);
  // The chamfer −x + z = 0 on the edge between the top and a wall at x = 0 (material at x > 0, z < 0):
  // outward normal (−1, 0, 1)/√2, probed along (1, 0, −1)/√2.
  const auto chamfer = with_approach({P(0, 0, 0), P(0, 10, 0), P(-1, 0, -1)}, {s, 0, -s});
  EXPECT_NEAR(Value(Def(DimensionType::kAngle, 2), {Role("FACE_A", top), Role("FACE_B", chamfer)}), 45.0, 1e-9);
  // Lines in the XY plane: along +X and at 120° → 120°.
  const double c120 = std::cos(2 * kPi / 3), s120 = std::sin(2 * kPi / 3);
  EXPECT_NEAR(Value(Def(DimensionType::kAngle, 2, DimensionMethod::kLine),
                    {Role("LINE_A", {P(0, 0, 0), P(5, 0, 0), P(10, 0, 0)}),
                     Role("LINE_B", {P(0, 0, 0), P(5 * c120, 5 * s120, 0), P(10 * c120, 10 * s120, 0)})}),
              120.0, 1e-9);
  // Cylinder: radius 5.002 along an axis tilted 0.5 mrad from Z, three rings → diameter 10.004.
  std::vector<ProbedPoint> cyl;
  const Eigen::Vector3d axis = Eigen::Vector3d(0.0005, 0, 1).normalized();
  const Eigen::Vector3d e1 = axis.cross(Eigen::Vector3d::UnitY()).normalized(), e2 = axis.cross(e1);
  for (double h : {0.0, 10.0, 20.0}) {
    for (int k = 0; k < 6; ++k) {
      const double a = 2 * kPi * k / 6 + 0.1 * h;
      const Eigen::Vector3d p = Eigen::Vector3d(1, 2, 0) + h * axis + 5.002 * (std::cos(a) * e1 + std::sin(a) * e2);
      cyl.push_back(P(p.x(), p.y(), p.z()));
    }
  }
  EXPECT_NEAR(Value(Def(DimensionType::kDiameter, 2, DimensionMethod::kCylinder), {Role("FEATURE", cyl)}), 10.004,
              1e-8);
  // The same points as a circle in the XY plane see an ellipse-ish section: not the cylinder's size.
  EXPECT_GT(std::abs(Value(Def(DimensionType::kDiameter, 2), {Role("FEATURE", cyl)}) - 10.004), 1e-6);
}

TEST(Dimensions, MissingOrDegeneratePointsNameTheDimensionAndRole) {
  DimensionDefinition d = Def(DimensionType::kDiameter, 2);
  d.id = "D7";
  auto v = EvaluateDimensionValue(d, {Role("FEATURE", {P(1, 0, 0), P(0, 1, 0)})});
  ASSERT_FALSE(v.ok());
  EXPECT_NE(v.status().message().find("dimension D7"), std::string::npos);
  EXPECT_NE(v.status().message().find("FEATURE"), std::string::npos);
  EXPECT_NE(v.status().message().find("DIM_INSUFFICIENT_POINTS"), std::string::npos);
  auto sym = EvaluateDimensionValue(Def(DimensionType::kSymmetry, 1),
                                    {Role("WALL_A", {P(0, 4, 0), P(1, 4, 0)}), Role("WALL_B", {P(0, -4, 0)}),
                                     Role("DATUM_A", {P(0, 20, 0)}), Role("DATUM_B", {P(0, -20, 0)})});
  ASSERT_FALSE(sym.ok());
  EXPECT_NE(sym.status().message().find("counts differ"), std::string::npos);
}

// GUM propagation: closed forms and a Monte Carlo check of the circle.
TEST(Dimensions, UncertaintyPropagation) {
  const double u = 0.001;
  // Two-point length along X, points measured on X only: u = √2·u_p.
  ProbedPoint a = P(0, 0, 0, u), b = P(24, 0, 0, u);
  a.measured = b.measured = {true, false, false};
  auto e = EvaluateDimension(Def(DimensionType::kLength, 0), {Role("WALL_A", {a}), Role("WALL_B", {b})});
  ASSERT_TRUE(e.ok());
  EXPECT_NEAR(e->u, std::sqrt(2.0) * u, 1e-9);
  EXPECT_NEAR(e->expanded_u, 2 * std::sqrt(2.0) * u, 1e-9);
  // LS circle, n evenly spaced points with isotropic u in the plane: u(D) = 2u/√n (the radial part).
  auto ring = Ring(5, -3, 12, 0, 8);
  for (auto& p : ring) {
    p.u_mm = u;
    p.measured = {true, true, false};
  }
  e = EvaluateDimension(Def(DimensionType::kDiameter, 2), {Role("FEATURE", ring)});
  ASSERT_TRUE(e.ok());
  EXPECT_NEAR(e->u, 2 * u / std::sqrt(8.0), 1e-7);
  // Monte Carlo: the spread of the fitted diameter under that noise.
  Rng rng(3);
  double sum = 0, sum2 = 0;
  const int draws = 4000;
  for (int t = 0; t < draws; ++t) {
    auto noisy = ring;
    for (auto& p : noisy) {
      p.position.x() += rng.Normal(0, u);
      p.position.y() += rng.Normal(0, u);
    }
    const double v = Value(Def(DimensionType::kDiameter, 2), {Role("FEATURE", noisy)});
    sum += v;
    sum2 += v * v;
  }
  const double sd = std::sqrt(sum2 / draws - (sum / draws) * (sum / draws));
  EXPECT_NEAR(sd / e->u, 1.0, 0.06) << "Monte Carlo sd " << sd << " vs GUM " << e->u;
}

}  // namespace
}  // namespace formloop::metrology
