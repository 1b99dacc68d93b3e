// `formloop kb ...`: the case-library maintenance tool (spec/case-library.md; kb/library.h).
//
//   formloop kb init    PATH [--starter] [--data DIR]  create or migrate a library; --starter fills a new one with
//                                                   the synthetic starter cases (data/starter/) and trains it
//   formloop kb train   PATH [--tau1 T] [--tau2 T] [--seed S]  standardise, train and store the GHSOM (JSON report)
//   formloop kb calibrate PATH [--breadth B] [--max-cases N] [--rerun [--work DIR]] [--data DIR]  leave-one-out report
//                                                   of the routes (JSON; app/route_calibration.h): retrieval
//                                                   without each case (at most N of them, evenly spaced),
//                                                   retained outcomes, and with --rerun the retained virtual-machine
//                                                   parts run again on a library without them
//   formloop kb migrate PATH                        bring an existing library to the current schema
//   formloop kb add     PATH CASE.json [--replace]  add one case (refuses an existing uid unless --replace, and a
//                                                   case retrieval could not use: concepts not in the taxonomies
//                                                   of --data, a descriptor not of 24 finite values); when
//                                                   the stored GHSOM was current, the case is inserted into it
//                                                   (Ghsom::Insert, local retraining) and it stays current;
//                                                   otherwise the GHSOM is left stale (kb check) until kb train
//   formloop kb import  PATH FILE.jsonl [--replace] import an export file in one transaction (cases checked as
//                                                   by add; one bad case refuses the whole file)
//   formloop kb export  PATH --out FILE.jsonl       deterministic JSON Lines, written atomically
//   formloop kb list    PATH [--family F] [--json]  the cases, sorted by uid
//   formloop kb show    PATH UID                    one case as its case-file JSON
//   formloop kb remove  PATH UID
//   formloop kb stats   PATH                        counts per family and facet concept, GHSOM status
//   formloop kb check   PATH                        JSON report; exit 1 when the library is not clean, including
//                                                   whatever retrieval would trip on (bad concepts/descriptors,
//                                                   a stored model that does not load) and a part record a
//                                                   pooled run could not read
//   formloop kb rules   PATH [--set RULES.json]     print the active rule base, or write a new version
//
// Machine-readable output goes to stdout (JSON unless `list` without --json); logs go to stderr.

#include <iostream>
#include <memory>
#include <string>

#include <nlohmann/json.hpp>

#include "app/case_knowledge.h"
#include "app/command.h"
#include "app/kb_jobs.h"
#include "app/route_calibration.h"
#include "core/json_io.h"
#include "core/log.h"
#include "core/output_file.h"
#include "kb/library.h"
#include "kb/library_url.h"
#include "kb/schema.h"
#include "retrieval/retrieve.h"
#include "retrieval/starter.h"

