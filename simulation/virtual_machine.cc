#include "simulation/virtual_machine.h"

#include <algorithm>
#include <cmath>

#include <pcl/kdtree/kdtree_flann.h>
#include <pcl/point_types.h>

#include "core/random.h"

namespace formloop::sim {
namespace {

// Distance from p to the segment [a, b].
double SegmentDistance(const Eigen::Vector3d& p, const Eigen::Vector3d& a, const Eigen::Vector3d& b) {
  const Eigen::Vector3d ab = b - a;
  const double len2 = ab.squaredNorm();
  const double t = len2 > 0 ? std::clamp((p - a).dot(ab) / len2, 0.0, 1.0) : 0.0;
  return (a + t * ab - p).norm();
}

}  // namespace

Status MachineEffects::Validate() const {
  if (!(thermal_tau_s > 0)) return Status::BadInput(Where{.field = "machine.effects.thermal_tau_s"}, "must be > 0");
  if (surface_noise_um < 0 || probe_noise_um < 0) {
    return Status::BadInput(Where{.field = "machine.effects"}, "noise sigmas must be >= 0");
  }
  for (double x : {tool_radius_error_um, deflection_um, thermal_amplitude_um, surface_noise_um, probe_noise_um}) {
    if (!std::isfinite(x)) return Status::BadInput(Where{.field = "machine.effects"}, "values must be finite");
  }
  return Status::Ok();
}

nlohmann::json MachineEffects::ToJson() const {
  return {{"tool_radius", {{"delta_r_um", tool_radius_error_um}}},
          {"tool_deflection", {{"k_d_um", deflection_um}}},
          {"thermal_drift_z", {{"A_um", thermal_amplitude_um}, {"tau_s", thermal_tau_s}}},
          {"noise", {{"surface_sigma_um", surface_noise_um}, {"probe_sigma_um", probe_noise_um}}}};
}

Status VirtualMachineOptions::Validate() const {
  if (!(tool_radius_mm > 0)) return Status::BadInput(Where{.field = "tool.radius_mm"}, "must be > 0");
  FL_RETURN_IF_ERROR(effects.Validate());
  FL_RETURN_IF_ERROR(true_probe.Validate());
  if (!(probe_seconds_per_point > 0)) {
    return Status::BadInput(Where{.field = "machine.probe_seconds_per_point"}, "must be > 0");
  }
  return Status::Ok();
}

Result<VirtualMachineResult> MachineAndProbe(const recon::BSplineSurface& surface,
                                             const std::vector<CutterLocation>& cutter_locations,
                                             const metrology::ProbingPlan& plan, const VirtualMachineOptions& options) {
  FL_RETURN_IF_ERROR(options.Validate());
  if (cutter_locations.empty()) return Status::BadInput("the program commands no cutting moves");
  const double r = options.tool_radius_mm;
  // Kd-tree over ball centres (float coordinates relative to their centroid: FLANN works in float;
  // candidates are re-ranked in double below).
  Eigen::Vector3d origin = Eigen::Vector3d::Zero();
  for (const auto& cl : cutter_locations) origin += cl.centre;
  origin /= static_cast<double>(cutter_locations.size());
  pcl::PointCloud<pcl::PointXYZ>::Ptr cloud(new pcl::PointCloud<pcl::PointXYZ>);
  cloud->reserve(cutter_locations.size());
  for (const auto& cl : cutter_locations) {
    const Eigen::Vector3d p = cl.centre - origin;
    cloud->push_back(pcl::PointXYZ(static_cast<float>(p.x()), static_cast<float>(p.y()), static_cast<float>(p.z())));
  }
  pcl::KdTreeFLANN<pcl::PointXYZ> tree;
  tree.setInputCloud(cloud);

  Rng rng(options.seed);
  VirtualMachineResult result;
  const MachineEffects& e = options.effects;
  double t_probe = 0;
  constexpr int kCandidates = 48;
  pcl::Indices found;
  std::vector<float> distances;
  for (const metrology::ProbePoint& pp : plan.points) {
    const Eigen::Vector3d n = pp.normal;
    // The ball that cut here sits about r above the point along n.
    const Eigen::Vector3d query = pp.point + r * n - origin;
    tree.nearestKSearch(pcl::PointXYZ(static_cast<float>(query.x()), static_cast<float>(query.y()),
                                      static_cast<float>(query.z())),
                        kCandidates, found, distances);
    double envelope = 1e300;
    std::size_t nearest = 0;
    double nearest_d2 = 1e300;
    for (const auto idx : found) {
      const std::size_t k = static_cast<std::size_t>(idx);
      const CutterLocation& cl = cutter_locations[k];
      envelope = std::min(envelope, (cl.centre - pp.point).norm() - r);
      // The ball sweeps the feed segments on either side of this location.
      for (std::size_t other : {k - 1, k + 1}) {
        if (k == 0 && other == k - 1) continue;
        if (other >= cutter_locations.size()) continue;
        const std::size_t later = std::max(k, other);
        if (!cutter_locations[later].fed_from_previous) continue;
        envelope = std::min(envelope, SegmentDistance(pp.point, cl.centre, cutter_locations[other].centre) - r);
      }
      const double d2 = (cl.centre - (pp.point + r * n)).squaredNorm();
      if (d2 < nearest_d2) {
        nearest_d2 = d2;
        nearest = static_cast<std::size_t>(idx);
      }
    }
    if (std::sqrt(nearest_d2) > 5.0 * r) {
      return Status::BadInput("probe point " + std::to_string(pp.id) +
                              " lies outside the machined area (nearest cutter location " +
                              std::to_string(std::sqrt(nearest_d2)) + " mm away). Fix: probe inside the tool path");
    }
    const CutterLocation& cut = cutter_locations[nearest];
    InjectedTruth truth;
    truth.id = pp.id;
    truth.scallop_um = 1e3 * envelope;
    truth.tool_radius_um = e.tool_radius_error_um;
    truth.deflection_um = e.deflection_um * (1.0 - n.z() * n.z());
    truth.thermal_um = -e.thermal_amplitude_um * (1.0 - std::exp(-cut.time_s / e.thermal_tau_s)) * n.z();
    truth.roughness_um = e.surface_noise_um * rng.Normal();
    truth.probe_noise_um = e.probe_noise_um * rng.Normal();
    const Eigen::Vector3d machined = pp.point + 1e-3 * truth.total_um() * n;
    metrology::ProbeRecord record;
    record.id = pp.id;
    record.approach = -n;
    // The ball touches the machined surface; the trigger reports its centre R_eff back along a,
    // with the probe's repeatability along the approach.
    record.centre = machined - options.true_probe.EffectiveRadius(record.approach) * record.approach +
                    1e-3 * truth.probe_noise_um * record.approach;
    t_probe += options.probe_seconds_per_point;
    record.t_s = t_probe;
    result.log.records.push_back(record);
    result.truth.push_back(truth);
  }
  return result;
}

nlohmann::json VirtualMachineResult::ReportJson() const {
  auto stats = [&](auto getter) {
    double mn = 1e300, mx = -1e300, sum = 0;
    for (const auto& t : truth) {
      const double x = getter(t);
      mn = std::min(mn, x);
      mx = std::max(mx, x);
      sum += x;
    }
    const double mean = truth.empty() ? 0 : sum / static_cast<double>(truth.size());
    return nlohmann::json{{"min", mn}, {"max", mx}, {"mean", mean}};
  };
  return {{"probed_points", truth.size()},
          {"injected_um",
           {{"scallop", stats([](const InjectedTruth& t) { return t.scallop_um; })},
            {"tool_radius", stats([](const InjectedTruth& t) { return t.tool_radius_um; })},
            {"tool_deflection", stats([](const InjectedTruth& t) { return t.deflection_um; })},
            {"thermal_drift_z", stats([](const InjectedTruth& t) { return t.thermal_um; })},
            {"roughness", stats([](const InjectedTruth& t) { return t.roughness_um; })},
            {"probe_noise", stats([](const InjectedTruth& t) { return t.probe_noise_um; })},
            {"total_surface", stats([](const InjectedTruth& t) { return t.total_um(); })}}}};
}

}  // namespace formloop::sim
