// FitScattered (scattered_fit.h): the points' frame and initial parameters, the knot layout and the net, the
// fit with parameter correction (orthogonal-distance fitting), knot redistribution, adaptive refinement and the
// report. The pieces it calls: the layout (frame, knots, coverage) in scattered_layout.cc, the penalised
// least-squares system TensorLsq in scattered_lsq.cc, the choice of λ and of the automatic net in
// scattered_choice.cc (issue 18 split the former 1,561-line file along these seams, outputs bit-identical).
#include "reconstruction/scattered_fit.h"

#include <pcl/kdtree/kdtree_flann.h>
#include <pcl/point_cloud.h>
#include <pcl/point_types.h>

#include <Eigen/Dense>
#include <Geom_BSplineSurface.hxx>
#include <Standard_Failure.hxx>
#include <TColStd_Array1OfInteger.hxx>
#include <TColStd_Array1OfReal.hxx>
#include <TColgp_Array2OfPnt.hxx>
#include <algorithm>
#include <cmath>
#include <gp_Pnt.hxx>
#include <gp_Vec.hxx>
#include <limits>
#include <memory>
#include <string>

#include "reconstruction/point_checks.h"
#include "reconstruction/scattered_choice.h"
#include "reconstruction/scattered_layout.h"
#include "reconstruction/scattered_lsq.h"

