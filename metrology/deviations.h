#pragma once
// Signed deviations of probed points from the ideal surface Q (spec/metrology.md §4).

#include <cstdint>
#include <vector>

#include <Eigen/Core>

#include "core/point_set.h"
#include "core/status.h"
#include "metrology/probe.h"
#include "metrology/spatial_weights.h"
#include "reconstruction/bspline_surface.h"

namespace formloop::metrology {

struct Deviation {
  std::int64_t id = 0;
  double u = 0, v = 0;                                // foot-point parameters on Q
  Eigen::Vector3d contact = Eigen::Vector3d::Zero();  // compensated contact point, mm
  Eigen::Vector3d foot = Eigen::Vector3d::Zero();     // foot point on Q
  Eigen::Vector3d normal = Eigen::Vector3d::UnitZ();  // unit normal of Q at the foot point
  double deviation_mm = 0;                            // (contact − foot)·n, positive = material left
  // The foot point is held at Q's edge, or (on a trimmed Q) lies outside the trim: either way the
  // deviation is not a normal distance to the part. outside_trim says which.
  bool on_boundary = false;
  bool outside_trim = false;
};

// Each log record is matched to the plan by id (the plan gives the start of the foot-point search).
// A record whose id is not in the plan is an error naming the id.
Result<std::vector<Deviation>> ComputeDeviations(const recon::BSplineSurface& surface, const ProbingPlan& plan,
                                                 const ProbeLog& log, const ProbeModel& probe);

// As a point set: contact points, normals (of Q at the foot points), ids, scalars u, v, foot_x, foot_y,
// foot_z, deviation_um, on_boundary (1/0; also 1 for a foot point outside Q's trim): the deviation vector,
// not only its length.
PointSet DeviationsToPoints(const std::vector<Deviation>& deviations);

// k-nearest-neighbour weights of the deviations in (u, v), row-standardised: the neighbourhood of
// formloop's Moran statistics on a machined part (decomposition, LISA maps).
Result<SpatialWeights> UvKnnWeights(const std::vector<Deviation>& deviations, int k);

}  // namespace formloop::metrology
