#include "nc-gen/toolpath.h"

#include <algorithm>
#include <cmath>
#include <unordered_map>
#include <vector>

#include <Eigen/Geometry>

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

// What one pass (iso-v curve) needs: the largest convex normal curvature across it, the largest
// curvature of the ball-centre path along it, and the largest parametric speeds.
struct PassProbe {
  double kappa_across = -1e300;
  double kappa_centre = 0;  // centre path: curve curvature κ_c plus r κ_n² where convex (κ_n > 0)
  double speed_u = 0, speed_v = 0;
};

PassProbe ProbePass(const recon::BSplineSurface& surface, const recon::ParamDomain& dom, double v, double r) {
  constexpr int kProbe = 81;  // samples along a pass used to size the step-over and point spacing
  PassProbe p;
  for (int i = 0; i < kProbe; ++i) {
    const double u = dom.u_min + dom.u_span() * i / (kProbe - 1);
    const recon::SurfaceDerivatives d = surface.Derivatives(u, v);
    p.kappa_across = std::max(p.kappa_across, NormalCurvature(d, 0, 1));
    const double kn = NormalCurvature(d, 1, 0);
    const double su = d.su.norm();
    const double kc = su > 0 ? d.su.cross(d.suu).norm() / (su * su * su) : 0;
    p.kappa_centre = std::max(p.kappa_centre, std::max(kc, std::abs(kn)) + r * std::max(kn, 0.0) * kn);
    p.speed_u = std::max(p.speed_u, su);
    p.speed_v = std::max(p.speed_v, d.sv.norm());
  }
  return p;
}

// Step-over that keeps h = s²/8 · (1/r + κ) at the target for the convex curvature κ across the passes.
double StepOver(double h, double r, double kappa_across) {
  const double curvature_term = std::max(1.0 / r + kappa_across, 0.05 / r);
  return std::sqrt(8.0 * h / curvature_term);
}

// xy positions of samples of Q whose smallest principal curvature is below −1/r, hashed in cells of
// size r, to find the CL points whose ball can reach such a region.
class ConcaveRegions {
 public:
  ConcaveRegions(const recon::BSplineSurface& surface, const recon::ParamDomain& dom, double r) : r_(r) {
    constexpr double kSpacing = 0.5;  // mm in parameter space
    const int nu = std::clamp(static_cast<int>(std::ceil(dom.u_span() / kSpacing)) + 1, 9, 801);
    const int nv = std::clamp(static_cast<int>(std::ceil(dom.v_span() / kSpacing)) + 1, 9, 801);
    for (int j = 0; j < nv; ++j) {
      for (int i = 0; i < nu; ++i) {
        const double u = dom.u_min + dom.u_span() * i / (nu - 1);
        const double v = dom.v_min + dom.v_span() * j / (nv - 1);
        const recon::SurfaceDerivatives d = surface.Derivatives(u, v);
        if (recon::CurvaturesFromDerivatives(d).k2 < -1.0 / r) Add(d.p);
      }
    }
  }
  void Add(const Eigen::Vector3d& p) { cells_[Key(Cell(p.x()), Cell(p.y()))].push_back(p); }
  bool empty() const { return cells_.empty(); }
  // True when a concave sample lies within horizontal distance r (+ one sample spacing) of p.
  bool Near(const Eigen::Vector3d& p) const {
    const double reach = r_ + 0.75;
    const long long ci = Cell(p.x()), cj = Cell(p.y());
    for (long long i = ci - 2; i <= ci + 2; ++i) {
      for (long long j = cj - 2; j <= cj + 2; ++j) {
        const auto it = cells_.find(Key(i, j));
        if (it == cells_.end()) continue;
        for (const Eigen::Vector3d& q : it->second) {
          if ((q - p).head<2>().squaredNorm() <= reach * reach) return true;
        }
      }
    }
    return false;
  }

 private:
  long long Cell(double x) const { return static_cast<long long>(std::floor(x / r_)); }
  static long long Key(long long i, long long j) { return i * 2000003LL + j; }
  double r_;
  std::unordered_map<long long, std::vector<Eigen::Vector3d>> cells_;
};

// Drop-cutter test against a dense local sample of Q: how far the ball centred at b must rise along ẑ
// so that no point of Q within horizontal distance r lies inside the ball (0 if none does).
double DropLift(const recon::BSplineSurface& surface, const recon::ParamDomain& dom, double u, double v,
                const recon::SurfaceDerivatives& d, const Eigen::Vector3d& b, double r) {
  // Parameter half-widths that cover horizontal distance r (with a margin for varying speed).
  const double wu = 1.5 * r / std::max(d.su.head<2>().norm(), 1e-3);
  const double wv = 1.5 * r / std::max(d.sv.head<2>().norm(), 1e-3);
  const auto need_at = [&](double uu, double vv) {
    const Eigen::Vector3d s = surface.Point(uu, vv);
    const double dh2 = (s - b).head<2>().squaredNorm();
    if (dh2 >= r * r) return -1e300;
    return s.z() + std::sqrt(r * r - dh2) - b.z();
  };
  double best = 0, bu = u, bv = v;
  // Coarse grid over the window, then two refinements around the worst sample.
  double cu = u, cv = v, hu = wu, hv = wv;
  int n = 24;
  for (int level = 0; level < 3; ++level) {
    const double u_lo = std::max(dom.u_min, cu - hu), u_hi = std::min(dom.u_max, cu + hu);
    const double v_lo = std::max(dom.v_min, cv - hv), v_hi = std::min(dom.v_max, cv + hv);
    for (int j = 0; j <= n; ++j) {
      for (int i = 0; i <= n; ++i) {
        const double uu = u_lo + (u_hi - u_lo) * i / n, vv = v_lo + (v_hi - v_lo) * j / n;
        const double need = need_at(uu, vv);
        if (need > best) {
          best = need;
          bu = uu;
          bv = vv;
        }
      }
    }
    if (best <= 0) break;
    cu = bu;
    cv = bv;
    hu = 2 * (u_hi - u_lo) / n;
    hv = 2 * (v_hi - v_lo) / n;
    n = 16;
  }
  return best;
}

}  // namespace

