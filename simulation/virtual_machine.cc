#include "simulation/virtual_machine.h"

#include <cmath>

#include "core/random.h"

namespace formloop::sim {
namespace {

// The centre the probe reports when it touches a surface displaced by δ_s (mm) along n at p, for the
// probe model `probe` and an extra effective-radius change ΔR (mm, the model's measurement effects).
Eigen::Vector3d ReportedCentre(const PointContext& c, double surface_mm, double delta_r_eff_mm,
                               const metrology::ProbeModel& probe) {
  const Eigen::Vector3d& a = c.approach;
  const double ca = std::max(1e-6, -a.dot(c.normal));
  const double t_touch = -surface_mm / ca;
  const double pretravel = probe.Pretravel(a) - delta_r_eff_mm;
  return c.point + probe.ball_radius_mm * c.normal + (t_touch + pretravel) * a;
}

}  // namespace

double MeasurementEffectsMm(const PointContext& c, const Model& model) {
  // The model's measurement effects are written as δ = ΔR·c_a; the probe needs ΔR itself.
  const double ca = std::max(1e-6, -c.approach.dot(c.normal));
  double sum_um = 0;
  for (const auto& e : model.effects) {
    if (e.effect->kind() == EffectKind::kMeasurement) sum_um += e.effect->DeviationUm(c, e.values);
  }
  return 1e-3 * sum_um / ca;
}

Status MachineEffects::Validate() const {
  if (!(thermal_tau_s > 0)) return Status::BadInput(Where{.field = "machine.effects.thermal_tau_s"}, "must be > 0");
  if (surface_noise_um < 0 || probe_noise_um < 0) {
    return Status::BadInput(Where{.field = "machine.effects"}, "noise sigmas must be >= 0");
  }
  for (double x : {tool_radius_error_um, deflection_um, thermal_amplitude_um, surface_noise_um, probe_noise_um}) {
    if (!std::isfinite(x)) return Status::BadInput(Where{.field = "machine.effects"}, "values must be finite");
  }
  return Status::Ok();
}

nlohmann::json MachineEffects::ToJson() const {
  return {{"tool_radius", {{"delta_r_um", tool_radius_error_um}}},
          {"tool_deflection", {{"k_d_um", deflection_um}}},
          {"thermal_drift_z", {{"A_um", thermal_amplitude_um}, {"tau_s", thermal_tau_s}}},
          {"noise", {{"surface_sigma_um", surface_noise_um}, {"probe_sigma_um", probe_noise_um}}}};
}

Model MachineEffects::ToModel() const {
  Model m;
  if (tool_radius_error_um != 0) (void)m.Set("tool_radius", {tool_radius_error_um});
  if (deflection_um != 0) (void)m.Set("tool_deflection", {deflection_um});
  if (thermal_amplitude_um != 0) (void)m.Set("thermal_drift_z", {thermal_amplitude_um, thermal_tau_s});
  if (surface_noise_um != 0 || probe_noise_um != 0) (void)m.Set("noise", {surface_noise_um, probe_noise_um});
  return m;
}

Status VirtualMachineOptions::Validate() const {
  if (!(tool_radius_mm > 0)) return Status::BadInput(Where{.field = "tool.radius_mm"}, "must be > 0");
  FL_RETURN_IF_ERROR(effects.Validate());
  FL_RETURN_IF_ERROR(true_probe.Validate());
  if (!(probe_seconds_per_point > 0)) {
    return Status::BadInput(Where{.field = "machine.probe_seconds_per_point"}, "must be > 0");
  }
  return Status::Ok();
}

std::vector<MeasuredPoint> MeasuredPointsOf(const metrology::ProbingPlan& plan,
                                            const std::vector<Eigen::Vector3d>& approaches) {
  std::vector<MeasuredPoint> out;
  out.reserve(plan.points.size());
  for (std::size_t i = 0; i < plan.points.size(); ++i) {
    const auto& p = plan.points[i];
    out.push_back({p.id, p.point, p.normal, approaches.empty() ? Eigen::Vector3d(-p.normal) : approaches[i]});
  }
  return out;
}

Result<VirtualMachineResult> MachineAndProbe(const std::vector<CutterLocation>& cutter_locations,
                                             const metrology::ProbingPlan& plan, const VirtualMachineOptions& options) {
  FL_RETURN_IF_ERROR(options.Validate());
  if (!options.approaches.empty() && options.approaches.size() != plan.points.size()) {
    return Status::BadInput("approach directions: " + std::to_string(options.approaches.size()) + " for " +
                            std::to_string(plan.points.size()) + " plan points");
  }
  for (std::size_t i = 0; i < options.approaches.size(); ++i) {
    const Eigen::Vector3d& a = options.approaches[i];
    if (std::abs(a.norm() - 1.0) > 1e-6 || -a.dot(plan.points[i].normal) < 0.2) {
      return Status::BadInput("approach of plan point " + std::to_string(plan.points[i].id) +
                              " must be a unit vector into the surface within 78 degrees of -n");
    }
  }
  VirtualMachineResult result;
  result.model = options.model;
  for (const auto& e : options.effects.ToModel().effects) {
    if (!result.model.Has(e.effect->name())) result.model.effects.push_back(e);
  }
  FL_ASSIGN_OR_RETURN(result.contexts, AssociateWithToolpath(cutter_locations, options.tool_radius_mm,
                                                             MeasuredPointsOf(plan, options.approaches)));
  const Model& model = result.model;
  Rng rng(options.seed);
  double t_probe = 0;
  for (const PointContext& c : result.contexts) {
    InjectedTruth truth;
    truth.id = c.id;
    truth.scallop_um = c.scallop_um;
    truth.surface_um = model.SurfaceDeviationUm(c);
    for (const auto& e : model.effects) truth.effect_um.push_back(e.effect->DeviationUm(c, e.values));
    truth.measurement_um = model.DeviationUm(c) - truth.surface_um;
    // Draws in a fixed order per point, so a run is repeatable.
    truth.roughness_um = model.surface_sigma_um() * rng.Normal();
    truth.probe_noise_um = model.probe_sigma_um() * rng.Normal();
    metrology::ProbeRecord record;
    record.id = c.id;
    record.approach = c.approach;
    record.centre = ReportedCentre(c, 1e-3 * truth.total_um(), MeasurementEffectsMm(c, model), options.true_probe) +
                    1e-3 * truth.probe_noise_um * c.approach;
    t_probe += options.probe_seconds_per_point;
    record.t_s = t_probe;
    result.log.records.push_back(record);
    result.truth.push_back(std::move(truth));
  }
  return result;
}

metrology::ProbeLog PredictProbeLog(const std::vector<PointContext>& contexts, const Model& model,
                                    const metrology::ProbeModel& probe, double extra_surface_um,
                                    double extra_radius_um) {
  metrology::ProbeLog log;
  for (const PointContext& c : contexts) {
    metrology::ProbeRecord record;
    record.id = c.id;
    record.approach = c.approach;
    record.centre = ReportedCentre(c, 1e-3 * (model.SurfaceDeviationUm(c) + extra_surface_um),
                                   MeasurementEffectsMm(c, model) + 1e-3 * extra_radius_um, probe);
    log.records.push_back(record);
  }
  return log;
}

double VirtualMachineResult::EffectUm(std::size_t point, std::string_view effect) const {
  for (std::size_t k = 0; k < model.effects.size(); ++k) {
    if (model.effects[k].effect->name() == effect) return truth[point].effect_um[k];
  }
  return 0.0;
}

nlohmann::json VirtualMachineResult::ReportJson() const {
  auto stats = [&](auto getter) {
    double mn = 1e300, mx = -1e300, sum = 0;
    for (std::size_t i = 0; i < truth.size(); ++i) {
      const double x = getter(i);
      mn = std::min(mn, x);
      mx = std::max(mx, x);
      sum += x;
    }
    const double mean = truth.empty() ? 0 : sum / static_cast<double>(truth.size());
    return nlohmann::json{{"min", mn}, {"max", mx}, {"mean", mean}};
  };
  nlohmann::json injected = {{"scallop", stats([&](std::size_t i) { return truth[i].scallop_um; })}};
  for (std::size_t k = 0; k < model.effects.size(); ++k) {
    if (model.effects[k].effect->kind() == EffectKind::kNoise) continue;
    injected[std::string(model.effects[k].effect->name())] =
        stats([&](std::size_t i) { return truth[i].effect_um[k]; });
  }
  injected["roughness"] = stats([&](std::size_t i) { return truth[i].roughness_um; });
  injected["probe_noise"] = stats([&](std::size_t i) { return truth[i].probe_noise_um; });
  injected["total_surface"] = stats([&](std::size_t i) { return truth[i].total_um(); });
  return {{"probed_points", truth.size()}, {"model", model.ToJson()}, {"injected_um", injected}};
}

}  // namespace formloop::sim
