#pragma once
// Foot points and signed deviations on the ideal surface (spec/reconstruction.md §4).
//
// For a point p the foot point q = S(u*, v*) minimises |p - S(u, v)| over the parameter domain. The unit
// normal there is n = S_u × S_v / |S_u × S_v| (outward from the material, docs/ARCHITECTURE.md) and the
// signed deviation is d = (p - q)·n: positive where material is left.
//
// Method (FootPointProjector::Project):
//  1. Start. A uniform 3-D cell grid (point_grid.h; cells 2δ wide) over a dense grid sample of S gives
//     the sample nearest to p, exactly; its (u, v) starts the search. (Until 2026-11 a PCL kd-tree did,
//     at about half of the time per point.)
//  2. Newton on the first-order conditions (S - p)·S_u = (S - p)·S_v = 0, i.e. on f = ½|S - p|² with the
//     exact Hessian (Piegl & Tiller, The NURBS Book, 2nd ed. 1997, §6.1 "point inversion and
//     projection"). Gauss-Newton replaces it where it is not positive definite; a step bound and
//     backtracking keep every step a descent step (Nocedal & Wright, Numerical Optimization, 2nd ed.,
//     §3.1). At the domain edge a coordinate whose gradient points outwards is held at its bound (the
//     active-set rule of projected Newton, Bertsekas 1982, SIAM J. Control Optim. 20(2):221-246); such
//     foot points are flagged on_boundary. Converged when the residual's tangential component is below
//     1e-12 mm; from the automatic start grid that takes 3 steps on average (bench points, franke and
//     egg_box fits: 3.8-4.0 surface evaluations a point).
//  3. Global check. Every point of S lies within δ of some sample (δ, seed_cover_mm(), is measured on
//     the sample grid). If a closer foot point q' existed elsewhere, the sample next to it would be
//     within d + δ of p, where d is the distance found. So every sample within d + δ of p is looked at,
//     and Newton is restarted from those that are not near a foot point found already. "Near" is
//     measured along the surface (parameter offsets through the first fundamental form), within the
//     disc that a smooth sheet at distance d can put inside that radius, so a fold or a second sheet
//     passing close by in space still gets its own run. On the bench points (100,000 within 2 mm of the
//     franke and egg_box fits) no restart happens; on the two-sheet fixture in the tests it recovers
//     every point whose nearest sample lies on the farther sheet.
//
// Accuracy (tests/reconstruction/foot_point_test.cc): on the analytic reference surfaces the deviation
// of S(u, v) + t n is t to 1e-9 mm; on B-spline surfaces it agrees with OpenCASCADE's
// GeomAPI_ProjectPointOnSurf to 1e-7 mm, and where OpenCASCADE finds no or a farther point ours is
// at least as close. Speed against OpenCASCADE: bench/projection_bench.cc (100,000 points within 1 mm
// of three fits, single thread, 2026-11: 0.72-0.83 µs a point; OpenCASCADE's Extrema Grad and Tree there).
// B-spline evaluation: span_polynomials.h for non-rational surfaces (all six outputs in one pass), else
// OpenCASCADE's span caches.

#include <memory>
#include <utility>
#include <vector>

#include <Eigen/Core>

#include "core/status.h"
#include "reconstruction/analytic_surface.h"

