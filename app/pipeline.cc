#include "app/pipeline.h"

#include <unistd.h>

#include "core/atomic_file.h"
#include "core/json_io.h"
#include "core/log.h"
#include "core/point_io.h"
#include "core/random.h"
#include "metrology/deviations.h"
#include "nc-gen/toolpath_io.h"
#include "reconstruction/analytic_surface.h"

namespace formloop::app {
namespace fs = std::filesystem;
namespace {

constexpr const char* kVersion = "0.1.0";

// Cutter locations as the program commands them: every feed move, ball centre = tip + r ẑ, path
// length and time accumulated over feed moves.
std::vector<sim::CutterLocation> CutterLocationsFromProgram(const std::vector<nc::ProgramMove>& moves,
                                                            double radius_mm) {
  std::vector<sim::CutterLocation> out;
  double length = 0, time = 0;
  const nc::ProgramMove* previous = nullptr;
  for (const auto& m : moves) {
    if (!m.rapid) {
      if (previous != nullptr && !previous->rapid) {
        const double d = (m.tip - previous->tip).norm();
        length += d;
        time += d / (m.feed_mm_per_min / 60.0);
      }
      sim::CutterLocation cl;
      cl.centre = m.tip + radius_mm * Eigen::Vector3d::UnitZ();
      cl.path_length_mm = length;
      cl.time_s = time;
      cl.line = m.line;
      cl.fed_from_previous = previous != nullptr && !previous->rapid;
      out.push_back(cl);
    }
    previous = &m;
  }
  return out;
}

struct Field {
  std::vector<metrology::FieldModel> terms;  // one per compensated loop
  double operator()(double u, double v) const {
    double sum = 0;
    for (const auto& t : terms) sum += t.Evaluate(u, v);
    return sum;
  }
};

Status RunStages(const PartSpec& part, const fs::path& dir, RunSummary* summary) {
  summary->part = part.name;
  summary->surface = part.surface_reference;
  summary->tolerance_um = part.tolerance_mm * 1e3;
  FL_RETURN_IF_ERROR(MakeDirectories(dir / "inputs"));
  FL_RETURN_IF_ERROR(WriteJsonFile(dir / "inputs" / "part.json", part.ToJson()));
  Rng seeds(part.seed);
  const std::uint64_t fit_seed = seeds.Fork();
  const std::uint64_t machine_seed = seeds.Fork();

  // 1. Ideal surface: sample the reference surface, fit a B-spline with OpenCASCADE, export STEP.
  log::Info("[1/4] surface '{}': sampling {}×{} and fitting a B-spline", part.surface_reference, part.fit_samples_u,
            part.fit_samples_v);
  FL_ASSIGN_OR_RETURN(std::unique_ptr<recon::AnalyticSurface> reference,
                      recon::MakeReferenceSurface(part.surface_reference));
  FL_RETURN_IF_ERROR(MakeDirectories(dir / "surface"));
  FL_RETURN_IF_ERROR(
      WritePoints(dir / "surface" / "samples.csv", recon::SampleGridPoints(*reference, part.fit_samples_u, part.fit_samples_v)));
  recon::FitReport fit_report;
  FL_ASSIGN_OR_RETURN(recon::BSplineSurface q,
                      recon::FitAnalytic(*reference, part.fit_samples_u, part.fit_samples_v, part.fit,
                                         part.fit_check_points, fit_seed, &fit_report));
  summary->fit_check_max_um = fit_report.check_max_mm * 1e3;
  nlohmann::json surface_json = {{"reference", reference->name()},
                                 {"description", reference->description()},
                                 {"fit", fit_report.ToJson()},
                                 {"bspline",
                                  {{"u_degree", q.u_degree()},
                                   {"v_degree", q.v_degree()},
                                   {"u_poles", q.u_poles()},
                                   {"v_poles", q.v_poles()}}}};
  FL_RETURN_IF_ERROR(WriteJsonFile(dir / "surface" / "surface.json", surface_json));
  FL_RETURN_IF_ERROR(recon::WriteStep(dir / "surface" / "Q.step", q, part.name));
  log::Info("      fit rms {:.4f} um, max {:.4f} um at samples; check max {:.4f} um at {} random points",
            fit_report.rms_mm * 1e3, fit_report.max_mm * 1e3, fit_report.check_max_mm * 1e3, fit_report.n_check);

  // 2. Tool path, program, probing plan and probing program.
  log::Info("[2/4] tool path: ball r = {} mm, scallop target {} um", part.toolpath.tool.radius_mm,
            part.toolpath.scallop_um);
  FL_ASSIGN_OR_RETURN(nc::Toolpath nominal, nc::PlanRaster(q, part.toolpath));
  nc::PostOptions post;
  post.limits = part.limits;
  post.title = "formloop " + std::string(kVersion) + " part " + part.name + " loop 0, nominal";
  FL_ASSIGN_OR_RETURN(const nc::MoveList nominal_moves_list, nc::BuildMoveList(nominal));
  FL_ASSIGN_OR_RETURN(std::string program, nc::Post(nominal_moves_list, part.dialect, post));
  // Program files carry the dialect's extension (.ngc LinuxCNC, .nc Fanuc, .h Heidenhain, .mpf Sinumerik).
  const std::string extension(nc::FindPost(part.dialect)->FileExtension());
  const fs::path nominal_program_path = dir / "toolpath" / ("program" + extension);
  FL_RETURN_IF_ERROR(MakeDirectories(dir / "toolpath"));
  FL_RETURN_IF_ERROR(WriteFileAtomic(nominal_program_path, program));
  FL_RETURN_IF_ERROR(nc::WriteToolpathFile(dir / "toolpath" / "toolpath.csv", nominal));
  FL_RETURN_IF_ERROR(WriteJsonFile(dir / "toolpath" / "toolpath.json", nominal.ReportJson()));
  log::Info("      {} passes, {} CL points, step-over {:.3f}..{:.3f} mm, {:.0f} s cutting", nominal.passes,
            nominal.points.size(), nominal.min_step_over_mm, nominal.max_step_over_mm, nominal.total_time_s);
  FL_ASSIGN_OR_RETURN(metrology::ProbingPlan plan,
                      metrology::PlanProbingGrid(q, part.probe_nu, part.probe_nv, part.probe_inset_fraction));
  FL_RETURN_IF_ERROR(WriteJsonFile(dir / "toolpath" / "probing_plan.json", plan.ToJson()));
  nc::ProbeProgramOptions probe_options = part.probe_program;
  probe_options.post = post;
  probe_options.post.title = "formloop " + std::string(kVersion) + " probing program for part " + part.name;
  probe_options.safe_z_mm = nominal.safe_z_mm + part.probe.ball_radius_mm + part.probe_program.clearance_mm;
  FL_ASSIGN_OR_RETURN(std::string probe_program, nc::PostProbing(plan, part.dialect, probe_options));
  FL_RETURN_IF_ERROR(WriteFileAtomic(dir / "toolpath" / ("probe" + extension), probe_program));

  // 3/4. Loops: machine the current program, probe, analyse, compensate when needed.
  Field field;
  std::string current_program = program;
  fs::path current_program_path = nominal_program_path;
  for (int loop = 0; loop < part.max_loops; ++loop) {
    const fs::path loop_dir = dir / ("loop-" + std::to_string(loop));
    FL_RETURN_IF_ERROR(MakeDirectories(loop_dir));
    log::Info("[3/4] loop {}: virtual machining of {}", loop, fs::relative(current_program_path, dir).string());
    FL_ASSIGN_OR_RETURN(std::vector<nc::ProgramMove> moves,
                        nc::ReadProgram(current_program, part.dialect, current_program_path.string()));
    const std::vector<sim::CutterLocation> cls = CutterLocationsFromProgram(moves, part.toolpath.tool.radius_mm);
    sim::VirtualMachineOptions vm;
    vm.tool_radius_mm = part.toolpath.tool.radius_mm;
    vm.effects = part.effects;
    vm.true_probe = part.true_probe;
    vm.seed = machine_seed + static_cast<std::uint64_t>(loop);
    FL_ASSIGN_OR_RETURN(sim::VirtualMachineResult machined, sim::MachineAndProbe(cls, plan, vm));
    FL_RETURN_IF_ERROR(metrology::WriteProbeLog(loop_dir / "probe_log.csv", machined.log));
    nlohmann::json machine_json = machined.ReportJson();
    machine_json["program"] = fs::relative(current_program_path, dir).string();
    machine_json["cutter_locations"] = cls.size();
    machine_json["effects"] = part.effects.ToJson();
    FL_RETURN_IF_ERROR(WriteJsonFile(loop_dir / "machine.json", machine_json));

    log::Info("[4/4] loop {}: probe compensation, deviations, Moran's I, decomposition", loop);
    // The analysis reads the log back from disk, as it would a real machine's.
    FL_ASSIGN_OR_RETURN(metrology::ProbeLog log_read, metrology::ReadProbeLog(loop_dir / "probe_log.csv"));
    FL_ASSIGN_OR_RETURN(std::vector<metrology::Deviation> deviations,
                        metrology::ComputeDeviations(q, plan, log_read, part.probe));
    FL_ASSIGN_OR_RETURN(metrology::Decomposition decomposition,
                        metrology::Decompose(deviations, q.domain(), part.analysis));
    PointSet points = metrology::DeviationsToPoints(deviations);
    std::vector<double> ds_um, du_um;
    for (std::size_t i = 0; i < deviations.size(); ++i) {
      ds_um.push_back(decomposition.systematic_mm[i] * 1e3);
      du_um.push_back(decomposition.random_mm[i] * 1e3);
    }
    points.SetScalar("systematic_um", std::move(ds_um));
    points.SetScalar("random_um", std::move(du_um));
    FL_RETURN_IF_ERROR(WritePoints(loop_dir / "deviations.csv", points, {.precision = 6}));
    FL_RETURN_IF_ERROR(WritePoints(loop_dir / "deviations.ply", points));

    // The decision is the §8 evaluation of the decomposition against the part's tolerance.
    FL_ASSIGN_OR_RETURN(const metrology::FormEvaluation evaluation,
                        metrology::EvaluateForm(decomposition, part.tolerance_mm));
    const metrology::DecompositionStep& chosen =
        decomposition.steps[static_cast<std::size_t>(decomposition.chosen_step)];
    LoopSummary ls;
    ls.index = loop;
    ls.form_error_um = decomposition.form_error_um;
    ls.systematic_peak_um = decomposition.systematic_peak_um;
    ls.random_sigma_um = decomposition.random_sigma_um;
    ls.raw_moran_z = decomposition.raw.z_normality;
    ls.field_degree = decomposition.systematic.degree();
    ls.within_tolerance = evaluation.within_tolerance;
    ls.chosen_model = decomposition.systematic.name();
    ls.residual_moran_z = chosen.residual_moran_z;
    ls.residual_independent = decomposition.independent;
    ls.systematic_significant = evaluation.systematic_significant;
    ls.compensation_advised = evaluation.compensate;
    nlohmann::json analysis = decomposition.ToJson();
    analysis["tolerance_um"] = part.tolerance_mm * 1e3;
    analysis["within_tolerance"] = ls.within_tolerance;
    analysis["evaluation"] = evaluation.ToJson();
    log::Info("      deviation rms {:.2f} um; raw Moran z {:.2f}; model {} (residual z {:.2f}, {}); d_s peak {:.2f} um;"
              " sigma(d_u) {:.2f} um; form error {:.2f} um vs tolerance {:.1f} um",
              decomposition.deviation_rms_um, decomposition.raw.z_normality, ls.chosen_model, ls.residual_moran_z,
              ls.residual_independent ? "independent" : "still correlated", decomposition.systematic_peak_um,
              decomposition.random_sigma_um, decomposition.form_error_um, part.tolerance_mm * 1e3);

    const bool compensate = evaluation.compensate && loop + 1 < part.max_loops;
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
    analysis["decision"] = ls.decision;
    analysis["compensate"] = compensate;
    analysis["decision_rule"] =
        "the decomposition's evaluation (spec/metrology.md §8): compensate by -d_s when the form error "
        "max|d_s| + k*sigma(d_u) exceeds the tolerance and d_s is significant (a non-constant model chosen by the "
        "residual-Moran ladder, or |mean| > 2.576 standard errors), while another loop is allowed";
    log::Info("      decision: {}", ls.decision);
    FL_RETURN_IF_ERROR(WriteJsonFile(loop_dir / "analysis.json", analysis));
    if (compensate) {
      field.terms.push_back(decomposition.systematic);
      const std::string source = "sum of systematic fields of loops 0.." + std::to_string(loop);
      nc::PostOptions post_k = post;
      post_k.title = "formloop " + std::string(kVersion) + " part " + part.name + " loop " + std::to_string(loop + 1) +
                     ", mirror-compensated";
      // Compensate, post, check against the nominal program and the field, then write program and side
      // file (both or neither; a refusal above the offset limit writes nothing).
      const fs::path next_program = loop_dir / ("program_compensated" + extension);
      FL_ASSIGN_OR_RETURN(nc::Compensation compensation,
                          nc::WriteCompensatedProgram(nominal, program, field, source, part.compensation, post_k,
                                                      next_program, loop_dir / "compensation_side.csv",
                                                      part.dialect));
      FL_ASSIGN_OR_RETURN(std::string compensated_program, ReadFile(next_program));
      FL_ASSIGN_OR_RETURN(std::vector<nc::ProgramMove> nominal_moves,
                          nc::ReadProgram(program, part.dialect, nominal_program_path.string()));
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
      current_program = compensated_program;
      current_program_path = next_program;
    }
    summary->loops.push_back(ls);
    if (!compensate) break;
  }
  summary->within_tolerance = summary->loops.back().within_tolerance;
  return Status::Ok();
}

}  // namespace

nlohmann::json RunSummary::ToJson() const {
  nlohmann::json loops_json = nlohmann::json::array();
  for (const auto& l : loops) {
    loops_json.push_back({{"loop", l.index},
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
                          {"systematic_significant", l.systematic_significant},
                          {"compensation_advised", l.compensation_advised},
                          {"decision", l.decision}});
  }
  return {{"formloop_version", kVersion},
          {"part", part},
          {"surface", surface},
          {"tolerance_um", tolerance_um},
          {"fit_check_max_um", fit_check_max_um},
          {"loops", loops_json},
          {"within_tolerance", within_tolerance}};
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
  fs::remove_all(partial, ec);
  FL_RETURN_IF_ERROR(MakeDirectories(partial));
  FL_RETURN_IF_ERROR(log::StartFileLog(partial / "formloop.log"));
  log::Info("formloop {} run of part '{}' into {}", kVersion, part.name, out.string());

  RunSummary summary;
  summary.out = out;
  Status status = RunStages(part, partial, &summary);
  if (status.ok()) {
    nlohmann::json summary_json = summary.ToJson();
    summary_json["part_file"] = options.part_source;
    status = WriteJsonFile(partial / "summary.json", summary_json);
  }
  if (status.ok()) {
    log::Info("run complete: {} after {} loop(s)", summary.within_tolerance ? "within tolerance" : "NOT within tolerance",
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
