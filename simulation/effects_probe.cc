// Probe effects (measurement only): probe_radius, probe_lobing; and noise (spec/simulation.md §3).
//
// The virtual machine's probe touches the machined surface and triggers after the pretravel along
// the approach a; `analyse` compensates with the assumed effective radius. An effective-radius error
// ΔR = R_true − R_assumed therefore reads as δ += ΔR · c_a with c_a = −a·n (first order; exact for
// a = −n). See effects.h for the conventions.

#include "simulation/effects_catalogue.h"

namespace formloop::sim {
namespace {

double ApproachCosine(const PointContext& c) { return -c.approach.dot(c.normal); }

class ProbeRadius final : public Effect {
 public:
  std::string_view name() const override { return "probe_radius"; }
  std::string_view physics() const override { return "the probe's effective radius is not the assumed one"; }
  std::string_view basis() const override { return "+dR * (-a . n) (constant along the approach)"; }
  EffectKind kind() const override { return EffectKind::kMeasurement; }
  const std::vector<EffectParameter>& parameters() const override {
    static const std::vector<EffectParameter> p = {
        {"delta_r_eff_um", "true minus assumed effective radius, um", true, -10, 10}};
    return p;
  }
  void Jacobian(const PointContext& c, std::span<const double>, std::span<double> j) const override {
    j[0] = ApproachCosine(c);
  }
};

// A kinematic probe's tri-lobe: the effective radius varies as ρ (c3 cos 3θ + s3 sin 3θ) with the
// azimuth θ of the probing direction −a and its horizontal length ρ (TriLobeFactors).
class ProbeLobing final : public Effect {
 public:
  std::string_view name() const override { return "probe_lobing"; }
  std::string_view physics() const override { return "direction-dependent pretravel (tri-lobe)"; }
  std::string_view basis() const override {
    return "+(-a . n) * rho * (c3 cos 3 theta + s3 sin 3 theta), theta/rho azimuth/horizontal length of -a";
  }
  EffectKind kind() const override { return EffectKind::kMeasurement; }
  const std::vector<EffectParameter>& parameters() const override {
    static const std::vector<EffectParameter> p = {
        {"c3_um", "cos 3 theta amplitude of the effective radius, um", true, -5, 5},
        {"s3_um", "sin 3 theta amplitude of the effective radius, um", true, -5, 5}};
    return p;
  }
  void Jacobian(const PointContext& c, std::span<const double>, std::span<double> j) const override {
    const Eigen::Vector2d f = TriLobeFactors(c.approach) * ApproachCosine(c);
    j[0] = f.x();
    j[1] = f.y();
  }
};

// Roughness (on the surface) and probe repeatability (along the approach): i.i.d. normal scatter. It
// adds no mean; the virtual machine draws it, diagnose estimates its σ from the residual.
class Noise final : public Effect {
 public:
  std::string_view name() const override { return "noise"; }
  std::string_view physics() const override { return "surface roughness and probe repeatability"; }
  std::string_view basis() const override { return "i.i.d. N(0, surface_sigma^2 + probe_sigma^2)"; }
  EffectKind kind() const override { return EffectKind::kNoise; }
  const std::vector<EffectParameter>& parameters() const override {
    static const std::vector<EffectParameter> p = {{"surface_sigma_um", "roughness sigma, um", true, 0, 2},
                                                   {"probe_sigma_um", "probe repeatability sigma, um", true, 0, 2}};
    return p;
  }
  double DeviationUm(const PointContext&, std::span<const double>) const override { return 0.0; }
  void Jacobian(const PointContext&, std::span<const double>, std::span<double> j) const override {
    for (double& x : j) x = 0;
  }
};

}  // namespace

const Effect* ProbeRadiusEffect() {
  static const ProbeRadius e;
  return &e;
}
const Effect* ProbeLobingEffect() {
  static const ProbeLobing e;
  return &e;
}
const Effect* NoiseEffect() {
  static const Noise e;
  return &e;
}

}  // namespace formloop::sim
