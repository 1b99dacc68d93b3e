// `formloop fit` and `formloop project` (app/surface_fit.h, spec/reconstruction.md).
//
//   formloop fit INPUT --out Q.step [--report fit.json] [--method M] [options]
//     INPUT: points (.csv .ply .xyz .pcd), CAD (.step .stp .iges .igs) or analytic:NAME
//   formloop fit CAD --list-faces                          faces of a CAD file as JSON on stdout
//   formloop project --surface Q.step --points P.csv --out deviations.csv|.ply

#include <cmath>
#include <iostream>
#include <memory>
#include <string>

#include <nlohmann/json.hpp>

#include "app/command.h"
#include "app/surface_fit.h"

namespace formloop::app {
namespace {

struct FitArgs {
  FitRequest request;
  std::string method;
  std::string grid;
  std::string poles;
  std::string smoothing = "none";
  double tolerance_mm = 0;  // 0 = each method's default
  int face_index = -1;
  bool list_faces = false;
};

Status ListFaces(const std::string& path) {
  FL_ASSIGN_OR_RETURN(const auto faces, recon::ListCadFaces(path));
  nlohmann::json list = nlohmann::json::array();
  for (const recon::CadFaceInfo& face : faces) {
    nlohmann::json entry = {{"index", face.index}, {"name", face.name}, {"surface_type", face.surface_type}};
    entry["box_min_mm"] = {face.box_min_mm[0], face.box_min_mm[1], face.box_min_mm[2]};
    entry["box_max_mm"] = {face.box_max_mm[0], face.box_max_mm[1], face.box_max_mm[2]};
    entry["area_mm2"] = face.area_mm2;
    // Which way the face looks (away from the material): a 3-axis job cuts faces that look up.
    entry["mean_normal_z"] = std::isfinite(face.mean_normal_z) ? nlohmann::json(face.mean_normal_z) : nullptr;
    list.push_back(entry);
  }
  std::cout << list.dump(2) << "\n";
  std::cout.flush();
  if (!std::cout) return Status::IoError("fit --list-faces: writing to stdout failed");
  return Status::Ok();
}

Status Fit(FitArgs args) {
  if (args.list_faces) return ListFaces(args.request.input);
  FitRequest& r = args.request;
  if (!args.method.empty()) {
    FL_ASSIGN_OR_RETURN(const FitMethod method, ParseFitMethod(args.method));
    r.method = method;
  }
  FL_RETURN_IF_ERROR(ParseLayout(args.grid, "--grid", &r.grid_nu, &r.grid_nv));
  FL_RETURN_IF_ERROR(ParseLayout(args.poles, "--poles", &r.scattered.u_poles, &r.scattered.v_poles));
  if (args.smoothing == "none") {
    r.scattered.smoothing = recon::ScatteredFitOptions::Smoothing::kNone;
  } else if (args.smoothing == "gcv") {
    r.scattered.smoothing = recon::ScatteredFitOptions::Smoothing::kGcv;
  } else if (args.smoothing == "tolerance") {
    r.scattered.smoothing = recon::ScatteredFitOptions::Smoothing::kTolerance;
  } else if (args.smoothing == "fixed") {
    r.scattered.smoothing = recon::ScatteredFitOptions::Smoothing::kFixed;
  } else {
    return Status::BadInput(Where{.field = "--smoothing"}, "unknown smoothing '" + args.smoothing + "'",
                            "use none, gcv, tolerance or fixed");
  }
  if (args.tolerance_mm != 0) {
    if (!(args.tolerance_mm > 0)) {
      return Status::BadInput(Where{.field = "--tolerance-mm"}, "the tolerance must be positive");
    }
    r.grid.tolerance_mm = args.tolerance_mm;
    r.scattered.tolerance_mm = args.tolerance_mm;
    r.quadric_tolerance_mm = args.tolerance_mm;
  }
  r.face.index = args.face_index;
  return RunFit(r);
}

}  // namespace

Status ParseLayout(const std::string& text, const std::string& option, int* nu, int* nv) {
  if (text.empty()) return Status::Ok();
  const std::size_t sep = text.find_first_of("x,X");
  int a = 0, b = 0;
  try {
    std::size_t used_a = 0, used_b = 0;
    if (sep == std::string::npos) throw std::invalid_argument(text);
    a = std::stoi(text.substr(0, sep), &used_a);
    b = std::stoi(text.substr(sep + 1), &used_b);
    if (used_a != sep || used_b != text.size() - sep - 1) throw std::invalid_argument(text);
  } catch (const std::exception&) {
    return Status::BadInput(Where{.field = option}, "'" + text + "' is not a layout", "write it as NUxNV, e.g. 40x40");
  }
  if (a < 2 || b < 2) {
    return Status::BadInput(Where{.field = option}, "'" + text + "' has a side below 2", "use at least 2x2");
  }
  *nu = a;
  *nv = b;
  return Status::Ok();
}

void AddFitCommand(CLI::App& root, CommandAction* action) {
  auto args = std::make_shared<FitArgs>();
  FitRequest& r = args->request;
  CLI::App* fit = root.add_subcommand(
      "fit",
      "The ideal surface Q as a B-spline (STEP) with its fit report, from points, a CAD face or an analytic "
      "reference surface.");
  fit->add_option("input", r.input,
                  "points (.csv .ply .xyz .pcd), CAD (.step .stp .iges .igs) or analytic:NAME "
                  "(see `formloop surfaces list`)")
      ->required();
  fit->add_option(
      "--method", args->method,
      "cad (CAD input, default there), grid (GeomAPI_PointsToBSplineSurface; default for analytic), "
      "scattered (least squares, optional thin-plate smoothing; default for points), adaptive (scattered + knot "
      "refinement), quadric-algebraic, quadric-geometric");
  fit->add_option("--out", r.out_step, "output STEP file (mm)");
  fit->add_option("--report", r.out_report, "fit report (JSON): residual RMS, max and where, method details");
  fit->add_option("--name", r.name, "name of the STEP product and face (default: the input's name)");
  fit->add_option("--face", args->face_index, "CAD: 0-based face index (see --list-faces)");
  fit->add_option("--face-name", r.face.name, "CAD: face name");
  fit->add_flag("--reverse", r.face.reverse,
                "CAD: turn the face over (Q's normal points away from the material; for a face without a solid "
                "written with its normal into the material)");
  AddForceFlag(fit, &r.force);
  fit->add_flag("--list-faces", args->list_faces,
                "CAD: print the faces (index, name, type, bounding box, area, mean normal z) as JSON and stop");
  fit->add_option("--grid", args->grid,
                  "grid method: NUxNV, the row-major layout of the point file (NU points per row); for analytic "
                  "input the samples per side (default 50x50)");
  fit->add_option("--samples", r.scattered_samples, "analytic input, scattered/quadric methods: random samples")
      ->capture_default_str();
  fit->add_option("--seed", r.seed, "seed of the analytic samples and check points")->capture_default_str();
  fit->add_option("--check", r.check_points, "analytic input: random check points against the exact surface")
      ->capture_default_str();
  fit->add_option("--degree", r.scattered.degree, "scattered: B-spline degree")->capture_default_str();
  fit->add_option("--poles", args->poles,
                  "scattered: control net NUxNV (default: chosen from the points' density and noise by GCV)");
  fit->add_option("--smoothing", args->smoothing,
                  "scattered: none (least squares on the net), or a thin-plate weight by gcv, to a target tolerance, "
                  "or fixed")
      ->capture_default_str();
  fit->add_option("--lambda", r.scattered.lambda, "scattered, --smoothing fixed: the weight (dimensionless)");
  fit->add_option("--tolerance-mm", args->tolerance_mm,
                  "grid: OpenCASCADE approximation tolerance (default 1e-4); scattered: target RMS for --smoothing "
                  "tolerance and the residual limit of adaptive refinement (default 1e-3); quadric: B-spline "
                  "conversion tolerance (default 1e-4)");
  fit->add_option("--corrections", r.scattered.max_correction_iterations,
                  "scattered: at most this many parameter-correction rounds")
      ->capture_default_str();
  fit->add_option("--refinements", r.scattered.max_refinements, "adaptive: at most this many knot-insertion rounds")
      ->capture_default_str();
  fit->callback([action, args] {
    *action = [args] {
      if (!args->list_faces && args->request.out_step.empty()) {
        return Status::BadInput(Where{.field = "--out"}, "no output STEP file given", "add --out Q.step");
      }
      return Fit(*args);
    };
  });

  auto project_args = std::make_shared<ProjectRequest>();
  auto project_face = std::make_shared<int>(-1);
  CLI::App* project = root.add_subcommand(
      "project",
      "Foot points of points on Q: signed deviation (+ = material left), foot point, unit normal, (u, v) "
      "and a boundary flag for every point. Summary (JSON) on stdout.");
  project->add_option("--surface", project_args->surface, "Q as a STEP or IGES file")->required();
  project->add_option("--face", *project_face, "0-based face index when the file has several faces");
  project->add_option("--face-name", project_args->face.name, "face name");
  project->add_option("--points", project_args->points, "points (.csv .ply .xyz .pcd)")->required();
  project
      ->add_option("--out", project_args->out,
                   "deviations (.csv .ply .xyz .pcd): the points with the normals of Q and the columns "
                   "deviation_mm, foot_u, foot_v (parameters of the foot point), foot_x, foot_y, foot_z, on_boundary")
      ->required();
  AddForceFlag(project, &project_args->force);
  project->callback([action, project_args, project_face] {
    *action = [project_args, project_face] {
      ProjectRequest request = *project_args;
      request.face.index = *project_face;
      return RunProject(request);
    };
  });
}

}  // namespace formloop::app
