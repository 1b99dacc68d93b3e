#pragma once
// Distributing probed deviations along an NC path with the markers M57/M58/M59 (spec/path-deviation.md,
// from seed 001: "method and process for automatically compensating probe measurements of CNC
// equipment"). Before a finishing pass a probe measures key points of the part; the program marks
// them, and every block between two key points is moved by the deviation interpolated linearly in
// path length:
//
//   M57            opens a compensated region; the deviation there is 0
//   M59 P<n>       the current programmed position is key point n, deviation D_n from the table
//   M59 I<dx> J<dy> K<dz>   the same with the deviation written in the block (program units)
//   M58            closes the region; the deviation there is 0
//
// In an interval with deviations D_begin, D_end and path length L_total (lines ||E − S||, arcs and
// helices sqrt((rφ)² + h²), rapids counted unless count_rapids is false), block k with cumulative length
// S_k moves to E'_k = E_k + D_begin + R·S_k, R = (D_end − D_begin)/L_total (spec §4 [R]: the absolute
// form of seed 001's D_k = R·L_k, which gives its −1 µm/+3 µm → +1 µm example). Arcs are kept (end
// moved, I/J/K and R unchanged: the centre moves with the start; the drift along the plane's normal
// becomes a helix) when the in-plane drift over the arc, δ = R·L_k, is below half the output
// resolution in each component — always when the deviation is constant; otherwise an arc is split
// into n = max(1, ceil(φ/θ_max)) straight moves, θ_max = min(π/2, 2 acos(1 − ε/r)), through
// V_i = P(λ_i) + Δ_(k−1) + λ_i·δ, which stay within the chord tolerance ε of the corrected curve
// (the drift is linear in λ on the curve and on each chord, so the gap is the arc's own sagitta).
// Blocks outside M57…M58 are written byte for byte; the marker blocks become comments (the correction
// is in the program, so no controller acts on them again). Everything is all or nothing: an error names
// its code, the line and the N number, and no output is written.
//
// Streaming: only the blocks of the current interval are held (at most buffer_max), so a program of
// millions of blocks is distributed in memory that does not grow with its length
// (bench/nc_distribute_bench.cc).
//
// Deviation table (CSV, ReadDeviationTable): a header naming the columns, ',' separated, '#' comments;
// columns index, dx, dy, dz are required (key point number 1..9999 and measured − nominal position in
// the program's work coordinates, mm unless the row's unit says inch); unit (mm|inch), session and
// timestamp are optional and kept with the entry. The table is converted to the program's unit at
// each M57.
//
// Error codes (spec §7): E_M59_OUTSIDE, E_NESTED_M57, E_M58_OUTSIDE, E_MISSING_M58, E_NO_DEVIATION,
// E_DEVIATION_LIMIT, E_GRADIENT, E_ZERO_LENGTH, E_UNIT_CHANGE, E_UNSUPPORTED_IN_REGION, E_COMP_CHANGE,
// E_ROTARY_NO_TCP, E_INVERSE_TIME, E_BUFFER_OVERFLOW, E_MARKER_BLOCK, E_POSITION_UNKNOWN,
// E_UNKNOWN_WORD (a word the reader does not know, anywhere in the program), E_INCREMENTAL_ARC (an arc
// in G91 inside a region: this rewriter writes incremental output for straight moves only), and the
// reader's E_ARC_* / E_SYNTAX / E_MODAL_GROUP / E_NO_MOTION_MODE.

#include <filesystem>
#include <functional>
#include <map>
#include <memory>
#include <string>
#include <string_view>
#include <vector>

#include <Eigen/Core>
#include <nlohmann/json.hpp>

#include "core/status.h"
#include "nc-gen/gcode_reader.h"

