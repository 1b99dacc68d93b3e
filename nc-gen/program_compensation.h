#pragma once
// Mirror compensation of a program formloop did not write (issue 23): the shop's own finishing program,
// read by GcodeReader (lines, arcs and helices in any plane), is mapped to the ideal surface Q and every
// point the ball-end tool cuts is moved by −d_s·n (spec/nc-gen.md §4, "Compensation (mirror offset)":
// A = i − d_s(i)·n(i), remove what was left, add back what was over-cut).
//
// Mapping. The programmed point is the ball tip (docs/ARCHITECTURE.md); the ball centre is B = tip + r ẑ.
// Its foot point on Q (FootPointProjector: nearest point, global check) gives (u, v), the contact point
// i and the normal n; the tool touches Q where | |B − i| − r | ≤ contact_tolerance (else the point is
// "off" Q: an approach, a retract, a move in the air, and it is not moved). Since B = i + r n, moving the
// contact point by −d_s n moves the centre and the tip by the same −d_s(u, v)·n.
//
// What moves. Feed blocks (G1, G2, G3); rapids are never changed. A straight move's end point moves by
// the offset there (the straight move between two moved ends is the compensated path to second order in
// the offsets; the report gives the largest gap at midpoints). An arc is kept as an arc (end point moved,
// centre moving with the start, the drift along the plane's normal a helix) when the offsets along it —
// sampled at 17 points — differ from the linear blend of the two end offsets by less than half the output
// resolution in every component and the in-plane change between its ends is below half the resolution;
// otherwise it is split into straight moves through the moved points of the arc, as many as the chord
// rule (program_writer.h ChordSegments) gives and doubled until every chord's midpoint lies within the
// chord tolerance of the compensated curve.
//
// Refused, with the line: a word the reader does not know; a feed block whose start or end the program
// does not state, under cutter radius compensation (G41/G42: the tip path is not the programmed one),
// with anything the reader does not model, or marked '/' (optional); an offset above max_offset_um
// (SafetyLimit).
//
// Side file: compensation.h's format with kind cut/off and a lambda column, one row per written end point
// of a feed move (a split arc has one per vertex, its point on the nominal arc at lambda). `formloop nc
// check` reads it with CheckProgramCompensation: the same report and tolerances as for formloop's own
// programs, rows paired with blocks by their lines.

#include <filesystem>
#include <string>
#include <string_view>

#include <nlohmann/json.hpp>

#include "core/status.h"
#include "nc-gen/compensation.h"
#include "nc-gen/gcode_reader.h"
#include "reconstruction/foot_point.h"

namespace formloop::nc {

struct ProgramCompensationOptions {
  ReaderOptions reader;
  double ball_radius_mm = 0;           // required
  double contact_tolerance_mm = 0.01;  // the tool touches Q within this of r
  double chord_tolerance_mm = 0.001;   // ε for split arcs
  int decimals_mm = 4;                 // output resolution 0.1 µm
  int decimals_inch = 5;
  double max_offset_um = 200;  // refuse any larger single offset
  Status Validate() const;
};

struct ProgramCompensationReport {
  std::string program, output, side_file, source;
  std::size_t lines = 0, feed_blocks = 0, points = 0, on_surface = 0, off_surface = 0;
  std::size_t arcs_kept = 0, arcs_split = 0, segments = 0, corrected_blocks = 0;
  double max_offset_um = 0;
  double max_line_midpoint_um = 0;  // largest gap between a straight move and the compensated path at its middle
  ReadReport read;
  nlohmann::json ToJson() const;
};

struct ProgramCompensation {
  std::string program;  // the compensated program
  Compensation side;    // rows for the side file (program_mapped)
  ProgramCompensationReport report;
};

// Compensates `nominal_text` (named `source` in messages); writes nothing.
Result<ProgramCompensation> CompensateProgramText(std::string_view nominal_text, const std::string& source,
                                                  const recon::FootPointProjector& q, const SystematicField& field,
                                                  const std::string& field_source,
                                                  const ProgramCompensationOptions& options);

// `formloop nc compensate --program`: CompensateProgramText, then CheckProgramCompensation of the result
// against the field; only when it passes are the side file and the program written (side file first;
// should the program then fail to write, the side file is removed). `out` may not be `program`.
Result<ProgramCompensationReport> WriteCompensatedShopProgram(
    const std::filesystem::path& program, const recon::FootPointProjector& q, const SystematicField& field,
    const std::string& field_source, const ProgramCompensationOptions& options, const std::filesystem::path& out,
    const std::filesystem::path& side_path);

// `formloop nc check` for a side file with a lambda column: rows are paired with the compensated
// program's feed moves in order (each must name its line) and with the nominal program's feed blocks by
// nominal_line, whose points at lambda are the nominal points (every feed block of the nominal program
// must appear, in order, its last row at lambda 1). Each row is then checked as CheckCompensation does:
// program offset against the side file, against −d_s·n from `field` for points on Q, the nominal point
// against the side file. Positions are compared in mm.
Result<CheckReport> CheckProgramCompensation(std::string_view nominal_text, std::string_view compensated_text,
                                             const SideFile& side, const SystematicField& field,
                                             const ReaderOptions& reader, const CheckOptions& options = {});

}  // namespace formloop::nc
