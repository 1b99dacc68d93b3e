// `formloop nc`: NC programs from the ideal surface Q (spec/nc-gen.md).
//
//   formloop nc path  --surface Q.step [--out program.ngc] [--toolpath path.csv] [--dialect D] [--report toolpath.json]
//                     [tool/path options: --raster-angle, --one-way, --lead-mm, ...]
//   formloop nc post  --toolpath path.csv --out program --dialect D           (a planned path for a controller)
//   formloop nc compensate --toolpath path.csv --field ds.csv --out P1 --side side.csv [--nominal P0] [--dialect D]
//   formloop nc compensate --program SHOP.ngc --surface Q.step --ball-radius-mm R --field ds.csv --out P1 --side S
//   formloop nc distribute PROGRAM --deviations D.csv --out OUT      (M57/M58/M59, app/cmd_nc_program.cc)
//   formloop nc probe --surface Q.step --out probe.ngc   [--dialect D] [--grid NUxNV | --count N [--curvature-weight
//   B]] formloop nc check --nominal P0 --compensated P1 --side side.csv [--field ds.csv] [--dialect D]
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
#include "core/number_text.h"
#include "core/output_file.h"
#include "core/work_estimate.h"
#include "metrology/probe.h"
#include "metrology/probing_plan.h"
#include "nc-gen/compensation.h"
#include "nc-gen/deviation_field.h"
#include "nc-gen/moves.h"
#include "nc-gen/post.h"
#include "nc-gen/probe_program.h"
#include "nc-gen/program_compensation.h"
#include "nc-gen/raster_estimate.h"
#include "nc-gen/toolpath.h"
#include "nc-gen/toolpath_io.h"
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

Status CheckDialect(const std::string& dialect) {
  if (nc::FindPost(dialect) != nullptr) return Status::Ok();
  std::string names;
  for (const std::string& name : nc::PostNames()) names += (names.empty() ? "" : ", ") + name;
  return Status::BadInput(Where{.field = "--dialect"}, "unknown dialect '" + dialect + "'", "use one of " + names);
}

