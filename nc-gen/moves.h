#pragma once
// The canonical, machine-independent move list (spec/nc-gen.md §3; STYLE.md habit 8): the tool path
// becomes one list of moves with their provenance, the machine's limits are checked once on that list,
// and every controller dialect is a post over it (nc-gen/post.h). No post decides a position, a feed or
// an order of moves; a post only spells them.
//
// Conventions the list fixes for every post: millimetres, absolute coordinates, XY plane, no cutter
// radius compensation (the programmed point is the ball tip, toolpath.h), feed in mm/min.

#include <functional>
#include <limits>
#include <string>
#include <vector>

#include <Eigen/Core>

#include "core/status.h"
#include "nc-gen/toolpath.h"

namespace formloop::nc {

struct MachineLimits;

enum class MoveType {
  kComment,  // a comment line: block provenance ("pass 3") for people and for log mapping
  kRapid,    // positioning at the controller's rapid rate (G0, FMAX)
  kFeed,     // linear move at feed_mm_per_min (G1, L ... F)
  kSetFeed,  // sets the modal feed to feed_mm_per_min without motion ("F1500" on its own block)
};

// Which axis words a motion block programs. The other axes keep their modal value; the first retract
// programs Z alone because the start position in X and Y is unknown (and Z-first is the safe order).
enum AxisMask : unsigned { kAxisX = 1u, kAxisY = 2u, kAxisZ = 4u, kAxisXY = 3u, kAxisXYZ = 7u };

struct Move {
  MoveType type = MoveType::kFeed;
  // Tip position after the move, mm, part frame. Axes not known yet (before the first move that
  // programs them) are NaN; only the axes in `axes` are written.
  Eigen::Vector3d tip = Eigen::Vector3d::Constant(std::numeric_limits<double>::quiet_NaN());
  unsigned axes = kAxisXYZ;
  double feed_mm_per_min = 0;  // kFeed: the feed of this move; kSetFeed: the new modal feed; else 0
  std::string text;            // kComment only
  // Provenance.
  int pass = -1;       // pass index from 0; -1 outside the passes (start, end)
  long cl_index = -1;  // index into Toolpath::points for a move to a CL point; -1 otherwise
  std::string source;  // what made the move: "cut", "plunge", "retract to safe Z", ...
  // "move 7 (pass 0, CL point 3, plunge)": how refusals and round-trip failures name a block.
  std::string Describe(std::size_t index) const;
};

// Header facts every post states in its own dialect (units mm, absolute and XY plane are fixed above).
struct MoveListHeader {
  int tool_number = 1;
  double tool_radius_mm = 0;
  double spindle_rpm = 0;  // clockwise (M3)
  bool coolant = false;    // flood coolant (M8) on for the whole program; the planner leaves it off
  int passes = 0;
};

struct MoveList {
  MoveListHeader header;
  std::vector<Move> moves;
  double safe_z_mm = 0;
};

// A move list walked in order, one move at a time: a post or the safety check over a million-point path
// needs no list of a million moves (ToolpathMoves makes each move as it is visited); a held MoveList is one
// too (HeldMoves). Visiting twice gives the same moves.
class MoveSequence {
 public:
  virtual ~MoveSequence() = default;
  virtual const MoveListHeader& Header() const = 0;
  virtual std::size_t Size() const = 0;  // number of moves
  // Visits every move in order with its index (Move::Describe's); the first non-OK status stops the walk
  // and is returned.
  using Visitor = std::function<Status(std::size_t index, const Move& move)>;
  virtual Status ForEach(const Visitor& visit) const = 0;
};

// A held list as a sequence (the list must outlive it).
class HeldMoves : public MoveSequence {
 public:
  explicit HeldMoves(const MoveList& list) : list_(list) {}
  const MoveListHeader& Header() const override { return list_.header; }
  std::size_t Size() const override { return list_.moves.size(); }
  Status ForEach(const Visitor& visit) const override;

 private:
  const MoveList& list_;
};

// The tip of CL point k, mm (e.g. compensated); called once per visit of the point, so it must be a pure
// function of k.
using TipOfPoint = std::function<Eigen::Vector3d(std::size_t k)>;

// The one function that turns a tool path into moves. Per pass: retract to safe Z (not before the first),
// comment "pass k", rapid in XY above the first point (the lead-in start when the path has leads), plunge
// feed to it, set the cutting feed, feed through the pass (lead-in, cut, lead-out); then a final retract.
// The i-th kFeed move is CL point i. Each move is made as it is visited (the path and the tip function must
// outlive the sequence).
class ToolpathMoves : public MoveSequence {
 public:
  // Tips from `tip` (nullptr: the points' own) and safe Z `safe_z_mm`. BadInput for a path without points.
  static Result<ToolpathMoves> Of(const Toolpath& path, TipOfPoint tip, double safe_z_mm);
  static Result<ToolpathMoves> Of(const Toolpath& path) { return Of(path, nullptr, path.safe_z_mm); }
  const MoveListHeader& Header() const override { return header_; }
  std::size_t Size() const override { return size_; }
  Status ForEach(const Visitor& visit) const override;

 private:
  ToolpathMoves(const Toolpath& path, TipOfPoint tip, double safe_z_mm);
  const Toolpath* path_;
  TipOfPoint tip_;
  double safe_z_mm_;
  MoveListHeader header_;
  std::size_t size_ = 0;
};

// ToolpathMoves' moves held in a list (small paths, tests, edits of a list).
Result<MoveList> BuildMoveList(const Toolpath& path);
// The same with the tips `tips` (one per CL point, e.g. compensated) in place of the points' own and safe Z
// `safe_z_mm` in place of the path's.
Result<MoveList> BuildMoveList(const Toolpath& path, const std::vector<Eigen::Vector3d>& tips, double safe_z_mm);

// The safety check (ARCHITECTURE.md "Safety"), done once on the list before any post writes text:
// limits valid; spindle > 0 and ≤ the maximum; every feed > 0 and ≤ the maximum; every programmed axis
// inside the travel. StatusCode::kSafetyLimit names the move (Move::Describe) and the limit: the first
// move with a feed outside the limits, else the first outside the travel (one walk over the sequence).
Status CheckMoveList(const MoveSequence& moves, const MachineLimits& limits);
Status CheckMoveList(const MoveList& list, const MachineLimits& limits);

}  // namespace formloop::nc
