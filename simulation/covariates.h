#pragma once
// Associating measured points with the tool path that cut them (spec/simulation.md §2): for every
// point, the cutter location whose ball made it (nearest ball centre to p + r n), and from it the
// covariates effects are written in — path length s, cutting time, pass, feed direction, radial
// engagement — plus the scallop: the distance from p to the volume the ball sweeps along the
// commanded feed segments.

#include <cstdint>
#include <vector>

#include <Eigen/Core>

#include "core/status.h"
#include "simulation/effects.h"

namespace formloop::sim {

// One commanded ball position, in program order.
struct CutterLocation {
  Eigen::Vector3d centre = Eigen::Vector3d::Zero();  // ball centre, mm
  double path_length_mm = 0;                         // cutting path length from the program start
  double time_s = 0;                                 // cutting time from the program start
  long line = 0;                                     // program line that commanded it
  bool fed_from_previous = false;                    // reached from the previous location by a feed move
  int pass = -1;  // pass index when known (tool-path files); −1: counted from the feed runs
};

// A point to associate: nominal point on Q, its outward unit normal and the probe's approach.
struct MeasuredPoint {
  std::int64_t id = 0;
  Eigen::Vector3d point = Eigen::Vector3d::Zero();
  Eigen::Vector3d normal = Eigen::Vector3d::UnitZ();
  Eigen::Vector3d approach = -Eigen::Vector3d::UnitZ();
};

// A point whose nearest ball centre is further than `max_distance_factor` · r from p + r n was not
// cut by this program: an error naming the point.
Result<std::vector<PointContext>> AssociateWithToolpath(const std::vector<CutterLocation>& cutter_locations,
                                                        double tool_radius_mm, const std::vector<MeasuredPoint>& points,
                                                        double max_distance_factor = 5.0);

}  // namespace formloop::sim