struct MachineArgs {
  std::string dialect = "linuxcnc";
  int decimals = -1;  // the dialect's default (Fanuc 3, others 4)
  bool block_numbers = false;
  int max_line_length = 0;
  double travel = 300;  // ± mm in x and y; z from −travel_z to +travel_z
  double travel_z = 200;
  double max_feed = 10000;
  double max_spindle = 24000;
  // The options as the user typed them, checked before any planning: messages name the option.
  Status Validate() const {
    FL_RETURN_IF_ERROR(CheckDialect(dialect));
    if (decimals != -1 && (decimals < 1 || decimals > 6)) {
      return Status::BadInput(Where{.field = "--decimals"}, "must be 1..6, got " + std::to_string(decimals),
                              "use 3 or 4");
    }
    FL_RETURN_IF_ERROR(nc::FindPost(dialect)->CheckDecimals(decimals, "--decimals"));
    if (max_line_length != 0 && max_line_length < 16) {
      return Status::BadInput(Where{.field = "--max-line-length"}, "must be 0 (no limit) or at least 16",
                              "give the controller's longest line, or 0");
    }
    for (const auto& [option, value] :
         {std::pair<const char*, double>{"--travel-mm", travel}, {"--travel-z-mm", travel_z}}) {
      if (!(value > 0 && value <= 100000)) {
        return Status::BadInput(Where{.field = option},
                                "must lie in (0, 100000] mm, got " + FormatSignificant(value, 6),
                                "give the machine's travel from the part zero in mm");
      }
    }
    if (!(max_feed > 0 && max_feed <= 200000)) {
      return Status::BadInput(Where{.field = "--max-feed"}, "must lie in (0, 200000] mm/min");
    }
    if (!(max_spindle > 0 && max_spindle <= 200000)) {
      return Status::BadInput(Where{.field = "--max-spindle"}, "must lie in (0, 200000] rpm");
    }
    return Status::Ok();
  }
  // A feed or speed above the machine's limit, named by its option.
  Status CheckFeed(const char* option, double value) const {
    if (value <= max_feed) return Status::Ok();
    return Status::BadInput(
        Where{.field = option},
        FormatSignificant(value, 6) + " mm/min is above the machine's --max-feed " + FormatSignificant(max_feed, 6),
        "lower it, or give the machine's real limit with --max-feed");
  }
  Status CheckSpindle(double value) const {
    if (value <= max_spindle) return Status::Ok();
    return Status::BadInput(
        Where{.field = "--spindle"},
        FormatSignificant(value, 6) + " rpm is above the machine's --max-spindle " + FormatSignificant(max_spindle, 6),
        "lower it, or give the machine's real limit with --max-spindle");
  }
  nc::PostOptions Post(const std::string& title) const {
    nc::PostOptions post;
    post.title = title;
    post.decimals = decimals != -1 ? decimals : nc::FindPost(dialect)->DefaultDecimals();
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
  app->add_option("--decimals", args->decimals,
                  "decimals of coordinates in mm (default: Fanuc 3 for IS-B, at most 4 on IS-C; others 4, at most 6)");
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
  bool one_way = false;
  std::string out;
  std::string toolpath;
  std::string report;
  bool force = false;
};

Status PlanAndPost(const PathArgs& input) {
  PathArgs args = input;
  if (args.one_way) args.path.zigzag = false;
  if (args.out.empty() && args.toolpath.empty()) {
    return Status::BadInput(Where{.field = "--out"}, "nothing to write", "give --out PROGRAM, --toolpath FILE or both");
  }
  // The options and the paths are checked before the (longer) planning.
  FL_RETURN_IF_ERROR(args.machine.Validate());
  FL_RETURN_IF_ERROR(args.machine.CheckFeed("--feed", args.path.feed_mm_per_min));
  FL_RETURN_IF_ERROR(args.machine.CheckFeed("--plunge-feed", args.path.plunge_feed_mm_per_min));
  FL_RETURN_IF_ERROR(args.machine.CheckSpindle(args.path.spindle_rpm));
  FL_RETURN_IF_ERROR(CheckOutputFiles({{"--out", args.out}, {"--toolpath", args.toolpath}, {"--report", args.report}},
                                      {{"--surface", args.surface.surface}}, args.force));
  FL_ASSIGN_OR_RETURN(const recon::CadFace face, args.surface.Read());
  FL_RETURN_IF_ERROR(args.path.Validate());
  const nc::RasterEstimate estimate = nc::EstimateRaster(face.surface, args.path);
  const WorkEstimate work{.what = "the tool path (" + FormatSignificant(estimate.passes, 3) + " passes)",
                          .points = estimate.cl_points,
                          .memory_bytes = 50e6 + nc::kPathBytesPerClPoint * estimate.cl_points,
                          .machining_s = estimate.cutting_s,
                          .output_bytes = 150 * estimate.cl_points};
  FL_RETURN_IF_ERROR(CheckWork(work, args.surface.surface,
                               std::string(estimate.driver()) == "scallop_um" ? "--scallop-um" : "--chord-um"));
  FL_ASSIGN_OR_RETURN(const nc::Toolpath path, nc::PlanRaster(face.surface, args.path));
  std::string program;
  if (!args.out.empty()) {
    FL_ASSIGN_OR_RETURN(const nc::ToolpathMoves moves, nc::ToolpathMoves::Of(path));
    FL_ASSIGN_OR_RETURN(
        program, nc::Post(moves, args.machine.dialect, args.machine.Post("formloop nc path " + args.surface.surface)));
  }
  // All files or none: the report waits in its temporary file until the others are in place.
  std::unique_ptr<AtomicFile> report;
  if (!args.report.empty()) {
    report = std::make_unique<AtomicFile>(args.report);
    FL_RETURN_IF_ERROR(report->open_status());
    nlohmann::json json = path.ReportJson();
    json["dialect"] = args.machine.dialect;
    json["program"] = args.out;
    json["toolpath_file"] = args.toolpath;
    json["cl_points"] = path.points.size();
    json["generator"] = kGeneratorName;
    report->stream() << json.dump(2) << "\n";
  }
  if (!args.toolpath.empty()) FL_RETURN_IF_ERROR(nc::WriteToolpathFile(args.toolpath, path));
  if (!args.out.empty()) FL_RETURN_IF_ERROR(WriteFileAtomic(args.out, program));
  if (report != nullptr) FL_RETURN_IF_ERROR(report->Commit());
  log::Info("nc path: {} CL points in {} passes at raster angle {} deg{}{}", path.points.size(), path.passes,
            args.path.raster_angle_deg, args.out.empty() ? "" : ", " + args.machine.dialect + " program -> " + args.out,
            args.toolpath.empty() ? "" : ", tool path -> " + args.toolpath);
  if (path.lifted_points > 0) log::Warn("nc path: {} (see --report)", path.UncutRegionText());
  return Status::Ok();
}

struct PostArgs {
  std::string toolpath;
  MachineArgs machine;
  std::string out;
  bool force = false;
};

// A planned tool path (from `nc path --toolpath`) posted for a controller; the machine-limit check runs
// on the move list first, so a refusal writes nothing.
Status PostToolpath(const PostArgs& args) {
  FL_RETURN_IF_ERROR(args.machine.Validate());
  FL_RETURN_IF_ERROR(CheckOutputFiles({{"--out", args.out}}, {{"--toolpath", args.toolpath}}, args.force));
  FL_ASSIGN_OR_RETURN(const nc::Toolpath path, nc::ReadToolpathFile(args.toolpath));
  FL_ASSIGN_OR_RETURN(const nc::ToolpathMoves moves, nc::ToolpathMoves::Of(path));
  FL_ASSIGN_OR_RETURN(const std::string program,
                      nc::Post(moves, args.machine.dialect, args.machine.Post("formloop nc post " + args.toolpath)));
  FL_RETURN_IF_ERROR(WriteFileAtomic(args.out, program));
  log::Info("nc post: {} CL points in {} passes, {} program -> {}", path.points.size(), path.passes,
            args.machine.dialect, args.out);
  return Status::Ok();
}

struct CompensateArgs {
  std::string toolpath, field, nominal, out, side;
  double lambda = 0;
  double max_offset_um = 200;
  bool force = false;
  MachineArgs machine;
  ShopProgramArgs shop;  // --program: a program formloop did not write
  ShopProgramArgs Shop() const {
    ShopProgramArgs s = shop;
    s.force = force;
    s.field = field;
    s.lambda = lambda;
    s.out = out;
    s.side = side;
    s.max_offset_um = max_offset_um;
    s.dialect = machine.dialect;
    // As formloop's own programs: the dialect's default decimals (Fanuc 3, others 4) unless --decimals is given;
    // the dialect's limit is enforced when the options are checked (nc::ProgramCompensationOptions::Validate).
    const nc::PostDialect* post = nc::FindPost(machine.dialect);
    s.decimals = machine.decimals != -1 ? machine.decimals : post != nullptr ? post->DefaultDecimals() : 4;
    return s;
  }
};

// Mirror compensation of a planned path by a systematic field: the compensated program and its side
// file, both or neither, after the program has passed its own `nc check` (WriteCompensatedProgram).
Status CompensateProgram(const CompensateArgs& args) {
  if (!args.shop.program.empty()) return CompensateShopProgram(args.Shop());
  if (args.toolpath.empty()) {
    return Status::BadInput(Where{.field = "--toolpath"}, "nothing to compensate",
                            "give --toolpath (a path formloop planned) or --program (a program it did not write)");
  }
  FL_RETURN_IF_ERROR(CheckDialect(args.machine.dialect));
  FL_RETURN_IF_ERROR(args.machine.Validate());
  if (!(args.max_offset_um > 0 && args.max_offset_um <= 5000)) {
    return Status::BadInput(Where{.field = "--max-offset-um"}, "must lie in (0, 5000] um",
                            "a compensation offset is a few to a few hundred um; use e.g. 200");
  }
  FL_RETURN_IF_ERROR(CheckOutputFiles(
      {{"--out", args.out}, {"--side", args.side}},
      {{"--toolpath", args.toolpath}, {"--field", args.field}, {"--nominal", args.nominal}}, args.force));
  FL_ASSIGN_OR_RETURN(const nc::Toolpath path, nc::ReadToolpathFile(args.toolpath));
  FL_ASSIGN_OR_RETURN(nc::DeviationField field, nc::ReadDeviationField(args.field, {.smoothing = args.lambda}));
  const nc::PostOptions post = args.machine.Post("formloop nc compensate " + args.toolpath);
  std::vector<nc::ProgramMove> nominal;
  if (args.nominal.empty()) {  // the nominal program is the path posted with the same options
    std::string text;
    {
      FL_ASSIGN_OR_RETURN(const nc::ToolpathMoves moves, nc::ToolpathMoves::Of(path));
      FL_ASSIGN_OR_RETURN(text, nc::Post(moves, args.machine.dialect, post));
    }
    FL_ASSIGN_OR_RETURN(nominal, nc::ReadProgram(text, args.machine.dialect, "the nominal program"));
  } else {
    // Read once, here, so that a program that is not the path's names its file.
    FL_ASSIGN_OR_RETURN(const std::string text, ReadFile(args.nominal));
    FL_ASSIGN_OR_RETURN(nominal, nc::ReadProgram(text, args.machine.dialect, args.nominal));
  }
  nc::CompensationOptions options;
  options.max_offset_um = args.max_offset_um;
  // A large job evaluates the tabulated field (nc-gen/deviation_field.h), its measured error in the source.
  double table_error_um = -1;
  const nc::SystematicField systematic = field.AsSystematicField(path.points.size(), &table_error_um);
  const std::string source =
      "systematic field " + args.field + " (thin-plate, lambda " + FormatExact(args.lambda) +
      (table_error_um >= 0 ? "; tabulated, within " + FormatSignificant(table_error_um, 2) + " um of the direct sum"
                           : "") +
      ")";
  FL_ASSIGN_OR_RETURN(const nc::Compensation compensation,
                      nc::WriteCompensatedProgram(path, nominal, systematic, source, options, post, args.out, args.side,
                                                  args.machine.dialect));
  nlohmann::json summary = {{"program", args.out},
                            {"side_file", args.side},
                            {"dialect", args.machine.dialect},
                            {"blocks", compensation.blocks},
                            {"max_offset_um", compensation.max_offset_um},
                            {"source", source}};
  std::cout << summary.dump(2) << "\n";
  log::Info("nc compensate: {} blocks, largest offset {:.3f} um -> {} and {}", compensation.blocks,
            compensation.max_offset_um, args.out, args.side);
  return Status::Ok();
}

struct ProbeArgs {
  SurfaceArgs surface;
  MachineArgs machine;
  nc::ProbeProgramOptions probe;
  std::string grid = "10x10";
  int count = 0;  // > 0: curvature-weighted plan of this many points instead of the grid
  double curvature_weight = 1.0;
  double inset_fraction = 0.05;
  std::string out;
  bool force = false;
};

Status PlanAndPostProbing(const ProbeArgs& args) {
  int nu = 0, nv = 0;
  FL_RETURN_IF_ERROR(args.machine.Validate());
  FL_RETURN_IF_ERROR(ParseLayout(args.grid, "--grid", &nu, &nv));
  const struct {
    const char* option;
    double value, max;
  } kProbeBounds[] = {{"--ball-radius-mm", args.probe.ball_radius_mm, 50},
                      {"--clearance-mm", args.probe.clearance_mm, 100},
                      {"--search-mm", args.probe.search_mm, 50},
                      {"--safe-z-mm", args.probe.safe_z_mm, 10000},
                      {"--min-gap-mm", args.probe.min_gap_mm, 50}};
  for (const auto& b : kProbeBounds) {
    if (!(b.value > 0 && b.value <= b.max)) {
      return Status::BadInput(Where{.field = b.option}, "must lie in (0, " + FormatSignificant(b.max, 6) + "] mm",
                              "give the distance in mm");
    }
  }
  if (!(args.probe.shank_radius_mm >= 0 && args.probe.shank_radius_mm <= 50)) {
    return Status::BadInput(Where{.field = "--shank-radius-mm"}, "must lie in [0, 50] mm",
                            "give the stylus shank's radius in mm, or 0 not to check the shank");
  }
  FL_RETURN_IF_ERROR(args.machine.CheckFeed("--probe-feed", args.probe.probe_feed_mm_per_min));
  if (args.probe.probe_tool < 1 || args.probe.probe_tool > 9999) {
    return Status::BadInput(Where{.field = "--probe-tool"}, "must be 1..9999", "give the probe's tool number");
  }
  FL_RETURN_IF_ERROR(CheckOutputsNotInputs({{"--out", args.out}}, {{"--surface", args.surface.surface}}));
  FL_RETURN_IF_ERROR(args.probe.Validate());
  const double points = args.count > 0 ? args.count : static_cast<double>(nu) * nv;
  const WorkEstimate work{.what = "the probing program",
                          .points = points,
                          .memory_bytes = 20e6 + 2e3 * points,
                          .machining_s = nc::ProbingSeconds(points, args.probe.clearance_mm, args.probe.search_mm,
                                                            args.probe.probe_feed_mm_per_min),
                          .output_bytes = 250 * points};
  FL_RETURN_IF_ERROR(CheckWork(work, "", args.count > 0 ? "--count" : "--grid"));
  FL_ASSIGN_OR_RETURN(const recon::CadFace face, args.surface.Read());
  metrology::ProbingPlan plan;
  if (args.count > 0) {
    FL_ASSIGN_OR_RETURN(plan, metrology::PlanProbingCurvatureWeighted(face.surface, args.count, args.inset_fraction,
                                                                      args.curvature_weight));
  } else {
    FL_ASSIGN_OR_RETURN(plan, metrology::PlanProbingGrid(face.surface, nu, nv, args.inset_fraction));
  }
  nc::ProbeProgramOptions options = args.probe;
  options.post = args.machine.Post("formloop nc probe " + args.surface.surface);
  FL_ASSIGN_OR_RETURN(options.part_surface, recon::FootPointProjector::Build(face.surface));
  FL_ASSIGN_OR_RETURN(const std::vector<std::string> programs,
                      nc::PostProbingBatches(plan, args.machine.dialect, options));
  // One program: --out. Batches (the controller cannot store every result at once): OUT_1.ext, OUT_2.ext, ...
  const std::filesystem::path out(args.out);
  std::vector<std::filesystem::path> paths;
  for (std::size_t b = 0; b < programs.size(); ++b) {
    paths.push_back(programs.size() == 1 ? out
                                         : out.parent_path() / (out.stem().string() + "_" + std::to_string(b + 1) +
                                                                out.extension().string()));
  }
  std::vector<NamedPath> outputs;
  for (const auto& path : paths) outputs.push_back({"--out", path});
  FL_RETURN_IF_ERROR(CheckOutputFiles(outputs, {{"--surface", args.surface.surface}}, args.force));
  for (std::size_t b = 0; b < programs.size(); ++b) FL_RETURN_IF_ERROR(WriteFileAtomic(paths[b], programs[b]));
  log::Info("nc probe: {} points, {} {} program(s) -> {}{}", plan.points.size(), programs.size(), args.machine.dialect,
            paths.front().string(),
            programs.size() > 1 ? " .. " + paths.back().string() + " (the controller stores the results of at most " +
                                      std::to_string(nc::FindPost(args.machine.dialect)->ProbeResultCapacity(options)) +
                                      " points at once)"
                                : "");
  return Status::Ok();
}

struct CheckArgs {
  std::string nominal, compensated, side, field;
  double lambda = 0;
  std::string dialect = "linuxcnc";
  int decimals = -1;  // the dialect's default, as nc post and nc compensate write
};

// Recomputes every compensated block from the two programs, the side file and (optionally) the
// field; the report goes to stdout as JSON, disagreeing blocks also to the log; exit 1 when any.
Status CheckPrograms(const CheckArgs& args) {
  FL_ASSIGN_OR_RETURN(const std::string nominal_text, ReadFile(args.nominal));
  FL_ASSIGN_OR_RETURN(const std::string compensated_text, ReadFile(args.compensated));
  FL_ASSIGN_OR_RETURN(const nc::SideFile side, nc::ReadSideFile(args.side));
  nc::SystematicField field;
  std::optional<nc::DeviationField> fitted;
  if (!args.field.empty()) {
    FL_ASSIGN_OR_RETURN(nc::DeviationField f, nc::ReadDeviationField(args.field, {.smoothing = args.lambda}));
    fitted = std::move(f);
    field = fitted->AsSystematicField(side.entries.size());
  }
  FL_RETURN_IF_ERROR(CheckDialect(args.dialect));
  const int decimals = args.decimals != -1 ? args.decimals : nc::FindPost(args.dialect)->DefaultDecimals();
  nc::CheckReport report;
  if (side.has_lambda) {  // a program formloop did not write (`nc compensate --program`)
    nc::ReaderOptions reader;
    FL_ASSIGN_OR_RETURN(reader.dialect, nc::ParseGcodeDialect(args.dialect));
    FL_ASSIGN_OR_RETURN(report, nc::CheckProgramCompensation(nominal_text, compensated_text, side, field, reader,
                                                             {.program_decimals = decimals}));
  } else {
    FL_ASSIGN_OR_RETURN(const auto nominal, nc::ReadProgram(nominal_text, args.dialect, args.nominal));
    FL_ASSIGN_OR_RETURN(const auto compensated, nc::ReadProgram(compensated_text, args.dialect, args.compensated));
    FL_ASSIGN_OR_RETURN(report,
                        nc::CheckCompensation(nominal, compensated, side, field, {.program_decimals = decimals}));
  }
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
  CLI::App* nc = root.add_subcommand(
      "nc", "NC programs from the ideal surface: cutting (path, post, compensate, check) and probing (probe).");
  nc->require_subcommand(1);

  auto path_args = std::make_shared<PathArgs>();
  CLI::App* path = nc->add_subcommand(
      "path",
      "Plan a ball-end raster on Q (scallop-driven step-over, chord tolerance, concave regions below the "
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
  path->add_option("--raster-angle", p.raster_angle_deg, "angle of the cutting direction from +X in the XY plane, deg")
      ->capture_default_str();
  path->add_flag("--one-way", path_args->one_way, "cut every pass in the same direction (default: zig-zag)");
  path->add_option("--lead-mm", p.lead_mm, "radius of the arc lead-in/out at each pass end, mm (0: none)")
      ->capture_default_str();
  path->add_option("--out", path_args->out, "the program");
  path->add_option("--toolpath", path_args->toolpath,
                   "the planned path as a CSV file (for `nc post`, `nc compensate`)");
  path->add_option("--report", path_args->report, "tool-path report (JSON): passes, step-over, lifted region");
  AddForceFlag(path, &path_args->force);
  path->callback([action, path_args] { *action = [path_args] { return PlanAndPost(*path_args); }; });

  auto post_args = std::make_shared<PostArgs>();
  CLI::App* post = nc->add_subcommand("post", "Post a planned tool path (from `nc path --toolpath`) for a controller.");
  post->add_option("--toolpath", post_args->toolpath, "the tool-path file")->required();
  AddMachineOptions(post, &post_args->machine);
  post->add_option("--out", post_args->out, "the program")->required();
  AddForceFlag(post, &post_args->force);
  post->callback([action, post_args] { *action = [post_args] { return PostToolpath(*post_args); }; });

  auto comp_args = std::make_shared<CompensateArgs>();
  CLI::App* comp = nc->add_subcommand(
      "compensate",
      "Mirror compensation: move every cutting CL point by -d_s*n of a systematic field, post the "
      "program, check it against the nominal one and write it with its side file (both or neither).");
  comp->add_option("--toolpath", comp_args->toolpath, "the nominal tool-path file (or --program)");
  ShopProgramArgs& shop = comp_args->shop;
  comp->add_option("--program", shop.program,
                   "instead of --toolpath: a program formloop did not write (lines, arcs, helices), mapped to Q "
                   "through the foot points of the ball centre; dialect linuxcnc or fanuc");
  comp->add_option("--surface", shop.surface, "with --program: Q as a STEP or IGES file");
  comp->add_option("--face", shop.face_index, "with --program: 0-based face index when the file has several faces");
  comp->add_option("--face-name", shop.face_name, "with --program: face name");
  comp->add_option("--ball-radius-mm", shop.ball_radius_mm,
                   "with --program: ball radius, mm (the program's point is the ball tip)");
  comp->add_option("--chord-tol", shop.chord_tol_mm, "with --program: chord tolerance of split arcs, mm")
      ->capture_default_str();
  comp->add_option("--contact-tol-mm", shop.contact_tol_mm,
                   "with --program: the tool touches Q within this of the ball radius (else the point is not moved)")
      ->capture_default_str();
  comp->add_option("--field", comp_args->field, "the systematic field as CSV u,v,ds_um (thin-plate interpolated)")
      ->required();
  comp->add_option("--lambda", comp_args->lambda, "smoothing of the field (0 = interpolate)")->capture_default_str();
  comp->add_option("--nominal", comp_args->nominal, "the nominal program (default: the tool path posted anew)");
  comp->add_option("--max-offset-um", comp_args->max_offset_um, "refuse any offset larger than this, um")
      ->capture_default_str();
  AddMachineOptions(comp, &comp_args->machine);
  comp->add_option("--out", comp_args->out, "the compensated program")->required();
  comp->add_option("--side", comp_args->side,
                   "the side file: CSV for a .csv name, else compact binary (docs/formats.md)")
      ->required();
  AddForceFlag(comp, &comp_args->force);
  comp->callback([action, comp_args] { *action = [comp_args] { return CompensateProgram(*comp_args); }; });

  auto probe_args = std::make_shared<ProbeArgs>();
  CLI::App* probe = nc->add_subcommand(
      "probe",
      "A probing program over Q: a grid of points equidistant in parameter space, each approached along "
      "its normal from a clearance, probed along -n with a search distance, and retracted.");
  AddSurfaceOptions(probe, &probe_args->surface);
  AddMachineOptions(probe, &probe_args->machine);
  probe->add_option("--grid", probe_args->grid, "points NUxNV equidistant in parameter space")->capture_default_str();
  probe->add_option(
      "--count", probe_args->count,
      "instead of the grid: this many points, denser where Q is curved (weighted farthest-point sampling)");
  probe
      ->add_option("--curvature-weight", probe_args->curvature_weight,
                   "with --count: 0 = evenly spread on Q; larger = more points where curvature is high")
      ->capture_default_str();
  probe->add_option("--inset", probe_args->inset_fraction, "keep this fraction of the domain free at each edge")
      ->capture_default_str();
  nc::ProbeProgramOptions& o = probe_args->probe;
  probe->add_option("--ball-radius-mm", o.ball_radius_mm, "probe ball radius, mm")->capture_default_str();
  probe->add_option("--clearance-mm", o.clearance_mm, "start this far from Q along n, mm")->capture_default_str();
  probe->add_option("--search-mm", o.search_mm, "probe this far beyond Q, mm")->capture_default_str();
  probe->add_option("--probe-feed", o.probe_feed_mm_per_min, "probing feed, mm/min")->capture_default_str();
  probe->add_option("--safe-z-mm", o.safe_z_mm, "rapid height between points, mm")->capture_default_str();
  probe
      ->add_option("--min-gap-mm", o.min_gap_mm,
                   "least gap between the probe and Q on the moves that do not probe (checked; a point that "
                   "cannot keep it is refused), mm")
      ->capture_default_str();
  probe->add_option("--shank-radius-mm", o.shank_radius_mm, "stylus shank radius, kept clear of Q too; 0 = not checked")
      ->capture_default_str();
  probe
      ->add_option("--fanuc-result-base", o.fanuc_result_base,
                   "Fanuc: first common variable of the results (#100-#199 or #500-#999); a plan that does not fit "
                   "is split into programs OUT_1, OUT_2, ...")
      ->capture_default_str();
  probe->add_option("--sinumerik-r-base", o.sinumerik_r_base, "Sinumerik: first R parameter of the results")
      ->capture_default_str();
  probe
      ->add_option("--sinumerik-r-last", o.sinumerik_r_last,
                   "Sinumerik: the control's last R parameter (MD28050 - 1); a plan that does not fit is split")
      ->capture_default_str();
  probe
      ->add_option("--probe-tool", o.probe_tool,
                   "the probe's tool number: changed to and its length offset activated (G43 H; length to the "
                   "stylus-ball centre)")
      ->capture_default_str();
  probe->add_option("--out", probe_args->out, "the program")->required();
  AddForceFlag(probe, &probe_args->force);
  probe->callback([action, probe_args] { *action = [probe_args] { return PlanAndPostProbing(*probe_args); }; });

  AddNcDistributeCommand(nc, action);

  auto check_args = std::make_shared<CheckArgs>();
  CLI::App* check = nc->add_subcommand(
      "check",
      "Recompute every compensated block from the nominal and compensated programs and compare it with the "
      "side file and, given the field, with -d_s*n; JSON report on stdout, exit 1 if any block disagrees.");
  check->add_option("--nominal", check_args->nominal, "the nominal program")->required();
  check->add_option("--compensated", check_args->compensated, "the compensated program")->required();
  check->add_option("--side", check_args->side, "the side file (CSV or compact) written with the compensated program")
      ->required();
  check->add_option("--field", check_args->field, "the systematic field as CSV u,v,ds_um (thin-plate interpolated)");
  check->add_option("--lambda", check_args->lambda, "smoothing of the field (0 = interpolate)")->capture_default_str();
  check->add_option("--dialect", check_args->dialect, "dialect of both programs")->capture_default_str();
  check->add_option("--decimals", check_args->decimals,
                    "coordinate decimals of the programs (default: the dialect's, Fanuc 3, others 4)");
  check->callback([action, check_args] { *action = [check_args] { return CheckPrograms(*check_args); }; });
}

}  // namespace formloop::app
