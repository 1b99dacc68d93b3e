#include "app/route_calibration.h"

#include <algorithm>
#include <map>
#include <memory>

#include <unistd.h>

#include "app/part.h"
#include "app/pipeline.h"
#include "core/log.h"
#include "retrieval/retrieve.h"
#include "retrieval/starter.h"

namespace formloop::app {
namespace {

namespace fs = std::filesystem;
using nlohmann::json;

// Parts per route: within tolerance on the first cycle, after at most one compensation loop, and the
// first-cycle form errors.
class RouteTally {
 public:
  void Add(const std::string& route, bool first_cycle, bool within_one_loop, double first_error_um) {
    Tally& t = routes_[route];
    ++t.parts;
    t.first_cycle += first_cycle ? 1 : 0;
    t.within_one_loop += within_one_loop ? 1 : 0;
    t.first_error_um.push_back(first_error_um);
  }
  json ToJson() const {
    json out = json::object();
    for (auto [route, t] : routes_) {
      std::sort(t.first_error_um.begin(), t.first_error_um.end());
      out[route] = {{"parts", t.parts},
                    {"within_tolerance_first_cycle", t.first_cycle},
                    {"within_tolerance_after_at_most_one_loop", t.within_one_loop},
                    {"median_first_cycle_form_error_um",
                     t.first_error_um.empty() ? json(nullptr) : json(t.first_error_um[t.first_error_um.size() / 2])}};
    }
    return out;
  }

 private:
  struct Tally {
    int parts = 0, first_cycle = 0, within_one_loop = 0;
    std::vector<double> first_error_um;
  };
  std::map<std::string, Tally> routes_{{"direct", {}}, {"simulate", {}}, {"default", {}}};
};

// A temporary folder for the reruns, removed when the calibration ends (unless the user named one).
class WorkDir {
 public:
  explicit WorkDir(fs::path given) : path_(std::move(given)) {
    if (path_.empty()) {
      path_ = fs::temp_directory_path() / ("formloop-calibrate-" + std::to_string(::getpid()));
      owned_ = true;
    }
  }
  ~WorkDir() {
    std::error_code ec;
    if (owned_) fs::remove_all(path_, ec);
  }
  WorkDir(const WorkDir&) = delete;
  WorkDir& operator=(const WorkDir&) = delete;
  const fs::path& path() const { return path_; }

