#include "app/pipeline_stages.h"

#include <algorithm>
#include <cmath>
#include <memory>
#include <set>

#include "app/case_knowledge.h"
#include "app/machine_profile.h"
#include "cnc/linuxcnc_probing.h"
#include "core/atomic_file.h"
#include "core/log.h"
#include "core/number_text.h"
#include "core/point_io.h"
#include "core/random.h"
#include "core/version.h"
#include "metrology/probe_log_analysis.h"
#include "nc-gen/cutter_locations.h"
#include "nc-gen/moves.h"
#include "nc-gen/toolpath_io.h"
#include "planning/case_plan.h"
#include "planning/precompensation.h"
#include "reconstruction/cad_io.h"
#include "reconstruction/surface_family.h"
#include "reconstruction/trim.h"
#include "retrieval/retrieve.h"
#include "simulation/experiment_design.h"
#include "simulation/virtual_machine.h"

namespace formloop::app::stages {
namespace fs = std::filesystem;
using nlohmann::json;

const char* const kVersion = Version();

namespace {

Result<Machine> ResolveMachine(const PartSpec& part, const RunOptions& options, const fs::path& data_dir,
                               const RunFolderWriter& folder) {
  Machine m;
  m.name = part.machine_name;
  m.probe = part.true_probe;
  if (!options.measured.empty()) {
    if (!options.machine.empty()) {
      return Status::BadInput(Where{.field = "--machine"}, "cannot be combined with --measured",
                              "give either a virtual machine or measured probe logs");
    }
    m.virtual_machine = false;
    FL_RETURN_IF_ERROR(folder.MakeFolder(fs::path("inputs") / "measured"));
    for (std::size_t k = 0; k < options.measured.size(); ++k) {
      // Read as a probe log here, before any stage runs, so a malformed one is refused at once and named as
      // the user gave it (the copy below is in a run folder that a failed run removes).
      FL_RETURN_IF_ERROR(metrology::ReadProbeLog(options.measured[k]).status());
      FL_ASSIGN_OR_RETURN(std::string text, ReadFile(options.measured[k]));
      const fs::path copy = fs::path("inputs") / "measured" / ("loop-" + std::to_string(k) + ".csv");
      FL_RETURN_IF_ERROR(folder.WriteText(copy, text));
      m.measured.push_back(folder.Path(copy).string());
      m.measured_given.push_back(options.measured[k]);
    }
    return m;
  }
  const std::string spec = options.machine.empty() ? "virtual" : options.machine;
  if (spec == "virtual" && !part.effects) {
    // The part's machine by name: its profile in data/machines/.
    return ResolveMachine(part, RunOptions{.machine = "virtual:" + part.machine_name}, data_dir, folder);
  }
  if (spec == "virtual") {
    m.model = *part.effects;
    FL_RETURN_IF_ERROR(
        folder.WriteJson(fs::path("inputs") / "machine_profile.json",
                         MachineProfile{m.name, "the part file's machine.effects", m.model, m.probe}.ToJson()));
    return m;
  }
  if (spec.rfind("linuxcnc:", 0) == 0) {
    FL_ASSIGN_OR_RETURN(const cnc::LinuxCncConfig config, cnc::ReadLinuxCncConfig(spec.substr(9)));
    if (part.dialect != "linuxcnc") {
      return Status::BadInput(Where{.field = "machine.dialect"},
                              "is '" + part.dialect + "', but --machine " + spec + " is a LinuxCNC controller",
                              "set machine.dialect to linuxcnc");
    }
    const std::string radius = config.Get("FORMLOOP", "PROBE_BALL_RADIUS_MM");
    double radius_mm = 0;
    if (!ParseDouble(radius, &radius_mm) || std::abs(radius_mm - part.probe.ball_radius_mm) > 1e-9) {
      return Status::BadInput(
          Where{.field = "probing.ball_radius_mm"},
          FormatExact(part.probe.ball_radius_mm) + " mm, but the probe surface of " + config.ini.string() +
              " is built for a " + (radius.empty() ? "missing" : radius) + " mm ball",
          "write the configuration with --ball-radius-mm " + FormatExact(part.probe.ball_radius_mm));
    }
    if (config.Get("FORMLOOP", "PROBE_SURFACE") != part.surface_reference) {
      log::Warn(
          "[machine] LinuxCNC's probe surface is '{}', the part's surface '{}': the deviations will show the "
          "difference",
          config.Get("FORMLOOP", "PROBE_SURFACE"), part.SurfaceName());
    }
    m.virtual_machine = false;
    m.name = config.Get("EMC", "MACHINE");
    m.linuxcnc = config.ini.string();
    FL_RETURN_IF_ERROR(
        folder.WriteJson(fs::path("inputs") / "machine_linuxcnc.json",
                         {{"ini", m.linuxcnc}, {"machine", m.name}, {"formloop", config.sections.at("FORMLOOP")}}));
    return m;
  }
  if (spec.rfind("virtual:", 0) != 0) {
    return Status::BadInput(Where{.field = "--machine"}, "unknown machine '" + spec + "'",
                            "use virtual, virtual:PROFILE, linuxcnc:CONFIG or --measured LOG.csv");
  }
  FL_ASSIGN_OR_RETURN(MachineProfile profile, ReadMachineProfile(spec.substr(8), data_dir));
  m.name = profile.name;
  m.model = profile.model;
  if (profile.probe) m.probe = *profile.probe;
  FL_RETURN_IF_ERROR(folder.WriteJson(fs::path("inputs") / "machine_profile.json", profile.ToJson()));
  return m;
}

// The plan points a 3-axis probe cannot reach clear of the part (nc::ReachableProbePoints: under an
// overhang or a fold) are left out of p's plan and approaches before any program is written; a warning and
// toolpath/probing_left_out.json name them, the move and the gap. Nothing is written when none is.
Status LeaveOutUnreachable(const nc::ProbeProgramOptions& options, const RunFolderWriter& folder, Programs* p) {
  const std::size_t planned = p->probing_plan.points.size();
  FL_ASSIGN_OR_RETURN(nc::ReachableProbePlan reachable, nc::ReachableProbePoints(p->probing_plan, options));
  if (reachable.left_out.empty()) return Status::Ok();
  json points = json::array();
  std::string ids;
  for (const nc::UnreachableProbePoint& u : reachable.left_out) {
    const metrology::ProbePoint& pt = p->probing_plan.points[u.index];
    points.push_back({{"id", u.id}, {"u", pt.u}, {"v", pt.v}, {"reason", u.reason}});
    ids += (ids.empty() ? "" : ", ") + std::to_string(u.id);
    log::Warn("[nc] probe point {} (u {:.4f}, v {:.4f}) left out: {}", u.id, pt.u, pt.v, u.reason);
  }
  log::Warn(
      "[nc] {} of {} probe points left out of the plan: a 3-axis probe cannot reach them clear of the part "
      "(points {}; toolpath/probing_left_out.json)",
      reachable.left_out.size(), planned, ids);
  FL_RETURN_IF_ERROR(folder.WriteJson(
      fs::path("toolpath") / "probing_left_out.json",
      {{"rule",
        "a point is left out when no clearance (full, halved, quartered) keeps the probe min_gap_mm clear of the "
        "part on its traverse, descent and probing move; the plan is refused when fewer than min_share remain"},
       {"min_gap_mm", options.min_gap_mm},
       {"min_share", nc::kMinReachableShare},
       {"planned", planned},
       {"kept", reachable.plan.points.size()},
       {"left_out", points}}));
  p->unreachable = std::move(reachable.left_out);
  p->probing_plan = std::move(reachable.plan);
  p->probe_approaches = std::move(reachable.approaches);
  return Status::Ok();
}

}  // namespace

Result<Inputs> ResolveInputs(const PartSpec& given, const RunOptions& options, const fs::path& data_dir,
                             const RunFolderWriter& folder) {
  FL_RETURN_IF_ERROR(folder.MakeFolder("inputs"));
  Inputs in;
  FL_ASSIGN_OR_RETURN(in.machine, ResolveMachine(given, options, data_dir, folder));
  // Learned models are keyed by the machine the part is really cut on.
  in.part = given;
  in.part.machine_name = in.machine.name;
  FL_RETURN_IF_ERROR(folder.WriteJson(fs::path("inputs") / "part.json", in.part.ToJson()));
  // The CAD model or scan beside it, so the run repeats from its folder (the part names the copy and its hash).
  if (in.part.surface_file) FL_RETURN_IF_ERROR(CopySurfaceFile(*in.part.surface_file, folder.Path("inputs")));
  FL_RETURN_IF_ERROR(folder.WriteJson(fs::path("inputs") / "options.json", {{"kb", options.kb},
                                                                            {"machine", options.machine},
                                                                            {"measured", options.measured},
                                                                            {"retain", options.retain},
                                                                            {"learn", options.learn},
                                                                            {"pool_cases", options.pool_cases}}));
  Rng seeds(in.part.seed);
  in.fit_seed = seeds.Fork();
  in.machine_seed = seeds.Fork();
  in.plan_seed = seeds.Fork();
  in.analysis_seed = seeds.Fork();
  return in;
}

recon::FamilySurfaceOptions FamilySurfaceOptionsOf(const PartSpec& part, std::uint64_t seed, int check_points) {
  const bool parametric = !part.surface_kind.empty();
  return {.kind = parametric ? recon::SurfaceFamilyKind::kParametric : recon::SurfaceFamilyKind::kReference,
          .name = parametric ? part.surface_kind : part.surface_reference,
          .params = part.surface_params,
          .samples_u = part.fit_samples_u,
          .samples_v = part.fit_samples_v,
          .samples = part.surface_samples,
          .fit = part.fit,
          .check_points = check_points,
          .seed = seed};
}

Result<Surface> BuildSurface(const PartSpec& part, std::uint64_t seed, const RunFolderWriter& folder) {
  const recon::FamilySurfaceOptions options = FamilySurfaceOptionsOf(part, seed, part.fit_check_points);
  FL_RETURN_IF_ERROR(folder.MakeFolder("surface"));
  const fs::path samples_path = folder.Path(fs::path("surface") / "samples.csv");
  if (part.surface_file) {
    Surface s;
    // CAD faces or a scan (app/surface_source.h); samples of Q inside its trim.
    FL_ASSIGN_OR_RETURN(SurfaceFromFile built, BuildSurfaceFromFile(*part.surface_file, part.tolerance_mm));
    s.q = std::move(built.q);
    s.report = std::move(built.report);
    s.description = std::move(built.description);
    const recon::TrimmedGrid grid = recon::SampleTrimmedGrid(s.q, part.fit_samples_u, part.fit_samples_v);
    PointSet samples;
    for (std::size_t k = 0; k < grid.uv.size(); ++k) {
      if (grid.inside[k]) samples.points.push_back(s.q.Point(grid.uv[k].x(), grid.uv[k].y()));
    }
    FL_RETURN_IF_ERROR(WritePoints(samples_path, samples));
    s.fit_check_max_mm = built.fit_check_max_mm;
    s.description["fit"] = s.report.ToJson();
    s.description["bspline"] = {{"u_degree", s.q.u_degree()},
                                {"v_degree", s.q.v_degree()},
                                {"u_poles", s.q.u_poles()},
                                {"v_poles", s.q.v_poles()}};
    FL_RETURN_IF_ERROR(folder.WriteJson(fs::path("surface") / "surface.json", s.description));
    FL_RETURN_IF_ERROR(recon::WriteStep(folder.Path(fs::path("surface") / "Q.step"), s.q, part.name));
    return s;
  }
  FL_ASSIGN_OR_RETURN(recon::FamilySurface built, recon::BuildFamilySurface(options));
  FL_RETURN_IF_ERROR(WritePoints(samples_path, built.samples));
  FL_RETURN_IF_ERROR(folder.WriteJson(fs::path("surface") / "surface.json", built.description));
  FL_RETURN_IF_ERROR(recon::WriteStep(folder.Path(fs::path("surface") / "Q.step"), built.q, part.name));
  Surface s{std::move(built.q), built.report, std::move(built.description)};
  s.fit_check_max_mm = s.report.check_max_mm;
  return s;
}

Result<Retrieved> Retrieve(const PartSpec& part, const recon::BSplineSurface& q, const RunOptions& options,
                           const fs::path& data_dir, const RunFolderWriter& folder) {
  Retrieved r;
  if (options.kb.empty()) {
    r.report = {{"route",
                 {{"name", "default"},
                  {"similarity", nullptr},
                  {"flag_engineer", true},
                  {"rule", "no case library given (--kb): the default plan, flagged"}}},
                {"ranked", json::array()}};
    FL_RETURN_IF_ERROR(folder.WriteJson("retrieval.json", r.report));
    return r;
  }
  FL_ASSIGN_OR_RETURN(retrieval::FacetTaxonomies tax, retrieval::FacetTaxonomies::Load(data_dir / "taxonomies"));
  retrieval::FeatureOptions fo;
  fo.taxonomies = std::make_shared<const retrieval::FacetTaxonomies>(std::move(tax));
  auto extracted = retrieval::ExtractFeatures(DescriptionOf(part, part.toolpath), q, fo);
  if (!extracted.ok()) {
    return extracted.status().WithContext(
        "the part's retrieval description (material, shape_family, finish_ra_um, machine.class in the part file)");
  }
  const retrieval::PartFeatures& features = *extracted;
  r.features = features;
  FL_ASSIGN_OR_RETURN(auto library, kb::Library::Open(options.kb));
  std::shared_ptr<const retrieval::RetrievalModel> model = options.retrieval_model;
  if (!model) {
    FL_ASSIGN_OR_RETURN(retrieval::RetrievalModel loaded, retrieval::RetrievalModel::Load(*library, *fo.taxonomies));
    model = std::make_shared<const retrieval::RetrievalModel>(std::move(loaded));
  }
  retrieval::RetrieveOptions ro;
  FL_ASSIGN_OR_RETURN(retrieval::RetrievalResult result, model->Retrieve(features, ro));
  r.report = result.ToJson();
  r.report["query"]["concepts"] = features.Concepts();
  // The library's file name, not its path: the run folder and its report name no folder (--kb /abs/path).
  r.report["library"] = fs::path(options.kb).filename().string();
  r.route = result.route;
  r.similarity = result.best_similarity;
  if (!result.ranked.empty()) {
    FL_ASSIGN_OR_RETURN(kb::CaseRecord best, library->GetCase(result.ranked.front().uid));
    r.best = std::move(best);
  }
  if (auto own = library->GetCase(part.name); own.ok()) r.own = std::move(own).value();
  FL_RETURN_IF_ERROR(folder.WriteJson("retrieval.json", r.report));
  return r;
}

Result<planning::PlanChoice> ChoosePlan(const Inputs& in, const Retrieved& retrieved, const recon::BSplineSurface& q,
                                        bool learn, const RunFolderWriter& folder) {
  const PartSpec& part = in.part;
  planning::PlanRequest request;
  request.surface = &q;
  request.part = {.plan = part.toolpath, .magazine = part.tools, .limits = part.limits};
  request.flutes = part.flutes;
  request.material = part.material;
  request.machine = in.machine.name;
  request.tolerance_mm = part.tolerance_mm;
  request.coverage_factor = part.analysis.coverage_factor;
  request.probe_inset_fraction = part.probe_inset_fraction;
  request.route = retrieved.route;
  request.best = retrieved.best ? &*retrieved.best : nullptr;
  request.similarity = retrieved.similarity;
  request.learn = learn;
  request.seed = in.plan_seed;
  FL_ASSIGN_OR_RETURN(planning::PlanChoice choice, planning::ChoosePlan(request));
  if (choice.correction) FL_RETURN_IF_ERROR(folder.WriteJson("sim_correction.json", choice.correction->ToJson()));
  return choice;
}

Result<Experiment> FindSeparatingExperiment(const PartSpec& part, const RunOptions& options,
                                            const std::string& retrieved_uid, const nc::ToolpathOptions& plan) {
  Experiment out;
  out.asked = !part.separating_experiment.empty();
  if (part.separating_experiment == "given") {
    out.proposals = part.proposals;
    out.source = "part file";
  } else if (part.separating_experiment == "library") {
    const std::string tool = planning::ToolKey(plan.tool.radius_mm);
    out.source =
        "none in the case library for machine " + part.machine_name + ", tool " + tool + ", material " + part.material;
    if (!options.kb.empty()) {
      FL_ASSIGN_OR_RETURN(auto library, kb::Library::Open(options.kb));
      std::string from;
      FL_ASSIGN_OR_RETURN(out.proposals, StoredSeparatingExperiments(*library, part.machine_name, tool, part.material,
                                                                     retrieved_uid, &from));
      if (!out.proposals.empty()) out.source = "case library, case " + from;
    }
  }
  if (out.asked) log::Info("[plan] separating experiment: {} ({} proposal(s))", out.source, out.proposals.size());
  return out;
}

Result<Programs> WritePrograms(const PartSpec& part, const recon::BSplineSurface& q, const nc::ToolpathOptions& plan,
                               std::shared_ptr<nc::Toolpath> planned, const Experiment& experiment,
                               const RunFolderWriter& folder) {
  Programs p;
  // The plan may come from a case or the simulation-correction step: its size is checked again.
  FL_RETURN_IF_ERROR(CheckPartWork(part, plan, "the chosen plan (plan.json)", &q));
  if (planned && nc::ToolpathOptionsJson(planned->options) == nc::ToolpathOptionsJson(plan)) {
    p.nominal = std::move(*planned);  // the same PlanRaster(q, plan) the simulation correction checked
  } else {
    FL_ASSIGN_OR_RETURN(p.nominal, nc::PlanRaster(q, plan));
  }
  planned.reset();
  p.post.limits = part.limits;
  p.post.title = "formloop " + std::string(kVersion) + " part " + part.name + " loop 0, nominal";
  std::string text;
  {  // the moves made as they are posted: a million-point path is never held as a list of moves
    FL_ASSIGN_OR_RETURN(const nc::ToolpathMoves moves, nc::ToolpathMoves::Of(p.nominal));
    FL_ASSIGN_OR_RETURN(text, nc::Post(moves, part.dialect, p.post));
  }
  p.extension = std::string(nc::FindPost(part.dialect)->FileExtension());
  p.program.path = fs::path("toolpath") / ("program" + p.extension);
  FL_RETURN_IF_ERROR(folder.WriteText(p.program.path, text));
  FL_RETURN_IF_ERROR(nc::WriteToolpathFile(folder.Path(fs::path("toolpath") / "toolpath.csv"), p.nominal));
  FL_RETURN_IF_ERROR(folder.WriteJson(fs::path("toolpath") / "toolpath.json", p.nominal.ReportJson()));
  log::Info("      {} passes, {} CL points, {:.0f} s cutting", p.nominal.passes, p.nominal.points.size(),
            p.nominal.total_time_s);
  FL_ASSIGN_OR_RETURN(p.probing_plan, metrology::PlanProbingGrid(q, part.probe_nu, part.probe_nv,
                                                                 part.probe_inset_fraction, part.probe_edge_margin_mm));
  if (experiment.asked) {
    const sim::PlanWithProposals applied = sim::ApplyProposals(p.probing_plan, q, experiment.proposals);
    nlohmann::json list = nlohmann::json::array();
    for (const auto& proposal : experiment.proposals) list.push_back(proposal.ToJson());
    FL_RETURN_IF_ERROR(folder.WriteJson(
        fs::path("toolpath") / "separating_experiment.json",
        {{"source", experiment.source},
         {"proposals", list},
         {"points_added", applied.added},
         {"points_dropped", applied.dropped},
         {"first_added_id",
          applied.added > 0 ? json(applied.plan.points[p.probing_plan.points.size()].id) : json(nullptr)},
         {"raster_turn_deg", applied.raster_turn_deg},
         {"feed_scale", applied.feed_scale}}));
    if (applied.added > 0 || applied.dropped > 0) {
      log::Info("      separating experiment: {} tilted probe point(s) added{}", applied.added,
                applied.dropped > 0 ? fmt::format(", {} left out (trim or approach)", applied.dropped) : "");
    }
    if (applied.tilted()) {
      p.probing_plan = applied.plan;
      p.probe_approaches = applied.approaches;
    }
  }
  nc::ProbeProgramOptions probe_options = part.probe_program;
  probe_options.approaches = p.probe_approaches;
  FL_ASSIGN_OR_RETURN(p.part_surface, recon::FootPointProjector::Build(q));
  probe_options.part_surface = p.part_surface;
  probe_options.post = p.post;
  probe_options.post.title = "formloop " + std::string(kVersion) + " probing program for part " + part.name;
  probe_options.safe_z_mm = p.nominal.safe_z_mm + part.probe.ball_radius_mm + part.probe_program.clearance_mm;
  FL_RETURN_IF_ERROR(LeaveOutUnreachable(probe_options, folder, &p));
  probe_options.approaches = p.probe_approaches;
  FL_RETURN_IF_ERROR(folder.WriteJson(fs::path("toolpath") / "probing_plan.json", p.probing_plan.ToJson()));
  if (!p.probe_approaches.empty()) {
    // The approaches beside the plan (formloop's plan CSV with ax, ay, az: app/run_folder.h ReadPlanFile).
    PointSet rows;
    std::vector<double> u, v, ax, ay, az;
    for (std::size_t i = 0; i < p.probing_plan.points.size(); ++i) {
      const auto& pt = p.probing_plan.points[i];
      rows.points.push_back(pt.point);
      rows.normals.push_back(pt.normal);
      rows.ids.push_back(pt.id);
      u.push_back(pt.u);
      v.push_back(pt.v);
      ax.push_back(p.probe_approaches[i].x());
      ay.push_back(p.probe_approaches[i].y());
      az.push_back(p.probe_approaches[i].z());
    }
    rows.SetScalar("u", u);
    rows.SetScalar("v", v);
    rows.SetScalar("ax", ax);
    rows.SetScalar("ay", ay);
    rows.SetScalar("az", az);
    FL_RETURN_IF_ERROR(WritePoints(folder.Path(fs::path("toolpath") / "probing_plan.csv"), rows, {.precision = 9}));
  }
  // Split into batches when the controller cannot store every result at once (probe_1, probe_2, ...).
  FL_ASSIGN_OR_RETURN(const std::vector<std::string> probe_programs,
                      nc::PostProbingBatches(p.probing_plan, part.dialect, probe_options));
  for (std::size_t b = 0; b < probe_programs.size(); ++b) {
    const std::string name = probe_programs.size() == 1 ? "probe" : "probe_" + std::to_string(b + 1);
    FL_RETURN_IF_ERROR(folder.WriteText(fs::path("toolpath") / (name + p.extension), probe_programs[b]));
  }
  if (probe_programs.size() > 1) {
    log::Info(
        "[nc] the probing plan is split into {} programs: the {} controller stores the results of at most {} "
        "points at once",
        probe_programs.size(), part.dialect, nc::FindPost(part.dialect)->ProbeResultCapacity(probe_options));
  }
  // The nominal program as written: what the first cycle cuts (unless pre-compensated).
  FL_ASSIGN_OR_RETURN(p.program.moves, nc::ReadProgram(text, part.dialect, folder.Path(p.program.path).string()));
  return p;
}

double CompensatedField::operator()(double u, double v) const {
  double sum = 0;
  for (const auto& t : terms) sum += t(u, v);
  return sum;
}

Result<FirstCut> Precompensate(const PartSpec& part, const recon::BSplineSurface& q, const planning::PlanChoice& choice,
                               const Programs& programs, const std::string& case_uid, std::uint64_t seed,
                               const RunFolderWriter& folder) {
  FirstCut cut;
  const nc::ToolpathOptions& plan = choice.plan;
  json plan_json = choice.report;
  plan_json["toolpath"] = {{"tool_number", plan.tool.number},         {"tool_radius_mm", plan.tool.radius_mm},
                           {"scallop_um", plan.scallop_um},           {"raster_angle_deg", plan.raster_angle_deg},
                           {"feed_mm_per_min", plan.feed_mm_per_min}, {"spindle_rpm", plan.spindle_rpm}};
  if (choice.learned && choice.precompensation_scale > 0) {
    FL_ASSIGN_OR_RETURN(planning::PredictedField predicted,
                        planning::PredictLearnedField(q, programs.nominal, *choice.learned, seed));
    json pre = predicted.report;
    const double scale = choice.precompensation_scale;
    cut.field.terms.push_back([field = predicted.field, scale](double u, double v) { return scale * field(u, v); });
    nc::PostOptions post = programs.post;
    post.title = "formloop " + std::string(kVersion) + " part " + part.name + " loop 0, pre-compensated";
    const fs::path path = fs::path("toolpath") / ("program_precompensated" + programs.extension);
    FL_ASSIGN_OR_RETURN(
        nc::Compensation pc,
        nc::WriteCompensatedProgram(programs.nominal, programs.program.moves, cut.field,
                                    "learned model of case " + case_uid, part.compensation, post, folder.Path(path),
                                    folder.Path(fs::path("toolpath") / "precompensation_side.bin"), part.dialect));
    cut.program = Program{path, std::move(pc.program_moves)};
    cut.precompensation_scale = scale;
    pre["scale"] = scale;
    pre["max_offset_um"] = pc.max_offset_um;
    pre["program"] = path.string();
    plan_json["precompensation"] = pre;
    log::Info(
        "[precompensation] learned model of case {}: predicted peak {:.1f} um, scale {:.2f}, max offset {:.1f} um",
        case_uid, pre["predicted_peak_um"].get<double>(), scale, pc.max_offset_um);
  } else {
    plan_json["precompensation"] = nullptr;
  }
  FL_RETURN_IF_ERROR(folder.WriteJson("plan.json", plan_json));
  return cut;
}

Result<Machined> MachineCycle(const Inputs& in, const Program& program, double tool_radius_mm,
                              const metrology::ProbingPlan& plan, const std::vector<Eigen::Vector3d>& approaches,
                              const std::optional<recon::FootPointProjector>& part_surface,
                              const std::vector<nc::UnreachableProbePoint>& left_out, int loop,
                              const RunFolderWriter& folder) {
  const fs::path loop_dir = RunFolderWriter::LoopDir(loop);
  FL_RETURN_IF_ERROR(folder.MakeFolder(loop_dir));
  Machined out;
  out.cutter_locations = nc::CutterLocationsOfProgram(program.moves, tool_radius_mm);
  const Machine& machine = in.machine;
  if (machine.virtual_machine) {
    log::Info("[machine] loop {}: virtual machine '{}' cuts {}", loop, machine.name, program.path.string());
    sim::VirtualMachineOptions vm;
    vm.tool_radius_mm = tool_radius_mm;
    vm.model = machine.model;
    vm.true_probe = machine.probe;
    vm.seed = in.machine_seed + static_cast<std::uint64_t>(loop);
    vm.approaches = approaches;
    FL_ASSIGN_OR_RETURN(sim::VirtualMachineResult machined, sim::MachineAndProbe(out.cutter_locations, plan, vm));
    FL_RETURN_IF_ERROR(metrology::WriteProbeLog(folder.Path(loop_dir / "probe_log.csv"), machined.log));
    FL_RETURN_IF_ERROR(folder.WriteJson(loop_dir / "machine.json", {{"machine", machine.name},
                                                                    {"program", program.path.string()},
                                                                    {"cutter_locations", out.cutter_locations.size()},
                                                                    {"points", machined.log.records.size()}}));
  } else if (!machine.linuxcnc.empty()) {
    log::Info("[machine] loop {}: LinuxCNC '{}' probes the part (its probe surface; the cutting program is not run)",
              loop, machine.name);
    FL_ASSIGN_OR_RETURN(const cnc::LinuxCncConfig config, cnc::ReadLinuxCncConfig(machine.linuxcnc));
    cnc::LinuxCncProbingOptions probing;
    probing.program.approaches = approaches;
    probing.program.part_surface = part_surface;
    probing.program.min_gap_mm = in.part.probe_program.min_gap_mm;
    probing.program.shank_radius_mm = in.part.probe_program.shank_radius_mm;
    FL_ASSIGN_OR_RETURN(const cnc::LinuxCncProbing probed,
                        cnc::ProbePlanOnLinuxCnc(config, plan, probing, folder.Path(loop_dir / "linuxcnc")));
    FL_RETURN_IF_ERROR(metrology::WriteProbeLog(folder.Path(loop_dir / "probe_log.csv"), probed.log));
    out.cut = false;
    FL_RETURN_IF_ERROR(folder.WriteJson(loop_dir / "machine.json",
                                        {{"machine", machine.name},
                                         {"linuxcnc", machine.linuxcnc},
                                         {"program", (loop_dir / "linuxcnc" / "probe.ngc").string()},
                                         {"cut", "not run: the simulated part is the configuration's probe surface, " +
                                                     config.Get("FORMLOOP", "PROBE_SURFACE")},
                                         {"points", probed.log.records.size()},
                                         {"controller_seconds", probed.run.total_s}}));
  } else {
    const std::string& measured = machine.measured[static_cast<std::size_t>(loop)];
    FL_ASSIGN_OR_RETURN(std::string text, ReadFile(measured));
    FL_RETURN_IF_ERROR(folder.WriteText(loop_dir / "probe_log.csv", text));
    FL_RETURN_IF_ERROR(
        folder.WriteJson(loop_dir / "machine.json",
                         {{"machine", machine.name}, {"measured", measured}, {"program", program.path.string()}}));
  }
  // The analysis reads the log back from disk, as it would a real machine's.
  FL_ASSIGN_OR_RETURN(out.log, metrology::ReadProbeLog(folder.Path(loop_dir / "probe_log.csv")));
  // A measured log is the user's file: what later stages say of its rows (an id of another plan, a point
  // this run left out) names that file, whose lines the copy holds byte for byte, not the run folder's copy.
  const bool measured_log = !machine.virtual_machine && machine.linuxcnc.empty();
  if (measured_log) out.log.source = machine.measured_given[static_cast<std::size_t>(loop)];
  for (std::size_t i = 0; measured_log && i < out.log.records.size(); ++i) {
    const metrology::ProbeRecord& r = out.log.records[i];
    const auto u = std::find_if(left_out.begin(), left_out.end(),
                                [&](const nc::UnreachableProbePoint& p) { return p.id == r.id; });
    if (u == left_out.end()) continue;
    return Status::BadInput(
        Where{.file = machine.measured_given[static_cast<std::size_t>(loop)], .line = r.line, .field = "id"},
        fmt::format("point {} was left out of this run's probing plan: {}", r.id, u->reason),
        "measure the part with the probing program this run writes (toolpath/probe.*, without that point; "
        "toolpath/probing_left_out.json lists the points left out), or delete the row");
  }
  return out;
}

Result<Analysed> AnalyseCycle(const PartSpec& part, const recon::BSplineSurface& q, const metrology::ProbingPlan& plan,
                              const metrology::ProbeLog& log, int loop, bool another_loop_allowed, std::uint64_t seed,
                              const RunFolderWriter& folder) {
  const fs::path loop_dir = RunFolderWriter::LoopDir(loop);
  metrology::ProbeLogAnalysisOptions options;
  options.decomposition = part.analysis;
  options.decomposition.tolerance_mm = part.tolerance_mm;
  options.lisa_permutations = 199;  // cluster map of the report
  options.lisa_seed = seed;
  // A point farther from Q than the probing program searches cannot be a real contact: flagged and left
  // out (a log mostly made of such points is refused).
  options.max_distance_mm = part.probe_program.search_mm;
  FL_ASSIGN_OR_RETURN(const metrology::ProbeLogAnalysis analysed,
                      metrology::AnalyseProbeLog(q, log, part.probe, &plan, options));
  const metrology::Decomposition& decomposition = analysed.decomposition;
  const PointSet points = analysed.PerPointTable();
  Analysed r;
  for (const auto& f : analysed.flagged) r.flagged_ids.push_back(f.id);
  FL_RETURN_IF_ERROR(WritePoints(folder.Path(loop_dir / "deviations.csv"), points, {.precision = 6}));
  FL_RETURN_IF_ERROR(WritePoints(folder.Path(loop_dir / "deviations.ply"), points));

  const metrology::FormEvaluation& evaluation = *decomposition.evaluation;
  const metrology::DecompositionStep& chosen = decomposition.steps[static_cast<std::size_t>(decomposition.chosen_step)];
  LoopSummary& ls = r.summary;
  ls.index = loop;
  ls.form_error_um = decomposition.form_error_um;
  ls.systematic_peak_um = decomposition.systematic_peak_um;
  ls.random_sigma_um = decomposition.random_sigma_um;
  ls.raw_moran_z = decomposition.raw.z_normality;
  ls.field_degree = decomposition.systematic.degree();
  ls.within_tolerance = evaluation.within_tolerance;
  ls.chosen_model = decomposition.systematic.name();
  ls.residual_moran_z = decomposition.residual_moran_z;
  ls.field_residual_moran_z = chosen.residual_moran_z;
  ls.fine_scale_rms_um = decomposition.fine_scale_rms_um;
  ls.residual_independent = decomposition.independent;
  ls.systematic_significant = evaluation.systematic_significant;
  ls.compensation_advised = evaluation.compensate;
  const bool compensate = evaluation.compensate && another_loop_allowed;
  if (ls.within_tolerance) {
    ls.decision = "within tolerance: done";
  } else if (!evaluation.compensate) {
    ls.decision =
        "out of tolerance but the error is random (constant model, offset not significant): "
        "compensation cannot help";
  } else if (!compensate) {
    ls.decision = "out of tolerance after the last allowed loop (" + evaluation.decision + ")";
  } else {
    ls.decision = evaluation.decision;
  }
  log::Info(
      "      deviation rms {:.2f} um; raw Moran z {:.2f}; model {} (residual z {:.2f}); d_s peak {:.2f} um;"
      " sigma(d_u) {:.2f} um; form error {:.2f} um vs tolerance {:.1f} um",
      decomposition.deviation_rms_um, decomposition.raw.z_normality, ls.chosen_model, ls.residual_moran_z,
      decomposition.systematic_peak_um, decomposition.random_sigma_um, decomposition.form_error_um,
      part.tolerance_mm * 1e3);
  log::Info("      decision: {}", ls.decision);
  json analysis = decomposition.ToJson();
  analysis["tolerance_um"] = part.tolerance_mm * 1e3;
  analysis["within_tolerance"] = ls.within_tolerance;
  analysis["evaluation"] = evaluation.ToJson();
  analysis["decision"] = ls.decision;
  analysis["compensate"] = compensate;
  if (!analysed.flagged.empty()) analysis["flagged_points"] = analysed.FlaggedJson();
  analysis["decision_rule"] =
      "the decomposition's evaluation (spec/metrology.md §8): compensate by -d_s when the form error "
      "max|d_s| + k*sigma(d_u) exceeds the tolerance and d_s is significant (a non-constant model chosen by the "
      "residual-Moran ladder, or |mean| > 2.576 standard errors), while another loop is allowed";
  FL_RETURN_IF_ERROR(folder.WriteJson(loop_dir / "analysis.json", analysis));
  if (compensate) r.systematic = decomposition.systematic;
  return r;
}

Result<sim::Diagnosis> DiagnoseFirstCycle(const PartSpec& part, const recon::BSplineSurface& q,
                                          const Machined& machined, const std::vector<std::int64_t>& excluded_ids,
                                          double tool_radius_mm, const metrology::ProbingPlan& plan,
                                          const planning::PlanChoice& choice, const std::string& case_uid,
                                          const sim::PlausibleRanges& plausible, const RunFolderWriter& folder,
                                          std::vector<sim::PlannedProposal>* proposals, FirstCyclePooling* pooling) {
  metrology::ProbeLog used = machined.log;
  if (!excluded_ids.empty()) {
    const std::set<std::int64_t> excluded(excluded_ids.begin(), excluded_ids.end());
    std::erase_if(used.records, [&](const metrology::ProbeRecord& r) { return excluded.count(r.id) > 0; });
  }
  sim::ProbeDataInput input;
  input.surface = &q;
  input.cutter_locations = &machined.cutter_locations;
  input.tool_radius_mm = tool_radius_mm;
  input.plan = &plan;
  input.measured = &used;
  input.probe = part.probe;
  const sim::Model learned = choice.learned ? *choice.learned : sim::Model{};
  sim::DiagnoseOptions options;
  options.plausible = plausible;
  const bool pooled =
      machined.cut && pooling != nullptr && pooling->earlier != nullptr && !pooling->earlier->records.empty();
  // Pooled, every part is fitted from no effects: a learned model fitted on fewer parts (an alias group
  // carried by some of its members) would leave on each part the same misfit of the carriers, which the
  // pooled data then name as an effect of their own.
  const sim::Model baseline = pooled ? sim::Model{} : learned;
  // The part's direct readings (a set-up's: the first part's of a pooled diagnosis, which is this one). An
  // effect the baseline holds is not diagnosed, so its reading has nothing to inform: said, not used.
  json direct_not_used = json::array();
  for (const sim::DirectMeasurement& m : part.direct) {
    if (baseline.Has(m.effect)) {
      direct_not_used.push_back({{"reading", m.ToJson()},
                                 {"why", "the baseline (the learned model of case " + case_uid + ") holds " + m.effect +
                                             ", which this diagnosis does not estimate again"}});
      log::Warn("[diagnosis] the reading of {}.{} is not used: the learned model of case {} holds {}", m.effect,
                m.parameter, case_uid, m.effect);
    } else {
      options.direct.push_back(m);
    }
  }
  if (machined.cut && pooling != nullptr) {
    FL_ASSIGN_OR_RETURN(pooling->record, sim::PartRecord::Of(input));
  }
  sim::Diagnosis d;
  std::vector<sim::ProbeResidualData> parts;  // pooled: this part's residuals, then the earlier cases'
  if (pooled) {
    FL_ASSIGN_OR_RETURN(sim::ProbeResidualData own, sim::ProbeResiduals(input, baseline));
    parts.push_back(std::move(own));
    std::vector<std::string> labels = {part.name};
    for (std::size_t k = 0; k < pooling->earlier->records.size(); ++k) {
      parts.push_back(pooling->earlier->records[k].Against(baseline));
      labels.push_back(pooling->earlier->uids[k]);
    }
    FL_ASSIGN_OR_RETURN(d, sim::DiagnosePooledResiduals(parts, baseline, options, labels));
  } else if (machined.cut) {
    FL_ASSIGN_OR_RETURN(d, sim::Diagnose(input, baseline, options));
  } else {
    FL_ASSIGN_OR_RETURN(d, sim::DiagnosePlanOnly(plan, machined.log, part.probe, baseline, options));
  }
  const fs::path dir = RunFolderWriter::LoopDir(0) / "diagnosis";
  json dj = d.ToJson();
  if (!machined.cut)
    dj["data"] = "probe data of a part the program did not cut: the tool-path effects are not screened";
  if (pooling != nullptr && pooling->earlier != nullptr) {
    json pj = pooling->earlier->report;
    pj["part"] = part.name;
    if (!machined.cut) pj["why_alone"] = "the program did not cut the part: no tool-path covariates to pool with";
    dj["pooled"] = pj;
    if (pooled) {
      log::Info("[diagnosis] pooled with {} earlier case(s) of {}: {}", pooling->earlier->uids.size(),
                part.machine_name, json(pooling->earlier->uids).dump());
    }
  }
  dj["baseline"] = pooled           ? "no effects (pooled: every part fitted from no effects)"
                   : choice.learned ? "learned model of case " + case_uid
                                    : "no effects (no learned model)";
  dj["baseline_model"] = baseline.ToJson();
  if (!direct_not_used.empty()) dj["direct_not_used"] = direct_not_used;
  FL_RETURN_IF_ERROR(folder.WriteJson(dir / "diagnosis.json", dj));
  FL_RETURN_IF_ERROR(sim::WriteModel(folder.Path(dir / "model.json"), d.extended));
  log::Info("[diagnosis] {}", d.Summary());
  if (proposals != nullptr && machined.cut && !d.alias_groups.empty()) {
    // The experiment that would separate each alias group on the next part of this machine/tool/material.
    sim::ExperimentOptions eo;
    eo.plausible = plausible;
    const nc::ToolpathOptions cut_plan = choice.plan;
    eo.replan = [&q, cut_plan](double turn_deg, double feed_scale) -> Result<std::vector<sim::CutterLocation>> {
      std::string skipped;
      auto cls = nc::ReplannedCutterLocations(q, cut_plan, turn_deg, feed_scale, &skipped);
      if (!skipped.empty()) log::Warn("[diagnosis] proposals: {}; that change is not proposed", skipped);
      return cls;
    };
    // Pooled: designed on the pooled diagnosis from the residuals it was made from — the groups
    // left are those no part split, and a change is judged by what it adds to all the parts.
    FL_ASSIGN_OR_RETURN(const auto found, pooled ? sim::ProposeExperiments(input, parts, d, eo)
                                                 : sim::ProposeExperiments({input}, d, baseline, eo));
    json list = json::array();
    for (const auto& p : found) {
      proposals->push_back(sim::PlannedProposal::Of(p, q.domain()));
      json pj = p.ToJson();
      pj["next_part"] = proposals->back().ToJson();
      list.push_back(pj);
      log::Info("[diagnosis] proposal for the next part: {} ({})", p.change,
                p.predicted_to_split ? "predicted to split the group" : "not predicted to split it on its own");
    }
    FL_RETURN_IF_ERROR(folder.WriteJson(dir / "proposals.json", {{"proposals", list}}));
  }
  return d;
}

Result<Program> CompensateCycle(const PartSpec& part, const Programs& programs, const CompensatedField& field, int loop,
                                const RunFolderWriter& folder) {
  const fs::path loop_dir = RunFolderWriter::LoopDir(loop);
  const std::string source =
      "sum of the pre-compensation and the systematic fields of loops 0.." + std::to_string(loop);
  nc::PostOptions post = programs.post;
  post.title = "formloop " + std::string(kVersion) + " part " + part.name + " loop " + std::to_string(loop + 1) +
               ", mirror-compensated";
  const fs::path path = loop_dir / ("program_compensated" + programs.extension);
  FL_ASSIGN_OR_RETURN(
      nc::Compensation compensation,
      nc::WriteCompensatedProgram(programs.nominal, programs.program.moves, field, source, part.compensation, post,
                                  folder.Path(path), folder.Path(loop_dir / "compensation_side.bin"), part.dialect));
  FL_RETURN_IF_ERROR(folder.WriteJson(loop_dir / "compensation.json",
                                      {{"source", compensation.source},
                                       {"cl_points", compensation.blocks},
                                       {"max_offset_um", compensation.max_offset_um},
                                       {"side_file_check_max_disagreement_um", compensation.check_max_disagreement_um},
                                       {"program", path.string()}}));
  log::Info("      compensated program written: max offset {:.2f} um; side-file check {:.3f} um",
            compensation.max_offset_um, compensation.check_max_disagreement_um);
  return Program{path, std::move(compensation.program_moves)};
}

Result<std::optional<Retained>> PrepareRetain(const PartSpec& part, const RunOptions& options,
                                              const Retrieved& retrieved, const nc::ToolpathOptions& plan,
                                              const std::optional<sim::Diagnosis>& diagnosis, RunSummary* summary,
                                              const RunFolderWriter& folder,
                                              const std::vector<sim::PlannedProposal>& proposals,
                                              const sim::PartRecord* part_record) {
  if (options.kb.empty() || !options.retain) return std::optional<Retained>();
  RetainInput in;
  in.part = &part;
  in.features = &*retrieved.features;
  in.plan = plan;
  in.outcome = {{"route", summary->route},
                {"similarity", summary->similarity},
                {"retrieved_case", summary->case_uid},
                {"within_tolerance", summary->within_tolerance},
                {"loops", summary->loops.size()},
                {"form_error_first_um", summary->loops.front().form_error_um},
                {"form_error_final_um", summary->loops.back().form_error_um},
                {"random_sigma_um", summary->loops.back().random_sigma_um},
                {"causes", summary->causes},
                {"precompensated", summary->precompensated}};
  for (std::size_t k = 0; k + 1 < summary->loops.size(); ++k) {
    in.compensation_loops.push_back({{"loop", k + 1},
                                     {"form_error_before_um", summary->loops[k].form_error_um},
                                     {"form_error_after_um", summary->loops[k + 1].form_error_um}});
  }
  if (diagnosis && !diagnosis->extended.effects.empty()) {
    in.learned = diagnosis->extended;
    in.learned_provenance = {
        {"part", part.name},
        // The run folder's name, not its path: the record goes into the library and the
        // report, which name no folder.
        {"run", (options.out.has_filename() ? options.out : options.out.parent_path()).filename().string()},
        {"data", "loop-0/probe_log.csv"},
        {"points", diagnosis->n},
        {"heldout_rms_before_um", diagnosis->heldout_rms_before_um},
        {"heldout_rms_after_um", diagnosis->heldout_rms_after_um}};
  }
  for (const auto& p : proposals) in.separating_experiments.push_back(p.ToJson());
  if (retrieved.own) in.existing = &*retrieved.own;
  // A part cut on the virtual machine can be run again (the leave-one-out of app/route_calibration.h); a
  // measured one cannot.
  if (options.measured.empty() && options.machine.rfind("linuxcnc:", 0) != 0) {
    in.rerun = {{"part", part.ToJson()}, {"machine", options.machine}};
  }
  in.part_record = part_record;
  Retained out;
  FL_ASSIGN_OR_RETURN(out.record, MakeRetainedCase(in));
  out.part_record = MakePartRecordRow(in);
  json retain = {{"library", fs::path(options.kb).filename().string()},
                 {"action", retrieved.own ? "update" : "add"},
                 {"uid", out.record.uid},
                 {"learned_model", in.learned ? in.learned->ToJson() : json(nullptr)},
                 {"case", out.record.ToJson()}};
  // The record itself is large (a few hundred bytes a point): its key and size here.
  retain["part_record"] = out.part_record ? json{{"machine", out.part_record->machine},
                                                 {"tool", out.part_record->tool},
                                                 {"material", out.part_record->material},
                                                 {"points", part_record->points()}}
                                          : json(nullptr);
  FL_RETURN_IF_ERROR(folder.WriteJson("retain.json", retain));
  summary->retained = (retrieved.own ? "updated " : "added ") + out.record.uid;
  return std::optional<Retained>(std::move(out));
}

Status CommitRetained(const std::string& kb_path, const Retained& retained) {
  FL_ASSIGN_OR_RETURN(auto library, kb::Library::Open(kb_path));
  // The case and its part record in one transaction.
  const Status committed = library->RunInTransaction([&]() -> Status {
    FL_RETURN_IF_ERROR(retrieval::AddCaseAndGrowGhsom(*library, retained.record, /*replace=*/true).status());
    return retained.part_record ? library->SetPartRecord(*retained.part_record) : Status::Ok();
  });
  FL_RETURN_IF_ERROR(committed);
  log::Info("[retain] case {} stored in {}{}", retained.record.uid, kb_path,
            retained.part_record ? " with its part record" : "");
  return Status::Ok();
}

json LoopJson(const LoopSummary& l) {
  return {{"loop", l.index},
          {"form_error_um", l.form_error_um},
          {"systematic_peak_um", l.systematic_peak_um},
          {"random_sigma_um", l.random_sigma_um},
          {"raw_moran_z", l.raw_moran_z},
          {"systematic_field_degree", l.field_degree},
          {"within_tolerance", l.within_tolerance},
          {"compensated_after", l.compensated},
          {"chosen_model", l.chosen_model},
          {"residual_moran_z", l.residual_moran_z},
          {"residual_independent", l.residual_independent},
          {"field_residual_moran_z", l.field_residual_moran_z},
          {"fine_scale_rms_um", l.fine_scale_rms_um},
          {"systematic_significant", l.systematic_significant},
          {"compensation_advised", l.compensation_advised},
          {"decision", l.decision}};
}

}  // namespace formloop::app::stages
