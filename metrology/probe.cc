#include "metrology/probe.h"

#include <cmath>
#include <map>

#include "core/atomic_file.h"
#include "core/point_io.h"

namespace formloop::metrology {

nlohmann::json ProbingPlan::ToJson() const {
  nlohmann::json points_json = nlohmann::json::array();
  for (const ProbePoint& p : points) {
    points_json.push_back({{"id", p.id},
                           {"u", p.u},
                           {"v", p.v},
                           {"point", {p.point.x(), p.point.y(), p.point.z()}},
                           {"normal", {p.normal.x(), p.normal.y(), p.normal.z()}}});
  }
  return {{"count", points.size()}, {"points", points_json}};
}

Result<ProbingPlan> PlanProbingGrid(const recon::BSplineSurface& surface, int nu, int nv, double inset_fraction) {
  if (nu < 2 || nv < 2) return Status::BadInput(Where{.field = "probing.grid"}, "needs at least 2 × 2 points");
  if (!(inset_fraction >= 0 && inset_fraction < 0.5)) {
    return Status::BadInput(Where{.field = "probing.inset_fraction"}, "must be in [0, 0.5)");
  }
  const recon::ParamDomain dom = surface.domain();
  const double u0 = dom.u_min + inset_fraction * dom.u_span(), u1 = dom.u_max - inset_fraction * dom.u_span();
  const double v0 = dom.v_min + inset_fraction * dom.v_span(), v1 = dom.v_max - inset_fraction * dom.v_span();
  ProbingPlan plan;
  for (int j = 0; j < nv; ++j) {
    for (int i = 0; i < nu; ++i) {
      ProbePoint p;
      p.id = static_cast<std::int64_t>(j) * nu + i + 1;
      p.u = u0 + (u1 - u0) * i / (nu - 1);
      p.v = v0 + (v1 - v0) * j / (nv - 1);
      p.point = surface.Point(p.u, p.v);
      p.normal = surface.Normal(p.u, p.v);
      plan.points.push_back(p);
    }
  }
  return plan;
}

Result<ProbeLog> ReadProbeLog(const std::filesystem::path& path) {
  FL_ASSIGN_OR_RETURN(PointSet points, ReadCsv(path));
  const std::string file = path.string();
  const auto* ax = points.FindScalar("ax");
  const auto* ay = points.FindScalar("ay");
  const auto* az = points.FindScalar("az");
  if (ax == nullptr || ay == nullptr || az == nullptr) {
    return Status::BadInput(Where{.file = file, .field = "ax/ay/az"}, "approach-direction columns are missing",
                            "a probe log has the columns id,x,y,z,ax,ay,az,t");
  }
  if (!points.has_ids()) {
    return Status::BadInput(Where{.file = file, .field = "id"}, "column is missing",
                            "a probe log has the columns id,x,y,z,ax,ay,az,t");
  }
  if (!points.has_times()) {
    return Status::BadInput(Where{.file = file, .field = "t"}, "column is missing",
                            "a probe log has the columns id,x,y,z,ax,ay,az,t");
  }
  ProbeLog log;
  std::map<std::int64_t, std::size_t> seen;
  for (std::size_t i = 0; i < points.size(); ++i) {
    ProbeRecord r;
    r.id = points.ids[i];
    r.centre = points.points[i];
    r.approach = Eigen::Vector3d((*ax)[i], (*ay)[i], (*az)[i]);
    r.t_s = points.times_s[i];
    const double norm = r.approach.norm();
    if (std::abs(norm - 1.0) > 1e-3) {
      return Status::BadInput(Where{.file = file, .field = "ax/ay/az"},
                              "approach direction of id " + std::to_string(r.id) + " has length " +
                                  FormatFixed(norm, 6) + ", not 1",
                              "write unit approach vectors");
    }
    r.approach /= norm;
    if (!seen.emplace(r.id, i).second) {
      return Status::BadInput(Where{.file = file, .field = "id"}, "id " + std::to_string(r.id) + " appears twice",
                              "give every probe point its own id");
    }
    log.records.push_back(r);
  }
  return log;
}

Status WriteProbeLog(const std::filesystem::path& path, const ProbeLog& log) {
  // Column order as in spec/metrology.md §1; 1 nm resolution.
  std::string text = "# formloop probe log: ball centre (mm), unit approach direction, time (s)\n";
  text += "id,x,y,z,ax,ay,az,t\n";
  for (const ProbeRecord& r : log.records) {
    if (!r.centre.allFinite() || !r.approach.allFinite() || !std::isfinite(r.t_s)) {
      return Status::Internal("probe record " + std::to_string(r.id) + " is not finite; " + path.string() +
                              " was not written");
    }
    text += std::to_string(r.id);
    for (int a = 0; a < 3; ++a) text += "," + FormatFixed(r.centre[a], 6);
    for (int a = 0; a < 3; ++a) text += "," + FormatFixed(r.approach[a], 9);
    text += "," + FormatFixed(r.t_s, 3) + "\n";
  }
  return WriteFileAtomic(path, text);
}

Status ProbeModel::Validate() const {
  if (!(ball_radius_mm > 0)) return Status::BadInput(Where{.field = "probe.ball_radius_mm"}, "must be > 0");
  if (!(std::abs(pretravel_mm) < ball_radius_mm)) {
    return Status::BadInput(Where{.field = "probe.pretravel_mm"}, "must be smaller than the ball radius");
  }
  return Status::Ok();
}

Eigen::Vector3d ContactPoint(const ProbeRecord& record, const ProbeModel& model) {
  return record.centre + model.EffectiveRadius(record.approach) * record.approach;
}

}  // namespace formloop::metrology
