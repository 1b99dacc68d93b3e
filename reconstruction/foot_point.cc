// Foot points (spec/reconstruction.md §4): kd-tree start, box-constrained Newton, global check. The
// method and its sources are in foot_point.h.
//
// B-spline evaluation. Geom_BSplineSurface::D2 locates the span and converts its poles on every call
// (0.41 µs per D2 on the franke fit, bench EvalGeomD2). GeomAdaptor_Surface keeps the current span as a
// power-form polynomial (BSplSLib_Cache) and evaluates that (0.27 µs, EvalAdaptorD2), but rebuilds it
// whenever a call leaves the span, which is nearly every new point, and the cache is mutable, so each
// thread would need its own. The projector therefore converts every span once: for non-rational
// surfaces into our own span polynomials (span_polynomials.h: 0.04 µs per bicubic D2, 0.063 µs at
// degree 5, bench EvalSpanPolynomials), otherwise into OpenCASCADE's BSplSLib_Cache per span (SpanCaches);
// both are read-only afterwards and shared by threads. Surfaces whose caches would exceed
// kMaxSpanCacheBytes, and the one-point functions, use a GeomAdaptor_Surface per call.
//
// Where the time goes (perf, 100,000 points within 1 mm of the bench's franke fit, 2026-11): before,
// 3.4 µs a point, a third of it in the PCL kd-tree (FLANN) searches and a quarter in OpenCASCADE's
// evaluation; then 1.0 µs, about 30 % in the cell grid's two queries, 30 % in evaluation (3.96 D2 a
// point), 15 % in Newton. Since 2026-11-27 0.83 µs: the span polynomials leave out the products with a
// zero power (0.090 -> 0.063 µs per degree-5 D2) and the grid scans whole rows of cells; the same bits.
// Tried and dropped: keeping D2 at every start sample so a run starts without an evaluation (one D2 a
// point fewer, but the 144-byte look-up misses the cache and cost as much).
// The foot points agree with the earlier ones to 6e-12 mm (204,000 points, far and edge points included).

#include "reconstruction/foot_point.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <limits>
#include <locale>
#include <sstream>
#include <string>

#include <BSplSLib_Cache.hxx>
#include <GeomAdaptor_Surface.hxx>
#include <Geom_BSplineSurface.hxx>
#include <TColStd_Array1OfReal.hxx>
#include <gp_Pnt.hxx>
#include <gp_Vec.hxx>

#include <Eigen/Dense>

#include "core/parallel.h"
#include "reconstruction/bspline_surface.h"
#include "reconstruction/occt_support.h"
#include "reconstruction/point_checks.h"
#include "reconstruction/point_grid.h"
#include "reconstruction/span_polynomials.h"
#include "reconstruction/trim.h"

namespace formloop::recon {
namespace {

using Eigen::Vector2d;
using Eigen::Vector3d;

// A foot point within this parameter distance of an edge is on the edge (Newton clamps exactly onto it).
constexpr double kBoundaryTol = 1e-9;
// Converged when the residual p - S is orthogonal to both tangents to 1e-12 mm (evaluation rounding is
// about 1e-14 mm on parts of 100 mm), three orders below the 1e-9 mm accuracy contract.
constexpr double kTangentialTol = 1e-12;
// Accepted when Newton stalls at the rounding floor with the residual orthogonal to this.
constexpr double kStalledTangentialTol = 1e-10;
// Newton runs per point at most (the first plus restarts from the global check). Points within a few
// mm of a surface whose radii exceed twice that distance need one; the cap bounds far points.
constexpr int kMaxRuns = 8;
// Above this the span polynomials are not precomputed and each call caches one span at a time
// (GeomAdaptor_Surface); 64 MB holds e.g. 10^5 spans of a bicubic.
constexpr double kMaxSpanCacheBytes = 64e6;
// Cell edge of the start samples' grid (PointGrid), in units of δ (seed_cover_mm): a query near the
// surface then visits about 27 cells of a few samples each. Measured on 100,000 points within 1 mm of
// the bench surfaces (bench/projection_bench.cc): 1 and 4 were slower than 2.
constexpr double kGridCellDeltas = 2;
// Start grid of the one-point Project(surface, p).
constexpr int kOneShotGrid = 33;
// Points per parallel chunk of ProjectAll / ProjectEachFrom (about 1 ms of work; fixed, so the chunks
// and with them the results do not depend on the thread count).
constexpr long kProjectChunk = 1024;

std::string Num(double value) { return FormatSignificant(value, 10); }

Vector3d ToEigen(const gp_XYZ& p) { return {p.X(), p.Y(), p.Z()}; }

// ---------------------------------------------------------------------------------------------
// Evaluators: one per call (they may cache), with SurfaceDerivatives D2(u, v).

// OpenCASCADE's D2 outputs (argument order p, S_u, S_v, S_uu, S_vv, S_uv) as SurfaceDerivatives.
SurfaceDerivatives FromOcct(const gp_Pnt& p, const gp_Vec& su, const gp_Vec& sv, const gp_Vec& suu, const gp_Vec& svv,
                            const gp_Vec& suv) {
  SurfaceDerivatives d;
  d.p = ToEigen(p.XYZ());
  d.su = ToEigen(su.XYZ());
  d.sv = ToEigen(sv.XYZ());
  d.suu = ToEigen(suu.XYZ());
  d.suv = ToEigen(suv.XYZ());
  d.svv = ToEigen(svv.XYZ());
  return d;
}

class AnalyticEvaluator {
 public:
  explicit AnalyticEvaluator(const AnalyticSurface& surface) : surface_(surface) {}
  SurfaceDerivatives D2(double u, double v) { return surface_.Derivatives(u, v); }

