#pragma once
// How a subcommand joins the `formloop` binary.
//
// Each subcommand lives in app/cmd_<name>.cc and provides one Add<Name>Command function that declares
// its options on a CLI11 subcommand (name, help, default declared once) and, when the user picks it,
// stores the work to do in *action. main() parses, runs the action, prints a non-ok Status on
// stderr and exits with Status::ExitCode(). The work itself is a library function the tests call
// directly; the command is a thin layer over it.

#include <functional>
#include <string>

#include <CLI/CLI.hpp>

#include "core/status.h"

namespace formloop::app {

using CommandAction = std::function<Status()>;

// `--force` of a command that writes files: an output file that exists is replaced only with it, and only when
// formloop wrote it (core/output_file.h); without it the command refuses and writes nothing.
inline CLI::Option* AddForceFlag(CLI::App* cmd, bool* force) {
  return cmd->add_flag("--force", *force, "replace an output file that exists, when formloop wrote it");
}

void AddRunCommand(CLI::App& root, CommandAction* action);
void AddRegressCommand(CLI::App& root, CommandAction* action);
void AddSurfacesCommand(CLI::App& root, CommandAction* action);
void AddKbCommand(CLI::App& root, CommandAction* action);
// `retrieve` (app/cmd_retrieve.cc).
void AddRetrieveCommand(CLI::App& root, CommandAction* action);
// "NUxNV" (or "NU,NV") into two integers of at least 2; `option` names the option in the message.
Status ParseLayout(const std::string& text, const std::string& option, int* nu, int* nv);

// `fit` and `project` (app/cmd_fit.cc).
void AddFitCommand(CLI::App& root, CommandAction* action);
// `nc path` and `nc probe` (app/cmd_nc.cc).
void AddNcCommand(CLI::App& root, CommandAction* action);
// `nc distribute` (app/cmd_nc_program.cc), added to the `nc` subcommand.
void AddNcDistributeCommand(CLI::App* nc, CommandAction* action);
// `nc compensate --program`: a program formloop did not write, mapped to Q and mirror-compensated
// (app/cmd_nc_program.cc; the options are declared with the rest of `nc compensate` in cmd_nc.cc).
struct ShopProgramArgs {
  std::string program, surface, face_name, field, out, side, dialect = "linuxcnc";
  int face_index = -1;
  int decimals = 4;
  bool force = false;  // --force: replace output files formloop wrote
  double lambda = 0, ball_radius_mm = 0, chord_tol_mm = 0.001, contact_tol_mm = 0.01, max_offset_um = 200;
};
Status CompensateShopProgram(const ShopProgramArgs& args);
// `analyse moran` (app/cmd_analyse.cc).
void AddAnalyseCommand(CLI::App& root, CommandAction* action);
// `calibrate sphere` and `calibrate synth-sphere` (app/cmd_calibrate.cc).
void AddCalibrateCommand(CLI::App& root, CommandAction* action);
// `simulate` and `diagnose` (app/cmd_simulate.cc).
void AddSimulateCommand(CLI::App& root, CommandAction* action);
void AddDiagnoseCommand(CLI::App& root, CommandAction* action);
// `report` (app/cmd_report.cc).
void AddReportCommand(CLI::App& root, CommandAction* action);
// `link emulate|collect|write|program|check|selftest` (app/cmd_link.cc).
void AddLinkCommand(CLI::App& root, CommandAction* action);
// `optimise cutting|feed|program` (app/cmd_optimise.cc).
void AddOptimiseCommand(CLI::App& root, CommandAction* action);
// `tune` (app/cmd_tune.cc).
void AddTuneCommand(CLI::App& root, CommandAction* action);
// `machine linuxcnc config|run|probe` (app/cmd_machine.cc).
void AddMachineCommand(CLI::App& root, CommandAction* action);

}  // namespace formloop::app
