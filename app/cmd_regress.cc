// `formloop regress`: the pipeline on every reference surface, with a pass/fail table.

#include <iostream>
#include <memory>

#include "app/command.h"
#include "app/pipeline.h"
#include "core/json_io.h"
#include "core/log.h"
#include "core/progress.h"
#include "reconstruction/analytic_surface.h"

namespace formloop::app {

void AddRegressCommand(CLI::App& root, CommandAction* action) {
  struct Options {
    std::string base;
    std::string out = "runs/regress";
    std::vector<std::string> surfaces;
  };
  auto opts = std::make_shared<Options>();
  CLI::App* cmd = root.add_subcommand(
      "regress",
      "Regression run on the reference surfaces: runs the pipeline of a base part on each surface and checks that it "
      "ends within tolerance with a B-spline fit error far below it. Prints a JSON table; exit code 1 when any fails.");
  cmd->add_option("--base", opts->base, "base part description; its surface is replaced by each reference surface")
      ->required()
      ->check(CLI::ExistingFile);
  cmd->add_option("--out,-o", opts->out, "folder for the per-surface run folders (replaced)")->capture_default_str();
  cmd->add_option("--surfaces", opts->surfaces, "only these reference surfaces (default: all)")->delimiter(',');
  cmd->callback([opts, action] {
    *action = [opts]() -> Status {
      FL_ASSIGN_OR_RETURN(Json base, ReadJsonFile(opts->base));
      std::vector<std::string> names = opts->surfaces.empty() ? recon::ReferenceSurfaceNames() : opts->surfaces;
      nlohmann::json table = nlohmann::json::array();
      int failures = 0;
      Progress progress("regress", names.size());
      for (const std::string& name : names) {
        Json part_json = base;
        part_json["name"] = base.value("name", std::string("part")) + "-" + name;
        part_json["surface"] = {{"reference", name}};
        FL_ASSIGN_OR_RETURN(PartSpec part, ParsePart(part_json, opts->base + " (surface " + name + ")"));
        RunOptions run;
        run.out = std::filesystem::path(opts->out) / name;
        run.force = true;
        run.part_source = opts->base;
        auto summary = RunPart(part, run);
        nlohmann::json row = {{"surface", name}};
        if (!summary.ok()) {
          row["pass"] = false;
          row["error"] = summary.status().ToString();
          ++failures;
        } else {
          const RunSummary& s = summary.value();
          // The fit must be an order of magnitude below the tolerance, so it is never taken for machining error.
          const bool fit_ok = s.fit_check_max_um <= 0.1 * s.tolerance_um;
          const bool pass = s.within_tolerance && fit_ok;
          row["pass"] = pass;
          row["loops"] = s.loops.size();
          row["form_error_first_um"] = s.loops.front().form_error_um;
          row["form_error_final_um"] = s.loops.back().form_error_um;
          row["tolerance_um"] = s.tolerance_um;
          row["fit_check_max_um"] = s.fit_check_max_um;
          if (!pass) ++failures;
        }
        log::Info("regress {:<18} {}", name, row.dump());
        table.push_back(row);
        progress.Advance();
      }
      progress.Finish();
      std::cout << nlohmann::json({{"surfaces", table}, {"failures", failures}}).dump(2) << std::endl;
      if (failures > 0) return Status::Failed(std::to_string(failures) + " reference surface(s) failed the regression");
      return Status::Ok();
    };
  });
}

}  // namespace formloop::app
