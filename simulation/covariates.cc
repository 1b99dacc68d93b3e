#include "simulation/covariates.h"

#include <algorithm>
#include <cmath>
#include <string>

#include <pcl/kdtree/kdtree_flann.h>
#include <pcl/point_types.h>

#include "core/geometry.h"

namespace formloop::sim {

Result<std::vector<PointContext>> AssociateWithToolpath(const std::vector<CutterLocation>& cls, double r,
                                                        const std::vector<MeasuredPoint>& points,
                                                        double max_distance_factor) {
  if (cls.empty()) return Status::BadInput("the program commands no cutting moves");
  if (!(r > 0)) return Status::BadInput(Where{.field = "tool.radius_mm"}, "must be > 0");
  // Pass index per location: given, or a new pass at every location not fed from its predecessor.
  std::vector<int> pass(cls.size());
  int run = 0;
  for (std::size_t k = 0; k < cls.size(); ++k) {
    if (k > 0 && !cls[k].fed_from_previous) ++run;
    pass[k] = cls[k].pass >= 0 ? cls[k].pass : run;
  }
  // Kd-tree over ball centres relative to their centroid (FLANN works in float; candidates are
  // re-ranked in double).
  Eigen::Vector3d origin = Eigen::Vector3d::Zero();
  for (const auto& cl : cls) origin += cl.centre;
  origin /= static_cast<double>(cls.size());
  pcl::PointCloud<pcl::PointXYZ>::Ptr cloud(new pcl::PointCloud<pcl::PointXYZ>);
  cloud->reserve(cls.size());
  for (const auto& cl : cls) {
    const Eigen::Vector3d p = cl.centre - origin;
    cloud->push_back(pcl::PointXYZ(static_cast<float>(p.x()), static_cast<float>(p.y()), static_cast<float>(p.z())));
  }
  pcl::KdTreeFLANN<pcl::PointXYZ> tree;
  tree.setInputCloud(cloud);

  constexpr int kCandidates = 48;
  pcl::Indices found;
  std::vector<float> distances;
  std::vector<PointContext> out;
  out.reserve(points.size());
  for (const MeasuredPoint& mp : points) {
    const Eigen::Vector3d query = mp.point + r * mp.normal - origin;
    tree.nearestKSearch(
        pcl::PointXYZ(static_cast<float>(query.x()), static_cast<float>(query.y()), static_cast<float>(query.z())),
        kCandidates, found, distances);
    double envelope = 1e300;
    std::size_t nearest = 0;
    double nearest_d2 = 1e300;
    for (const auto idx : found) {
      const std::size_t k = static_cast<std::size_t>(idx);
      envelope = std::min(envelope, (cls[k].centre - mp.point).norm() - r);
      for (std::size_t other : {k - 1, k + 1}) {
        if (k == 0 && other == k - 1) continue;
        if (other >= cls.size()) continue;
        if (!cls[std::max(k, other)].fed_from_previous) continue;
        envelope = std::min(envelope, SegmentDistance(mp.point, cls[k].centre, cls[other].centre) - r);
      }
      const double d2 = (cls[k].centre - (mp.point + r * mp.normal)).squaredNorm();
      if (d2 < nearest_d2) {
        nearest_d2 = d2;
        nearest = k;
      }
    }
    if (std::sqrt(nearest_d2) > max_distance_factor * r) {
      return Status::BadInput("point " + std::to_string(mp.id) +
                              " lies outside the machined area (nearest cutter location " +
                              std::to_string(std::sqrt(nearest_d2)) + " mm away). Fix: probe inside the tool path");
    }
    const CutterLocation& cut = cls[nearest];
    PointContext c;
    c.id = mp.id;
    c.point = mp.point;
    c.normal = mp.normal;
    c.approach = mp.approach;
    c.path_length_mm = cut.path_length_mm;
    c.cut_time_s = cut.time_s;
    c.pass = pass[nearest];
    // Feed direction: along the pass through this location (central difference inside the pass).
    std::size_t a = nearest, b = nearest;
    if (nearest > 0 && pass[nearest - 1] == pass[nearest] && cls[nearest].fed_from_previous) a = nearest - 1;
    if (nearest + 1 < cls.size() && pass[nearest + 1] == pass[nearest] && cls[nearest + 1].fed_from_previous) {
      b = nearest + 1;
    }
    const Eigen::Vector3d f = cls[b].centre - cls[a].centre;
    c.feed = f.norm() > 0 ? Eigen::Vector3d(f / f.norm()) : Eigen::Vector3d::UnitX();
    // Radial engagement: the distance across the feed to the nearest location of another pass (the
    // local step-over), over r, capped at 1 (full slot).
    double step = 1e300;
    for (const auto idx : found) {
      const std::size_t k = static_cast<std::size_t>(idx);
      if (pass[k] == c.pass) continue;
      Eigen::Vector3d d = cls[k].centre - cut.centre;
      d -= d.dot(c.feed) * c.feed;
      step = std::min(step, d.norm());
    }
    c.engagement = step < 1e299 ? std::min(1.0, step / r) : 0.0;
    c.scallop_um = 1e3 * envelope;
    out.push_back(c);
  }
  // A point on an outer pass has no neighbour pass on one side only; one with no other pass among its
  // candidates at all (a single-pass program) gets the mean engagement of the others.
  double sum = 0;
  int n = 0;
  for (const auto& c : out) {
    if (c.engagement > 0) {
      sum += c.engagement;
      ++n;
    }
  }
  for (auto& c : out) {
    if (c.engagement == 0 && n > 0) c.engagement = sum / n;
  }
  return out;
}

}  // namespace formloop::sim
