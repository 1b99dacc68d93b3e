#include "simulation/effects.h"

#include <algorithm>
#include <vector>

#include "simulation/effects_catalogue.h"

namespace formloop::sim {

bool Effect::linear() const {
  const auto& ps = parameters();
  return std::all_of(ps.begin(), ps.end(), [](const EffectParameter& p) { return p.linear; });
}

double Effect::DeviationUm(const PointContext& c, std::span<const double> theta) const {
  // Linear effects: δ = J·θ.
  std::vector<double> j(static_cast<std::size_t>(parameter_count()));
  Jacobian(c, theta, j);
  double sum = 0;
  for (std::size_t k = 0; k < j.size(); ++k) sum += j[k] * theta[k];
  return sum;
}

Eigen::Vector3d Effect::DisplacementUm(const Eigen::Vector3d&, std::span<const double>) const {
  return Eigen::Vector3d::Zero();
}

const std::vector<const Effect*>& EffectCatalogue() {
  // The registry: one line per effect, in the order of spec §3.
  static const std::vector<const Effect*> catalogue = {
      ScallopEffect(),     ToolRadiusEffect(),  ToolWearEffect(),   ToolDeflectionEffect(), ThermalDriftZEffect(),
      AxisScaleEffect(0),  AxisScaleEffect(1),  AxisScaleEffect(2), SquarenessEffect(0),    SquarenessEffect(1),
      SquarenessEffect(2), BacklashEffect(0),   BacklashEffect(1),  SetupOffsetEffect(),    SetupRotationEffect(),
      ProbeRadiusEffect(), ProbeLobingEffect(), NoiseEffect(),
  };
  return catalogue;
}

const Effect* FindEffect(std::string_view name) {
  for (const Effect* e : EffectCatalogue()) {
    if (e->name() == name) return e;
  }
  return nullptr;
}

std::string EffectNames() {
  std::string out;
  for (const Effect* e : EffectCatalogue()) {
    if (!out.empty()) out += ", ";
    out += e->name();
  }
  return out;
}

Eigen::Vector2d TriLobeFactors(const Eigen::Vector3d& approach) {
  // (−a)_h = ρ (cos θ, sin θ): ρ³ cos 3θ = Re (x + iy)³ and ρ³ sin 3θ = Im (x + iy)³, so ρ cos 3θ =
  // Re(...)/ρ² without any angle (and no pole singularity).
  const double x = -approach.x(), y = -approach.y();
  const double rho2 = x * x + y * y;
  if (rho2 < 1e-18) return Eigen::Vector2d::Zero();
  const double re = x * x * x - 3 * x * y * y;
  const double im = 3 * x * x * y - y * y * y;
  return Eigen::Vector2d(re / rho2, im / rho2);
}

}  // namespace formloop::sim