namespace formloop::recon {

using scattered_internal::ChooseLambda;
using scattered_internal::ChooseNet;
using scattered_internal::DataKnots;
using scattered_internal::EdgePlan;
using scattered_internal::Frame;
using scattered_internal::Gap;
using scattered_internal::kEndSpanWidth;
using scattered_internal::LambdaChoice;
using scattered_internal::LargestGap;
using scattered_internal::NetChoice;
using scattered_internal::PcaFrame;
using scattered_internal::RedistributedKnots;
using scattered_internal::TensorLsq;

namespace {

using Eigen::Vector3d;

constexpr int kMinDegree = 2;  // the thin-plate energy needs second derivatives inside the spans
constexpr int kMaxDegree = 7;
constexpr int kMaxPoles = 1000;
// Smallest margin beyond the points' parameter box, in point spacings: scattered samples stop
// short of the true boundary (by ~side/m along an edge and by about a spacing at a corner) and the
// projected boundary of a curved patch is curved, so without a margin the boundary of the sampled
// surface would project onto Q's edge and be clamped. See DataKnots for the margin's span.
constexpr double kMarginSpacings = 2;
// Dense coverage (DataKnots: uniform knots over the data, no margin) when the largest hole in
// the initial parameter box (LargestGap, a corner in practice) is at most this many widths of a
// uniform span of the net over the data. Wide end spans and the margin pay for themselves
// only where a corner span lacks data. Measured: 0.59-0.78 spans with 5,000-10,000 points and the
// automatic net (about 8 points a pole; there uniform corner spans left 2-36 µm of corner error);
// 0.28 with 100,000 points on a 24 × 24 net (franke, 1 µm noise), where the margin layout gave an
// orthogonal RMS of 1.231 µm against 1.153 µm with uniform knots. 0.4 lies between.
constexpr double kDenseGapSpans = 0.4;
// A gap in the points wider than this many point spacings is reported (Poisson-scattered points
// leave interior gaps of up to ~1.7 spacings for 10^3..10^5 points; corners are worse).
constexpr double kGapSpacings = 2;
// Parameter correction stops when the orthogonal RMS falls by less than this (relative).
constexpr double kCorrectionStall = 1e-3;
// kTolerance stops correcting when the orthogonal RMS is this close to the target (relative).
constexpr double kToleranceMatch = 5e-3;

// Messages print numbers like the other fits.
std::string Num(double value, int precision = 6) { return FormatSignificant(value, precision); }

nlohmann::json JsonVector(const Vector3d& v) { return {v.x(), v.y(), v.z()}; }
Handle(Geom_BSplineSurface)
    MakeGeom(const KnotVector& ku, const KnotVector& kv, const Eigen::MatrixXd& poles, const Vector3d& origin) {
  const int nu = ku.n_poles(), nv = kv.n_poles();
  TColgp_Array2OfPnt net(1, nu, 1, nv);
  for (int b = 0; b < nv; ++b) {
    for (int a = 0; a < nu; ++a) {
      const int k = a + nu * b;
      net(a + 1, b + 1) = gp_Pnt(poles(k, 0) + origin.x(), poles(k, 1) + origin.y(), poles(k, 2) + origin.z());
    }
  }
  auto knots = [](const KnotVector& kvec, TColStd_Array1OfReal* values, TColStd_Array1OfInteger* mults) {
    std::vector<double> t;
    std::vector<int> m;
    kvec.Distinct(&t, &m);
    values->Resize(1, static_cast<int>(t.size()), false);
    mults->Resize(1, static_cast<int>(t.size()), false);
    for (std::size_t k = 0; k < t.size(); ++k) {
      (*values)(static_cast<int>(k) + 1) = t[k];
      (*mults)(static_cast<int>(k) + 1) = m[k];
    }
  };
  TColStd_Array1OfReal uk(1, 1), vk(1, 1);
  TColStd_Array1OfInteger um(1, 1), vm(1, 1);
  knots(ku, &uk, &um);
  knots(kv, &vk, &vm);
  return new Geom_BSplineSurface(net, uk, vk, um, vm, ku.degree(), kv.degree());
}

nlohmann::json DistinctKnotsJson(const KnotVector& k) {
  std::vector<double> t;
  std::vector<int> m;
  k.Distinct(&t, &m);
  return t;
}

// One fit with parameter correction, for fixed knots.
struct CorrectedFit {
  BSplineSurface surface;
  Eigen::MatrixXd poles;
  TensorLsq::Trial trial;
  double lambda_scale = 1;          // tr AᵀA / tr R of the final system
  std::vector<double> u, v;         // foot-point parameters of the points on `surface`
  std::vector<double> distance_mm;  // orthogonal residuals
  double rms_mm = 0;
  int rounds = 0;  // refits after the first
  int failed_projections = 0;
  int boundary_feet = 0;
  std::vector<double> rms_history;
  std::vector<std::string> notes;
};

Result<CorrectedFit> FitWithCorrection(const std::vector<Vector3d>& points, const std::vector<Vector3d>& centred,
                                       const Vector3d& origin, const KnotVector& ku, const KnotVector& kv,
                                       const ParamDomain& data_box, std::vector<double> u, std::vector<double> v,
                                       const ScatteredFitOptions& options, double* previous_log_lambda,
                                       std::unique_ptr<TensorLsq> assembled = nullptr) {
  const int m = static_cast<int>(points.size());
  // `assembled`: the same knots and parameters already assembled without the trend (the net ladder's
  // chosen rung); used for the first round when that is what this fit needs.
  const bool assembled_given = assembled != nullptr;
  std::unique_ptr<TensorLsq> lsq_owner =
      assembled != nullptr ? std::move(assembled)
                           : std::make_unique<TensorLsq>(ku, kv, ParamDomain{ku.lo(), ku.hi(), kv.lo(), kv.hi()});
  TensorLsq& lsq = *lsq_owner;
  CorrectedFit best;
  bool have_best = false;
  // kTolerance aims at an orthogonal RMS of tolerance_mm, but λ is chosen on the parametric RMS at
  // the current parameters, which the projection then lowers (by 5-6 % measured on franke with 5 µm
  // noise). Each round rescales the parametric target by tolerance / orthogonal RMS reached.
  const bool to_tolerance = options.smoothing == ScatteredFitOptions::Smoothing::kTolerance;
  double target_mm = options.tolerance_mm;
  // The trend matters only through the energy: not for kNone (its weight is a floor) or a fixed λ = 0.
  const bool with_trend = !(options.smoothing == ScatteredFitOptions::Smoothing::kNone ||
                            (options.smoothing == ScatteredFitOptions::Smoothing::kFixed && options.lambda == 0));
  const bool reuse_first = lsq_owner != nullptr && assembled_given && !with_trend;
  for (int round = 0; round <= options.max_correction_iterations; ++round) {
    if (!(round == 0 && reuse_first)) lsq.Assemble(u, v, centred, with_trend);
    LambdaChoice choice = ChooseLambda(lsq, options, *previous_log_lambda, m, target_mm);
    if (!choice.trial.ok) {
      if (have_best) break;  // keep the previous round's surface
      return Status::Failed(
          "scattered fit: the penalised normal matrix is not positive definite (lambda = " + Num(choice.trial.lambda) +
          "); some control points have no data and no smoothing; use smoothing (kGcv) or fewer "
          "poles");
    }
    CorrectedFit fit;
    try {
      fit.surface = BSplineSurface(MakeGeom(ku, kv, choice.trial.poles, origin));
    } catch (const Standard_Failure& failure) {
      return Status::Internal(std::string("scattered fit: OpenCASCADE refused the surface: ") +
                              failure.DynamicType()->Name());
    }
    fit.poles = choice.trial.poles;
    fit.lambda_scale = lsq.lambda_scale();
    if (!choice.note.empty()) fit.notes.push_back(choice.note);
    fit.trial = std::move(choice.trial);
    fit.u = u;
    fit.v = v;
    fit.distance_mm.assign(static_cast<std::size_t>(m), 0.0);
    double sum2 = 0;
    // Only Newton from the current parameters is used: the smallest start grid (no kd-tree searches).
    FL_ASSIGN_OR_RETURN(const FootPointProjector projector,
                        FootPointProjector::Build(fit.surface, ProjectorOptions{.seed_grid = 2}));
    // The projections on the cores --threads allows (fixed chunks), the sums below in point order.
    const std::vector<Result<FootPoint>> feet = projector.ProjectEachFrom(points, u, v);
    for (int i = 0; i < m; ++i) {
      const std::size_t si = static_cast<std::size_t>(i);
      const Result<FootPoint>& foot = feet[si];
      if (foot.ok()) {
        fit.u[si] = foot->u;
        fit.v[si] = foot->v;
        fit.distance_mm[si] = (points[si] - foot->foot).norm();
        fit.boundary_feet += foot->on_boundary ? 1 : 0;
      } else {
        // Keep the parameters; the parametric distance bounds the orthogonal one.
        fit.distance_mm[si] = (points[si] - fit.surface.Point(u[si], v[si])).norm();
        ++fit.failed_projections;
      }
      sum2 += fit.distance_mm[si] * fit.distance_mm[si];
    }
    fit.rms_mm = std::sqrt(sum2 / m);
    if (fit.trial.lambda > 0) *previous_log_lambda = std::log10(fit.trial.lambda);
    const std::vector<double> history = have_best ? best.rms_history : std::vector<double>{};
    if (to_tolerance) {
      // Keep the round closest to the target; stop within kToleranceMatch of it.
      const double miss = std::abs(fit.rms_mm / options.tolerance_mm - 1);
      const double reached_mm = fit.rms_mm;
      u = fit.u;
      v = fit.v;
      if (!have_best || miss < std::abs(best.rms_mm / options.tolerance_mm - 1)) {
        fit.rounds = round;
        fit.rms_history = history;
        fit.rms_history.push_back(fit.rms_mm);
        best = std::move(fit);
        have_best = true;
      } else {
        best.rms_history.push_back(fit.rms_mm);
      }
      if (miss < kToleranceMatch || !(reached_mm > 0)) break;
      target_mm *= options.tolerance_mm / reached_mm;
      continue;
    }
    const bool improved = !have_best || fit.rms_mm < best.rms_mm;
    const bool stalled = have_best && fit.rms_mm > best.rms_mm * (1 - kCorrectionStall);
    if (improved) {
      fit.rounds = round;
      fit.rms_history = history;
      fit.rms_history.push_back(fit.rms_mm);
      best = std::move(fit);
      have_best = true;
    } else {
      best.rms_history.push_back(fit.rms_mm);
    }
    if (stalled) break;
    u = best.u;
    v = best.v;
  }
  return best;
}
}  // namespace
// ---------------------------------------------------------------------------------------------
// Options

Status ScatteredFitOptions::Validate() const {
  if (degree < kMinDegree || degree > kMaxDegree) {
    return Status::BadInput(Where{.field = "degree"}, "degree " + std::to_string(degree) + " is out of range",
                            "use a degree between " + std::to_string(kMinDegree) + " and " +
                                std::to_string(kMaxDegree) + " (3 = cubic; the thin-plate energy needs degree >= 2)");
  }
  for (const auto& [name, poles] : {std::pair<const char*, int>{"u_poles", u_poles}, {"v_poles", v_poles}}) {
    if (poles != 0 && (poles < degree + 1 || poles > kMaxPoles)) {
      return Status::BadInput(Where{.field = name}, std::to_string(poles) + " poles is out of range",
                              "use 0 (automatic) or between degree + 1 = " + std::to_string(degree + 1) + " and " +
                                  std::to_string(kMaxPoles));
    }
  }
  if ((u_poles == 0) != (v_poles == 0)) {
    return Status::BadInput(Where{.field = u_poles == 0 ? "u_poles" : "v_poles"},
                            "only one direction's pole count is given", "give both u_poles and v_poles, or neither");
  }
  if (!std::isfinite(lambda) || lambda < 0) {
    return Status::BadInput(Where{.field = "lambda"}, "lambda = " + Num(lambda) + " must be a finite number >= 0",
                            "use e.g. 1e-6 (dimensionless; see scattered_fit.h)");
  }
  if (!std::isfinite(tolerance_mm) || !(tolerance_mm > 0)) {
    return Status::BadInput(Where{.field = "tolerance_mm"}, "tolerance must be a positive finite number of mm",
                            "use e.g. 1e-3");
  }
  if (max_correction_iterations < 0 || max_correction_iterations > 100) {
    return Status::BadInput(Where{.field = "max_correction_iterations"},
                            std::to_string(max_correction_iterations) + " is out of range", "use 0 to 100");
  }
  if (max_refinements < 0 || max_refinements > 20) {
    return Status::BadInput(Where{.field = "max_refinements"}, std::to_string(max_refinements) + " is out of range",
                            "use 0 to 20");
  }
  return Status::Ok();
}

// ---------------------------------------------------------------------------------------------
// FitScattered

Result<BSplineSurface> FitScattered(const std::vector<Vector3d>& points, const ScatteredFitOptions& options,
                                    FitReport* report, const BSplineSurface* base) {
  FL_RETURN_IF_ERROR(options.Validate().WithContext("scattered fit options"));
  const int m = static_cast<int>(points.size());
  const int p = options.degree;
  const int min_unknowns = options.u_poles > 0 ? options.u_poles * options.v_poles : (p + 1) * (p + 1);
  if (m < min_unknowns) {
    return Status::BadInput(
        Where{.field = "points"},
        std::to_string(m) + " points cannot determine a " +
            (options.u_poles > 0 ? std::to_string(options.u_poles) + " × " + std::to_string(options.v_poles)
                                 : std::to_string(p + 1) + " × " + std::to_string(p + 1) + " (smallest)") +
            " control net (" + std::to_string(min_unknowns) + " unknowns per coordinate)",
        "give at least " + std::to_string(min_unknowns) + " points or fewer poles");
  }
  FL_RETURN_IF_ERROR(CheckFiniteAndDistinct(points).WithContext("scattered fit"));
  if (base != nullptr && !base->valid()) {
    return Status::BadInput(Where{.field = "base"}, "the base surface is empty", "pass nullptr to use the PCA plane");
  }

  // Principal components (on centred coordinates, so the offset of the part does not cost digits).
  Vector3d mean = Vector3d::Zero();
  for (const Vector3d& q : points) mean += q;
  mean /= m;
  Eigen::Matrix3d cov = Eigen::Matrix3d::Zero();
  for (const Vector3d& q : points) cov += (q - mean) * (q - mean).transpose();
  cov /= m;
  const Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> eig(cov);
  const Vector3d variances = eig.eigenvalues().reverse();  // descending
  Eigen::Matrix3d axes;
  axes << eig.eigenvectors().col(2), eig.eigenvectors().col(1), eig.eigenvectors().col(0);
  // Coincident: all points within ~1 nm of each other (relative to their distance from the origin,
  // which bounds the rounding of the coordinates).
  if (!(std::sqrt(variances(0)) > 1e-9 * (1 + mean.norm()))) {
    return Status::BadInput(
        Where{.field = "points"},
        "the points are coincident (spread " + Num(std::sqrt(variances(0))) + " mm): they do not span a surface",
        "give points spread over an area");
  }
  if (!(variances(1) > 1e-12 * variances(0))) {
    return Status::BadInput(Where{.field = "points"},
                            "the points are collinear (principal variances " + Num(variances(0)) + ", " +
                                Num(variances(1)) + " mm²): they do not span a surface",
                            "give points spread over an area");
  }

  std::vector<Vector3d> centred(points.size());
  for (std::size_t i = 0; i < points.size(); ++i) centred[i] = points[i] - mean;

  // Initial parameters and the parameter box.
  std::vector<double> u(points.size()), v(points.size());
  ParamDomain box, data_box;
  Frame frame;
  nlohmann::json details = nlohmann::json::object();
  if (base == nullptr) {
    frame = PcaFrame(points, mean, axes);
    double u0 = std::numeric_limits<double>::infinity(), u1 = -u0, v0 = u0, v1 = -u0;
    for (std::size_t i = 0; i < points.size(); ++i) {
      u[i] = centred[i].dot(frame.u_axis);
      v[i] = centred[i].dot(frame.v_axis);
      u0 = std::min(u0, u[i]);
      u1 = std::max(u1, u[i]);
      v0 = std::min(v0, v[i]);
      v1 = std::max(v1, v[i]);
    }
    data_box = ParamDomain{u0, u1, v0, v1};
    details["parameterisation"] = "pca-plane";
    details["frame"] = {{"origin_mm", JsonVector(frame.origin)},
                        {"u_axis", JsonVector(frame.u_axis)},
                        {"v_axis", JsonVector(frame.v_axis)},
                        {"normal", JsonVector(frame.normal)}};
  } else {
    // Foot points on base, each Newton search started from the nearest node of a 65 × 65 sample.
    box = base->domain();
    data_box = box;
    constexpr int kSamples = 65;
    pcl::PointCloud<pcl::PointXYZ>::Ptr cloud(new pcl::PointCloud<pcl::PointXYZ>);
    std::vector<std::pair<double, double>> node_uv;
    for (int j = 0; j < kSamples; ++j) {
      for (int i = 0; i < kSamples; ++i) {
        const double su = box.u_min + box.u_span() * i / (kSamples - 1);
        const double sv = box.v_min + box.v_span() * j / (kSamples - 1);
        const Vector3d q = base->Point(su, sv) - mean;
        cloud->push_back(
            pcl::PointXYZ(static_cast<float>(q.x()), static_cast<float>(q.y()), static_cast<float>(q.z())));
        node_uv.emplace_back(su, sv);
      }
    }
    pcl::KdTreeFLANN<pcl::PointXYZ> tree;
    tree.setInputCloud(cloud);
    std::vector<int> nearest(1);
    std::vector<float> d2(1);
    FL_ASSIGN_OR_RETURN(const FootPointProjector base_projector,
                        FootPointProjector::Build(*base, ProjectorOptions{.seed_grid = 2}));
    for (std::size_t i = 0; i < points.size(); ++i) {
      const pcl::PointXYZ query(static_cast<float>(centred[i].x()), static_cast<float>(centred[i].y()),
                                static_cast<float>(centred[i].z()));
      tree.nearestKSearch(query, 1, nearest, d2);
      const auto [su, sv] = node_uv[static_cast<std::size_t>(nearest[0])];
      const Result<FootPoint> foot = base_projector.ProjectFrom(points[i], su, sv);
      u[i] = foot.ok() ? foot->u : su;
      v[i] = foot.ok() ? foot->v : sv;
    }
    details["parameterisation"] = "base-surface";
  }
  // Margin (PCA case): at least kMarginSpacings point spacings, the distance by which the points
  // typically miss the boundary of the sampled surface at a corner.
  const double min_margin = kMarginSpacings * std::sqrt(data_box.u_span() * data_box.v_span() / m);
  // Coverage (PCA case): the largest hole the initial parameters leave in their box (a corner, in
  // practice), in widths of a uniform span of the net over the data. Small: dense knots (see
  // DataKnots and kDenseGapSpans); otherwise wide end spans reaching over a margin.
  const bool margin = base == nullptr;
  const Gap initial_gap = margin ? LargestGap(u, v, data_box, min_margin / kMarginSpacings) : Gap{};
  auto plan_for = [&](int nu_net, int nv_net, double* gap_spans) {
    EdgePlan net_plan;
    if (!margin) return net_plan;
    const double span =
        std::min(data_box.u_span() / std::max(1, nu_net - p), data_box.v_span() / std::max(1, nv_net - p));
    *gap_spans = initial_gap.radius_mm / span;
    if (*gap_spans <= kDenseGapSpans) {
      net_plan = EdgePlan{false, 1, min_margin};
    } else {
      net_plan.margin_span = true;
    }
    return net_plan;
  };
  // Control net: given, or the best of a ladder of nets by GCV (scattered_fit.h, u_poles).
  int nu = options.u_poles, nv = options.v_poles;
  std::unique_ptr<TensorLsq> ladder_system;
  bool sparse_fallback = false;
  const bool ladder_net = options.smoothing == ScatteredFitOptions::Smoothing::kNone ||
                          options.smoothing == ScatteredFitOptions::Smoothing::kGcv;
  if (nu == 0 && !ladder_net) {
    // kTolerance and kFixed keep the point-count net: their energy, not the net, does the smoothing.
    const double target = std::max(1.0, static_cast<double>(m) / kScatteredPointsPerPole);
    const double aspect = data_box.u_span() / data_box.v_span();
    nu = std::clamp(static_cast<int>(std::lround(std::sqrt(target * aspect))), p + 1, kScatteredMaxAutoPoles);
    nv = std::clamp(static_cast<int>(std::lround(target / nu)), p + 1, kScatteredMaxAutoPoles);
    details["net"] = "points-per-pole";
  } else if (nu == 0) {
    // kNone and kGcv: the ladder's net (kGcv then chooses λ by GCV on it). Until 2026-11 kGcv kept the
    // point-count net; on the ladder's net, measured with 10,000 points and 5 µm noise (ScatteredFitNoise), the
    // band max fell on every reference surface (sphere_cap 7.90 -> 5.39 µm, cylinder 8.57 -> 5.76, ellipsoid_cap
    // 5.90 -> 4.22, egg_box 11.10 -> 10.60) and the truth RMS halved (1.24 -> 0.60, 1.55 -> 0.65, 0.97 -> 0.49,
    // 1.78 -> 1.38 µm), and with 100,000 points the fit is 25 × 25 instead of 112 × 112 (0.8 s instead of 19 s;
    // bench/fit_default_bench.cc). The interior improved more than the band, so band / interior rose above 2 there
    // (2.2-3.2): the test bounds the band's error against the noise as well (see there).
    // The finest rung: about m / kScatteredPointsPerPole poles, in the ratio of the data box's sides.
    const double target = std::max(1.0, static_cast<double>(m) / kScatteredPointsPerPole);
    const double aspect = data_box.u_span() / data_box.v_span();
    const int nu_max =
        std::clamp(static_cast<int>(std::lround(std::sqrt(target * aspect))), p + 1, kScatteredMaxAutoPoles);
    const int nv_max = std::clamp(static_cast<int>(std::lround(target / nu_max)), p + 1, kScatteredMaxAutoPoles);
    FL_ASSIGN_OR_RETURN(NetChoice net, ChooseNet(centred, u, v, p, nu_max, nv_max, [&](int a, int b) {
                          double gap_spans = 0;
                          const EdgePlan net_plan = plan_for(a, b, &gap_spans);
                          return std::make_pair(DataKnots(p, a, data_box.u_min, data_box.u_max, net_plan, min_margin),
                                                DataKnots(p, b, data_box.v_min, data_box.v_max, net_plan, min_margin));
                        }));
    details["net_ladder"] = net.ladder;
    double net_gap_spans = 0;
    if (plan_for(net.nu, net.nv, &net_gap_spans).margin_span) {
      // Sparse coverage at the chosen net (a hole wider than kDenseGapSpans of its spans): least squares
      // would extrapolate the holes and corners freely, so the thin-plate energy with GCV's weight takes
      // over on the point-count net, as before the ladder (measured with 10,000 points and 5 µm noise on
      // the reference surfaces: least squares on the ladder's net left 0.4-0.9 mm of error in corner
      // holes, ScatteredFitNoise).
      nu = nu_max;
      nv = nv_max;
      sparse_fallback = true;
      details["net"] = "points-per-pole";
    } else {
      nu = net.nu;
      nv = net.nv;
      ladder_system = std::move(net.assembled);
      details["net"] = "gcv-ladder";
    }
  } else {
    details["net"] = "given";
  }
  ScatteredFitOptions effective = options;  // kNone becomes kGcv on sparse coverage (see above)
  if (sparse_fallback && options.smoothing == ScatteredFitOptions::Smoothing::kNone) {
    effective.smoothing = ScatteredFitOptions::Smoothing::kGcv;
  }
  double gap_spans = 0;
  const EdgePlan plan = plan_for(nu, nv, &gap_spans);
  if (margin) {
    details["initial_gap_spans"] = gap_spans;
    details["edge_spans"] = plan.margin_span ? "margin" : "uniform";
  }
  const double end_width = plan.end_width;
  FL_ASSIGN_OR_RETURN(KnotVector ku, DataKnots(p, nu, data_box.u_min, data_box.u_max, plan, min_margin));
  FL_ASSIGN_OR_RETURN(KnotVector kv, DataKnots(p, nv, data_box.v_min, data_box.v_max, plan, min_margin));
  if (margin) box = ParamDomain{ku.lo(), ku.hi(), kv.lo(), kv.hi()};
  details["domain"] = {box.u_min, box.u_max, box.v_min, box.v_max};
  details["data_box"] = {data_box.u_min, data_box.u_max, data_box.v_min, data_box.v_max};

  // Fit, then refine where the residual exceeds the tolerance.
  double previous_log_lambda = std::numeric_limits<double>::quiet_NaN();
  std::vector<double> inserted_u, inserted_v;
  std::vector<std::string> notes;
  int refinements = 0;
  nlohmann::json rounds_per_fit = nlohmann::json::array();
  // Dense coverage (knots redistributed below): the uniform fit only places the knots and gives the refit its
  // start parameters (its foot points), and the refit corrects them itself, so the uniform fit is not corrected
  // (kTolerance excepted: its rounds also steer the target). Measured on issue 26's recipe
  // (bench/fit_default_bench.cc): one assembly, solve and projection of the 100,000 points fewer, 0.38 -> 0.32 s
  // CPU for the default, 0.23 -> 0.18 s at 24 × 24; truth RMS unchanged to 1 nm (0.410, 0.406 µm).
  ScatteredFitOptions uniform_options = effective;
  if (plan.rim > 0 && effective.smoothing != ScatteredFitOptions::Smoothing::kTolerance) {
    uniform_options.max_correction_iterations = 0;
  }
  FL_ASSIGN_OR_RETURN(CorrectedFit fit,
                      FitWithCorrection(points, centred, mean, ku, kv, data_box, u, v, uniform_options,
                                        &previous_log_lambda, std::move(ladder_system)));
  rounds_per_fit.push_back(fit.rounds);
  // Dense coverage: every span is well filled whatever its width, so the knots can follow the shape
  // rather than the data box. One redistribution (RedistributedKnots) from the uniform fit, then a
  // refit from its foot points. Sparse coverage keeps its knots: there each span has about
  // kScatteredPointsPerPole points a pole and the wide end spans carry the corners.
  const bool redistribute = plan.rim > 0;
  if (redistribute) {
    FL_ASSIGN_OR_RETURN(ku, RedistributedKnots(fit.surface, ku, kv, true));
    FL_ASSIGN_OR_RETURN(kv, RedistributedKnots(fit.surface, kv, ku, false));
    FL_ASSIGN_OR_RETURN(CorrectedFit refit, FitWithCorrection(points, centred, mean, ku, kv, data_box, fit.u, fit.v,
                                                              effective, &previous_log_lambda));
    rounds_per_fit.push_back(refit.rounds);
    fit = std::move(refit);
  }
  details["knots_redistributed"] = redistribute;
  auto max_distance = [](const CorrectedFit& f) {
    return *std::max_element(f.distance_mm.begin(), f.distance_mm.end());
  };
  while (options.adaptive && max_distance(fit) > options.tolerance_mm) {
    if (refinements == options.max_refinements) {
      notes.push_back("adaptive refinement stopped after " + std::to_string(refinements) +
                      " refinements (max_refinements) with a max orthogonal residual of " + Num(max_distance(fit)) +
                      " mm > tolerance_mm = " + Num(options.tolerance_mm) + " mm");
      break;
    }
    // Midpoints of the spans that hold an out-of-tolerance point.
    std::vector<char> mark_u(static_cast<std::size_t>(ku.n_poles()), 0),
        mark_v(static_cast<std::size_t>(kv.n_poles()), 0);
    for (int i = 0; i < m; ++i) {
      const std::size_t si = static_cast<std::size_t>(i);
      if (fit.distance_mm[si] <= options.tolerance_mm) continue;
      // A foot point in the margin marks the end span (its part over the data is refined).
      const double cu = std::clamp(fit.u[si], data_box.u_min, std::nextafter(data_box.u_max, data_box.u_min));
      const double cv = std::clamp(fit.v[si], data_box.v_min, std::nextafter(data_box.v_max, data_box.v_min));
      mark_u[static_cast<std::size_t>(ku.FindSpan(cu))] = 1;
      mark_v[static_cast<std::size_t>(kv.FindSpan(cv))] = 1;
    }
    // Interior spans are halved. An end span keeps its role (see DataKnots): its part over the data
    // is split so that it stays kEndSpanWidth times as wide as the new span next to it.
    auto midpoints = [end_width](const KnotVector& k, const std::vector<char>& mark, double a, double b) {
      std::vector<double> mids;
      const double end_share = end_width / (end_width + 1);
      for (std::size_t s = 0; s < mark.size(); ++s) {
        if (!mark[s]) continue;
        const double t0 = k.knots()[s], t1 = k.knots()[s + 1];
        const double lo = std::max(t0, a), hi = std::min(t1, b);  // the span's part over the data
        const bool first = t0 <= a, last = t1 >= b;
        if (first && !last && hi > lo) {
          mids.push_back(lo + end_share * (hi - lo));
        } else if (last && !first && hi > lo) {
          mids.push_back(hi - end_share * (hi - lo));
        } else {
          mids.push_back(0.5 * (t0 + t1));
        }
      }
      return mids;
    };
    const std::vector<double> add_u = midpoints(ku, mark_u, data_box.u_min, data_box.u_max);
    const std::vector<double> add_v = midpoints(kv, mark_v, data_box.v_min, data_box.v_max);
    const long next_unknowns =
        static_cast<long>(ku.n_poles() + add_u.size()) * static_cast<long>(kv.n_poles() + add_v.size());
    if (next_unknowns > m || ku.n_poles() + static_cast<int>(add_u.size()) > kMaxPoles ||
        kv.n_poles() + static_cast<int>(add_v.size()) > kMaxPoles) {
      notes.push_back("adaptive refinement stopped after " + std::to_string(refinements) +
                      " refinements: the next net (" + std::to_string(ku.n_poles() + add_u.size()) + " × " +
                      std::to_string(kv.n_poles() + add_v.size()) + " poles) would have more unknowns than the " +
                      std::to_string(m) + " points can determine; max orthogonal residual " + Num(max_distance(fit)) +
                      " mm > tolerance_mm = " + Num(options.tolerance_mm) + " mm");
      break;
    }
    FL_ASSIGN_OR_RETURN(ku, ku.Inserted(add_u));
    FL_ASSIGN_OR_RETURN(kv, kv.Inserted(add_v));
    inserted_u.insert(inserted_u.end(), add_u.begin(), add_u.end());
    inserted_v.insert(inserted_v.end(), add_v.begin(), add_v.end());
    ++refinements;
    FL_ASSIGN_OR_RETURN(CorrectedFit refined, FitWithCorrection(points, centred, mean, ku, kv, data_box, fit.u, fit.v,
                                                                effective, &previous_log_lambda));
    rounds_per_fit.push_back(refined.rounds);
    fit = std::move(refined);
  }

  // Coverage: where Q is extrapolated rather than fitted.
  const double spacing = std::sqrt(data_box.u_span() * data_box.v_span() / m);
  const Gap gap = LargestGap(fit.u, fit.v, data_box, spacing);

  // Report.
  FitReport local;
  local.method = options.adaptive ? "scattered-thin-plate-adaptive" : "scattered-thin-plate";
  local.n_points = m;
  local.residual =
      "orthogonal: distance from each input point to its foot point on Q (parameter-corrected least squares)";
  local.rms_mm = fit.rms_mm;
  std::size_t worst = 0;
  for (std::size_t i = 1; i < fit.distance_mm.size(); ++i) {
    if (fit.distance_mm[i] > fit.distance_mm[worst]) worst = i;
  }
  local.max_mm = fit.distance_mm[worst];
  local.max_at = points[worst];
  const char* smoothing_name = effective.smoothing == ScatteredFitOptions::Smoothing::kNone        ? "none"
                               : effective.smoothing == ScatteredFitOptions::Smoothing::kGcv       ? "gcv"
                               : effective.smoothing == ScatteredFitOptions::Smoothing::kTolerance ? "tolerance"
                                                                                                   : "fixed";
  details["degree"] = p;
  details["u_poles"] = ku.n_poles();
  details["v_poles"] = kv.n_poles();
  details["u_knots"] = DistinctKnotsJson(ku);
  details["v_knots"] = DistinctKnotsJson(kv);
  details["smoothing"] = smoothing_name;
  details["lambda"] = fit.trial.lambda;
  details["lambda_scale"] = fit.lambda_scale;
  details["gcv_score_mm2"] = fit.trial.gcv;
  details["effective_dof"] = fit.trial.trace;
  details["penalty_weight_min"] = fit.trial.min_weight;
  details["penalty_weight_mean"] = fit.trial.mean_weight;
  details["parametric_rms_mm"] = std::sqrt(fit.trial.rss / m);
  details["correction_iterations"] = fit.rounds;
  details["correction_iterations_per_fit"] = rounds_per_fit;
  details["rms_history_mm"] = fit.rms_history;
  details["refinements"] = refinements;
  details["knots_inserted_u"] = inserted_u;
  details["knots_inserted_v"] = inserted_v;
  details["boundary_feet"] = fit.boundary_feet;
  details["point_spacing_mm"] = spacing;
  details["largest_gap_mm"] = gap.radius_mm;
  details["largest_gap_at_uv"] = {gap.u, gap.v};
  details["failed_projections"] = fit.failed_projections;
  local.details = std::move(details);
  local.notes = std::move(notes);
  for (const std::string& note : fit.notes) local.notes.push_back(note);
  if (fit.failed_projections > 0) {
    local.notes.push_back(std::to_string(fit.failed_projections) +
                          " points could not be projected onto Q; their residual is the parametric distance");
  }
  if (fit.boundary_feet > 0) {
    local.notes.push_back(std::to_string(fit.boundary_feet) +
                          " points have their foot point on the edge of Q (they lie beyond it); their residual is the "
                          "distance to the edge");
  }
  if (gap.radius_mm > kGapSpacings * spacing) {
    local.notes.push_back("the points leave a gap of radius " + Num(gap.radius_mm, 3) + " mm (" +
                          Num(gap.radius_mm / spacing, 2) + " point spacings) around (u, v) = (" + Num(gap.u) + ", " +
                          Num(gap.v) + ") mm, point " + PointText(fit.surface.Point(gap.u, gap.v)) +
                          ": Q is extrapolated there and the residuals do not measure its error");
  }
  if (!options.adaptive && local.max_mm > options.tolerance_mm) {
    local.notes.push_back("max orthogonal residual " + Num(local.max_mm) + " mm exceeds tolerance_mm = " +
                          Num(options.tolerance_mm) + " mm (set adaptive to insert knots where it does)");
  }
  if (report != nullptr) *report = std::move(local);
  return std::move(fit.surface);
}

}  // namespace formloop::recon
