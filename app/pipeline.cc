#include "app/pipeline.h"

#include <chrono>
#include <optional>

#include <fmt/format.h>

#include "app/case_knowledge.h"
#include "app/machine_profile.h"
#include "app/report.h"
#include "app/run_folder.h"
#include "app/sim_correction.h"
#include "core/atomic_file.h"
#include "core/json_io.h"
#include "core/log.h"
#include "core/point_io.h"
#include "core/random.h"
#include "kb/library.h"
#include "metrology/deviations.h"
#include "metrology/morans_i.h"
#include "metrology/spatial_weights.h"
#include "nc-gen/cutter_locations.h"
#include "nc-gen/deviation_field.h"
#include "nc-gen/toolpath_io.h"
#include "reconstruction/analytic_surface.h"
#include "retrieval/retrieve.h"
#include "retrieval/starter.h"
#include "simulation/diagnose.h"

namespace formloop::app {
namespace fs = std::filesystem;
using nlohmann::json;
namespace {

constexpr const char* kVersion = "0.2.0";

// The sum of the fields compensated so far (mm): the pre-compensation and one term per loop.
struct Field {
  std::vector<std::function<double(double, double)>> terms;
  double operator()(double u, double v) const {
    double sum = 0;
    for (const auto& t : terms) sum += t(u, v);
    return sum;
  }
};

// Stage bookkeeping: status.json says where an unfinished run stopped; on_stage gets the wall time.
class Stages {
 public:
  Stages(fs::path dir, const RunOptions& options) : dir_(std::move(dir)), options_(options) {}
  Status Begin(const std::string& stage) {
    End();
    stage_ = stage;
    start_ = std::chrono::steady_clock::now();
    return WriteJsonFile(dir_ / "status.json", {{"state", "incomplete"}, {"stage", stage}});
  }
  void End() {
    if (stage_.empty()) return;
    const double s = std::chrono::duration<double>(std::chrono::steady_clock::now() - start_).count();
    if (options_.on_stage) options_.on_stage(StageName(stage_), s);
    stage_.clear();
  }

