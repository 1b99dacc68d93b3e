#pragma once
// The per-part batch pipeline behind `formloop run` (docs/ARCHITECTURE.md, "One part through the
// pipeline"). This first version runs every stage for real on an analytic reference surface:
//
//   sample → B-spline fit (OpenCASCADE) → raster tool path with ball-end offset → LinuxCNC program
//   (+ probing plan and probing program) → loop: virtual machining of the program as written →
//   probe log → probe compensation → signed deviations to Q → Moran's I and systematic/random
//   decomposition → if the form error exceeds the tolerance, a mirror-compensated program, which the
//   next loop machines.
//
// Outputs go to a run folder that is built under "<out>.partial" and renamed to <out> only when the
// run completes, so <out> is never half-written; a failed run leaves "<out>.failed" with the log.

#include <filesystem>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "app/part.h"
#include "core/status.h"

namespace formloop::app {

struct RunOptions {
  std::filesystem::path out;      // run folder
  bool force = false;             // replace an existing run folder
  std::string part_source;        // path of the part file, recorded in the summary
};

// One loop of the run. The compensation decision is the §8 evaluation of the decomposition
// (metrology::EvaluateForm, spec/metrology.md §7–§8): compensate when the form error exceeds the
// tolerance and d_s is significant (a non-constant model was chosen, or a constant offset beyond
// 2.576 standard errors), and a further loop is allowed. The raw Moran z is reported, not decided on.
struct LoopSummary {
  int index = 0;
  double form_error_um = 0;
  double systematic_peak_um = 0;
  double random_sigma_um = 0;
  double raw_moran_z = 0;         // Moran z of the deviations themselves (reported only)
  int field_degree = 0;
  bool within_tolerance = false;
  bool compensated = false;       // a compensated program was written after this loop
  std::string chosen_model;       // the decomposition's chosen model ("constant", "plane", "bspline 6x6", ...)
  double residual_moran_z = 0;    // residual Moran z (Cliff–Ord) of the chosen model
  bool residual_independent = false;  // residual_moran_z <= 2.326
  bool systematic_significant = false;  // from the §8 evaluation
  bool compensation_advised = false;    // the §8 evaluation's decision (before the loop limit)
  std::string decision;                 // one sentence: what the loop decided and why
};

struct RunSummary {
  std::string part;
  std::string surface;
  double tolerance_um = 0;
  double fit_check_max_um = 0;
  std::vector<LoopSummary> loops;
  bool within_tolerance = false;
  std::filesystem::path out;
  nlohmann::json ToJson() const;
};

Result<RunSummary> RunPart(const PartSpec& part, const RunOptions& options);

}  // namespace formloop::app
