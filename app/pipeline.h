#pragma once
// The per-part pipeline behind `formloop run` (docs/ARCHITECTURE.md, "One part through the pipeline"):
//
//   surface Q (B-spline) → retrieval from the case library and routing by A → plan (the case's, the
//   simulation-corrected one, or the flagged default) → tool path, NC and probing programs → pre-
//   compensation from the case's learned model → loop: machining (virtual machine with a machine
//   profile, or measured probe logs) → probe compensation, deviations, Moran's I, decomposition →
//   diagnosis against the case's model (loop 0) → mirror compensation while the form error exceeds α
//   → report.html → retain: the part becomes a case (or updates its own) with outcome, causes and
//   the learned model.
//
// A run folder is built as "<out>.partial" with status.json {"state": "incomplete", "stage": ...}
// and renamed to <out> (state "complete") only when every output is written and the case library
// has been updated; a killed run leaves "<out>.partial" marked incomplete and the library untouched
// (the library changes in one transaction at the very end). A failed run leaves "<out>.failed".

#include <cstdint>
#include <filesystem>
#include <functional>
#include <memory>
#include <string>
#include <string_view>
#include <vector>

#include <Eigen/Core>
#include <nlohmann/json.hpp>

#include "app/part.h"
#include "core/status.h"
#include "retrieval/retrieve.h"

namespace formloop::app {

struct RunOptions {
  std::filesystem::path out;  // run folder
  bool force = false;         // replace an existing run folder
  std::string part_source;    // path of the part file, recorded in the summary
  std::string kb;             // case library; empty: no retrieval (default plan, flagged)
  std::string machine;        // "virtual" (the part's machine.effects), "virtual:NAME|PATH.json" or "linuxcnc:CONFIG"
  std::vector<std::string> measured;  // measured probe logs, one per cycle, instead of the virtual machine
  bool retain = true;                 // store the outcome in the case library (needs kb)
  bool learn = true;                  // pre-compensate with the case's learned model
  bool report = true;                 // write report.html
  // The first cycle's diagnosis pools the part with at most this many earlier cases of the library that
  // share its machine/tool/material and hold a part record (newest first); 0: the part alone.
  int pool_cases = 2;
  std::filesystem::path data_dir;  // taxonomies, machines (default: retrieval::DefaultDataDir())
  // Retrieve with this model instead of the library's stored GHSOM (the leave-one-out rerun of
  // app/route_calibration.h: a model trained without the part's own case); the cases are still read from kb.
  std::shared_ptr<const retrieval::RetrievalModel> retrieval_model;
  // Called after each stage with its wall time (the pipeline benchmark); never written to the run
  // folder, which stays byte-identical between runs.
  std::function<void(std::string_view stage, double seconds)> on_stage;
};

// One machining cycle. The compensation decision is the §8 evaluation of the decomposition
// (metrology::EvaluateForm): compensate when the form error exceeds the tolerance and d_s is
// significant, while a further loop is allowed.
struct LoopSummary {
  int index = 0;
  double form_error_um = 0;
  double systematic_peak_um = 0;
  double random_sigma_um = 0;
  double raw_moran_z = 0;
  int field_degree = 0;
  bool within_tolerance = false;
  bool compensated = false;
  std::string chosen_model;
  double residual_moran_z = 0;  // of d_u
  bool residual_independent = false;
  double field_residual_moran_z = 0;  // of y − d_s (differs when the spatial filter ran)
  double fine_scale_rms_um = 0;       // d_f: correlated structure finer than the field, not compensated
  bool systematic_significant = false;
  bool compensation_advised = false;
  std::string decision;
};

struct RunSummary {
  std::string part;
  std::string surface;
  double tolerance_um = 0;
  double fit_check_max_um = 0;
  std::string route = "default";  // direct | simulate | default
  double similarity = -1;         // A of the best case (-1: no library)
  std::string case_uid;           // the retrieved case
  bool flag_engineer = true;
  std::string plan_source;  // "case X", "case X, simulation-corrected", "default plan"
  bool precompensated = false;
  double precompensation_scale = 0;
  std::vector<std::string> causes;                  // named by the diagnosis of loop 0
  std::vector<std::string> pooled_cases;            // earlier cases that diagnosis pooled (RunOptions::pool_cases)
  std::size_t probe_points_planned = 0;             // the probing grid's points before the reach check
  std::vector<std::int64_t> probe_points_left_out;  // ids the probe cannot reach clear of the part
  // Where Q is concave below the ball radius: CL points at gouge risk, those lifted out of Q (the region
  // they cover is left uncut: its box of CC points, mm) and the largest lift (nc::Toolpath).
  int gouge_risk_points = 0, lifted_points = 0;
  Eigen::Vector3d uncut_min = Eigen::Vector3d::Zero(), uncut_max = Eigen::Vector3d::Zero();
  double max_lift_mm = 0;
  std::string retained;  // "added <uid>", "updated <uid>", "" (not retained)
  std::vector<LoopSummary> loops;
  bool within_tolerance = false;
  std::filesystem::path out;
  int LoopsToTolerance() const;  // compensation loops until within tolerance, -1 if never
  nlohmann::json ToJson() const;
};

Result<RunSummary> RunPart(const PartSpec& part, const RunOptions& options);

}  // namespace formloop::app
