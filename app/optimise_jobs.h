#pragma once
// `formloop optimise cutting|feed|program` as library functions: the three levels of process
// optimisation (spec/process-optimization.md §1-3, planning/) on a user's files.
//
// Every command writes its outputs into a fresh folder (--out): built as "<out>.partial" and renamed
// into place when complete, so the folder is whole or absent. An existing --out is refused unless
// --force, and --force replaces only a folder an optimise command wrote (it holds optimise.json). An
// input inside --out is refused (formloop never writes onto an input). optimise.json records the
// command, its arguments, the SHA-256 of every input file and the results; stdout gets the same JSON.
//
//   cutting   Level 1. Without --program: the optimum of one cut (--a-p-mm, --a-e-mm) by the adaptive
//             GA (--seed), checked against the exact log-space LP optimum and reported with the Taylor
//             tool lives T_p and T_c. With --program: the per-block depth-of-cut check (L1-DOC-RANGE names
//             every failing block; nothing is written) and the optimum written into the program's F and S
//             words (program.<ext>). The engagement per block comes from --engagement (JSON of
//             planning/cutting_program.h) or from cutting --stock with the program (planning/
//             tool_path_engagement.h). Recommended cutting data for the fusion come from --cutting-data
//             (JSON array) and/or the case library (--library KB --case UID: manufacturing.cutting_data).
//   feed      Level 2. The fuzzy feed controller against the spindle-current plant of §2.6 along the
//             engagement of a program cut from --stock (or --scenario wall-step, formloop's own raster
//             over a stepped wall), next to the conservative constant feed through the same plant:
//             feed.csv (every control sample of both runs), feed.png (current and feed over time),
//             report.html (the plot and the §2.7 figures, self-contained) and optimise.json.
//   program   Level 3. The inspection of a part (deviations.csv of `formloop run`/`formloop analyse`)
//             against the nominal surface Q of the run that cut it (or Q.step with the program, the ball
//             radius and the tolerance given): out-of-tolerance regions traced to
//             the program's blocks and those blocks adjusted (program.<ext>, adjustment.json), the §3.5
//             record appended to the inspection log (--log, JSON Lines) after the folder is complete; its
//             "time" is the current UTC time (the only thing that differs between two identical runs, and
//             it is not in the folder).

#include <cstdint>
#include <string>

#include <nlohmann/json.hpp>

#include "core/status.h"

namespace formloop::app {

struct OptimiseOutput {
  std::string out;     // the output folder
  bool force = false;  // replace an earlier optimise folder
};

struct OptimiseCuttingArgs {
  OptimiseOutput output;
  std::string coefficients;       // COEFFS.json (planning/cutting_model.h, data/cutting/s1.json)
  double a_p_mm = 0, a_e_mm = 0;  // one cut (no --program)
  std::string program, dialect = "linuxcnc";
  std::string engagement;    // ENGAGEMENT.json ...
  std::string stock;         // ... or STOCK.json
  std::string cutting_data;  // recommended data (JSON array of records)
  std::string library, case_uid;
  double model_credibility = 0.3;
  std::uint64_t seed = 1;
};
Result<nlohmann::json> RunOptimiseCutting(const OptimiseCuttingArgs& args);

struct OptimiseFeedArgs {
  OptimiseOutput output;
  std::string program, dialect = "linuxcnc", stock;
  std::string scenario;  // "wall-step" instead of program + stock
  std::uint64_t noise_seed = 1;
};
Result<nlohmann::json> RunOptimiseFeed(const OptimiseFeedArgs& args);

struct OptimiseProgramArgs {
  OptimiseOutput output;
  std::string run;      // the `formloop run` folder: Q, ball radius, tolerance, dialect ...
  std::string surface;  // ... or Q.step with --program, --inspection, --ball-radius-mm, --tolerance-mm
  double ball_radius_mm = 0;
  std::string dialect = "linuxcnc";  // without --run
  std::string program;               // default: the run's toolpath program
  std::string inspection;            // deviations.csv; default: the run's loop-0/deviations.csv
  std::string load;                  // optional: {"N120": load, ...} (e.g. mean I − I_0 per block from Level 2)
  std::string log;                   // inspection log (JSON Lines) to append the §3.5 record to
  double tolerance_mm = 0;           // t_p; 0: the part's (2 x its ± tolerance)
  std::string inspection_id, part_id, operation_id, probe_calibration_id;
};
Result<nlohmann::json> RunOptimiseProgram(const OptimiseProgramArgs& args);

}  // namespace formloop::app
