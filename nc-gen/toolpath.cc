#include "nc-gen/toolpath.h"

#include <algorithm>
#include <cmath>

namespace formloop::nc {

Status ToolpathOptions::Validate() const {
  auto bad = [](const std::string& field, const std::string& what) {
    return Status::BadInput(Where{.field = field}, what);
  };
  if (!(tool.radius_mm > 0)) return bad("tool.radius_mm", "must be > 0");
  if (!(scallop_um > 0) || scallop_um >= 1000 * tool.radius_mm) {
    return bad("toolpath.scallop_um", "must be > 0 and below the tool radius");
  }
  if (!(chord_tolerance_um > 0)) return bad("toolpath.chord_tolerance_um", "must be > 0");
  if (!(max_point_spacing_mm > 0)) return bad("toolpath.max_point_spacing_mm", "must be > 0");
  if (!(feed_mm_per_min > 0)) return bad("toolpath.feed_mm_per_min", "must be > 0");
  if (!(plunge_feed_mm_per_min > 0)) return bad("toolpath.plunge_feed_mm_per_min", "must be > 0");
  if (!(spindle_rpm > 0)) return bad("toolpath.spindle_rpm", "must be > 0");
  if (!(clearance_mm > 0)) return bad("toolpath.clearance_mm", "must be > 0");
  return Status::Ok();
}

namespace {

// Normal curvature of Q at (u, v) in the parameter direction (du, dv); positive = convex (bends away
// from n), as in reconstruction/analytic_surface.h.
double NormalCurvature(const recon::SurfaceDerivatives& d, double du, double dv) {
  const Eigen::Vector3d n = recon::NormalFromDerivatives(d);
  const Eigen::Vector3d t = d.su * du + d.sv * dv;
  const double second = (d.suu * du * du + 2 * d.suv * du * dv + d.svv * dv * dv).dot(n);
  return -second / t.squaredNorm();
}

}  // namespace

Result<Toolpath> PlanRaster(const recon::BSplineSurface& surface, const ToolpathOptions& options) {
  FL_RETURN_IF_ERROR(options.Validate());
  if (!surface.valid()) return Status::Internal("PlanRaster: no surface");
  const recon::ParamDomain dom = surface.domain();
  const double r = options.tool.radius_mm;
  const double h = options.scallop_um * 1e-3;
  const double chord = options.chord_tolerance_um * 1e-3;
  constexpr int kProbe = 41;  // samples along a pass used to size the step-over and point spacing

  Toolpath path;
  path.options = options;
  path.min_step_over_mm = 1e300;
  path.max_step_over_mm = 0;

  double v = dom.v_min;
  int pass = 0;
  while (true) {
    // Curvature across and along this pass, and parametric speeds.
    double kappa_across = -1e300, kappa_along = 0, speed_u = 0, speed_v = 0;
    for (int i = 0; i < kProbe; ++i) {
      const double u = dom.u_min + dom.u_span() * i / (kProbe - 1);
      const recon::SurfaceDerivatives d = surface.Derivatives(u, v);
      kappa_across = std::max(kappa_across, NormalCurvature(d, 0, 1));
      kappa_along = std::max(kappa_along, std::abs(NormalCurvature(d, 1, 0)));
      speed_u = std::max(speed_u, d.su.norm());
      speed_v = std::max(speed_v, d.sv.norm());
    }
    // Along the pass: chord error of an arc of radius ρ over length L is L²/(8ρ).
    double spacing = options.max_point_spacing_mm;
    if (kappa_along > 1e-12) spacing = std::min(spacing, std::sqrt(8.0 * chord / kappa_along));
    const int n_points = std::max(2, static_cast<int>(std::ceil(dom.u_span() * speed_u / spacing)) + 1);
    const bool reverse = options.zigzag && (pass % 2 == 1);
    for (int i = 0; i < n_points; ++i) {
      const int k = reverse ? n_points - 1 - i : i;
      const double u = dom.u_min + dom.u_span() * k / (n_points - 1);
      const recon::SurfaceDerivatives d = surface.Derivatives(u, v);
      ClPoint cl;
      cl.pass = pass;
      cl.index_in_pass = i;
      cl.u = u;
      cl.v = v;
      cl.cc = d.p;
      cl.normal = recon::NormalFromDerivatives(d);
      const recon::PrincipalCurvatures curvatures = recon::CurvaturesFromDerivatives(d);
      if (curvatures.k2 < -1.0 / r) ++path.gouge_risk_points;
      path.points.push_back(cl);
    }
    ++pass;
    if (v >= dom.v_max) break;
    // Across the passes: h = s²/8 · (1/r + κ) for a ball on a surface of normal curvature κ.
    const double curvature_term = std::max(1.0 / r + kappa_across, 0.05 / r);
    const double step = std::sqrt(8.0 * h / curvature_term);
    path.min_step_over_mm = std::min(path.min_step_over_mm, step);
    path.max_step_over_mm = std::max(path.max_step_over_mm, step);
    const double dv = step / speed_v;
    v = (v + dv >= dom.v_max - 1e-9) ? dom.v_max : v + dv;
  }
  path.passes = pass;
  UpdateCutterLocations(&path);
  return path;
}

void UpdateCutterLocations(Toolpath* path) {
  const double r = path->options.tool.radius_mm;
  const double feed_mm_per_s = path->options.feed_mm_per_min / 60.0;
  double length = 0, max_tip_z = -1e300;
  for (std::size_t k = 0; k < path->points.size(); ++k) {
    ClPoint& cl = path->points[k];
    cl.centre = cl.cc + r * cl.normal;
    cl.tip = cl.centre - r * Eigen::Vector3d::UnitZ();
    if (k > 0 && path->points[k - 1].pass == cl.pass) length += (cl.tip - path->points[k - 1].tip).norm();
    cl.path_length_mm = length;
    cl.time_s = length / feed_mm_per_s;
    max_tip_z = std::max(max_tip_z, cl.tip.z());
  }
  path->total_length_mm = length;
  path->total_time_s = length / feed_mm_per_s;
  path->safe_z_mm = max_tip_z + path->options.clearance_mm;
}

nlohmann::json Toolpath::ReportJson() const {
  return {{"strategy", "iso-v raster (section planes y = const on graph surfaces)"},
          {"zigzag", options.zigzag},
          {"tool", {{"number", options.tool.number}, {"type", "ball_end"}, {"radius_mm", options.tool.radius_mm}}},
          {"scallop_target_um", options.scallop_um},
          {"chord_tolerance_um", options.chord_tolerance_um},
          {"passes", passes},
          {"cl_points", points.size()},
          {"step_over_mm", {{"min", min_step_over_mm}, {"max", max_step_over_mm}}},
          {"cutting_length_mm", total_length_mm},
          {"cutting_time_s", total_time_s},
          {"safe_z_mm", safe_z_mm},
          {"gouge_risk_points", gouge_risk_points}};
}

}  // namespace formloop::nc
