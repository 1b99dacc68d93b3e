#pragma once
// `formloop regress`: every reference part of data/regress/parts through the pipeline with the virtual
// machine, in name order, with one case library that starts as the starter library (so later parts
// can learn from earlier ones); key figures compared with stored goldens within stated tolerances.

#include <filesystem>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "app/pipeline.h"
#include "core/status.h"
#include "simulation/model.h"

namespace formloop::app {

// The key figures of a finished run folder: route, A and case, fit RMS and check max, planned scallop, raw Moran z
// of the first cycle, causes named, form error per cycle, loops to tolerance, the simulation-correction's
// defects before/after.
Result<nlohmann::json> KeyFigures(const std::filesystem::path& run_dir);

// How close a figure must stay to its golden: |value − golden| ≤ abs + rel·|golden|; exact for text,
// booleans, integers and lists of names.
struct FigureTolerance {
  double abs = 0, rel = 0;
};
const std::vector<std::pair<std::string, FigureTolerance>>& FigureTolerances();

struct FigureDifference {
  std::string figure;
  nlohmann::json golden, value;
  std::string allowed;  // "exact" or "±(abs + rel·|golden|)"
};
// The figures outside tolerance (missing figures count as different).
std::vector<FigureDifference> CompareFigures(const nlohmann::json& golden, const nlohmann::json& value);

// The causes a finished run named (loop-0/diagnosis/diagnosis.json) scored against the true effects of
// the virtual machine it was cut on: effects named that the machine does not have, true effects neither
// named, inside a reported alias group nor already in the baseline (the case's learned model) the
// diagnosis started from, and named parameters whose 95 % interval misses the true value. `truth` is
// the profile's model (noise ignored).
Result<nlohmann::json> TruthCheck(const std::filesystem::path& run_dir, const sim::Model& truth);

struct RegressOptions {
  std::filesystem::path parts;     // folder of part files
  std::filesystem::path goldens;   // folder of <part>.json goldens
  std::filesystem::path out;       // run folders and the library
  std::vector<std::string> only;   // part names (empty: all)
  bool update = false;             // rewrite the goldens and report what changed
  std::filesystem::path data_dir;  // default retrieval::DefaultDataDir()
};
struct RegressResult {
  nlohmann::json table = nlohmann::json::array();
  int regressions = 0;      // parts whose figures left the golden tolerances (or failed)
  int within_one_loop = 0;  // parts within tolerance after at most one compensation loop
  int parts = 0;
  // The truth line (TruthCheck summed over the parts): not compared with goldens.
  int named_not_in_profile = 0, true_effects = 0, true_missed = 0, parameters = 0, parameters_outside = 0;
  nlohmann::json ToJson() const;
};
Result<RegressResult> RunRegress(const RegressOptions& options);

}  // namespace formloop::app
