#pragma once
// Writing a corrected program from one read by GcodeReader (internal to nc-gen; used by `nc distribute`,
// path_deviation.h, and by the mirror compensation of a foreign program, program_compensation.h).
//
// A block is written back as its own text with the fewest changes (spec/path-deviation.md §5):
//   - unchanged when its rounded coordinates equal the rounded originals;
//   - otherwise only the changed X/Y/Z values are replaced (letter case and every other word, comment
//     and space kept), an axis word is appended when a value changes on an axis the block did not
//     program, and in incremental mode (G91) each written increment is round(E'_k) − (the controller's
//     position before the block), the difference of rounded absolute values, so rounding never drifts;
//   - an arc that must bend is replaced by straight feed moves through given vertices: the first keeps
//     the block's head (block delete, N word), its other words (F, S, M, comments) and its plane, with
//     the motion code changed to G1 and the centre words (I/J/K, R, LinuxCNC's P) removed; the rest are
//     "X.. Y.. Z.." lines in the modal G1;
//   - where a later block relied on the modal arc (coordinates and centre words only), the arc motion
//     code is written into it, so the program still means what it meant.
// Coordinates are written with a decimal point (FormatCoordinate), rounded once, halves away from zero.

#include <functional>
#include <string>
#include <string_view>
#include <vector>

#include <Eigen/Core>

#include "nc-gen/gcode_reader.h"

namespace formloop::nc::internal {

// A block kept until it is written: its text, terminator, words and what the reader said about it.
struct BlockRecord {
  std::string text, eol;
  std::vector<Word> words;
  long line = 0, n_word = -1;
  std::uint32_t head_end = 0;
  Motion motion = Motion::kNone, modal_motion = Motion::kNone;
  bool explicit_motion = false;
  Plane plane = Plane::kXY;
  Units units = Units::kMm;
  bool incremental = false, arc_absolute = false;
  FeedMode feed_mode = FeedMode::kUnitsPerMinute;
  Eigen::Vector3d start = Eigen::Vector3d::Zero(), end = Eigen::Vector3d::Zero();
  unsigned start_known = 0, end_known = 0, xyz_words = 0;
  bool has_arc = false;
  ArcGeometry arc;
  // Path length and cumulative length from the interval start to the block's end, mm (path_deviation).
  double length_mm = 0, s_end_mm = 0;
  void Assign(const Block& block, std::string_view line_end);
  const Word* Find(char letter) const;
};

// Straight moves an arc is split into so that each chord stays within `chord_tolerance` (program
// units) of it: n = max(1, ceil(φ/θ_max)), θ_max = min(π/2, 2 acos(1 − ε/r)) (π/2 when ε ≥ r), r the
// larger of the start and end radii (spec §5 SEGMENT).
int ChordSegments(const ArcGeometry& arc, double chord_tolerance);

class ProgramWriter {
 public:
  using Sink = std::function<void(std::string_view)>;
  ProgramWriter(GcodeDialect dialect, Sink sink);

  // The block as it was (plus the motion code when the program relied on a modal arc that an earlier
  // split replaced).
  void Unchanged(const BlockRecord& block);
  // The block with its end point at `end` (absolute, program units) rounded to `decimals`; for an arc
  // with absolute centre words (G90.1) the centre words are set from `centre` (absolute u, v). Returns
  // true when the text changed.
  bool MoveEnd(const BlockRecord& block, const Eigen::Vector3d& end, const Eigen::Vector3d* centre, int decimals);
  // True when the controller, reading the arc with its end at `end` (absolute, rounded to `decimals`)
  // from where it stands after the previous block, with the block's centre words (I/J/K unchanged, or
  // `centre` for absolute centres G90.1, or R), runs the same sweep (to within 2·10^-decimals of arc
  // length) with start and end radii within `radius_tolerance`: rounding can turn a full circle into a
  // sliver or move an R-form arc to the other side, and then the arc must be split instead.
  bool KeepsArc(const BlockRecord& block, const Eigen::Vector3d& end, const Eigen::Vector3d& centre, int decimals,
                double radius_tolerance) const;
  // The block replaced by straight feed moves through `vertices` (absolute, the last one is the end).
  void Split(const BlockRecord& block, const std::vector<Eigen::Vector3d>& vertices, int decimals);
  // A line of its own.
  void Line(std::string_view text, std::string_view eol);

  // The controller's position after what was written, for a block starting at `nominal_start`.
  Eigen::Vector3d Controller(const Eigen::Vector3d& nominal_start) const { return nominal_start + residual_; }
  // Lines written so far.
  long lines() const { return lines_; }
  // Where the controller stands after the last block: rounded minus nominal end point, per axis.
  const Eigen::Vector3d& residual() const { return residual_; }

 private:
  const char* MotionCode(Motion motion) const;
  // True when the block relies on a modal motion that the written program is no longer in.
  bool NeedsMotionCode(const BlockRecord& block) const;
  void Emit(std::string&& text, std::string_view eol);
  void Track(const BlockRecord& block);

  GcodeDialect dialect_;
  Sink sink_;
  Motion emitted_modal_ = Motion::kNone;  // the motion mode the written program is in
  bool changed_modal_ = false;            // a split left the written program in G1 where the input is not
  Eigen::Vector3d residual_ = Eigen::Vector3d::Zero();
  long lines_ = 0;
};

// The coordinate decimals a corrected program may be written with on `dialect`'s controller: mm 1..the post's
// MaxDecimals (Fanuc 4: IS-C; 3 is IS-B), inch one more (the least input increment in inch is a tenth of the
// mm one's digit count: 0.001 mm ~ 0.0001 in). BadInput naming --decimals / --decimals-inch otherwise.
Status CheckWrittenDecimals(GcodeDialect dialect, int decimals_mm, int decimals_inch);

}  // namespace formloop::nc::internal