 private:
  const AnalyticSurface& surface_;
};

class BSplineEvaluator {
 public:
  explicit BSplineEvaluator(const Handle(Geom_BSplineSurface) & geom) : adaptor_(geom) {}
  SurfaceDerivatives D2(double u, double v) {
    gp_Pnt p;
    gp_Vec su, sv, suu, svv, suv;
    adaptor_.D2(u, v, p, su, sv, suu, svv, suv);
    return FromOcct(p, su, sv, suu, svv, suv);
  }

 private:
  GeomAdaptor_Surface adaptor_;
};

// The power-form polynomial of every knot span (OpenCASCADE's BSplSLib_Cache, the cache
// GeomAdaptor_Surface keeps for one span), built once: evaluation is one polynomial evaluation with
// no span rebuild, and the caches are read-only afterwards, so threads share them.
class SpanCaches {
 public:
  // Bytes the caches of geom would take (poles and weights of every span, plus per-object overhead).
  static double EstimateBytes(const Handle(Geom_BSplineSurface) & geom) {
    const double spans = static_cast<double>(geom->NbUKnots() - 1) * (geom->NbVKnots() - 1);
    return spans * ((geom->UDegree() + 1) * (geom->VDegree() + 1) * 4 * sizeof(double) + 256);
  }

  explicit SpanCaches(const Handle(Geom_BSplineSurface) & geom) {
    for (int i = 1; i <= geom->NbUKnots(); ++i) u_knots_.push_back(geom->UKnot(i));
    for (int j = 1; j <= geom->NbVKnots(); ++j) v_knots_.push_back(geom->VKnot(j));
    const std::size_t nu = u_knots_.size() - 1, nv = v_knots_.size() - 1;
    caches_.reserve(nu * nv);
    for (std::size_t j = 0; j < nv; ++j) {
      for (std::size_t i = 0; i < nu; ++i) {
        Handle(BSplSLib_Cache) cache =
            new BSplSLib_Cache(geom->UDegree(), geom->IsUPeriodic(), geom->UKnotSequence(), geom->VDegree(),
                               geom->IsVPeriodic(), geom->VKnotSequence(), geom->Weights());
        // A parameter inside the span selects it.
        cache->BuildCache(0.5 * (u_knots_[i] + u_knots_[i + 1]), 0.5 * (v_knots_[j] + v_knots_[j + 1]),
                          geom->UKnotSequence(), geom->VKnotSequence(), geom->Poles(), geom->Weights());
        caches_.push_back(std::move(cache));
      }
    }
  }

  // The span holding (u, v): [k_i, k_i+1) with the last span closed; outside the domain the nearest.
  const BSplSLib_Cache& At(double u, double v) const {
    return *caches_[Span(v_knots_, v) * (u_knots_.size() - 1) + Span(u_knots_, u)];
  }

 private:
  static std::size_t Span(const std::vector<double>& knots, double t) {
    // Number of interior knots <= t.
    return static_cast<std::size_t>(std::upper_bound(knots.begin() + 1, knots.end() - 1, t) - (knots.begin() + 1));
  }

  std::vector<double> u_knots_, v_knots_;       // distinct knots
  std::vector<Handle(BSplSLib_Cache)> caches_;  // span (i, j) at j * (u spans) + i
};

// Non-rational surfaces: our own span polynomials (span_polynomials.h), all six outputs in one pass.
class PolynomialEvaluator {
 public:
  explicit PolynomialEvaluator(const SpanPolynomials& polynomials) : eval_(polynomials) {}
  SurfaceDerivatives D2(double u, double v) { return eval_.D2(u, v); }

