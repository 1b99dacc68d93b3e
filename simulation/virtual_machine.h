#pragma once
// The virtual machine: machines a program on the ideal surface Q and probes the result
// (spec/simulation.md §2, §3). This first forward model is deliberately small but real at every
// step: the machined surface is the envelope of the ball positions the program actually commands,
// plus a few physical effects from the catalogue, plus noise; the probe log is what a touch probe
// would report for the probing plan.
//
// Effects in this model (names as in the catalogue, stable in output):
//   scallop          geometric: distance from p to the volume swept by the ball along the programmed
//                    feed segments [B_k, B_k+1], i.e. min_k dist(p, segment) − r (always on)
//   tool_radius      +Δr (material left when the real ball is smaller than programmed)
//   tool_deflection  +k_d · (1 − n_z²)      (steeper walls leave more)
//   thermal_drift_z  −A (1 − exp(−t_cut/τ)) · n_z   (spindle growth over cutting time)
//   noise            surface roughness N(0, σ_s²) and probe repeatability N(0, σ_p²)
// Each probed point is associated with the nearest cutter location to take its cutting time.

#include <cstdint>
#include <vector>

#include <Eigen/Core>
#include <nlohmann/json.hpp>

#include "core/status.h"
#include "metrology/probe.h"
#include "reconstruction/bspline_surface.h"

namespace formloop::sim {

// One commanded ball position, in program order.
struct CutterLocation {
  Eigen::Vector3d centre = Eigen::Vector3d::Zero();  // ball centre, mm
  double path_length_mm = 0;                         // cutting path length from the program start
  double time_s = 0;                                 // cutting time from the program start
  long line = 0;                                     // program line that commanded it
  bool fed_from_previous = false;                    // reached from the previous location by a feed move
};

struct MachineEffects {
  double tool_radius_error_um = 0;     // tool_radius: Δr
  double deflection_um = 0;            // tool_deflection: k_d
  double thermal_amplitude_um = 0;     // thermal_drift_z: A
  double thermal_tau_s = 600;          // thermal_drift_z: τ
  double surface_noise_um = 0;         // noise: roughness σ_s
  double probe_noise_um = 0;           // noise: probe repeatability σ_p
  Status Validate() const;
  nlohmann::json ToJson() const;
};

struct VirtualMachineOptions {
  double tool_radius_mm = 3.0;         // programmed ball radius
  MachineEffects effects;
  metrology::ProbeModel true_probe;    // the probe the machine really has
  double probe_seconds_per_point = 4.0;
  std::uint64_t seed = 1;
  Status Validate() const;
};

// What was injected at each probed point (for reports and tests; analysis never reads it).
struct InjectedTruth {
  std::int64_t id = 0;
  double scallop_um = 0, tool_radius_um = 0, deflection_um = 0, thermal_um = 0, roughness_um = 0, probe_noise_um = 0;
  double total_um() const { return scallop_um + tool_radius_um + deflection_um + thermal_um + roughness_um; }
};

struct VirtualMachineResult {
  metrology::ProbeLog log;
  std::vector<InjectedTruth> truth;
  nlohmann::json ReportJson() const;
};

Result<VirtualMachineResult> MachineAndProbe(const recon::BSplineSurface& surface,
                                             const std::vector<CutterLocation>& cutter_locations,
                                             const metrology::ProbingPlan& plan, const VirtualMachineOptions& options);

}  // namespace formloop::sim