namespace formloop::recon {

class BSplineSurface;  // reconstruction/bspline_surface.h, which includes this header

// The foot point of p on a surface S. Lengths in mm, points and vectors in the part frame.
struct FootPoint {
  double u = 0, v = 0;                                // parameters of the foot point (mm for the reference surfaces)
  Eigen::Vector3d foot = Eigen::Vector3d::Zero();     // q = S(u, v)
  Eigen::Vector3d normal = Eigen::Vector3d::UnitZ();  // unit S_u × S_v at (u, v), away from the material
  double deviation_mm = 0;                            // (p - q)·n, positive = material left / point outside
  // |p - q|; equals |deviation_mm| to rounding unless the foot point is clamped to an edge, where p - q
  // also has a tangential part.
  double distance_mm = 0;
  // The edge of the parameter domain holds the foot point back: p lies beyond Q, so deviation_mm is
  // not a normal distance. Points exactly over an edge (orthogonal there) are not flagged.
  bool on_boundary = false;
  // Q is trimmed (reconstruction/trim.h) and (u, v) lies outside the trim: the foot point is on the
  // underlying patch beyond the part's edge or over a hole, so deviation_mm is not a deviation from
  // the part. Flagged like on_boundary; the search itself runs over Q's whole parameter box.
  bool outside_trim = false;
};

struct ProjectorOptions {
  // Samples per parameter direction of the start grid (the kd-tree holds seed_grid² points), 2..4096.
  // 0 = automatic: about 1 mm between samples, at most R/16 where R is the smallest curvature radius, at
  // least 2 samples per knot span, at most 2^20 samples (about 40 bytes each). Denser grids give closer
  // starts but more samples for the global check; bench/projection_bench.cc (ours_seed_grid) measures it.
  int seed_grid = 0;
  Status Validate() const;
};

// Projects points onto one surface: Build once, then Project / ProjectAll as often as needed. The
// const methods are thread-safe: the state built by Build (samples, kd-tree, B-spline span polynomials)
// is read-only, and anything that caches is made per call. Copies share that state.
class FootPointProjector {
 public:
  // Samples q, builds the kd-tree. Keeps its own copy of the B-spline geometry, so q may be destroyed
  // or changed afterwards.
  static Result<FootPointProjector> Build(const BSplineSurface& q, const ProjectorOptions& options = {});
  // Keeps a reference to s: s must outlive the projector and every copy of it.
  static Result<FootPointProjector> Build(const AnalyticSurface& s, const ProjectorOptions& options = {});

  // The nearest foot point (kd-tree start, Newton, global check; see the header comment).
  Result<FootPoint> Project(const Eigen::Vector3d& p) const;
  // The foot point Newton reaches from (u0, v0) (clamped into the domain): a local minimum of the
  // distance, the nearest one when the start is in its basin (e.g. the planned parameters of a probe
  // point). No kd-tree look-up and no global check.
  Result<FootPoint> ProjectFrom(const Eigen::Vector3d& p, double u0, double v0) const;
  // Project for every point, on the cores --threads allows (core/parallel.h: fixed chunks of points,
  // each point's foot independent of the others, so the same bytes for any thread count). A failing
  // point stops its chunk; the error names the first failing index ("points[17]"), as one thread would.
  Result<std::vector<FootPoint>> ProjectAll(const std::vector<Eigen::Vector3d>& points) const;
  // ProjectFrom(points[i], u0[i], v0[i]) for every i, in parallel like ProjectAll; each point keeps its
  // own Result (callers such as the scattered fit's parameter correction keep a failed point's start).
  std::vector<Result<FootPoint>> ProjectEachFrom(const std::vector<Eigen::Vector3d>& points,
                                                 const std::vector<double>& u0, const std::vector<double>& v0) const;

  const ParamDomain& domain() const;
  int seed_grid_u() const;  // samples along u and v actually used
  int seed_grid_v() const;
  // δ: every point of the surface lies within this distance of a start sample (measured bound, mm).
  double seed_cover_mm() const;

 private:
  struct Impl;
  explicit FootPointProjector(std::shared_ptr<const Impl> impl) : impl_(std::move(impl)) {}
  // span_caches = false skips precomputing the span polynomials (for one-point use).
  static Result<FootPointProjector> BuildBSpline(const BSplineSurface& q, const ProjectorOptions& options,
                                                 bool span_caches);
  friend Result<FootPoint> Project(const BSplineSurface& surface, const Eigen::Vector3d& p);

  std::shared_ptr<const Impl> impl_;
};

// One-point conveniences on a B-spline (kept for their callers). Project builds a coarse projector
// (33 × 33 start samples) on every call: to project many points, Build a FootPointProjector once.
Result<FootPoint> Project(const BSplineSurface& surface, const Eigen::Vector3d& p);
// Newton from (u0, v0) only, like FootPointProjector::ProjectFrom; no set-up cost.
Result<FootPoint> ProjectFrom(const BSplineSurface& surface, const Eigen::Vector3d& p, double u0, double v0);

}  // namespace formloop::recon
