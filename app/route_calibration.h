#pragma once
// `formloop kb calibrate`: is routing by A calibrated? spec/case-library.md §4 asks that "leave-one-out over
// the library reports how often each route leads to an in-tolerance part". One report, three measures:
//
// - "retrieval" (always; RetrievalModel::LeaveOneOut): every case is retrieved by a model trained without it
//   (standardiser, GHSOM, IC counts); per route the share whose best case is of the same family, A's
//   distribution and the family confusion. It covers every case, starter cases included, but "same family"
//   is only a proxy for "the case's plan and learned model fit this part".
// - "outcomes" (always; OutcomesByRoute): what `formloop run` recorded when it retained a part: the route it
//   took, with the library as it was then, and its form error per cycle.
// - "rerun" (with CalibrationOptions::rerun): the measure the spec asks for. Every retained case that was cut
//   on the virtual machine (part.rerun: the resolved part and its machine) is run again through the whole
//   pipeline (RunPart): retrieval by a model trained without the case, the route's plan, pre-compensation
//   from the retrieved case's learned model, machining, analysis and compensation loops, against the library
//   as it is now; nothing is retained. Per route: parts, within tolerance on the first cycle and after at
//   most one compensation loop, the median first-cycle form error; and one row per part beside what was
//   recorded when it was retained. Starter cases and parts cut on a real machine carry nothing to cut them
//   again on, so they count only in "retrieval" (and "outcomes").

#include <filesystem>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "core/status.h"
#include "kb/library.h"

namespace formloop::app {

// Per route from the outcomes the pipeline retained (part.outcome): parts, within tolerance on the first
// cycle and after at most one compensation loop, the median first-cycle form error. Cases without a
// pipeline outcome (e.g. the starter cases) are counted apart.
nlohmann::json OutcomesByRoute(const std::vector<kb::CaseRecord>& cases);

struct CalibrationOptions {
  int breadth = 1;                 // candidate breadth of the retrieval (RetrieveOptions::breadth)
  int max_cases = 1000;            // "retrieval": at most this many cases left out (0: all; one training each)
  bool rerun = false;              // run the retained virtual-machine parts again (see above)
  std::filesystem::path work_dir;  // their run folders; empty: a temporary folder, removed afterwards
  std::filesystem::path data_dir;  // taxonomies and machine profiles (default: retrieval::DefaultDataDir())
};

// The report of `formloop kb calibrate` (JSON; see the header comment).
Result<nlohmann::json> CalibrationReport(const std::string& kb_path, const CalibrationOptions& options);

}  // namespace formloop::app
