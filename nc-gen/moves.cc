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

Status HeldMoves::ForEach(const Visitor& visit) const {
  for (std::size_t i = 0; i < list_.moves.size(); ++i) FL_RETURN_IF_ERROR(visit(i, list_.moves[i]));
  return Status::Ok();
}

Result<ToolpathMoves> ToolpathMoves::Of(const Toolpath& path, TipOfPoint tip, double safe_z_mm) {
  if (path.points.empty()) return Status::BadInput("the tool path has no points; nothing to post");
  return ToolpathMoves(path, std::move(tip), safe_z_mm);
}

ToolpathMoves::ToolpathMoves(const Toolpath& path, TipOfPoint tip, double safe_z_mm)
    : path_(&path), tip_(std::move(tip)), safe_z_mm_(safe_z_mm) {
  const ToolpathOptions& tp = path.options;
  header_.tool_number = tp.tool.number;
  header_.tool_radius_mm = tp.tool.radius_mm;
  header_.spindle_rpm = tp.spindle_rpm;
  header_.passes = path.passes;
  // One move per CL point; per pass a comment, a rapid and a set feed, and a retract before every pass but
  // the first; a retract and the "cut" comment at the start, a retract at the end.
  std::size_t passes = 0;
  for (std::size_t k = 0; k < path.points.size(); ++k)
    passes += k == 0 || path.points[k].pass != path.points[k - 1].pass;
  size_ = path.points.size() + 4 * passes + 2;
}

Status ToolpathMoves::ForEach(const Visitor& visit) const {
  const Toolpath& path = *path_;
  const ToolpathOptions& tp = path.options;
  const double safe_z_mm = safe_z_mm_;
  std::size_t index = 0;
  const auto tip_of = [&](std::size_t k) { return tip_ ? tip_(k) : path.points[k].tip; };
  Eigen::Vector3d at = Eigen::Vector3d::Constant(std::numeric_limits<double>::quiet_NaN());
  const auto retract = [&](int pass, const char* source) {
    at.z() = safe_z_mm;
    return visit(index++, {.type = MoveType::kRapid, .tip = at, .axes = kAxisZ, .pass = pass, .source = source});
  };
  FL_RETURN_IF_ERROR(retract(-1, "start: retract to safe Z"));
  FL_RETURN_IF_ERROR(visit(index++, {.type = MoveType::kComment, .text = "cut", .source = "start of cutting"}));
  int current_pass = -1;
  for (std::size_t k = 0; k < path.points.size(); ++k) {
    const ClPoint& cl = path.points[k];
    const Eigen::Vector3d tip = tip_of(k);
    // The feed move to CL point k (its i-th such move is CL point i).
    const auto feed_to = [&](const Eigen::Vector3d& to, double feed_mm_per_min, const char* source) {
      at = to;
      return visit(index++, {.type = MoveType::kFeed,
                             .tip = at,
                             .feed_mm_per_min = feed_mm_per_min,
                             .pass = cl.pass,
                             .cl_index = static_cast<long>(k),
                             .source = source});
    };
    if (cl.pass != current_pass) {
      if (current_pass >= 0) FL_RETURN_IF_ERROR(retract(current_pass, "retract to safe Z"));
      current_pass = cl.pass;
      FL_RETURN_IF_ERROR(visit(index++, {.type = MoveType::kComment,
                                         .text = "pass " + std::to_string(cl.pass),
                                         .pass = cl.pass,
                                         .source = "pass start"}));
      at = Eigen::Vector3d(tip.x(), tip.y(), safe_z_mm);
      FL_RETURN_IF_ERROR(visit(index++, {.type = MoveType::kRapid,
                                         .tip = at,
                                         .axes = kAxisXY,
                                         .pass = cl.pass,
                                         .cl_index = static_cast<long>(k),
                                         .source = "rapid above the first point"}));
      FL_RETURN_IF_ERROR(
          feed_to(tip, tp.plunge_feed_mm_per_min, cl.kind == ClKind::kLeadIn ? "plunge to the lead-in" : "plunge"));
      FL_RETURN_IF_ERROR(visit(index++, {.type = MoveType::kSetFeed,
                                         .feed_mm_per_min = tp.feed_mm_per_min,
                                         .pass = cl.pass,
                                         .source = "cutting feed"}));
      continue;
    }
    FL_RETURN_IF_ERROR(feed_to(tip, tp.feed_mm_per_min,
                               cl.kind == ClKind::kLeadOut                           ? "lead-out"
                               : k > 0 && path.points[k - 1].kind == ClKind::kLeadIn ? "lead-in"
                                                                                     : "cut"));
  }
  return retract(-1, "end: retract to safe Z");
}

