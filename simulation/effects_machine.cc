// Machine effects: thermal_drift_z, axis_scale_x/y/z, squareness_xy/yz/zx, backlash_x/y
// (spec/simulation.md §3). Displacements are of the tool relative to the part, µm; δ = D·n.

#include <cmath>
#include <string>

#include "simulation/effects_catalogue.h"

namespace formloop::sim {
namespace {

constexpr const char* kAxis[] = {"x", "y", "z"};

// Spindle growth: the tool moves down (−z) by A (1 − exp(−t/τ)) as the spindle warms over cutting
// time; material is removed where the normal points up, δ = −A (1 − e^(−t/τ)) n_z.
class ThermalDriftZ final : public Effect {
 public:
  std::string_view name() const override { return "thermal_drift_z"; }
  std::string_view physics() const override { return "spindle growth along z over cutting time"; }
  std::string_view basis() const override { return "-A * (1 - exp(-t_cut / tau)) * n_z"; }
  bool uses_toolpath() const override { return true; }
  const std::vector<EffectParameter>& parameters() const override {
    static const std::vector<EffectParameter> p = {
        {"A_um", "saturated growth, um", true, 0, 20},
        {"tau_s", "thermal time constant, s (a nonlinear parameter)", false, 60, 3600}};
    return p;
  }
  double DeviationUm(const PointContext& c, std::span<const double> theta) const override {
    const double tau = theta[1];
    if (!(tau > 0)) return 0.0;
    return -theta[0] * (1.0 - std::exp(-c.cut_time_s / tau)) * c.normal.z();
  }
  void Jacobian(const PointContext& c, std::span<const double> theta, std::span<double> j) const override {
    const double tau = theta[1];
    if (!(tau > 0)) {
      j[0] = j[1] = 0;
      return;
    }
    const double e = std::exp(-c.cut_time_s / tau);
    j[0] = -(1.0 - e) * c.normal.z();
    j[1] = theta[0] * e * (c.cut_time_s / (tau * tau)) * c.normal.z();
  }
};

// Positioning scale error e (µm/m = ppm) on one axis: D_axis = e · coordinate.
class AxisScale final : public Effect {
 public:
  explicit AxisScale(int axis)
      : axis_(axis),
        name_(std::string("axis_scale_") + kAxis[axis]),
        basis_(std::string("e * ") + kAxis[axis] + " * n_" + kAxis[axis] + " (e in um/m, coordinates in m)"),
        params_{{std::string("e_") + kAxis[axis] + "_um_per_m",
                 std::string("scale error of the ") + kAxis[axis] + " axis, um/m (ppm)", true, -50, 50}} {}
  std::string_view name() const override { return name_; }
  std::string_view physics() const override { return "the axis positions with a scale error"; }
  std::string_view basis() const override { return basis_; }
  const std::vector<EffectParameter>& parameters() const override { return params_; }
  void Jacobian(const PointContext& c, std::span<const double>, std::span<double> j) const override {
    j[0] = c.point[axis_] * 1e-3 * c.normal[axis_];
  }
  bool acts_on_positions() const override { return true; }
  Eigen::Vector3d DisplacementUm(const Eigen::Vector3d& p, std::span<const double> theta) const override {
    Eigen::Vector3d d = Eigen::Vector3d::Zero();
    d[axis_] = theta[0] * p[axis_] * 1e-3;
    return d;
  }