namespace formloop::app {
namespace {

struct KbArgs {
  std::string path;
  std::string file;
  std::string uid;
  std::string out;
  std::string family;
  std::string rules;
  bool replace = false;
  bool force = false;
  bool json = false;
  bool starter = false;
  std::string data;
  double tau1 = -1, tau2 = -1;
  long long seed = -1;
  int breadth = 1;
  bool rerun = false;
  std::string work;
  int max_cases = 1000;
};

std::filesystem::path DataDir(const KbArgs& args) {
  return args.data.empty() ? retrieval::DefaultDataDir() : std::filesystem::path(args.data);
}

retrieval::GhsomOptions TrainOptions(const KbArgs& args) {
  retrieval::GhsomOptions o = retrieval::LibraryGhsomDefaults();
  if (args.tau1 > 0) o.tau1 = args.tau1;
  if (args.tau2 > 0) o.tau2 = args.tau2;
  if (args.seed >= 0) o.seed = static_cast<std::uint64_t>(args.seed);
  return o;
}

CLI::App* PathCommand(CLI::App* kb, const std::string& name, const std::string& help, KbArgs* args) {
  CLI::App* sub = kb->add_subcommand(name, help);
  sub->add_option("path", args->path,
                  "case library: a file (cases.db), sqlite:PATH or postgresql://user@host:port/db (password through "
                  "PGPASSWORD or ~/.pgpass)")
      ->required();
  return sub;
}

void Print(const nlohmann::json& j) { std::cout << j.dump(2) << std::endl; }

}  // namespace

void AddKbCommand(CLI::App& root, CommandAction* action) {
  CLI::App* kb = root.add_subcommand("kb", "Case-library maintenance (SQLite).");
  kb->require_subcommand(1);
  auto args = std::make_shared<KbArgs>();

  CLI::App* init = PathCommand(
      kb, "init",
      "Create the case library at PATH (SQLite: schema version in PRAGMA user_version, foreign keys on, WAL journal; "
      "PostgreSQL: the tables in an existing, empty database, version in formloop_schema_version), or migrate an "
      "existing library to the current schema. Prints a JSON report on stdout.",
      args.get());
  init->add_flag("--starter", args->starter,
                 "fill a new library with the synthetic starter cases (data/starter/families.json), write the starter "
                 "rule base (data/starter/rules.json) and train the GHSOM");
  init->add_option("--data", args->data,
                   "data folder with taxonomies/ and starter/ (default: the source tree's data/)");
  init->callback([args, action] {
    *action = [args]() -> Status {
      FL_ASSIGN_OR_RETURN(kb::InitReport report, kb::InitLibrary(args->path));
      log::Info("case library {} at schema version {} ({} migration(s) applied)", report.path,
                report.migration.to_version, report.migration.applied.size());
      nlohmann::json out = report.ToJson();
      if (args->starter) {
        FL_ASSIGN_OR_RETURN(out["starter"], FillStarterLibrary(args->path, DataDir(*args), TrainOptions(*args)));
        log::Info("starter library: {} cases, GHSOM trained", out["starter"]["cases"].get<long long>());
      }
      Print(out);
      return Status::Ok();
    };
  });

  CLI::App* train = PathCommand(
      kb, "train",
      "Standardise the case descriptors, train the GHSOM (spec §2) and store it with its scaling, parameters, quality "
      "figures (per-map QE/TE/MQE) and the change counter. JSON report on stdout.",
      args.get());
  train->add_option("--tau1", args->tau1, "breadth threshold (default: retrieval::LibraryGhsomDefaults)")
      ->check(CLI::Range(1e-9, 1.0));
  train->add_option("--tau2", args->tau2, "depth threshold (default: retrieval::LibraryGhsomDefaults)")
      ->check(CLI::Range(1e-9, 1.0));
  train->add_option("--seed", args->seed, "seed of the degenerate initial directions");
  train->callback([args, action] {
    *action = [args]() -> Status {
      FL_ASSIGN_OR_RETURN(auto library, kb::Library::Open(args->path));
      FL_ASSIGN_OR_RETURN(nlohmann::json report, retrieval::TrainLibraryGhsom(*library, TrainOptions(*args)));
      log::Info("GHSOM {} trained on {} case(s)", report["ghsom_id"].get<long long>(),
                report["cases"].get<long long>());
      Print(report);
      return Status::Ok();
    };
  });

  CLI::App* calibrate = PathCommand(
      kb, "calibrate",
      "Leave-one-out calibration of the routes (JSON): every case retrieved by a model trained without it (per route "
      "the share whose best case is of the same family); the outcomes `formloop run` retained per route; with "
      "--rerun, every retained part cut on the virtual machine run again through the pipeline on a library without "
      "it, per route how many end within tolerance on the first cycle and after one compensation loop.",
      args.get());
  calibrate->add_option("--breadth", args->breadth,
                        "candidate breadth (0 leaf, 1 + neighbours, 2 + the leaf's map ...)");
  calibrate
      ->add_option("--max-cases", args->max_cases,
                   "leave out at most this many cases, evenly spaced (0: all; each costs one GHSOM training)")
      ->capture_default_str()
      ->check(CLI::NonNegativeNumber);
  calibrate->add_flag("--rerun", args->rerun, "run the retained virtual-machine parts again (a pipeline run each)");
  calibrate->add_option("--work", args->work, "keep the reruns' run folders here (default: a temporary folder)");
  calibrate->add_option("--data", args->data,
                        "data folder with taxonomies/ and machines/ (default: the source tree's data/)");
  calibrate->callback([args, action] {
    *action = [args]() -> Status {
      CalibrationOptions options;
      options.breadth = args->breadth;
      options.rerun = args->rerun;
      options.max_cases = args->max_cases;
      options.work_dir = args->work;
      options.data_dir = DataDir(*args);
      FL_ASSIGN_OR_RETURN(nlohmann::json report, CalibrationReport(args->path, options));
      Print(report);
      return Status::Ok();
    };
  });

  CLI::App* migrate = PathCommand(
      kb, "migrate", "Migrate an existing case library to this formloop's schema (never downgrades).", args.get());
  migrate->callback([args, action] {
    *action = [args]() -> Status {
      FL_RETURN_IF_ERROR(kb::ProbeLibrary(args->path, /*allow_unversioned=*/false).status());
      FL_ASSIGN_OR_RETURN(kb::InitReport report, kb::InitLibrary(args->path));
      log::Info("case library {}: schema {} -> {}", report.path, report.migration.from_version,
                report.migration.to_version);
      Print(report.ToJson());
      return Status::Ok();
    };
  });

  CLI::App* add = PathCommand(kb, "add", "Add one case from a case file (JSON; format: docs/formats.md).", args.get());
  add->add_option("case", args->file, "case file, e.g. blade-017.json")->required();
  add->add_flag("--replace", args->replace, "overwrite a case with the same uid (keeps its created_at)");
  add->add_option("--data", args->data, "data folder whose taxonomies/ the concepts are checked against");
  add->callback([args, action] {
    *action = [args]() -> Status {
      FL_ASSIGN_OR_RETURN(kb::CaseRecord record, kb::ReadCaseFile(args->file));
      FL_ASSIGN_OR_RETURN(const retrieval::FacetTaxonomies tax,
                          retrieval::FacetTaxonomies::Load(DataDir(*args) / "taxonomies"));
      FL_RETURN_IF_ERROR(retrieval::CheckCaseForRetrieval(record, tax).WithContext(args->file + " (not added)"));
      FL_ASSIGN_OR_RETURN(auto library, kb::Library::Open(args->path));
      FL_ASSIGN_OR_RETURN(const nlohmann::json ghsom, retrieval::AddCaseAndGrowGhsom(*library, record, args->replace));
      log::Info("added case {} to {}", record.uid, kb::RedactPassword(args->path));
      Print({{"added", record.uid}, {"replace", args->replace}, {"ghsom", ghsom}});
      return Status::Ok();
    };
  });

  CLI::App* import_cmd =
      PathCommand(kb, "import", "Import a `kb export` file (JSON Lines) in one transaction.", args.get());
  import_cmd->add_option("file", args->file, "export file, e.g. cases.jsonl")->required();
  import_cmd->add_flag("--replace", args->replace, "replace cases whose uid exists instead of refusing the import");
  import_cmd->add_option("--data", args->data, "data folder whose taxonomies/ the concepts are checked against");
  import_cmd->callback([args, action] {
    *action = [args]() -> Status {
      FL_ASSIGN_OR_RETURN(auto library, kb::Library::Open(args->path));
      FL_ASSIGN_OR_RETURN(const retrieval::FacetTaxonomies tax,
                          retrieval::FacetTaxonomies::Load(DataDir(*args) / "taxonomies"));
      kb::ImportOptions options;
      options.replace = args->replace;
      options.check_case = [&tax](const kb::CaseRecord& r) { return retrieval::CheckCaseForRetrieval(r, tax); };
      FL_ASSIGN_OR_RETURN(kb::ImportReport report, library->ImportFile(args->file, options));
      log::Info("imported {} case(s) into {}", report.cases_added + report.cases_replaced,
                kb::RedactPassword(args->path));
      Print(report.ToJson());
      return Status::Ok();
    };
  });

  CLI::App* export_cmd = PathCommand(kb, "export", "Export the library as deterministic JSON Lines.", args.get());
  export_cmd->add_option("--out", args->out, "output file (written through a temporary file and renamed)")->required();
  AddForceFlag(export_cmd, &args->force);
  export_cmd->callback([args, action] {
    *action = [args]() -> Status {
      FL_RETURN_IF_ERROR(CheckOutputFiles(
          {{"--out", args->out}}, {{"PATH", args->path}, {"PATH", args->path + "-wal"}, {"PATH", args->path + "-shm"}},
          args->force));
      FL_ASSIGN_OR_RETURN(auto library, kb::Library::Open(args->path));
      FL_RETURN_IF_ERROR(library->ExportToFile(args->out));
      FL_ASSIGN_OR_RETURN(kb::LibraryStats stats, library->Stats());
      log::Info("exported {} case(s) to {}", stats.cases, args->out);
      Print({{"out", args->out}, {"cases", stats.cases}, {"format", kb::kExportFormatName}});
      return Status::Ok();
    };
  });

  CLI::App* list = PathCommand(kb, "list", "List the cases, sorted by uid.", args.get());
  list->add_option("--family", args->family, "only this surface family");
  list->add_flag("--json", args->json, "a JSON array instead of a table");
  list->callback([args, action] {
    *action = [args]() -> Status {
      FL_ASSIGN_OR_RETURN(auto library, kb::Library::Open(args->path));
      FL_ASSIGN_OR_RETURN(auto cases, library->ListCases(args->family));
      if (args->json) {
        nlohmann::json rows = nlohmann::json::array();
        for (const auto& c : cases) {
          rows.push_back({{"uid", c.uid},
                          {"name", c.name},
                          {"family", c.family},
                          {"created_at", c.created_at},
                          {"updated_at", c.updated_at},
                          {"descriptor_length", c.descriptor ? c.descriptor->size() : 0},
                          {"concepts", c.concepts}});
        }
        Print(rows);
      } else {
        for (const auto& c : cases) std::cout << c.uid << "\t" << c.family << "\t" << c.name << "\n";
        std::cout.flush();
      }
      return Status::Ok();
    };
  });

  CLI::App* show = PathCommand(kb, "show", "Print one case as its case-file JSON.", args.get());
  show->add_option("uid", args->uid, "the case's uid")->required();
  show->callback([args, action] {
    *action = [args]() -> Status {
      FL_ASSIGN_OR_RETURN(auto library, kb::Library::Open(args->path));
      FL_ASSIGN_OR_RETURN(kb::CaseRecord record, library->GetCase(args->uid));
      Print(record.ToJson());
      return Status::Ok();
    };
  });

  CLI::App* remove = PathCommand(kb, "remove", "Remove one case (its concepts go with it).", args.get());
  remove->add_option("uid", args->uid, "the case's uid")->required();
  remove->callback([args, action] {
    *action = [args]() -> Status {
      FL_ASSIGN_OR_RETURN(auto library, kb::Library::Open(args->path));
      FL_RETURN_IF_ERROR(library->RemoveCase(args->uid));
      log::Info("removed case {} from {}", args->uid, kb::RedactPassword(args->path));
      Print({{"removed", args->uid}});
      return Status::Ok();
    };
  });

  CLI::App* stats =
      PathCommand(kb, "stats", "Counts per family and per facet concept, rule version, GHSOM status.", args.get());
  stats->callback([args, action] {
    *action = [args]() -> Status {
      FL_ASSIGN_OR_RETURN(auto library, kb::Library::Open(args->path));
      FL_ASSIGN_OR_RETURN(kb::LibraryStats s, library->Stats());
      Print(s.ToJson());
      return Status::Ok();
    };
  });

  CLI::App* check = PathCommand(
      kb, "check",
      "Integrity, foreign keys, orphan concepts, descriptors, rule-base sanity, GHSOM staleness, part records a "
      "pooled run cannot read. JSON report; "
      "exit 1 when not clean.",
      args.get());
  check->add_option("--data", args->data, "data folder whose taxonomies/ the concepts are checked against");
  check->callback([args, action] {
    *action = [args]() -> Status {
      FL_ASSIGN_OR_RETURN(auto library, kb::Library::Open(args->path));
      FL_ASSIGN_OR_RETURN(kb::CheckReport report, library->Check());
      // What retrieval would trip on: the cases' concepts and descriptors, and the model as retrieve loads it.
      FL_ASSIGN_OR_RETURN(const retrieval::FacetTaxonomies tax,
                          retrieval::FacetTaxonomies::Load(DataDir(*args) / "taxonomies"));
      FL_ASSIGN_OR_RETURN(const std::vector<std::string> retrieval_problems,
                          retrieval::RetrievalProblems(*library, tax));
      for (const std::string& p : retrieval_problems) report.problems.push_back("retrieval: " + p);
      // What a pooled `formloop run` would trip on: the part records as it reads them.
      FL_ASSIGN_OR_RETURN(const std::vector<std::string> record_problems, PartRecordProblems(*library));
      for (const std::string& p : record_problems) report.problems.push_back("pooling: " + p);
      nlohmann::json out = report.ToJson();
      out["retrieval_problems"] = retrieval_problems;
      out["part_record_problems"] = record_problems;
      Print(out);
      if (!report.clean()) {
        return Status::Failed(
            "case library '" + kb::RedactPassword(args->path) + "' is not clean: " + report.problems.front() +
            (report.problems.size() > 1 ? " (and " + std::to_string(report.problems.size() - 1) + " more)" : ""));
      }
      for (const auto& w : report.warnings) log::Warn("{}", w);
      return Status::Ok();
    };
  });

  CLI::App* rules =
      PathCommand(kb, "rules", "Print the active rule base, or write a new version with --set.", args.get());
  rules->add_option("--set", args->rules, "rules file: {\"rules\": [{\"name\", \"condition\", \"choice\"}, ...]}");
  rules->callback([args, action] {
    *action = [args]() -> Status {
      FL_ASSIGN_OR_RETURN(auto library, kb::Library::Open(args->path));
      if (!args->rules.empty()) {
        FL_ASSIGN_OR_RETURN(Json input, ReadJsonFile(args->rules));
        FL_ASSIGN_OR_RETURN(int version, library->SetRules(input, args->rules));
        log::Info("rule base of {} is now version {}", kb::RedactPassword(args->path), version);
      }
      FL_ASSIGN_OR_RETURN(kb::RuleSet set, library->GetRules());
      Print(set.ToJson());
      return Status::Ok();
    };
  });
}

}  // namespace formloop::app
