// The shop's own NC programs (issue 23): `formloop nc distribute` (M57/M58/M59 deviation distribution,
// nc-gen/path_deviation.h) and `formloop nc compensate --program` (mirror compensation of a program
// formloop did not write, nc-gen/program_compensation.h; its options sit on `nc compensate` in cmd_nc.cc).
//
//   formloop nc distribute PROGRAM --deviations D.csv --out OUT [--chord-tol MM] [--dialect linuxcnc|fanuc]
//                          [--decimals N] [--report R.json] [more options: --help]
//   formloop nc compensate --program SHOP.ngc --surface Q.step --field ds.csv --ball-radius-mm R
//                          --out OUT --side side.csv [--chord-tol MM] [--dialect linuxcnc|fanuc]
//
// stdout: a JSON summary; nothing is written on any error (codes E_* with the line, docs in the headers).

#include <iostream>
#include <memory>
#include <string>

#include <nlohmann/json.hpp>

#include "app/command.h"
#include "core/atomic_file.h"
#include "core/log.h"
#include "core/output_file.h"
#include "core/point_io.h"
#include "nc-gen/deviation_field.h"
#include "nc-gen/path_deviation.h"
#include "nc-gen/program_compensation.h"
#include "reconstruction/cad_io.h"
#include "reconstruction/foot_point.h"

