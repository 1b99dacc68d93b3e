#include "nc-gen/moves.h"

#include <cmath>

#include "core/number_text.h"
#include "nc-gen/post.h"

namespace formloop::nc {

std::string Move::Describe(std::size_t index) const {
  std::string what = "move " + std::to_string(index) + " (";
  if (pass >= 0) what += "pass " + std::to_string(pass) + ", ";
  if (cl_index >= 0) what += "CL point " + std::to_string(cl_index) + ", ";
  return what + source + ")";
}

Result<MoveList> BuildMoveList(const Toolpath& path) {
  std::vector<Eigen::Vector3d> tips(path.points.size());
  for (std::size_t k = 0; k < tips.size(); ++k) tips[k] = path.points[k].tip;
  return BuildMoveList(path, tips, path.safe_z_mm);
}

Result<MoveList> BuildMoveList(const Toolpath& path, const std::vector<Eigen::Vector3d>& tips, double safe_z_mm) {
  if (path.points.empty()) return Status::BadInput("the tool path has no points; nothing to post");
  if (tips.size() != path.points.size()) {
    return Status::Internal(std::to_string(tips.size()) + " tips for " + std::to_string(path.points.size()) +
                            " CL points");
  }
  const ToolpathOptions& tp = path.options;
  MoveList list;
  list.header.tool_number = tp.tool.number;
  list.header.tool_radius_mm = tp.tool.radius_mm;
  list.header.spindle_rpm = tp.spindle_rpm;
  list.header.passes = path.passes;
  list.safe_z_mm = safe_z_mm;
  // One move per CL point, four more per pass (retract, comment, rapid, set feed) and three at the ends: the
  // list is allocated once (a million moves grown by doubling would hold half as many again at its peak).
  std::size_t passes = 0;
  for (std::size_t k = 0; k < path.points.size(); ++k)
    passes += k == 0 || path.points[k].pass != path.points[k - 1].pass;
  list.moves.reserve(path.points.size() + 4 * passes + 3);

  Eigen::Vector3d at = Eigen::Vector3d::Constant(std::numeric_limits<double>::quiet_NaN());
  const auto retract = [&](int pass, const std::string& source) {
    at.z() = safe_z_mm;
    list.moves.push_back({.type = MoveType::kRapid, .tip = at, .axes = kAxisZ, .pass = pass, .source = source});
  };
  retract(-1, "start: retract to safe Z");
  list.moves.push_back({.type = MoveType::kComment, .text = "cut", .source = "start of cutting"});
  int current_pass = -1;
  for (std::size_t k = 0; k < path.points.size(); ++k) {
    const ClPoint& cl = path.points[k];
    const long index = static_cast<long>(k);
    if (cl.pass != current_pass) {
      if (current_pass >= 0) retract(current_pass, "retract to safe Z");
      current_pass = cl.pass;
      list.moves.push_back({.type = MoveType::kComment,
                            .text = "pass " + std::to_string(cl.pass),
                            .pass = cl.pass,
                            .source = "pass start"});
      at = Eigen::Vector3d(tips[k].x(), tips[k].y(), safe_z_mm);
      list.moves.push_back({.type = MoveType::kRapid,
                            .tip = at,
                            .axes = kAxisXY,
                            .pass = cl.pass,
                            .cl_index = index,
                            .source = "rapid above the first point"});
      at = tips[k];
      list.moves.push_back({.type = MoveType::kFeed,
                            .tip = at,
                            .feed_mm_per_min = tp.plunge_feed_mm_per_min,
                            .pass = cl.pass,
                            .cl_index = index,
                            .source = cl.kind == ClKind::kLeadIn ? "plunge to the lead-in" : "plunge"});
      list.moves.push_back({.type = MoveType::kSetFeed,
                            .feed_mm_per_min = tp.feed_mm_per_min,
                            .pass = cl.pass,
                            .source = "cutting feed"});
      continue;
    }
    at = tips[k];
    list.moves.push_back({.type = MoveType::kFeed,
                          .tip = at,
                          .feed_mm_per_min = tp.feed_mm_per_min,
                          .pass = cl.pass,
                          .cl_index = index,
                          .source = cl.kind == ClKind::kLeadOut                           ? "lead-out"
                                    : k > 0 && path.points[k - 1].kind == ClKind::kLeadIn ? "lead-in"
                                                                                          : "cut"});
  }
  retract(-1, "end: retract to safe Z");
  return list;
}

Status CheckMoveList(const MoveList& list, const MachineLimits& limits) {
  FL_RETURN_IF_ERROR(limits.Validate());
  const std::string nothing = "; no program was written";
  const double rpm = list.header.spindle_rpm;
  if (!(rpm > 0) || rpm > limits.max_spindle_rpm) {
    return Status::SafetyLimit("spindle " + FormatFixed(rpm, 0) + " rpm is outside 0 < S <= the machine limit " +
                               FormatFixed(limits.max_spindle_rpm, 0) + " rpm" + nothing);
  }
  // Rates first, then travel: a wrong feed is a setting, a wrong position is geometry; both refuse.
  for (std::size_t i = 0; i < list.moves.size(); ++i) {
    const Move& m = list.moves[i];
    if (m.type != MoveType::kFeed && m.type != MoveType::kSetFeed) continue;
    if (!(m.feed_mm_per_min > 0) || m.feed_mm_per_min > limits.max_feed_mm_per_min) {
      return Status::SafetyLimit(m.Describe(i) + ": feed " + FormatFixed(m.feed_mm_per_min, 0) +
                                 " mm/min is outside 0 < F <= the machine limit " +
                                 FormatFixed(limits.max_feed_mm_per_min, 0) + " mm/min" + nothing);
    }
  }
  static const char* kAxis[] = {"X", "Y", "Z"};
  for (std::size_t i = 0; i < list.moves.size(); ++i) {
    const Move& m = list.moves[i];
    if (m.type != MoveType::kRapid && m.type != MoveType::kFeed) continue;
    for (int a = 0; a < 3; ++a) {
      if ((m.axes & (1u << a)) == 0) continue;
      if (!std::isfinite(m.tip[a])) {
        return Status::SafetyLimit(m.Describe(i) + ": " + kAxis[a] + " is not a finite number" + nothing);
      }
    }
    Eigen::Vector3d known = m.tip;
    for (int a = 0; a < 3; ++a) {
      if (!std::isfinite(known[a])) known[a] = 0.5 * (limits.travel_min_mm[a] + limits.travel_max_mm[a]);
    }
    // The move's description only for a refusal (a million-point program has a million moves).
    if (!WithinTravel(limits, known)) FL_RETURN_IF_ERROR(CheckTravel(limits, known, m.Describe(i)));
  }
  return Status::Ok();
}

}  // namespace formloop::nc