 private:
  SpanPolynomials::Evaluator eval_;
};

class SpanCacheEvaluator {
 public:
  explicit SpanCacheEvaluator(const SpanCaches& caches) : caches_(caches) {}
  SurfaceDerivatives D2(double u, double v) {
    gp_Pnt p;
    gp_Vec su, sv, suu, svv, suv;
    caches_.At(u, v).D2(u, v, p, su, sv, suu, svv, suv);
    return FromOcct(p, su, sv, suu, svv, suv);
  }

 private:
  const SpanCaches& caches_;
};

// ---------------------------------------------------------------------------------------------
// Newton on f(u, v) = ½ |S(u, v) - p|² in the box of the domain.

struct NewtonResult {
  Vector2d x;
  SurfaceDerivatives d;  // at x
  double distance_mm;    // |S(x) - p|
  bool converged;
};

template <typename Evaluator>
NewtonResult MinimiseDistance(Evaluator& eval, const ParamDomain& dom, const Vector3d& p, const Vector2d& x0) {
  const double span = std::max(dom.u_span(), dom.v_span());
  const Vector2d lo(dom.u_min, dom.v_min), hi(dom.u_max, dom.v_max);
  auto clamp = [&](const Vector2d& y) -> Vector2d { return y.cwiseMax(lo).cwiseMin(hi); };

  // State at x: f = ½|r|², gradient g, which coordinates are free (not held at a bound by an outward
  // gradient) and the projected gradient as a tangential length in mm: |g_k| / |S_k| is how far the
  // residual is from orthogonal to the tangent S_k.
  struct State {
    Vector2d x;
    SurfaceDerivatives d;
    Vector3d r;
    double f;
    Vector2d g;
    bool free[2];
    double tangential;
  };
  auto evaluate = [&](const Vector2d& x) {
    State s;
    s.x = x;
    s.d = eval.D2(x(0), x(1));
    s.r = s.d.p - p;
    s.f = 0.5 * s.r.squaredNorm();
    s.g = Vector2d(s.r.dot(s.d.su), s.r.dot(s.d.sv));
    s.tangential = 0;
    for (int k = 0; k < 2; ++k) {
      const bool at_lo = x(k) <= lo(k) && s.g(k) > 0;
      const bool at_hi = x(k) >= hi(k) && s.g(k) < 0;
      s.free[k] = !(at_lo || at_hi);
      const double speed = (k == 0 ? s.d.su : s.d.sv).norm();
      if (s.free[k] && speed > 0) s.tangential = std::max(s.tangential, std::abs(s.g(k)) / speed);
    }
    return s;
  };
  auto result = [](const State& s, bool converged) { return NewtonResult{s.x, s.d, std::sqrt(2 * s.f), converged}; };

  State cur = evaluate(clamp(x0));
  for (int iter = 0; iter < 100; ++iter) {
    if (cur.tangential <= kTangentialTol) return result(cur, true);
    const SurfaceDerivatives& d = cur.d;
    Eigen::Matrix2d jtj;
    jtj << d.su.dot(d.su), d.su.dot(d.sv), d.su.dot(d.sv), d.sv.dot(d.sv);
    Eigen::Matrix2d h = jtj;
    h(0, 0) += cur.r.dot(d.suu);
    h(0, 1) += cur.r.dot(d.suv);
    h(1, 0) += cur.r.dot(d.suv);
    h(1, 1) += cur.r.dot(d.svv);

    // Newton step on the free coordinates; Gauss-Newton (JᵀJ) where the Hessian is not positive
    // definite (p beyond a centre of curvature), steepest descent where even that is singular.
    Vector2d step = Vector2d::Zero();
    auto solve = [&](const Eigen::Matrix2d& m) -> bool {
      if (cur.free[0] && cur.free[1]) {
        const Eigen::LLT<Eigen::Matrix2d> llt(m);
        if (llt.info() != Eigen::Success) return false;
        step = -llt.solve(cur.g);
        return step.allFinite();
      }
      for (int k = 0; k < 2; ++k) {
        if (cur.free[k]) {
          if (!(m(k, k) > 0)) return false;
          step(k) = -cur.g(k) / m(k, k);
        }
      }
      return true;
    };
    if (!solve(h) && !solve(jtj)) {
      for (int k = 0; k < 2; ++k) step(k) = cur.free[k] ? -cur.g(k) : 0;
    }
    // Trust region: never jump more than a quarter of the domain at once.
    const double max_step = 0.25 * span;
    if (step.norm() > max_step) step *= max_step / step.norm();

    // Backtracking on f. Near the solution f stops resolving the tangential offset t (f changes by
    // t²/2, below rounding for t < ~1e-7 mm), so a step that keeps f within its rounding and reduces
    // the tangential offset is accepted too. Rounding of f: the point carries ~eps·|p| absolute error
    // per coordinate, times |r|.
    const double f_noise =
        16 * std::numeric_limits<double>::epsilon() * (1 + p.norm() + span) * (1 + std::sqrt(2 * cur.f));
    bool accepted = false;
    State next;
    for (int halving = 0; halving < 60; ++halving) {
      next = evaluate(clamp(cur.x + step));
      if (next.f < cur.f || (next.f <= cur.f + f_noise && next.tangential < cur.tangential)) {
        accepted = true;
        break;
      }
      step *= 0.5;
    }
    if (!accepted || next.x == cur.x) break;  // no descent left: at the rounding floor
    cur = next;
  }
  // Out of iterations or descent: accept when orthogonal to far below the 1e-9 mm contract.
  return result(cur, cur.tangential <= kStalledTangentialTol);
}

Status CheckPoint(const Vector3d& p) {
  if (!p.allFinite()) {
    return Status::BadInput("projection: point " + PointText(p) + " is not finite. Fix: drop or repair the point");
  }
  return Status::Ok();
}

// Tangential offset (mm) of p from the normal line at an edge foot point above which the edge, not
// orthogonality, fixed the foot (1 nm: far below any metrology meaning, far above rounding).
constexpr double kEdgeTangentialTolMm = 1e-6;

Result<FootPoint> MakeFoot(const ParamDomain& dom, const Vector3d& p, const NewtonResult& r) {
  FootPoint foot;
  foot.u = r.x(0);
  foot.v = r.x(1);
  foot.foot = r.d.p;
  foot.normal = NormalFromDerivatives(r.d);
  foot.deviation_mm = (p - foot.foot).dot(foot.normal);
  foot.distance_mm = (p - foot.foot).norm();
  // Flagged only when the edge holds the foot point back: p - q keeps a tangential component across
  // that edge. A point exactly over the edge (a grid sample on it, say) is an ordinary normal foot.
  const Vector3d r_vec = p - foot.foot;
  const auto held = [&](const Vector3d& tangent) {
    const double speed = tangent.norm();
    return speed > 0 && std::abs(r_vec.dot(tangent)) / speed > kEdgeTangentialTolMm;
  };
  const bool at_u_edge = foot.u - dom.u_min <= kBoundaryTol || dom.u_max - foot.u <= kBoundaryTol;
  const bool at_v_edge = foot.v - dom.v_min <= kBoundaryTol || dom.v_max - foot.v <= kBoundaryTol;
  foot.on_boundary = (at_u_edge && held(r.d.su)) || (at_v_edge && held(r.d.sv));
  if (!foot.foot.allFinite() || !foot.normal.allFinite()) {
    return Status::Internal("projection of " + PointText(p) + ": the surface gave a non-finite point or normal");
  }
  return foot;
}

// Newton from (u0, v0) only: ProjectFrom.
template <typename Evaluator>
Result<FootPoint> LocalProject(Evaluator& eval, const ParamDomain& dom, const Vector3d& p, double u0, double v0) {
  FL_RETURN_IF_ERROR(CheckPoint(p));
  if (!std::isfinite(u0) || !std::isfinite(v0)) {
    return Status::BadInput("projection of " + PointText(p) + ": start (u, v) = (" + Num(u0) + ", " + Num(v0) +
                            ") is not finite");
  }
  const NewtonResult r = MinimiseDistance(eval, dom, p, Vector2d(u0, v0));
  if (!r.converged) {
    return Status::Failed("projection of " + PointText(p) + " onto the surface did not converge from (u, v) = (" +
                          Num(u0) + ", " + Num(v0) + ")");
  }
  return MakeFoot(dom, p, r);
}

double GridParam(double lo, double hi, int i, int n) {
  if (i == n - 1) return hi;  // exact edge
  return lo + (hi - lo) * static_cast<double>(i) / (n - 1);
}

ParamDomain DomainOf(const Handle(Geom_BSplineSurface) & geom) {
  ParamDomain d;
  geom->Bounds(d.u_min, d.u_max, d.v_min, d.v_max);
  return d;
}

}  // namespace

// ---------------------------------------------------------------------------------------------
// The projector's read-only state.

struct FootPointProjector::Impl {
  ParamDomain domain;
  std::shared_ptr<const Trim> trim;               // of the B-spline it was built from (may be null)
  Handle(Geom_BSplineSurface) bspline;            // set for a B-spline projector
  SpanPolynomials polynomials;                    // its span polynomials (non-rational, not too large)
  std::unique_ptr<const SpanCaches> span_caches;  // else OpenCASCADE's, unless they would be too large
  const AnalyticSurface* analytic = nullptr;      // set for an analytic projector (not owned)

