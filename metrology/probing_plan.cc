#include "metrology/probing_plan.h"

#include <algorithm>
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <limits>
#include <string>
#include <vector>

#include <Eigen/Core>
#include <Eigen/Geometry>

#include "core/point_io.h"
#include "reconstruction/analytic_surface.h"
#include "reconstruction/trim.h"

namespace formloop::metrology {
namespace {

// 3-D length of the polyline through `segments` + 1 points of Q from (u0, v0) to (u1, v1).
double IsoLineLength(const recon::BSplineSurface& q, double u0, double v0, double u1, double v1) {
  constexpr int kSegments = 32;
  double length = 0;
  Eigen::Vector3d previous = q.Point(u0, v0);
  for (int s = 1; s <= kSegments; ++s) {
    const double t = static_cast<double>(s) / kSegments;
    const Eigen::Vector3d p = q.Point(u0 + t * (u1 - u0), v0 + t * (v1 - v0));
    length += (p - previous).norm();
    previous = p;
  }
  return length;
}

struct Candidate {
  double u = 0, v = 0;
  Eigen::Vector3d point;
  double mean_abs_curvature = 0;  // (|κ1| + |κ2|)/2, 1/mm; 0 where not finite
};

}  // namespace

Result<ProbingPlan> PlanProbingCurvatureWeighted(const recon::BSplineSurface& q, int count, double inset_fraction,
                                                 double curvature_weight, double edge_margin_mm) {
  if (!q.valid()) return Status::BadInput(Where{.field = "probing.surface"}, "the surface Q is empty");
  if (count < 1) {
    return Status::BadInput(Where{.field = "probing.count"}, "must be at least 1, got " + std::to_string(count),
                            "ask for one or more probe points");
  }
  if (!(inset_fraction >= 0 && inset_fraction < 0.45)) {
    return Status::BadInput(Where{.field = "probing.inset_fraction"}, "must be in [0, 0.45)",
                            "give the margin as a fraction of each parameter span, e.g. 0.05");
  }
  if (!(curvature_weight >= 0 && std::isfinite(curvature_weight))) {
    return Status::BadInput(Where{.field = "probing.curvature_weight"}, "must be a finite number ≥ 0",
                            "use 0 for uniform spacing, 1 for the default weighting");
  }

  const recon::ParamDomain dom = q.domain();
  const double u0 = dom.u_min + inset_fraction * dom.u_span(), u1 = dom.u_max - inset_fraction * dom.u_span();
  const double v0 = dom.v_min + inset_fraction * dom.v_span(), v1 = dom.v_max - inset_fraction * dom.v_span();

  // Candidate grid, aspect from the 3-D lengths of the middle iso-lines.
  const long long wanted =
      std::min<long long>(static_cast<long long>(kProbingCandidatesPerPoint) * count, kMaxProbingCandidates);
  const double length_u = IsoLineLength(q, u0, 0.5 * (v0 + v1), u1, 0.5 * (v0 + v1));
  const double length_v = IsoLineLength(q, 0.5 * (u0 + u1), v0, 0.5 * (u0 + u1), v1);
  double aspect = length_u > 0 && length_v > 0 ? length_u / length_v : 1.0;
  aspect = std::clamp(aspect, 1e-3, 1e3);
  const double n_wanted = static_cast<double>(wanted);
  const int nu = std::max(2, static_cast<int>(std::lround(std::sqrt(n_wanted * aspect))));
  const int nv = std::max(2, static_cast<int>(n_wanted / nu));
  std::size_t n = static_cast<std::size_t>(nu) * static_cast<std::size_t>(nv);
  if (static_cast<std::size_t>(count) > n) {
    return Status::BadInput(Where{.field = "probing.count"},
                            std::to_string(count) + " points asked for, but only " + std::to_string(n) +
                                " candidates are sampled (at most " + std::to_string(kMaxProbingCandidates) + ")",
                            "ask for at most " + std::to_string(n) + " points");
  }

  if (!(edge_margin_mm >= 0) || !std::isfinite(edge_margin_mm)) {
    return Status::BadInput(Where{.field = "probing.edge_margin_mm"}, "must be a finite number >= 0");
  }
  std::vector<Candidate> candidates;
  candidates.reserve(n);
  Eigen::AlignedBox3d box;
  int left_out = 0;
  for (int j = 0; j < nv; ++j) {
    for (int i = 0; i < nu; ++i) {
      Candidate c;
      c.u = u0 + (u1 - u0) * i / (nu - 1);
      c.v = v0 + (v1 - v0) * j / (nv - 1);
      const recon::SurfaceDerivatives d = q.Derivatives(c.u, c.v);
      c.point = d.p;
      if (!ProbePositionAllowed(q, c.u, c.v, c.point, edge_margin_mm)) {
        ++left_out;
        continue;
      }
      const recon::PrincipalCurvatures k = recon::CurvaturesFromDerivatives(d);
      const double h = 0.5 * (std::abs(k.k1) + std::abs(k.k2));
      c.mean_abs_curvature = std::isfinite(h) ? h : 0.0;
      box.extend(c.point);
      candidates.push_back(c);
    }
  }
  n = candidates.size();
  if (static_cast<std::size_t>(count) > n) {
    return Status::BadInput(Where{.field = "probing.count"},
                            std::to_string(count) + " points asked for, but only " + std::to_string(n) +
                                " candidates lie inside the trimmed face at least " + FormatExact(edge_margin_mm) +
                                " mm from its edge",
                            "ask for at most " + std::to_string(n) + " points");
  }
  const double diagonal = box.diagonal().norm();  // L, mm

  std::vector<double> sqrt_rho(n);
  std::size_t first = 0;
  for (std::size_t c = 0; c < n; ++c) {
    sqrt_rho[c] = std::sqrt(1.0 + curvature_weight * diagonal * candidates[c].mean_abs_curvature);
    if (sqrt_rho[c] > sqrt_rho[first]) first = c;  // strict: the lowest index wins ties
  }

  // Weighted farthest-point sampling.
  std::vector<double> nearest(n, std::numeric_limits<double>::infinity());
  std::vector<char> chosen(n, 0);
  ProbingPlan plan;
  plan.trimmed = q.trim() != nullptr && !q.trim()->natural();
  plan.edge_margin_mm = plan.trimmed ? edge_margin_mm : 0.0;
  plan.left_out = left_out;
  plan.points.reserve(static_cast<std::size_t>(count));
  std::size_t next = first;
  for (int id = 1; id <= count; ++id) {
    const Candidate& c = candidates[next];
    chosen[next] = 1;
    ProbePoint p;
    p.id = id;
    p.u = c.u;
    p.v = c.v;
    p.point = c.point;
    p.normal = q.Normal(c.u, c.v);
    plan.points.push_back(p);
    if (id == count) break;
    double best = -1;
    std::size_t best_index = 0;
    for (std::size_t k = 0; k < n; ++k) {
      if (chosen[k]) continue;
      nearest[k] = std::min(nearest[k], (candidates[k].point - c.point).norm());
      const double priority = nearest[k] * sqrt_rho[k];
      if (priority > best) {
        best = priority;
        best_index = k;
      }
    }
    next = best_index;
  }
  return plan;
}

}  // namespace formloop::metrology
