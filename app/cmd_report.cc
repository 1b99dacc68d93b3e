// `formloop report DIR [--out FILE]`: the self-contained report.html of a run folder or of an `analyse`
// folder (app/report.h); `formloop report --batch DIR`: the plant overview of a batch or regression
// folder (DIR/overview.html). Prints {"report": FILE} on stdout (stdout carries only JSON).

#include <iostream>
#include <memory>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "app/command.h"
#include "app/report.h"
#include "core/log.h"
#include "core/output_file.h"

namespace formloop::app {
namespace {

struct ReportArgs {
  std::string run_dir;
  std::string out;  // empty: RUN_DIR/report.html (RUN_DIR/overview.html with --batch)
  bool batch = false;
  bool force = false;
};

// Every file of the folder the report reads from (its own report.html aside): none may be overwritten.
std::vector<NamedPath> FolderInputs(const std::filesystem::path& dir, const std::filesystem::path& own) {
  std::vector<NamedPath> inputs;
  std::error_code ec;
  for (auto it = std::filesystem::recursive_directory_iterator(dir, ec);
       !ec && it != std::filesystem::recursive_directory_iterator(); it.increment(ec)) {
    if (it->is_regular_file(ec) && it->path() != dir / own) inputs.push_back({"RUN_DIR", it->path()});
  }
  return inputs;
}

Status RunReport(const ReportArgs& args) {
  const char* own = args.batch ? "overview.html" : "report.html";
  const std::filesystem::path out =
      args.out.empty() ? std::filesystem::path(args.run_dir) / own : std::filesystem::path(args.out);
  if (out.extension() != ".html" && out.extension() != ".htm") {
    return Status::BadInput(Where{.file = out.string(), .field = "--out"}, "the report is an HTML file",
                            "give a file name ending in .html");
  }
  FL_RETURN_IF_ERROR(CheckOutputsNotInputs({{"--out", out}}, FolderInputs(args.run_dir, own)));
  // Without --out the report is the folder's own: (re)writing it is what the command is for, in a folder formloop
  // wrote. Any other file is replaced only with --force and only when formloop wrote it (core/output_file.h).
  const bool own_report = args.out.empty() && OutputFolder::HasMarker(args.run_dir);
  if (!own_report) FL_RETURN_IF_ERROR(CheckReplaceable(out, args.force, "--out"));
  FL_RETURN_IF_ERROR(args.batch ? WriteBatchOverview(args.run_dir, out) : WriteRunReport(args.run_dir, out));
  log::Info("report written: {}", out.string());
  std::cout << nlohmann::json{{"report", out.string()}}.dump() << std::endl;
  return Status::Ok();
}

}  // namespace

void AddReportCommand(CLI::App& root, CommandAction* action) {
  auto args = std::make_shared<ReportArgs>();
  CLI::App* cmd = root.add_subcommand(
      "report",
      "Write a self-contained HTML report of a run folder or an analyse folder: verdict, retrieval, plan, loop "
      "history, the part in 3-D, deviation maps before/after, Moran scatter and LISA clusters, diagnosis. Everything "
      "is embedded; nothing is fetched. With --batch: one overview page for a batch or regression folder.");
  cmd->add_option("RUN_DIR", args->run_dir,
                  "a `formloop run` folder (holds summary.json) or a `formloop analyse` folder (holds analysis.json)")
      ->required();
  cmd->add_option("--out", args->out,
                  "HTML file to write; default: RUN_DIR/report.html (RUN_DIR/overview.html with --batch)");
  cmd->add_flag("--batch", args->batch,
                "RUN_DIR is a batch folder of `formloop run` or the output of `formloop regress`: write the plant "
                "overview linking each part's report");
  AddForceFlag(cmd, &args->force);
  cmd->callback([args, action] { *action = [args] { return RunReport(*args); }; });
}

}  // namespace formloop::app
