#pragma once
// Posts: the tool path as controller text, with a safety check against the machine's limits first
// (spec/nc-gen.md §3). This first post is LinuxCNC (RS274NGC); Fanuc, Heidenhain and Sinumerik join
// it as further posts over the same move list.
//
// Safety: a program is never emitted when any programmed position, feed or spindle speed lies
// outside MachineLimits; the Status names the first offending block and the limit.

#include <string>
#include <vector>

#include <Eigen/Core>
#include <nlohmann/json.hpp>

#include "core/status.h"
#include "nc-gen/toolpath.h"

namespace formloop::nc {

struct MachineLimits {
  Eigen::Vector3d travel_min_mm{-300, -300, -200};  // tip position limits in the part (work) frame
  Eigen::Vector3d travel_max_mm{300, 300, 200};
  double max_feed_mm_per_min = 10000;
  double max_spindle_rpm = 24000;
  Status Validate() const;
  nlohmann::json ToJson() const;
};

// Checks one tip position; `what` names it in the message ("block N120", "probe point 17").
Status CheckTravel(const MachineLimits& limits, const Eigen::Vector3d& tip, const std::string& what);

struct PostOptions {
  std::string title;           // first comment line
  int decimals = 4;            // 0.1 µm resolution in mm
  bool block_numbers = false;  // N10, N20, ...
  MachineLimits limits;
};

// A programmed move read back from a program: enough to rebuild the cutter locations.
struct ProgramMove {
  bool rapid = false;
  Eigen::Vector3d tip = Eigen::Vector3d::Zero();  // end point, mm
  long line = 0;                                  // 1-based line in the program text
  double feed_mm_per_min = 0;
  std::string comment;                            // a comment on the same line, if any
};

// Text safe inside an RS274NGC comment: LinuxCNC rejects nested parentheses ("Nested comment
// found"), so ( ) become [ ] and control characters become spaces.
std::string CommentText(const std::string& text);

// RS274NGC text for LinuxCNC. The i-th feed move after the "(cut)" marker is the i-th CL point.
Result<std::string> PostLinuxCnc(const Toolpath& path, const PostOptions& options);

// Reads formloop's own LinuxCNC output back (G0/G1 with X Y Z F, comments, N numbers, G21/G90 only).
// Anything else is reported with its line, so a hand-edited program is never misread.
Result<std::vector<ProgramMove>> ReadLinuxCncMoves(const std::string& text, const std::string& source);

}  // namespace formloop::nc
