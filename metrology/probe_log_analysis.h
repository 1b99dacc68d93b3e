#pragma once
// The one analysis of a probe log (spec/metrology.md §1–8), behind both `formloop run` (each cycle) and
// `formloop analyse`:
//
//   1. probe compensation of each record along its own approach direction (ContactPoint);
//   2. foot points on Q: from the planned (u, v) when a plan is given (the log's ids are checked against
//      it), else by global search. A point whose foot point is farther than max_distance_mm, or is held
//      at the edge of Q (the deviation is then not a normal distance), is flagged and left out;
//   3. optional registration to Q over a chosen subset of the 6 DOF (Besl & McKay 1992 point-to-surface,
//      metrology/registration.h), fitted to the unflagged points; every point is moved and projected again;
//   4. the decomposition (raw Moran's I, the residual-Moran ladder guarded by spatial block CV, d_s | d_f |
//      d_u) and, with a tolerance, the §8 evaluation (metrology/decomposition.h);
//   5. local Moran (LISA, Anselin 1995) of the deviations and of the random part d_u on the same k-NN
//      weights in (u, v), and the spatial lag of the deviations for the Moran scatter plot.
//
// The per-point table (PerPointTable) has one set of names, suffixed with their unit where they carry
// one; run folders (loop-K/deviations.csv|.ply) and `analyse` folders (deviations.csv|.ply) hold the same
// columns, so `formloop report` draws both.

#include <cstdint>
#include <optional>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "core/point_set.h"
#include "core/status.h"
#include "metrology/decomposition.h"
#include "metrology/deviations.h"
#include "metrology/morans_i.h"
#include "metrology/probe.h"
#include "metrology/registration.h"
#include "reconstruction/bspline_surface.h"

namespace formloop::metrology {

struct ProbeLogAnalysisOptions {
  // Ladder, CV guard, coverage factor, tolerance (when given: the §8 evaluation); `neighbours` is the k
  // of the k-NN weights in (u, v) of every Moran statistic here.
  DecompositionOptions decomposition;
  double max_distance_mm = 1.0;  // search distance: a point whose foot point is farther is flagged
  DofMask registration{};        // none (default): deviations in the machine frame
  int lisa_permutations = 999;   // conditional permutations of both LISAs; 0 = analytical p-values
  double lisa_alpha = 0.05;      // significance of a LISA cluster
  std::uint64_t lisa_seed = 1;   // seeds the permutations
  Status Validate() const;
};

// A record left out of the statistics, and why.
struct FlaggedPoint {
  std::int64_t id = 0;
  long line = 0;  // in the probe log
  double distance_mm = 0, deviation_um = 0, u = 0, v = 0;
  std::string reason;
  nlohmann::json ToJson() const;
};

struct ProbeLogAnalysis {
  std::size_t records = 0;                         // in the log
  std::vector<std::int64_t> not_measured;          // planned ids without a record (with a plan)
  std::vector<FlaggedPoint> flagged;               // left out, in log order
  std::optional<RegistrationReport> registration;  // when registration was asked for
  std::vector<Deviation> deviations;               // the points used, in log order
  std::vector<long> lines;                         // their probe-log lines
  Decomposition decomposition;
  std::vector<double> lag_um;                   // spatial lag of the centred deviations, µm
  LocalMoranResult lisa;                        // of the deviations
  std::optional<LocalMoranResult> lisa_random;  // of d_u; absent when d_u is identically zero

  // n_records, n_used, n_flagged, mean/rms/max |deviation| (µm) and where the largest is.
  nlohmann::json DeviationSummaryJson() const;
  nlohmann::json FlaggedJson() const;
  // The LISA of d_u with its significant points, or a note when d_u is identically zero.
  nlohmann::json LisaRandomJson() const;
  // One row per point used: contact point (x, y, z; registered when registration is on), the normal of Q
  // at the foot point (nx, ny, nz), id, and the scalars of PerPointColumns() in that order.
  PointSet PerPointTable() const;
  // {name: description} of the per-point scalars.
  static nlohmann::json PerPointColumns();
};

// `plan` may be null (foot points by global search). Errors name the log line of a point that cannot
// be projected; a log whose ids are not in the plan is BadInput naming the id.
Result<ProbeLogAnalysis> AnalyseProbeLog(const recon::BSplineSurface& q, const ProbeLog& log, const ProbeModel& probe,
                                         const ProbingPlan* plan, const ProbeLogAnalysisOptions& options);

}  // namespace formloop::metrology
