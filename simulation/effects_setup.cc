// Set-up effects: setup_offset, setup_rotation (spec/simulation.md §3). Both are written as the
// displacement of the tool relative to the workpiece, D = t (shift, µm) or D = ω × p (small rotation
// ω in µrad about the part origin, p in mm), so δ = D·n. A workpiece clamped 5 µm too far in +x is
// t = (−5, 0, 0): the tool sits 5 µm in −x relative to it.

#include <Eigen/Geometry>

#include "simulation/effects_catalogue.h"

namespace formloop::sim {
namespace {

class SetupOffset final : public Effect {
 public:
  std::string_view name() const override { return "setup_offset"; }
  std::string_view physics() const override { return "the workpiece is shifted from its programmed position"; }
  std::string_view basis() const override { return "t . n"; }
  bool part_specific() const override { return true; }
  const std::vector<EffectParameter>& parameters() const override {
    static const std::vector<EffectParameter> p = {{"tx_um", "shift along x, um", true, -20, 20},
                                                   {"ty_um", "shift along y, um", true, -20, 20},
                                                   {"tz_um", "shift along z, um", true, -20, 20}};
    return p;
  }
  void Jacobian(const PointContext& c, std::span<const double>, std::span<double> j) const override {
    j[0] = c.normal.x();
    j[1] = c.normal.y();
    j[2] = c.normal.z();
  }
  bool acts_on_positions() const override { return true; }
  Eigen::Vector3d DisplacementUm(const Eigen::Vector3d&, std::span<const double> theta) const override {
    return {theta[0], theta[1], theta[2]};
  }
};

class SetupRotation final : public Effect {
 public:
  std::string_view name() const override { return "setup_rotation"; }
  std::string_view physics() const override { return "the workpiece is rotated about the part origin"; }
  std::string_view basis() const override { return "(w x p) . n = w . (p x n), w in urad, p in m"; }
  bool part_specific() const override { return true; }
  const std::vector<EffectParameter>& parameters() const override {
    static const std::vector<EffectParameter> p = {{"wx_urad", "rotation about x, urad", true, -200, 200},
                                                   {"wy_urad", "rotation about y, urad", true, -200, 200},
                                                   {"wz_urad", "rotation about z, urad", true, -200, 200}};
    return p;
  }
  void Jacobian(const PointContext& c, std::span<const double>, std::span<double> j) const override {
    const Eigen::Vector3d pxn = c.point.cross(c.normal) * 1e-3;
    j[0] = pxn.x();
    j[1] = pxn.y();
    j[2] = pxn.z();
  }
  bool acts_on_positions() const override { return true; }
  Eigen::Vector3d DisplacementUm(const Eigen::Vector3d& p, std::span<const double> theta) const override {
    return Eigen::Vector3d(theta[0], theta[1], theta[2]).cross(p) * 1e-3;
  }
};

}  // namespace

const Effect* SetupOffsetEffect() {
  static const SetupOffset e;
  return &e;
}
const Effect* SetupRotationEffect() {
  static const SetupRotation e;
  return &e;
}

}  // namespace formloop::sim
