// `formloop run PART.json|FOLDER ... [--kb KB] [--machine virtual[:PROFILE] | linuxcnc:CONFIG | --measured LOG.csv ...]
// --out DIR`:
// the per-part pipeline (app/pipeline.h), for one part or a batch.
//
// One part: DIR is its run folder (default runs/<part name>); summary.json is printed on stdout.
// A batch (several part files, or a folder of *.json parts, taken in name order): DIR holds one run
// folder per part and batch_summary.json; a progress bar goes to stderr and a summary table at the end.
// Parts run in order, so a part can learn from the parts before it through the case library; with
// --jobs N, N parts run at once in separate processes (a part learns from those finished before it
// started). One failing part never stops the others. Exit status: 0 when every part ran (and, with --strict, ended
// within tolerance); 1 otherwise; 2 for bad command-line input.

#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <iostream>
#include <map>
#include <memory>

#include <fmt/format.h>

#include "app/command.h"
#include "app/pipeline.h"
#include "core/atomic_file.h"
#include "core/json_io.h"
#include "core/log.h"
#include "core/output_folder.h"
#include "core/progress.h"

namespace formloop::app {
namespace {
namespace fs = std::filesystem;

struct RunArgs {
  std::vector<std::string> parts;
  std::string out;
  std::string kb;
  std::string machine;
  std::vector<std::string> measured;
  bool force = false;
  bool strict = false;
  bool no_retain = false;
  bool no_learn = false;
  bool no_report = false;
  int jobs = 1;
  int pool_cases = 2;
};

// Part files of the arguments: files as given, folders expanded to their *.json files in name order.
Result<std::vector<fs::path>> PartFiles(const std::vector<std::string>& args) {
  std::vector<fs::path> files;
  for (const std::string& a : args) {
    std::error_code ec;
    if (fs::is_directory(a, ec)) {
      std::vector<fs::path> in_folder;
      for (const auto& entry : fs::directory_iterator(a, ec)) {
        if (entry.is_regular_file() && entry.path().extension() == ".json") in_folder.push_back(entry.path());
      }
      std::sort(in_folder.begin(), in_folder.end());
      if (in_folder.empty()) {
        return Status::BadInput(Where{.file = a}, "the folder holds no part files (*.json)");
      }
      files.insert(files.end(), in_folder.begin(), in_folder.end());
    } else if (fs::is_regular_file(a, ec)) {
      files.emplace_back(a);
    } else {
      return Status::BadInput(Where{.file = a}, "no such part file or folder");
    }
  }
  return files;
}

RunOptions OptionsOf(const RunArgs& args) {
  RunOptions run;
  run.force = args.force;
  run.kb = args.kb;
  run.machine = args.machine;
  run.measured = args.measured;
  run.retain = !args.no_retain;
  run.learn = !args.no_learn;
  run.report = !args.no_report;
  run.pool_cases = args.pool_cases;
  return run;
}

Status RunOne(const RunArgs& args, const fs::path& file) {
  FL_ASSIGN_OR_RETURN(PartSpec part, ReadPart(file));
  RunOptions run = OptionsOf(args);
  run.out = args.out.empty() ? fs::path("runs") / part.name : fs::path(args.out);
  run.part_source = file.string();
  FL_ASSIGN_OR_RETURN(RunSummary summary, RunPart(part, run));
  nlohmann::json json = summary.ToJson();
  json["run_folder"] = run.out.string();
  std::cout << json.dump(2) << std::endl;
  log::Info("outputs in {}/ (report.html, summary.json, surface/, toolpath/, loop-*/)", run.out.string());
  if (args.strict && !summary.within_tolerance) {
    return Status::Failed("part '" + part.name + "' is out of tolerance after " + std::to_string(summary.loops.size()) +
                          " cycle(s) (--strict)");
  }
  return Status::Ok();
}

std::string Row(const std::string& part, const std::string& status, const std::string& route, const std::string& a,
                const std::string& first, const std::string& last, const std::string& cycles) {
  return fmt::format("{:<28} {:<8} {:<9} {:>7} {:>10} {:>10} {:>6}", part, status, route, a, first, last, cycles);
}

// One part of a batch: its batch_summary.json row and its line of the summary table.
struct PartOutcome {
  nlohmann::json row;
  std::string table_line;
  bool failed = false;
  bool out_of_tolerance = false;
  nlohmann::json ToJson() const {
    return {{"row", row}, {"table_line", table_line}, {"failed", failed}, {"out_of_tolerance", out_of_tolerance}};
  }
};

PartOutcome RunBatchPart(const RunArgs& args, const fs::path& out, const fs::path& file) {
  PartOutcome outcome;
  nlohmann::json& row = outcome.row;
  row = {{"part_file", file.string()}};
  // A part file that does not parse fails like a run that does not complete.
  auto run_one = [&]() -> Result<RunSummary> {
    FL_ASSIGN_OR_RETURN(PartSpec part, ReadPart(file));
    RunOptions run = OptionsOf(args);
    run.out = out / part.name;
    run.part_source = file.string();
    row["part"] = part.name;
    row["run_folder"] = run.out.string();
    return RunPart(part, run);
  };
  const Result<RunSummary> summary = run_one();
  if (!summary.ok()) {
    outcome.failed = true;
    row["status"] = "failed";
    row["error"] = summary.status().ToString();
    log::Error("{}: {}", file.string(), summary.status().ToString());
    outcome.table_line = Row(row.value("part", file.filename().string()), "FAILED", "-", "-", "-", "-", "-");
  } else {
    const RunSummary& s = *summary;
    outcome.out_of_tolerance = !s.within_tolerance;
    row["status"] = s.within_tolerance ? "within tolerance" : "out of tolerance";
    row["summary"] = s.ToJson();
    outcome.table_line = Row(s.part, s.within_tolerance ? "ok" : "OUT", s.route,
                             s.similarity >= 0 ? fmt::format("{:.3f}", s.similarity) : "-",
                             fmt::format("{:.2f}", s.loops.front().form_error_um),
                             fmt::format("{:.2f}", s.loops.back().form_error_um), std::to_string(s.loops.size()));
  }
  return outcome;
}

// --jobs N: each part in a process of its own (fork), at most N at a time, all against the same case
// library (its transactions keep concurrent retain steps apart). A worker hands its outcome back in a
// file of the batch folder, read and removed by the parent; a worker that dies is that part's failure.
// The outcomes are put back in file order, so the table and batch_summary.json read as in a serial run.
std::vector<PartOutcome> RunBatchInProcesses(const RunArgs& args, const fs::path& out,
                                             const std::vector<fs::path>& files, Progress* progress) {
  std::vector<PartOutcome> outcomes(files.size());
  std::map<pid_t, std::size_t> running;
  auto outcome_file = [&](std::size_t i) { return out / (".outcome-" + std::to_string(i) + ".json"); };
  std::size_t next = 0;
  std::cout.flush();
  std::cerr.flush();
  while (next < files.size() || !running.empty()) {
    while (running.size() < static_cast<std::size_t>(args.jobs) && next < files.size()) {
      const pid_t pid = fork();
      if (pid == 0) {
        const PartOutcome outcome = RunBatchPart(args, out, files[next]);
        const Status written = WriteFileAtomic(outcome_file(next), outcome.ToJson().dump());
        std::cout.flush();
        std::cerr.flush();
        _exit(written.ok() ? 0 : 3);
      }
      if (pid < 0) {
        // No process to be had: this part runs here, in the parent.
        outcomes[next] = RunBatchPart(args, out, files[next]);
        progress->Advance();
      } else {
        running[pid] = next;
      }
      ++next;
    }
    if (running.empty()) continue;
    int wait_status = 0;
    const pid_t done = waitpid(-1, &wait_status, 0);
    if (done < 0) break;
    const auto it = running.find(done);
    if (it == running.end()) continue;
    const std::size_t i = it->second;
    running.erase(it);
    PartOutcome& outcome = outcomes[i];
    auto read = ReadJsonFile(outcome_file(i));
    std::error_code ec;
    fs::remove(outcome_file(i), ec);
    if (read.ok() && read->contains("row") && read->contains("table_line")) {
      outcome.row = (*read)["row"];
      outcome.table_line = (*read)["table_line"].get<std::string>();
      outcome.failed = read->value("failed", true);
      outcome.out_of_tolerance = read->value("out_of_tolerance", false);
    } else {
      const std::string how = WIFSIGNALED(wait_status)
                                  ? "was killed by signal " + std::to_string(WTERMSIG(wait_status))
                                  : "ended with exit code " + std::to_string(WEXITSTATUS(wait_status));
      outcome.failed = true;
      outcome.row = {{"part_file", files[i].string()},
                     {"status", "failed"},
                     {"error", "internal error: the part's worker process " + how + " without a result"}};
      log::Error("{}: {}", files[i].string(), outcome.row["error"].get<std::string>());
      outcome.table_line = Row(files[i].stem().string(), "FAILED", "-", "-", "-", "-", "-");
    }
    progress->Advance();
  }
  return outcomes;
}

Status RunBatch(const RunArgs& args, const std::vector<fs::path>& files) {
  const fs::path out = args.out.empty() ? fs::path("runs") / "batch" : fs::path(args.out);
  // The batch folder is formloop's (marker); a folder of the user's is never written into.
  FL_RETURN_IF_ERROR(OutputFolder::Create(out, "--out", "run (batch)"));
  Progress progress("run", files.size());
  std::vector<PartOutcome> outcomes;
  if (args.jobs > 1) {
    outcomes = RunBatchInProcesses(args, out, files, &progress);
  } else {
    for (const fs::path& file : files) {
      outcomes.push_back(RunBatchPart(args, out, file));
      progress.Advance();
    }
  }
  progress.Finish();
  nlohmann::json rows = nlohmann::json::array();
  int failed = 0, out_of_tolerance = 0;
  std::vector<std::string> table = {Row("part", "status", "route", "A", "first um", "final um", "cycles")};
  for (const PartOutcome& o : outcomes) {
    rows.push_back(o.row);
    table.push_back(o.table_line);
    failed += o.failed ? 1 : 0;
    out_of_tolerance += o.out_of_tolerance ? 1 : 0;
  }
  const nlohmann::json batch = {{"parts", rows},
                                {"count", files.size()},
                                {"failed", failed},
                                {"out_of_tolerance", out_of_tolerance},
                                {"within_tolerance", static_cast<int>(files.size()) - failed - out_of_tolerance}};
  FL_RETURN_IF_ERROR(WriteJsonFile(out / "batch_summary.json", batch));
  for (const std::string& line : table) std::cerr << line << '\n';
  std::cout << batch.dump(2) << std::endl;
  if (failed > 0)
    return Status::Failed(std::to_string(failed) + " of " + std::to_string(files.size()) + " part(s) failed");
  if (args.strict && out_of_tolerance > 0) {
    return Status::Failed(std::to_string(out_of_tolerance) + " part(s) out of tolerance (--strict)");
  }
  return Status::Ok();
}

}  // namespace

void AddRunCommand(CLI::App& root, CommandAction* action) {
  auto args = std::make_shared<RunArgs>();
  CLI::App* cmd = root.add_subcommand(
      "run",
      "Run the per-part pipeline: ideal surface (B-spline), retrieval from the case library and routing by A (direct / "
      "simulation-correction / flagged default plan), tool path, NC and probing programs, pre-compensation from the "
      "case's learned model, machining (virtual machine or measured logs), analysis, diagnosis, compensation until "
      "within tolerance, report.html, and the retain step. Several parts or a folder run as a batch.");
  cmd->add_option("parts", args->parts,
                  "part description(s) (JSON) or folder(s) of them, e.g. data/parts/demo-saddle.json")
      ->required();
  cmd->add_option("--out,-o", args->out,
                  "run folder (one part; default runs/<part>) or batch folder (default runs/batch)");
  cmd->add_option("--kb", args->kb,
                  "case library (formloop kb init --starter); without it the default plan is used, flagged");
  cmd->add_option("--machine", args->machine,
                  "virtual (the part's machine.effects), virtual:PROFILE (data/machines/PROFILE.json or a path) or "
                  "linuxcnc:CONFIG (a `formloop machine linuxcnc config` folder: LinuxCNC runs the probing program)");
  cmd->add_option("--measured", args->measured, "measured probe log(s) of a real machine, one per cycle, in order");
  cmd->add_flag("--force", args->force, "replace existing run folders");
  cmd->add_flag("--strict", args->strict, "exit with code 1 when a part ends out of tolerance");
  cmd->add_flag("--no-retain", args->no_retain, "do not store the outcome in the case library");
  cmd->add_flag("--no-learn", args->no_learn, "do not pre-compensate with the case's learned model");
  cmd->add_flag("--no-report", args->no_report, "do not write report.html");
  cmd->add_option("--pool-cases", args->pool_cases,
                  "diagnose the first cycle together with up to N earlier cases of the library that share the "
                  "machine, tool and material (newest first; the shared effects fitted jointly, each part's set-up "
                  "on its own); 0: the part alone")
      ->check(CLI::Range(0, 16))
      ->capture_default_str();
  cmd->add_option("--jobs,-j", args->jobs,
                  "batch: run N parts at once, each in a process of its own, against the same case library (the "
                  "table and batch_summary.json keep the file order; parts running at the same time do not learn "
                  "from each other)")
      ->check(CLI::Range(1, 64))
      ->capture_default_str();
  cmd->callback([args, action] {
    *action = [args]() -> Status {
      FL_ASSIGN_OR_RETURN(std::vector<fs::path> files, PartFiles(args->parts));
      const bool batch = files.size() > 1 || (args->parts.size() == 1 && fs::is_directory(args->parts[0]));
      if (batch && !args->measured.empty()) {
        return Status::BadInput(Where{.field = "--measured"}, "measured logs belong to one part",
                                "run the parts one at a time with their own logs");
      }
      return batch ? RunBatch(*args, files) : RunOne(*args, files.front());
    };
  });
}

}  // namespace formloop::app