Result<Toolpath> PlanRaster(const recon::BSplineSurface& surface, const ToolpathOptions& options) {
  FL_RETURN_IF_ERROR(options.Validate());
  if (!surface.valid()) return Status::Internal("PlanRaster: no surface");
  const recon::ParamDomain dom = surface.domain();
  const double r = options.tool.radius_mm;
  const double h = options.scallop_um * 1e-3;
  const double chord = options.chord_tolerance_um * 1e-3;
  const ConcaveRegions concave(surface, dom, r);
  // Where the ball is lifted it rests on Q at up to two points and its centre follows arcs of radius up
  // to r: spacing for the chord tolerance on such an arc, with a margin.
  const double lifted_spacing = 0.6 * std::sqrt(8.0 * chord * r);

  Toolpath path;
  path.options = options;
  path.min_step_over_mm = 1e300;
  path.max_step_over_mm = 0;

  double v = dom.v_min;
  int pass = 0;
  PassProbe probe = ProbePass(surface, dom, v, r);
  while (true) {
    // Along the pass: the sag of a chord of length L on a path of curvature κ is L²κ/8.
    double spacing = options.max_point_spacing_mm;
    if (probe.kappa_centre > 1e-12) spacing = std::min(spacing, std::sqrt(8.0 * chord / probe.kappa_centre));
    const auto n_for = [&](double sp) {
      return std::max(2, static_cast<int>(std::ceil(dom.u_span() * probe.speed_u / sp)) + 1);
    };
    int n_points = n_for(spacing);
    // Passes that reach a concave region below the ball radius get the lifted-path spacing.
    bool at_risk = false;
    if (!concave.empty()) {
      for (int i = 0; i < n_points && !at_risk; ++i) {
        at_risk = concave.Near(surface.Point(dom.u_min + dom.u_span() * i / (n_points - 1), v));
      }
      if (at_risk && spacing > lifted_spacing) n_points = n_for(lifted_spacing);
    }
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
      if (at_risk && concave.Near(cl.cc)) {
        const double lift = DropLift(surface, dom, u, v, d, cl.cc + r * cl.normal, r);
        if (lift > 1e-6) {
          cl.lift_mm = lift;
          const Eigen::Vector3d& p = cl.cc;
          if (path.lifted_points == 0) path.lifted_box_min = path.lifted_box_max = p;
          path.lifted_box_min = path.lifted_box_min.cwiseMin(p);
          path.lifted_box_max = path.lifted_box_max.cwiseMax(p);
          path.max_lift_mm = std::max(path.max_lift_mm, lift);
          path.lifted_indices.push_back(static_cast<int>(path.points.size()));
          ++path.lifted_points;
        }
      }
      path.points.push_back(cl);
    }
    ++pass;
    if (v >= dom.v_max) break;
    // Across the passes: h = s²/8 · (1/r + κ), κ the largest convex curvature on this pass and the next.
    double step = StepOver(h, r, probe.kappa_across);
    double v_next = std::min(dom.v_max, v + step / probe.speed_v);
    PassProbe next = ProbePass(surface, dom, v_next, r);
    const double step_next = StepOver(h, r, next.kappa_across);
    if (step_next < step || next.speed_v > probe.speed_v) {
      step = std::min(step, step_next);
      v_next = std::min(dom.v_max, v + step / std::max(probe.speed_v, next.speed_v));
      next = ProbePass(surface, dom, v_next, r);
    }
    path.min_step_over_mm = std::min(path.min_step_over_mm, step);
    path.max_step_over_mm = std::max(path.max_step_over_mm, step);
    v = (v_next >= dom.v_max - 1e-9) ? dom.v_max : v_next;
    probe = next;
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
    cl.centre = cl.cc + r * cl.normal + cl.lift_mm * Eigen::Vector3d::UnitZ();
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
          {"gouge_risk_points", gouge_risk_points},
          {"lifted",
           {{"note", "CL points lifted along the tool axis so the ball stays out of Q where its concave radius is below "
                     "the ball radius: the region is never cut to Q"},
            {"points", lifted_points},
            {"max_lift_mm", max_lift_mm},
            {"cc_box_min_mm", {lifted_box_min.x(), lifted_box_min.y(), lifted_box_min.z()}},
            {"cc_box_max_mm", {lifted_box_max.x(), lifted_box_max.y(), lifted_box_max.z()}},
            {"cl_indices", lifted_indices}}},
          {"lifted_points", lifted_points}};
}

}  // namespace formloop::nc
