// formloop: closed-loop precision machining of free-form surfaces. One binary, one subcommand per
// front door (docs/ARCHITECTURE.md). Exit codes: 0 ok, 1 the job's own failure, 2 bad input/usage.

#include <cmath>
#include <iostream>
#include <string>

#include "app/command.h"
#include "core/log.h"
#include "core/number_text.h"
#include "core/parallel.h"
#include "core/progress.h"
#include "core/version.h"
#include "core/work_estimate.h"
#include "reconstruction/cad_io.h"

int main(int argc, char** argv) {
  using namespace formloop;
  CLI::App app(
      "formloop — closed-loop precision machining of free-form surfaces.\n"
      "Plans ball-end tool paths on the ideal surface, writes NC and probing programs, analyses in-situ probe\n"
      "measurements (deviations, Moran's I, systematic/random split) and compensates the systematic error.\n"
      "Machine-readable results go to stdout (JSON); logs go to stderr and to the run folder.",
      "formloop");
  app.require_subcommand(1);
  app.fallthrough();  // global options (--quiet, --log-level) may also follow the subcommand
  app.set_version_flag("--version", std::string("formloop ") + Version());
  std::string level = "info";
  app.add_option("--log-level", level, "stderr log level: trace, debug, info, warn, error, off")->capture_default_str();
  bool quiet = false;
  app.add_flag("--quiet,-q", quiet, "only warnings and errors on stderr, no progress");
  bool yes = false;
  app.add_flag("--yes", yes,
               "go ahead with a job above formloop's stated size limits (more than 20 million points, 4 GB of memory, "
               "8 h on the machine or 2 GB of output, estimated before it starts); never above what this computer "
               "can hold");

  int threads = 0;
  app.add_option("--threads", threads,
                 "worker threads of the parallel stages (k-NN weights, ...); 0 = all cores. Every output is the "
                 "same bytes for any count")
      ->check(CLI::NonNegativeNumber)
      ->capture_default_str();

  double cad_timeout_s = recon::kDefaultCadReadTimeout_s;
  app.add_option("--cad-timeout-s", cad_timeout_s,
                 "seconds OpenCASCADE's STEP/IGES reader may take for one file before it is stopped and the file "
                 "reported (the reader runs in a child process, killed at the limit); 0 = no limit")
      ->check([](const std::string& text) {
        double seconds = 0;
        const bool valid = ParseDouble(text, &seconds) && std::isfinite(seconds) && seconds >= 0;
        return valid ? std::string() : "'" + text + "' is not a number of seconds >= 0 (0 = no limit)";
      })
      ->capture_default_str();

  app::CommandAction action;
  app::AddRunCommand(app, &action);
  app::AddRegressCommand(app, &action);
  app::AddSurfacesCommand(app, &action);
  app::AddFitCommand(app, &action);
  app::AddNcCommand(app, &action);
  app::AddKbCommand(app, &action);
  app::AddRetrieveCommand(app, &action);
  app::AddAnalyseCommand(app, &action);
  app::AddCalibrateCommand(app, &action);
  app::AddSimulateCommand(app, &action);
  app::AddDiagnoseCommand(app, &action);
  app::AddReportCommand(app, &action);
  app::AddLinkCommand(app, &action);
  app::AddOptimiseCommand(app, &action);
  app::AddTuneCommand(app, &action);
  app::AddMachineCommand(app, &action);

  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    const int code = app.exit(e);  // prints help or the usage error
    return code == 0 ? 0 : 2;
  }
  auto parsed = log::ParseLevel(quiet ? "warn" : level);
  if (!parsed.ok()) {
    std::cerr << "formloop: " << parsed.status().message() << "\n";
    return 2;
  }
  log::SetLevel(parsed.value());
  if (quiet) Progress::SetEnabled(false);
  SetLargeWorkConfirmed(yes);
  SetThreadCount(threads);
  recon::SetCadReadTimeoutSeconds(cad_timeout_s);
  if (!action) {
    std::cerr << app.help();
    return 2;
  }
  Status status;
  try {
    status = action();
  } catch (const std::bad_alloc&) {
    status = Status::Failed(
        "out of memory: the job asks for more than this computer can hold; nothing was replaced. Fix: check the "
        "sizes given (grids, point counts, scallop and chord tolerances) and their units");
  } catch (const std::exception& e) {
    status = Status::Internal(std::string("unexpected exception: ") + e.what());
  }
  if (!status.ok()) {
    std::cerr << "formloop: " << status.ToString() << "\n";
    return status.ExitCode();
  }
  return 0;
}
