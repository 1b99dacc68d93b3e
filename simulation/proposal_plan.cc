#include "simulation/proposal_plan.h"

#include <algorithm>
#include <cmath>
#include <numbers>

#include "core/json_io.h"

namespace formloop::sim {
namespace {

constexpr double kDeg = std::numbers::pi / 180.0;

}  // namespace

PlannedProposal PlannedProposal::Of(const ExperimentProposal& proposal, const recon::ParamDomain& domain) {
  PlannedProposal out;
  out.members = proposal.members;
  out.kind = proposal.kind;
  out.raster_turn_deg = proposal.raster_turn_deg;
  out.feed_scale = proposal.feed_scale;
  if (proposal.kind != "reprobe") return out;
  for (std::size_t i = 0; i < proposal.plan.points.size(); ++i) {
    const metrology::ProbePoint& p = proposal.plan.points[i];
    const Eigen::Vector3d n = p.normal.normalized();
    const Eigen::Vector3d a =
        i < proposal.approaches.size() ? proposal.approaches[i].normalized() : Eigen::Vector3d(-n);
    Point q;
    q.s = domain.u_span() > 0 ? std::clamp((p.u - domain.u_min) / domain.u_span(), 0.0, 1.0) : 0.5;
    q.t = domain.v_span() > 0 ? std::clamp((p.v - domain.v_min) / domain.v_span(), 0.0, 1.0) : 0.5;
    q.tilt_deg = std::acos(std::clamp(-a.dot(n), -1.0, 1.0)) / kDeg;
    const Eigen::Vector3d tangential = a + a.dot(-n) * n;  // a's part in the tangent plane
    q.azimuth_deg = tangential.norm() > 1e-9 ? std::atan2(tangential.y(), tangential.x()) / kDeg : 0.0;
    out.points.push_back(q);
  }
  return out;
}

nlohmann::json PlannedProposal::ToJson() const {
  nlohmann::json j = {{"alias_group", members}, {"kind", kind}};
  if (kind == "reprobe") {
    nlohmann::json rows = nlohmann::json::array();
    for (const Point& p : points) {
      rows.push_back({{"s", p.s}, {"t", p.t}, {"tilt_deg", p.tilt_deg}, {"azimuth_deg", p.azimuth_deg}});
    }
    j["points"] = rows;
  } else {
    j["raster_turn_deg"] = raster_turn_deg;
    j["feed_scale"] = feed_scale;
  }
  return j;
}

Result<PlannedProposal> PlannedProposal::FromJson(const nlohmann::json& j, const std::string& source,
                                                  const std::string& prefix) {
  if (!j.is_object()) {
    return Status::BadInput(Where{.file = source, .field = prefix.empty() ? "(top level)" : prefix},
                            "a planned proposal must be a JSON object",
                            "use the \"next_part\" object of a proposal of formloop diagnose");
  }
  JsonFields f(j, source, prefix);
  FL_RETURN_IF_ERROR(f.CheckKnown({"alias_group", "kind", "points", "raster_turn_deg", "feed_scale"}));
  PlannedProposal out;
  FL_RETURN_IF_ERROR(f.StringArray("alias_group", &out.members));
  FL_RETURN_IF_ERROR(f.String("kind", &out.kind));
  if (out.kind == "reprobe") {
    std::vector<JsonFields> points;
    FL_RETURN_IF_ERROR(f.ObjectArray("points", &points));
    if (points.empty() || points.size() > 1000) {
      return Status::BadInput(Where{.file = source, .field = f.Path("points")},
                              "must hold 1..1000 points, got " + std::to_string(points.size()));
    }
    for (const JsonFields& p : points) {
      FL_RETURN_IF_ERROR(p.CheckKnown({"s", "t", "tilt_deg", "azimuth_deg"}));
      Point q;
      FL_RETURN_IF_ERROR(p.Number("s", &q.s, {.min = 0, .max = 1}));
      FL_RETURN_IF_ERROR(p.Number("t", &q.t, {.min = 0, .max = 1}));
      // A probe comes down onto the part: at most 60° from the normal (the design's tilts are 30°).
      FL_RETURN_IF_ERROR(p.Number("tilt_deg", &q.tilt_deg, {.min = 0, .max = 60}));
      FL_RETURN_IF_ERROR(p.Number("azimuth_deg", &q.azimuth_deg, {.min = -360, .max = 360}));
      out.points.push_back(q);
    }
  } else if (out.kind == "raster_turn" || out.kind == "feed") {
    FL_RETURN_IF_ERROR(f.Number("raster_turn_deg", &out.raster_turn_deg, {.min = -360, .max = 360}));
    FL_RETURN_IF_ERROR(f.Number("feed_scale", &out.feed_scale, {.min = 0.1, .max = 2}));
  } else {
    return Status::BadInput(Where{.file = source, .field = f.Path("kind")}, "unknown kind '" + out.kind + "'",
                            "use reprobe, raster_turn or feed");
  }
  return out;
}

PathChange PathChangeOf(const std::vector<PlannedProposal>& proposals) {
  PathChange out;
  bool turned = false, scaled = false;
  for (const PlannedProposal& p : proposals) {
    if (p.kind == "raster_turn" && !turned) {
      out.raster_turn_deg = p.raster_turn_deg;
      turned = true;
    }
    if (p.kind == "feed" && !scaled) {
      out.feed_scale = p.feed_scale;
      scaled = true;
    }
  }
  return out;
}

PlanWithProposals ApplyProposals(const metrology::ProbingPlan& plan, const recon::BSplineSurface& q,
                                 const std::vector<PlannedProposal>& proposals) {
  PlanWithProposals out;
  out.plan = plan;
  for (const auto& p : plan.points) out.approaches.push_back(-p.normal);
  std::int64_t next_id = 0;
  for (const auto& p : plan.points) next_id = std::max(next_id, p.id);
  const recon::ParamDomain dom = q.domain();
  const PathChange change = PathChangeOf(proposals);
  out.raster_turn_deg = change.raster_turn_deg;
  out.feed_scale = change.feed_scale;
  for (const PlannedProposal& proposal : proposals) {
    for (const PlannedProposal::Point& pp : proposal.points) {
      metrology::ProbePoint p;
      p.u = dom.u_min + pp.s * dom.u_span();
      p.v = dom.v_min + pp.t * dom.v_span();
      p.point = q.Point(p.u, p.v);
      p.normal = q.Normal(p.u, p.v);
      const Eigen::Vector3d e(std::cos(pp.azimuth_deg * kDeg), std::sin(pp.azimuth_deg * kDeg), 0.0);
      Eigen::Vector3d d = e - e.dot(p.normal) * p.normal;
      const double tilt = pp.tilt_deg * kDeg;
      const bool allowed = metrology::ProbePositionAllowed(q, p.u, p.v, p.point, plan.edge_margin_mm);
      if (!allowed || (tilt > 0 && d.norm() < 1e-6)) {
        ++out.dropped;
        continue;
      }
      d = d.norm() < 1e-6 ? Eigen::Vector3d::Zero() : Eigen::Vector3d(d.normalized());
      const Eigen::Vector3d a = (-std::cos(tilt) * p.normal + std::sin(tilt) * d).normalized();
      if (a.z() >= -kMinApproachDown) {
        ++out.dropped;
        continue;
      }
      p.id = ++next_id;
      out.plan.points.push_back(p);
      out.approaches.push_back(a);
      ++out.added;
    }
  }
  return out;
}

}  // namespace formloop::sim