namespace {

Result<MoveList> Held(const ToolpathMoves& moves, double safe_z_mm) {
  MoveList list;
  list.header = moves.Header();
  list.safe_z_mm = safe_z_mm;
  list.moves.reserve(moves.Size());  // allocated once
  FL_RETURN_IF_ERROR(moves.ForEach([&list](std::size_t, const Move& m) {
    list.moves.push_back(m);
    return Status::Ok();
  }));
  return list;
}

}  // namespace

Result<MoveList> BuildMoveList(const Toolpath& path) {
  FL_ASSIGN_OR_RETURN(const ToolpathMoves moves, ToolpathMoves::Of(path));
  return Held(moves, path.safe_z_mm);
}

Result<MoveList> BuildMoveList(const Toolpath& path, const std::vector<Eigen::Vector3d>& tips, double safe_z_mm) {
  if (path.points.empty()) return Status::BadInput("the tool path has no points; nothing to post");
  if (tips.size() != path.points.size()) {
    return Status::Internal(std::to_string(tips.size()) + " tips for " + std::to_string(path.points.size()) +
                            " CL points");
  }
  FL_ASSIGN_OR_RETURN(const ToolpathMoves moves, ToolpathMoves::Of(
                                                     path, [&tips](std::size_t k) { return tips[k]; }, safe_z_mm));
  return Held(moves, safe_z_mm);
}

Status CheckMoveList(const MoveSequence& moves, const MachineLimits& limits) {
  FL_RETURN_IF_ERROR(limits.Validate());
  const std::string nothing = "; no program was written";
  const double rpm = moves.Header().spindle_rpm;
  if (!(rpm > 0) || rpm > limits.max_spindle_rpm) {
    return Status::SafetyLimit("spindle " + FormatFixed(rpm, 0) + " rpm is outside 0 < S <= the machine limit " +
                               FormatFixed(limits.max_spindle_rpm, 0) + " rpm" + nothing);
  }
  // Rates before travel: a wrong feed is a setting, a wrong position is geometry; both refuse. One walk keeps
  // the first of each and stops at the first rate.
  Status travel = Status::Ok();
  static const char* kAxis[] = {"X", "Y", "Z"};
  const Status rates = moves.ForEach([&](std::size_t i, const Move& m) {
    if (m.type == MoveType::kFeed || m.type == MoveType::kSetFeed) {
      if (!(m.feed_mm_per_min > 0) || m.feed_mm_per_min > limits.max_feed_mm_per_min) {
        return Status::SafetyLimit(m.Describe(i) + ": feed " + FormatFixed(m.feed_mm_per_min, 0) +
                                   " mm/min is outside 0 < F <= the machine limit " +
                                   FormatFixed(limits.max_feed_mm_per_min, 0) + " mm/min" + nothing);
      }
    }
    if (!travel.ok() || (m.type != MoveType::kRapid && m.type != MoveType::kFeed)) return Status::Ok();
    for (int a = 0; a < 3; ++a) {
      if ((m.axes & (1u << a)) != 0 && !std::isfinite(m.tip[a])) {
        travel = Status::SafetyLimit(m.Describe(i) + ": " + kAxis[a] + " is not a finite number" + nothing);
        return Status::Ok();
      }
    }
    Eigen::Vector3d known = m.tip;
    for (int a = 0; a < 3; ++a) {
      if (!std::isfinite(known[a])) known[a] = 0.5 * (limits.travel_min_mm[a] + limits.travel_max_mm[a]);
    }
    // The move's description only for a refusal (a million-point program has a million moves).
    if (!WithinTravel(limits, known)) travel = CheckTravel(limits, known, m.Describe(i));
    return Status::Ok();
  });
  FL_RETURN_IF_ERROR(rates);
  return travel;
}

Status CheckMoveList(const MoveList& list, const MachineLimits& limits) {
  return CheckMoveList(HeldMoves(list), limits);
}

}  // namespace formloop::nc
