// `formloop nc`: NC programs from the ideal surface Q (spec/nc-gen.md).
//
//   formloop nc path  --surface Q.step --out program.ngc [--dialect D] [--report toolpath.json] [tool/path options]
//   formloop nc probe --surface Q.step --out probe.ngc   [--dialect D] [--grid NUxNV] [probe options]
//   formloop nc check --nominal P0 --compensated P1 --side side.csv [--field ds.csv] [--dialect D]
//
// Every program passes the machine-limit check before any text exists; a refusal names the block
// or probe point and nothing is written. Outputs are written through a temporary file and renamed.

#include <iostream>
#include <memory>
#include <optional>
#include <string>

#include <nlohmann/json.hpp>

#include "app/command.h"
#include "core/atomic_file.h"
#include "core/log.h"
#include "metrology/probe.h"
#include "nc-gen/compensation.h"
#include "nc-gen/deviation_field.h"
#include "nc-gen/moves.h"
#include "nc-gen/post.h"
#include "nc-gen/probe_program.h"
#include "nc-gen/toolpath.h"
#include "reconstruction/cad_io.h"

namespace formloop::app {
namespace {

struct SurfaceArgs {
  std::string surface;
  int face_index = -1;
  std::string face_name;
  Result<recon::CadFace> Read() const {
    return recon::ReadCadFace(surface, recon::CadFaceSelector{.index = face_index, .name = face_name});
  }
};

struct MachineArgs {
  std::string dialect = "linuxcnc";
  int decimals = 4;
  bool block_numbers = false;
  int max_line_length = 0;
  double travel = 300;  // ± mm in x and y; z from −travel_z to +travel_z
  double travel_z = 200;
  double max_feed = 10000;
  double max_spindle = 24000;
  nc::PostOptions Post(const std::string& title) const {
    nc::PostOptions post;
    post.title = title;
    post.decimals = decimals;
    post.block_numbers = block_numbers;
    post.max_line_length = max_line_length;
    post.limits.travel_min_mm = {-travel, -travel, -travel_z};
    post.limits.travel_max_mm = {travel, travel, travel_z};
    post.limits.max_feed_mm_per_min = max_feed;
    post.limits.max_spindle_rpm = max_spindle;
    return post;
  }
};

void AddSurfaceOptions(CLI::App* app, SurfaceArgs* args) {
  app->add_option("--surface", args->surface, "Q as a STEP or IGES file (e.g. from `formloop fit`)")->required();
  app->add_option("--face", args->face_index, "0-based face index when the file has several faces");
  app->add_option("--face-name", args->face_name, "face name");
}

void AddMachineOptions(CLI::App* app, MachineArgs* args) {
  std::string names;
  for (const std::string& name : nc::PostNames()) names += (names.empty() ? "" : ", ") + name;
  app->add_option("--dialect", args->dialect, "controller dialect: " + names)->capture_default_str();
  app->add_option("--decimals", args->decimals, "decimals of coordinates in mm (Fanuc IS-B: at most 3)")
      ->capture_default_str();
  app->add_flag("--block-numbers", args->block_numbers, "number the blocks (N10, N20, ...)");
  app->add_option("--max-line-length", args->max_line_length, "longest line the controller accepts (0 = no limit)")
      ->capture_default_str();
  app->add_option("--travel-mm", args->travel, "machine travel in x and y: ± this, part frame")->capture_default_str();
  app->add_option("--travel-z-mm", args->travel_z, "machine travel in z: ± this, part frame")->capture_default_str();
  app->add_option("--max-feed", args->max_feed, "highest feed the machine allows, mm/min")->capture_default_str();
  app->add_option("--max-spindle", args->max_spindle, "highest spindle speed, rpm")->capture_default_str();
}

struct PathArgs {
  SurfaceArgs surface;
  MachineArgs machine;
  nc::ToolpathOptions path;
  std::string out;
  std::string report;
};

Status PlanAndPost(const PathArgs& args) {
  // The dialect is checked before the (longer) planning.
  if (nc::FindPost(args.machine.dialect) == nullptr) {
    return Status::BadInput(Where{.field = "--dialect"}, "unknown dialect '" + args.machine.dialect + "'",
                            "see `formloop nc path --help`");
  }
  FL_ASSIGN_OR_RETURN(const recon::CadFace face, args.surface.Read());
  FL_ASSIGN_OR_RETURN(const nc::Toolpath path, nc::PlanRaster(face.surface, args.path));
  FL_ASSIGN_OR_RETURN(const nc::MoveList moves, nc::BuildMoveList(path));
  FL_ASSIGN_OR_RETURN(const std::string program,
                      nc::Post(moves, args.machine.dialect, args.machine.Post("formloop nc path " + args.surface.surface)));
  // Both files or neither: the report waits in its temporary file until the program is in place.
  std::unique_ptr<AtomicFile> report;
  if (!args.report.empty()) {
    report = std::make_unique<AtomicFile>(args.report);
    FL_RETURN_IF_ERROR(report->open_status());
    nlohmann::json json = path.ReportJson();
    json["dialect"] = args.machine.dialect;
    json["program"] = args.out;
    json["cl_points"] = path.points.size();
    report->stream() << json.dump(2) << "\n";
  }
  FL_RETURN_IF_ERROR(WriteFileAtomic(args.out, program));
  if (report != nullptr) FL_RETURN_IF_ERROR(report->Commit());
  log::Info("nc path: {} CL points in {} passes, {} program -> {}", path.points.size(), path.passes,
            args.machine.dialect, args.out);
  if (path.gouge_risk_points > 0) {
    log::Warn("nc path: {} CL points lie where Q is concave below the ball radius; they are lifted and the region "
              "is left uncut (see the report)",
              path.gouge_risk_points);
  }
  return Status::Ok();
}

struct ProbeArgs {
  SurfaceArgs surface;
  MachineArgs machine;
  nc::ProbeProgramOptions probe;
  std::string grid = "10x10";
  double inset_fraction = 0.05;
  std::string out;
};

Status PlanAndPostProbing(const ProbeArgs& args) {
  int nu = 0, nv = 0;
  FL_RETURN_IF_ERROR(ParseLayout(args.grid, "--grid", &nu, &nv));
  FL_ASSIGN_OR_RETURN(const recon::CadFace face, args.surface.Read());
  FL_ASSIGN_OR_RETURN(const metrology::ProbingPlan plan,
                      metrology::PlanProbingGrid(face.surface, nu, nv, args.inset_fraction));
  nc::ProbeProgramOptions options = args.probe;
  options.post = args.machine.Post("formloop nc probe " + args.surface.surface);
  FL_ASSIGN_OR_RETURN(const std::string program, nc::PostProbing(plan, args.machine.dialect, options));
  FL_RETURN_IF_ERROR(WriteFileAtomic(args.out, program));
  log::Info("nc probe: {} points, {} program -> {}", plan.points.size(), args.machine.dialect, args.out);
  return Status::Ok();
}

struct CheckArgs {
  std::string nominal, compensated, side, field;
  double lambda = 0;
  std::string dialect = "linuxcnc";
  int decimals = 4;
};

// Recomputes every compensated block from the two programs, the side file and (optionally) the
// field; the report goes to stdout as JSON, disagreeing blocks also to the log; exit 1 when any.
Status CheckPrograms(const CheckArgs& args) {
  FL_ASSIGN_OR_RETURN(const std::string nominal_text, ReadFile(args.nominal));
  FL_ASSIGN_OR_RETURN(const std::string compensated_text, ReadFile(args.compensated));
  FL_ASSIGN_OR_RETURN(const auto nominal, nc::ReadProgram(nominal_text, args.dialect, args.nominal));
  FL_ASSIGN_OR_RETURN(const auto compensated, nc::ReadProgram(compensated_text, args.dialect, args.compensated));
  FL_ASSIGN_OR_RETURN(const nc::SideFile side, nc::ReadSideFile(args.side));
  nc::SystematicField field;
  std::optional<nc::DeviationField> fitted;
  if (!args.field.empty()) {
    FL_ASSIGN_OR_RETURN(nc::DeviationField f, nc::ReadDeviationField(args.field, {.smoothing = args.lambda}));
    fitted = std::move(f);
    field = fitted->AsSystematicField();
  }
  FL_ASSIGN_OR_RETURN(const nc::CheckReport report,
                      nc::CheckCompensation(nominal, compensated, side, field, {.program_decimals = args.decimals}));
  std::cout << report.ToJson().dump(2) << "\n";
  std::cout.flush();
  if (report.ok()) {
    log::Info("nc check: all {} blocks agree within {:.3f} um", report.blocks, report.tolerance_um);
    return Status::Ok();
  }
  for (const auto& block : report.disagreeing) log::Warn("nc check: {}", block.Describe());
  return Status::Failed("nc check: " + std::to_string(report.disagreeing.size()) + " of " +
                        std::to_string(report.blocks) + " blocks disagree (listed above and in the JSON report)");
}

}  // namespace

void AddNcCommand(CLI::App& root, CommandAction* action) {
  CLI::App* nc = root.add_subcommand("nc", "NC programs from the ideal surface: cutting (path) and probing (probe).");
  nc->require_subcommand(1);

  auto path_args = std::make_shared<PathArgs>();
  CLI::App* path = nc->add_subcommand(
      "path", "Plan a ball-end raster on Q (scallop-driven step-over, chord tolerance, concave regions below the "
              "ball radius lifted and flagged) and post it for a controller.");
  AddSurfaceOptions(path, &path_args->surface);
  AddMachineOptions(path, &path_args->machine);
  nc::ToolpathOptions& p = path_args->path;
  path->add_option("--tool-radius-mm", p.tool.radius_mm, "ball radius, mm")->capture_default_str();
  path->add_option("--tool-number", p.tool.number, "tool number")->capture_default_str();
  path->add_option("--scallop-um", p.scallop_um, "scallop height target between passes, µm")->capture_default_str();
  path->add_option("--chord-um", p.chord_tolerance_um, "chord tolerance along a pass, µm")->capture_default_str();
  path->add_option("--max-spacing-mm", p.max_point_spacing_mm, "longest step along a pass, mm")->capture_default_str();
  path->add_option("--feed", p.feed_mm_per_min, "cutting feed, mm/min")->capture_default_str();
  path->add_option("--plunge-feed", p.plunge_feed_mm_per_min, "plunge feed, mm/min")->capture_default_str();
  path->add_option("--spindle", p.spindle_rpm, "spindle speed, rpm")->capture_default_str();
  path->add_option("--clearance-mm", p.clearance_mm, "rapid height above the highest tip point, mm")
      ->capture_default_str();
  path->add_option("--out", path_args->out, "the program")->required();
  path->add_option("--report", path_args->report, "tool-path report (JSON): passes, step-over, lifted region");
  path->callback([action, path_args] { *action = [path_args] { return PlanAndPost(*path_args); }; });

  auto probe_args = std::make_shared<ProbeArgs>();
  CLI::App* probe = nc->add_subcommand(
      "probe", "A probing program over Q: a grid of points equidistant in parameter space, each approached along "
               "its normal from a clearance, probed along -n with a search distance, and retracted.");
  AddSurfaceOptions(probe, &probe_args->surface);
  AddMachineOptions(probe, &probe_args->machine);
  probe->add_option("--grid", probe_args->grid, "points NUxNV over the domain")->capture_default_str();
  probe->add_option("--inset", probe_args->inset_fraction, "keep this fraction of the domain free at each edge")
      ->capture_default_str();
  nc::ProbeProgramOptions& o = probe_args->probe;
  probe->add_option("--ball-radius-mm", o.ball_radius_mm, "probe ball radius, mm")->capture_default_str();
  probe->add_option("--clearance-mm", o.clearance_mm, "start this far from Q along n, mm")->capture_default_str();
  probe->add_option("--search-mm", o.search_mm, "probe this far beyond Q, mm")->capture_default_str();
  probe->add_option("--probe-feed", o.probe_feed_mm_per_min, "probing feed, mm/min")->capture_default_str();
  probe->add_option("--safe-z-mm", o.safe_z_mm, "rapid height between points, mm")->capture_default_str();
  probe->add_option("--out", probe_args->out, "the program")->required();
  probe->callback([action, probe_args] { *action = [probe_args] { return PlanAndPostProbing(*probe_args); }; });

  auto check_args = std::make_shared<CheckArgs>();
  CLI::App* check = nc->add_subcommand(
      "check", "Recompute every compensated block from the nominal and compensated programs and compare it with the "
               "side file and, given the field, with -d_s*n; JSON report on stdout, exit 1 if any block disagrees.");
  check->add_option("--nominal", check_args->nominal, "the nominal program")->required();
  check->add_option("--compensated", check_args->compensated, "the compensated program")->required();
  check->add_option("--side", check_args->side, "the side file (CSV) written with the compensated program")
      ->required();
  check->add_option("--field", check_args->field, "the systematic field as CSV u,v,ds_um (thin-plate interpolated)");
  check->add_option("--lambda", check_args->lambda, "smoothing of the field (0 = interpolate)")->capture_default_str();
  check->add_option("--dialect", check_args->dialect, "dialect of both programs")->capture_default_str();
  check->add_option("--decimals", check_args->decimals, "coordinate decimals of the programs")->capture_default_str();
  check->callback([action, check_args] { *action = [check_args] { return CheckPrograms(*check_args); }; });
}

}  // namespace formloop::app
