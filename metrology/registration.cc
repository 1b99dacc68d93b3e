#include "metrology/registration.h"

#include <cmath>
#include <sstream>
#include <string>
#include <vector>

#include <Eigen/Dense>

#include "core/number_text.h"

namespace formloop::metrology {
namespace {

Eigen::Matrix3d Skew(const Eigen::Vector3d& w) {
  Eigen::Matrix3d m;
  m << 0, -w.z(), w.y(), w.z(), 0, -w.x(), -w.y(), w.x(), 0;
  return m;
}

}  // namespace

Result<DofMask> ParseDofMask(const std::string& text, const std::string& field) {
  DofMask mask = {false, false, false, false, false, false};
  if (text.empty() || text == "none") return mask;
  if (text == "all") return DofMask{true, true, true, true, true, true};
  std::stringstream stream(text);
  std::string item;
  while (std::getline(stream, item, ',')) {
    bool found = false;
    for (int d = 0; d < 6; ++d) {
      if (item == kDofNames[d]) {
        mask[d] = true;
        found = true;
      }
    }
    if (!found) {
      return Status::BadInput(Where{.field = field}, "unknown degree of freedom '" + item + "'",
                              "list some of tx,ty,tz,rx,ry,rz separated by commas, or write all or none");
    }
  }
  return mask;
}

std::string DofMaskToString(const DofMask& mask) {
  std::string out;
  for (int d = 0; d < 6; ++d) {
    if (mask[d]) out += (out.empty() ? "" : ",") + std::string(kDofNames[d]);
  }
  return out.empty() ? "none" : out;
}

Status RegistrationOptions::Validate() const {
  if (max_iterations < 1) return Status::BadInput(Where{.field = "registration.max_iterations"}, "must be >= 1");
  if (!(max_distance_mm > 0)) {
    return Status::BadInput(Where{.field = "registration.max_distance_mm"}, "must be > 0");
  }
  return Status::Ok();
}

Eigen::Isometry3d RegistrationTransform(const std::array<double, 6>& values, const Eigen::Vector3d& pivot_mm) {
  const Eigen::Matrix3d R = (Eigen::AngleAxisd(values[kRz], Eigen::Vector3d::UnitZ()) *
                             Eigen::AngleAxisd(values[kRy], Eigen::Vector3d::UnitY()) *
                             Eigen::AngleAxisd(values[kRx], Eigen::Vector3d::UnitX()))
                                .toRotationMatrix();
  Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
  T.linear() = R;
  T.translation() = pivot_mm - R * pivot_mm + Eigen::Vector3d(values[kTx], values[kTy], values[kTz]);
  return T;
}

nlohmann::json RegistrationReport::ToJson() const {
  nlohmann::json v = nlohmann::json::object(), se = nlohmann::json::object();
  for (int d = 0; d < 6; ++d) {
    const std::string unit = d < 3 ? "_mm" : "_rad";
    v[std::string(kDofNames[d]) + unit] = values[d];
    se[std::string(kDofNames[d]) + unit] = standard_errors[d];
  }
  nlohmann::json matrix = nlohmann::json::array();
  for (int r = 0; r < 4; ++r) {
    matrix.push_back({part_from_machine.matrix()(r, 0), part_from_machine.matrix()(r, 1),
                      part_from_machine.matrix()(r, 2), part_from_machine.matrix()(r, 3)});
  }
  return {{"enabled", enabled},
          {"dofs", DofMaskToString(dofs)},
          {"pivot_mm", {pivot_mm.x(), pivot_mm.y(), pivot_mm.z()}},
          {"values", v},
          {"standard_errors", se},
          {"part_from_machine", matrix},
          {"points", points},
          {"iterations", iterations},
          {"rms_before_mm", rms_before_mm},
          {"rms_after_mm", rms_after_mm}};
}

Result<RegistrationReport> RegisterToSurface(const std::vector<Eigen::Vector3d>& points_mm,
                                             const recon::FootPointProjector& projector,
                                             const RegistrationOptions& options) {
  FL_RETURN_IF_ERROR(options.Validate());
  const int n = static_cast<int>(points_mm.size());
  RegistrationReport report;
  report.dofs = options.dofs;
  report.points = n;
  std::vector<int> free;
  for (int d = 0; d < 6; ++d) {
    if (options.dofs[d]) free.push_back(d);
  }
  const int p = static_cast<int>(free.size());
  if (n == 0) return Status::BadInput(Where{.field = "points"}, "no points to register");
  for (const auto& x : points_mm) report.pivot_mm += x;
  report.pivot_mm /= n;

  std::array<double, 6> values{};
  std::vector<recon::FootPoint> feet(n);
  // Residuals of the points moved by `v`, with their foot points; the first call checks the distances.
  auto residuals = [&](const std::array<double, 6>& v, bool check, Eigen::VectorXd* r) -> Status {
    const Eigen::Isometry3d T = RegistrationTransform(v, report.pivot_mm);
    r->resize(n);
    for (int i = 0; i < n; ++i) {
      FL_ASSIGN_OR_RETURN(feet[i], projector.Project(T * points_mm[i]));
      if (check && feet[i].distance_mm > options.max_distance_mm) {
        return Status::BadInput(Where{.field = "points[" + std::to_string(i) + "]"},
                                "the point is " + FormatFixed(feet[i].distance_mm, 4) +
                                    " mm from the surface, beyond the search distance of " +
                                    FormatFixed(options.max_distance_mm, 4) + " mm",
                                "remove points that missed the part, or check the frames of points and surface");
      }
      (*r)(i) = feet[i].deviation_mm;
    }
    return Status::Ok();
  };
  Eigen::VectorXd r;
  FL_RETURN_IF_ERROR(residuals(values, true, &r));
  report.rms_before_mm = std::sqrt(r.squaredNorm() / n);
  if (p == 0) {
    report.rms_after_mm = report.rms_before_mm;
    return report;
  }
  report.enabled = true;
  if (n <= p) {
    return Status::BadInput(Where{.field = "points"},
                            std::to_string(n) + " points cannot fix " + std::to_string(p) + " degrees of freedom",
                            "probe more points than free DOF");
  }
  double ssr = r.squaredNorm();
  Eigen::MatrixXd J(n, p);
  for (int iteration = 0; iteration < options.max_iterations; ++iteration) {
    report.iterations = iteration + 1;
    // Point-to-plane Jacobian at the current foot points: ∂r_i/∂v = n_iᵀ ∂x'_i/∂v.
    const Eigen::Matrix3d Rx = Eigen::AngleAxisd(values[kRx], Eigen::Vector3d::UnitX()).toRotationMatrix();
    const Eigen::Matrix3d Ry = Eigen::AngleAxisd(values[kRy], Eigen::Vector3d::UnitY()).toRotationMatrix();
    const Eigen::Matrix3d Rz = Eigen::AngleAxisd(values[kRz], Eigen::Vector3d::UnitZ()).toRotationMatrix();
    for (int i = 0; i < n; ++i) {
      const Eigen::Vector3d q = points_mm[i] - report.pivot_mm;
      const Eigen::Vector3d& normal = feet[i].normal;
      for (int c = 0; c < p; ++c) {
        Eigen::Vector3d dx;
        switch (free[c]) {
          case kTx:
            dx = Eigen::Vector3d::UnitX();
            break;
          case kTy:
            dx = Eigen::Vector3d::UnitY();
            break;
          case kTz:
            dx = Eigen::Vector3d::UnitZ();
            break;
          case kRx:
            dx = Rz * Ry * Rx * Skew(Eigen::Vector3d::UnitX()) * q;
            break;
          case kRy:
            dx = Rz * Ry * Skew(Eigen::Vector3d::UnitY()) * Rx * q;
            break;
          default:
            dx = Rz * Skew(Eigen::Vector3d::UnitZ()) * Ry * Rx * q;
            break;
        }
        J(i, c) = normal.dot(dx);
      }
    }
    Eigen::ColPivHouseholderQR<Eigen::MatrixXd> qr(J);
    qr.setThreshold(1e-9);
    if (qr.rank() < p) {
      std::string names;
      for (int c = static_cast<int>(qr.rank()); c < p; ++c) {
        names += (names.empty() ? "" : ", ") + std::string(kDofNames[free[qr.colsPermutation().indices()(c)]]);
      }
      return Status::BadInput(Where{.field = "--register"},
                              "the surface does not constrain " + names + " given the other free DOF",
                              "leave " + names + " out of the DOF mask");
    }
    const Eigen::VectorXd step = qr.solve(-r);
    double scale = 1.0;
    std::array<double, 6> trial_values = values;
    Eigen::VectorXd trial_r;
    for (int halvings = 0; halvings < 30; ++halvings, scale *= 0.5) {
      trial_values = values;
      for (int c = 0; c < p; ++c) trial_values[free[c]] += scale * step(c);
      FL_RETURN_IF_ERROR(residuals(trial_values, false, &trial_r));
      if (trial_r.squaredNorm() <= ssr) break;
    }
    values = trial_values;
    r = trial_r;
    ssr = r.squaredNorm();
    if (scale * step.norm() < 1e-10) break;
  }
  // Standard errors from the last Jacobian: σ̂² (JᵀJ)⁻¹.
  const double sigma2 = ssr / (n - p);
  const Eigen::MatrixXd cov = sigma2 * (J.transpose() * J).ldlt().solve(Eigen::MatrixXd::Identity(p, p));
  for (int c = 0; c < p; ++c) report.standard_errors[free[c]] = std::sqrt(std::max(0.0, cov(c, c)));
  report.values = values;
  report.part_from_machine = RegistrationTransform(values, report.pivot_mm);
  report.rms_after_mm = std::sqrt(ssr / n);
  return report;
}

}  // namespace formloop::metrology
