#pragma once
// Which points of a probing plan a 3-axis probe reaches clear of the part (nc-gen/probe_clearance.h, the
// check of ProbeProgramOptions::part_surface): `formloop run` leaves the others out of its plan before it
// writes the probing program, as a trim's outside is left out of a grid (metrology/probe.h).

#include <cstddef>
#include <cstdint>
#include <string>
#include <vector>

#include <Eigen/Dense>

#include "core/status.h"
#include "metrology/probe.h"
#include "nc-gen/probe_program.h"

namespace formloop::nc {

// A plan point left out because a 3-axis probe cannot reach it clear of the part: its plan index and id,
// and the clearance check's finding without the refusal's fix, e.g. "the stylus ball would come within
// 0.615 mm of the part (1.000 mm required) on the descent from safe Z to its start point, at (x, y, z)".
struct UnreachableProbePoint {
  std::size_t index = 0;
  std::int64_t id = 0;
  std::string reason;
};
// The plan reduced to the points the probe reaches clear of the part (plan order, ids kept), the
// approaches of those points (empty when options.approaches is) and the points left out.
struct ReachableProbePlan {
  metrology::ProbingPlan plan;
  std::vector<Eigen::Vector3d> approaches;
  std::vector<UnreachableProbePoint> left_out;
};
// Of the points kept, at least this share of the plan (rounded up), else the plan is refused.
inline constexpr double kMinReachableShare = 0.5;
// The points of `plan` a probing program with `options` can carry: the program's own check of each point
// against options.part_surface (with the shortened clearances it tries), in plan order, each point's
// traverse starting above the last point KEPT; a point no clearance clears is left out (the way a trim's
// outside is left out of a grid), the others stay. The program posted from the result with the same
// options carries every kept point with the same moves (the same checks pass again; a batch's first point
// only drops its traverse check). Without part_surface nothing is left out. SafetyLimit when fewer than
// kMinReachableShare of the plan remain (naming how many, the first point's finding and the fix); the
// options' and machine limits' refusals of PostProbing stay. `formloop run` reduces its grid plan with
// it; `formloop nc probe` does not (a plan the user gives is refused, not changed).
Result<ReachableProbePlan> ReachableProbePoints(const metrology::ProbingPlan& plan, const ProbeProgramOptions& options);

}  // namespace formloop::nc