  // Start grid: samples[j * nu + i] = S(us[i], vs[j]), and the same points in a cell grid.
  int nu = 0, nv = 0;
  std::vector<double> us, vs;
  std::vector<Vector3d> samples;
  double delta_mm = 0;  // every surface point lies within delta_mm of a sample
  PointGrid grid;

  // Calls f(evaluator) with a fresh evaluator for this surface.
  template <typename F>
  auto Visit(F&& f) const {
    if (analytic != nullptr) {
      AnalyticEvaluator eval(*analytic);
      return f(eval);
    }
    if (!polynomials.empty()) {
      PolynomialEvaluator eval(polynomials);
      return f(eval);
    }
    if (span_caches != nullptr) {
      SpanCacheEvaluator eval(*span_caches);
      return f(eval);
    }
    BSplineEvaluator eval(bspline);
    return f(eval);
  }

  // Geodesic radius around a Newton run's end point q (distance d from p) whose samples count as the
  // run's own: a sample of the same sheet within d + δ of p lies within sqrt(2 d δ + δ²) of q on a
  // plane; the factor 1.5 allows for a sheet curving towards p with radius down to about 2d, and the
  // last δ for the sample spacing.
  double CoverRadius(double d) const { return 1.5 * std::sqrt(2 * d * delta_mm + delta_mm * delta_mm) + delta_mm; }