namespace formloop::nc {

struct DeviationEntry {
  long index = 0;
  Eigen::Vector3d d_mm = Eigen::Vector3d::Zero();  // measured − nominal, mm
  std::string session, timestamp;
  long line = 0;  // line in the table file
};

class DeviationTable {
 public:
  // `source` names the text in messages.
  static Result<DeviationTable> Parse(std::string_view text, const std::string& source);
  // Adds an entry (tests, other front ends); BadInput on a repeated or out-of-range index.
  Status Add(const DeviationEntry& entry);
  const DeviationEntry* Find(long index) const;
  std::size_t size() const { return entries_.size(); }
  const std::string& source() const { return source_; }

 private:
  std::map<long, DeviationEntry> entries_;
  std::string source_ = "deviation table";
};

Result<DeviationTable> ReadDeviationTable(const std::filesystem::path& path);

struct DistributeOptions {
  ReaderOptions reader;  // dialect, numbers without a point, arc radius tolerance, block delete
  int marker_start = 57, marker_end = 58, marker_key = 59;
  int decimals_mm = 3;                // output resolution q = 0.001 mm (4 on fine-increment controls)
  int decimals_inch = 4;              // q = 0.0001 in
  double chord_tolerance_mm = 0.001;  // ε for split arcs
  bool count_rapids = true;
  double max_deviation_mm = 0.5;         // D_max: larger |D_n| is refused as a probing fault
  double max_gradient = 0.01;            // R_max, mm of deviation per mm of path
  double min_interval_mm = 1e-6;         // L_min
  std::size_t buffer_max = 100000;       // blocks held for one interval
  bool implicit_sequential = false;      // M59 without P uses entry k for the k-th M59 of the region
  bool deviation_frame_program = false;  // the table is in programmed coordinates (rotary axes may move)
  bool allow_comp_change = false;        // allow G40-G42 / G43-G49 changes inside a region
  Status Validate() const;
};

struct IntervalReport {
  long begin_line = 0, end_line = 0;  // marker lines
  long key_index = -1;                // table index at the end (-1 for M58 or explicit words)
  Eigen::Vector3d d_begin_mm = Eigen::Vector3d::Zero(), d_end_mm = Eigen::Vector3d::Zero();
  double length_mm = 0;
  double gradient = 0;  // ||R||, mm per mm
  std::size_t blocks = 0, motion_blocks = 0, corrected = 0, arcs_kept = 0, arcs_split = 0, segments = 0;
  double max_abs_delta_mm = 0;  // largest |Δ| applied to an end point
  nlohmann::json ToJson() const;
};

struct DistributeReport {
  static constexpr std::size_t kIntervalsListed = 1000;  // the rest are counted only
  std::string program, output;
  std::size_t lines_in = 0, lines_out = 0, regions = 0, intervals = 0;
  std::size_t corrected = 0, arcs_kept = 0, arcs_split = 0, segments = 0;
  double max_abs_delta_mm = 0;
  std::vector<IntervalReport> interval_list;  // the first kIntervalsListed
  std::vector<std::string> warnings;
  ReadReport read;
  nlohmann::json ToJson() const;
};

// The streaming filter: lines in, corrected lines out through `sink`, in order. Blocks outside regions
// pass at once; blocks of an interval are released when its closing marker arrives.
class DeviationDistributor {
 public:
  using Sink = std::function<void(std::string_view)>;
  DeviationDistributor(const DeviationTable& table, const DistributeOptions& options, std::string source, Sink sink);
  ~DeviationDistributor();
  // One line of the program (without its terminator) and its terminator.
  Status Push(std::string_view line, std::string_view eol);
  // End of the program: a region still open is E_MISSING_M58.
  Status Finish();
  const DistributeReport& report() const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

// `nc distribute`: reads `program`, writes the corrected program to `out` (temporary file + rename,
// nothing on error; `out` may not be `program`).
Result<DistributeReport> DistributeProgram(const std::filesystem::path& program, const std::filesystem::path& out,
                                           const DeviationTable& table, const DistributeOptions& options);
// The same on text (tests).
Result<std::string> DistributeText(std::string_view text, const DeviationTable& table, const DistributeOptions& options,
                                   DistributeReport* report = nullptr);

}  // namespace formloop::nc
