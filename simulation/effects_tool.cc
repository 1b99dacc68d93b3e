// Tool effects: scallop, tool_radius, tool_wear, tool_deflection (spec/simulation.md §3).

#include <cmath>

#include "simulation/effects_catalogue.h"

namespace formloop::sim {
namespace {

// scallop: the cusps a ball leaves between passes. Its value comes from the swept-ball envelope of the
// commanded cutter locations (covariates.h), so it has no parameters and is in every model.
class Scallop final : public Effect {
 public:
  std::string_view name() const override { return "scallop"; }
  std::string_view physics() const override { return "ball-end cusps between passes (always on)"; }
  std::string_view basis() const override {
    return "distance from the point to the volume swept by the ball along the commanded feed segments";
  }
  EffectKind kind() const override { return EffectKind::kGeometric; }
  const std::vector<EffectParameter>& parameters() const override {
    static const std::vector<EffectParameter> none;
    return none;
  }
  double DeviationUm(const PointContext& c, std::span<const double>) const override { return c.scallop_um; }
  void Jacobian(const PointContext&, std::span<const double>, std::span<double>) const override {}
};

class ToolRadius final : public Effect {
 public:
  std::string_view name() const override { return "tool_radius"; }
  std::string_view physics() const override { return "the real ball radius differs from the programmed one"; }
  std::string_view basis() const override { return "+delta_r (a smaller ball leaves material everywhere)"; }
  const std::vector<EffectParameter>& parameters() const override {
    static const std::vector<EffectParameter> p = {
        {"delta_r_um", "programmed minus real ball radius, um", true, -10, 10}};
    return p;
  }
  void Jacobian(const PointContext&, std::span<const double>, std::span<double> j) const override { j[0] = 1.0; }
};

class ToolWear final : public Effect {
 public:
  std::string_view name() const override { return "tool_wear"; }
  std::string_view physics() const override { return "the ball wears: its radius shrinks with cut length"; }
  std::string_view basis() const override { return "+k_w * s, s the cutting path length to the point in m"; }
  bool uses_toolpath() const override { return true; }
  const std::vector<EffectParameter>& parameters() const override {
    static const std::vector<EffectParameter> p = {
        {"k_w_um_per_m", "radius loss per metre of cutting path, um/m", true, 0, 5}};
    return p;
  }
  void Jacobian(const PointContext& c, std::span<const double>, std::span<double> j) const override {
    j[0] = c.path_length_mm * 1e-3;
  }
};

// Load ∝ radial engagement a_e/r (chip cross-section), and a ball bends away from a steep wall along
// its normal: g = (1 − n_z²) · (a_e/r) / 0.1, so k_d is the deflection on a vertical wall at a radial
// engagement of a tenth of the ball radius (a typical finishing step-over).
class ToolDeflection final : public Effect {
 public:
  std::string_view name() const override { return "tool_deflection"; }
  std::string_view physics() const override { return "cutting load bends the tool away from steep walls"; }
  std::string_view basis() const override { return "+k_d * (1 - n_z^2) * (a_e / r) / 0.1"; }
  bool uses_toolpath() const override { return true; }
  const std::vector<EffectParameter>& parameters() const override {
    static const std::vector<EffectParameter> p = {
        {"k_d_um", "deflection on a vertical wall at a_e = 0.1 r, um", true, 0, 20}};
    return p;
  }
  void Jacobian(const PointContext& c, std::span<const double>, std::span<double> j) const override {
    j[0] = (1.0 - c.normal.z() * c.normal.z()) * c.engagement / 0.1;
  }
};

}  // namespace

const Effect* ScallopEffect() {
  static const Scallop e;
  return &e;
}
const Effect* ToolRadiusEffect() {
  static const ToolRadius e;
  return &e;
}
const Effect* ToolWearEffect() {
  static const ToolWear e;
  return &e;
}
const Effect* ToolDeflectionEffect() {
  static const ToolDeflection e;
  return &e;
}

}  // namespace formloop::sim