namespace formloop::app {
namespace {

struct DistributeArgs {
  std::string program, deviations, out, report, dialect = "linuxcnc", deviation_frame = "workpiece";
  nc::DistributeOptions options;
  bool no_count_rapids = false;
  bool force = false;
};

Status Distribute(const DistributeArgs& input) {
  DistributeArgs args = input;
  FL_ASSIGN_OR_RETURN(args.options.reader.dialect, nc::ParseGcodeDialect(args.dialect));
  args.options.count_rapids = !args.no_count_rapids;
  if (args.deviation_frame != "workpiece" && args.deviation_frame != "program") {
    return Status::BadInput(Where{.field = "--deviation-frame"}, "'" + args.deviation_frame + "'",
                            "use workpiece or program");
  }
  args.options.deviation_frame_program = args.deviation_frame == "program";
  FL_RETURN_IF_ERROR(CheckOutputFiles({{"--out", args.out}, {"--report", args.report}},
                                      {{"PROGRAM", args.program}, {"--deviations", args.deviations}}, args.force));
  FL_ASSIGN_OR_RETURN(const nc::DeviationTable table, nc::ReadDeviationTable(args.deviations));
  // The report waits in its temporary file until the program is in place: both or neither.
  std::unique_ptr<AtomicFile> report_file;
  if (!args.report.empty()) {
    report_file = std::make_unique<AtomicFile>(args.report);
    FL_RETURN_IF_ERROR(report_file->open_status());
  }
  FL_ASSIGN_OR_RETURN(const nc::DistributeReport report,
                      nc::DistributeProgram(args.program, args.out, table, args.options));
  if (report_file != nullptr) {
    nlohmann::json json = report.ToJson();
    json["generator"] = kGeneratorName;
    report_file->stream() << json.dump(2) << "\n";
    FL_RETURN_IF_ERROR(report_file->Commit());
  }
  nlohmann::json summary = report.ToJson();
  summary.erase("interval_list");
  summary["deviations"] = args.deviations;
  summary["table_entries"] = table.size();
  std::cout << summary.dump(2) << "\n";
  for (const std::string& w : report.warnings) log::Warn("nc distribute: {}", w);
  log::Info(
      "nc distribute: {} regions, {} intervals, {} blocks corrected, {} arcs kept, {} split into {} moves, "
      "largest |delta| {:.4f} mm -> {}",
      report.regions, report.intervals, report.corrected, report.arcs_kept, report.arcs_split, report.segments,
      report.max_abs_delta_mm, args.out);
  return Status::Ok();
}

}  // namespace

void AddNcDistributeCommand(CLI::App* nc, CommandAction* action) {
  auto args = std::make_shared<DistributeArgs>();
  CLI::App* cmd = nc->add_subcommand(
      "distribute",
      "Distribute probed key-point deviations along a program between its M57 (start), M59 P<n> (key point n) and "
      "M58 (end) markers: every block moves by the deviation interpolated in path length. "
      "Blocks outside the markers are written byte for byte; arcs stay arcs where the deviation is constant over "
      "them, else they are split within the chord tolerance. All or nothing: an error names its code and line.");
  nc::DistributeOptions& o = args->options;
  cmd->add_option("program", args->program, "the NC program with the markers")->required();
  cmd->add_option("--deviations", args->deviations,
                  "deviation table CSV: index,dx,dy,dz (mm; optional unit, session, timestamp columns)")
      ->required();
  cmd->add_option("--out", args->out, "the corrected program (never the input)")->required();
  cmd->add_option("--report", args->report, "full report (JSON): every interval with its length and corrections");
  cmd->add_option("--dialect", args->dialect, "G-code dialect of the program: linuxcnc (RS274NGC) or fanuc")
      ->capture_default_str();
  cmd->add_option("--chord-tol", o.chord_tolerance_mm, "chord tolerance of split arcs, mm")->capture_default_str();
  cmd->add_option("--decimals", o.decimals_mm, "decimals of corrected coordinates in mm (4 on fine-increment controls)")
      ->capture_default_str();
  cmd->add_option("--decimals-inch", o.decimals_inch, "decimals of corrected coordinates in inch programs")
      ->capture_default_str();
  cmd->add_flag("--no-count-rapids", args->no_count_rapids,
                "rapids add no path length (their end points take the deviation where they stand)");
  cmd->add_option("--max-deviation-mm", o.max_deviation_mm, "refuse a key point deviating more (probing fault)")
      ->capture_default_str();
  cmd->add_option("--max-gradient", o.max_gradient, "refuse a deviation changing faster, mm per mm of path")
      ->capture_default_str();
  cmd->add_option("--buffer-max", o.buffer_max, "most blocks between two markers")->capture_default_str();
  cmd->add_flag("--implicit-sequential", o.implicit_sequential,
                "an M59 without P uses table entry k for the k-th M59 of its region");
  cmd->add_option("--deviation-frame", args->deviation_frame,
                  "workpiece, or program: the table is in programmed coordinates (rotary axes may then move)")
      ->capture_default_str();
  cmd->add_flag("--allow-comp-change", o.allow_comp_change, "allow G40-G42 / G43-G49 changes inside a region");
  cmd->add_flag("--block-delete", o.reader.block_delete, "the block delete switch is on ('/' blocks are skipped)");
  cmd->add_option("--arc-radius-tol-mm", o.reader.arc_radius_tolerance_mm,
                  "largest difference of an arc's start and end radius, mm")
      ->capture_default_str();
  cmd->add_option("--marker-start", o.marker_start, "M-code of the region start")->capture_default_str();
  cmd->add_option("--marker-end", o.marker_end, "M-code of the region end")->capture_default_str();
  cmd->add_option("--marker-key", o.marker_key, "M-code of a key point")->capture_default_str();
  AddForceFlag(cmd, &args->force);
  cmd->callback([action, args] { *action = [args] { return Distribute(*args); }; });
}

Status CompensateShopProgram(const ShopProgramArgs& args) {
  if (args.surface.empty()) {
    return Status::BadInput(Where{.field = "--surface"}, "a program formloop did not write is mapped to Q",
                            "give --surface Q.step (and --face when the file has several)");
  }
  nc::ProgramCompensationOptions options;
  FL_ASSIGN_OR_RETURN(options.reader.dialect, nc::ParseGcodeDialect(args.dialect));
  options.ball_radius_mm = args.ball_radius_mm;
  options.chord_tolerance_mm = args.chord_tol_mm;
  options.contact_tolerance_mm = args.contact_tol_mm;
  options.decimals_mm = args.decimals;
  options.decimals_inch = args.decimals + 1;  // the same least input increment class in inch (0.001 mm ~ 0.0001 in)
  options.max_offset_um = args.max_offset_um;
  FL_RETURN_IF_ERROR(options.Validate());
  FL_RETURN_IF_ERROR(CheckOutputFiles(
      {{"--out", args.out}, {"--side", args.side}},
      {{"--program", args.program}, {"--surface", args.surface}, {"--field", args.field}}, args.force));
  FL_ASSIGN_OR_RETURN(
      const recon::CadFace face,
      recon::ReadCadFace(args.surface, recon::CadFaceSelector{.index = args.face_index, .name = args.face_name}));
  FL_ASSIGN_OR_RETURN(const recon::FootPointProjector q, recon::FootPointProjector::Build(face.surface));
  FL_ASSIGN_OR_RETURN(const nc::DeviationField field, nc::ReadDeviationField(args.field, {.smoothing = args.lambda}));
  const std::string source =
      "systematic field " + args.field + " (thin-plate, lambda " + FormatExact(args.lambda) + ")";
  FL_ASSIGN_OR_RETURN(const nc::ProgramCompensationReport report,
                      nc::WriteCompensatedShopProgram(args.program, q, field.AsSystematicField(), source, options,
                                                      args.out, args.side));
  nlohmann::json summary = report.ToJson();
  summary["dialect"] = args.dialect;
  std::cout << summary.dump(2) << "\n";
  log::Info(
      "nc compensate: {} feed blocks of {} mapped to Q ({} points on Q, {} off), {} arcs kept, {} split into {} "
      "moves, largest offset {:.3f} um -> {} and {}",
      report.feed_blocks, args.program, report.on_surface, report.off_surface, report.arcs_kept, report.arcs_split,
      report.segments, report.max_offset_um, args.out, args.side);
  return Status::Ok();
}

}  // namespace formloop::app
