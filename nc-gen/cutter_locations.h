#pragma once
// Cutter locations as the virtual machine (simulation/) takes them, from a planned tool path or from a
// program read back: ball centres with the path length and cutting time at each, and which locations
// were fed from their predecessor.

#include <string>
#include <vector>

#include "nc-gen/post.h"
#include "nc-gen/toolpath.h"
#include "simulation/covariates.h"

namespace formloop::nc {

// Every CL point of the path in cutting order, fed from its predecessor within a pass.
std::vector<sim::CutterLocation> CutterLocationsOf(const Toolpath& toolpath);

// The part's path planned again for a separating experiment's next part (sim::ExperimentOptions::replan):
// the raster turned by turn_deg, the feed scaled. A raster that cannot be planned on Q at that angle
// (BadInput: Q turns too steep along the turned planes) gives no locations, so that change is not
// proposed, and *skipped says why; other errors are returned.
Result<std::vector<sim::CutterLocation>> ReplannedCutterLocations(const recon::BSplineSurface& q, ToolpathOptions plan,
                                                                  double turn_deg, double feed_scale,
                                                                  std::string* skipped);

// Every feed move of a program as the program commands it (ball centre = tip + r ẑ), path length and
// time accumulated over feed moves: what a machine cuts, compensation offsets included.
std::vector<sim::CutterLocation> CutterLocationsOfProgram(const std::vector<ProgramMove>& moves, double radius_mm);

}  // namespace formloop::nc
