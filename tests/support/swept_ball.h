#pragma once
// Test support: an independent scallop/gouge checker for ball-end tool paths (used by
// tests/nc-gen/toolpath_test.cc and bench/checker_bench.cc). It uses nothing of the planner but
// Toolpath::points[].centre and .pass.
//
// A 3-axis ball-end tool (vertical axis, radius r) sweeps a capsule between the ball centres of
// consecutive feed CLs of a pass (a single ball at each CL). The machined surface is the lower envelope
// of these capsules: at (x, y) its height is the minimum over the capsules of the capsule's lowest point
// on the vertical line through (x, y) (closed form: the two end balls and the lower root of the lateral
// cylinder). The surface Q is sampled on dense windows of its (u, v) grid; at each sample P = Q(u, v)
// with unit normal n, Δz = machined height − P.z, and the normal distance is Δz · n_z:
// scallop = max(Δz n_z, 0), gouge = max(−Δz n_z, 0). This holds for every surface that is a graph over
// the xy plane in space (n_z > 0 and a one-to-one projection), which covers all nine reference surfaces
// (blade and tilted_paraboloid are not graphs over (u, v), but are over (x, y)) and a concave bowl.
// Capsules sit in a uniform xy hash (cell 1 mm) for speed; BruteForceHeight visits every capsule (the
// reference the hash is measured against).

#include <algorithm>
#include <cmath>
#include <cstddef>
#include <limits>
#include <unordered_map>
#include <vector>

#include <Eigen/Core>

#include "nc-gen/toolpath.h"
#include "reconstruction/bspline_surface.h"

namespace formloop::testing {

inline constexpr double kNoMaterialRemoved = std::numeric_limits<double>::infinity();

struct Capsule {
  Eigen::Vector3d a, b;
};

// Lowest z of the capsule {p : dist(p, [a, b]) ≤ r} on the vertical line through (x, y); +inf if missed.
inline double CapsuleBottom(const Capsule& c, double r, double x, double y) {
  using Eigen::Vector3d;
  double best = kNoMaterialRemoved;
  for (const Vector3d* e : {&c.a, &c.b}) {
    const double dx = x - e->x(), dy = y - e->y();
    const double d2 = dx * dx + dy * dy;
    if (d2 <= r * r) best = std::min(best, e->z() - std::sqrt(r * r - d2));
  }
  const Vector3d ab = c.b - c.a;
  const double len = ab.norm();
  if (len < 1e-12) return best;
  const Vector3d w = ab / len;
  // Point P = (x, y, a.z + s): D = D0 + s ẑ with D0 = (x − a.x, y − a.y, 0).
  const Vector3d d0(x - c.a.x(), y - c.a.y(), 0);
  const Vector3d p0 = d0 - d0.dot(w) * w;
  const Vector3d pe = Vector3d::UnitZ() - w.z() * w;
  const double qa = pe.squaredNorm();
  if (qa < 1e-14) return best;  // vertical segment: the end balls cover it
  const double qb = 2 * p0.dot(pe), qc = p0.squaredNorm() - r * r;
  const double disc = qb * qb - 4 * qa * qc;
  if (disc < 0) return best;
  const double s = (-qb - std::sqrt(disc)) / (2 * qa);
  const double t = (d0 + s * Vector3d::UnitZ()).dot(w) / len;
  if (t >= 0 && t <= 1) best = std::min(best, c.a.z() + s);
  return best;
}

class MachinedSurface {
 public:
  MachinedSurface(const nc::Toolpath& path, double r) : r_(r) {
    for (std::size_t k = 0; k < path.points.size(); ++k) {
      const Eigen::Vector3d& c = path.points[k].centre;
      if (k > 0 && path.points[k - 1].pass == path.points[k].pass) {
        Add({path.points[k - 1].centre, c});
      } else {
        Add({c, c});
      }
    }
  }
  // Machined height at (x, y), +inf where no capsule reaches.
  double Height(double x, double y) const {
    const auto it = cells_.find(Key(Cell(x), Cell(y)));
    if (it == cells_.end()) return kNoMaterialRemoved;
    double z = kNoMaterialRemoved;
    for (int i : it->second) z = std::min(z, CapsuleBottom(capsules_[i], r_, x, y));
    return z;
  }
  // The same height from every capsule (no hash): the reference for Height.
  double BruteForceHeight(double x, double y) const {
    double z = kNoMaterialRemoved;
    for (const Capsule& c : capsules_) z = std::min(z, CapsuleBottom(c, r_, x, y));
    return z;
  }
  std::size_t capsule_count() const { return capsules_.size(); }
  std::size_t cell_count() const { return cells_.size(); }

 private:
  static constexpr double kCell = 1.0;
  static long long Cell(double v) { return static_cast<long long>(std::floor(v / kCell)); }
  static long long Key(long long i, long long j) { return i * 1000003LL + j; }
  void Add(const Capsule& c) {
    const int id = static_cast<int>(capsules_.size());
    capsules_.push_back(c);
    const long long i0 = Cell(std::min(c.a.x(), c.b.x()) - r_), i1 = Cell(std::max(c.a.x(), c.b.x()) + r_);
    const long long j0 = Cell(std::min(c.a.y(), c.b.y()) - r_), j1 = Cell(std::max(c.a.y(), c.b.y()) + r_);
    for (long long i = i0; i <= i1; ++i) {
      for (long long j = j0; j <= j1; ++j) cells_[Key(i, j)].push_back(id);
    }
  }
  double r_;
  std::vector<Capsule> capsules_;
  std::unordered_map<long long, std::vector<int>> cells_;
};

struct CheckResult {
  double max_scallop_um = 0, max_gouge_um = 0;
  int samples = 0, uncovered = 0;
};

// Adds one sample P = Q(u, v) to `out`.
inline void CheckSample(const recon::BSplineSurface& q, const MachinedSurface& machined, double u, double v,
                        CheckResult* out) {
  const Eigen::Vector3d p = q.Point(u, v);
  const Eigen::Vector3d n = q.Normal(u, v);
  const double z = machined.Height(p.x(), p.y());
  ++out->samples;
  if (!std::isfinite(z)) {
    ++out->uncovered;
    return;
  }
  const double normal_um = (z - p.z()) * n.z() * 1e3;
  out->max_scallop_um = std::max(out->max_scallop_um, normal_um);
  out->max_gouge_um = std::max(out->max_gouge_um, -normal_um);
}

// Samples Q on `windows` × `windows` parameter windows of size win_u × win_v spread over the domain (kept
// `margin` inside its edges), spacing du × dv, and compares with the machined surface.
inline CheckResult Check(const recon::BSplineSurface& q, const nc::Toolpath& path, int windows, double win_u,
                         double win_v, double du, double dv, double margin) {
  const MachinedSurface machined(path, path.options.tool.radius_mm);
  const recon::ParamDomain dom = q.domain();
  CheckResult out;
  for (int wi = 0; wi < windows; ++wi) {
    for (int wj = 0; wj < windows; ++wj) {
      const double fu = windows == 1 ? 0.5 : static_cast<double>(wi) / (windows - 1);
      const double fv = windows == 1 ? 0.5 : static_cast<double>(wj) / (windows - 1);
      const double u0 = dom.u_min + margin + fu * (dom.u_span() - 2 * margin - win_u);
      const double v0 = dom.v_min + margin + fv * (dom.v_span() - 2 * margin - win_v);
      for (double v = v0; v <= v0 + win_v; v += dv) {
        for (double u = u0; u <= u0 + win_u; u += du) CheckSample(q, machined, u, v, &out);
      }
    }
  }
  return out;
}

}  // namespace formloop::testing
