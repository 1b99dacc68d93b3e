#pragma once
// The virtual machine: machines a program on the ideal surface Q and probes the result
// (spec/simulation.md §2, §3). The machined surface is the envelope of the ball positions the
// program commands (the scallop effect) plus the surface effects of a Model (effects.h); the probe
// touches it along each point's approach direction, triggers after its pretravel and reports the
// ball centre, with the measurement effects of the model and noise.
//
// Probe physics for an approach a at an angle to the normal n (c_a = −a·n > 0): the ball (true
// radius R) travels along a toward the position where it would touch Q at p, meets the machined
// surface (offset δ_s along n) at t* = −δ_s / c_a and triggers after the pretravel δ_p(a) of the true
// probe, minus the model's effective-radius error; the log holds that centre. For a = −n this is
// centre = machined point − R_eff·a.

#include <cstdint>
#include <vector>

#include <Eigen/Core>
#include <nlohmann/json.hpp>

#include "core/status.h"
#include "metrology/probe.h"
#include "simulation/covariates.h"
#include "simulation/model.h"

namespace formloop::sim {

// The part file's `machine.effects` block: a few catalogue effects under their part-file names. It is
// turned into a Model (ToModel) before machining.
struct MachineEffects {
  double tool_radius_error_um = 0;  // tool_radius: Δr
  double deflection_um = 0;         // tool_deflection: k_d
  double thermal_amplitude_um = 0;  // thermal_drift_z: A
  double thermal_tau_s = 600;       // thermal_drift_z: τ
  double surface_noise_um = 0;      // noise: roughness σ_s
  double probe_noise_um = 0;        // noise: probe repeatability σ_p
  Status Validate() const;
  nlohmann::json ToJson() const;
  Model ToModel() const;  // only the effects with a non-zero value
};

struct VirtualMachineOptions {
  double tool_radius_mm = 3.0;  // programmed ball radius
  MachineEffects effects;       // merged into `model` (the model's entry wins for an effect in both)
  Model model;
  metrology::ProbeModel true_probe;  // the probe the machine really has
  // Approach direction per plan point (unit, into the surface); empty = along −n everywhere.
  std::vector<Eigen::Vector3d> approaches;
  double probe_seconds_per_point = 4.0;
  std::uint64_t seed = 1;
  Status Validate() const;
};

// What was injected at each probed point (for reports and tests; analysis never reads it).
struct InjectedTruth {
  std::int64_t id = 0;
  double scallop_um = 0;
  std::vector<double> effect_um;  // per entry of the machining model, in its order (noise: 0)
  double surface_um = 0;          // scallop + surface effects: where the machined surface is
  double measurement_um = 0;      // the probe's effects
  double roughness_um = 0, probe_noise_um = 0;
  double total_um() const { return surface_um + roughness_um; }
};

struct VirtualMachineResult {
  metrology::ProbeLog log;
  Model model;                         // the model that was machined (effects merged in)
  std::vector<PointContext> contexts;  // per plan point
  std::vector<InjectedTruth> truth;
  double EffectUm(std::size_t point, std::string_view effect) const;  // 0 when not in the model
  nlohmann::json ReportJson() const;
};

// Plan points as measured points (approach −n unless given).
std::vector<MeasuredPoint> MeasuredPointsOf(const metrology::ProbingPlan& plan,
                                            const std::vector<Eigen::Vector3d>& approaches = {});

// The plan's points carry Q's point and normal; Q itself is not needed.
Result<VirtualMachineResult> MachineAndProbe(const std::vector<CutterLocation>& cutter_locations,
                                             const metrology::ProbingPlan& plan, const VirtualMachineOptions& options);

// The effective-radius change ΔR (mm) the model's measurement effects give the probe at c (they are
// written as δ = ΔR·c_a, c_a = −approach·n).
double MeasurementEffectsMm(const PointContext& c, const Model& model);

// The probe log a model predicts for given contexts (no noise): the same physics as MachineAndProbe.
// `extra_surface_um` / `extra_radius_um` (per context, optional) add a surface offset along n and an
// effective-radius change on top of the model (diagnose's measurement sensitivities).
metrology::ProbeLog PredictProbeLog(const std::vector<PointContext>& contexts, const Model& model,
                                    const metrology::ProbeModel& probe, double extra_surface_um = 0,
                                    double extra_radius_um = 0);

}  // namespace formloop::sim
