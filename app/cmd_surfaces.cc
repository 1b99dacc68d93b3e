// `formloop surfaces`: the analytic reference surfaces (reconstruction/analytic_surface.h).
//
//   formloop surfaces list                               JSON array on stdout
//   formloop surfaces sample NAME --nu N --nv N --out F  points, normals, u, v, k1, k2 (.csv .ply .xyz .pcd)
//   formloop surfaces export NAME --out Q.step           B-spline fit + STEP, optional --report fit.json

#include <iostream>
#include <memory>
#include <string>

#include <nlohmann/json.hpp>

#include "app/command.h"
#include "app/surface_fit.h"
#include "core/log.h"
#include "core/output_file.h"
#include "core/point_io.h"
#include "core/work_estimate.h"
#include "reconstruction/analytic_surface.h"

namespace formloop::app {
namespace {

nlohmann::json DomainJson(const recon::ParamDomain& d) {
  return {{"u_min", d.u_min}, {"u_max", d.u_max}, {"v_min", d.v_min}, {"v_max", d.v_max}};
}

Status ListSurfaces() {
  nlohmann::json list = nlohmann::json::array();
  for (const std::string& name : recon::ReferenceSurfaceNames()) {
    FL_ASSIGN_OR_RETURN(auto surface, recon::MakeReferenceSurface(name));
    list.push_back({{"name", surface->name()},
                    {"description", surface->description()},
                    {"domain", DomainJson(surface->domain())},
                    {"is_graph", surface->is_graph()}});
  }
  std::cout << list.dump(2) << "\n";
  std::cout.flush();
  if (!std::cout) return Status::IoError("surfaces list: writing to stdout failed");
  return Status::Ok();
}

struct SampleArgs {
  std::string name;
  int nu = 101;
  int nv = 101;
  std::string out;
  bool force = false;
};

Status CheckGrid(int nu, int nv) {
  if (nu < 2) return Status::BadInput(Where{.field = "--nu"}, "need at least 2 samples, got " + std::to_string(nu));
  if (nv < 2) return Status::BadInput(Where{.field = "--nv"}, "need at least 2 samples, got " + std::to_string(nv));
  return Status::Ok();
}

Status SampleSurface(const SampleArgs& args) {
  FL_RETURN_IF_ERROR(CheckGrid(args.nu, args.nv));
  const double count = static_cast<double>(args.nu) * args.nv;
  // A point with its normal, u, v and curvatures: about 100 bytes in memory, twice that as text.
  FL_RETURN_IF_ERROR(CheckWork(
      {.what = "sampling " + args.name + " on " + std::to_string(args.nu) + " x " + std::to_string(args.nv) + " points",
       .points = count,
       .memory_bytes = 300 * count,
       .output_bytes = 200 * count},
      "", "--nu/--nv"));
  FL_ASSIGN_OR_RETURN(auto surface, recon::MakeReferenceSurface(args.name));
  FL_RETURN_IF_ERROR(PointFormatFromPath(args.out).status());  // reject the extension before sampling
  FL_RETURN_IF_ERROR(CheckOutputFiles({{"--out", args.out}}, {}, args.force));
  const PointSet points = recon::SampleGridPoints(*surface, args.nu, args.nv);
  FL_RETURN_IF_ERROR(WritePoints(args.out, points));
  log::Info("sampled {} on {} x {} points -> {}", args.name, args.nu, args.nv, args.out);
  return Status::Ok();
}

struct ExportArgs {
  std::string name;
  std::string out;
  int nu = 61;
  int nv = 61;
  double tolerance_mm = 1e-4;
  std::string report;
  bool force = false;
};

// Fit check: 1000 seeded random points inside the domain (fixed seed: the report is reproducible).
constexpr int kCheckPoints = 1000;
constexpr unsigned long long kCheckSeed = 20240611ULL;

// `surfaces export NAME` is `fit analytic:NAME --method grid` with this command's grid and check size.
Status ExportSurface(const ExportArgs& args) {
  FL_RETURN_IF_ERROR(CheckGrid(args.nu, args.nv));
  if (!(args.tolerance_mm > 0)) {
    return Status::BadInput(Where{.field = "--tolerance-mm"}, "the tolerance must be positive", "use e.g. 1e-4");
  }
  FitRequest request;
  request.input = "analytic:" + args.name;
  request.method = FitMethod::kGrid;
  request.grid_nu = args.nu;
  request.grid_nv = args.nv;
  request.grid.tolerance_mm = args.tolerance_mm;
  request.check_points = kCheckPoints;
  request.seed = kCheckSeed;
  request.out_step = args.out;
  request.out_report = args.report;
  request.name = args.name;
  request.force = args.force;
  return RunFit(request);
}

std::string NamesHelp() {
  std::string names;
  for (const std::string& name : recon::ReferenceSurfaceNames()) names += (names.empty() ? "" : ", ") + name;
  return names;
}

}  // namespace

void AddSurfacesCommand(CLI::App& root, CommandAction* action) {
  CLI::App* surfaces = root.add_subcommand("surfaces", "The analytic reference surfaces: list, sample, export.");
  surfaces->require_subcommand(1);

  CLI::App* list = surfaces->add_subcommand(
      "list", "Print the reference surfaces as a JSON array (name, description, domain in mm, is_graph).");
  list->callback([action] { *action = [] { return ListSurfaces(); }; });

  auto sample_args = std::make_shared<SampleArgs>();
  CLI::App* sample = surfaces->add_subcommand(
      "sample",
      "Sample a reference surface on a regular grid: points, normals and the scalars u, v, k1, k2 "
      "(principal curvatures, 1/mm, positive = convex).");
  sample->add_option("name", sample_args->name, "surface name: " + NamesHelp())->required();
  sample->add_option("--nu", sample_args->nu, "samples along u (corners included)")->capture_default_str();
  sample->add_option("--nv", sample_args->nv, "samples along v (corners included)")->capture_default_str();
  sample->add_option("--out", sample_args->out, "output point file; format from the extension: .csv .ply .xyz .pcd")
      ->required();
  AddForceFlag(sample, &sample_args->force);
  sample->callback([action, sample_args] { *action = [sample_args] { return SampleSurface(*sample_args); }; });

  auto export_args = std::make_shared<ExportArgs>();
  CLI::App* exp = surfaces->add_subcommand(
      "export",
      "Fit a B-spline to a reference surface (GeomAPI_PointsToBSplineSurface on a grid), check it "
      "against the analytic surface and write it as a STEP face (mm).");
  exp->add_option("name", export_args->name, "surface name: " + NamesHelp())->required();
  exp->add_option("--out", export_args->out, "output STEP file")->required();
  exp->add_option("--nu", export_args->nu, "grid samples along u")->capture_default_str();
  exp->add_option("--nv", export_args->nv, "grid samples along v")->capture_default_str();
  exp->add_option("--tolerance-mm", export_args->tolerance_mm, "approximation tolerance handed to OpenCASCADE, mm")
      ->capture_default_str();
  exp->add_option("--report", export_args->report, "write the fit report (JSON) to this file");
  AddForceFlag(exp, &export_args->force);
  exp->callback([action, export_args] { *action = [export_args] { return ExportSurface(*export_args); }; });
}

}  // namespace formloop::app