 private:
  int axis_;
  std::string name_, basis_;
  std::vector<EffectParameter> params_;
};

// Out-of-squareness S (µrad) between two axes: moving the second axis displaces the first.
//   squareness_xy: D_x = S · y   (x and y not at 90°)
//   squareness_yz: D_y = S · z   (z tilted in the yz plane)
//   squareness_zx: D_x = S · z   (z tilted in the zx plane)
class Squareness final : public Effect {
 public:
  explicit Squareness(int pair) : pair_(pair) {
    static constexpr const char* kNames[] = {"squareness_xy", "squareness_yz", "squareness_zx"};
    static constexpr const char* kBasis[] = {"S * y * n_x (S in urad, y in m)", "S * z * n_y (S in urad, z in m)",
                                             "S * z * n_x (S in urad, z in m)"};
    static constexpr const char* kParams[] = {"S_xy_urad", "S_yz_urad", "S_zx_urad"};
    name_ = kNames[pair];
    basis_ = kBasis[pair];
    params_ = {{kParams[pair], "out-of-squareness angle, urad", true, -100, 100}};
  }
  std::string_view name() const override { return name_; }
  std::string_view physics() const override { return "two axes are not at right angles"; }
  std::string_view basis() const override { return basis_; }
  const std::vector<EffectParameter>& parameters() const override { return params_; }
  void Jacobian(const PointContext& c, std::span<const double>, std::span<double> j) const override {
    const Eigen::Vector3d d = Unit(c.point);
    j[0] = d.dot(c.normal);
  }
  bool acts_on_positions() const override { return true; }
  Eigen::Vector3d DisplacementUm(const Eigen::Vector3d& p, std::span<const double> theta) const override {
    return theta[0] * Unit(p);
  }

 private:
  // The displacement for S = 1 µrad at p (mm): µrad · mm = 1e-3 µm.
  Eigen::Vector3d Unit(const Eigen::Vector3d& p) const {
    switch (pair_) {
      case 0:
        return {p.y() * 1e-3, 0, 0};
      case 1:
        return {0, p.z() * 1e-3, 0};
      default:
        return {p.z() * 1e-3, 0, 0};
    }
  }
  int pair_;
  std::string name_, basis_;
  std::vector<EffectParameter> params_;
};

// Lost motion b (µm) on an axis: after a reversal the axis lags the command by b, so a cut fed in +x
// sits b/2 behind (−x) and one fed in −x b/2 ahead, relative to the mean: D_x = −(b/2) sign(f_x).
// Cuts fed nearly across the axis (|f_x| < 0.05) carry no lag on it.
class Backlash final : public Effect {
 public:
  explicit Backlash(int axis)
      : axis_(axis),
        name_(std::string("backlash_") + kAxis[axis]),
        basis_(std::string("-(b/2) * sign(f_") + kAxis[axis] + ") * n_" + kAxis[axis]),
        params_{{std::string("b_") + kAxis[axis] + "_um",
                 std::string("lost motion of the ") + kAxis[axis] + " axis on reversal, um", true, 0, 20}} {}
  std::string_view name() const override { return name_; }
  std::string_view physics() const override { return "lost motion when the axis reverses"; }
  bool uses_toolpath() const override { return true; }
  std::string_view basis() const override { return basis_; }
  const std::vector<EffectParameter>& parameters() const override { return params_; }
  void Jacobian(const PointContext& c, std::span<const double>, std::span<double> j) const override {
    const double f = c.feed[axis_];
    const double sign = f > 0.05 ? 1.0 : (f < -0.05 ? -1.0 : 0.0);
    j[0] = -0.5 * sign * c.normal[axis_];
  }

 private:
  int axis_;
  std::string name_, basis_;
  std::vector<EffectParameter> params_;
};

}  // namespace

const Effect* ThermalDriftZEffect() {
  static const ThermalDriftZ e;
  return &e;
}
const Effect* AxisScaleEffect(int axis) {
  static const AxisScale e[] = {AxisScale(0), AxisScale(1), AxisScale(2)};
  return &e[axis];
}
const Effect* SquarenessEffect(int pair) {
  static const Squareness e[] = {Squareness(0), Squareness(1), Squareness(2)};
  return &e[pair];
}
const Effect* BacklashEffect(int axis) {
  static const Backlash e[] = {Backlash(0), Backlash(1)};
  return &e[axis];
}

}  // namespace formloop::sim
