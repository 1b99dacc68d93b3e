#pragma once
// Curvature-weighted probing plans (spec/nc-gen.md §5: "equidistant in parameter space, or
// curvature-weighted; count configurable"). The equidistant plan is PlanProbingGrid in
// metrology/probe.h; this file adds the curvature-weighted one, with the same ProbingPlan output.
//
// Method (deterministic, no random numbers):
//  1. Candidates: a regular nu × nv grid of (u, v) over the inset domain (corners included), with
//     nu · nv ≈ min(kProbingCandidatesPerPoint · count, kMaxProbingCandidates) and nu : nv in the
//     ratio of the 3-D lengths of the two middle iso-lines, so candidates are roughly square on Q.
//  2. Density: each candidate gets the target areal point density (points per mm², up to a common
//     factor)
//        ρ = 1 + β · L · (|κ1| + |κ2|) / 2,
//     β = curvature_weight (dimensionless), κ1, κ2 the principal curvatures of Q (1/mm) and L the
//     diagonal of the 3-D bounding box of the candidates (mm), so L·κ is dimensionless and does not
//     change when the part is scaled. β = 1 on a part whose mean absolute curvature is 1/L doubles
//     the density there. A candidate whose curvatures are not finite (degenerate parametrisation)
//     gets ρ = 1.
//     The area element |S_u × S_v| du dv of the brief's density is not a factor of ρ: the selection
//     below measures spacing with 3-D distances, which already accounts for how much surface a
//     parameter cell covers; multiplying ρ by it again would crowd points where the parametrisation
//     is stretched, and β = 0 would then not give uniform spacing on Q.
//  3. Selection: weighted farthest-point sampling in 3-D. The first point is the candidate of
//     highest ρ (lowest candidate index on ties); each next point is the unchosen candidate with the
//     highest priority d · sqrt(ρ), d the 3-D distance to the nearest chosen point (lowest index on
//     ties). Local spacing then scales like 1/sqrt(ρ), i.e. points per area like ρ.
// Ids are 1..count in selection order (the most important points first, so a plan cut short keeps
// the best coverage). Each point carries u, v, point = Q(u, v) and the unit normal of Q there.
// Cost: O(count · candidates) distance evaluations, at most 1.6e9 at the largest count.

#include "core/status.h"
#include "metrology/probe.h"
#include "reconstruction/bspline_surface.h"

namespace formloop::metrology {

inline constexpr int kProbingCandidatesPerPoint = 40;
inline constexpr int kMaxProbingCandidates = 40000;

// count in 1..(number of candidates, at most kMaxProbingCandidates); inset_fraction in [0, 0.45)
// of each parameter span (as in PlanProbingGrid); curvature_weight = β ≥ 0 (0: uniform spacing on Q).
// On a trimmed Q only candidates that ProbePositionAllowed (probe.h) with edge_margin_mm take part.
Result<ProbingPlan> PlanProbingCurvatureWeighted(const recon::BSplineSurface& q, int count, double inset_fraction,
                                                 double curvature_weight = 1.0,
                                                 double edge_margin_mm = kProbeEdgeMarginMm);

}  // namespace formloop::metrology
