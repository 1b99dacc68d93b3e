#pragma once
// `formloop simulate` and `formloop diagnose` as library functions (spec/simulation.md §2, §5).

#include <cstdint>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "core/status.h"

namespace formloop::app {

struct SimulateArgs {
  std::string run;         // a `formloop run` folder: Q, tool path, part (tool, true probe)
  std::string model;       // MODEL.json: what the machine does
  std::string probe_plan;  // PLAN.json|.csv (default: the run's plan)
  std::string out;         // LOG.csv
  std::string truth;       // optional: what was injected, per point, JSON
  std::uint64_t seed = 1;
  bool force = false;  // --force: replace output files formloop wrote (core/output_file.h)
};
// Writes the probe log the machine would report (and the truth file when asked), both or neither.
Status RunSimulate(const SimulateArgs& args);

struct DiagnoseArgs {
  std::string measured;  // LOG.csv (probe data) ...
  std::string features;  // ... or F.csv (feature positions)
  std::string run;       // the run that made the part (probe data)
  // More parts of the same machine, tool and material (--measured/--run given again, in pairs): the
  // shared effects are fitted over all parts, each part's set-up on its own (sim::DiagnosePooled).
  std::vector<std::string> more_measured, more_runs;
  std::string plan;           // its probing plan (default: the run's); without --run: plan-only diagnosis
  std::string probe_profile;  // without --run: the probe the log was measured with (else the run's)
  std::string baseline;       // MODEL.json (default: no effects)
  std::string out;            // folder: diagnosis.json, model.json, residuals.csv, inputs/
  std::string validate;       // optional second part: LOG2.csv ...
  std::string validate_run;   // ... and its run folder
  std::string validate_plan;  // ... and plan (default: that run's)
  std::string library;        // optional case library: store the extended model in case `case_uid`
  std::string case_uid;       // ... as its learned model for this machine/tool/material (replacing one with that key)
  std::string machine = "unspecified";  // the machine the part was cut on (the key's machine)
  std::vector<std::string> effects;     // screen only these catalogue effects (empty: all)
  // The rule base the plausible parameter ranges come from (rule "diagnose.plausible_ranges"): the
  // library's when --library is given, else data/starter/rules.json of `data_dir`.
  std::string data_dir;  // empty: retrieval::DefaultDataDir()
  bool propose = true;   // with --run: propose the experiment that separates each alias group
  // Direct measurements (sim::ReadDirectMeasurements: tool setter, reference sphere, datum faces) used
  // as extra observations in the fit; empty: none.
  std::string direct;
};
// Returns diagnosis.json's content; the summary goes to the log (stderr).
Result<nlohmann::json> RunDiagnose(const DiagnoseArgs& args);

}  // namespace formloop::app
