#pragma once
// A separating experiment carried to the next part (issue 20): the proposal an earlier part of the same
// machine, tool and material earned (sim::ExperimentProposal, simulation/experiment_design.h) as a
// plan change the next part's run can apply, whatever its shape.
//
//   - "reprobe": K extra points with a tilted approach. A point keeps its place on the part as a
//     fraction of Q's parameter domain (s, t in [0, 1]) and its approach as the tilt from −n and the
//     azimuth (from +x, about +z) of the approach's tangential part; on the new part the point is
//     put at the same fractions of its Q, and the approach rebuilt from its normal there:
//     a = −cos(tilt) n + sin(tilt) d, d the azimuth's direction projected onto the tangent plane.
//     What a tilt separates (a probe radius acts along the approach, c_a = −a·n, a tool radius along
//     n: identical columns when every point is probed along −n) does not depend on the part's shape.
//     A point is dropped when its position is not allowed on Q (a trim and its margin), when the
//     tangent plane has no direction for the azimuth, or when the approach would not come from
//     above (a_z ≥ −kMinApproachDown): the stylus comes down onto the part.
//   - "raster_turn" / "feed": the next part's raster angle turned and feed scaled.
// Several proposals apply together: the re-probe points of all, the first raster turn and feed scale.

#include <string>
#include <vector>

#include <Eigen/Core>
#include <nlohmann/json.hpp>

#include "core/status.h"
#include "metrology/probe.h"
#include "reconstruction/bspline_surface.h"
#include "simulation/experiment_design.h"

namespace formloop::sim {

inline constexpr double kMinApproachDown = 0.1;

struct PlannedProposal {
  struct Point {
    double s = 0.5, t = 0.5;               // fraction of Q's u and v spans
    double tilt_deg = 0, azimuth_deg = 0;  // of the approach (see above)
  };
  std::vector<std::string> members;  // the alias group it separates
  std::string kind;                  // "reprobe", "raster_turn", "feed"
  std::vector<Point> points;         // reprobe
  double raster_turn_deg = 0, feed_scale = 1;

  // The proposal made on a part whose Q has `domain`.
  static PlannedProposal Of(const ExperimentProposal& proposal, const recon::ParamDomain& domain);
  nlohmann::json ToJson() const;
  // Bad input names `source` (the file), the key path `prefix` ("probing.proposals[0].") and the member.
  static Result<PlannedProposal> FromJson(const nlohmann::json& j, const std::string& source,
                                          const std::string& prefix);
};

// A probing plan with the proposals' re-probe points appended (ids after the plan's largest) and the
// approach of every point in plan order (−n for the plan's own points).
struct PlanWithProposals {
  metrology::ProbingPlan plan;
  std::vector<Eigen::Vector3d> approaches;
  int added = 0, dropped = 0;  // re-probe points put on Q / left out (see above)
  double raster_turn_deg = 0, feed_scale = 1;
  bool tilted() const { return added > 0; }
};
// The next part's path change the proposals ask for: the first raster turn and the first feed scale.
struct PathChange {
  double raster_turn_deg = 0, feed_scale = 1;
};
PathChange PathChangeOf(const std::vector<PlannedProposal>& proposals);

PlanWithProposals ApplyProposals(const metrology::ProbingPlan& plan, const recon::BSplineSurface& q,
                                 const std::vector<PlannedProposal>& proposals);

}  // namespace formloop::sim
