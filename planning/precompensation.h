#pragma once
// Pre-compensation of the first program from a case's learned model (spec/simulation.md §4): the model
// is run on the nominal tool path in the virtual machine without its noise; the surface part of its
// prediction (the scallop left out: it is local to each pass and no mirror offset removes it) at a
// 24 × 24 grid on Q becomes a smooth thin-plate field (nc::DeviationField), which the mirror compensation
// then takes off the nominal program, scaled by the plan's c_pc.

#include <cstdint>

#include <nlohmann/json.hpp>

#include "core/status.h"
#include "nc-gen/compensation.h"
#include "nc-gen/toolpath.h"
#include "reconstruction/bspline_surface.h"
#include "simulation/model.h"

namespace formloop::planning {

struct PredictedField {
  nc::SystematicField field;  // d_s(u, v) in mm as the learned model predicts it
  // {"grid": [24, 24], "predicted_peak_um": ..., "model": the model without its noise}
  nlohmann::json report;
};

// `seed` seeds the virtual machine (the model has no noise, so it only matters to effects that draw).
Result<PredictedField> PredictLearnedField(const recon::BSplineSurface& q, const nc::Toolpath& nominal,
                                           const sim::Model& learned, std::uint64_t seed);

}  // namespace formloop::planning
