// `formloop tune`: offset tuning from dimension measurements (tuning/tune.h; spec/tuning-and-link.md §1-6).
//
//   formloop tune --model M.json --points P.csv [--block B.csv] [--offsets CURRENT.json]
//                 [--strategy wls|average] --out DIR [--recheck-block B2.csv] [--confirm]
//                 [--acknowledge-ng D3,D7] [--accept-alarm] [--session TEXT] [--measured-at ISO8601] [--force]
//
// Writes DIR/report.json, report.csv, offsets.json (the write plan `formloop link write` reads),
// audit.jsonl and summary.txt, and prints a JSON summary on stdout. Exit 0 when the plan is SAFE (confirmed
// or waiting for --confirm); 1 when it is RECHECK, INTERVENE or BLOCKED (the outputs say why); 2 for bad
// input (nothing written).

#include <iostream>
#include <memory>
#include <string>
#include <vector>

#include "app/command.h"
#include "tuning/tune.h"

namespace formloop::app {
namespace {

struct TuneArgs {
  std::string model, points, block, recheck_block, offsets, out, strategy = "wls", session, measured_at;
  std::vector<std::string> acknowledge;
  bool confirm = false, accept_alarm = false, force = false;
};

Status Tune(const TuneArgs& args) {
  tuning::TuneOptions o;
  o.model = args.model;
  o.points = args.points;
  o.block = args.block;
  o.recheck_block = args.recheck_block;
  o.current_offsets = args.offsets;
  o.out = args.out;
  if (!tuning::ParseStrategy(args.strategy, &o.strategy)) {
    return Status::BadInput(Where{.field = "--strategy"}, "value '" + args.strategy + "' is unknown",
                            "write wls or average");
  }
  o.confirm = args.confirm;
  o.accept_alarm = args.accept_alarm;
  o.acknowledge_ng = args.acknowledge;
  o.session = args.session;
  o.measured_at = args.measured_at;
  o.force = args.force;
  FL_ASSIGN_OR_RETURN(const tuning::TuneReport report, tuning::RunTune(o));
  nlohmann::json summary = report.SummaryJson();
  summary["out"] = args.out;
  std::cout << summary.dump(2) << "\n";
  std::cout.flush();
  if (!std::cout) return Status::IoError("tune: writing to stdout failed");
  if (report.plan.status == tuning::PlanStatus::kSafe) return Status::Ok();
  std::string reasons;
  for (const auto& r : report.plan.blocked_reasons) reasons += "\n  - " + r;
  const std::string what = std::string("tune: write plan ") + tuning::PlanStatusName(report.plan.status) +
                           ", nothing may be written (" + args.out + "/offsets.json):" + reasons;
  return report.plan.status == tuning::PlanStatus::kBlocked ? Status::Failed(what) : Status::SafetyLimit(what);
}

}  // namespace

void AddTuneCommand(CLI::App& root, CommandAction* action) {
  auto args = std::make_shared<TuneArgs>();
  CLI::App* cmd = root.add_subcommand(
      "tune",
      "Dimensions from probe points, OK/NG, and the tool/work offset changes that bring the compensated "
      "dimensions back to their targets, through the safety ladder to a write plan (no controller is touched)");
  cmd->add_option("--model", args->model, "measurement model JSON (formloop.measurement_model)")->required();
  cmd->add_option("--points", args->points, "probe points CSV: id,x,y,z[,t] in the process WCS (mm, s)")->required();
  cmd->add_option("--block", args->block, "standard-block CSV of this session: axis,reference_mm,measured_mm[,t]");
  cmd->add_option("--recheck-block", args->recheck_block,
                  "the standard block probed again after a RECHECK: recompute and decide SAFE or INTERVENE");
  cmd->add_option(
      "--offsets", args->offsets,
      "current offsets read at acquisition start (formloop.current_offsets); without it nothing can be written");
  cmd->add_option("--strategy", args->strategy, "wls (weighted bounded solve) or average (seed-004 averaging)")
      ->capture_default_str();
  cmd->add_option("--out", args->out, "output folder (must not exist; --force replaces an earlier tune output)")
      ->required();
  cmd->add_flag("--confirm", args->confirm,
                "the operator confirms the whole set (only a SAFE plan is marked confirmed)");
  cmd->add_option("--acknowledge-ng", args->acknowledge,
                  "dimension ids the operator accepts will stay NG (or, TOLERANCE_ONLY, become NG by the change)")
      ->delimiter(',');
  cmd->add_flag("--accept-alarm", args->accept_alarm,
                "average strategy: send values beyond the allowed maximum (logged)");
  cmd->add_option("--session", args->session, "session text for the plan (default: part code and points file name)");
  cmd->add_option("--measured-at", args->measured_at,
                  "measurement time, ISO 8601 with time zone, for the report records");
  cmd->add_flag("--force", args->force, "replace an earlier tune output in --out");
  cmd->callback([args, action] { *action = [args] { return Tune(*args); }; });
}

}  // namespace formloop::app
