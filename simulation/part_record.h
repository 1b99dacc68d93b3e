#pragma once
// One part's probe data as a later pooled diagnosis needs it (issue 20, "Pooling parts"; simulation/diagnose.h
// DiagnosePooledResiduals): what the case library keeps of a part so that the next parts of the same
// machine/tool/material can be diagnosed together with it, without the run folder, the surface or the
// tool path it came from.
//
// Per probe point: its context (nominal point, normal, approach, and the tool-path covariates of the cut
// that made it: path length, cutting time, pass, feed direction, engagement, scallop), the measured
// deviation against a model with no effects — r₀ = measured − simulated(∅), both through the probe
// compensation and foot-point projection, so the measurement process cancels — and that chain's
// sensitivities (∂/∂ surface offset, ∂/∂ effective radius). A pre-compensated cut needs nothing added
// back: the simulated cut is the envelope of the program's own cutter locations (the scallop term of
// the context, simulation/covariates.h), so the program's offsets are in both terms and r₀ is the
// machine's own deviation, whatever the program did.
//
// Against a baseline B (the model the current run diagnoses against) the residual is
//   r_B ≈ r₀ − [S_B(c) − S_∅(c)]·∂_surface − ΔR_B(c)·∂_radius,
// S the model's surface deviation, ΔR its measurement effects' effective-radius change (µm): the chain
// is linear to ~1e-4 over tens of µm (diagnose.cc measures the sensitivities by a 1 µm step), which
// leaves < 0.01 µm beside noise of ~1 µm.
//
// The JSON form (format "formloop-part-record", version 1) is columnar: one array per field, in log
// order; numbers round-trip exactly (nlohmann's shortest form), so the same data give the same bytes.

#include <string>
#include <vector>

#include <Eigen/Core>
#include <nlohmann/json.hpp>

#include "core/status.h"
#include "simulation/diagnose.h"

namespace formloop::sim {

inline constexpr const char* kPartRecordFormat = "formloop-part-record";
inline constexpr int kPartRecordVersion = 1;

struct PartRecord {
  std::vector<PointContext> contexts;  // log order
  Eigen::VectorXd residual_um;         // r₀: measured − simulated(no effects), pre-compensation added back
  MeasurementSensitivity sensitivity;

  int points() const { return static_cast<int>(contexts.size()); }
  // The record of a part from its probe data (ProbeResiduals against a model with no effects).
  static Result<PartRecord> Of(const ProbeDataInput& input);
  // The residuals against `baseline`, as ProbeResiduals would give them for this part (above).
  ProbeResidualData Against(const Model& baseline) const;

  nlohmann::json ToJson() const;
  // Errors name `source` and the field.
  static Result<PartRecord> FromJson(const nlohmann::json& json, const std::string& source);
};

}  // namespace formloop::sim