 private:
  static std::string StageName(const std::string& stage) {
    const auto colon = stage.find(':');
    return colon == std::string::npos ? stage : stage.substr(colon + 2);
  }
  fs::path dir_;
  const RunOptions& options_;
  std::string stage_;
  std::chrono::steady_clock::time_point start_;
};

struct Surface {
  recon::BSplineSurface q;
  recon::FitReport report;
  json description;
};

// The ideal surface: an analytic reference surface or a parametric kind, fitted as a B-spline and
// checked against its defining function at random points not used in the fit.
Result<Surface> BuildSurface(const PartSpec& part, std::uint64_t seed, const fs::path& dir) {
  Surface s;
  FL_RETURN_IF_ERROR(MakeDirectories(dir / "surface"));
  if (part.surface_kind.empty()) {
    FL_ASSIGN_OR_RETURN(std::unique_ptr<recon::AnalyticSurface> reference,
                        recon::MakeReferenceSurface(part.surface_reference));
    FL_RETURN_IF_ERROR(WritePoints(dir / "surface" / "samples.csv",
                                   recon::SampleGridPoints(*reference, part.fit_samples_u, part.fit_samples_v)));
    FL_ASSIGN_OR_RETURN(s.q, recon::FitAnalytic(*reference, part.fit_samples_u, part.fit_samples_v, part.fit,
                                                part.fit_check_points, seed, &s.report));
    s.description = {{"reference", reference->name()}, {"description", reference->description()}};
  } else {
    FL_ASSIGN_OR_RETURN(const retrieval::StarterHeight height,
                        retrieval::StarterHeightOf(part.surface_kind, part.surface_params));
    FL_ASSIGN_OR_RETURN(const recon::GridSamples g,
                        retrieval::StarterGrid(part.surface_kind, part.surface_params, part.surface_samples));
    PointSet samples;
    samples.points = g.points;
    FL_RETURN_IF_ERROR(WritePoints(dir / "surface" / "samples.csv", samples));
    FL_ASSIGN_OR_RETURN(s.q, recon::FitGrid(g, part.fit, &s.report));
    Rng rng(seed);
    double sum2 = 0;
    for (int k = 0; k < part.fit_check_points; ++k) {
      const double u = g.domain.u_min + g.domain.u_span() * rng.Uniform();
      const double v = g.domain.v_min + g.domain.v_span() * rng.Uniform();
      const Eigen::Vector3d p = s.q.Point(u, v);
      const double e = std::abs(p.z() - height.z(p.x(), p.y()));
      sum2 += e * e;
      if (e > s.report.check_max_mm) {
        s.report.check_max_mm = e;
        s.report.check_max_at = p;
      }
    }
    s.report.n_check = part.fit_check_points;
    s.report.check_rms_mm = part.fit_check_points > 0 ? std::sqrt(sum2 / part.fit_check_points) : 0.0;
    s.description = {{"kind", part.surface_kind}, {"params", part.surface_params},
                     {"check", "vertical distance to z = f(x, y) at random points"}};
  }
  s.description["fit"] = s.report.ToJson();
  s.description["bspline"] = {{"u_degree", s.q.u_degree()}, {"v_degree", s.q.v_degree()},
                              {"u_poles", s.q.u_poles()},   {"v_poles", s.q.v_poles()}};
  FL_RETURN_IF_ERROR(WriteJsonFile(dir / "surface" / "surface.json", s.description));
  FL_RETURN_IF_ERROR(recon::WriteStep(dir / "surface" / "Q.step", s.q, part.name));
  return s;
}

// Retrieval from the case library: route, best case, and the part's features (kept for the retain step).
struct Retrieved {
  std::optional<retrieval::PartFeatures> features;
  std::optional<kb::CaseRecord> best;
  std::optional<kb::CaseRecord> own;  // the part's own case (same uid), for an update
  std::string route = "default";
  double similarity = -1;
  json report = json::object();
};

Result<Retrieved> Retrieve(const PartSpec& part, const recon::BSplineSurface& q, const RunOptions& options,
                           const fs::path& data_dir) {
  Retrieved r;
  if (options.kb.empty()) {
    r.report = {{"route", {{"name", "default"}, {"similarity", nullptr}, {"flag_engineer", true},
                           {"rule", "no case library given (--kb): the default plan, flagged"}}},
                {"ranked", json::array()}};
    return r;
  }
  FL_ASSIGN_OR_RETURN(retrieval::FacetTaxonomies tax, retrieval::FacetTaxonomies::Load(data_dir / "taxonomies"));
  retrieval::FeatureOptions fo;
  fo.taxonomies = std::make_shared<const retrieval::FacetTaxonomies>(std::move(tax));
  auto extracted = retrieval::ExtractFeatures(DescriptionOf(part, part.toolpath), q, fo);
  if (!extracted.ok()) {
    return extracted.status().WithContext("the part's retrieval description (material, shape_family, finish_ra_um, "
                                          "machine.class in the part file)");
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
  r.report["library"] = options.kb;
  r.route = result.route;
  r.similarity = result.best_similarity;
  if (!result.ranked.empty()) {
    FL_ASSIGN_OR_RETURN(kb::CaseRecord best, library->GetCase(result.ranked.front().uid));
    r.best = std::move(best);
  }
  if (auto own = library->GetCase(part.name); own.ok()) r.own = std::move(own).value();
  return r;
}

// The surface part of a model's prediction at a grid of points on the nominal tool path (scallop left
// out: it is local to each pass and no mirror offset removes it), as a smooth field in mm.
Result<nc::SystematicField> PredictedField(const recon::BSplineSurface& q, const nc::Toolpath& nominal,
                                           const sim::Model& learned, std::uint64_t seed, json* report) {
  const sim::Model model = learned.WithoutNoise();
  FL_ASSIGN_OR_RETURN(metrology::ProbingPlan grid, metrology::PlanProbingGrid(q, 24, 24, 0.0));
  sim::VirtualMachineOptions vm;
  vm.tool_radius_mm = nominal.options.tool.radius_mm;
  vm.model = model;
  vm.seed = seed;
  FL_ASSIGN_OR_RETURN(sim::VirtualMachineResult predicted, sim::MachineAndProbe(nc::CutterLocationsOf(nominal), grid, vm));
  std::vector<nc::DeviationSample> samples;
  double peak = 0;
  for (std::size_t i = 0; i < grid.points.size(); ++i) {
    const double ds = predicted.truth[i].surface_um - predicted.truth[i].scallop_um;
    samples.push_back({.u = grid.points[i].u, .v = grid.points[i].v, .ds_um = ds});
    peak = std::max(peak, std::abs(ds));
  }
  FL_ASSIGN_OR_RETURN(nc::DeviationField field, nc::DeviationField::Fit(samples, {}, "learned model prediction"));
  *report = {{"grid", {24, 24}}, {"predicted_peak_um", peak}, {"model", model.ToJson()}};
  return field.AsSystematicField();
}

// Spatial lag and LISA cluster of the deviations (k-NN in (u, v), row-standardised), for the report.
Status AddLocalMoran(const std::vector<metrology::Deviation>& deviations, int k, std::uint64_t seed,
                     PointSet* points) {
  Eigen::VectorXd d(static_cast<Eigen::Index>(deviations.size()));
  for (std::size_t i = 0; i < deviations.size(); ++i) d(static_cast<Eigen::Index>(i)) = deviations[i].deviation_mm * 1e3;
  FL_ASSIGN_OR_RETURN(metrology::SpatialWeights w, metrology::UvKnnWeights(deviations, k));
  metrology::LocalMoranOptions lo;
  lo.permutations = 199;
  lo.seed = seed;
  FL_ASSIGN_OR_RETURN(metrology::LocalMoranResult lisa, metrology::LocalMoranI(d, w, lo));
  std::vector<double> lag(deviations.size()), cluster(deviations.size());
  for (std::size_t i = 0; i < deviations.size(); ++i) {
    lag[i] = lisa.lag(static_cast<Eigen::Index>(i));
    cluster[i] = static_cast<double>(static_cast<int>(lisa.cluster[i]));
  }
  points->SetScalar("lag_um", std::move(lag));
  points->SetScalar("lisa", std::move(cluster));
  return Status::Ok();
}

struct Machine {
  bool virtual_machine = true;
  std::string name;
  sim::Model model;                      // the profile's true effects (virtual)
  metrology::ProbeModel probe;           // the probe the machine really has (virtual)
  std::vector<std::string> measured;     // measured logs (real machine)
};

Result<Machine> ResolveMachine(const PartSpec& part, const RunOptions& options, const fs::path& data_dir,
                               const fs::path& dir) {
  Machine m;
  m.name = part.machine_name;
  m.probe = part.true_probe;
  if (!options.measured.empty()) {
    if (!options.machine.empty()) {
      return Status::BadInput(Where{.field = "--machine"}, "cannot be combined with --measured",
                              "give either a virtual machine or measured probe logs");
    }
    m.virtual_machine = false;
    FL_RETURN_IF_ERROR(MakeDirectories(dir / "inputs" / "measured"));
    for (std::size_t k = 0; k < options.measured.size(); ++k) {
      FL_ASSIGN_OR_RETURN(std::string text, ReadFile(options.measured[k]));
      const fs::path copy = dir / "inputs" / "measured" / ("loop-" + std::to_string(k) + ".csv");
      FL_RETURN_IF_ERROR(WriteFileAtomic(copy, text));
      m.measured.push_back(copy.string());
    }
    return m;
  }
  const std::string spec = options.machine.empty() ? "virtual" : options.machine;
  if (spec == "virtual" && !part.effects_given) {
    // The part's machine by name: its profile in data/machines/.
    return ResolveMachine(part, RunOptions{.machine = "virtual:" + part.machine_name}, data_dir, dir);
  }
  if (spec == "virtual") {
    m.model = part.effects.ToModel();
    FL_RETURN_IF_ERROR(WriteJsonFile(dir / "inputs" / "machine_profile.json",
                                     MachineProfile{m.name, "the part file's machine.effects", m.model, m.probe}.ToJson()));
    return m;
  }
  if (spec.rfind("virtual:", 0) != 0) {
    return Status::BadInput(Where{.field = "--machine"}, "unknown machine '" + spec + "'",
                            "use virtual, virtual:PROFILE or --measured LOG.csv");
  }
  FL_ASSIGN_OR_RETURN(MachineProfile profile, ReadMachineProfile(spec.substr(8), data_dir));
  m.name = profile.name;
  m.model = profile.model;
  if (profile.probe) m.probe = *profile.probe;
  FL_RETURN_IF_ERROR(WriteJsonFile(dir / "inputs" / "machine_profile.json", profile.ToJson()));
  return m;
}

struct PlanChoice {
  nc::ToolpathOptions plan;
  std::optional<sim::Model> learned;   // the case's model for this machine/tool/material
  double precompensation_scale = 0;
  bool flag_engineer = false;          // the default plan, or a correction that could not remove every defect
  std::string source;
  json report = json::object();
};

// The plan by route: the case's (direct), the simulation-corrected one (simulate), the part's own
// flagged default (default). The case's learned model is the baseline of the diagnosis and, when
// `learn`, the pre-compensation.
Result<PlanChoice> ChoosePlan(const PartSpec& part, const Retrieved& r, const recon::BSplineSurface& q,
                              const Machine& machine, const RunOptions& options, std::uint64_t seed,
                              const fs::path& dir) {
  PlanChoice c;
  c.plan = part.toolpath;
  if (r.route == "default" || !r.best) {
    c.source = "default plan (the part file's), flagged for an engineer";
    c.flag_engineer = true;
    c.report = {{"source", c.source}, {"route", r.route}};
    return c;
  }
  json notes;
  c.plan = PlanFromCase(*r.best, part, &notes);
  c.learned = LearnedModelOf(*r.best, machine.name, ToolKey(c.plan.tool.radius_mm), part.material);
  c.source = "case " + r.best->uid;
  c.precompensation_scale = c.learned && options.learn ? 1.0 : 0.0;
  c.report = {{"source", c.source}, {"route", r.route}, {"case_plan", notes},
              {"learned_model", c.learned ? c.learned->ToJson() : json(nullptr)}};
  if (r.route != "simulate") return c;

  // 0.80 ≤ A ≤ 0.95: simulate the case's plan on this part with the case's model and correct it.
  SimCorrectionInput in;
  in.surface = &q;
  in.case_plan = c.plan;
  in.tools = part.tools;
  in.flutes = part.flutes;
  if (c.learned) in.model = *c.learned;
  in.similarity = r.similarity;
  // e_rand: the random error the case's own run left (coverage factor × σ(d_u) of its last cycle), when
  // the case was retained by formloop run; else the GA's default.
  const json outcome = r.best->part.value("outcome", json::object());
  if (outcome.is_object() && outcome.contains("random_sigma_um") && outcome["random_sigma_um"].is_number()) {
    in.random_um = part.analysis.coverage_factor * outcome["random_sigma_um"].get<double>();
  }
  in.tolerance_mm = part.tolerance_mm;
  in.limits = part.limits;
  FL_ASSIGN_OR_RETURN(in.probing_plan, metrology::PlanProbingGrid(q, 10, 10, part.probe_inset_fraction));
  in.seed = seed;
  FL_ASSIGN_OR_RETURN(SimCorrectionResult corrected, RunSimulationCorrection(in));
  FL_RETURN_IF_ERROR(WriteJsonFile(dir / "sim_correction.json", corrected.ToJson()));
  if (corrected.defects_before.empty()) {
    // Nothing to correct: the case's plan is kept (the GA's optimum would only trade time for error
    // the case's plan already meets), pre-compensated as on the direct route.
    log::Info("[plan] simulation-correction: the case's plan has no predicted defect on this part; kept");
    c.source += ", simulation-checked (no predicted defect)";
  } else if (corrected.corrected) {
    // The GA may switch tools: the learned model belongs to the tool it was learned with.
    if (corrected.plan.tool.radius_mm != c.plan.tool.radius_mm) {
      c.learned = LearnedModelOf(*r.best, machine.name, ToolKey(corrected.plan.tool.radius_mm), part.material);
    }
    c.plan = corrected.plan;
    c.precompensation_scale = c.learned && options.learn ? corrected.precompensation_scale : 0.0;
    c.source += ", simulation-corrected";
  } else {
    log::Warn("simulation-correction could not remove every predicted defect: {}", corrected.why_not);
    c.source += ", simulation-correction failed (" + corrected.why_not + "), flagged";
    c.flag_engineer = true;
  }
  c.report["source"] = c.source;
  c.report["sim_correction"] = {{"defects_before", corrected.defects_before.size()},
                                {"defects_after", corrected.defects_after.size()},
                                {"corrected", corrected.corrected},
                                {"why_not", corrected.why_not}};
  return c;
}

struct LoopResult {
  LoopSummary summary;
  std::optional<metrology::FieldModel> systematic;
};

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

// Probe compensation, deviations, decomposition and the §8 evaluation of one cycle's probe log.
Result<LoopResult> AnalyseLoop(const PartSpec& part, const recon::BSplineSurface& q,
                               const metrology::ProbingPlan& plan, const fs::path& loop_dir, int loop,
                               bool another_loop_allowed, std::uint64_t seed,
                               std::vector<metrology::Deviation>* deviations_out) {
  // The analysis reads the log back from disk, as it would a real machine's.
  FL_ASSIGN_OR_RETURN(metrology::ProbeLog log_read, metrology::ReadProbeLog(loop_dir / "probe_log.csv"));
  FL_ASSIGN_OR_RETURN(std::vector<metrology::Deviation> deviations,
                      metrology::ComputeDeviations(q, plan, log_read, part.probe));
  FL_ASSIGN_OR_RETURN(metrology::Decomposition decomposition,
                      metrology::Decompose(deviations, q.domain(), part.analysis));
  PointSet points = metrology::DeviationsToPoints(deviations);
  std::vector<double> ds_um, df_um, du_um;
  for (std::size_t i = 0; i < deviations.size(); ++i) {
    ds_um.push_back(decomposition.systematic_mm[i] * 1e3);
    df_um.push_back(decomposition.fine_scale_mm[i] * 1e3);
    du_um.push_back(decomposition.random_mm[i] * 1e3);
  }
  points.SetScalar("systematic_um", std::move(ds_um));
  points.SetScalar("fine_scale_um", std::move(df_um));
  points.SetScalar("random_um", std::move(du_um));
  FL_RETURN_IF_ERROR(AddLocalMoran(deviations, part.analysis.neighbours, seed, &points));
  FL_RETURN_IF_ERROR(WritePoints(loop_dir / "deviations.csv", points, {.precision = 6}));
  FL_RETURN_IF_ERROR(WritePoints(loop_dir / "deviations.ply", points));

  FL_ASSIGN_OR_RETURN(const metrology::FormEvaluation evaluation,
                      metrology::EvaluateForm(decomposition, part.tolerance_mm));
  const metrology::DecompositionStep& chosen = decomposition.steps[static_cast<std::size_t>(decomposition.chosen_step)];
  LoopResult r;
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
    ls.decision = "out of tolerance but the error is random (constant model, offset not significant): "
                  "compensation cannot help";
  } else if (!compensate) {
    ls.decision = "out of tolerance after the last allowed loop (" + evaluation.decision + ")";
  } else {
    ls.decision = evaluation.decision;
  }
  log::Info("      deviation rms {:.2f} um; raw Moran z {:.2f}; model {} (residual z {:.2f}); d_s peak {:.2f} um;"
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
  analysis["decision_rule"] =
      "the decomposition's evaluation (spec/metrology.md §8): compensate by -d_s when the form error "
      "max|d_s| + k*sigma(d_u) exceeds the tolerance and d_s is significant (a non-constant model chosen by the "
      "residual-Moran ladder, or |mean| > 2.576 standard errors), while another loop is allowed";
  FL_RETURN_IF_ERROR(WriteJsonFile(loop_dir / "analysis.json", analysis));
  if (compensate) r.systematic = decomposition.systematic;
  if (deviations_out != nullptr) *deviations_out = std::move(deviations);
  return r;
}

// Everything the run produces, staged in `dir` (the .partial folder).
Status RunStages(const PartSpec& given_part, const RunOptions& options, const fs::path& dir, RunSummary* summary,
                 std::optional<kb::CaseRecord>* retained) {
  Stages stages(dir, options);
  const fs::path data_dir = options.data_dir.empty() ? retrieval::DefaultDataDir() : options.data_dir;
  summary->part = given_part.name;
  summary->surface = given_part.SurfaceName();
  summary->tolerance_um = given_part.tolerance_mm * 1e3;
  FL_RETURN_IF_ERROR(stages.Begin("1/9: inputs"));
  FL_RETURN_IF_ERROR(MakeDirectories(dir / "inputs"));
  FL_ASSIGN_OR_RETURN(const Machine machine, ResolveMachine(given_part, options, data_dir, dir));
  // Learned models are keyed by the machine the part is really cut on.
  PartSpec part = given_part;
  part.machine_name = machine.name;
  FL_RETURN_IF_ERROR(WriteJsonFile(dir / "inputs" / "part.json", part.ToJson()));
  FL_RETURN_IF_ERROR(WriteJsonFile(dir / "inputs" / "options.json",
                                   {{"kb", options.kb}, {"machine", options.machine}, {"measured", options.measured},
                                    {"retain", options.retain}, {"learn", options.learn}}));
  Rng seeds(part.seed);
  const std::uint64_t fit_seed = seeds.Fork();
  const std::uint64_t machine_seed = seeds.Fork();
  const std::uint64_t plan_seed = seeds.Fork();
  const std::uint64_t analysis_seed = seeds.Fork();

  // 1. Ideal surface.
  FL_RETURN_IF_ERROR(stages.Begin("2/9: surface"));
  log::Info("[surface] '{}': B-spline fit", part.SurfaceName());
  FL_ASSIGN_OR_RETURN(const Surface surface, BuildSurface(part, fit_seed, dir));
  const recon::BSplineSurface& q = surface.q;
  summary->fit_check_max_um = surface.report.check_max_mm * 1e3;
  log::Info("      fit rms {:.4f} um at samples; check max {:.4f} um at {} random points", surface.report.rms_mm * 1e3,
            surface.report.check_max_mm * 1e3, surface.report.n_check);

  // 2. Retrieval and routing.
  FL_RETURN_IF_ERROR(stages.Begin("3/9: retrieval"));
  FL_ASSIGN_OR_RETURN(const Retrieved retrieved, Retrieve(part, q, options, data_dir));
  FL_RETURN_IF_ERROR(WriteJsonFile(dir / "retrieval.json", retrieved.report));
  summary->route = retrieved.route;
  summary->similarity = retrieved.similarity;
  summary->flag_engineer = retrieved.route == "default";
  if (retrieved.best) summary->case_uid = retrieved.best->uid;
  log::Info("[retrieval] route {} (A = {:.4f}{})", retrieved.route, retrieved.similarity,
            retrieved.best ? ", case " + retrieved.best->uid : std::string());

  // 3. Plan.
  FL_RETURN_IF_ERROR(stages.Begin("4/9: plan"));
  FL_ASSIGN_OR_RETURN(const PlanChoice choice, ChoosePlan(part, retrieved, q, machine, options, plan_seed, dir));
  summary->plan_source = choice.source;
  summary->flag_engineer = summary->flag_engineer || choice.flag_engineer;
  const nc::ToolpathOptions& plan_options = choice.plan;
  log::Info("[plan] {}: ball r = {} mm, scallop {} um, feed {} mm/min", choice.source, plan_options.tool.radius_mm,
            plan_options.scallop_um, plan_options.feed_mm_per_min);

  // 4. Tool path, programs, probing plan and probing program.
  FL_RETURN_IF_ERROR(stages.Begin("5/9: nc"));
  FL_ASSIGN_OR_RETURN(nc::Toolpath nominal, nc::PlanRaster(q, plan_options));
  nc::PostOptions post;
  post.limits = part.limits;
  post.title = "formloop " + std::string(kVersion) + " part " + part.name + " loop 0, nominal";
  FL_ASSIGN_OR_RETURN(const nc::MoveList nominal_moves_list, nc::BuildMoveList(nominal));
  FL_ASSIGN_OR_RETURN(const std::string program, nc::Post(nominal_moves_list, part.dialect, post));
  const std::string extension(nc::FindPost(part.dialect)->FileExtension());
  const fs::path nominal_program_path = dir / "toolpath" / ("program" + extension);
  FL_RETURN_IF_ERROR(MakeDirectories(dir / "toolpath"));
  FL_RETURN_IF_ERROR(WriteFileAtomic(nominal_program_path, program));
  FL_RETURN_IF_ERROR(nc::WriteToolpathFile(dir / "toolpath" / "toolpath.csv", nominal));
  FL_RETURN_IF_ERROR(WriteJsonFile(dir / "toolpath" / "toolpath.json", nominal.ReportJson()));
  log::Info("      {} passes, {} CL points, {:.0f} s cutting", nominal.passes, nominal.points.size(), nominal.total_time_s);
  FL_ASSIGN_OR_RETURN(const metrology::ProbingPlan plan,
                      metrology::PlanProbingGrid(q, part.probe_nu, part.probe_nv, part.probe_inset_fraction));
  FL_RETURN_IF_ERROR(WriteJsonFile(dir / "toolpath" / "probing_plan.json", plan.ToJson()));
  nc::ProbeProgramOptions probe_options = part.probe_program;
  probe_options.post = post;
  probe_options.post.title = "formloop " + std::string(kVersion) + " probing program for part " + part.name;
  probe_options.safe_z_mm = nominal.safe_z_mm + part.probe.ball_radius_mm + part.probe_program.clearance_mm;
  FL_ASSIGN_OR_RETURN(const std::string probe_program, nc::PostProbing(plan, part.dialect, probe_options));
  FL_RETURN_IF_ERROR(WriteFileAtomic(dir / "toolpath" / ("probe" + extension), probe_program));

  // 5. Pre-compensation of what the case's learned model predicts (spec/simulation.md §4).
  FL_RETURN_IF_ERROR(stages.Begin("6/9: precompensation"));
  Field field;
  std::string current_program = program;
  fs::path current_program_path = nominal_program_path;
  json plan_json = choice.report;
  plan_json["toolpath"] = {{"tool_number", plan_options.tool.number}, {"tool_radius_mm", plan_options.tool.radius_mm},
                           {"scallop_um", plan_options.scallop_um}, {"raster_angle_deg", plan_options.raster_angle_deg},
                           {"feed_mm_per_min", plan_options.feed_mm_per_min}, {"spindle_rpm", plan_options.spindle_rpm}};
  if (choice.learned && choice.precompensation_scale > 0) {
    json pre;
    FL_ASSIGN_OR_RETURN(nc::SystematicField predicted, PredictedField(q, nominal, *choice.learned, plan_seed, &pre));
    const double scale = choice.precompensation_scale;
    field.terms.push_back([predicted, scale](double u, double v) { return scale * predicted(u, v); });
    nc::PostOptions post_pc = post;
    post_pc.title = "formloop " + std::string(kVersion) + " part " + part.name + " loop 0, pre-compensated";
    const fs::path pc_path = dir / "toolpath" / ("program_precompensated" + extension);
    FL_ASSIGN_OR_RETURN(nc::Compensation pc,
                        nc::WriteCompensatedProgram(nominal, program, field, "learned model of case " + summary->case_uid,
                                                    part.compensation, post_pc, pc_path,
                                                    dir / "toolpath" / "precompensation_side.csv", part.dialect));
    FL_ASSIGN_OR_RETURN(current_program, ReadFile(pc_path));
    current_program_path = pc_path;
    summary->precompensated = true;
    summary->precompensation_scale = scale;
    pre["scale"] = scale;
    pre["max_offset_um"] = pc.max_offset_um;
    pre["program"] = fs::relative(pc_path, dir).string();
    plan_json["precompensation"] = pre;
    log::Info("[precompensation] learned model of case {}: predicted peak {:.1f} um, scale {:.2f}, max offset {:.1f} um",
              summary->case_uid, pre["predicted_peak_um"].get<double>(), scale, pc.max_offset_um);
  } else {
    plan_json["precompensation"] = nullptr;
  }
  FL_RETURN_IF_ERROR(WriteJsonFile(dir / "plan.json", plan_json));

  // 6. Cycles: machine (or read the measured log), analyse, diagnose (cycle 0), compensate.
  const int max_loops = machine.virtual_machine ? part.max_loops : static_cast<int>(machine.measured.size());
  std::optional<sim::Diagnosis> diagnosis;
  // The nominal program as written: each compensated program is verified against it.
  FL_ASSIGN_OR_RETURN(const std::vector<nc::ProgramMove> nominal_moves,
                      nc::ReadProgram(program, part.dialect, nominal_program_path.string()));
  for (int loop = 0; loop < max_loops; ++loop) {
    const fs::path loop_dir = dir / ("loop-" + std::to_string(loop));
    FL_RETURN_IF_ERROR(MakeDirectories(loop_dir));
    FL_RETURN_IF_ERROR(stages.Begin("7/9: loop " + std::to_string(loop) + " machine"));
    FL_ASSIGN_OR_RETURN(std::vector<nc::ProgramMove> moves,
                        nc::ReadProgram(current_program, part.dialect, current_program_path.string()));
    const std::vector<sim::CutterLocation> cls = nc::CutterLocationsOfProgram(moves, plan_options.tool.radius_mm);
    if (machine.virtual_machine) {
      log::Info("[machine] loop {}: virtual machine '{}' cuts {}", loop, machine.name,
                fs::relative(current_program_path, dir).string());
      sim::VirtualMachineOptions vm;
      vm.tool_radius_mm = plan_options.tool.radius_mm;
      vm.model = machine.model;
      vm.true_probe = machine.probe;
      vm.seed = machine_seed + static_cast<std::uint64_t>(loop);
      FL_ASSIGN_OR_RETURN(sim::VirtualMachineResult machined, sim::MachineAndProbe(cls, plan, vm));
      FL_RETURN_IF_ERROR(metrology::WriteProbeLog(loop_dir / "probe_log.csv", machined.log));
      json machine_json = {{"machine", machine.name},
                           {"program", fs::relative(current_program_path, dir).string()},
                           {"cutter_locations", cls.size()},
                           {"points", machined.log.records.size()}};
      FL_RETURN_IF_ERROR(WriteJsonFile(loop_dir / "machine.json", machine_json));
    } else {
      FL_ASSIGN_OR_RETURN(std::string text, ReadFile(machine.measured[static_cast<std::size_t>(loop)]));
      FL_RETURN_IF_ERROR(WriteFileAtomic(loop_dir / "probe_log.csv", text));
      FL_RETURN_IF_ERROR(WriteJsonFile(loop_dir / "machine.json",
                                       {{"machine", machine.name},
                                        {"measured", machine.measured[static_cast<std::size_t>(loop)]},
                                        {"program", fs::relative(current_program_path, dir).string()}}));
    }

    FL_RETURN_IF_ERROR(stages.Begin("7/9: loop " + std::to_string(loop) + " analysis"));
    const bool another = loop + 1 < max_loops || !machine.virtual_machine;
    FL_ASSIGN_OR_RETURN(LoopResult result, AnalyseLoop(part, q, plan, loop_dir, loop, another,
                                                       analysis_seed + static_cast<std::uint64_t>(loop), nullptr));
    LoopSummary& ls = result.summary;

    if (loop == 0) {
      // What the simulation (the case's model) gets wrong on this part, and the extended model.
      FL_RETURN_IF_ERROR(stages.Begin("7/9: loop 0 diagnosis"));
      FL_ASSIGN_OR_RETURN(metrology::ProbeLog measured, metrology::ReadProbeLog(loop_dir / "probe_log.csv"));
      sim::ProbeDataInput input;
      input.surface = &q;
      input.cutter_locations = &cls;
      input.tool_radius_mm = plan_options.tool.radius_mm;
      input.plan = &plan;
      input.measured = &measured;
      input.probe = part.probe;
      const sim::Model baseline = choice.learned ? *choice.learned : sim::Model{};
      FL_ASSIGN_OR_RETURN(sim::Diagnosis d, sim::Diagnose(input, baseline, sim::DiagnoseOptions{}));
      FL_RETURN_IF_ERROR(MakeDirectories(loop_dir / "diagnosis"));
      json dj = d.ToJson();
      dj["baseline"] = choice.learned ? "learned model of case " + summary->case_uid : "no effects (no learned model)";
      FL_RETURN_IF_ERROR(WriteJsonFile(loop_dir / "diagnosis" / "diagnosis.json", dj));
      FL_RETURN_IF_ERROR(sim::WriteModel(loop_dir / "diagnosis" / "model.json", d.extended));
      for (const auto& c : d.causes) summary->causes.push_back(c.effect);
      log::Info("[diagnosis] {}", d.Summary());
      diagnosis = std::move(d);
    }

    if (result.systematic) {
      FL_RETURN_IF_ERROR(stages.Begin("7/9: loop " + std::to_string(loop) + " compensation"));
      const metrology::FieldModel fm = *result.systematic;
      field.terms.push_back([fm](double u, double v) { return fm.Evaluate(u, v); });
      const std::string source = "sum of the pre-compensation and the systematic fields of loops 0.." + std::to_string(loop);
      nc::PostOptions post_k = post;
      post_k.title = "formloop " + std::string(kVersion) + " part " + part.name + " loop " + std::to_string(loop + 1) +
                     ", mirror-compensated";
      const fs::path next_program = loop_dir / ("program_compensated" + extension);
      FL_ASSIGN_OR_RETURN(nc::Compensation compensation,
                          nc::WriteCompensatedProgram(nominal, program, field, source, part.compensation, post_k,
                                                      next_program, loop_dir / "compensation_side.csv", part.dialect));
      FL_ASSIGN_OR_RETURN(std::string compensated_program, ReadFile(next_program));
      FL_ASSIGN_OR_RETURN(std::vector<nc::ProgramMove> compensated_moves,
                          nc::ReadProgram(compensated_program, part.dialect, next_program.string()));
      FL_ASSIGN_OR_RETURN(double disagreement_um,
                          nc::VerifyCompensation(nominal_moves, compensated_moves, compensation));
      FL_RETURN_IF_ERROR(WriteJsonFile(loop_dir / "compensation.json",
                                       {{"source", compensation.source},
                                        {"cl_points", compensation.entries.size()},
                                        {"max_offset_um", compensation.max_offset_um},
                                        {"side_file_check_max_disagreement_um", disagreement_um},
                                        {"program", fs::relative(next_program, dir).string()}}));
      log::Info("      compensated program written: max offset {:.2f} um; side-file check {:.3f} um",
                compensation.max_offset_um, disagreement_um);
      ls.compensated = true;
      current_program = std::move(compensated_program);
      current_program_path = next_program;
    }
    summary->loops.push_back(ls);
    if (!ls.compensated) break;  // measured logs: the next log (if given) measures the compensated cut
  }
  summary->within_tolerance = summary->loops.back().within_tolerance;

  // 7. Retain: the case the library will hold (committed by RunPart after everything else is written).
  FL_RETURN_IF_ERROR(stages.Begin("8/9: retain"));
  if (!options.kb.empty() && options.retain) {
    RetainInput in;
    in.part = &part;
    in.features = &*retrieved.features;
    in.plan = plan_options;
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
      in.learned_provenance = {{"part", part.name},
                               {"run", options.out.string()},
                               {"data", "loop-0/probe_log.csv"},
                               {"points", diagnosis->n},
                               {"heldout_rms_before_um", diagnosis->heldout_rms_before_um},
                               {"heldout_rms_after_um", diagnosis->heldout_rms_after_um}};
    }
    if (retrieved.own) in.existing = &*retrieved.own;
    // A part cut on the virtual machine can be run again (the leave-one-out of app/route_calibration.h); a
    // measured one cannot.
    if (options.measured.empty()) in.rerun = {{"part", part.ToJson()}, {"machine", options.machine}};
    FL_ASSIGN_OR_RETURN(kb::CaseRecord record, MakeRetainedCase(in));
    FL_RETURN_IF_ERROR(WriteJsonFile(dir / "retain.json",
                                     {{"library", options.kb},
                                      {"action", retrieved.own ? "update" : "add"},
                                      {"uid", record.uid},
                                      {"learned_model", in.learned ? in.learned->ToJson() : json(nullptr)},
                                      {"case", record.ToJson()}}));
    summary->retained = (retrieved.own ? "updated " : "added ") + record.uid;
    *retained = std::move(record);
  }
  // 8. Summary and report.
  FL_RETURN_IF_ERROR(stages.Begin("9/9: report"));
  json summary_json = summary->ToJson();
  summary_json["part_file"] = options.part_source;
  FL_RETURN_IF_ERROR(WriteJsonFile(dir / "summary.json", summary_json));
  if (options.report) FL_RETURN_IF_ERROR(WriteRunReport(dir, dir / "report.html"));

  stages.End();
  return Status::Ok();
}

// One transaction for the case, then the GHSOM insertion (a failure there leaves it stale, not wrong).
Status CommitRetained(const std::string& kb_path, const kb::CaseRecord& record) {
  FL_ASSIGN_OR_RETURN(auto library, kb::Library::Open(kb_path));
  FL_ASSIGN_OR_RETURN(long long changes_before, library->ChangeCounter());
  FL_RETURN_IF_ERROR(library->AddCase(record, /*replace=*/true));
  auto inserted = retrieval::InsertCaseIntoGhsom(*library, record, changes_before);
  if (!inserted.ok()) log::Warn("case {} not inserted into the GHSOM: {}", record.uid, inserted.status().ToString());
  log::Info("[retain] case {} stored in {}", record.uid, kb_path);
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
  for (const auto& l : loops) loops_json.push_back(LoopJson(l));
  const int to_tolerance = LoopsToTolerance();
  return {{"formloop_version", kVersion},
          {"part", part},
          {"surface", surface},
          {"tolerance_um", tolerance_um},
          {"fit_check_max_um", fit_check_max_um},
          {"route",
           {{"name", route},
            {"similarity", similarity >= 0 ? json(similarity) : json(nullptr)},
            {"case_uid", case_uid.empty() ? json(nullptr) : json(case_uid)},
            {"flag_engineer", flag_engineer}}},
          {"plan_source", plan_source},
          {"precompensated", precompensated},
          {"precompensation_scale", precompensation_scale},
          {"causes", causes},
          {"loops", loops_json},
          {"within_tolerance", within_tolerance},
          {"loops_to_tolerance", to_tolerance >= 0 ? json(to_tolerance) : json(nullptr)},
          {"retained", retained}};
}

Result<RunSummary> RunPart(const PartSpec& part, const RunOptions& options) {
  const fs::path out = options.out;
  if (out.empty()) return Status::BadInput(Where{.field = "--out"}, "no run folder given");
  std::error_code ec;
  if (fs::exists(out, ec) && !options.force) {
    return Status::BadInput(Where{.field = "--out"}, "run folder '" + out.string() + "' already exists",
                            "choose another folder or pass --force to replace it");
  }
  if (out.has_parent_path() && !fs::exists(out.parent_path(), ec)) {
    FL_RETURN_IF_ERROR(MakeDirectories(out.parent_path()));
  }
  fs::path partial = out;
  partial += ".partial";
  fs::path failed = out;
  failed += ".failed";
  if (fs::exists(partial / "status.json", ec)) {
    auto previous = ReadJsonFile(partial / "status.json");
    log::Warn("an incomplete run of '{}' was found in {} (stopped at: {}); starting it again", part.name,
              partial.string(), previous.ok() ? previous->value("stage", "?") : "?");
  }
  fs::remove_all(partial, ec);
  FL_RETURN_IF_ERROR(MakeDirectories(partial));
  FL_RETURN_IF_ERROR(log::StartFileLog(partial / "formloop.log"));
  log::Info("formloop {} run of part '{}' into {}", kVersion, part.name, out.string());

  RunSummary summary;
  summary.out = out;
  std::optional<kb::CaseRecord> retained;
  Status status = RunStages(part, options, partial, &summary, &retained);
  // The library changes last, in one transaction, after every file of the run is written.
  if (status.ok() && retained) {
    const auto start = std::chrono::steady_clock::now();
    status = CommitRetained(options.kb, *retained);
    if (options.on_stage) {
      options.on_stage("retain commit", std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count());
    }
  }
  if (status.ok()) status = WriteJsonFile(partial / "status.json", {{"state", "complete"}});
  if (status.ok()) {
    log::Info("run complete: {} after {} cycle(s)", summary.within_tolerance ? "within tolerance" : "NOT within tolerance",
              summary.loops.size());
  } else {
    log::Error("run failed: {}", status.ToString());
  }
  log::StopFileLog();
  if (!status.ok()) {
    fs::remove_all(failed, ec);
    fs::rename(partial, failed, ec);
    return status.WithContext("run of part '" + part.name + "' (log and partial outputs in " + failed.string() + ")");
  }
  fs::remove_all(out, ec);
  fs::remove_all(failed, ec);
  fs::rename(partial, out, ec);
  if (ec) return Status::IoError("cannot rename '" + partial.string() + "' to '" + out.string() + "': " + ec.message());
  return summary;
}

}  // namespace formloop::app
