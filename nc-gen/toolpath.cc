// The raster planner (nc-gen/toolpath.h): the options check, the step-over and concave-region helpers,
// the section tracing (plane crossings, sections, clipping to the trim and the neighbours' clearance,
// leads, contour thinning), PlanRaster itself and the path summaries.
//
// Why one file of ~980 lines: PlanRaster (about 300 lines) is one algorithm that uses nearly every helper
// above it, and the helpers are internal to it; splitting the section tracing into its own file would
// publish a dozen internals (RasterFrame, Section, Domain, TraceSection, ClipSection, LeadArc, ...) in a
// header for no other reader. The sections follow the order of the planner's steps.

#include "nc-gen/toolpath.h"

#include <algorithm>
#include <array>
#include <bit>
#include <cmath>
#include <cstdint>
#include <optional>
#include <unordered_map>
#include <vector>

#include <fmt/format.h>
#include <Eigen/Cholesky>
#include <Eigen/Geometry>
#include <Eigen/LU>

#include <BRepBndLib.hxx>
#include <Bnd_Box.hxx>
#include <TopoDS_Face.hxx>

#include "core/number_text.h"
#include "reconstruction/span_polynomials.h"
#include "reconstruction/trim.h"

namespace formloop::nc {

Status ToolpathOptions::Validate() const {
  auto bad = [](const std::string& field, const std::string& what) {
    return Status::BadInput(Where{.field = field}, what);
  };
  // Upper bounds far beyond any real ball-end finishing job, short of what a wrong unit gives.
  if (!(tool.radius_mm > 0 && tool.radius_mm <= 50)) return bad("tool.radius_mm", "must lie in (0, 50] mm");
  if (!(scallop_um > 0) || scallop_um >= 1000 * tool.radius_mm || scallop_um > 1000) {
    return bad("toolpath.scallop_um", "must be > 0, at most 1000 um and below the tool radius");
  }
  if (!(chord_tolerance_um > 0 && chord_tolerance_um <= 1000)) {
    return bad("toolpath.chord_tolerance_um", "must lie in (0, 1000] um");
  }
  if (!(max_point_spacing_mm > 0 && max_point_spacing_mm <= 100)) {
    return bad("toolpath.max_point_spacing_mm", "must lie in (0, 100] mm");
  }
  if (!(feed_mm_per_min > 0 && feed_mm_per_min <= 200000)) {
    return bad("toolpath.feed_mm_per_min", "must lie in (0, 200000] mm/min");
  }
  if (!(plunge_feed_mm_per_min > 0 && plunge_feed_mm_per_min <= 200000)) {
    return bad("toolpath.plunge_feed_mm_per_min", "must lie in (0, 200000] mm/min");
  }
  if (!(spindle_rpm > 0 && spindle_rpm <= 200000)) return bad("toolpath.spindle_rpm", "must lie in (0, 200000] rpm");
  if (!(clearance_mm > 0 && clearance_mm <= 1000)) return bad("toolpath.clearance_mm", "must lie in (0, 1000] mm");
  if (!std::isfinite(raster_angle_deg)) return bad("toolpath.raster_angle_deg", "must be a finite angle in degrees");
  if (!(lead_mm >= 0) || lead_mm > 100) return bad("toolpath.lead_mm", "must be between 0 (no leads) and 100 mm");
  return Status::Ok();
}

namespace {

// Q as the planner evaluates it: through its span polynomials (reconstruction/span_polynomials.h: each
// knot span converted once to a power-form polynomial, the point and its derivatives in one pass, about
// ten times faster than OpenCASCADE's Geom_BSplineSurface::D2 and within 1e-12 mm of it on the domain;
// a rational or periodic Q, or one whose polynomials would take more than 64 MB, is evaluated by
// OpenCASCADE), and each evaluation remembered by its exact (u, v) in a small direct-mapped table
// (derivatives and points apart), so the sample a section's Newton solve ends on is not evaluated again
// by the step-over, the cut point or the clearance checks that follow, and the domain edges' samples,
// where every plane's crossings are looked for, are mostly found from the planes before (a slot another
// evaluation took is evaluated again: only time, never a different answer). One per PlanRaster call (not
// shared between threads).
class MemoSurface {
 public:
  explicit MemoSurface(const recon::BSplineSurface& q) : q_(q), derivatives_(kSlots), points_(kSlots) {
    const Handle(Geom_BSplineSurface)& g = q.geom();
    if (recon::SpanPolynomials::EstimateBytes(g->UDegree(), g->VDegree(), g->NbUKnots() - 1, g->NbVKnots() - 1) <=
        kMaxPolynomialBytes) {
      Result<recon::SpanPolynomials> polynomials = recon::SpanPolynomials::Of(q);
      if (polynomials.ok()) {
        polynomials_ = std::move(polynomials).value();
        evaluator_.emplace(polynomials_);
      }
    }
  }
  MemoSurface(const MemoSurface&) = delete;
  MemoSurface& operator=(const MemoSurface&) = delete;
  Eigen::Vector3d Point(double u, double v) const {
    return Remembered(points_, u, v, [&] { return evaluator_ ? evaluator_->Point(u, v) : q_.Point(u, v); });
  }
  recon::SurfaceDerivatives Derivatives(double u, double v) const {
    return Remembered(derivatives_, u, v, [&] { return evaluator_ ? evaluator_->D2(u, v) : q_.Derivatives(u, v); });
  }
  const recon::Trim* trim() const { return q_.trim(); }

