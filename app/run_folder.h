#pragma once
// A `formloop run` folder as input to other commands (simulate, diagnose): the resolved part, the
// ideal surface Q (surface/Q.step), the tool path (toolpath/toolpath.csv) and the probing plan
// (toolpath/probing_plan.json), each read with the error naming the file.

#include <filesystem>
#include <vector>

#include <Eigen/Core>

#include "app/part.h"
#include "core/status.h"
#include "metrology/probe.h"
#include "nc-gen/toolpath.h"
#include "reconstruction/bspline_surface.h"
#include "simulation/covariates.h"

namespace formloop::app {

struct RunFolder {
  std::filesystem::path dir;
  PartSpec part;
  recon::BSplineSurface q;
  nc::Toolpath toolpath;
  std::vector<sim::CutterLocation> cutter_locations;  // nc::CutterLocationsOf(toolpath)
  metrology::ProbingPlan plan;
};

Result<RunFolder> ReadRunFolder(const std::filesystem::path& dir);

// A probing plan with optional approach directions: formloop's JSON ({"points": [{"id", "u", "v",
// "point", "normal"}]}) or CSV with the columns id, u, v, x, y, z, nx, ny, nz and optionally ax, ay, az
// (unit, into the surface). `approaches` is empty when the file gives none (approach along −n).
struct PlanWithApproaches {
  metrology::ProbingPlan plan;
  std::vector<Eigen::Vector3d> approaches;
};
Result<PlanWithApproaches> ReadPlanFile(const std::filesystem::path& path);

}  // namespace formloop::app