  template <typename Evaluator>
  Result<FootPoint> GlobalProject(Evaluator& eval, const Vector3d& p, std::vector<std::pair<double, int>>& found) const;
  template <typename Evaluator>
  Status BuildSamples(Evaluator& eval, int spans_u, int spans_v, const ProjectorOptions& options);
};

template <typename Evaluator>
Result<FootPoint> FootPointProjector::Impl::GlobalProject(Evaluator& eval, const Vector3d& p,
                                                          std::vector<std::pair<double, int>>& found) const {
  FL_RETURN_IF_ERROR(CheckPoint(p));
  // The nearest sample starts Newton.
  double nearest_d = 0, complete_mm = 0;
  const int nearest = grid.Nearest(p, &nearest_d, &found, &complete_mm);
  if (nearest < 0) return Status::Internal("projection of " + PointText(p) + ": the start grid holds no sample");

  // Each Newton run covers the samples of its own sheet near its end point: parameter offsets Δ with
  // √(Δᵀ I Δ) <= cover_mm, I the first fundamental form there (the geodesic distance to first order).
  // Parameter space, not 3-D distance, so that a fold or a second sheet passing close by is not
  // mistaken for the same neighbourhood.
  struct Run {
    Vector2d x;
    Eigen::Matrix2d metric;
    double cover_mm;
  };
  std::array<Run, kMaxRuns> runs;
  int n_runs = 0;
  NewtonResult best{};
  double best_d = std::numeric_limits<double>::infinity();
  auto run_from = [&](int sample) {
    const int i = sample % nu, j = sample / nu;
    const NewtonResult r = MinimiseDistance(eval, domain, p, Vector2d(us[i], vs[j]));
    Eigen::Matrix2d metric;
    metric << r.d.su.squaredNorm(), r.d.su.dot(r.d.sv), r.d.su.dot(r.d.sv), r.d.sv.squaredNorm();
    // A run that did not converge still marks where it ended, but only the sample spacing around it.
    runs[n_runs++] = {r.x, metric, r.converged ? CoverRadius(r.distance_mm) : delta_mm};
    if (r.converged && r.distance_mm < best_d) {
      best = r;
      best_d = r.distance_mm;
    }
  };
  auto covered = [&](int sample) {
    const Vector2d x(us[sample % nu], vs[sample / nu]);
    return std::any_of(runs.begin(), runs.begin() + n_runs, [&](const Run& r) {
      const Vector2d delta = x - r.x;
      return delta.dot(r.metric * delta) <= r.cover_mm * r.cover_mm;
    });
  };
  run_from(nearest);

  // Global check (foot_point.h, step 3): every sample within best_d + δ of p that no run covers starts
  // another run, nearest first. The nearest-sample search has usually seen all of them already (found,
  // squared distances); samples the first run covers stay covered, so only the others are sorted.
  const double seed_limit = nearest_d + delta_mm;  // >= best_d + δ
  auto limit = [&] { return std::isfinite(best_d) ? best_d + delta_mm : seed_limit; };
  if (limit() > complete_mm) {
    grid.WithinRadius(p, limit(), &found);
    for (auto& [d, index] : found) d *= d;
  }
  std::size_t open = 0;
  const double limit2 = limit() * limit();
  for (std::size_t k = 0; k < found.size(); ++k) {
    if (found[k].second != nearest && found[k].first <= limit2 && !covered(found[k].second)) found[open++] = found[k];
  }
  found.resize(open);
  std::sort(found.begin(), found.end());
  for (std::size_t k = 0; k < found.size() && n_runs < kMaxRuns; ++k) {
    if (std::sqrt(found[k].first) > limit()) continue;
    if (!covered(found[k].second)) run_from(found[k].second);
  }
  if (!std::isfinite(best_d)) {
    return Status::Failed("projection of " + PointText(p) + ": Newton did not converge from any of " +
                          std::to_string(n_runs) + " start samples");
  }
  return MakeFoot(domain, p, best);
}

template <typename Evaluator>
Status FootPointProjector::Impl::BuildSamples(Evaluator& eval, int spans_u, int spans_v,
                                              const ProjectorOptions& options) {
  if (!(domain.u_max > domain.u_min) || !(domain.v_max > domain.v_min) || !std::isfinite(domain.u_span()) ||
      !std::isfinite(domain.v_span())) {
    return Status::BadInput("foot-point projector: the parameter domain [" + Num(domain.u_min) + ", " +
                            Num(domain.u_max) + "] × [" + Num(domain.v_min) + ", " + Num(domain.v_max) +
                            "] is empty or not finite");
  }
  if (options.seed_grid > 0) {
    nu = nv = options.seed_grid;
  } else {
    // Automatic density from a pre-grid: the longest iso-line in each direction (3-D polyline) and the
    // largest principal curvature. Target spacing 1 mm, and at most R/16 where the smallest curvature
    // radius R is below 16 mm, so that the start is well inside Newton's quadratic range. Denser grids
    // are slower (more samples within d + δ for the global check: bench ours_seed_grid, 128 a side 0 %,
    // 256 +40 %, 512 +130 % against the automatic ~110 on franke); coarser ones (16-64 a side) are about
    // 25 % faster on these smooth fits but widen δ, and with it the distance (CoverRadius) below which
    // the global check cannot tell two sheets apart.
    constexpr double kTargetSpacingMm = 1.0, kMinSpacingMm = 0.02;
    constexpr int kMaxPerDirection = 4096;
    constexpr double kMaxSamples = 1 << 20;
    const int pu = std::clamp(4 * spans_u + 1, 33, 257), pv = std::clamp(4 * spans_v + 1, 33, 257);
    std::vector<Vector3d> pre(static_cast<std::size_t>(pu) * pv);
    double k_max = 0;
    for (int j = 0; j < pv; ++j) {
      for (int i = 0; i < pu; ++i) {
        const SurfaceDerivatives d =
            eval.D2(GridParam(domain.u_min, domain.u_max, i, pu), GridParam(domain.v_min, domain.v_max, j, pv));
        const PrincipalCurvatures k = CurvaturesFromDerivatives(d);
        k_max = std::max({k_max, std::abs(k.k1), std::abs(k.k2)});
        pre[static_cast<std::size_t>(j) * pu + i] = d.p;
      }
    }
    double length_u = 0, length_v = 0;
    for (int j = 0; j < pv; ++j) {
      double length = 0;
      for (int i = 1; i < pu; ++i) length += (pre[j * pu + i] - pre[j * pu + i - 1]).norm();
      length_u = std::max(length_u, length);
    }
    for (int i = 0; i < pu; ++i) {
      double length = 0;
      for (int j = 1; j < pv; ++j) length += (pre[j * pu + i] - pre[(j - 1) * pu + i]).norm();
      length_v = std::max(length_v, length);
    }
    if (!std::isfinite(length_u) || !std::isfinite(length_v) || !std::isfinite(k_max)) {
      return Status::BadInput("foot-point projector: the surface gives non-finite points or curvatures");
    }
    const double spacing = std::max(kMinSpacingMm, std::min(kTargetSpacingMm, k_max > 0 ? 1 / (16 * k_max) : 1e9));
    auto count = [&](double length, int spans) {
      const double n = std::ceil(length / spacing) + 1;
      return static_cast<int>(
          std::clamp(n, static_cast<double>(std::max(2 * spans + 1, 9)), static_cast<double>(kMaxPerDirection)));
    };
    nu = count(length_u, spans_u);
    nv = count(length_v, spans_v);
    const double total = static_cast<double>(nu) * nv;
    if (total > kMaxSamples) {
      const double shrink = std::sqrt(kMaxSamples / total);
      nu = std::max(9, static_cast<int>(nu * shrink));
      nv = std::max(9, static_cast<int>(nv * shrink));
    }
  }

  us.resize(nu);
  vs.resize(nv);
  for (int i = 0; i < nu; ++i) us[i] = GridParam(domain.u_min, domain.u_max, i, nu);
  for (int j = 0; j < nv; ++j) vs[j] = GridParam(domain.v_min, domain.v_max, j, nv);
  samples.resize(static_cast<std::size_t>(nu) * nv);
  for (int j = 0; j < nv; ++j) {
    for (int i = 0; i < nu; ++i) {
      const std::size_t k = static_cast<std::size_t>(j) * nu + i;
      samples[k] = eval.D2(us[i], vs[j]).p;
      if (!samples[k].allFinite()) {
        return Status::BadInput("foot-point projector: the surface is not finite at (u, v) = (" + Num(us[i]) + ", " +
                                Num(vs[j]) + ")");
      }
    }
  }
  // δ: a point of a cell is within 1/√3 of the cell's longer diagonal of a corner (circumradius of the
  // acute triangle of a parallelogram); 0.75 leaves room for the cell's curvature.
  double diagonal = 0;
  for (int j = 1; j < nv; ++j) {
    for (int i = 1; i < nu; ++i) {
      const std::size_t k = static_cast<std::size_t>(j) * nu + i;
      diagonal =
          std::max({diagonal, (samples[k] - samples[k - nu - 1]).norm(), (samples[k - 1] - samples[k - nu]).norm()});
    }
  }
  delta_mm = 0.75 * diagonal;
  grid = PointGrid(samples, kGridCellDeltas * delta_mm);
  return Status::Ok();
}

// ---------------------------------------------------------------------------------------------
// Public API

Status ProjectorOptions::Validate() const {
  if (seed_grid != 0 && (seed_grid < 2 || seed_grid > 4096)) {
    return Status::BadInput(Where{.field = "seed_grid"}, "seed_grid " + std::to_string(seed_grid) + " is out of range",
                            "use 0 (automatic) or a sample count per direction between 2 and 4096");
  }
  return Status::Ok();
}

namespace {

// Flags a foot point outside Q's trim (FootPoint::outside_trim).
Result<FootPoint> MarkTrim(const Trim* trim, Result<FootPoint> foot) {
  if (foot.ok() && trim != nullptr && !trim->natural()) foot->outside_trim = !trim->Inside(foot->u, foot->v);
  return foot;
}

}  // namespace

Result<FootPointProjector> FootPointProjector::Build(const BSplineSurface& q, const ProjectorOptions& options) {
  return BuildBSpline(q, options, true);
}

Result<FootPointProjector> FootPointProjector::BuildBSpline(const BSplineSurface& q, const ProjectorOptions& options,
                                                            bool span_caches) {
  FL_RETURN_IF_ERROR(options.Validate().WithContext("foot-point projector options"));
  if (!q.valid()) {
    return Status::BadInput("foot-point projector: the B-spline surface is empty. Fix: read or fit the surface first");
  }
  try {
    auto impl = std::make_shared<Impl>();
    // A private copy: later changes to q (or its destruction) do not reach the projector.
    impl->bspline = Handle(Geom_BSplineSurface)::DownCast(q.geom()->Copy());
    impl->domain = DomainOf(impl->bspline);
    impl->trim = q.shared_trim();
    if (span_caches && SpanCaches::EstimateBytes(impl->bspline) <= kMaxSpanCacheBytes) {
      Result<SpanPolynomials> polynomials = SpanPolynomials::Of(BSplineSurface(impl->bspline));
      if (polynomials.ok()) impl->polynomials = std::move(polynomials).value();
      if (impl->polynomials.empty()) impl->span_caches = std::make_unique<const SpanCaches>(impl->bspline);
    }
    const int spans_u = impl->bspline->NbUKnots() - 1, spans_v = impl->bspline->NbVKnots() - 1;
    FL_RETURN_IF_ERROR(impl->Visit([&](auto& eval) { return impl->BuildSamples(eval, spans_u, spans_v, options); }));
    return FootPointProjector(std::move(impl));
  } catch (const Standard_Failure& failure) {
    return Status::Internal("foot-point projector: OpenCASCADE failed: " + occt::Message(failure));
  }
}

Result<FootPointProjector> FootPointProjector::Build(const AnalyticSurface& s, const ProjectorOptions& options) {
  FL_RETURN_IF_ERROR(options.Validate().WithContext("foot-point projector options"));
  auto impl = std::make_shared<Impl>();
  impl->analytic = &s;
  impl->domain = s.domain();
  AnalyticEvaluator eval(s);
  FL_RETURN_IF_ERROR(impl->BuildSamples(eval, 1, 1, options).WithContext(s.name()));
  return FootPointProjector(std::move(impl));
}

Result<FootPoint> FootPointProjector::Project(const Eigen::Vector3d& p) const {
  try {
    return impl_->Visit([&](auto& eval) {
      std::vector<std::pair<double, int>> found;
      return MarkTrim(impl_->trim.get(), impl_->GlobalProject(eval, p, found));
    });
  } catch (const Standard_Failure& failure) {
    return Status::Internal("projection of " + PointText(p) + ": OpenCASCADE failed: " + occt::Message(failure));
  }
}

Result<FootPoint> FootPointProjector::ProjectFrom(const Eigen::Vector3d& p, double u0, double v0) const {
  try {
    return impl_->Visit(
        [&](auto& eval) { return MarkTrim(impl_->trim.get(), LocalProject(eval, impl_->domain, p, u0, v0)); });
  } catch (const Standard_Failure& failure) {
    return Status::Internal("projection of " + PointText(p) + ": OpenCASCADE failed: " + occt::Message(failure));
  }
}

Result<std::vector<FootPoint>> FootPointProjector::ProjectAll(const std::vector<Eigen::Vector3d>& points) const {
  const long n = static_cast<long>(points.size());
  std::vector<FootPoint> out(points.size());
  // Per chunk: the first index that failed there (-1: none) and why.
  const long chunks = (n + kProjectChunk - 1) / kProjectChunk;
  std::vector<long> failed(static_cast<std::size_t>(chunks), -1);
  std::vector<Status> why(static_cast<std::size_t>(chunks));
  ParallelFor(n, kProjectChunk, [&](long begin, long end) {
    const auto chunk = static_cast<std::size_t>(begin / kProjectChunk);
    long index = begin;
    try {
      impl_->Visit([&](auto& eval) {
        std::vector<std::pair<double, int>> found;  // reused by every point of the chunk
        for (; index < end; ++index) {
          const auto i = static_cast<std::size_t>(index);
          Result<FootPoint> foot = MarkTrim(impl_->trim.get(), impl_->GlobalProject(eval, points[i], found));
          if (!foot.ok()) {
            failed[chunk] = index;
            why[chunk] = foot.status();
            return;
          }
          out[i] = *foot;
        }
      });
    } catch (const Standard_Failure& failure) {
      failed[chunk] = index;
      why[chunk] = Status::Internal("OpenCASCADE failed: " + occt::Message(failure));
    }
  });
  for (std::size_t c = 0; c < failed.size(); ++c) {
    if (failed[c] >= 0) {
      return Status(why[c].code(), "points[" + std::to_string(failed[c]) + "] of " + std::to_string(points.size()) +
                                       ": " + why[c].message());
    }
  }
  return out;
}

std::vector<Result<FootPoint>> FootPointProjector::ProjectEachFrom(const std::vector<Eigen::Vector3d>& points,
                                                                   const std::vector<double>& u0,
                                                                   const std::vector<double>& v0) const {
  std::vector<Result<FootPoint>> out(points.size(), Status::Internal("ProjectEachFrom: not projected"));
  if (u0.size() != points.size() || v0.size() != points.size()) {
    for (auto& foot : out) {
      foot = Status::Internal("ProjectEachFrom: " + std::to_string(points.size()) + " points but " +
                              std::to_string(u0.size()) + " u and " + std::to_string(v0.size()) + " v starts");
    }
    return out;
  }
  ParallelFor(static_cast<long>(points.size()), kProjectChunk, [&](long begin, long end) {
    for (auto i = static_cast<std::size_t>(begin); i < static_cast<std::size_t>(end); ++i) {
      out[i] = ProjectFrom(points[i], u0[i], v0[i]);
    }
  });
  return out;
}

const ParamDomain& FootPointProjector::domain() const { return impl_->domain; }
int FootPointProjector::seed_grid_u() const { return impl_->nu; }
int FootPointProjector::seed_grid_v() const { return impl_->nv; }
double FootPointProjector::seed_cover_mm() const { return impl_->delta_mm; }

Result<FootPoint> Project(const BSplineSurface& surface, const Eigen::Vector3d& p) {
  FL_RETURN_IF_ERROR(CheckPoint(p));
  FL_ASSIGN_OR_RETURN(const FootPointProjector projector,
                      FootPointProjector::BuildBSpline(surface, ProjectorOptions{.seed_grid = kOneShotGrid}, false));
  return projector.Project(p);
}

Result<FootPoint> ProjectFrom(const BSplineSurface& surface, const Eigen::Vector3d& p, double u0, double v0) {
  FL_RETURN_IF_ERROR(CheckPoint(p));
  if (!surface.valid()) {
    return Status::BadInput("projection of " + PointText(p) +
                            ": the B-spline surface is empty. Fix: read or fit the surface first");
  }
  try {
    BSplineEvaluator eval(surface.geom());
    return MarkTrim(surface.trim(), LocalProject(eval, DomainOf(surface.geom()), p, u0, v0));
  } catch (const Standard_Failure& failure) {
    return Status::Internal("projection of " + PointText(p) + ": OpenCASCADE failed: " + occt::Message(failure));
  }
}

}  // namespace formloop::recon
