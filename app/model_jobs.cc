#include "app/model_jobs.h"

#include <algorithm>
#include <cmath>
#include <deque>
#include <filesystem>
#include <optional>

#include <fmt/format.h>
#include <fmt/ranges.h>

#include "app/case_knowledge.h"
#include "app/run_folder.h"
#include "core/atomic_file.h"
#include "core/json_io.h"
#include "core/log.h"
#include "core/output_file.h"
#include "core/point_io.h"
#include "kb/library.h"
#include "nc-gen/cutter_locations.h"
#include "planning/case_plan.h"
#include "retrieval/starter.h"
#include "simulation/diagnose.h"
#include "simulation/experiment_design.h"
#include "simulation/proposal_plan.h"
#include "simulation/virtual_machine.h"

namespace formloop::app {
namespace fs = std::filesystem;
namespace {

Status CopyInto(const std::string& from, const fs::path& to) {
  FL_ASSIGN_OR_RETURN(const std::string content, ReadFile(from));
  return WriteFileAtomic(to, content, true);
}

Result<PlanWithApproaches> PlanFor(const RunFolder& run, const std::string& plan_path) {
  if (plan_path.empty()) return PlanWithApproaches{run.plan, run.approaches};
  return ReadPlanFile(plan_path);
}

// What diagnose needs of a part: its Q, tool path, tool, plan, measured log and assumed probe.
sim::ProbeDataInput ProbeInputOf(const RunFolder& run, const PlanWithApproaches& plan, const metrology::ProbeLog& log) {
  sim::ProbeDataInput in;
  in.surface = &run.q;
  in.cutter_locations = &run.cutter_locations;
  in.tool_radius_mm = run.part.toolpath.tool.radius_mm;
  in.plan = &plan.plan;
  in.measured = &log;
  in.probe = run.part.probe;
  return in;
}

// The case's simulation knowledge keeps one learned model per machine/tool/material
// (simulation.effect_models): the extended model in formloop's format, each parameter as an
// {name, estimate, standard_error} row the library validates, and where it came from.
Status StoreLearnedModel(const DiagnoseArgs& args, const RunFolder& run, const sim::Diagnosis& diagnosis) {
  FL_ASSIGN_OR_RETURN(auto library, kb::Library::Open(args.library));
  FL_ASSIGN_OR_RETURN(kb::CaseRecord record, library->GetCase(args.case_uid));
  const std::string tool = planning::ToolKey(run.part.toolpath.tool.radius_mm);
  const nlohmann::json entry = LearnedModelEntry(diagnosis.extended, args.machine, tool, run.part.material,
                                                 {{"measured", args.measured},
                                                  {"run", args.run},
                                                  {"more_measured", args.more_measured},
                                                  {"more_runs", args.more_runs},
                                                  {"baseline", args.baseline},
                                                  {"points", diagnosis.n},
                                                  {"heldout_rms_before_um", diagnosis.heldout_rms_before_um},
                                                  {"heldout_rms_after_um", diagnosis.heldout_rms_after_um}});
  nlohmann::json& models = record.simulation["effect_models"];
  if (!models.is_array()) models = nlohmann::json::array();
  bool replaced = false;
  for (auto& m : models) {
    if (m.value("machine", "") == args.machine && m.value("tool", "") == tool &&
        m.value("material", "") == run.part.material) {
      m = entry;
      replaced = true;
    }
  }
  if (!replaced) models.push_back(entry);
  FL_RETURN_IF_ERROR(library->AddCase(record, /*replace=*/true));
  log::Info("learned model stored in case {} of {} ({} / {} / {}{})", args.case_uid, args.library, args.machine, tool,
            run.part.material, replaced ? ", replacing the previous one" : "");
  return Status::Ok();
}

}  // namespace

Status RunSimulate(const SimulateArgs& args) {
  if (args.run.empty()) return Status::BadInput(Where{.field = "--run"}, "is required", "give a `formloop run` folder");
  if (args.model.empty()) return Status::BadInput(Where{.field = "--model"}, "is required", "give a MODEL.json");
  if (args.out.empty()) return Status::BadInput(Where{.field = "--out"}, "is required", "give the probe log to write");
  std::vector<NamedPath> inputs = RunFolderInputs("--run", args.run);
  inputs.push_back({"--model", args.model});
  inputs.push_back({"--probe-plan", args.probe_plan});
  FL_RETURN_IF_ERROR(CheckOutputFiles({{"--out", args.out}, {"--truth", args.truth}}, inputs, args.force));
  FL_ASSIGN_OR_RETURN(const RunFolder run, ReadRunFolder(args.run));
  FL_ASSIGN_OR_RETURN(const sim::Model model, sim::ReadModel(args.model));
  FL_ASSIGN_OR_RETURN(const PlanWithApproaches plan, PlanFor(run, args.probe_plan));
  sim::VirtualMachineOptions vm;
  vm.tool_radius_mm = run.part.toolpath.tool.radius_mm;
  vm.model = model;
  vm.true_probe = run.part.true_probe;
  vm.approaches = plan.approaches;
  vm.seed = args.seed;
  FL_ASSIGN_OR_RETURN(const sim::VirtualMachineResult result,
                      sim::MachineAndProbe(run.cutter_locations, plan.plan, vm));
  // Truth first into a temporary name, then the log: a failure leaves neither.
  if (!args.truth.empty()) {
    nlohmann::json truth = result.ReportJson();
    nlohmann::json points = nlohmann::json::array();
    for (std::size_t i = 0; i < result.truth.size(); ++i) {
      nlohmann::json effects = nlohmann::json::object();
      for (std::size_t k = 0; k < result.model.effects.size(); ++k) {
        effects[std::string(result.model.effects[k].effect->name())] = result.truth[i].effect_um[k];
      }
      points.push_back({{"id", result.truth[i].id},
                        {"scallop_um", result.truth[i].scallop_um},
                        {"effects_um", effects},
                        {"roughness_um", result.truth[i].roughness_um},
                        {"probe_noise_um", result.truth[i].probe_noise_um}});
    }
    truth["points"] = points;
    truth["seed"] = args.seed;
    truth["generator"] = kGeneratorName;
    FL_RETURN_IF_ERROR(WriteJsonFile(args.truth, truth));
  }
  const Status written = metrology::WriteProbeLog(args.out, result.log);
  if (!written.ok() && !args.truth.empty()) {
    std::error_code ec;
    fs::remove(args.truth, ec);
  }
  FL_RETURN_IF_ERROR(written);
  log::Info("simulate: {} probe points on {} cutter locations with {} effect(s); log {}", result.log.records.size(),
            run.cutter_locations.size(), result.model.effects.size(), args.out);
  return Status::Ok();
}

Result<nlohmann::json> RunDiagnose(const DiagnoseArgs& args) {
  if (args.out.empty())
    return Status::BadInput(Where{.field = "--out"}, "is required", "give a folder for the diagnosis");
  if (args.measured.empty() == args.features.empty()) {
    return Status::BadInput(Where{.field = "--measured/--features"}, "give exactly one of them");
  }
  if (!args.library.empty() && (args.case_uid.empty() || args.run.empty() || args.measured.empty())) {
    return Status::BadInput(Where{.field = "--library"}, "needs --case, --run and --measured",
                            "give the case the part belongs to and the run that made it");
  }
  if (!args.validate.empty() && args.validate_run.empty()) {
    return Status::BadInput(Where{.field = "--validate-run"}, "is required with --validate",
                            "give the run folder of the second part");
  }
  // The output folder is checked (and its staging folder started) before any work: it is built whole in
  // DIR.partial and renamed into place at the end, replacing only a folder formloop wrote.
  const fs::path dir(args.out);
  std::vector<NamedPath> input_paths = {
      {"--measured", args.measured}, {"--features", args.features},           {"--run", args.run},
      {"--plan", args.plan},         {"--probe-profile", args.probe_profile}, {"--baseline", args.baseline},
      {"--validate", args.validate}, {"--validate-run", args.validate_run},   {"--validate-plan", args.validate_plan},
      {"--library", args.library}};
  input_paths.push_back({"--direct", args.direct});
  for (const auto& m : args.more_measured) input_paths.push_back({"--measured", m});
  for (const auto& r : args.more_runs) input_paths.push_back({"--run", r});
  StagedOutputFolder folder;
  FL_RETURN_IF_ERROR(folder.Open(dir, "--out", "diagnose", input_paths));
  const fs::path& staging = folder.dir();
  sim::Model baseline;
  if (!args.baseline.empty()) {
    FL_ASSIGN_OR_RETURN(baseline, sim::ReadModel(args.baseline));
  }
  if (args.more_measured.size() != args.more_runs.size() || (!args.more_measured.empty() && args.run.empty())) {
    return Status::BadInput(Where{.field = "--measured/--run"}, "give them in pairs, one run folder per log",
                            "--measured A.csv --run RUN_A --measured B.csv --run RUN_B ...");
  }
  sim::DiagnoseOptions options;
  options.candidates = args.effects;
  if (!args.direct.empty()) {
    FL_ASSIGN_OR_RETURN(options.direct, sim::ReadDirectMeasurements(args.direct));
  }
  {
    std::unique_ptr<kb::Library> library;
    if (!args.library.empty()) {
      FL_ASSIGN_OR_RETURN(library, kb::Library::Open(args.library));
    }
    const fs::path data_dir = args.data_dir.empty() ? retrieval::DefaultDataDir() : fs::path(args.data_dir);
    FL_ASSIGN_OR_RETURN(options.plausible, PlausibleRangesFor(library.get(), data_dir));
  }
  FL_RETURN_IF_ERROR(options.Validate());
  sim::Diagnosis diagnosis;
  nlohmann::json proposals = nlohmann::json::array();
  nlohmann::json second_part = nullptr;
  PointSet residuals;
  std::optional<RunFolder> stored_run;  // kept when the model goes into the case library
  if (!args.features.empty()) {
    FL_ASSIGN_OR_RETURN(const auto features, sim::ReadFeatures(args.features));
    FL_ASSIGN_OR_RETURN(diagnosis, sim::DiagnoseFeatures(features, baseline, options));
  } else if (args.run.empty()) {
    // Plan and log alone: no Q, no tool path.
    if (args.plan.empty()) {
      return Status::BadInput(Where{.field = "--run/--plan"}, "give the run folder, or at least the probing plan",
                              "--run RUN_DIR screens every effect; --plan PLAN.json --probe-profile P.json screens "
                              "those that do not need the tool path");
    }
    if (args.probe_profile.empty()) {
      return Status::BadInput(Where{.field = "--probe-profile"}, "is required with --plan and no --run",
                              "give the probe profile the log was measured with (`formloop calibrate sphere`)");
    }
    FL_ASSIGN_OR_RETURN(const PlanWithApproaches plan, ReadPlanFile(args.plan));
    FL_ASSIGN_OR_RETURN(const metrology::ProbeLog log, metrology::ReadProbeLog(args.measured));
    FL_ASSIGN_OR_RETURN(const metrology::ProbeModel probe, metrology::ReadProbeProfile(args.probe_profile));
    FL_ASSIGN_OR_RETURN(diagnosis, sim::DiagnosePlanOnly(plan.plan, log, probe, baseline, options));
  } else {
    // One part, or several of the same machine/tool/material (the first with --plan when given).
    std::vector<std::string> measured = {args.measured}, runs = {args.run};
    measured.insert(measured.end(), args.more_measured.begin(), args.more_measured.end());
    runs.insert(runs.end(), args.more_runs.begin(), args.more_runs.end());
    std::deque<RunFolder> folders;
    std::deque<PlanWithApproaches> plans;
    std::deque<metrology::ProbeLog> logs;
    std::vector<sim::ProbeDataInput> inputs;
    std::vector<sim::ProbeResidualData> data;
    std::vector<std::string> labels;
    for (std::size_t p = 0; p < measured.size(); ++p) {
      FL_ASSIGN_OR_RETURN(folders.emplace_back(), ReadRunFolder(runs[p]));
      FL_ASSIGN_OR_RETURN(plans.emplace_back(), PlanFor(folders.back(), p == 0 ? args.plan : std::string()));
      FL_ASSIGN_OR_RETURN(logs.emplace_back(), metrology::ReadProbeLog(measured[p]));
      inputs.push_back(ProbeInputOf(folders.back(), plans.back(), logs.back()));
      FL_ASSIGN_OR_RETURN(data.emplace_back(), sim::ProbeResiduals(inputs.back(), baseline));
      std::string label = fs::path(runs[p]).lexically_normal().filename().string();
      if (label.empty()) label = fs::path(runs[p]).lexically_normal().parent_path().filename().string();
      if (label.empty() || std::find(labels.begin(), labels.end(), label) != labels.end())
        label = std::to_string(p + 1);
      labels.push_back(label);
    }
    if (data.size() == 1) {
      FL_ASSIGN_OR_RETURN(diagnosis, sim::DiagnoseResiduals(data[0].contexts, data[0].residual_um, baseline, options,
                                                            &data[0].sensitivity));
    } else {
      FL_ASSIGN_OR_RETURN(diagnosis, sim::DiagnosePooledResiduals(data, baseline, options, labels));
    }
    if (!args.library.empty()) stored_run = folders.front();
    std::vector<double> part_index;
    for (std::size_t p = 0; p < data.size(); ++p) {
      for (std::size_t i = 0; i < data[p].contexts.size(); ++i) {
        residuals.points.push_back(data[p].contexts[i].point);
        residuals.normals.push_back(data[p].contexts[i].normal);
        residuals.ids.push_back(data[p].contexts[i].id);
        part_index.push_back(static_cast<double>(p + 1));
      }
    }
    residuals.SetScalar("residual_um", diagnosis.residual_um);
    residuals.SetScalar("residual_after_um", diagnosis.residual_after_um);
    if (data.size() > 1) residuals.SetScalar("part", part_index);
    if (args.propose && !diagnosis.alias_groups.empty()) {
      // The experiment that would separate each alias group, the next part re-planned by nc-gen.
      sim::ExperimentOptions eo;
      eo.plausible = options.plausible;
      const RunFolder& first = folders.front();
      eo.replan = [&first](double turn_deg, double feed_scale) -> Result<std::vector<sim::CutterLocation>> {
        std::string skipped;
        auto cls = nc::ReplannedCutterLocations(first.q, first.toolpath.options, turn_deg, feed_scale, &skipped);
        if (!skipped.empty()) log::Warn("proposals: {}; that change is not proposed", skipped);
        return cls;
      };
      FL_ASSIGN_OR_RETURN(const auto found, sim::ProposeExperiments(inputs, diagnosis, baseline, eo));
      for (const auto& p : found) {
        nlohmann::json pj = p.ToJson();
        // The same change for the next part of another shape (`formloop run`'s separating_experiment).
        pj["next_part"] = sim::PlannedProposal::Of(p, first.q.domain()).ToJson();
        proposals.push_back(pj);
        log::Info("proposal for {}: {} (cost {:.0f} s; design correlation {:.4f} -> {:.4f}{})",
                  fmt::format("{}", fmt::join(p.members, ", ")), p.change, p.cost_s, p.correlation_before,
                  p.correlation_after, p.predicted_to_split ? "" : "; not predicted to split it on its own");
      }
    }
    if (!args.validate.empty()) {
      FL_ASSIGN_OR_RETURN(const RunFolder run2, ReadRunFolder(args.validate_run));
      FL_ASSIGN_OR_RETURN(const PlanWithApproaches plan2, PlanFor(run2, args.validate_plan));
      FL_ASSIGN_OR_RETURN(const metrology::ProbeLog log2, metrology::ReadProbeLog(args.validate));
      const sim::ProbeDataInput in2 = ProbeInputOf(run2, plan2, log2);
      FL_ASSIGN_OR_RETURN(const double before, sim::PredictionRms(in2, baseline));
      FL_ASSIGN_OR_RETURN(const double after, sim::PredictionRms(in2, diagnosis.extended));
      second_part = {
          {"log", args.validate}, {"run", args.validate_run}, {"rms_before_um", before}, {"rms_after_um", after}};
    }
  }
  nlohmann::json out = diagnosis.ToJson();
  out["gain"]["second_part"] = second_part;
  out["proposals"] = proposals;
  FL_RETURN_IF_ERROR(MakeDirectories(staging / "inputs"));
  for (const auto& [from, name] :
       std::vector<std::pair<std::string, std::string>>{{args.measured, "measured.csv"},
                                                        {args.features, "features.csv"},
                                                        {args.baseline, "baseline.json"},
                                                        {args.plan, "plan" + fs::path(args.plan).extension().string()},
                                                        {args.validate, "validate.csv"},
                                                        {args.direct, "direct.json"},
                                                        {args.probe_profile, "probe_profile.json"}}) {
    if (!from.empty()) FL_RETURN_IF_ERROR(CopyInto(from, staging / "inputs" / name));
  }
  for (std::size_t p = 0; p < args.more_measured.size(); ++p) {
    FL_RETURN_IF_ERROR(
        CopyInto(args.more_measured[p], staging / "inputs" / ("measured_" + std::to_string(p + 2) + ".csv")));
  }
  nlohmann::json args_json = {
      {"measured", args.measured},           {"features", args.features},   {"run", args.run},
      {"more_measured", args.more_measured}, {"more_runs", args.more_runs}, {"plan", args.plan},
      {"probe_profile", args.probe_profile}, {"baseline", args.baseline},   {"validate", args.validate},
      {"validate_run", args.validate_run},   {"direct", args.direct}};
  FL_RETURN_IF_ERROR(WriteJsonFile(staging / "inputs" / "arguments.json", args_json));
  FL_RETURN_IF_ERROR(WriteJsonFile(staging / "diagnosis.json", out));
  FL_RETURN_IF_ERROR(sim::WriteModel(staging / "model.json", diagnosis.extended));
  if (!residuals.points.empty())
    FL_RETURN_IF_ERROR(WritePoints(staging / "residuals.csv", residuals, {.precision = 6}));
  FL_RETURN_IF_ERROR(folder.Commit());
  log::Info("{}", diagnosis.Summary());
  if (stored_run.has_value()) {
    const Status stored = StoreLearnedModel(args, *stored_run, diagnosis);
    if (!stored.ok()) {
      return Status(stored.code(), "the diagnosis is in '" + dir.string() +
                                       "', but storing the learned model failed: " + stored.message());
    }
    out["stored_in_library"] = {{"library", args.library}, {"case", args.case_uid}};
  }
  if (!second_part.is_null()) {
    log::Info("second part: prediction rms {:.2f} um (baseline) -> {:.2f} um (extended model)",
              second_part["rms_before_um"].get<double>(), second_part["rms_after_um"].get<double>());
  }
  return out;
}

}  // namespace formloop::app
