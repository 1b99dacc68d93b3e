#include "app/surface_fit.h"

#include <cmath>
#include <filesystem>
#include <iostream>
#include <memory>
#include <system_error>

#include "core/atomic_file.h"
#include "core/log.h"
#include "core/output_file.h"
#include "core/point_io.h"
#include "core/random.h"
#include "core/work_estimate.h"
#include "reconstruction/analytic_surface.h"
#include "reconstruction/foot_point.h"
#include "reconstruction/quadric_fit.h"
#include "reconstruction/trim.h"

namespace formloop::app {
namespace {

namespace fs = std::filesystem;

constexpr const char* kAnalyticPrefix = "analytic:";
// Samples per side of an analytic surface for the grid method when --grid is not given.
constexpr int kDefaultAnalyticGrid = 50;

struct MethodName {
  FitMethod method;
  const char* name;
};
constexpr MethodName kMethods[] = {
    {FitMethod::kCad, "cad"},
    {FitMethod::kGrid, "grid"},
    {FitMethod::kScattered, "scattered"},
    {FitMethod::kAdaptive, "adaptive"},
    {FitMethod::kQuadricAlgebraic, "quadric-algebraic"},
    {FitMethod::kQuadricGeometric, "quadric-geometric"},
};

bool IsScattered(FitMethod m) { return m == FitMethod::kScattered || m == FitMethod::kAdaptive; }

nlohmann::json DomainJson(const recon::ParamDomain& d) {
  return {{"u_min", d.u_min}, {"u_max", d.u_max}, {"v_min", d.v_min}, {"v_max", d.v_max}};
}

nlohmann::json SurfaceJson(const recon::BSplineSurface& q) {
  return {{"degree", {{"u", q.u_degree()}, {"v", q.v_degree()}}},
          {"poles", {{"u", q.u_poles()}, {"v", q.v_poles()}}},
          {"domain", DomainJson(q.domain())}};
}

Status CheckOutputs(const FitRequest& request) {
  if (request.out_step.empty()) {
    return Status::BadInput(Where{.field = "--out"}, "no output STEP file given", "add --out Q.step");
  }
  const auto format = recon::CadFormatFromPath(request.out_step);
  if (!format.ok() || *format != recon::CadFormat::kStep) {
    return Status::BadInput(Where{.file = request.out_step, .field = "--out"}, "the output must be a STEP file",
                            "name it *.step or *.stp");
  }
  if (!request.out_report.empty() && fs::path(request.out_report).extension() != ".json") {
    return Status::BadInput(Where{.file = request.out_report, .field = "--report"}, "the report is JSON",
                            "name it *.json");
  }
  const bool file_input = request.input.rfind("analytic:", 0) != 0;
  return CheckOutputFiles({{"--out", request.out_step}, {"--report", request.out_report}},
                          {{"INPUT", file_input ? request.input : std::string()}}, request.force);
}

// A row-major grid layout for `n` points: the requested one, or a square one when none is given.
Result<std::pair<int, int>> GridLayout(const FitRequest& request, std::size_t n, std::vector<std::string>* notes) {
  if (request.grid_nu > 0 || request.grid_nv > 0) {
    if (request.grid_nu < 2 || request.grid_nv < 2 ||
        static_cast<std::size_t>(request.grid_nu) * static_cast<std::size_t>(request.grid_nv) != n) {
      return Status::BadInput(Where{.file = request.input, .field = "--grid"},
                              "a " + std::to_string(request.grid_nu) + " x " + std::to_string(request.grid_nv) +
                                  " grid does not match the " + std::to_string(n) + " points of the file",
                              "give --grid NUxNV with NU * NV = the number of points (NU points per row)");
    }
    return std::make_pair(request.grid_nu, request.grid_nv);
  }
  const int side = static_cast<int>(std::lround(std::sqrt(static_cast<double>(n))));
  if (side < 2 || static_cast<std::size_t>(side) * static_cast<std::size_t>(side) != n) {
    return Status::BadInput(Where{.file = request.input, .field = "--grid"},
                            std::to_string(n) + " points are not a square grid and no layout was given",
                            "give --grid NUxNV (NU points per row, rows one after the other), or use "
                            "--method scattered");
  }
  notes->push_back("grid layout inferred from the point count: " + std::to_string(side) + " x " + std::to_string(side) +
                   ", row-major");
  return std::make_pair(side, side);
}

// Parameters of a point grid: mean chord length along rows (u) and along columns (v), in mm, so
// that Q's parameters read roughly as arc length.
recon::GridSamples GridFromPoints(std::vector<Eigen::Vector3d> points, int nu, int nv) {
  double lu = 0, lv = 0;
  for (int j = 0; j < nv; ++j) {
    for (int i = 0; i + 1 < nu; ++i) lu += (points[j * nu + i + 1] - points[j * nu + i]).norm();
  }
  for (int i = 0; i < nu; ++i) {
    for (int j = 0; j + 1 < nv; ++j) lv += (points[(j + 1) * nu + i] - points[j * nu + i]).norm();
  }
  recon::GridSamples samples;
  samples.nu = nu;
  samples.nv = nv;
  samples.domain = {0, std::max(lu / nv, 1e-9), 0, std::max(lv / nu, 1e-9)};
  samples.points = std::move(points);
  return samples;
}

// Distance from the exact surface to Q at seeded random parameters (the fit check).
Status CheckAgainstTruth(const recon::AnalyticSurface& truth, const recon::BSplineSurface& q, int n,
                         unsigned long long seed, recon::FitReport* report) {
  if (n <= 0) return Status::Ok();
  FL_ASSIGN_OR_RETURN(const recon::FootPointProjector projector, recon::FootPointProjector::Build(q));
  const recon::ParamDomain dom = truth.domain();
  Rng rng(seed);
  double sum2 = 0, max = -1;
  for (int k = 0; k < n; ++k) {
    const double u = rng.Uniform(dom.u_min, dom.u_max), v = rng.Uniform(dom.v_min, dom.v_max);
    const Eigen::Vector3d p = truth.Point(u, v);
    FL_ASSIGN_OR_RETURN(const recon::FootPoint foot, projector.Project(p));
    const double e = (p - foot.foot).norm();
    sum2 += e * e;
    if (e > max) {
      max = e;
      report->check_max_at = p;
    }
  }
  report->n_check = n;
  report->check_rms_mm = std::sqrt(sum2 / n);
  report->check_max_mm = max;
  return Status::Ok();
}

Result<FitOutcome> FitCad(const FitRequest& request, FitMethod method) {
  if (method != FitMethod::kCad) {
    return Status::BadInput(Where{.file = request.input, .field = "--method"},
                            "a CAD face is taken as it is; --method " + FitMethodName(method) + " fits points",
                            "leave out --method (or use --method cad), or sample the face into points first");
  }
  FL_ASSIGN_OR_RETURN(recon::CadFace face, recon::ReadCadFace(request.input, request.face));
  recon::FitReport fit;
  fit.method = "cad";
  fit.residual = face.converted ? "none: the face's " + face.info.surface_type +
                                      " was converted exactly to a B-spline by GeomConvert over the face's "
                                      "parameter box"
                                : "none: the face is a B-spline surface and is taken as it is";
  if (face.converted) fit.notes.push_back("the face's trimming curves are not kept; Q covers its parameter box");
  FitOutcome outcome;
  outcome.surface = face.surface;
  outcome.report = {{"input",
                     {{"kind", "cad"},
                      {"file", request.input},
                      {"face_index", face.info.index},
                      {"face_name", face.info.name},
                      {"surface_type", face.info.surface_type},
                      {"reversed", request.face.reverse},
                      {"file_unit", face.file_unit},
                      {"unit_of_q", "mm"}}},
                    {"fit", fit.ToJson()}};
  return outcome;
}

Result<FitOutcome> FitPoints(const FitRequest& request, FitMethod method, const std::vector<Eigen::Vector3d>& points,
                             nlohmann::json input_json, const recon::AnalyticSurface* truth) {
  if (method == FitMethod::kCad) {
    return Status::BadInput(Where{.file = request.input, .field = "--method"}, "--method cad needs a STEP or IGES file",
                            "use grid, scattered or a quadric method");
  }
  recon::FitReport fit;
  recon::BSplineSurface q;
  nlohmann::json extra;
  if (method == FitMethod::kGrid) {
    recon::GridSamples samples;
    if (truth != nullptr) {
      // FitSurface sampled the truth on this grid already (row-major over its domain).
      samples.nu = request.grid_nu > 0 ? request.grid_nu : kDefaultAnalyticGrid;
      samples.nv = request.grid_nv > 0 ? request.grid_nv : kDefaultAnalyticGrid;
      samples.domain = truth->domain();
      samples.points = points;
    } else {
      std::vector<std::string> notes;
      FL_ASSIGN_OR_RETURN(const auto layout, GridLayout(request, points.size(), &notes));
      samples = GridFromPoints(points, layout.first, layout.second);
      fit.notes = notes;
    }
    std::vector<std::string> notes = fit.notes;
    FL_ASSIGN_OR_RETURN(q, recon::FitGrid(samples, request.grid, &fit));
    fit.notes.insert(fit.notes.begin(), notes.begin(), notes.end());
    extra["grid"] = {{"nu", samples.nu}, {"nv", samples.nv}, {"tolerance_mm", request.grid.tolerance_mm}};
  } else if (IsScattered(method)) {
    recon::ScatteredFitOptions options = request.scattered;
    options.adaptive = method == FitMethod::kAdaptive;
    FL_ASSIGN_OR_RETURN(q, recon::FitScattered(points, options, &fit));
  } else {
    FL_ASSIGN_OR_RETURN(recon::QuadricFit quadric, recon::FitQuadricAlgebraic(points));
    nlohmann::json quadrics = {{"algebraic", quadric.ToJson()}};
    if (method == FitMethod::kQuadricGeometric) {
      FL_ASSIGN_OR_RETURN(recon::QuadricFit geometric, recon::FitQuadricGeometric(points, quadric));
      quadrics["geometric"] = geometric.ToJson();
      quadric = geometric;
    }
    extra["quadric"] = quadrics;
    FL_ASSIGN_OR_RETURN(q, recon::QuadricToBSpline(quadric, points, request.quadric_tolerance_mm, &fit));
  }
  if (truth != nullptr) FL_RETURN_IF_ERROR(CheckAgainstTruth(*truth, q, request.check_points, request.seed + 1, &fit));
  FitOutcome outcome;
  outcome.surface = q;
  outcome.report = {{"input", std::move(input_json)}, {"fit", fit.ToJson()}};
  for (auto& [key, value] : extra.items()) outcome.report[key] = value;
  return outcome;
}

Result<std::unique_ptr<recon::AnalyticSurface>> AnalyticInput(const std::string& input) {
  const std::string name = input.substr(std::string(kAnalyticPrefix).size());
  auto surface = recon::MakeReferenceSurface(name);
  if (!surface.ok()) return surface.status().WithContext("input '" + input + "'");
  return surface;
}

}  // namespace

Result<FitMethod> ParseFitMethod(const std::string& text) {
  std::string names;
  for (const MethodName& m : kMethods) {
    if (text == m.name) return m.method;
    names += (names.empty() ? "" : ", ") + std::string(m.name);
  }
  return Status::BadInput(Where{.field = "--method"}, "unknown fit method '" + text + "'", "use one of: " + names);
}

std::string FitMethodName(FitMethod method) {
  for (const MethodName& m : kMethods) {
    if (m.method == method) return m.name;
  }
  return "?";
}

// The size of the fit before it starts: samples and check points of an analytic input, and the
// control net of a scattered fit (its banded normal equations hold about 4 (degree + 1) u_poles
// numbers per pole).
Status CheckFitWork(const FitRequest& request, bool analytic) {
  double points = 0;
  std::string field = "--poles";
  if (analytic) {
    const double grid = static_cast<double>(request.grid_nu > 0 ? request.grid_nu : kDefaultAnalyticGrid) *
                        (request.grid_nv > 0 ? request.grid_nv : kDefaultAnalyticGrid);
    points = std::max(grid, static_cast<double>(request.scattered_samples)) + std::max(request.check_points, 0);
    field = request.check_points > request.scattered_samples ? "--check" : "--samples";
  }
  const double poles = static_cast<double>(request.scattered.u_poles) * request.scattered.v_poles;
  const double band = 4.0 * (request.scattered.degree + 1) * std::max(request.scattered.u_poles, 1);
  const double memory = 200 * points + 8 * poles * band * 3;
  if (poles > 0 && 8 * poles * band * 3 > 200 * points) field = "--poles";
  return CheckWork({.what = "the fit", .points = points + poles, .memory_bytes = memory}, request.input, field);
}

Result<FitOutcome> FitSurface(const FitRequest& request) {
  FL_RETURN_IF_ERROR(CheckOutputs(request));
  FL_RETURN_IF_ERROR(CheckFitWork(request, request.input.rfind(kAnalyticPrefix, 0) == 0));
  if (request.input.empty()) return Status::BadInput(Where{.field = "input"}, "no input given");
  const bool analytic = request.input.rfind(kAnalyticPrefix, 0) == 0;
  const bool cad = !analytic && recon::IsCadPath(request.input);
  const FitMethod method = request.method.value_or(analytic ? FitMethod::kGrid
                                                   : cad    ? FitMethod::kCad
                                                            : FitMethod::kScattered);
  Result<FitOutcome> outcome = Status::Internal("fit: no branch taken");
  if (analytic) {
    FL_ASSIGN_OR_RETURN(const auto truth, AnalyticInput(request.input));
    if (method == FitMethod::kCad) {
      return Status::BadInput(Where{.field = "--method"}, "an analytic surface is not a CAD file",
                              "use grid, scattered, adaptive or a quadric method");
    }
    if (request.scattered_samples < 1) {
      return Status::BadInput(Where{.field = "--samples"}, "the number of samples must be positive");
    }
    if (request.check_points < 0) {
      return Status::BadInput(Where{.field = "--check"}, "the number of check points must be >= 0");
    }
    // Grid: the grid itself; scattered and quadric methods: seeded uniform samples.
    std::vector<Eigen::Vector3d> points;
    const recon::ParamDomain dom = truth->domain();
    if (method == FitMethod::kGrid) {
      const int nu = request.grid_nu > 0 ? request.grid_nu : kDefaultAnalyticGrid;
      const int nv = request.grid_nv > 0 ? request.grid_nv : kDefaultAnalyticGrid;
      points = recon::SampleGrid(*truth, nu, nv).points;
    } else {
      Rng rng(request.seed);
      points.reserve(static_cast<std::size_t>(request.scattered_samples));
      for (int k = 0; k < request.scattered_samples; ++k) {
        const double u = rng.Uniform(dom.u_min, dom.u_max), v = rng.Uniform(dom.v_min, dom.v_max);
        points.push_back(truth->Point(u, v));
      }
    }
    nlohmann::json input = {
        {"kind", "analytic"},        {"surface", truth->name()},  {"description", truth->description()},
        {"domain", DomainJson(dom)}, {"n_points", points.size()}, {"seed", request.seed}};
    outcome = FitPoints(request, method, points, std::move(input), truth.get());
  } else if (cad) {
    outcome = FitCad(request, method);
  } else {
    FL_ASSIGN_OR_RETURN(const PointSet points, ReadPoints(request.input));
    if (points.empty()) return Status::BadInput(Where{.file = request.input}, "the file holds no points");
    nlohmann::json input = {{"kind", "points"}, {"file", request.input}, {"n_points", points.size()}};
    outcome = FitPoints(request, method, points.points, std::move(input), nullptr);
  }
  if (!outcome.ok()) return outcome.status();
  outcome->report["method"] = FitMethodName(method);
  outcome->report["surface"] = SurfaceJson(outcome->surface);
  outcome->report["step"] = request.out_step;
  return outcome;
}

Status RunFit(const FitRequest& request) {
  FL_ASSIGN_OR_RETURN(const FitOutcome outcome, FitSurface(request));
  std::string name = request.name;
  if (name.empty()) {
    name = request.input.rfind(kAnalyticPrefix, 0) == 0 ? request.input.substr(std::string(kAnalyticPrefix).size())
                                                        : fs::path(request.input).stem().string();
  }
  // Both files or neither: the report waits in its temporary file until the STEP file is in place.
  std::unique_ptr<AtomicFile> report;
  if (!request.out_report.empty()) {
    report = std::make_unique<AtomicFile>(request.out_report);
    FL_RETURN_IF_ERROR(report->open_status());
    nlohmann::json json = outcome.report;
    json["generator"] = kGeneratorName;
    report->stream() << json.dump(2) << "\n";
  }
  FL_RETURN_IF_ERROR(recon::WriteStep(request.out_step, outcome.surface, name));
  if (report != nullptr) {
    if (Status status = report->Commit(); !status.ok()) {
      std::error_code ec;
      fs::remove(request.out_step, ec);
      return status;
    }
  }
  const nlohmann::json& fit = outcome.report["fit"];
  log::Info("fit {} ({}) -> {}: {} x {} poles, residual rms {:.3g} mm, max {:.3g} mm{}", request.input,
            outcome.report["method"].get<std::string>(), request.out_step, outcome.surface.u_poles(),
            outcome.surface.v_poles(), fit.value("rms_mm", 0.0), fit.value("max_mm", 0.0),
            fit.value("n_check", 0) > 0 ? fmt::format(", check max {:.3g} mm at {} points",
                                                      fit.value("check_max_mm", 0.0), fit.value("n_check", 0))
                                        : std::string());
  for (const auto& note : fit["notes"]) log::Warn("fit: {}", note.get<std::string>());
  return Status::Ok();
}

Result<ProjectOutcome> ProjectPoints(const ProjectRequest& request) {
  if (request.out.empty()) {
    return Status::BadInput(Where{.field = "--out"}, "no output file given", "add --out deviations.csv");
  }
  FL_RETURN_IF_ERROR(PointFormatFromPath(request.out).status());
  FL_RETURN_IF_ERROR(CheckOutputFiles({{"--out", request.out}},
                                      {{"--surface", request.surface}, {"--points", request.points}}, request.force));
  FL_ASSIGN_OR_RETURN(const recon::CadFace face, recon::ReadCadFace(request.surface, request.face));
  FL_ASSIGN_OR_RETURN(PointSet set, ReadPoints(request.points));
  if (set.empty()) return Status::BadInput(Where{.file = request.points}, "the file holds no points");
  for (const char* name : {"deviation_mm", "foot_u", "foot_v", "foot_x", "foot_y", "foot_z", "on_boundary"}) {
    if (set.FindScalar(name) != nullptr) {
      return Status::BadInput(Where{.file = request.points, .field = name},
                              "the input already has a column '" + std::string(name) + "'",
                              "rename or drop that column: the output adds it");
    }
  }
  FL_ASSIGN_OR_RETURN(const recon::FootPointProjector projector, recon::FootPointProjector::Build(face.surface));
  auto feet = projector.ProjectAll(set.points);
  if (!feet.ok()) return feet.status().WithContext("projecting '" + request.points + "'");
  const std::size_t n = set.size();
  std::vector<double> deviation(n), u(n), v(n), fx(n), fy(n), fz(n), boundary(n), outside(n);
  set.normals.assign(n, Eigen::Vector3d::Zero());
  double sum2 = 0, max_abs = 0;
  long boundary_count = 0, outside_count = 0;
  for (std::size_t i = 0; i < n; ++i) {
    const recon::FootPoint& f = (*feet)[i];
    deviation[i] = f.deviation_mm;
    u[i] = f.u;
    v[i] = f.v;
    fx[i] = f.foot.x();
    fy[i] = f.foot.y();
    fz[i] = f.foot.z();
    boundary[i] = f.on_boundary ? 1 : 0;
    outside[i] = f.outside_trim ? 1 : 0;
    outside_count += f.outside_trim ? 1 : 0;
    set.normals[i] = f.normal;
    sum2 += f.deviation_mm * f.deviation_mm;
    max_abs = std::max(max_abs, std::abs(f.deviation_mm));
    boundary_count += f.on_boundary ? 1 : 0;
  }
  set.SetScalar("deviation_mm", std::move(deviation));
  set.SetScalar("foot_u", std::move(u));
  set.SetScalar("foot_v", std::move(v));
  set.SetScalar("foot_x", std::move(fx));
  set.SetScalar("foot_y", std::move(fy));
  set.SetScalar("foot_z", std::move(fz));
  set.SetScalar("on_boundary", std::move(boundary));
  // A trimmed face (reconstruction/trim.h): foot points over a hole or past the face's edge.
  const bool trimmed = face.surface.trim() != nullptr && !face.surface.trim()->natural();
  if (trimmed) set.SetScalar("outside_trim", std::move(outside));
  ProjectOutcome outcome;
  outcome.summary = {{"surface", request.surface},
                     {"face_index", face.info.index},
                     {"points", request.points},
                     {"n_points", n},
                     {"rms_deviation_mm", std::sqrt(sum2 / static_cast<double>(n))},
                     {"max_abs_deviation_mm", max_abs},
                     {"n_on_boundary", boundary_count},
                     {"out", request.out}};
  if (trimmed) outcome.summary["n_outside_trim"] = outside_count;
  outcome.deviations = std::move(set);
  return outcome;
}

Status RunProject(const ProjectRequest& request) {
  FL_ASSIGN_OR_RETURN(const ProjectOutcome outcome, ProjectPoints(request));
  FL_RETURN_IF_ERROR(WritePoints(request.out, outcome.deviations));
  std::cout << outcome.summary.dump(2) << "\n";
  std::cout.flush();
  if (!std::cout) return Status::IoError("project: writing the summary to stdout failed");
  if (outcome.summary["n_on_boundary"].get<long>() > 0) {
    log::Warn(
        "project: {} of {} points have their foot point on the edge of the surface (on_boundary = 1): "
        "they lie beyond Q and their deviation is not a normal distance",
        outcome.summary["n_on_boundary"].get<long>(), outcome.summary["n_points"].get<std::size_t>());
  }
  if (outcome.summary.value("n_outside_trim", 0L) > 0) {
    log::Warn(
        "project: {} of {} points have their foot point outside the trimmed face (outside_trim = 1): over a "
        "hole or past the face's edge, their deviation is not from the part",
        outcome.summary["n_outside_trim"].get<long>(), outcome.summary["n_points"].get<std::size_t>());
  }
  return Status::Ok();
}

}  // namespace formloop::app