 private:
  fs::path path_;
  bool owned_ = false;
};

Result<json> Rerun(const std::string& kb_path, const std::vector<kb::CaseRecord>& cases,
                   const retrieval::GhsomOptions& ghsom, const std::vector<kb::Rule>& rules,
                   const retrieval::FacetTaxonomies& taxonomies, const CalibrationOptions& options) {
  const WorkDir work(options.work_dir);
  RouteTally tally;
  json rows = json::array();
  int failed = 0, runnable = 0;
  for (const kb::CaseRecord& c : cases) {
    if (c.part.contains("rerun") && c.descriptor) ++runnable;
  }
  int done = 0;
  for (const kb::CaseRecord& c : cases) {
    if (!c.part.contains("rerun") || !c.descriptor) continue;
    const json& rerun = c.part["rerun"];
    const std::string source = "case " + c.uid + " part.rerun";
    log::Info("[calibrate] {}/{}: part {} again, on a library without it", ++done, runnable, c.uid);
    json row = {{"uid", c.uid}, {"recorded", c.part.value("outcome", json(nullptr))}};
    auto part = rerun.contains("part") ? ParsePart(rerun["part"], source + ".part")
                                       : Result<PartSpec>(Status::BadInput(Where{.file = source}, "no part"));
    if (!part.ok()) {
      row["error"] = part.status().ToString();
      rows.push_back(std::move(row));
      ++failed;
      continue;
    }
    auto model = retrieval::RetrievalModel::Train(cases, ghsom, rules, taxonomies, c.uid);
    if (!model.ok()) {
      row["error"] = model.status().WithContext("retrieval model without the case").ToString();
      rows.push_back(std::move(row));
      ++failed;
      continue;
    }
    RunOptions ro;
    ro.out = work.path() / c.uid;
    ro.force = true;
    ro.part_source = source;
    ro.kb = kb_path;
    ro.machine = rerun.value("machine", "virtual");
    ro.retain = false;
    ro.report = false;
    ro.data_dir = options.data_dir;
    ro.retrieval_model = std::make_shared<const retrieval::RetrievalModel>(std::move(model).value());
    auto summary = RunPart(*part, ro);
    if (!summary.ok()) {
      row["error"] = summary.status().ToString();
      rows.push_back(std::move(row));
      ++failed;
      continue;
    }
    const bool first = summary->loops.front().within_tolerance;
    const int to_tolerance = summary->LoopsToTolerance();
    const double first_um = summary->loops.front().form_error_um;
    tally.Add(summary->route, first, to_tolerance >= 0 && to_tolerance <= 1, first_um);
    row["route"] = summary->route;
    row["similarity"] = summary->similarity;
    row["case"] = summary->case_uid;
    row["precompensated"] = summary->precompensated;
    row["tolerance_um"] = summary->tolerance_um;
    row["form_error_first_um"] = first_um;
    row["form_error_um"] = json::array();
    for (const LoopSummary& l : summary->loops) row["form_error_um"].push_back(l.form_error_um);
    row["loops_to_tolerance"] = to_tolerance >= 0 ? json(to_tolerance) : json(nullptr);
    rows.push_back(std::move(row));
  }
  return json{{"method",
               "leave-one-out by machining: every retained case cut on the virtual machine (part.rerun) is run "
               "again through formloop run, retrieved by a model trained without it, against the library as it "
               "is now; nothing retained"},
              {"parts", runnable},
              {"failed", failed},
              {"by_route", tally.ToJson()},
              {"per_part", rows}};
}

}  // namespace

json OutcomesByRoute(const std::vector<kb::CaseRecord>& cases) {
  RouteTally tally;
  int without = 0;
  for (const auto& c : cases) {
    const json outcome = c.part.value("outcome", json());
    if (!outcome.is_object() || !outcome.contains("route") || !outcome.contains("form_error_first_um")) {
      ++without;
      continue;
    }
    const int cycles = outcome.value("loops", 0);
    const bool within = outcome.value("within_tolerance", false);
    tally.Add(outcome["route"].get<std::string>(), within && cycles == 1, within && cycles <= 2,
              outcome["form_error_first_um"].get<double>());
  }
  return {{"by_route", tally.ToJson()},
          {"cases_without_pipeline_outcome", without},
          {"method",
           "outcomes recorded by formloop run's retain step (part.outcome): the route the run took and "
           "its form error per cycle"}};
}

Result<json> CalibrationReport(const std::string& kb_path, const CalibrationOptions& options_in) {
  CalibrationOptions options = options_in;
  if (options.data_dir.empty()) options.data_dir = retrieval::DefaultDataDir();
  FL_ASSIGN_OR_RETURN(retrieval::FacetTaxonomies taxonomies,
                      retrieval::FacetTaxonomies::Load(options.data_dir / "taxonomies"));
  FL_ASSIGN_OR_RETURN(auto library, kb::Library::Open(kb_path));
  FL_ASSIGN_OR_RETURN(std::vector<kb::CaseRecord> cases, library->ListCases());
  FL_ASSIGN_OR_RETURN(kb::RuleSet rules, library->GetRules());
  FL_ASSIGN_OR_RETURN(retrieval::GhsomOptions ghsom, retrieval::StoredGhsomOptions(*library));
  library.reset();  // the reruns open it themselves
  retrieval::RetrieveOptions ro;
  ro.breadth = options.breadth;
  FL_ASSIGN_OR_RETURN(json report, retrieval::RetrievalModel::LeaveOneOut(cases, ghsom, rules.rules, taxonomies, ro,
                                                                          options.max_cases));
  json out = {{"library", kb_path}, {"retrieval", std::move(report)}, {"outcomes", OutcomesByRoute(cases)}};
  if (options.rerun) {
    FL_ASSIGN_OR_RETURN(out["rerun"], Rerun(kb_path, cases, ghsom, rules.rules, taxonomies, options));
  }
  return out;
}

}  // namespace formloop::app