 private:
  static constexpr int kSlotBits = 13;
  static constexpr std::size_t kSlots = std::size_t{1} << kSlotBits;
  template <typename T>
  struct Slot {
    std::uint64_t u = 0, v = 0;
    bool filled = false;
    T value;
  };
  template <typename T, typename Evaluate>
  static T Remembered(std::vector<Slot<T>>& table, double u, double v, const Evaluate& evaluate) {
    const std::uint64_t bu = std::bit_cast<std::uint64_t>(u), bv = std::bit_cast<std::uint64_t>(v);
    Slot<T>& slot = table[((bu * 0x9E3779B97F4A7C15ULL) ^ (bv * 0xC2B2AE3D27D4EB4FULL)) >> (64 - kSlotBits)];
    if (!slot.filled || slot.u != bu || slot.v != bv) {
      slot.value = evaluate();
      slot.u = bu;
      slot.v = bv;
      slot.filled = true;
    }
    return slot.value;
  }
  static constexpr double kMaxPolynomialBytes = 64e6;  // as the foot-point projector's limit
  const recon::BSplineSurface& q_;
  recon::SpanPolynomials polynomials_;
  mutable std::optional<recon::SpanPolynomials::Evaluator> evaluator_;
  mutable std::vector<Slot<recon::SurfaceDerivatives>> derivatives_;
  mutable std::vector<Slot<Eigen::Vector3d>> points_;
};

// Normal curvature of Q at (u, v) in the parameter direction (du, dv); positive = convex (bends away
// from n), as in reconstruction/analytic_surface.h.
double NormalCurvature(const recon::SurfaceDerivatives& d, double du, double dv) {
  const Eigen::Vector3d n = recon::NormalFromDerivatives(d);
  const Eigen::Vector3d t = d.su * du + d.sv * dv;
  const double second = (d.suu * du * du + 2 * d.suv * du * dv + d.svv * dv * dv).dot(n);
  return -second / t.squaredNorm();
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
  ConcaveRegions(const MemoSurface& surface, const recon::ParamDomain& dom, double r) : r_(r) {
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
// The window is centred on (u, v) and covers horizontal distance `reach` (1.5 r by default: the ball
// centre is above the CC point (u, v) within r).
double DropLift(const MemoSurface& surface, const recon::ParamDomain& dom, double u, double v,
                const recon::SurfaceDerivatives& d, const Eigen::Vector3d& b, double r, double reach = 0) {
  // Parameter half-widths that cover horizontal distance r (with a margin for varying speed).
  if (reach <= 0) reach = 1.5 * r;
  const double wu = reach / std::max(d.su.head<2>().norm(), 1e-3);
  const double wv = reach / std::max(d.sv.head<2>().norm(), 1e-3);
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

namespace {

// The raster's frame: cutting direction d and section-plane normal m, both horizontal.
struct RasterFrame {
  Eigen::Vector3d d, m;
  explicit RasterFrame(double angle_deg) {
    const double a = angle_deg * M_PI / 180.0;
    d = Eigen::Vector3d(std::cos(a), std::sin(a), 0);
    m = Eigen::Vector3d(-std::sin(a), std::cos(a), 0);
  }
};

// Solves S(u, v)·m = c, S(u, v)·d = s by Newton from (*u, *v), clamped to the domain. False when it
// does not converge to 1e-9 mm inside the domain (the point (c, s) is not over Q).
bool SolveOnPlane(const MemoSurface& q, const recon::ParamDomain& dom, const RasterFrame& f, double c, double s,
                  double* u, double* v) {
  for (int it = 0; it < 40; ++it) {
    const recon::SurfaceDerivatives d = q.Derivatives(*u, *v);
    const Eigen::Vector2d residual(d.p.dot(f.m) - c, d.p.dot(f.d) - s);
    Eigen::Matrix2d jacobian;
    jacobian << d.su.dot(f.m), d.sv.dot(f.m), d.su.dot(f.d), d.sv.dot(f.d);
    if (residual.lpNorm<Eigen::Infinity>() < 1e-12) return true;
    if (!(std::abs(jacobian.determinant()) > 1e-14)) return false;
    const Eigen::Vector2d step = jacobian.partialPivLu().solve(residual);
    // Damped where the full step would leave the domain: the largest fraction that stays inside.
    double alpha = 1.0;
    const auto limit = [&alpha](double x, double dx, double lo, double hi) {
      if (x - dx < lo && dx > 0) alpha = std::min(alpha, (x - lo) / dx);
      if (x - dx > hi && dx < 0) alpha = std::min(alpha, (x - hi) / dx);
    };
    limit(*u, step[0], dom.u_min, dom.u_max);
    limit(*v, step[1], dom.v_min, dom.v_max);
    // At the boundary and pushing out: a projected step (the solution may lie on the boundary itself;
    // if it lies outside, the iterate stalls and the residual check below refuses it).
    if (alpha < 1e-12) alpha = 1.0;
    const double nu = std::clamp(*u - alpha * step[0], dom.u_min, dom.u_max);
    const double nv = std::clamp(*v - alpha * step[1], dom.v_min, dom.v_max);
    if (nu == *u && nv == *v) break;
    *u = nu;
    *v = nv;
  }
  const Eigen::Vector3d p = q.Point(*u, *v);
  return std::abs(p.dot(f.m) - c) < 1e-9 && std::abs(p.dot(f.d) - s) < 1e-9;
}

// A point where the plane meets the domain boundary.
struct EdgeCrossing {
  double u = 0, v = 0, s = 0;
};

// The domain's four edges as (u, v) segments.
std::array<std::array<Eigen::Vector2d, 2>, 4> DomainEdges(const recon::ParamDomain& dom) {
  const Eigen::Vector2d a(dom.u_min, dom.v_min), b(dom.u_max, dom.v_min), c(dom.u_max, dom.v_max),
      e(dom.u_min, dom.v_max);
  return {{{a, b}, {b, c}, {c, e}, {e, a}}};
}

constexpr int kEdgeSamples = 128;  // samples per domain edge to find where a plane crosses it

// A sample of the boundary this near the plane (mm) is on it. Exact zeros are not enough: along a
// straight domain edge S·m varies by rounding (1e-16 mm on a fitted face, more on a CAD face whose
// poles were written in decimals), and a first or last plane along such an edge would then meet it at
// one sample instead of running along it, and the edge's pass would be lost.
constexpr double kOnPlaneMm = 1e-9;

// Where plane S·m = c crosses the domain boundary, by sign changes on sampled edges refined by regula
// falsi (Illinois); samples on the plane (kOnPlaneMm) count too (a plane through a corner or along an
// edge).
std::vector<EdgeCrossing> PlaneCrossings(const MemoSurface& q, const recon::ParamDomain& dom, const RasterFrame& f,
                                         double c) {
  std::vector<EdgeCrossing> out;
  const auto add = [&](const Eigen::Vector2d& uv) {
    const Eigen::Vector3d p = q.Point(uv.x(), uv.y());
    for (const auto& e : out) {
      if (std::abs(e.u - uv.x()) + std::abs(e.v - uv.y()) < 1e-12) return;
    }
    out.push_back({uv.x(), uv.y(), p.dot(f.d)});
  };
  for (const auto& edge : DomainEdges(dom)) {
    const auto at = [&](double t) { return Eigen::Vector2d(edge[0] + t * (edge[1] - edge[0])); };
    const auto g = [&](double t) {
      const Eigen::Vector2d uv = at(t);
      return q.Point(uv.x(), uv.y()).dot(f.m) - c;
    };
    double t0 = 0, g0 = g(0);
    for (int i = 1; i <= kEdgeSamples; ++i) {
      const double t1 = static_cast<double>(i) / kEdgeSamples, g1 = g(t1);
      const bool on0 = std::abs(g0) <= kOnPlaneMm, on1 = std::abs(g1) <= kOnPlaneMm;
      if (on0) add(at(t0));
      if (on1) add(at(t1));
      if (!on0 && !on1 && (g0 < 0) != (g1 < 0)) {
        double a = t0, b = t1, ga = g0, gb = g1;
        int side = 0;
        for (int it = 0; it < 100 && b - a > 1e-15; ++it) {
          const double t = (a * gb - b * ga) / (gb - ga);
          const double gt = g(t);
          if (std::abs(gt) < 1e-13) {
            a = b = t;
            break;
          }
          if ((gt < 0) == (ga < 0)) {
            a = t;
            ga = gt;
            if (side == -1) gb *= 0.5;
            side = -1;
          } else {
            b = t;
            gb = gt;
            if (side == 1) ga *= 0.5;
            side = 1;
          }
        }
        add(at(0.5 * (a + b)));
      }
      t0 = t1;
      g0 = g1;
    }
  }
  return out;
}

// One pass: the section of Q by plane c, densely sampled along +d between its two boundary ends.
struct Section {
  double c = 0;
  std::vector<Eigen::Vector2d> uv;  // dense samples (u, v) in order of increasing s
  std::vector<double> s;            // abscissa along d
  std::vector<double> arc;          // cumulative length of the ball-centre path, mm
  double kappa_centre = 0;          // largest curvature of the ball-centre path
  double min_plane_step = 1e300;    // largest plane spacing that keeps the scallop target across this pass
  bool empty() const { return uv.empty(); }
};

// Curvatures, step-over and centre-path length over the samples of one piece.
Section PieceGeometry(const MemoSurface& q, const RasterFrame& f, double c, std::vector<Eigen::Vector2d> uv,
                      std::vector<double> abscissa, double r, double h) {
  Section sec;
  sec.c = c;
  sec.uv = std::move(uv);
  sec.s = std::move(abscissa);
  Eigen::Vector3d previous_centre = Eigen::Vector3d::Zero();
  for (const Eigen::Vector2d& p : sec.uv) {
    const recon::SurfaceDerivatives d = q.Derivatives(p.x(), p.y());
    const Eigen::Vector3d normal = recon::NormalFromDerivatives(d);
    // Tangent-plane directions as (du, dv): solve [Su Sv] (a, b) = t through the first fundamental form.
    Eigen::Matrix2d first;
    first << d.su.dot(d.su), d.su.dot(d.sv), d.su.dot(d.sv), d.sv.dot(d.sv);
    const auto param = [&](const Eigen::Vector3d& t) {
      return Eigen::Vector2d(first.ldlt().solve(Eigen::Vector2d(t.dot(d.su), t.dot(d.sv))));
    };
    Eigen::Vector3d tangent = normal.cross(f.m).normalized();  // along the section, in the plane
    if (tangent.dot(f.d) < 0) tangent = -tangent;
    const Eigen::Vector2d ab = param(tangent);
    const double kn = NormalCurvature(d, ab.x(), ab.y());
    // Meusnier: the section curve's curvature is |κ_n| / |N·n| with N its principal normal (in the plane, ⊥ t).
    const double cos_normal = std::abs(f.m.cross(tangent).dot(normal));
    const double kc = std::abs(kn) / std::max(cos_normal, 0.2);
    sec.kappa_centre = std::max(sec.kappa_centre, std::max(kc, std::abs(kn)) + r * std::max(kn, 0.0) * kn);
    // Across the pass: the unit tangent along m's projection on the tangent plane.
    const Eigen::Vector3d m_t = f.m - f.m.dot(normal) * normal;
    const double m_t_norm = m_t.norm();
    if (m_t_norm > 1e-9) {
      const Eigen::Vector2d ae = param(m_t / m_t_norm);
      const double kappa_across = NormalCurvature(d, ae.x(), ae.y());
      sec.min_plane_step = std::min(sec.min_plane_step, m_t_norm * StepOver(h, r, kappa_across));
    } else {
      // Q is tangent to the plane here (its normal along m: a silhouette, where the planes start or end on
      // a face that turns vertical): a plane a little further crosses Q far from here, so the next one
      // comes a thousandth of a flat step-over on, and the planes after it take their own steps. Without
      // this such a point set no bound, and the next plane went as far as the planes allowed (OCCT
      // hammer.iges face 9, 2,989 mm across: the last one, two one-point passes, exit 0).
      sec.min_plane_step = std::min(sec.min_plane_step, 1e-3 * StepOver(h, r, 0.0));
    }
    const Eigen::Vector3d centre = d.p + r * normal;
    sec.arc.push_back(sec.arc.empty() ? 0.0 : sec.arc.back() + (centre - previous_centre).norm());
    previous_centre = centre;
  }
  return sec;
}

// Every piece of the section of Q by plane c, in order along d. From the lowest boundary crossing the
// plane is followed (Newton continuation in small steps) as far as it stays over Q; the piece ends at
// the last crossing reached, and the next piece starts at the next crossing (the part between is
// outside a non-convex outline). A plane running along a domain edge is one piece; a crossing where
// the plane only touches the outline (a corner at the first or last plane) is a one-point piece.
Result<std::vector<Section>> TraceSection(const MemoSurface& q, const recon::ParamDomain& dom, const RasterFrame& f,
                                          double c, double r, double h) {
  std::vector<EdgeCrossing> ends = PlaneCrossings(q, dom, f, c);
  std::sort(ends.begin(), ends.end(), [](const EdgeCrossing& a, const EdgeCrossing& b) { return a.s < b.s; });
  std::vector<Section> pieces;
  std::size_t i = 0;
  while (i < ends.size()) {
    const EdgeCrossing& lo = ends[i];
    const double far = ends.back().s;
    const double length = far - lo.s;
    std::vector<Eigen::Vector2d> uv{Eigen::Vector2d(lo.u, lo.v)};
    std::vector<double> abscissa{lo.s};
    std::size_t last = i;  // the last crossing reached
    if (length > 1e-9) {
      double reached = far;  // the plane is over Q up to here (the first failed abscissa, else the end)
      const int n = std::clamp(static_cast<int>(std::ceil(length / 0.25)) + 1, 33, 801);
      double u = lo.u, v = lo.v;
      for (int k = 1; k < n; ++k) {
        const double s = lo.s + length * k / (n - 1);
        if (uv.size() >= 2) {  // start Newton from the straight continuation of the last two samples
          const Eigen::Vector2d guess = 2 * uv[uv.size() - 1] - uv[uv.size() - 2];
          u = std::clamp(guess.x(), dom.u_min, dom.u_max);
          v = std::clamp(guess.y(), dom.v_min, dom.v_max);
        }
        if (k == n - 1) {  // the last crossing: known exactly
          uv.emplace_back(ends.back().u, ends.back().v);
          abscissa.push_back(s);
          break;
        }
        if (!SolveOnPlane(q, dom, f, c, s, &u, &v)) {
          reached = s;  // it left Q between the last sample and s: at a crossing in that interval
          break;
        }
        uv.emplace_back(u, v);
        abscissa.push_back(s);
      }
      while (last + 1 < ends.size() && ends[last + 1].s <= reached + 1e-9) ++last;
    }
    // Keep the samples up to the last crossing reached and end exactly on it.
    const EdgeCrossing& hi = ends[last];
    while (abscissa.size() > 1 && abscissa.back() >= hi.s - 1e-9) {
      abscissa.pop_back();
      uv.pop_back();
    }
    if (last != i) {
      uv.emplace_back(hi.u, hi.v);
      abscissa.push_back(hi.s);
    }
    pieces.push_back(PieceGeometry(q, f, c, std::move(uv), std::move(abscissa), r, h));
    i = last + 1;
  }
  return pieces;
}

double MinPlaneStep(const std::vector<Section>& pieces) {
  double step = 1e300;
  for (const Section& p : pieces) step = std::min(step, p.min_plane_step);
  return step;
}

// True when a plane only touches Q (at a corner of its outline) or misses it: no pass runs across Q there.
bool OnlyTouches(const std::vector<Section>& pieces) {
  for (const Section& p : pieces) {
    if (p.uv.size() >= 2 && p.arc.back() > 1e-9) return false;
  }
  return true;
}

// True when the passes meet an edge of Q's parameter box at a slant (its xy direction neither along d
// nor along m, by more than 0.06°, anywhere on it). Ends of neighbouring passes on such an edge are
// farther apart than the step-over, and on one side of each pass the foot of a point on the edge falls
// beyond the pass's end: the edge is left with up to twice the scallop target (a 5 µm target at 45°:
// 11 µm measured on the sphere cap), and the first and last planes only touch corners.
bool SlantedEdges(const MemoSurface& q, const recon::ParamDomain& dom, const RasterFrame& f) {
  constexpr int kSamples = 32;
  for (const auto& edge : DomainEdges(dom)) {
    Eigen::Vector3d previous = q.Point(edge[0].x(), edge[0].y());
    for (int i = 1; i <= kSamples; ++i) {
      const Eigen::Vector2d uv = edge[0] + (static_cast<double>(i) / kSamples) * (edge[1] - edge[0]);
      const Eigen::Vector3d p = q.Point(uv.x(), uv.y());
      const Eigen::Vector3d step = p - previous;
      previous = p;
      const double length = step.head<2>().norm();
      if (!(length > 1e-12)) continue;
      if (std::min(std::abs(step.dot(f.d)), std::abs(step.dot(f.m))) > 1e-3 * length) return true;
    }
  }
  return false;
}

// The boundary of Q's parameter box as one closed loop of (u, v) samples, about 0.05 mm apart (at
// least 64 and at most 20,000 per edge), from (u_min, v_min) on; the start is not repeated at the end.
std::vector<Eigen::Vector2d> BoxLoop(const MemoSurface& q, const recon::ParamDomain& dom) {
  std::vector<Eigen::Vector2d> loop;
  for (const auto& edge : DomainEdges(dom)) {
    double length = 0;
    Eigen::Vector3d previous = q.Point(edge[0].x(), edge[0].y());
    for (int i = 1; i <= 64; ++i) {
      const Eigen::Vector2d uv = edge[0] + (i / 64.0) * (edge[1] - edge[0]);
      const Eigen::Vector3d p = q.Point(uv.x(), uv.y());
      length += (p - previous).norm();
      previous = p;
    }
    const int n = std::clamp(static_cast<int>(std::ceil(length / 0.05)), 64, 20000);
    for (int i = 0; i < n; ++i) loop.push_back(edge[0] + (static_cast<double>(i) / n) * (edge[1] - edge[0]));
  }
  return loop;
}

// A lead at a pass end: a quarter circle in the plane of the path direction t (away from the pass) and
// the normal n of Q there, tangent to the path at the end, curving away from Q: offsets of the tip
// ρ·(sin φ·t + (1 − cos φ)·n), φ = 15°, 30°, ..., 90°, in that order. Moving along the arc the ball
// gains clearance as ρφ²/2 and loses at most (ρφ)²/(2ρ_c) to a concave centre path of radius ρ_c in
// that direction (ρ_c = concave radius of Q − r), so ρ is cut to ρ_c/2 where that is smaller; where Q's
// concave radius is at most r (a lifted region) the lead leaves along n alone. Chords of the arc lie
// on its inner side, away from Q.
std::vector<Eigen::Vector3d> LeadArc(const MemoSurface& q, const ClPoint& end, const Eigen::Vector3d& t, double lead_mm,
                                     double r) {
  constexpr int kSegments = 6;
  const recon::SurfaceDerivatives d = q.Derivatives(end.u, end.v);
  const Eigen::Vector3d& n = end.normal;
  const Eigen::Vector3d tangent = (t - t.dot(n) * n).normalized();
  Eigen::Matrix2d first;
  first << d.su.dot(d.su), d.su.dot(d.sv), d.su.dot(d.sv), d.sv.dot(d.sv);
  const Eigen::Vector2d ab = first.ldlt().solve(Eigen::Vector2d(tangent.dot(d.su), tangent.dot(d.sv)));
  const double kappa = NormalCurvature(d, ab.x(), ab.y());
  double radius = lead_mm;
  bool normal_only = false;
  if (kappa < 0) {
    const double centre_radius = -1.0 / kappa - r;
    if (centre_radius <= 0) {
      normal_only = true;
    } else {
      radius = std::min(radius, 0.5 * centre_radius);
    }
  }
  std::vector<Eigen::Vector3d> out;
  for (int k = 1; k <= kSegments; ++k) {
    const double phi = 0.5 * M_PI * k / kSegments;
    out.push_back(normal_only ? Eigen::Vector3d(lead_mm * k / kSegments * n)
                              : Eigen::Vector3d(radius * (std::sin(phi) * tangent + (1 - std::cos(phi)) * n)));
  }
  return out;
}

// What the planner must respect beyond Q's parameter box: the trim (which (u, v) are the part) and the
// neighbouring faces (the ball must stay clear of them). Without a trim every (u, v) is usable.
class Domain {
 public:
  Domain(const MemoSurface& q, double r) : q_(q), trim_(q.trim()), r_(r) {}
  bool trimmed() const { return trim_ != nullptr && !trim_->natural(); }
  bool has_neighbours() const { return trim_ != nullptr && trim_->has_neighbours(); }
  bool Inside(double u, double v) const { return !trimmed() || trim_->Inside(u, v); }
  // The ball centred at `centre` stays clear of every neighbouring face.
  bool BallClear(const Eigen::Vector3d& centre) const {
    if (!has_neighbours()) return true;
    return trim_->NeighbourDistanceMm(centre, r_) >= r_ - kNeighbourClearanceToleranceMm;
  }
  // The ball moved straight up from `centre` to top_z stays clear (steps of r/2, both ends included).
  bool ColumnClear(const Eigen::Vector3d& centre, double top_z) const {
    if (!has_neighbours()) return true;
    const int steps = std::max(1, static_cast<int>(std::ceil((top_z - centre.z()) / (0.5 * r_))));
    for (int k = 0; k <= steps; ++k) {
      const double z = centre.z() + (top_z - centre.z()) * k / steps;
      if (!BallClear(Eigen::Vector3d(centre.x(), centre.y(), std::max(z, centre.z())))) return false;
    }
    return true;
  }
  // A CC point at (u, v) is usable: inside the trim and its ball clear of the neighbours. Counts the
  // samples inside the trim that the neighbours block.
  bool Usable(double u, double v, int* blocked = nullptr) const {
    if (!Inside(u, v)) return false;
    if (!has_neighbours()) return true;
    const recon::SurfaceDerivatives d = q_.Derivatives(u, v);
    const bool clear = BallClear(d.p + r_ * recon::NormalFromDerivatives(d));
    if (!clear && blocked != nullptr) ++*blocked;
    return clear;
  }
  const recon::Trim* trim() const { return trim_; }

 private:
  const MemoSurface& q_;
  const recon::Trim* trim_;
  double r_;
};

// "(x, y, z) mm at (u, v)" for the messages below.
std::string WhereOnQ(const Eigen::Vector3d& p, double u, double v) {
  return "(" + FormatFixed(p.x(), 3) + ", " + FormatFixed(p.y(), 3) + ", " + FormatFixed(p.z(), 3) +
         ") mm at (u, v) = (" + FormatFixed(u, 4) + ", " + FormatFixed(v, 4) + ")";
}

// A 3-axis ball-end job cuts Q from above: Q's normal, which points away from the material, must point
// up. Where it points down (n_z < 0, an undercut) the ball's centre is below the contact point and the
// shank above the ball (a cylinder of the ball's radius) enters the part by r (1 − √(1 − n_z²)); Q is
// refused where that exceeds the chord tolerance, and a face whose normal points down all over is refused
// as facing down (turned over, it may be right). Checked on a 65 × 65 grid of the parameter box (inside
// the trim) before any section is traced: on a face that faces down the raster would be planned under it,
// and on an overhang the shank would cut the lip.
Status CheckFacesTheTool(const MemoSurface& q, const recon::ParamDomain& dom, const Domain& domain, double r,
                         double chord) {
  constexpr int kGrid = 65;
  int inside = 0, down = 0, undercut = 0;
  double sum_nz = 0, worst_nz = 2, worst_u = 0, worst_v = 0;
  Eigen::Vector3d worst_p = Eigen::Vector3d::Zero();
  for (int j = 0; j < kGrid; ++j) {
    for (int i = 0; i < kGrid; ++i) {
      const double u = dom.u_min + dom.u_span() * i / (kGrid - 1), v = dom.v_min + dom.v_span() * j / (kGrid - 1);
      if (!domain.Inside(u, v)) continue;
      const recon::SurfaceDerivatives d = q.Derivatives(u, v);
      const double nz = recon::NormalFromDerivatives(d).z();
      if (!std::isfinite(nz)) continue;  // a degenerate point (a pole of the parameterisation)
      ++inside;
      sum_nz += nz;
      down += nz <= 0;
      undercut += nz < 0 && r * (1 - std::sqrt(1 - nz * nz)) > chord;
      if (nz < worst_nz) {
        worst_nz = nz;
        worst_u = u;
        worst_v = v;
        worst_p = d.p;
      }
    }
  }
  if (inside > 0 && down == inside) {
    return Status::BadInput(
        Where{.field = "surface"},
        "Q faces down: its normal, which points away from the material, has n_z <= 0 all over the face (mean "
        "n_z " +
            FormatFixed(sum_nz / inside, 3) + "), and a 3-axis ball-end job cuts a face from above (+z)",
        "place the part so that this face looks up (the face in the machine's set-up frame, z up); a face "
        "without a solid whose orientation in the file is the wrong way round (its material below it) is "
        "turned with \"reverse\": true in the part's surface (formloop fit --reverse)");
  }
  if (undercut == 0) return Status::Ok();
  const double depth_um = 1000 * r * (1 - std::sqrt(1 - worst_nz * worst_nz));
  return Status::BadInput(
      Where{.field = "surface"},
      "Q turns under itself: its normal points down at " + FormatFixed(100.0 * undercut / inside, 1) +
          " % of the face, most at " + WhereOnQ(worst_p, worst_u, worst_v) + " (n_z " + FormatFixed(worst_nz, 3) +
          "), where the shank above a " + FormatFixed(r, 3) + " mm ball would cut into the part (by up to " +
          FormatFixed(depth_um, 1) +
          " um, more than the chord tolerance); a 3-axis ball-end cannot reach under an overhang",
      "choose the faces that look up (formloop fit FILE --list-faces lists them) and machine the others in another "
      "set-up");
}

// The runs of usable samples of one section piece, each a new piece whose ends are moved onto the
// boundary of the usable set by bisection along the plane (to 1e-7 mm in the abscissa).
std::vector<Section> ClipSection(const MemoSurface& q, const recon::ParamDomain& dom, const RasterFrame& f,
                                 const Section& piece, const Domain& domain, double r, double h, int* blocked) {
  const std::size_t n = piece.uv.size();
  std::vector<char> usable(n);
  bool all = true;
  for (std::size_t i = 0; i < n; ++i) {
    usable[i] = domain.Usable(piece.uv[i].x(), piece.uv[i].y(), blocked) ? 1 : 0;
    all = all && usable[i];
  }
  if (all) return {piece};
  // The usable end between sample `in` (usable) and `out` (not).
  const auto boundary = [&](std::size_t in, std::size_t out) {
    double s_in = piece.s[in], s_out = piece.s[out];
    Eigen::Vector2d uv_in = piece.uv[in], uv_out = piece.uv[out];
    for (int it = 0; it < 60 && std::abs(s_out - s_in) > 1e-7; ++it) {
      const double s_mid = 0.5 * (s_in + s_out);
      const Eigen::Vector2d guess = 0.5 * (uv_in + uv_out);
      double u = guess.x(), v = guess.y();
      if (SolveOnPlane(q, dom, f, piece.c, s_mid, &u, &v) && domain.Usable(u, v)) {
        s_in = s_mid;
        uv_in = Eigen::Vector2d(u, v);
      } else {
        s_out = s_mid;
        uv_out = guess;
      }
    }
    return std::make_pair(uv_in, s_in);
  };
  std::vector<Section> out;
  std::size_t i = 0;
  while (i < n) {
    if (!usable[i]) {
      ++i;
      continue;
    }
    std::size_t j = i;
    while (j + 1 < n && usable[j + 1]) ++j;
    std::vector<Eigen::Vector2d> uv;
    std::vector<double> abscissa;
    if (i > 0) {
      const auto [b_uv, b_s] = boundary(i, i - 1);
      if (b_s < piece.s[i] - 1e-12) {
        uv.push_back(b_uv);
        abscissa.push_back(b_s);
      }
    }
    for (std::size_t k = i; k <= j; ++k) {
      uv.push_back(piece.uv[k]);
      abscissa.push_back(piece.s[k]);
    }
    if (j + 1 < n) {
      const auto [b_uv, b_s] = boundary(j, j + 1);
      if (b_s > piece.s[j] + 1e-12) {
        uv.push_back(b_uv);
        abscissa.push_back(b_s);
      }
    }
    out.push_back(PieceGeometry(q, f, piece.c, std::move(uv), std::move(abscissa), r, h));
    i = j + 1;
  }
  return out;
}

// CC samples of one contour pass: from the dense loop samples `uv` (in order), the subset whose straight
// ball-centre segments stay within `chord` of every skipped sample's centre and are at most `spacing`
// long, first and last kept.
std::vector<Eigen::Vector2d> ThinContour(const MemoSurface& q, const std::vector<Eigen::Vector2d>& uv, double r,
                                         double chord, double spacing) {
  if (uv.size() <= 2) return uv;
  std::vector<Eigen::Vector3d> centre(uv.size());
  for (std::size_t i = 0; i < uv.size(); ++i) {
    const recon::SurfaceDerivatives d = q.Derivatives(uv[i].x(), uv[i].y());
    centre[i] = d.p + r * recon::NormalFromDerivatives(d);
  }
  std::vector<Eigen::Vector2d> out{uv.front()};
  std::size_t i = 0;
  while (i + 1 < uv.size()) {
    std::size_t best = i + 1;
    for (std::size_t j = i + 2; j < uv.size(); ++j) {
      const Eigen::Vector3d a = centre[i], b = centre[j];
      if ((b - a).norm() > spacing) break;
      bool ok = true;
      for (std::size_t k = i + 1; k < j && ok; ++k) {
        const Eigen::Vector3d ab = b - a;
        const double t = std::clamp((centre[k] - a).dot(ab) / std::max(ab.squaredNorm(), 1e-300), 0.0, 1.0);
        ok = (a + t * ab - centre[k]).norm() <= chord;
      }
      if (!ok) break;
      best = j;
    }
    out.push_back(uv[best]);
    i = best;
  }
  return out;
}

}  // namespace

Result<Toolpath> PlanRaster(const recon::BSplineSurface& q, const ToolpathOptions& options) {
  FL_RETURN_IF_ERROR(options.Validate());
  if (!q.valid()) return Status::Internal("PlanRaster: no surface");
  const recon::ParamDomain dom = q.domain();
  const MemoSurface surface(q);
  const double r = options.tool.radius_mm;
  const double h = options.scallop_um * 1e-3;
  const double chord = options.chord_tolerance_um * 1e-3;
  const RasterFrame frame(options.raster_angle_deg);
  const Domain domain(surface, r);
  FL_RETURN_IF_ERROR(CheckFacesTheTool(surface, dom, domain, r, chord));
  const ConcaveRegions concave(surface, dom, r);
  // Where the ball is lifted it rests on Q at up to two points and its centre follows arcs of radius up
  // to r: spacing for the chord tolerance on such an arc, with a margin.
  const double lifted_spacing = 0.6 * std::sqrt(8.0 * chord * r);

  // The planes cover the range of S·m over the domain boundary (for a graph over XY, S·m has no
  // interior extremum); the extremes are taken at the same samples PlaneCrossings uses, so the first and
  // last planes meet the boundary exactly.
  double c_min = 1e300, c_max = -1e300;
  for (const auto& edge : DomainEdges(dom)) {
    for (int i = 0; i <= kEdgeSamples; ++i) {
      const Eigen::Vector2d uv = edge[0] + (static_cast<double>(i) / kEdgeSamples) * (edge[1] - edge[0]);
      const double c = surface.Point(uv.x(), uv.y()).dot(frame.m);
      c_min = std::min(c_min, c);
      c_max = std::max(c_max, c);
    }
  }

  Toolpath path;
  path.options = options;
  path.min_step_over_mm = 1e300;
  path.max_step_over_mm = 0;
  path.trimmed = domain.trimmed();
  path.neighbours_checked = domain.has_neighbours();
  if (domain.has_neighbours()) {
    // The highest neighbouring geometry within reach of the tool over Q (its bounding box widened by the
    // ball and the leads): rapids between passes run above it.
    Eigen::AlignedBox3d reach;
    for (int j = 0; j <= 32; ++j) {
      for (int i = 0; i <= 32; ++i)
        reach.extend(surface.Point(dom.u_min + dom.u_span() * i / 32, dom.v_min + dom.v_span() * j / 32));
    }
    const double margin = r + options.lead_mm + 1.0;
    double top = -1e300;
    for (const TopoDS_Face& face : domain.trim()->neighbours()) {
      Bnd_Box box;
      BRepBndLib::Add(face, box);
      double x0, y0, z0, x1, y1, z1;
      box.Get(x0, y0, z0, x1, y1, z1);
      if (x1 < reach.min().x() - margin || x0 > reach.max().x() + margin || y1 < reach.min().y() - margin ||
          y0 > reach.max().y() + margin) {
        continue;
      }
      top = std::max(top, z1);
    }
    if (top > -1e300) path.min_safe_z_mm = top + options.clearance_mm;
  }
  const double column_top = std::isfinite(path.min_safe_z_mm) ? path.min_safe_z_mm : -1e300;

  const auto tip_of = [r](const ClPoint& cl) {
    return Eigen::Vector3d(cl.cc + r * cl.normal + (cl.lift_mm - r) * Eigen::Vector3d::UnitZ());
  };
  const auto lead_point = [](ClKind kind, const ClPoint& end, const Eigen::Vector3d& tip) {
    ClPoint lead;
    lead.kind = kind;
    lead.pass = end.pass;
    lead.u = end.u;
    lead.v = end.v;
    lead.cc = tip;  // off Q: cc = tip and normal = ẑ make the centre tip + r ẑ
    lead.normal = Eigen::Vector3d::UnitZ();
    return lead;
  };
  // The tip offsets of a lead at `end` leaving along t: the arc of LeadArc, or, where it (or the vertical
  // retract above its outer end) would bring the ball nearer than r to a neighbouring face, a straight
  // lead along the normal, then a vertical one. Error when none is clear.
  const auto clear_lead = [&](const ClPoint& end, const Eigen::Vector3d& t) -> Result<std::vector<Eigen::Vector3d>> {
    std::vector<Eigen::Vector3d> offsets = LeadArc(surface, end, t, options.lead_mm, r);
    if (!domain.has_neighbours()) return offsets;
    const Eigen::Vector3d tip = tip_of(end);
    const auto clear = [&](const std::vector<Eigen::Vector3d>& o) {
      for (const Eigen::Vector3d& offset : o) {
        if (!domain.BallClear(tip + offset + r * Eigen::Vector3d::UnitZ())) return false;
      }
      return domain.ColumnClear(tip + o.back() + r * Eigen::Vector3d::UnitZ(), column_top);
    };
    if (clear(offsets)) return offsets;
    const int k_max = static_cast<int>(offsets.size());
    for (const Eigen::Vector3d& direction : {Eigen::Vector3d(end.normal), Eigen::Vector3d(Eigen::Vector3d::UnitZ())}) {
      for (int k = 1; k <= k_max; ++k)
        offsets[static_cast<std::size_t>(k - 1)] = options.lead_mm * k / k_max * direction;
      if (clear(offsets)) {
        ++(direction.z() == 1.0 && direction.head<2>().isZero() ? path.leads_vertical : path.leads_along_normal);
        return offsets;
      }
    }
    return Status::Failed(
        "tool path: the pass ending at (" + FormatFixed(end.cc.x(), 3) + ", " + FormatFixed(end.cc.y(), 3) + ", " +
        FormatFixed(end.cc.z(), 3) +
        ") has no lead that keeps the ball clear of the neighbouring faces (arc, along the normal and "
        "vertical all reach them); choose a smaller tool or machine this region from another set-up");
  };

  int pass = 0;  // one pass per piece of a section, then one per contour run
  // Leads, the lift of leads near concave regions, and the pass appended to the path.
  const auto finish_pass = [&](std::vector<ClPoint> cut, const Eigen::Vector3d& along, bool at_risk) -> Status {
    for (ClPoint& cl : cut) cl.pass = pass;
    // Tangential leads: along the tip path's direction at each end (`along` for a one-point pass).
    const auto direction = [&](const Eigen::Vector3d& from, const Eigen::Vector3d& to) {
      const Eigen::Vector3d t = to - from;
      return t.norm() > 1e-9 ? Eigen::Vector3d(t.normalized()) : along;
    };
    std::vector<ClPoint> points;
    if (options.lead_mm > 0) {
      const Eigen::Vector3d t0 = cut.size() > 1 ? direction(tip_of(cut[0]), tip_of(cut[1])) : along;
      FL_ASSIGN_OR_RETURN(const std::vector<Eigen::Vector3d> arc, clear_lead(cut.front(), -t0));
      for (auto it = arc.rbegin(); it != arc.rend(); ++it) {
        points.push_back(lead_point(ClKind::kLeadIn, cut.front(), tip_of(cut.front()) + *it));
      }
    }
    points.insert(points.end(), cut.begin(), cut.end());
    if (options.lead_mm > 0) {
      const std::size_t k = cut.size() - 1;
      const Eigen::Vector3d t1 = cut.size() > 1 ? direction(tip_of(cut[k - 1]), tip_of(cut[k])) : along;
      FL_ASSIGN_OR_RETURN(const std::vector<Eigen::Vector3d> arc, clear_lead(cut.back(), t1));
      for (const Eigen::Vector3d& offset : arc) {
        points.push_back(lead_point(ClKind::kLeadOut, cut.back(), tip_of(cut.back()) + offset));
      }
    }
    // On a pass near a concave region below the ball radius the lead arcs are checked like CL points
    // (the local argument of LeadArc does not hold there) and lifted clear of Q.
    if (at_risk) {
      for (ClPoint& cl : points) {
        if (cl.kind == ClKind::kCut) continue;
        const Eigen::Vector3d centre = cl.cc + r * Eigen::Vector3d::UnitZ();
        const recon::SurfaceDerivatives d = surface.Derivatives(cl.u, cl.v);
        const double reach = 1.5 * r + (centre - d.p).head<2>().norm();
        const double lift = DropLift(surface, dom, cl.u, cl.v, d, centre, r, reach);
        if (lift > 1e-6) cl.cc.z() += lift;
      }
    }
    for (std::size_t i = 0; i < points.size(); ++i) {
      points[i].index_in_pass = static_cast<int>(i);
      path.points.push_back(points[i]);
    }
    ++pass;
    return Status::Ok();
  };
  // A cut CL at (u, v): CC point, normal, gouge-risk count and the drop-cutter lift near concave regions.
  const auto cut_point = [&](double u, double v, bool at_risk) {
    const recon::SurfaceDerivatives d = surface.Derivatives(u, v);
    ClPoint cl;
    cl.u = u;
    cl.v = v;
    cl.cc = d.p;
    cl.normal = recon::NormalFromDerivatives(d);
    if (recon::CurvaturesFromDerivatives(d).k2 < -1.0 / r) ++path.gouge_risk_points;
    if (at_risk && concave.Near(cl.cc)) {
      const double lift = DropLift(surface, dom, u, v, d, cl.cc + r * cl.normal, r);
      if (lift > 1e-6) cl.lift_mm = lift;
    }
    return cl;
  };
  const auto near_concave = [&](const std::vector<Eigen::Vector2d>& uv) {
    if (concave.empty()) return false;
    for (const auto& p : uv) {
      if (concave.Near(surface.Point(p.x(), p.y()))) return true;
    }
    return false;
  };

  double c = c_min;
  int plane = 0;  // sections with at least one piece
  FL_ASSIGN_OR_RETURN(std::vector<Section> sections, TraceSection(surface, dom, frame, c, r, h));
  while (true) {
    // The pieces that are cut: clipped to the usable set on a trimmed Q or beside neighbouring faces (the
    // step-over below is planned on the whole sections).
    std::vector<Section> cut_sections;
    if (domain.trimmed() || domain.has_neighbours()) {
      for (const Section& piece : sections) {
        for (Section& clipped :
             ClipSection(surface, dom, frame, piece, domain, r, h, &path.neighbour_blocked_samples)) {
          cut_sections.push_back(std::move(clipped));
        }
      }
    } else {
      cut_sections = sections;
    }
    // Pieces of one plane are cut in the pass direction: along d, or against it on reversed passes.
    const bool reversed = options.zigzag && plane % 2 == 1;
    if (reversed) std::reverse(cut_sections.begin(), cut_sections.end());
    if (!cut_sections.empty()) ++plane;
    for (const Section& section : cut_sections) {
      // Along the pass: the sag of a chord of length L on a path of curvature κ is L²κ/8 (3 % margin for
      // the interpolated arc length).
      double spacing = options.max_point_spacing_mm;
      if (section.kappa_centre > 1e-12) spacing = std::min(spacing, std::sqrt(8.0 * chord / section.kappa_centre));
      spacing *= 0.97;
      const double length = section.arc.back();
      const auto n_for = [&](double sp) { return std::max(2, static_cast<int>(std::ceil(length / sp)) + 1); };
      int n_points = section.uv.size() == 1 ? 1 : n_for(spacing);
      const bool at_risk = near_concave(section.uv);
      if (at_risk && n_points > 1 && spacing > lifted_spacing) n_points = n_for(lifted_spacing);
      std::vector<ClPoint> cut;
      cut.reserve(n_points);
      std::size_t j = 0;  // dense sample at or before the target arc length
      for (int i = 0; i < n_points; ++i) {
        double u = section.uv.back().x(), v = section.uv.back().y();
        if (i == 0) {
          u = section.uv.front().x();
          v = section.uv.front().y();
        } else if (i < n_points - 1) {
          const double target = length * i / (n_points - 1);
          while (j + 2 < section.arc.size() && section.arc[j + 1] < target) ++j;
          const double span = section.arc[j + 1] - section.arc[j];
          const double t = span > 0 ? std::clamp((target - section.arc[j]) / span, 0.0, 1.0) : 0.0;
          const double s = section.s[j] + t * (section.s[j + 1] - section.s[j]);
          u = section.uv[j].x() + t * (section.uv[j + 1].x() - section.uv[j].x());
          v = section.uv[j].y() + t * (section.uv[j + 1].y() - section.uv[j].y());
          if (!SolveOnPlane(surface, dom, frame, section.c, s, &u, &v)) {
            // Between two samples of the section Q turned too steep to follow along the plane (it passes
            // the facing check above on its grid, and folds between the grid's samples or outside the trim).
            const Eigen::Vector3d p = surface.Point(u, v);
            return Status::BadInput(Where{.field = "surface"},
                                    "the raster cannot follow Q near " + WhereOnQ(p, u, v) +
                                        ": Q is nearly vertical or folds over there (on the face or on the "
                                        "untrimmed surface under it)",
                                    "choose the faces that look up (formloop fit FILE --list-faces lists them), or "
                                    "try another raster angle (--raster-angle, toolpath.raster_angle_deg)");
          }
        }
        cut.push_back(cut_point(u, v, at_risk));
      }
      if (reversed) std::reverse(cut.begin(), cut.end());
      FL_RETURN_IF_ERROR(finish_pass(std::move(cut), reversed ? Eigen::Vector3d(-frame.d) : frame.d, at_risk));
    }
    if (c >= c_max) break;
    // Across the passes: the smallest plane spacing that keeps the scallop on this plane and the next,
    // never more than the widest step-over anywhere (a section whose points set no bound).
    double step = std::min({MinPlaneStep(sections), c_max - c + 1.0, StepOver(h, r, -1e300)});
    double c_next = std::min(c_max, c + step);
    FL_ASSIGN_OR_RETURN(std::vector<Section> next, TraceSection(surface, dom, frame, c_next, r, h));
    if (MinPlaneStep(next) < step) {
      step = MinPlaneStep(next);
      c_next = std::min(c_max, c + step);
      FL_ASSIGN_OR_RETURN(next, TraceSection(surface, dom, frame, c_next, r, h));
    }
    // A face narrower than a step-over across the planes whose first and last planes only touch it (at
    // corners of its outline): a pass half-way between them, else nothing of it would be cut.
    if (c_next >= c_max && OnlyTouches(sections) && OnlyTouches(next) && c_max - c > 1e-9) {
      c_next = 0.5 * (c + c_max);
      step = c_next - c;
      FL_ASSIGN_OR_RETURN(next, TraceSection(surface, dom, frame, c_next, r, h));
    }
    path.min_step_over_mm = std::min(path.min_step_over_mm, step);
    path.max_step_over_mm = std::max(path.max_step_over_mm, step);
    c = (c_next >= c_max - 1e-9) ? c_max : c_next;
    sections = std::move(next);
  }

  // Contour passes along the trimming loops (outer first, then the holes), or, on an untrimmed Q whose
  // edges the passes meet at a slant, along the boundary of its parameter box; split where the ball would
  // reach a neighbouring face.
  std::vector<std::vector<Eigen::Vector2d>> contours;
  if (domain.trimmed()) {
    for (const recon::TrimLoop& loop : domain.trim()->loops()) contours.push_back(loop.uv);
  } else if (SlantedEdges(surface, dom, frame)) {
    contours.push_back(BoxLoop(surface, dom));
    path.boundary_contour = true;
  }
  for (const std::vector<Eigen::Vector2d>& loop : contours) {
    const std::size_t n = loop.size();
    std::vector<char> usable(n);
    std::size_t first_blocked = n;
    for (std::size_t i = 0; i < n; ++i) {
      const recon::SurfaceDerivatives d = surface.Derivatives(std::clamp(loop[i].x(), dom.u_min, dom.u_max),
                                                              std::clamp(loop[i].y(), dom.v_min, dom.v_max));
      usable[i] = domain.BallClear(d.p + r * recon::NormalFromDerivatives(d)) ? 1 : 0;
      if (!usable[i] && first_blocked == n) first_blocked = i;
    }
    std::vector<std::vector<Eigen::Vector2d>> runs;
    if (first_blocked == n) {
      std::vector<Eigen::Vector2d> closed(loop.begin(), loop.end());
      closed.push_back(loop.front());  // around and back to the start
      runs.push_back(std::move(closed));
    } else {
      std::vector<Eigen::Vector2d> run;
      for (std::size_t k = 1; k <= n; ++k) {  // from just after a blocked sample, once around
        const std::size_t i = (first_blocked + k) % n;
        if (usable[i]) {
          run.push_back(loop[i]);
        } else if (!run.empty()) {
          runs.push_back(std::move(run));
          run.clear();
        }
      }
      if (!run.empty()) runs.push_back(std::move(run));
    }
    for (const std::vector<Eigen::Vector2d>& run : runs) {
      std::vector<Eigen::Vector2d> uv = ThinContour(surface, run, r, chord, options.max_point_spacing_mm);
      for (Eigen::Vector2d& p : uv) {
        p = Eigen::Vector2d(std::clamp(p.x(), dom.u_min, dom.u_max), std::clamp(p.y(), dom.v_min, dom.v_max));
      }
      const bool at_risk = near_concave(uv);
      std::vector<ClPoint> cut;
      for (const Eigen::Vector2d& p : uv) cut.push_back(cut_point(p.x(), p.y(), at_risk));
      FL_RETURN_IF_ERROR(finish_pass(std::move(cut), frame.d, at_risk));
      ++path.contour_passes;
    }
  }
  path.passes = pass;
  if (path.points.empty()) {
    if (!domain.trimmed() && !domain.has_neighbours()) return Status::Internal("PlanRaster: no section plane met Q");
    // Every sample of every section was clipped: outside the trim, or where the ball would touch a
    // neighbouring face (a fillet or a narrow face between walls narrower than the ball).
    Eigen::AlignedBox3d box;
    for (int j = 0; j <= 16; ++j) {
      for (int i = 0; i <= 16; ++i)
        box.extend(surface.Point(dom.u_min + dom.u_span() * i / 16, dom.v_min + dom.v_span() * j / 16));
    }
    const Eigen::Vector3d size = box.sizes();
    return Status::BadInput(
        Where{.field = "tool.radius_mm"},
        fmt::format("a ball of radius {:g} mm reaches no part of the face ({:.3g} x {:.3g} x {:.3g} mm){}", r, size.x(),
                    size.y(), size.z(),
                    path.neighbour_blocked_samples > 0
                        ? fmt::format(": at each of the {} samples inside it the ball would touch a neighbouring face",
                                      path.neighbour_blocked_samples)
                        : std::string(": no sample of the raster lies inside the trim")),
        std::string(
            "choose a smaller ball (tool.radius_mm, --tool-radius-mm) or machine this face from another set-up") +
            (size.maxCoeff() < 1.0 ? "; a face this small may also mean the CAD file's unit is not what it says" : ""));
  }
  if (path.min_step_over_mm > path.max_step_over_mm) path.min_step_over_mm = path.max_step_over_mm = 0;
  SummariseLifted(&path);
  UpdateCutterLocations(&path);
  return path;
}

void SummariseLifted(Toolpath* path) {
  path->lifted_points = 0;
  path->lifted_indices.clear();
  path->max_lift_mm = 0;
  path->lifted_box_min = path->lifted_box_max = Eigen::Vector3d::Zero();
  for (std::size_t k = 0; k < path->points.size(); ++k) {
    const ClPoint& cl = path->points[k];
    if (!(cl.lift_mm > 0)) continue;
    if (path->lifted_points == 0) path->lifted_box_min = path->lifted_box_max = cl.cc;
    path->lifted_box_min = path->lifted_box_min.cwiseMin(cl.cc);
    path->lifted_box_max = path->lifted_box_max.cwiseMax(cl.cc);
    path->max_lift_mm = std::max(path->max_lift_mm, cl.lift_mm);
    path->lifted_indices.push_back(static_cast<int>(k));
    ++path->lifted_points;
  }
}

void UpdateCutterLocations(Toolpath* path) {
  const double r = path->options.tool.radius_mm;
  const double feed_mm_per_s = path->options.feed_mm_per_min / 60.0;
  double length = 0, max_tip_z = -1e300;
  for (std::size_t k = 0; k < path->points.size(); ++k) {
    ClPoint& cl = path->points[k];
    cl.centre = BallCentre(cl.cc, cl.normal, cl.lift_mm, r);
    cl.tip = TipOf(cl.centre, r);
    if (k > 0 && path->points[k - 1].pass == cl.pass) length += (cl.tip - path->points[k - 1].tip).norm();
    cl.path_length_mm = length;
    cl.time_s = length / feed_mm_per_s;
    max_tip_z = std::max(max_tip_z, cl.tip.z());
  }
  path->total_length_mm = length;
  path->total_time_s = length / feed_mm_per_s;
  path->safe_z_mm = max_tip_z + path->options.clearance_mm;
  if (std::isfinite(path->min_safe_z_mm)) path->safe_z_mm = std::max(path->safe_z_mm, path->min_safe_z_mm);
}

std::string Toolpath::UncutRegionText() const {
  if (lifted_points == 0) return "";
  return fmt::format(
      "Q is concave below the ball radius ({} mm) at {} CL points: {} CL points are lifted out of Q (by up to "
      "{:.3f} mm), and the region they cover (x {:.2f} to {:.2f}, y {:.2f} to {:.2f} mm) is left uncut; a smaller "
      "ball cuts it",
      options.tool.radius_mm, gouge_risk_points, lifted_points, max_lift_mm, lifted_box_min.x(), lifted_box_max.x(),
      lifted_box_min.y(), lifted_box_max.y());
}

nlohmann::json Toolpath::ReportJson() const {
  nlohmann::json out = {
      {"strategy", "section-plane raster"},
      {"raster_angle_deg", options.raster_angle_deg},
      {"zigzag", options.zigzag},
      {"lead_mm", options.lead_mm},
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
       {{"note",
         "CL points lifted along the tool axis so the ball stays out of Q where its concave radius is below "
         "the ball radius: the region is never cut to Q"},
        {"points", lifted_points},
        {"max_lift_mm", max_lift_mm},
        {"cc_box_min_mm", {lifted_box_min.x(), lifted_box_min.y(), lifted_box_min.z()}},
        {"cc_box_max_mm", {lifted_box_max.x(), lifted_box_max.y(), lifted_box_max.z()}},
        {"cl_indices", lifted_indices}}},
      {"lifted_points", lifted_points}};
  if (trimmed || neighbours_checked) {
    out["trim"] = {{"note",
                    "passes end at the trim (OpenCASCADE classification); a contour pass follows every trimming "
                    "loop; leads and retracts keep the ball clear of the neighbouring faces"},
                   {"trimmed", trimmed},
                   {"contour_passes", contour_passes},
                   {"neighbours_checked", neighbours_checked},
                   {"neighbour_blocked_samples", neighbour_blocked_samples},
                   {"leads_along_normal", leads_along_normal},
                   {"leads_vertical", leads_vertical},
                   {"min_safe_z_mm", std::isfinite(min_safe_z_mm) ? nlohmann::json(min_safe_z_mm) : nlohmann::json()}};
  }
  if (boundary_contour) {
    out["boundary_contour"] = {
        {"note",
         "the passes meet the edges of Q's parameter box at a slant: one contour pass along its boundary keeps "
         "the scallop target there"},
        {"contour_passes", contour_passes}};
  }
  return out;
}

}  // namespace formloop::nc
