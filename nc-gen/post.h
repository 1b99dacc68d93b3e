#pragma once
// Posts: the canonical move list (nc-gen/moves.h) as controller text, with the safety check against the
// machine's limits done once before any text exists (spec/nc-gen.md §3). Each controller dialect is a
// small class in its own file, listed in one registry (post.cc; STYLE.md habit 9): adding a dialect is a
// file, a registry line and a golden-file test (tests/nc-gen/dialects_test.cc).
//
// Dialects today (the conventions each relies on are cited in its file):
//   "linuxcnc"   RS274NGC for LinuxCNC (accepted by LinuxCNC's own rs274 interpreter, post_test.cc)
//   "fanuc"      Fanuc 0i/30i ISO word-address programs
//   "heidenhain" Heidenhain TNC conversational (Klartext) programs
//   "sinumerik"  Siemens Sinumerik 840D ISO/G-code programs
// Every dialect has a reader for formloop's own output (positions, rapid/feed, feed rate), so a program
// can be checked by reading it back; anything else is refused with its line. LinuxCNC, Fanuc and
// Sinumerik programs are read by the one G-code reader (gcode_reader.h).
//
// Safety: a program is never emitted when any programmed position, feed or spindle speed lies outside
// MachineLimits; the Status names the first offending move and the limit.

#include <memory>
#include <string>
#include <string_view>
#include <vector>

#include <Eigen/Core>
#include <nlohmann/json.hpp>

#include "core/status.h"
#include "nc-gen/moves.h"
#include "nc-gen/toolpath.h"

namespace formloop::metrology {
struct ProbingPlan;
}  // namespace formloop::metrology

namespace formloop::nc {

struct ProbeProgramOptions;  // nc-gen/probe_program.h

struct MachineLimits {
  Eigen::Vector3d travel_min_mm{-300, -300, -200};  // tip position limits in the part (work) frame
  Eigen::Vector3d travel_max_mm{300, 300, 200};
  double max_feed_mm_per_min = 10000;
  double max_spindle_rpm = 24000;
  Status Validate() const;
  nlohmann::json ToJson() const;
};

// True when the tip lies inside the travel on every axis (CheckTravel's test, without a message).
bool WithinTravel(const MachineLimits& limits, const Eigen::Vector3d& tip);
// Checks one tip position; `what` names it in the message ("block N120", "probe point 17").
Status CheckTravel(const MachineLimits& limits, const Eigen::Vector3d& tip, const std::string& what);

struct PostOptions {
  std::string title;           // first comment line
  int decimals = 4;            // fixed decimals of coordinates, mm: 4 = 0.1 µm (Fanuc IS-B takes at most 3)
  bool block_numbers = false;  // N10, N20, ... (Heidenhain numbers every line whatever this says)
  long block_start = 10;
  long block_increment = 10;
  // Longest line the controller or its DNC link accepts; 0 = no limit. Comments are wrapped onto more
  // comment lines; a block that cannot fit is refused, naming the line (no program is returned).
  int max_line_length = 0;
  int program_number = 1234;              // Fanuc O-number, 1..9999
  std::string program_name = "FORMLOOP";  // Heidenhain BEGIN/END PGM name (letters, digits, _)
  MachineLimits limits;
  Status Validate() const;
};

// A programmed move read back from a program: enough to rebuild the cutter locations.
struct ProgramMove {
  bool rapid = false;
  Eigen::Vector3d tip = Eigen::Vector3d::Zero();  // end point, mm (NaN for an axis not programmed yet)
  long line = 0;                                  // 1-based line in the program text
  double feed_mm_per_min = 0;                     // modal feed in effect (also reported on rapids)
};

// One controller dialect: spells a checked move list and reads its own spelling back.
class PostDialect {
 public:
  virtual ~PostDialect() = default;
  virtual std::string_view Name() const = 0;
  virtual std::string_view FileExtension() const = 0;  // ".ngc", ".nc", ".h", ".mpf"
  // The moves have passed CheckMoveList and the options Validate when this is called; they are walked in
  // order (once or twice), never held.
  virtual Result<std::string> Format(const MoveSequence& moves, const PostOptions& options) const = 0;
  virtual Result<std::vector<ProgramMove>> Read(const std::string& text, const std::string& source) const = 0;
  // The dialect's probing program for a plan (nc-gen/probe_program.h: the format, its conventions and
  // what is checked before any text).
  virtual Result<std::string> FormatProbing(const metrology::ProbingPlan& plan,
                                            const ProbeProgramOptions& options) const = 0;
  // The most probe points one program of this dialect can store the results of (Fanuc: the common-variable
  // range from the base, Sinumerik: the R parameters up to sinumerik_r_last; 0 = no limit, the results are
  // logged to a file or by the cycle). 0 too when the base itself is invalid: FormatProbing refuses it.
  virtual std::size_t ProbeResultCapacity(const ProbeProgramOptions&) const { return 0; }
  // Coordinate decimals the controller takes (Fanuc: 4 on IS-C, 3 on IS-B) and the default of the CLI.
  virtual int MaxDecimals() const { return 6; }
  virtual int DefaultDecimals() const { return 4; }
  // BadInput naming `field` when `decimals` is beyond MaxDecimals.
  Status CheckDecimals(int decimals, const std::string& field) const;
};

// The registry: every dialect by name, in a fixed order.
std::vector<std::string> PostNames();
// nullptr when there is no such dialect.
const PostDialect* FindPost(std::string_view name);

// Checks the options and the moves (CheckMoveList) and then formats them in `dialect`. A ToolpathMoves
// sequence posts a million-point path without its list of moves.
Result<std::string> Post(const MoveSequence& moves, std::string_view dialect, const PostOptions& options);
Result<std::string> Post(const MoveList& list, std::string_view dialect, const PostOptions& options);
// Reads formloop's own output in `dialect` back; `source` names the text in messages.
Result<std::vector<ProgramMove>> ReadProgram(const std::string& text, std::string_view dialect,
                                             const std::string& source);

// Text safe inside an RS274NGC comment: LinuxCNC rejects nested parentheses ("Nested comment
// found"), so ( ) become [ ] and control characters become spaces.
std::string CommentText(const std::string& text);

// RS274NGC text for LinuxCNC: BuildMoveList + Post(..., "linuxcnc", ...). The i-th feed move after the
// "(cut)" marker is the i-th CL point.
Result<std::string> PostLinuxCnc(const Toolpath& path, const PostOptions& options);

// Reads formloop's own LinuxCNC output back (straight moves in mm and absolute coordinates; the G-code
// reader underneath, held to what formloop writes).
// Anything else is reported with its line, so a hand-edited program is never misread.
Result<std::vector<ProgramMove>> ReadLinuxCncMoves(const std::string& text, const std::string& source);

}  // namespace formloop::nc
