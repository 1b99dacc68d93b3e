// Scattered-point surface fitting (reconstruction/scattered_fit.h): the building blocks, the nine
// reference surfaces without noise, noisy fits (RMS and boundary behaviour, against OpenCASCADE's grid
// approximator), GCV and tolerance smoothing, and input errors. Every fixture is seeded.
//
// Figures measured in Release (GCC 12) are printed as "[ measured ]" lines; the assertions below
// say what they must stay within.

#include "reconstruction/scattered_fit.h"

#include <gtest/gtest.h>

#include <Eigen/Dense>
#include <Geom_BSplineSurface.hxx>
#include <TColStd_Array1OfInteger.hxx>
#include <TColStd_Array1OfReal.hxx>
#include <TColgp_Array2OfPnt.hxx>
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <limits>
#include <string>
#include <vector>

#include "core/random.h"

namespace formloop::recon {
namespace {

using Eigen::Vector2d;
using Eigen::Vector3d;

std::unique_ptr<AnalyticSurface> Make(const std::string& name) {
  auto made = MakeReferenceSurface(name);
  EXPECT_TRUE(made.ok()) << made.status().ToString();
  return std::move(made).value();
}

// Points at seeded uniform (u, v) in the surface's domain, optionally moved along the unit normal by
// Gaussian noise; the (u, v) are kept to know where the samples are.
struct Samples {
  std::vector<Vector3d> points;
  std::vector<Vector2d> uv;
};

Samples Scatter(const AnalyticSurface& s, int n, std::uint64_t seed, double noise_sigma_mm = 0) {
  const ParamDomain dom = s.domain();
  Rng rng(seed);
  Samples out;
  for (int i = 0; i < n; ++i) {
    const double u = rng.Uniform(dom.u_min, dom.u_max), v = rng.Uniform(dom.v_min, dom.v_max);
    Vector3d p = s.Point(u, v);
    if (noise_sigma_mm > 0) p += rng.Normal(0, noise_sigma_mm) * s.Normal(u, v);
    out.points.push_back(p);
    out.uv.emplace_back(u, v);
  }
  return out;
}

// Start of the foot-point search on a fitted Q for a point p: its coordinates in the parameter
// frame the fit reports (PCA case); Q's parameters follow that frame up to the parameter correction.
Vector2d FrameStart(const FitReport& report, const Vector3d& p) {
  const nlohmann::json& frame = report.details.at("frame");
  auto vec = [&](const char* key) {
    const nlohmann::json& a = frame.at(key);
    return Vector3d(a[0].get<double>(), a[1].get<double>(), a[2].get<double>());
  };
  const Vector3d d = p - vec("origin_mm");
  return {d.dot(vec("u_axis")), d.dot(vec("v_axis"))};
}

double Cross(const Vector2d& o, const Vector2d& a, const Vector2d& b) {
  return (a.x() - o.x()) * (b.y() - o.y()) - (a.y() - o.y()) * (b.x() - o.x());
}

// Convex hull (counter-clockwise) of the sample parameters: inside it Q interpolates the samples,
// outside it (slivers along the edges, the corners) Q extrapolates.
std::vector<Vector2d> Hull(std::vector<Vector2d> pts) {
  std::sort(pts.begin(), pts.end(),
            [](const Vector2d& a, const Vector2d& b) { return a.x() < b.x() || (a.x() == b.x() && a.y() < b.y()); });
  std::vector<Vector2d> hull(2 * pts.size());
  std::size_t k = 0;
  for (std::size_t i = 0; i < pts.size(); ++i) {
    while (k >= 2 && Cross(hull[k - 2], hull[k - 1], pts[i]) <= 0) --k;
    hull[k++] = pts[i];
  }
  for (std::size_t i = pts.size() - 1, t = k + 1; i > 0; --i) {
    while (k >= t && Cross(hull[k - 2], hull[k - 1], pts[i - 1]) <= 0) --k;
    hull[k++] = pts[i - 1];
  }
  hull.resize(k - 1);
  return hull;
}

bool InsideHull(const std::vector<Vector2d>& hull, const Vector2d& q) {
  for (std::size_t i = 0; i < hull.size(); ++i) {
    if (Cross(hull[i], hull[(i + 1) % hull.size()], q) < 0) return false;
  }
  return true;
}

// Distance from the analytic S(u, v) to its foot point on Q at n seeded random (u, v), split by
// where the check point lies: inside/outside the samples' hull (no hull: all inside), and, inside
// it, in the outer band (a fraction of each side) or the interior.
struct TruthCheck {
  int n = 0, failures = 0, outside_hull = 0;
  double max_mm = 0, rms_mm = 0;
  double max_inside_hull_mm = 0, max_outside_hull_mm = 0;
  double max_band_mm = 0, max_interior_mm = 0;
  Vector2d worst_uv = Vector2d::Zero();
};

template <typename StartFn>
TruthCheck CheckAgainstTruth(const AnalyticSurface& s, const BSplineSurface& q, int n, std::uint64_t seed,
                             const std::vector<Vector2d>& hull, double band_fraction, StartFn start) {
  const ParamDomain dom = s.domain();
  Rng rng(seed);
  TruthCheck c;
  c.n = n;
  double sum2 = 0;
  for (int k = 0; k < n; ++k) {
    const double u = rng.Uniform(dom.u_min, dom.u_max), v = rng.Uniform(dom.v_min, dom.v_max);
    const Vector3d p = s.Point(u, v);
    const Vector2d s0 = start(p, u, v);
    const auto foot = ProjectFrom(q, p, s0.x(), s0.y());
    if (!foot.ok()) {
      ++c.failures;
      continue;
    }
    const double e = (p - foot->foot).norm();
    sum2 += e * e;
    if (e > c.max_mm) {
      c.max_mm = e;
      c.worst_uv = Vector2d(u, v);
    }
    if (hull.empty() || InsideHull(hull, Vector2d(u, v))) {
      c.max_inside_hull_mm = std::max(c.max_inside_hull_mm, e);
    } else {
      ++c.outside_hull;
      c.max_outside_hull_mm = std::max(c.max_outside_hull_mm, e);
      continue;
    }
    const double bu = band_fraction * dom.u_span(), bv = band_fraction * dom.v_span();
    const bool band = u < dom.u_min + bu || u > dom.u_max - bu || v < dom.v_min + bv || v > dom.v_max - bv;
    (band ? c.max_band_mm : c.max_interior_mm) = std::max(band ? c.max_band_mm : c.max_interior_mm, e);
  }
  c.rms_mm = std::sqrt(sum2 / std::max(1, n - c.failures));
  return c;
}

bool HasNote(const FitReport& report, const std::string& words) {
  for (const std::string& note : report.notes) {
    if (note.find(words) != std::string::npos) return true;
  }
  return false;
}

// ---------------------------------------------------------------------------------------------
// Building blocks

TEST(ScatteredFitInternals, ThinPlateEnergyIsExactForPolynomials) {
  // Coefficients of f(u) = 1, u, u² in a cubic basis from 1-D least squares (exact for degree ≤ 3);
  // tensor products give f(u, v) whose energy ∫∫ f_uu² + 2 f_uv² + f_vv² is known.
  const auto ku = KnotVector::WithInteriorKnots(3, -2, 3, {-1.1, 0.2, 0.5, 2.0});
  const auto kv = KnotVector::WithInteriorKnots(3, 1, 4, {1.7, 2.9});
  ASSERT_TRUE(ku.ok() && kv.ok());
  auto coefficients = [](const KnotVector& k, int power) {
    std::vector<double> x, y;
    for (int i = 0; i <= 80; ++i) {
      x.push_back(k.lo() + (k.hi() - k.lo()) * i / 80);
      y.push_back(std::pow(x.back(), power));
    }
    return FitCurve1d(x, y, k)->coefficients;
  };
  const Eigen::VectorXd u0 = coefficients(*ku, 0), u1 = coefficients(*ku, 1), u2 = coefficients(*ku, 2);
  const Eigen::VectorXd v0 = coefficients(*kv, 0), v1 = coefficients(*kv, 1), v2 = coefficients(*kv, 2);
  auto tensor = [&](const Eigen::VectorXd& a, const Eigen::VectorXd& b) {
    Eigen::VectorXd c(a.size() * b.size());
    for (Eigen::Index j = 0; j < b.size(); ++j) c.segment(j * a.size(), a.size()) = a * b(j);  // index a + n_u b
    return c;
  };
  const scattered_internal::SparseMatrix r = scattered_internal::ThinPlateMatrix(*ku, *kv);
  const double area = 5.0 * 3.0;
  auto energy = [&](const Eigen::VectorXd& c) { return c.dot(r * c); };
  EXPECT_NEAR(energy(tensor(u1, v0) + tensor(u0, v1)), 0.0, 1e-10);      // a plane: no energy
  EXPECT_NEAR(energy(tensor(u2, v0)), 4 * area, 1e-9);                   // f = u²: f_uu = 2
  EXPECT_NEAR(energy(tensor(u1, v1)), 2 * area, 1e-9);                   // f = uv: f_uv = 1
  EXPECT_NEAR(energy(tensor(u2, v0) + tensor(u0, v2)), 8 * area, 1e-9);  // f = u² + v²
  EXPECT_NEAR(energy(tensor(u2, v1)), 4 * (4.0 * 4 * 4 - 1) / 3 * 5 + 2 * 4 * (27.0 + 8) / 3 * 3, 1e-8);  // u² v
  // Restricted to a sub-box, the energy of f = u² scales with its area.
  const ParamDomain sub{-1, 2, 1.5, 3.5};
  const scattered_internal::SparseMatrix r_sub = scattered_internal::ThinPlateMatrix(*ku, *kv, &sub);
  const Eigen::VectorXd c = tensor(u2, v0);
  EXPECT_NEAR(c.dot(r_sub * c), 4 * 3.0 * 2.0, 1e-9);
}

TEST(ScatteredFitInternals, SelectedInversionTraceMatchesDenseInverse) {
  // M = N + λR for a random sparse N (on R's pattern) must give tr(M⁻¹N) equal to the dense value.
  const auto ku = KnotVector::Uniform(3, 9, 0, 1);
  const auto kv = KnotVector::Uniform(3, 7, 0, 2);
  ASSERT_TRUE(ku.ok() && kv.ok());
  scattered_internal::SparseMatrix r = scattered_internal::ThinPlateMatrix(*ku, *kv);
  scattered_internal::SparseMatrix n = r;
  Rng rng(5);
  // A symmetric positive semi-definite N on the same pattern: BᵀB of a random matrix with the
  // B-spline sparsity (rows = random points' basis values).
  Eigen::MatrixXd dense_n = Eigen::MatrixXd::Zero(n.rows(), n.cols());
  for (int i = 0; i < 120; ++i) {
    const double u = rng.Uniform(), v = rng.Uniform(0, 2);
    double bu[4], bv[4];
    const int su = ku->FindSpan(u), sv = kv->FindSpan(v);
    ku->BasisFunctions(su, u, bu);
    kv->BasisFunctions(sv, v, bv);
    Eigen::VectorXd row = Eigen::VectorXd::Zero(n.rows());
    for (int b = 0; b < 4; ++b) {
      for (int a = 0; a < 4; ++a) row((su - 3 + a) + 9 * (sv - 3 + b)) = bu[a] * bv[b];
    }
    dense_n += row * row.transpose();
  }
  for (int col = 0; col < n.outerSize(); ++col) {
    for (scattered_internal::SparseMatrix::InnerIterator it(n, col); it; ++it) it.valueRef() = dense_n(it.row(), col);
  }
  for (double lambda : {1e-6, 1e-2, 1.0}) {
    scattered_internal::SparseMatrix m = n;
    for (Eigen::Index k = 0; k < m.nonZeros(); ++k) m.valuePtr()[k] += lambda * r.valuePtr()[k];
    scattered_internal::Ldlt ldlt(m);
    ASSERT_EQ(ldlt.info(), Eigen::Success);
    const auto trace = scattered_internal::TraceOfInverseTimes(ldlt, n);
    ASSERT_TRUE(trace.ok()) << trace.status().ToString();
    const Eigen::MatrixXd dense_m = Eigen::MatrixXd(m);
    const double expected = dense_m.ldlt().solve(dense_n).trace();
    EXPECT_NEAR(*trace, expected, 1e-9 * std::abs(expected)) << "lambda " << lambda;
  }
}

// ---------------------------------------------------------------------------------------------
// The reference surfaces, noise-free: (i) FitGrid on a 50 × 50 grid, (ii) FitScattered on 5,000
// scattered points; both checked at 10,000 random points of the whole domain.

constexpr int kScatteredPoints = 5000;
constexpr int kCheckPoints = 10000;
constexpr double kMicron = 1e-3;  // mm

class ScatteredFitReference : public ::testing::TestWithParam<std::string> {};

TEST_P(ScatteredFitReference, GridAndScatteredFitsAreWithinOneMicron) {
  const auto s = Make(GetParam());

  // (i) OpenCASCADE grid approximation, 50 × 50 samples, tolerance 0.1 µm.
  GridFitOptions grid_options;
  grid_options.tolerance_mm = 1e-4;
  FitReport grid_report;
  const auto grid_q = FitGrid(SampleGrid(*s, 50, 50), grid_options, &grid_report);
  ASSERT_TRUE(grid_q.ok()) << grid_q.status().ToString();
  const TruthCheck grid_check = CheckAgainstTruth(*s, *grid_q, kCheckPoints, 301, {}, 0.05,
                                                  [](const Vector3d&, double u, double v) { return Vector2d(u, v); });
  std::printf("[ measured ] %-18s grid 50x50: %d x %d poles, check max %.2e rms %.2e mm\n", GetParam().c_str(),
              grid_q->u_poles(), grid_q->v_poles(), grid_check.max_mm, grid_check.rms_mm);
  EXPECT_EQ(grid_check.failures, 0);
  EXPECT_LE(grid_check.max_mm, kMicron);

  // (ii) Scattered points, degree 6, automatic net (about 8 points per pole), adaptive refinement
  // to 0.5 µm. Seed 11 leaves a 2.6 mm point-free hole at the corner (0, 0) (3.4 mm on franke),
  // and there Q extrapolates: its error is the model error near the hole (what Q misses between
  // the samples) amplified by the extrapolation, 5 to 12 times here. The degree sets that model
  // error. Measured worst error over the whole domain / inside the samples' hull, µm:
  //            quartic        quintic        degree 6       degree 7
  //   egg_box  13.4 / 1.96    1.11 / 0.28    0.13 / 0.05    0.03 / 0.005
  //   franke   0.74 / 0.70    0.50 / 0.34    0.98 / 0.08    1.10 / 0.05
  // (quartic measured with the margin as a span of its own, before the current knot
  // layout; every other surface is below 0.1 µm from degree 5 up; cubic, earlier: egg_box 6.7 and
  // franke 18 µm after refinement, cylinder 1.2 µm). Only degree 6 keeps both within 1 µm,
  // franke by a small margin. The smoothing weight moves the corner error erratically (quintic
  // egg_box at fixed λ = 1e-12, 1e-10, 1e-9, 1e-8, 1e-6: 1.46, 1.19, 0.28, 1.01, 13.1 µm; franke
  // 1.61, 1.43, 0.69, 0.77, 10.6 µm), so GCV's λ is kept. With the margin as a span of its own
  // (scattered_fit.h) quintic egg_box was 1.35 µm, degree 6 franke 1.50 µm; before the local
  // weights of the thin-plate energy (scattered_fit.h) degree 6 franke was 0.98 / 0.08 µm.
  // Three correction rounds: later rounds gain < 1 % in RMS here.
  const Samples samples = Scatter(*s, kScatteredPoints, 11);
  ScatteredFitOptions options;
  options.degree = 6;
  options.adaptive = true;
  options.tolerance_mm = 0.5 * kMicron;
  options.max_correction_iterations = 3;
  FitReport report;
  const auto q = FitScattered(samples.points, options, &report);
  ASSERT_TRUE(q.ok()) << q.status().ToString();
  const std::vector<Vector2d> hull = Hull(samples.uv);
  const TruthCheck check = CheckAgainstTruth(*s, *q, kCheckPoints, 301, hull, 0.05,
                                             [&](const Vector3d& p, double, double) { return FrameStart(report, p); });
  std::printf(
      "[ measured ] %-18s scattered 5000: %d x %d poles, residual max %.2e, check max %.2e (inside hull %.2e, "
      "%d outside: %.2e, worst at (%.2f, %.2f)), largest gap %.2f mm (initial %.2f spans: %s), lambda %.1e\n",
      GetParam().c_str(), q->u_poles(), q->v_poles(), report.max_mm, check.max_mm, check.max_inside_hull_mm,
      check.outside_hull, check.max_outside_hull_mm, check.worst_uv.x(), check.worst_uv.y(),
      report.details.at("largest_gap_mm").get<double>(), report.details.at("initial_gap_spans").get<double>(),
      report.details.at("edge_spans").get<std::string>().c_str(), report.details.at("lambda").get<double>());
  for (const std::string& note : report.notes) std::printf("[ measured ]   note: %s\n", note.c_str());
  EXPECT_EQ(check.failures, 0);
  EXPECT_EQ(report.n_points, kScatteredPoints);
  EXPECT_NE(report.residual.find("orthogonal"), std::string::npos);
  EXPECT_LE(report.max_mm, options.tolerance_mm);  // adaptive refinement reached its tolerance
  // Where the samples surround the check point, Q is within 1 µm.
  EXPECT_LE(check.max_inside_hull_mm, kMicron);
  // Over the whole domain, the corner hole included (see above): within 1 µm (issue item 1).
  // Measured at most 0.57 µm (franke, at the corner (0, 0)); egg_box 0.13 µm.
  EXPECT_LE(check.max_outside_hull_mm, 5 * kMicron);
  EXPECT_LE(check.max_mm, kMicron);
  if (check.max_mm > kMicron) {
    EXPECT_TRUE(HasNote(report, "Q is extrapolated there")) << "no gap note";
  }

  // Orientation: the normal S_u × S_v points to +z (tool side), like the reference surfaces'.
  const ParamDomain dom = q->domain();
  for (double fu : {0.1, 0.5, 0.9}) {
    for (double fv : {0.1, 0.5, 0.9}) {
      const double u = dom.u_min + fu * dom.u_span(), v = dom.v_min + fv * dom.v_span();
      EXPECT_GT(q->Normal(u, v).z(), 0.0) << "at (" << u << ", " << v << ")";
    }
  }
}

std::string ParamName(const ::testing::TestParamInfo<std::string>& param) { return param.param; }

// The prefix keeps the instances inside the filter 'ScatteredFit*'.
INSTANTIATE_TEST_SUITE_P(ScatteredFit, ScatteredFitReference, ::testing::ValuesIn(ReferenceSurfaceNames()), ParamName);

// ---------------------------------------------------------------------------------------------
// Noise: 5 µm Gaussian along the normal on 10,000 scattered points of the reference surfaces, with
// the default options (cubic, GCV with local penalty weights, parameter correction).
//
// The boundary criterion is taken over check points inside the samples' convex hull. Outside it
// (the corners the random samples miss: here a 1.8 mm hole at (100, 0)) any fit extrapolates the
// noise; measured there 0.3-25 µm on the reference surfaces (10-49 µm on the curved ones before the
// local weights, and with λ → 0 as well), so it is printed and only bounded loosely. Measured
// inside the hull, before and with the local weights of the thin-plate energy (scattered_fit.h), µm:
//                      band max / interior max   band max        interior max    vs truth RMS
//   plane              1.05 -> 1.06              0.34 -> 0.35    0.33 -> 0.33    0.160 -> 0.162
//   sphere_cap         1.83 -> 1.81              6.78 -> 7.81    3.72 -> 4.31    1.305 -> 1.245
//   cylinder           1.75 -> 1.32              10.36 -> 8.42   5.92 -> 6.36    1.623 -> 1.549
//   ellipsoid_cap      2.50 -> 1.73              6.32 -> 5.89    2.53 -> 3.40    0.988 -> 0.970
//   saddle             1.05 -> 1.05              0.35 -> 0.34    0.33 -> 0.33    0.160 -> 0.162
//   egg_box            1.54 -> 1.64              10.42 -> 11.07  6.77 -> 6.76    1.861 -> 1.778
//   franke             1.35 -> 1.62              8.81 -> 10.55   6.52 -> 6.52    1.802 -> 1.793
//   blade              2.75 -> 1.92              15.39 -> 10.79  5.60 -> 5.61    1.542 -> 1.448
//   tilted_paraboloid  1.05 -> 1.05              0.35 -> 0.35    0.33 -> 0.33    0.160 -> 0.162
// What kept ellipsoid_cap and blade above 2 was smoothing bias at the corners, not noise and not
// oscillation: without noise at GCV's λ the band error was 7.6 µm (ellipsoid_cap, λ = 1.15, at the
// corner (0, 0)) and 10.7 µm (blade, λ = 0.10) against interior 1.5 and 2.3 µm. The energy of
// S − S₀ flattens what the cubic trend S₀ misses, most at the edges where these shapes curve
// fastest, and GCV's λ minimises the global error, not the band's. The local weights lower the
// energy where the estimated bias outweighs the noise, mostly along those edges; there the fit is
// noisier, so the band max rises where it was noise-dominated (sphere_cap, egg_box, franke) and
// falls where it was bias-dominated (cylinder, ellipsoid_cap, blade). On ellipsoid_cap the lowered
// weights reach 4-6 spans (more than 10 mm) in from the long edges, past the 4 mm band, so the
// interior max rises too; the error against the true surface falls on every curved surface.
// The ratio depends on the noise draw: over the nine surfaces with noise seeds 24, 25 and 26
// instead of 23 the largest ratio went 3.05 -> 2.12 (blade), 2.24 -> 1.93 (ellipsoid_cap ->
// sphere_cap) and 2.44 -> 2.01 (ellipsoid_cap -> plane); plane, saddle and tilted_paraboloid
// (λ → ∞: the fit is the cubic trend, whose variance grows towards the corners) reached 1.46-1.49
// (seed 24) and 1.96-2.01 (seed 26) on their own, unchanged by the weights.
//
// Variants measured that were not kept (ratios ellipsoid_cap / blade; truth RMS in µm where it
// moved). Without local weights:
// - fixed λ = 0.02 (instead of GCV's 2.2 / 0.17): 1.24 / 1.56, but the interior max doubles
//   (ellipsoid_cap 2.5 -> 6.5 µm) and egg_box fails (2.30);
// - quartic trend (monomials above the spline degree L2-projected): band 6.5 -> 4.8 µm, but GCV
//   then chose λ = 18 and the interior improved more: 3.07 / 3.81;
// - a separate weight κ on the energy of the end spans, chosen by GCV together with λ: GCV takes
//   κ ≈ 0.1 (less smoothing at the edge): 2.30 / 3.57 (truth RMS 1.00 -> 0.83, 1.53 -> 1.27);
// - κ fixed at 0.1 / 0.01: 2.59 / 3.14, 2.27 / 4.23; κ chosen to equalise the mean leverage of edge
//   and interior points (κ ≈ 1.8): 2.29 / 1.45;
// - κ fixed at 10 (more smoothing at the edge): all nine surfaces ≤ 1.63 (1.51 / 1.63), but GCV
//   then lowers λ 10-20 times and the interior gets noisier: ellipsoid_cap band max 6.3 -> 7.1 µm,
//   interior 2.5 -> 4.7 µm, truth RMS 0.99 -> 1.29 (sphere_cap 1.31 -> 1.60, blade 1.54 -> 1.70):
//   it meets the ratio with a worse surface, so it was not kept;
// - separate λ for the u and v energies (2-D GCV): 2.14 / 3.22 (sphere_cap 2.06);
// - end spans 3 or 4 times as wide (instead of 2): 2.31-2.38 / 1.77-2.49, but the noise-free
//   egg_box corner (ScatteredFitReference) goes to 1.58 µm;
// - uniform knots with no margin: 2.62 / 2.98; a third-order penalty, edge-down-weighted
//   penalties, wider margins: worse (earlier measurements);
// - parameter plane tilted from the principal one to the plane whose projection best fills its
//   bounding rectangle: blade 1.81 (ellipsoid_cap unchanged), but noise-free franke's corner error
//   2.9 µm;
// - twicing (Tukey 1977: one more pass of the same smoother over the residuals, influence matrix
//   2H − H²) at GCV's λ: all nine ≤ 1.76 (1.66 / 1.76), but the interior gets noisier: truth RMS
//   -2 to +19 % (plane 0.160 -> 0.190, sphere_cap 1.31 -> 1.41, ellipsoid_cap 0.99 -> 1.08);
// - twicing with λ chosen by GCV for the twiced fit (tr(2H − H²) = tr H + a Hutchinson estimate
//   of tr(H − H²) with 32 fixed ±1 probes): GCV raises λ 2-10 times: 2.01 / 2.79, cylinder 2.55.
// With local weights, other choices:
// - bias estimated from the difference of the fits at λ and λ/10 (bias ∝ λ^½) instead of twicing,
//   pooled over 3 × 3 spans: 1.28 / 1.86 but franke 2.13 and plane's truth RMS +7 % (the weight map
//   follows the noise); with the noise expectation subtracted twice / four times: 3.00 / 1.86,
//   2.50 / 1.97;
// - λ chosen again by GCV with the weights: the best truth RMS (ellipsoid_cap 0.87, blade 1.33,
//   cylinder 1.45) but GCV raises λ 2-4 times: 2.18 / 2.59 (cylinder 2.02, sphere_cap 2.06);
// - weights estimated a second time from the weighted fit: 2.43 / 2.34 (its smaller bias raises
//   the weights again).
constexpr double kNoiseMm = 5e-3;

class ScatteredFitNoise : public ::testing::TestWithParam<std::string> {};

TEST_P(ScatteredFitNoise, ResidualMatchesNoiseAndBoundaryDoesNotOscillate) {
  const auto s = Make(GetParam());
  const Samples samples = Scatter(*s, 10000, 23, kNoiseMm);
  FitReport report;
  ScatteredFitOptions options;
  options.smoothing = ScatteredFitOptions::Smoothing::kGcv;  // the thin-plate energy and its local weights
  const auto q = FitScattered(samples.points, options, &report);
  ASSERT_TRUE(q.ok()) << q.status().ToString();
  const TruthCheck check = CheckAgainstTruth(*s, *q, kCheckPoints, 302, Hull(samples.uv), 0.05,
                                             [&](const Vector3d& p, double, double) { return FrameStart(report, p); });
  const double ratio = check.max_band_mm / check.max_interior_mm;
  std::printf(
      "[ measured ] %-8s noisy scattered: %d x %d poles, lambda %.2e, dof %.0f, penalty weights min %.2f mean %.2f, "
      "residual rms %.3f um; vs truth rms %.3f um; inside the hull: interior max %.3f um, outer 5%% band max %.3f um "
      "(ratio %.2f); outside the hull (%d points) max %.3f um; initial gap %.2f spans (%s)\n",
      GetParam().c_str(), q->u_poles(), q->v_poles(), report.details.at("lambda").get<double>(),
      report.details.at("effective_dof").get<double>(), report.details.at("penalty_weight_min").get<double>(),
      report.details.at("penalty_weight_mean").get<double>(), report.rms_mm * 1e3, check.rms_mm * 1e3,
      check.max_interior_mm * 1e3, check.max_band_mm * 1e3, ratio, check.outside_hull, check.max_outside_hull_mm * 1e3,
      report.details.at("initial_gap_spans").get<double>(), report.details.at("edge_spans").get<std::string>().c_str());
  EXPECT_EQ(check.failures, 0);
  EXPECT_NEAR(report.rms_mm, kNoiseMm, 0.1 * kNoiseMm);
  EXPECT_LT(check.rms_mm, 0.5 * kNoiseMm);  // most of the noise is removed
  EXPECT_LT(check.max_outside_hull_mm, 20 * kNoiseMm);
  // The edge band's worst error within 2.5σ: a boundary that oscillates or is biased shows several σ there
  // (blade before the local weights: 15.4 µm). Since 2026-11 the GCV mode fits on the ladder's net (scattered_fit.cc),
  // which lowered the band max on every surface but the interior max more (sphere_cap band 7.90 -> 5.39 µm,
  // interior 4.31 -> 2.49 µm), so band / interior, bounded by 2.0 on the point-count net, is now 1.05-3.20
  // (ellipsoid_cap: band 4.22 µm, interior 1.32 µm) and bounded loosely.
  EXPECT_LE(check.max_band_mm, 2.5 * kNoiseMm);
  EXPECT_LE(ratio, 3.5);

  // OpenCASCADE's grid approximator on a noisy 100 × 100 grid (same noise), default degrees 3-5,
  // tolerance 5σ. Its boundary behaviour depends erratically on the settings; measured band max /
  // interior max (franke, saddle): tolerance 15 µm: 12.4, 28.2 (6.5 s each); 25 µm: 72.5, 1.9;
  // degree ≤ 3 at 15 µm: 5.2, 1.9; degree ≤ 4 at 20 µm: 1.0, 2.0. The grid reaches the corners, so
  // its whole band is compared with our band inside the hull.
  GridSamples grid = SampleGrid(*s, 100, 100);
  Rng rng(29);
  for (int j = 0; j < 100; ++j) {
    for (int i = 0; i < 100; ++i) {
      const double u = grid.domain.u_min + grid.domain.u_span() * i / 99;
      const double v = grid.domain.v_min + grid.domain.v_span() * j / 99;
      grid.points[static_cast<std::size_t>(j * 100 + i)] += rng.Normal(0, kNoiseMm) * s->Normal(u, v);
    }
  }
  GridFitOptions grid_options;
  grid_options.tolerance_mm = 5 * kNoiseMm;
  FitReport grid_report;
  const auto grid_q = FitGrid(grid, grid_options, &grid_report);
  ASSERT_TRUE(grid_q.ok()) << grid_q.status().ToString();
  const TruthCheck grid_check = CheckAgainstTruth(*s, *grid_q, kCheckPoints, 302, {}, 0.05,
                                                  [](const Vector3d&, double u, double v) { return Vector2d(u, v); });
  std::printf(
      "[ measured ] %-8s noisy grid (OCCT, tolerance 25 um): %d x %d poles, grid residual rms %.3f um; vs truth rms "
      "%.3f um; interior max %.3f um, band max %.3f um (ratio %.2f)\n",
      GetParam().c_str(), grid_q->u_poles(), grid_q->v_poles(), grid_report.rms_mm * 1e3, grid_check.rms_mm * 1e3,
      grid_check.max_interior_mm * 1e3, grid_check.max_band_mm * 1e3,
      grid_check.max_band_mm / grid_check.max_interior_mm);
  EXPECT_LT(check.max_band_mm, grid_check.max_band_mm);
}

INSTANTIATE_TEST_SUITE_P(ScatteredFit, ScatteredFitNoise, ::testing::ValuesIn(ReferenceSurfaceNames()), ParamName);

// The default (least squares on the net the GCV ladder chooses; thin-plate GCV where the coverage is
// sparse at that net) on the same noisy points: most of the noise removed, nothing wild outside the hull,
// the edge band's worst error within a measured bound of the interior's (least squares has no energy
// pulling the edges; measured 2026-11: ratios printed below).
// Measured 2026-11: plane 1.84, saddle 1.74, tilted_paraboloid 1.74, sphere_cap 2.28, cylinder 2.58,
// ellipsoid_cap 3.92 (least squares); franke and blade take the thin-plate fallback (1.67, 1.93).
constexpr double kDefaultBandRatio = 4.5;
class ScatteredFitNoiseDefault : public ::testing::TestWithParam<std::string> {};

TEST_P(ScatteredFitNoiseDefault, RemovesTheNoise) {
  const auto s = Make(GetParam());
  const Samples samples = Scatter(*s, 10000, 23, kNoiseMm);
  FitReport report;
  const auto q = FitScattered(samples.points, ScatteredFitOptions{}, &report);
  ASSERT_TRUE(q.ok()) << q.status().ToString();
  const TruthCheck check = CheckAgainstTruth(*s, *q, kCheckPoints, 302, Hull(samples.uv), 0.05,
                                             [&](const Vector3d& p, double, double) { return FrameStart(report, p); });
  const double ratio = check.max_band_mm / check.max_interior_mm;
  std::printf(
      "[ measured ] %-8s default: %d x %d poles (%s, smoothing %s), residual rms %.3f um; vs truth rms %.3f um; "
      "interior max %.3f um, band max %.3f um (ratio %.2f); outside the hull max %.3f um\n",
      GetParam().c_str(), q->u_poles(), q->v_poles(), report.details.at("net").get<std::string>().c_str(),
      report.details.at("smoothing").get<std::string>().c_str(), report.rms_mm * 1e3, check.rms_mm * 1e3,
      check.max_interior_mm * 1e3, check.max_band_mm * 1e3, ratio, check.max_outside_hull_mm * 1e3);
  EXPECT_EQ(check.failures, 0);
  EXPECT_NEAR(report.rms_mm, kNoiseMm, 0.1 * kNoiseMm);
  EXPECT_LT(check.rms_mm, 0.5 * kNoiseMm) << report.details.at("net_ladder").dump();
  // Outside the samples' hull (corner holes) least squares extrapolates the end pieces with no energy to
  // hold them: measured 2026-11 egg_box 159 um (32 sigma), the others <= 15 um; the report's gap note says
  // where Q is extrapolated. The thin-plate modes stay below 20 sigma there (ScatteredFitNoise).
  EXPECT_LT(check.max_outside_hull_mm, 40 * kNoiseMm);
  EXPECT_LE(ratio, kDefaultBandRatio) << report.details.at("net_ladder").dump();
}

INSTANTIATE_TEST_SUITE_P(ScatteredFit, ScatteredFitNoiseDefault, ::testing::ValuesIn(ReferenceSurfaceNames()),
                         ParamName);

// ---------------------------------------------------------------------------------------------
// Smoothing weight

TEST(ScatteredFitSmoothing, GcvLambdaFollowsTheNoiseAndToleranceIsReached) {
  const auto s = Make("sphere_cap");
  const Samples clean = Scatter(*s, 4000, 31);
  const Samples noisy = Scatter(*s, 4000, 31, kNoiseMm);
  ScatteredFitOptions options;
  options.smoothing = ScatteredFitOptions::Smoothing::kGcv;  // the default (kNone) has no λ to choose
  options.max_correction_iterations = 3;
  FitReport clean_report, noisy_report;
  ASSERT_TRUE(FitScattered(clean.points, options, &clean_report).ok());
  ASSERT_TRUE(FitScattered(noisy.points, options, &noisy_report).ok());
  const double clean_lambda = clean_report.details.at("lambda").get<double>();
  const double noisy_lambda = noisy_report.details.at("lambda").get<double>();
  std::printf("[ measured ] GCV lambda: noise-free %.2e (dof %.0f), 5 um noise %.2e (dof %.0f)\n", clean_lambda,
              clean_report.details.at("effective_dof").get<double>(), noisy_lambda,
              noisy_report.details.at("effective_dof").get<double>());
  EXPECT_LE(clean_lambda, 1e-6);
  EXPECT_GE(noisy_lambda, 100 * clean_lambda);
  EXPECT_LT(noisy_report.details.at("effective_dof").get<double>(),
            clean_report.details.at("effective_dof").get<double>());

  // kTolerance: the smoothest surface whose RMS residual is the target.
  for (double target_um : {8.0, 20.0}) {
    ScatteredFitOptions tol = options;
    tol.smoothing = ScatteredFitOptions::Smoothing::kTolerance;
    tol.tolerance_mm = target_um * 1e-3;
    FitReport report;
    ASSERT_TRUE(FitScattered(noisy.points, tol, &report).ok());
    std::printf("[ measured ] kTolerance target %.1f um: rms %.3f um, lambda %.2e\n", target_um, report.rms_mm * 1e3,
                report.details.at("lambda").get<double>());
    EXPECT_NEAR(report.rms_mm, tol.tolerance_mm, 0.05 * tol.tolerance_mm);
    EXPECT_EQ(report.details.at("smoothing"), "tolerance");
  }
  // Below the noise the target cannot be met; the report says so with the figure reached.
  ScatteredFitOptions tight = options;
  tight.smoothing = ScatteredFitOptions::Smoothing::kTolerance;
  tight.tolerance_mm = 1e-3;
  FitReport tight_report;
  ASSERT_TRUE(FitScattered(noisy.points, tight, &tight_report).ok());
  EXPECT_TRUE(HasNote(tight_report, "leaves an RMS residual of")) << tight_report.ToJson().dump(1);

  // kFixed uses the given weight.
  ScatteredFitOptions fixed = options;
  fixed.smoothing = ScatteredFitOptions::Smoothing::kFixed;
  fixed.lambda = 1e-3;
  FitReport fixed_report;
  ASSERT_TRUE(FitScattered(noisy.points, fixed, &fixed_report).ok());
  EXPECT_EQ(fixed_report.details.at("lambda").get<double>(), 1e-3);
}

// ---------------------------------------------------------------------------------------------
// Adaptive refinement

TEST(ScatteredFitAdaptive, InsertsKnotsWhereTheResidualExceedsTheTolerance) {
  const auto s = Make("franke");
  const Samples samples = Scatter(*s, 5000, 53);
  ScatteredFitOptions options;  // cubic: its 26 × 26 automatic net leaves up to ~4 µm on franke
  options.adaptive = true;
  options.tolerance_mm = 2e-3;
  options.max_correction_iterations = 1;
  FitReport report;
  const auto q = FitScattered(samples.points, options, &report);
  ASSERT_TRUE(q.ok()) << q.status().ToString();
  const auto inserted_u = report.details.at("knots_inserted_u").get<std::vector<double>>();
  const auto inserted_v = report.details.at("knots_inserted_v").get<std::vector<double>>();
  const auto box = report.details.at("data_box").get<std::vector<double>>();
  std::printf("[ measured ] adaptive franke: %d refinements, %zu + %zu knots, %d x %d poles, residual max %.3f um\n",
              report.details.at("refinements").get<int>(), inserted_u.size(), inserted_v.size(), q->u_poles(),
              q->v_poles(), report.max_mm * 1e3);
  EXPECT_GE(report.details.at("refinements").get<int>(), 1);
  EXPECT_FALSE(inserted_u.empty() && inserted_v.empty());
  EXPECT_LE(report.max_mm, options.tolerance_mm);
  EXPECT_EQ(report.method, "scattered-thin-plate-adaptive");
  // Knots go inside the data, never into the margin spans.
  for (double t : inserted_u) EXPECT_TRUE(t > box[0] && t < box[1]) << t;
  for (double t : inserted_v) EXPECT_TRUE(t > box[2] && t < box[3]) << t;

  // An unreachable tolerance: the refinement stops and the report gives the figure reached.
  options.tolerance_mm = 1e-6;
  options.max_refinements = 1;
  FitReport limited;
  ASSERT_TRUE(FitScattered(samples.points, options, &limited).ok());
  EXPECT_EQ(limited.details.at("refinements").get<int>(), 1);
  EXPECT_TRUE(HasNote(limited, "adaptive refinement stopped after 1 refinements")) << limited.ToJson().dump(1);
}

// ---------------------------------------------------------------------------------------------
// A previous surface as the base: its parameters and its domain carry over.

TEST(ScatteredFitBase, ParametersFromABaseSurfaceCoverItsDomain) {
  const auto s = Make("tilted_paraboloid");
  FitReport base_report;
  const auto base = FitAnalytic(*s, 9, 9, GridFitOptions{}, 0, 1, &base_report);
  ASSERT_TRUE(base.ok()) << base.status().ToString();
  const Samples samples = Scatter(*s, 3000, 37);
  ScatteredFitOptions options;
  options.degree = 5;
  options.max_correction_iterations = 3;
  FitReport report;
  const auto q = FitScattered(samples.points, options, &report, &*base);
  ASSERT_TRUE(q.ok()) << q.status().ToString();
  EXPECT_EQ(report.details.at("parameterisation"), "base-surface");
  const ParamDomain dq = q->domain(), db = base->domain();
  EXPECT_DOUBLE_EQ(dq.u_min, db.u_min);
  EXPECT_DOUBLE_EQ(dq.u_max, db.u_max);
  EXPECT_DOUBLE_EQ(dq.v_min, db.v_min);
  EXPECT_DOUBLE_EQ(dq.v_max, db.v_max);
  const TruthCheck check = CheckAgainstTruth(*s, *q, 2000, 303, Hull(samples.uv), 0.05,
                                             [](const Vector3d&, double u, double v) { return Vector2d(u, v); });
  std::printf("[ measured ] base-surface fit: check max %.2e mm (inside hull %.2e)\n", check.max_mm,
              check.max_inside_hull_mm);
  EXPECT_EQ(check.failures, 0);
  EXPECT_LE(check.max_inside_hull_mm, kMicron);
  EXPECT_GT(q->Normal(0, 0).dot(s->Normal(0, 0)), 0.99);
}

TEST(ScatteredFitBase, RepeatedFitsAreIdentical) {
  const auto s = Make("saddle");
  const Samples samples = Scatter(*s, 1500, 41, kNoiseMm);
  ScatteredFitOptions options;
  options.adaptive = true;
  options.tolerance_mm = 0.02;
  FitReport a, b;
  const auto qa = FitScattered(samples.points, options, &a);
  const auto qb = FitScattered(samples.points, options, &b);
  ASSERT_TRUE(qa.ok() && qb.ok());
  EXPECT_EQ(a.ToJson().dump(), b.ToJson().dump());
  for (int j = 1; j <= qa->v_poles(); ++j) {
    for (int i = 1; i <= qa->u_poles(); ++i) {
      ASSERT_EQ(qa->geom()->Pole(i, j).XYZ().X(), qb->geom()->Pole(i, j).XYZ().X());
      ASSERT_EQ(qa->geom()->Pole(i, j).XYZ().Z(), qb->geom()->Pole(i, j).XYZ().Z());
    }
  }
}

// ---------------------------------------------------------------------------------------------
// Bad input: BadInput with a message naming the problem, and the report left untouched.

void ExpectBadInput(const std::vector<Vector3d>& points, const ScatteredFitOptions& options,
                    const std::vector<std::string>& words, const BSplineSurface* base = nullptr) {
  FitReport report;
  report.method = "untouched";
  const auto q = FitScattered(points, options, &report, base);
  ASSERT_FALSE(q.ok()) << "expected an error naming: " << words.front();
  EXPECT_EQ(q.status().code(), StatusCode::kBadInput) << q.status().ToString();
  for (const std::string& w : words) {
    EXPECT_NE(q.status().message().find(w), std::string::npos) << "'" << w << "' not in: " << q.status().message();
  }
  EXPECT_EQ(report.method, "untouched");
}

TEST(ScatteredFitBadInput, EachProblemIsNamed) {
  const auto s = Make("saddle");
  const std::vector<Vector3d> good = Scatter(*s, 400, 43).points;
  const ScatteredFitOptions defaults;
  ASSERT_TRUE(FitScattered(good, defaults, nullptr).ok());

  // Fewer points than unknowns, with the number needed.
  ScatteredFitOptions big_net;
  big_net.u_poles = big_net.v_poles = 25;
  ExpectBadInput(good, big_net, {"400 points", "25 × 25", "625 unknowns", "at least 625"});
  ExpectBadInput(std::vector<Vector3d>(good.begin(), good.begin() + 10), defaults, {"10 points", "at least 16"});
  // Non-finite coordinates, with the index.
  {
    std::vector<Vector3d> bad = good;
    bad[123].y() = std::numeric_limits<double>::quiet_NaN();
    ExpectBadInput(bad, defaults, {"point 123", "not finite"});
    bad[123].y() = 0;
    bad[7].z() = std::numeric_limits<double>::infinity();
    ExpectBadInput(bad, defaults, {"point 7", "not finite"});
  }
  // Exact duplicates, with both indices.
  {
    std::vector<Vector3d> bad = good;
    bad[250] = bad[31];
    ExpectBadInput(bad, defaults, {"points 31 and 250", "identical"});
  }
  // Degenerate sets: collinear, coincident (within 1e-12 mm, no two identical).
  {
    std::vector<Vector3d> line;
    for (int i = 0; i < 100; ++i) line.emplace_back(i * 0.5, 2 * i * 0.5, 3 - i * 0.5);
    ExpectBadInput(line, defaults, {"collinear"});
    std::vector<Vector3d> blob;
    Rng rng(47);
    for (int i = 0; i < 100; ++i)
      blob.emplace_back(Vector3d(10, 20, 30) + 1e-12 * Vector3d(rng.Normal(), rng.Normal(), rng.Normal()));
    ExpectBadInput(blob, defaults, {"coincident"});
  }
  // Options out of range.
  auto with = [&](auto change) {
    ScatteredFitOptions o;
    change(o);
    return o;
  };
  ExpectBadInput(good, with([](ScatteredFitOptions& o) { o.degree = 1; }), {"degree", "out of range"});
  ExpectBadInput(good, with([](ScatteredFitOptions& o) { o.degree = 9; }), {"degree"});
  ExpectBadInput(good, with([](ScatteredFitOptions& o) { o.u_poles = 3, o.v_poles = 10; }), {"u_poles"});
  ExpectBadInput(good, with([](ScatteredFitOptions& o) { o.u_poles = 10; }), {"v_poles", "give both"});
  ExpectBadInput(good, with([](ScatteredFitOptions& o) { o.lambda = -1; }), {"lambda"});
  ExpectBadInput(good, with([](ScatteredFitOptions& o) { o.tolerance_mm = 0; }), {"tolerance"});
  ExpectBadInput(good, with([](ScatteredFitOptions& o) { o.max_correction_iterations = -1; }),
                 {"max_correction_iterations"});
  ExpectBadInput(good, with([](ScatteredFitOptions& o) { o.max_refinements = 99; }), {"max_refinements"});
  // An empty base surface.
  const BSplineSurface empty;
  ExpectBadInput(good, defaults, {"base"}, &empty);
}

}  // namespace
}  // namespace formloop::recon
