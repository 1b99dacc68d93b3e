#include "app/pipeline.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <filesystem>
#include <memory>
#include <optional>

#include "app/case_knowledge.h"
#include "app/machine_profile.h"
#include "app/pipeline_stages.h"
#include "app/report.h"
#include "app/run_folder.h"
#include "core/log.h"
#include "kb/schema.h"
#include "metrology/probe.h"
#include "retrieval/features.h"
#include "retrieval/starter.h"

namespace formloop::app {
namespace fs = std::filesystem;
using nlohmann::json;
namespace {

// Everything the run produces, staged in the .partial folder, one stage after another.
Status RunStages(const PartSpec& given_part, const RunOptions& options, RunFolderWriter& folder, RunSummary* summary,
                 std::optional<stages::Retained>* retained) {
  const fs::path data_dir = options.data_dir.empty() ? retrieval::DefaultDataDir() : options.data_dir;
  summary->part = given_part.name;
  summary->surface = given_part.SurfaceName();
  summary->tolerance_um = given_part.tolerance_mm * 1e3;

  FL_RETURN_IF_ERROR(folder.Begin("1/9: inputs"));
  FL_ASSIGN_OR_RETURN(const stages::Inputs in, stages::ResolveInputs(given_part, options, data_dir, folder));
  const PartSpec& part = in.part;

  FL_RETURN_IF_ERROR(folder.Begin("2/9: surface"));
  log::Info("[surface] '{}': B-spline fit", part.SurfaceName());
  FL_ASSIGN_OR_RETURN(const stages::Surface surface, stages::BuildSurface(part, in.fit_seed, folder));
  const recon::BSplineSurface& q = surface.q;
  summary->fit_check_max_um = surface.fit_check_max_mm * 1e3;
  log::Info("      fit rms {:.4f} um at samples; check max {:.4f} um at {} random points", surface.report.rms_mm * 1e3,
            surface.report.check_max_mm * 1e3, surface.report.n_check);

  FL_RETURN_IF_ERROR(folder.Begin("3/9: retrieval"));
  FL_ASSIGN_OR_RETURN(const stages::Retrieved retrieved, stages::Retrieve(part, q, options, data_dir, folder));
  summary->route = retrieved.route;
  summary->similarity = retrieved.similarity;
  summary->flag_engineer = retrieved.route == "default";
  if (retrieved.best) summary->case_uid = retrieved.best->uid;
  log::Info("[retrieval] route {} (A = {:.4f}{})", retrieved.route, retrieved.similarity,
            retrieved.best ? ", case " + retrieved.best->uid : std::string());

  FL_RETURN_IF_ERROR(folder.Begin("4/9: plan"));
  FL_ASSIGN_OR_RETURN(planning::PlanChoice choice, stages::ChoosePlan(in, retrieved, q, options.learn, folder));
  summary->plan_source = choice.source;
  summary->flag_engineer = summary->flag_engineer || choice.flag_engineer;
  FL_ASSIGN_OR_RETURN(const stages::Experiment experiment,
                      stages::FindSeparatingExperiment(part, options, summary->case_uid, choice.plan));
  if (!experiment.proposals.empty()) {
    // The next part cut as the proposals say: the raster turned, the feed scaled.
    const sim::PathChange change = sim::PathChangeOf(experiment.proposals);
    choice.plan.raster_angle_deg = std::fmod(choice.plan.raster_angle_deg + change.raster_turn_deg + 360.0, 360.0);
    choice.plan.feed_mm_per_min *= change.feed_scale;
  }
  const nc::ToolpathOptions& plan = choice.plan;
  log::Info("[plan] {}: ball r = {} mm, scallop {} um, feed {} mm/min", choice.source, plan.tool.radius_mm,
            plan.scallop_um, plan.feed_mm_per_min);

  FL_RETURN_IF_ERROR(folder.Begin("5/9: nc"));
  FL_ASSIGN_OR_RETURN(const stages::Programs programs,
                      stages::WritePrograms(part, q, plan, std::move(choice.path), experiment, folder));
  summary->probe_points_planned = programs.probing_plan.points.size() + programs.unreachable.size();
  for (const nc::UnreachableProbePoint& u : programs.unreachable) summary->probe_points_left_out.push_back(u.id);
  const nc::Toolpath& nominal = programs.nominal;
  summary->gouge_risk_points = nominal.gouge_risk_points;
  summary->lifted_points = nominal.lifted_points;
  summary->uncut_min = nominal.lifted_box_min;
  summary->uncut_max = nominal.lifted_box_max;
  summary->max_lift_mm = nominal.max_lift_mm;
  if (nominal.lifted_points > 0) log::Warn("[nc] {} (toolpath/toolpath.json)", nominal.UncutRegionText());

  FL_RETURN_IF_ERROR(folder.Begin("6/9: precompensation"));
  FL_ASSIGN_OR_RETURN(stages::FirstCut cut,
                      stages::Precompensate(part, q, choice, programs, summary->case_uid, in.plan_seed, folder));
  summary->precompensated = cut.precompensation_scale > 0;
  summary->precompensation_scale = cut.precompensation_scale;

  // Cycles: machine (or take the measured log), analyse, diagnose (cycle 0), compensate.
  const int max_loops = in.machine.virtual_machine     ? part.max_loops
                        : !in.machine.linuxcnc.empty() ? 1  // its part does not change (stages::Machine)
                                                       : static_cast<int>(in.machine.measured.size());
  std::optional<sim::Diagnosis> diagnosis;
  std::vector<sim::PlannedProposal> proposals;  // for the next part (the part asks for a separating experiment)
  stages::FirstCyclePooling pooling;            // the earlier cases pooled; this part's record
  PooledCases earlier;
  stages::CompensatedField& field = cut.field;
  // The program each cycle cuts: the pre-compensated or the nominal one, then the compensated one (no copies).
  stages::Program compensated;
  const stages::Program* current = cut.program ? &*cut.program : &programs.program;
  for (int loop = 0; loop < max_loops; ++loop) {
    const std::string cycle = "7/9: loop " + std::to_string(loop);
    FL_RETURN_IF_ERROR(folder.Begin(cycle + " machine"));
    FL_ASSIGN_OR_RETURN(
        stages::Machined machined,
        stages::MachineCycle(in, *current, plan.tool.radius_mm, programs.probing_plan, programs.probe_approaches,
                             programs.part_surface, programs.unreachable, loop, folder));

    FL_RETURN_IF_ERROR(folder.Begin(cycle + " analysis"));
    const bool another = loop + 1 < max_loops || !in.machine.virtual_machine;
    auto analysed_or = stages::AnalyseCycle(part, q, programs.probing_plan, machined.log, loop, another,
                                            in.analysis_seed + static_cast<std::uint64_t>(loop), folder);
    if (!analysed_or.ok() && !in.machine.virtual_machine) {
      // A measured log is the user's file: name it, not only its copy in the run folder.
      return analysed_or.status().WithContext("the probe log of --measured " +
                                              options.measured[static_cast<std::size_t>(loop)]);
    }
    FL_ASSIGN_OR_RETURN(stages::Analysed analysed, std::move(analysed_or));
    if (loop == 0) {
      FL_RETURN_IF_ERROR(folder.Begin("7/9: loop 0 diagnosis"));
      std::unique_ptr<kb::Library> library;
      if (!options.kb.empty()) {
        FL_ASSIGN_OR_RETURN(library, kb::Library::Open(options.kb));
      }
      FL_ASSIGN_OR_RETURN(const sim::PlausibleRanges plausible, PlausibleRangesFor(library.get(), data_dir));
      if (library && options.pool_cases > 0) {
        FL_ASSIGN_OR_RETURN(
            earlier, FindPooledCases(*library, part.machine_name, planning::ToolKey(plan.tool.radius_mm), part.material,
                                     part.name, options.pool_cases));
        pooling.earlier = &earlier;
        // The library's records this diagnosis used are inputs of the run: the same part, options and
        // records give the same bytes.
        FL_RETURN_IF_ERROR(folder.WriteJson(fs::path("inputs") / "pooled_cases.json",
                                            {{"library", options.kb},
                                             {"key",
                                              {{"machine", part.machine_name},
                                               {"tool", planning::ToolKey(plan.tool.radius_mm)},
                                               {"material", part.material}}},
                                             {"limit", options.pool_cases},
                                             {"cases", earlier.inputs}}));
      }
      FL_ASSIGN_OR_RETURN(sim::Diagnosis d,
                          stages::DiagnoseFirstCycle(part, q, machined, analysed.flagged_ids, plan.tool.radius_mm,
                                                     programs.probing_plan, choice, summary->case_uid, plausible,
                                                     folder, experiment.asked ? &proposals : nullptr, &pooling));
      summary->pooled_cases = earlier.uids;
      for (const auto& c : d.causes) summary->causes.push_back(c.effect);
      diagnosis = std::move(d);
    }
    machined.cutter_locations = {};  // a million locations, not needed by the compensation
    if (analysed.systematic) {
      FL_RETURN_IF_ERROR(folder.Begin(cycle + " compensation"));
      field.terms.push_back([fm = *analysed.systematic](double u, double v) { return fm.Evaluate(u, v); });
      FL_ASSIGN_OR_RETURN(compensated, stages::CompensateCycle(part, programs, field, loop, folder));
      current = &compensated;
      analysed.summary.compensated = true;
    }
    summary->loops.push_back(analysed.summary);
    if (!analysed.summary.compensated) break;  // measured logs: the next log (if given) measures the compensated cut
  }
  summary->within_tolerance = summary->loops.back().within_tolerance;

  FL_RETURN_IF_ERROR(folder.Begin("8/9: retain"));
  FL_ASSIGN_OR_RETURN(*retained, stages::PrepareRetain(part, options, retrieved, plan, diagnosis, summary, folder,
                                                       proposals, pooling.record ? &*pooling.record : nullptr));

  FL_RETURN_IF_ERROR(folder.Begin("9/9: report"));
  json summary_json = summary->ToJson();
  summary_json["part_file"] = options.part_source;
  FL_RETURN_IF_ERROR(folder.WriteJson("summary.json", summary_json));
  if (options.report) FL_RETURN_IF_ERROR(WriteRunReport(folder.dir(), folder.Path("report.html")));
  folder.EndStage();
  return Status::Ok();
}

}  // namespace

int RunSummary::LoopsToTolerance() const {
  for (const auto& l : loops) {
    if (l.within_tolerance) return l.index;
  }
  return -1;
}

json RunSummary::ToJson() const {
  json loops_json = json::array();
  for (const auto& l : loops) loops_json.push_back(stages::LoopJson(l));
  const int to_tolerance = LoopsToTolerance();
  return {{"formloop_version", stages::kVersion},
          {"part", part},
          {"surface", surface},
          {"tolerance_um", tolerance_um},
          {"fit_check_max_um", std::isfinite(fit_check_max_um) ? json(fit_check_max_um) : json(nullptr)},
          {"route",
           {{"name", route},
            {"similarity", similarity >= 0 ? json(similarity) : json(nullptr)},
            {"case_uid", case_uid.empty() ? json(nullptr) : json(case_uid)},
            {"flag_engineer", flag_engineer}}},
          {"plan_source", plan_source},
          {"precompensated", precompensated},
          {"precompensation_scale", precompensation_scale},
          {"causes", causes},
          {"pooled_cases", pooled_cases},
          {"probing", {{"planned", probe_points_planned}, {"left_out", probe_points_left_out}}},
          {"toolpath",
           {{"gouge_risk_points", gouge_risk_points},
            {"lifted_points", lifted_points},
            {"max_lift_mm", max_lift_mm},
            {"uncut_box_mm", lifted_points > 0 ? json{{uncut_min.x(), uncut_min.y(), uncut_min.z()},
                                                      {uncut_max.x(), uncut_max.y(), uncut_max.z()}}
                                               : json(nullptr)}}},
          {"loops", loops_json},
          {"within_tolerance", within_tolerance},
          {"loops_to_tolerance", to_tolerance >= 0 ? json(to_tolerance) : json(nullptr)},
          {"retained", retained}};
}

std::vector<NamedPath> RunInputs(const RunOptions& options) {
  std::vector<NamedPath> inputs = {{"PART", options.part_source}, {"--kb", options.kb}};
  if (!options.kb.empty()) {
    for (const char* suffix : {"-wal", "-shm"}) inputs.push_back({"--kb", options.kb + suffix});
  }
  for (const std::string& log : options.measured) inputs.push_back({"--measured", log});
  const std::string profile = options.machine.rfind("virtual:", 0) == 0 ? options.machine.substr(8) : "";
  if (profile.find('/') != std::string::npos || profile.find(".json") != std::string::npos) {
    inputs.push_back({"--machine", profile});
  }
  return inputs;
}

// What can be checked of the inputs before the run folder exists, so that a wrong option, a missing
// profile or library or an unreadable log is refused with nothing written.
Status CheckRunInputs(const PartSpec& part, const RunOptions& options) {
  const fs::path data_dir = options.data_dir.empty() ? retrieval::DefaultDataDir() : options.data_dir;
  if (!options.measured.empty()) {
    if (!options.machine.empty()) {
      return Status::BadInput(Where{.field = "--machine"}, "cannot be combined with --measured",
                              "give either a virtual machine or measured probe logs");
    }
    for (const std::string& log : options.measured) FL_RETURN_IF_ERROR(metrology::ReadProbeLog(log).status());
  } else {
    const std::string spec = options.machine.empty() ? "virtual" : options.machine;
    const bool linuxcnc = spec.rfind("linuxcnc:", 0) == 0;  // its configuration is checked by the machine stage
    if (spec != "virtual" && spec.rfind("virtual:", 0) != 0 && !linuxcnc) {
      return Status::BadInput(Where{.field = "--machine"}, "unknown machine '" + spec + "'",
                              "use virtual, virtual:PROFILE, linuxcnc:CONFIG or --measured LOG.csv");
    }
    if (!linuxcnc && (spec != "virtual" || !part.effects)) {
      const std::string profile = spec == "virtual" ? part.machine_name : spec.substr(8);
      const Status read = ReadMachineProfile(profile, data_dir).status();
      // (A machine.name that is a path to a .json file and missing gets ReadMachineProfile's "not found".)
      const bool a_name = std::filesystem::path(profile).extension() != ".json";
      if (spec == "virtual" && a_name && read.code() == StatusCode::kBadInput &&
          !std::filesystem::exists(data_dir / "machines" / (profile + ".json"))) {
        // The part names no effects and its machine has no profile: say which field and what to give.
        std::string names;
        std::error_code ec;
        std::vector<std::string> found;
        for (const auto& entry : std::filesystem::directory_iterator(data_dir / "machines", ec)) {
          if (entry.path().extension() == ".json") found.push_back(entry.path().stem().string());
        }
        std::sort(found.begin(), found.end());
        for (const auto& n : found) names += (names.empty() ? "" : ", ") + n;
        return Status::BadInput(
            Where{.file = options.part_source, .field = "machine.name"},
            "the virtual machine takes its effects from machine.effects or from the machine profile machine.name "
            "names; the part gives no effects and there is no profile '" +
                profile + "' in " + (data_dir / "machines").string(),
            "set machine.name to a profile (" + names +
                "), give machine.effects (docs/formats.md; an empty list is an ideal machine), or run with "
                "--measured LOG.csv");
      }
      FL_RETURN_IF_ERROR(read);
    }
  }
  if (!options.kb.empty()) {
    FL_RETURN_IF_ERROR(kb::ProbeLibrary(options.kb, /*allow_unversioned=*/false).status());
    // The retrieval description's concepts and bands, before the run folder exists (a shape_family typo
    // used to fail after the surface fit, leaving DIR.failed).
    FL_ASSIGN_OR_RETURN(const retrieval::FacetTaxonomies taxonomies,
                        retrieval::FacetTaxonomies::Load(data_dir / "taxonomies"));
    const auto classified = retrieval::ClassifyPart(DescriptionOf(part, part.toolpath), taxonomies);
    if (!classified.ok()) {
      return Status(classified.status().code(),
                    options.part_source + ": " + classified.status().message() +
                        " (the part's retrieval description: material, shape_family, finish_ra_um, machine.class)");
    }
  }
  // The size of the job: a scallop typed in the wrong unit is refused here.
  return CheckPartWork(part, part.toolpath, options.part_source);
}

Result<RunSummary> RunPart(const PartSpec& part, const RunOptions& options) {
  FL_RETURN_IF_ERROR(CheckRunInputs(part, options));
  RunFolderWriter folder(options.out, options.on_stage);
  FL_RETURN_IF_ERROR(folder.Open(options.force, part.name, RunInputs(options)));
  log::Info("formloop {} run of part '{}' into {}", stages::kVersion, part.name, options.out.string());

  RunSummary summary;
  summary.out = options.out;
  std::optional<stages::Retained> retained;
  // Whatever goes wrong inside (std::bad_alloc included) ends as DIR.failed with the error, never as a
  // DIR.partial that looks like a killed run.
  Status status;
  try {
    status = RunStages(part, options, folder, &summary, &retained);
    // The library changes last, in one transaction, after every file of the run is written.
    if (status.ok() && retained) {
      const auto start = std::chrono::steady_clock::now();
      status = stages::CommitRetained(options.kb, *retained);
      if (options.on_stage) {
        options.on_stage("retain commit",
                         std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count());
      }
    }
  } catch (const std::bad_alloc&) {
    status = Status::Failed(
        "out of memory during the run; the part asks for more work than this computer can hold. "
        "Fix: check the part's sizes (toolpath.scallop_um, toolpath.chord_tolerance_um, "
        "probing.grid)");
  } catch (const std::exception& e) {
    status = Status::Internal(std::string("unexpected exception: ") + e.what());
  }
  if (status.ok()) status = folder.MarkComplete();
  if (status.ok()) {
    log::Info("run complete: {} after {} cycle(s)",
              summary.within_tolerance ? "within tolerance" : "NOT within tolerance", summary.loops.size());
  } else {
    log::Error("run failed: {}", status.ToString());
  }
  FL_RETURN_IF_ERROR(folder.Close(status, "run of part '" + part.name + "'"));
  return summary;
}

}  // namespace formloop::app
