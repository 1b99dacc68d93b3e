#include "metrology/probe_calibration.h"

#include <algorithm>
#include <cmath>
#include <numbers>
#include <string>
#include <utility>
#include <vector>

#include <Eigen/Dense>

#include "core/log.h"
#include "core/number_text.h"
#include "core/random.h"

namespace formloop::metrology {
namespace {

// One fitted lobing unknown: coefficient of sin^j φ · cos kθ (is_sine = false) or sin kθ.
struct Basis {
  int k = 0, j = 0;
  bool is_sine = false;
  std::string Name() const {
    return std::string(is_sine ? "b" : "a") + "_" + std::to_string(k) + std::to_string(j) +
           (is_sine ? " (sin " : " (cos ") + std::to_string(k) + "θ·sin^" + std::to_string(j) + " φ)";
  }
  double Value(const ProbingAngles& angles) const {
    if (k > 0 && angles.at_pole) return 0.0;
    const double g = std::pow(std::sin(angles.elevation_rad), j);
    return g * (is_sine ? std::sin(k * angles.azimuth_rad) : std::cos(k * angles.azimuth_rad));
  }
};

// Distinct values of xs (sorted, gaps > tolerance start a new group).
int CountLevels(std::vector<double> xs, double tolerance) {
  if (xs.empty()) return 0;
  std::sort(xs.begin(), xs.end());
  int levels = 1;
  for (std::size_t i = 1; i < xs.size(); ++i) {
    if (xs[i] - xs[i - 1] > tolerance) ++levels;
  }
  return levels;
}

std::string Join(const std::vector<std::string>& parts) {
  std::string out;
  for (const auto& p : parts) out += (out.empty() ? "" : ", ") + p;
  return out;
}

}  // namespace

Status SphereCalibrationOptions::Validate() const {
  if (!(sphere_radius_mm > 0)) {
    return Status::BadInput(Where{.field = "--radius"}, "the certified sphere radius must be > 0",
                            "give the radius of the standard sphere from its certificate, mm");
  }
  if (!(ball_radius_mm > 0)) {
    return Status::BadInput(Where{.field = "--ball"}, "the nominal stylus-ball radius must be > 0",
                            "give the nominal ball radius, mm");
  }
  if (max_order < 0 || max_order > PretravelLobing::kMaxOrder) {
    return Status::BadInput(Where{.field = "--lobes"}, "must be in 0..3, got " + std::to_string(max_order));
  }
  if (elevation_degree < 0 || elevation_degree > PretravelLobing::kMaxElevationDegree) {
    return Status::BadInput(Where{.field = "--elevation-degree"},
                            "must be in 0..3, got " + std::to_string(elevation_degree));
  }
  if (!(same_elevation_tolerance > 0 && same_elevation_tolerance < 0.5)) {
    return Status::BadInput(Where{.field = "same_elevation_tolerance"}, "must be in (0, 0.5)");
  }
  if (max_iterations < 1) return Status::BadInput(Where{.field = "max_iterations"}, "must be >= 1");
  if (!(amplitude_target_relative > 0 && amplitude_target_relative <= 1)) {
    return Status::BadInput(Where{.field = "amplitude_target_relative"}, "must be in (0, 1]");
  }
  return Status::Ok();
}

nlohmann::json SphereFit::ToJson() const {
  return {{"centre_mm", {centre_mm.x(), centre_mm.y(), centre_mm.z()}},
          {"radius_mm", radius_mm},
          {"diameter_mm", 2 * radius_mm},
          {"form_error_mm", form_error_mm},
          {"rms_mm", rms_mm}};
}

Result<SphereFit> FitSphere(const std::vector<Eigen::Vector3d>& points_mm) {
  const int n = static_cast<int>(points_mm.size());
  if (n < 4) {
    return Status::BadInput(Where{.field = "points"}, "a sphere fit needs at least 4 points, got " + std::to_string(n));
  }
  // Algebraic start (‖p‖² = 2 p·S + k, linear in S and k), around the centroid for conditioning.
  Eigen::Vector3d mean = Eigen::Vector3d::Zero();
  for (const auto& p : points_mm) mean += p;
  mean /= n;
  Eigen::MatrixXd A(n, 4);
  Eigen::VectorXd b(n);
  for (int i = 0; i < n; ++i) {
    const Eigen::Vector3d q = points_mm[i] - mean;
    A.row(i) << 2 * q.x(), 2 * q.y(), 2 * q.z(), 1.0;
    b(i) = q.squaredNorm();
  }
  Eigen::ColPivHouseholderQR<Eigen::MatrixXd> qr(A);
  if (qr.rank() < 4) {
    return Status::BadInput(Where{.field = "points"}, "the points lie on a plane or a line; no sphere is defined");
  }
  const Eigen::Vector4d x0 = qr.solve(b);
  Eigen::Vector3d centre = x0.head<3>();
  double radius = std::sqrt(std::max(0.0, x0(3) + centre.squaredNorm()));
  // Geometric refinement: Gauss-Newton on r_i = ‖q_i − S‖ − ρ.
  Eigen::VectorXd r(n);
  Eigen::MatrixXd J(n, 4);
  for (int iteration = 0; iteration < 50; ++iteration) {
    for (int i = 0; i < n; ++i) {
      const Eigen::Vector3d d = points_mm[i] - mean - centre;
      const double dn = d.norm();
      r(i) = dn - radius;
      J.row(i) << -(d / dn).transpose(), -1.0;
    }
    const Eigen::Vector4d step = J.colPivHouseholderQr().solve(-r);
    centre += step.head<3>();
    radius += step(3);
    if (step.norm() < 1e-13 * (1 + radius)) break;
  }
  SphereFit fit;
  fit.centre_mm = centre + mean;
  fit.radius_mm = radius;
  double lo = 1e300, hi = -1e300, ss = 0;
  for (const auto& p : points_mm) {
    const double e = (p - fit.centre_mm).norm() - radius;
    lo = std::min(lo, e);
    hi = std::max(hi, e);
    ss += e * e;
  }
  fit.form_error_mm = hi - lo;
  fit.rms_mm = std::sqrt(ss / n);
  return fit;
}

Result<SphereCalibrationReport> CalibrateOnSphere(const ProbeLog& log, const SphereCalibrationOptions& options) {
  FL_RETURN_IF_ERROR(options.Validate());
  const std::string& file = log.source;
  const int n = static_cast<int>(log.records.size());
  SphereCalibrationReport report;
  report.certified_radius_mm = options.sphere_radius_mm;
  auto warn = [&](const std::string& text) {
    log::Warn("calibrate sphere: {}", text);
    report.warnings.push_back(text);
  };
  if (n < 25) {
    warn("ISO 10360-5 asks for 25 points on the sphere, the log has " + std::to_string(n) +
         "; the form and size errors are not comparable with an ISO test");
  }

  // Elevations present: those of the non-pole points identify the k ≥ 2 terms; the pole adds one for k = 0.
  std::vector<ProbingAngles> angles(n);
  std::vector<double> ring_levels;
  bool has_pole = false;
  for (int i = 0; i < n; ++i) {
    angles[i] = AnglesOfApproach(log.records[i].approach);
    if (angles[i].at_pole) {
      has_pole = true;
    } else {
      ring_levels.push_back(std::sin(angles[i].elevation_rad));
    }
  }
  const int levels = CountLevels(ring_levels, options.same_elevation_tolerance);
  if (levels == 0 && n > 0) {
    return Status::BadInput(Where{.file = file, .field = "ax,ay,az"},
                            "every point was probed vertically at the pole; the sphere centre is not defined",
                            "probe the sphere at several elevations (ISO 10360-5: the pole and rings at 0°, "
                            "22.5°, 45° and 67.5°)");
  }
  if (levels + (has_pole ? 1 : 0) < 2) {
    return Status::BadInput(Where{.file = file, .field = "ax,ay,az"},
                            "every point was probed at one elevation and none at the pole: a shift of the sphere "
                            "centre's z moves all ball centres radially alike, exactly as R_eff does, so centre z "
                            "and R_eff cannot be told apart",
                            "add the pole (a vertical touch from above) or a second ring at another elevation");
  }
  int degree = std::min(options.elevation_degree, std::max(0, levels - 1));
  if (degree < options.elevation_degree) {
    warn("the points lie at " + std::to_string(levels) +
         " elevation(s) (not counting the pole), which identify g_k(φ) " + "only up to degree " +
         std::to_string(degree) + " in sin φ; the elevation terms of degree " + std::to_string(degree + 1) + ".." +
         std::to_string(options.elevation_degree) + " were dropped (probe rings at more elevations to fit them)");
  }
  const int degree_k0 = std::min(options.elevation_degree, std::max(0, levels + (has_pole ? 1 : 0) - 1));
  report.elevation_degree_used = degree;

  std::vector<Basis> basis;
  for (int j = 2; j <= degree_k0; ++j) basis.push_back({0, j, false});
  for (int k = 2; k <= options.max_order; ++k) {
    for (int j = 0; j <= degree; ++j) {
      basis.push_back({k, j, false});
      basis.push_back({k, j, true});
    }
  }
  const int p = 4 + static_cast<int>(basis.size());
  report.points = n;
  report.parameters = p;
  if (n < p + 1) {
    return Status::BadInput(Where{.file = file},
                            "the log has " + std::to_string(n) + " points; the lobing model (--lobes " +
                                std::to_string(options.max_order) + ", elevation degree " + std::to_string(degree) +
                                ") has " + std::to_string(p) + " unknowns and needs at least " + std::to_string(p + 1),
                            "probe at least 25 points (ISO 10360-5), or lower --lobes / --elevation-degree");
  }

  // Start: algebraic sphere through the ball centres (radius R_s + R_eff,0), lobing zero.
  std::vector<Eigen::Vector3d> centres(n);
  for (int i = 0; i < n; ++i) centres[i] = log.records[i].centre;
  Result<SphereFit> start = FitSphere(centres);
  if (!start.ok()) return Status::BadInput(Where{.file = file}, start.status().message());
  Eigen::VectorXd x = Eigen::VectorXd::Zero(p);
  x.head<3>() = start->centre_mm;
  x(3) = start->radius_mm - options.sphere_radius_mm;

  Eigen::MatrixXd basis_values(n, basis.size());
  for (int i = 0; i < n; ++i) {
    for (std::size_t t = 0; t < basis.size(); ++t) basis_values(i, t) = basis[t].Value(angles[i]);
  }
  Eigen::VectorXd r(n);
  Eigen::MatrixXd J(n, p);
  auto parameter_name = [&](int col) {
    return col < 3 ? std::string("centre ") + "xyz"[col] : col == 3 ? std::string("R_eff") : basis[col - 4].Name();
  };
  // Rank of the Jacobian with columns scaled to unit norm; a column that is zero (to rounding: the basis
  // values are O(1), so 1e-8·√n) is not identified at all. Sets the condition number.
  auto check_identifiable = [&](const Eigen::MatrixXd& jacobian) -> Status {
    Eigen::MatrixXd scaled = jacobian;
    std::vector<std::string> names;
    for (int c = 0; c < p; ++c) {
      const double norm = jacobian.col(c).norm();
      if (norm < 1e-8 * std::sqrt(static_cast<double>(n))) {
        names.push_back(parameter_name(c));
        scaled.col(c).setZero();
      } else {
        scaled.col(c) /= norm;
      }
    }
    if (names.empty()) {
      Eigen::ColPivHouseholderQR<Eigen::MatrixXd> qr(scaled);
      qr.setThreshold(1e-9);
      const auto& perm = qr.colsPermutation().indices();
      for (int c = static_cast<int>(qr.rank()); c < p; ++c) names.push_back(parameter_name(perm(c)));
    }
    if (!names.empty()) {
      return Status::BadInput(
          Where{.file = file},
          "the points do not identify the model: " + Join(names) + " cannot be told apart from the other unknowns",
          "probe the pole and rings at several elevations with at least 2·K + 1 azimuths each "
          "(ISO 10360-5 pattern), or lower --lobes / --elevation-degree");
    }
    Eigen::JacobiSVD<Eigen::MatrixXd> svd(scaled);
    const Eigen::VectorXd sv = svd.singularValues();
    report.condition_number = sv(0) / std::max(sv(p - 1), 1e-300);
    return Status::Ok();
  };
  auto evaluate = [&](const Eigen::VectorXd& params, bool with_jacobian) {
    const Eigen::Vector3d S = params.head<3>();
    for (int i = 0; i < n; ++i) {
      const Eigen::Vector3d d = centres[i] - S;
      const double dn = d.norm();
      double lobing = 0;
      for (std::size_t t = 0; t < basis.size(); ++t) lobing += params(4 + t) * basis_values(i, t);
      r(i) = dn - options.sphere_radius_mm - params(3) + lobing;
      if (with_jacobian) {
        J.block<1, 3>(i, 0) = -(d / dn).transpose();
        J(i, 3) = -1.0;
        J.block(i, 4, 1, basis.size()) = basis_values.row(i);
      }
    }
    return r.squaredNorm();
  };
  double ssr = evaluate(x, true);
  FL_RETURN_IF_ERROR(check_identifiable(J));  // at the start: before a singular step can run away
  int iteration = 0;
  for (; iteration < options.max_iterations; ++iteration) {
    const Eigen::VectorXd step = J.colPivHouseholderQr().solve(-r);
    double scale = 1.0;
    double trial = 0;
    for (int halvings = 0; halvings < 30; ++halvings, scale *= 0.5) {
      trial = evaluate(x + scale * step, false);
      if (trial <= ssr) break;
    }
    x += scale * step;
    ssr = evaluate(x, true);
    if (scale * step.norm() < 1e-12) {
      ++iteration;
      break;
    }
  }
  report.iterations = iteration;

  FL_RETURN_IF_ERROR(check_identifiable(J));  // and at the solution
  if (report.condition_number > 1e4) {
    warn("the fit is ill-conditioned (condition number " + FormatFixed(report.condition_number, 0) +
         "): the coefficients' standard errors are large; spread the points more evenly over the hemisphere");
  }

  const double dof = n - p;
  report.sigma_mm = std::sqrt(ssr / dof);
  report.residual_rms_mm = std::sqrt(ssr / n);
  const Eigen::MatrixXd JtJ = J.transpose() * J;
  const Eigen::MatrixXd cov = report.sigma_mm * report.sigma_mm * JtJ.ldlt().solve(Eigen::MatrixXd::Identity(p, p));
  auto se = [&](int c) { return std::sqrt(std::max(0.0, cov(c, c))); };
  report.centre_mm = x.head<3>();
  report.centre_se_mm = Eigen::Vector3d(se(0), se(1), se(2));
  report.effective_radius_mm = x(3);
  report.effective_radius_se_mm = se(3);
  report.residuals_mm.assign(r.data(), r.data() + n);
  report.form_error_mm = r.maxCoeff() - r.minCoeff();

  // The model assumes touches along the sphere normal. A direction off the normal by α shifts the ball
  // centre tangentially and the fit cannot see it: beyond kMaxOffNormalDeg that is an error naming the
  // row, beyond kWarnOffNormalDeg a warning. Residuals beyond 5 robust σ are named too (a bad touch, dirt).
  // Robust scale for the outlier check (1.4826 · median |r − median r|): σ̂ itself is inflated by the
  // outliers it should find.
  std::vector<double> sorted(r.data(), r.data() + n);
  std::nth_element(sorted.begin(), sorted.begin() + n / 2, sorted.end());
  const double median = sorted[n / 2];
  for (double& v : sorted) v = std::abs(v - median);
  std::nth_element(sorted.begin(), sorted.begin() + n / 2, sorted.end());
  const double robust_sigma_mm = 1.4826 * sorted[n / 2];
  constexpr double kMaxOffNormalDeg = 10.0, kWarnOffNormalDeg = 1.0;
  std::vector<std::string> off_normal, outliers;
  for (int i = 0; i < n; ++i) {
    const ProbeRecord& rec = log.records[i];
    const Eigen::Vector3d normal = (rec.centre - x.head<3>()).normalized();
    const double off_deg = std::acos(std::clamp(-rec.approach.dot(normal), -1.0, 1.0)) * 180 / std::numbers::pi;
    const std::string label =
        "id " + std::to_string(rec.id) + (rec.line > 0 ? " (line " + std::to_string(rec.line) + ")" : "");
    if (off_deg > kMaxOffNormalDeg) {
      return Status::BadInput(Where{.file = file, .line = rec.line, .field = "ax,ay,az"},
                              "the approach of id " + std::to_string(rec.id) + " is " + FormatFixed(off_deg, 1) +
                                  "° off the sphere normal; the calibration needs touches along the normal",
                              "probe the sphere along its normals (approach = centre − point direction), or "
                              "remove the row");
    }
    if (off_deg > kWarnOffNormalDeg) off_normal.push_back(label + ": " + FormatFixed(off_deg, 2) + "°");
    if (std::abs(r(i) - median) > 5 * std::max(robust_sigma_mm, 1e-5)) {  // never below 50 nm
      outliers.push_back(label + ": " + FormatFixed(r(i) * 1e3, 2) + " µm");
    }
  }
  if (!off_normal.empty()) {
    warn("approach directions more than 1° off the sphere normal (the model assumes touches along it): " +
         Join(off_normal));
  }
  if (!outliers.empty()) {
    warn("residuals beyond 5 robust sigma (" + FormatFixed(robust_sigma_mm * 1e3, 2) +
         " µm), check these touches: " + Join(outliers));
  }

  // The profile: δ(a) = R_nom − R_eff(a) = (R_nom − R_eff,0) + lobing(a).
  ProbeModel& profile = report.profile;
  profile.ball_radius_mm = options.ball_radius_mm;
  profile.pretravel_mm = options.ball_radius_mm - x(3);
  profile.lobing = PretravelLobing::Zero(options.max_order, std::max(degree, degree_k0));
  for (std::size_t t = 0; t < basis.size(); ++t) {
    const Basis& b = basis[t];
    (b.is_sine ? profile.lobing.sin_mm : profile.lobing.cos_mm)(b.k, b.j) = x(4 + t);
    auto it = std::find_if(report.terms.begin(), report.terms.end(),
                           [&](const FittedLobingTerm& f) { return f.k == b.k && f.j == b.j; });
    if (it == report.terms.end()) {
      report.terms.push_back({.k = b.k, .j = b.j});
      it = std::prev(report.terms.end());
    }
    (b.is_sine ? it->sin_mm : it->cos_mm) = x(4 + t);
    (b.is_sine ? it->sin_se_mm : it->cos_se_mm) = se(4 + static_cast<int>(t));
  }
  for (FittedLobingTerm& t : report.terms) {
    if (t.k == 0) continue;
    t.amplitude_mm = std::hypot(t.cos_mm, t.sin_mm);
    if (t.amplitude_mm > 0) {
      t.amplitude_se_mm = std::hypot(t.cos_mm * t.cos_se_mm, t.sin_mm * t.sin_se_mm) / t.amplitude_mm;
    }
    const double target_mm = options.amplitude_target_relative * t.amplitude_mm;
    if (t.j != 0 || !(t.amplitude_mm > 3 * t.amplitude_se_mm) || 2 * t.amplitude_se_mm <= target_mm) continue;
    const double ratio = 2 * t.amplitude_se_mm / target_mm;
    t.points_for_target = 1 + static_cast<int>(std::ceil((n - 1) * ratio * ratio));
    warn("the k = " + std::to_string(t.k) + " lobing amplitude " + FormatFixed(t.amplitude_mm * 1e3, 2) +
         " µm is known to ±" + FormatFixed(2 * t.amplitude_se_mm * 1e3, 2) + " µm (k = 2), " +
         FormatFixed(200 * t.amplitude_se_mm / t.amplitude_mm, 0) + " % of it; for ±" +
         FormatFixed(100 * options.amplitude_target_relative, 0) + " % probe about " +
         std::to_string(t.points_for_target) + " points (or repeat the pattern)");
  }
  Status valid = profile.Validate();
  if (!valid.ok()) {
    return Status::BadInput(Where{.file = file}, "the calibrated pretravel is not plausible: " + valid.message(),
                            "check --ball and --radius (mm) and that the log probes the sphere along its normals");
  }

  // ISO 10360-5 evaluation, nominal ball and calibrated profile.
  ProbeModel nominal;
  nominal.ball_radius_mm = options.ball_radius_mm;
  std::vector<Eigen::Vector3d> contact_nominal(n), contact_compensated(n);
  for (int i = 0; i < n; ++i) {
    contact_nominal[i] = ContactPoint(log.records[i], nominal);
    contact_compensated[i] = ContactPoint(log.records[i], profile);
  }
  FL_ASSIGN_OR_RETURN(report.iso_nominal, FitSphere(contact_nominal));
  FL_ASSIGN_OR_RETURN(report.iso_compensated, FitSphere(contact_compensated));
  report.iso_nominal_size_error_mm = 2 * (report.iso_nominal.radius_mm - options.sphere_radius_mm);
  report.iso_compensated_size_error_mm = 2 * (report.iso_compensated.radius_mm - options.sphere_radius_mm);
  return report;
}

nlohmann::json SphereCalibrationReport::ToJson() const {
  nlohmann::json terms_json = nlohmann::json::array();
  for (const FittedLobingTerm& t : terms) {
    nlohmann::json term = {{"k", t.k}, {"j", t.j}, {"cos_mm", t.cos_mm}, {"cos_se_mm", t.cos_se_mm}};
    if (t.k > 0) {
      term["sin_mm"] = t.sin_mm;
      term["sin_se_mm"] = t.sin_se_mm;
      term["amplitude_mm"] = t.amplitude_mm;
      term["amplitude_se_mm"] = t.amplitude_se_mm;
      if (t.points_for_target > 0) term["points_for_target"] = t.points_for_target;
    }
    terms_json.push_back(term);
  }
  const nlohmann::json not_fitted = nlohmann::json::array(
      {{{"k", 0}, {"j", 0}, {"reason", "is the constant effective radius R_eff,0"}},
       {{"k", 0}, {"j", 1}, {"reason", "sin(phi) moves the ball centres like the sphere centre's z"}},
       {{"k", 1}, {"reason", "cos/sin(theta) move the ball centres like the sphere centre's x and y"}}});
  return {{"standard", "ISO 10360-5 probing error on a reference sphere (form P_form and size)"},
          {"points", points},
          {"parameters", parameters},
          {"iterations", iterations},
          {"certified_diameter_mm", 2 * certified_radius_mm},
          {"iso_nominal_ball",
           {{"sphere", iso_nominal.ToJson()},
            {"probing_form_error_mm", iso_nominal.form_error_mm},
            {"size_error_mm", iso_nominal_size_error_mm}}},
          {"iso_compensated",
           {{"sphere", iso_compensated.ToJson()},
            {"probing_form_error_mm", iso_compensated.form_error_mm},
            {"size_error_mm", iso_compensated_size_error_mm}}},
          {"fit",
           {{"centre_mm", {centre_mm.x(), centre_mm.y(), centre_mm.z()}},
            {"centre_se_mm", {centre_se_mm.x(), centre_se_mm.y(), centre_se_mm.z()}},
            {"effective_radius_mm", effective_radius_mm},
            {"effective_radius_se_mm", effective_radius_se_mm},
            {"pretravel_mm", profile.pretravel_mm},
            {"elevation_degree_used", elevation_degree_used},
            {"terms", terms_json},
            {"not_fitted", not_fitted},
            {"residual_rms_mm", residual_rms_mm},
            {"sigma_mm", sigma_mm},
            {"form_error_mm", form_error_mm},
            {"condition_number", condition_number}}},
          {"warnings", warnings}};
}

PretravelLobing TriLobe(double amplitude_mm, double phase_rad) {
  PretravelLobing lobing = PretravelLobing::Zero(3, 0);
  lobing.cos_mm(3, 0) = amplitude_mm * std::cos(phase_rad);
  lobing.sin_mm(3, 0) = amplitude_mm * std::sin(phase_rad);
  return lobing;
}

Status SphereLogOptions::Validate() const {
  if (points < 5 || points > 10000) {
    return Status::BadInput(Where{.field = "--points"}, "must be in 5..10000, got " + std::to_string(points));
  }
  if (!(sphere_radius_mm > 0)) return Status::BadInput(Where{.field = "--radius"}, "must be > 0");
  if (!(noise_um >= 0)) return Status::BadInput(Where{.field = "--noise-um"}, "must be >= 0");
  if (!centre_mm.allFinite()) return Status::BadInput(Where{.field = "centre_mm"}, "must be finite");
  FL_RETURN_IF_ERROR(probe.Validate());
  if (elevations_deg.empty()) return Status::BadInput(Where{.field = "elevations_deg"}, "needs at least one ring");
  for (double e : elevations_deg) {
    if (!(e >= -30 && e < 90)) {
      return Status::BadInput(Where{.field = "elevations_deg"}, "ring elevations must be in [-30°, 90°)");
    }
  }
  if (!ring_weights.empty()) {
    if (ring_weights.size() != elevations_deg.size()) {
      return Status::BadInput(Where{.field = "ring_weights"}, "needs one weight per elevation (or none)");
    }
    for (double w : ring_weights) {
      if (!(w > 0)) return Status::BadInput(Where{.field = "ring_weights"}, "weights must be > 0");
    }
  }
  return Status::Ok();
}

Result<ProbeLog> GenerateSphereProbeLog(const SphereLogOptions& options) {
  FL_RETURN_IF_ERROR(options.Validate());
  const int rings = static_cast<int>(options.elevations_deg.size());
  const int on_rings = options.points - (options.pole ? 1 : 0);
  std::vector<double> weights = options.ring_weights;
  if (weights.empty()) weights.assign(rings, 1.0);
  double total = 0;
  for (double w : weights) total += w;
  // Largest remainder; ties go to the earlier ring.
  std::vector<int> counts(rings);
  std::vector<std::pair<double, int>> remainders;
  int assigned = 0;
  for (int g = 0; g < rings; ++g) {
    const double share = on_rings * weights[g] / total;
    counts[g] = static_cast<int>(std::floor(share));
    assigned += counts[g];
    remainders.emplace_back(share - counts[g], g);
  }
  std::stable_sort(remainders.begin(), remainders.end(),
                   [](const auto& a, const auto& b) { return a.first > b.first; });
  for (int e = 0; e < on_rings - assigned; ++e) ++counts[remainders[e % rings].second];

  std::vector<Eigen::Vector3d> normals;
  if (options.pole) normals.push_back(Eigen::Vector3d::UnitZ());
  constexpr double kPi = std::numbers::pi;
  for (int g = rings - 1; g >= 0; --g) {  // from the top down, as a probing cycle would go
    const int m = counts[g];
    const double elevation = options.elevations_deg[g] * kPi / 180.0;
    const double offset = (g % 2 == 1 && m > 0) ? kPi / m : 0.0;
    for (int i = 0; i < m; ++i) {
      const double theta = offset + 2 * kPi * i / m;
      normals.emplace_back(std::cos(elevation) * std::cos(theta), std::cos(elevation) * std::sin(theta),
                           std::sin(elevation));
    }
  }
  Rng rng(options.seed);
  ProbeLog log;
  for (std::size_t i = 0; i < normals.size(); ++i) {
    const Eigen::Vector3d n = normals[i].normalized();
    ProbeRecord r;
    r.id = static_cast<std::int64_t>(i) + 1;
    r.approach = -n;
    const double noise_mm = options.noise_um * 1e-3 * rng.Normal();
    r.centre =
        options.centre_mm + (options.sphere_radius_mm + options.probe.EffectiveRadius(r.approach) + noise_mm) * n;
    r.t_s = 2.0 * static_cast<double>(i);
    log.records.push_back(r);
  }
  return log;
}

}  // namespace formloop::metrology
