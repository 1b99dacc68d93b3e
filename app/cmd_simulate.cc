// `formloop simulate` and `formloop diagnose`: thin CLI over app/model_jobs.h.

#include <algorithm>
#include <iostream>
#include <memory>
#include <string>
#include <vector>

#include "app/command.h"
#include "app/model_jobs.h"

namespace formloop::app {

void AddSimulateCommand(CLI::App& root, CommandAction* action) {
  auto args = std::make_shared<SimulateArgs>();
  CLI::App* cmd = root.add_subcommand(
      "simulate",
      "Machine a run's tool path on the virtual machine with a model of effects and write the probe log it would "
      "report, to rehearse a job or hide effects for a test.");
  cmd->add_option("--run", args->run, "a `formloop run` folder (Q, tool path, part)")->required();
  cmd->add_option("--model", args->model, "MODEL.json: effects and parameters (format: docs/formats.md)")->required();
  cmd->add_option("--probe-plan", args->probe_plan,
                  "PLAN.json or PLAN.csv (id,u,v,x,y,z,nx,ny,nz[,ax,ay,az]); default: the run's plan with the "
                  "approaches it planned");
  cmd->add_option("--out", args->out, "probe log to write (CSV: id,x,y,z,ax,ay,az,t)")->required();
  cmd->add_option("--truth", args->truth, "also write what was injected at each point (JSON)");
  AddForceFlag(cmd, &args->force);
  cmd->add_option("--seed", args->seed, "noise seed")->default_val(1);
  cmd->callback([args, action] { *action = [args] { return RunSimulate(*args); }; });
}

void AddDiagnoseCommand(CLI::App& root, CommandAction* action) {
  auto args = std::make_shared<DiagnoseArgs>();
  CLI::App* cmd = root.add_subcommand(
      "diagnose",
      "Compare measurement with the baseline simulation: residuals and their Moran's I, screening of every "
      "catalogue effect, the named cause(s) with parameters and standard errors, confounded effects, an unexplained "
      "systematic residual when nothing explains it, the extended model and its gain on held-out data. Writes "
      "DIR/diagnosis.json, DIR/model.json, DIR/residuals.csv and DIR/inputs/; prints diagnosis.json on stdout.");
  auto measured = std::make_shared<std::vector<std::string>>();
  auto runs = std::make_shared<std::vector<std::string>>();
  cmd->add_option("--measured", *measured,
                  "measured probe log LOG.csv; give --measured/--run again for more parts of the same machine, tool "
                  "and material (shared effects fitted over all, each part's set-up on its own)");
  cmd->add_option("--features", args->features, "feature positions F.csv: id,x_nom,y_nom,[z_nom,]x,y,[z] (mm)");
  cmd->add_option("--run", *runs, "the `formloop run` folder that made the part (with --measured, one per log)");
  cmd->add_option("--plan", args->plan,
                  "its probing plan (.json/.csv); default: the run's. Without --run: plan-only diagnosis of the "
                  "effects that do not need the tool path");
  cmd->add_option("--probe-profile", args->probe_profile, "without --run: the probe profile the log was measured with");
  cmd->add_option("--baseline", args->baseline, "MODEL.json the simulation used; default: no effects");
  cmd->add_option("--out", args->out, "output folder")->required();
  cmd->add_option("--validate", args->validate, "probe log of a second part to measure the gain on");
  cmd->add_option("--validate-run", args->validate_run, "the run folder of that second part");
  cmd->add_option("--validate-plan", args->validate_plan, "its plan; default: that run's");
  cmd->add_option("--library", args->library, "case library: store the extended model in the case given by --case");
  cmd->add_option("--case", args->case_uid, "uid of the case the part belongs to");
  cmd->add_option("--machine", args->machine, "machine name for the learned model's key (machine/tool/material)")
      ->default_val("unspecified");
  cmd->add_option("--effects", args->effects,
                  "screen only these catalogue effects (e.g. setup_offset,setup_rotation when only the set-up is in "
                  "question); default: all")
      ->delimiter(',');
  cmd->add_flag("!--no-proposal", args->propose, "do not propose the experiment that separates an alias group");
  cmd->add_option("--direct", args->direct,
                  "DIRECT.json: parameters measured on the machine (tool setter, reference sphere, datum faces) with "
                  "their uncertainty, used as extra observations in the fit (docs/formats.md, direct measurements)");
  cmd->callback([args, action, measured, runs] {
    if (!measured->empty()) args->measured = measured->front();
    if (!runs->empty()) args->run = runs->front();
    args->more_measured.assign(measured->begin() + std::min<std::size_t>(1, measured->size()), measured->end());
    args->more_runs.assign(runs->begin() + std::min<std::size_t>(1, runs->size()), runs->end());
    *action = [args]() -> Status {
      FL_ASSIGN_OR_RETURN(const nlohmann::json out, RunDiagnose(*args));
      std::cout << out.dump(2) << std::endl;
      return Status::Ok();
    };
  });
}

}  // namespace formloop::app
