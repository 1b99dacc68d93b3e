// `formloop run PART.json --out DIR`: the per-part batch pipeline.

#include <iostream>
#include <memory>

#include "app/command.h"
#include "app/pipeline.h"
#include "core/log.h"

namespace formloop::app {

void AddRunCommand(CLI::App& root, CommandAction* action) {
  struct Options {
    std::string part;
    std::string out;
    bool force = false;
    bool strict = false;
  };
  auto opts = std::make_shared<Options>();
  CLI::App* cmd = root.add_subcommand(
      "run",
      "Run the per-part pipeline on PART.json: ideal surface (B-spline fit, STEP), tool path and LinuxCNC program, "
      "probing program, virtual machining and probing, deviations, Moran's I, systematic/random decomposition, and "
      "mirror-compensated programs until the form error is within tolerance. Writes a run folder with the resolved "
      "inputs and every stage's JSON report; prints summary.json on stdout.");
  cmd->add_option("part", opts->part, "part description (JSON), e.g. data/parts/demo-saddle.json")
      ->required()
      ->check(CLI::ExistingFile);
  cmd->add_option("--out,-o", opts->out, "run folder to create (default: runs/<part name>)");
  cmd->add_flag("--force", opts->force, "replace the run folder if it exists");
  cmd->add_flag("--strict", opts->strict, "exit with code 1 when the part ends out of tolerance");
  cmd->callback([opts, action] {
    *action = [opts]() -> Status {
      FL_ASSIGN_OR_RETURN(PartSpec part, ReadPart(opts->part));
      RunOptions run;
      run.out = opts->out.empty() ? std::filesystem::path("runs") / part.name : std::filesystem::path(opts->out);
      run.force = opts->force;
      run.part_source = opts->part;
      FL_ASSIGN_OR_RETURN(RunSummary summary, RunPart(part, run));
      nlohmann::json json = summary.ToJson();
      json["run_folder"] = run.out.string();
      std::cout << json.dump(2) << std::endl;
      log::Info("outputs in {}/ (summary.json, surface/, toolpath/, loop-*/)", run.out.string());
      if (opts->strict && !summary.within_tolerance) {
        return Status::Failed("part '" + part.name + "' is out of tolerance after " +
                              std::to_string(summary.loops.size()) + " loop(s) (--strict)");
      }
      return Status::Ok();
    };
  });
}

}  // namespace formloop::app
