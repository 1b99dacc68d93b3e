#include "metrology/deviations.h"

#include <unordered_map>

namespace formloop::metrology {

Result<std::vector<Deviation>> ComputeDeviations(const recon::BSplineSurface& surface, const ProbingPlan& plan,
                                                 const ProbeLog& log, const ProbeModel& probe) {
  FL_RETURN_IF_ERROR(probe.Validate());
  std::unordered_map<std::int64_t, const ProbePoint*> by_id;
  for (const ProbePoint& p : plan.points) by_id[p.id] = &p;
  std::vector<Deviation> out;
  out.reserve(log.records.size());
  for (const ProbeRecord& record : log.records) {
    auto it = by_id.find(record.id);
    if (it == by_id.end()) {
      return Status::BadInput(Where{.field = "id"},
                              "probe log id " + std::to_string(record.id) + " is not in the probing plan",
                              "use the log written for this plan");
    }
    Deviation d;
    d.id = record.id;
    d.contact = ContactPoint(record, probe);
    FL_ASSIGN_OR_RETURN(recon::FootPoint foot, recon::ProjectFrom(surface, d.contact, it->second->u, it->second->v));
    d.u = foot.u;
    d.v = foot.v;
    d.foot = foot.foot;
    d.normal = foot.normal;
    d.deviation_mm = foot.deviation_mm;
    d.outside_trim = foot.outside_trim;
    d.on_boundary = foot.on_boundary || foot.outside_trim;
    out.push_back(d);
  }
  return out;
}

PointSet DeviationsToPoints(const std::vector<Deviation>& deviations) {
  PointSet points;
  std::vector<double> u, v, fx, fy, fz, dev_um, boundary;
  for (const Deviation& d : deviations) {
    points.points.push_back(d.contact);
    points.normals.push_back(d.normal);
    points.ids.push_back(d.id);
    u.push_back(d.u);
    v.push_back(d.v);
    fx.push_back(d.foot.x());
    fy.push_back(d.foot.y());
    fz.push_back(d.foot.z());
    dev_um.push_back(d.deviation_mm * 1e3);
    boundary.push_back(d.on_boundary ? 1 : 0);
  }
  points.SetScalar("u", std::move(u));
  points.SetScalar("v", std::move(v));
  points.SetScalar("foot_x", std::move(fx));
  points.SetScalar("foot_y", std::move(fy));
  points.SetScalar("foot_z", std::move(fz));
  points.SetScalar("deviation_um", std::move(dev_um));
  points.SetScalar("on_boundary", std::move(boundary));
  return points;
}

Result<SpatialWeights> UvKnnWeights(const std::vector<Deviation>& deviations, int k) {
  Eigen::MatrixXd uv(2, static_cast<Eigen::Index>(deviations.size()));  // one column per point
  for (std::size_t i = 0; i < deviations.size(); ++i) {
    uv(0, static_cast<Eigen::Index>(i)) = deviations[i].u;
    uv(1, static_cast<Eigen::Index>(i)) = deviations[i].v;
  }
  return KnnWeights(uv, k, WeightStyle::kRowStandardised);
}

}  // namespace formloop::metrology
