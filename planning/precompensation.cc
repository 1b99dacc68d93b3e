#include "planning/precompensation.h"

#include <algorithm>
#include <cmath>
#include <vector>

#include "metrology/probe.h"
#include "nc-gen/cutter_locations.h"
#include "nc-gen/deviation_field.h"
#include "simulation/virtual_machine.h"

namespace formloop::planning {

Result<PredictedField> PredictLearnedField(const recon::BSplineSurface& q, const nc::Toolpath& nominal,
                                           const sim::Model& learned, std::uint64_t seed) {
  constexpr int kGrid = 24;
  const sim::Model model = learned.WithoutNoise();
  FL_ASSIGN_OR_RETURN(metrology::ProbingPlan grid, metrology::PlanProbingGrid(q, kGrid, kGrid, 0.0));
  sim::VirtualMachineOptions vm;
  vm.tool_radius_mm = nominal.options.tool.radius_mm;
  vm.model = model;
  vm.seed = seed;
  FL_ASSIGN_OR_RETURN(sim::VirtualMachineResult predicted,
                      sim::MachineAndProbe(nc::CutterLocationsOf(nominal), grid, vm));
  std::vector<nc::DeviationSample> samples;
  double peak = 0;
  for (std::size_t i = 0; i < grid.points.size(); ++i) {
    const double ds = predicted.truth[i].surface_um - predicted.truth[i].scallop_um;
    samples.push_back({.u = grid.points[i].u, .v = grid.points[i].v, .ds_um = ds});
    peak = std::max(peak, std::abs(ds));
  }
  FL_ASSIGN_OR_RETURN(nc::DeviationField field, nc::DeviationField::Fit(samples, {}, "learned model prediction"));
  PredictedField out;
  out.field = field.AsSystematicField();
  out.report = {{"grid", {kGrid, kGrid}}, {"predicted_peak_um", peak}, {"model", model.ToJson()}};
  return out;
}

}  // namespace formloop::planning
