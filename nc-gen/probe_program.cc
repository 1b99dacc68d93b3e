#include "nc-gen/probe_program.h"

// The probing programs themselves are part of each post dialect (PostDialect::FormatProbing in
// nc-gen/post_<dialect>.cc, with the dialect's conventions); here are what they share: the checked
// stations, the header text, and the dispatch by dialect name.

#include <algorithm>
#include <cmath>
#include <numbers>

#include "core/log.h"
#include "core/number_text.h"
#include "nc-gen/post_text.h"
#include "nc-gen/probe_clearance.h"
#include "nc-gen/probe_reach.h"

namespace formloop::nc {
namespace internal {
namespace {

// The start (s->clearance_mm back along the approach from the ball centre at contact), the search end
// and the position above the start at safe Z.
void Place(const ProbeProgramOptions& options, ProbeStation* s) {
  const Eigen::Vector3d centre_on_surface = s->surface + options.ball_radius_mm * s->normal;
  s->start = centre_on_surface - s->clearance_mm * s->approach;
  s->target = centre_on_surface + options.search_mm * s->approach;
  s->above = s->start;
  s->above.z() = options.safe_z_mm;
}

// A point that is not clear of the part: tries the clearance halved, then quartered (above the
// two-touch back-off), and keeps the first that clears; false when none does (s unchanged).
// `warn`: log the shortened clearance (not when only asking which points are reachable).
bool Shorten(const recon::FootPointProjector& part, const ProbeStation* previous, const ProbeProgramOptions& options,
             bool warn, ProbeStation* s) {
  for (const double fraction : {0.5, 0.25}) {
    ProbeStation shorter = *s;
    shorter.clearance_mm = fraction * options.clearance_mm;
    if (options.touch_feed_mm_per_min > 0 && !(shorter.clearance_mm > options.backoff_mm)) break;
    Place(options, &shorter);
    if (CheckProbeClearance(part, shorter, previous, options).ok()) {
      if (warn) {
        log::Warn(
            "[nc] probe point {}: its probing move starts {} mm from the contact instead of {} mm, to keep "
            "the probe clear of the part",
            s->id, FormatExact(shorter.clearance_mm), FormatExact(options.clearance_mm));
      }
      *s = shorter;
      return true;
    }
  }
  return false;
}

// The stations of ProbeStations; with `left_out`, a point the part is in the way of is recorded there
// and skipped (the next traverse starts above the last station kept) instead of refusing the plan.
Result<std::vector<ProbeStation>> Stations(const metrology::ProbingPlan& plan, const ProbeProgramOptions& options,
                                           std::vector<UnreachableProbePoint>* left_out) {
  FL_RETURN_IF_ERROR(options.Validate());
  if (plan.points.empty()) return Status::BadInput("the probing plan has no points");
  if (options.probe_feed_mm_per_min > options.post.limits.max_feed_mm_per_min) {
    return Status::SafetyLimit("probe feed exceeds the machine's feed limit; no probing program was written");
  }
  if (!options.approaches.empty() && options.approaches.size() != plan.points.size()) {
    return Status::BadInput("probing program: " + std::to_string(options.approaches.size()) +
                            " approach directions for " + std::to_string(plan.points.size()) + " points");
  }
  const double min_cos = std::cos(kMaxApproachTiltDeg * std::numbers::pi / 180.0);
  std::vector<ProbeStation> stations;
  for (std::size_t i = 0; i < plan.points.size(); ++i) {
    const metrology::ProbePoint& p = plan.points[i];
    const std::string what = "probe point " + std::to_string(p.id);
    ProbeStation s;
    s.id = p.id;
    s.surface = p.point;
    s.normal = p.normal;
    s.approach = -p.normal;
    if (!options.approaches.empty()) {
      const Eigen::Vector3d& a = options.approaches[i];
      if (!(std::abs(a.norm() - 1.0) < 1e-6) || !(a.z() < 0) || !(-a.dot(p.normal) >= min_cos)) {
        return Status::BadInput(what + ": approach (" + FormatExact(a.x()) + ", " + FormatExact(a.y()) + ", " +
                                FormatExact(a.z()) + ") is not a unit vector coming down onto the part within " +
                                FormatExact(kMaxApproachTiltDeg) + " degrees of the normal; no program was written");
      }
      s.approach = a;
      s.tilted = (a + p.normal).norm() > 1e-9;
    }
    s.clearance_mm = options.clearance_mm;
    Place(options, &s);
    if (options.part_surface) {
      const ProbeStation* previous = stations.empty() ? nullptr : &stations.back();
      std::string finding;
      const Status clear = CheckProbeClearance(*options.part_surface, s, previous, options, &finding);
      if (!clear.ok() && !Shorten(*options.part_surface, previous, options, left_out == nullptr, &s)) {
        if (left_out == nullptr || clear.code() != StatusCode::kSafetyLimit) return clear;
        left_out->push_back({i, p.id, finding});
        continue;
      }
    }
    FL_RETURN_IF_ERROR(CheckTravel(options.post.limits, s.above, what));
    FL_RETURN_IF_ERROR(CheckTravel(options.post.limits, s.start, what));
    FL_RETURN_IF_ERROR(CheckTravel(options.post.limits, s.target, what));
    // Two touches: the back-off from a contact at the start point is the highest point reached.
    if (options.touch_feed_mm_per_min > 0) {
      FL_RETURN_IF_ERROR(CheckTravel(options.post.limits, s.start - options.backoff_mm * s.approach, what));
    }
    stations.push_back(s);
  }
  return stations;
}

}  // namespace

Result<std::vector<ProbeStation>> ProbeStations(const metrology::ProbingPlan& plan,
                                                const ProbeProgramOptions& options) {
  return Stations(plan, options, nullptr);
}

std::string XyzWords(const ProgramText& w, const Eigen::Vector3d& p) {
  return "X" + w.Num(p.x()) + " Y" + w.Num(p.y()) + " Z" + w.Num(p.z());
}

std::string ProbeHeader(const ProbeProgramOptions& options, std::size_t points) {
  return "probe T" + std::to_string(options.probe_tool) + ", stylus ball radius " +
         FormatFixed(options.ball_radius_mm, 4) +
         " mm; programmed point = ball centre, tool length of the probe measured to the ball centre; " +
         std::to_string(points) + " points";
}

}  // namespace internal

Status ProbeProgramOptions::Validate() const {
  if (!(min_gap_mm > 0)) {
    return Status::BadInput(Where{.field = "probe.min_gap_mm"}, "must be > 0, got " + FormatExact(min_gap_mm),
                            "give the least gap between the probe and the part in mm (default 1)");
  }
  if (!(shank_radius_mm >= 0)) {
    return Status::BadInput(Where{.field = "probe.shank_radius_mm"},
                            "must be >= 0, got " + FormatExact(shank_radius_mm),
                            "give the stylus shank's radius in mm, or 0 not to check the shank");
  }
  if (!(ball_radius_mm > 0)) return Status::BadInput(Where{.field = "probe.ball_radius_mm"}, "must be > 0");
  if (!(clearance_mm > 0)) return Status::BadInput(Where{.field = "probe.clearance_mm"}, "must be > 0");
  if (!(search_mm > 0)) return Status::BadInput(Where{.field = "probe.search_mm"}, "must be > 0");
  if (!(probe_feed_mm_per_min > 0)) return Status::BadInput(Where{.field = "probe.feed_mm_per_min"}, "must be > 0");
  if (touch_feed_mm_per_min < 0 || touch_feed_mm_per_min > probe_feed_mm_per_min) {
    return Status::BadInput(Where{.field = "probe.touch_feed_mm_per_min"},
                            "must be 0 (one touch) or in (0, probe feed], got " + FormatExact(touch_feed_mm_per_min),
                            "the second touch is the slow, measuring one");
  }
  if (touch_feed_mm_per_min > 0 && !(backoff_mm > 0 && backoff_mm < clearance_mm)) {
    return Status::BadInput(Where{.field = "probe.backoff_mm"},
                            "must be in (0, clearance) with two touches, got " + FormatExact(backoff_mm));
  }
  if (linuxcnc_log_file.find_first_of(",()") != std::string::npos) {
    return Status::BadInput(Where{.field = "probe.linuxcnc_log_file"},
                            "'" + linuxcnc_log_file + "' has a comma or a parenthesis, which end a LinuxCNC comment",
                            "choose a plain file name");
  }
  if (linuxcnc_time_input > 63) {
    return Status::BadInput(Where{.field = "probe.linuxcnc_time_input"}, "LinuxCNC has analog inputs 0..63");
  }
  if (probe_tool < 1 || probe_tool > 9999) {
    return Status::BadInput(Where{.field = "probe.tool"}, "must be 1..9999, got " + std::to_string(probe_tool),
                            "give the probe's pocket/tool number of the machine's tool table");
  }
  return post.limits.Validate();
}

std::vector<std::string> ProbingDialectNames() { return PostNames(); }

Result<std::string> PostProbing(const metrology::ProbingPlan& plan, std::string_view dialect,
                                const ProbeProgramOptions& options) {
  const PostDialect* post = FindPost(dialect);
  if (post == nullptr) {
    return Status::BadInput(Where{.field = "post.dialect"},
                            "no probing post for dialect '" + std::string(dialect) + "'",
                            "use linuxcnc, fanuc, heidenhain or sinumerik");
  }
  FL_RETURN_IF_ERROR(post->CheckDecimals(options.post.decimals, "post.decimals"));
  return post->FormatProbing(plan, options);
}

Result<std::vector<std::string>> PostProbingBatches(const metrology::ProbingPlan& plan, std::string_view dialect,
                                                    const ProbeProgramOptions& options) {
  const PostDialect* post = FindPost(dialect);
  const std::size_t capacity = post != nullptr ? post->ProbeResultCapacity(options) : 0;
  if (capacity == 0 || plan.points.size() <= capacity) {
    FL_ASSIGN_OR_RETURN(std::string one, PostProbing(plan, dialect, options));
    return std::vector<std::string>{std::move(one)};
  }
  const std::size_t n = (plan.points.size() + capacity - 1) / capacity;
  std::vector<std::string> programs;
  for (std::size_t b = 0; b < n; ++b) {
    metrology::ProbingPlan part;
    const std::size_t first = b * capacity, last = std::min(plan.points.size(), first + capacity);
    part.points.assign(plan.points.begin() + static_cast<long>(first), plan.points.begin() + static_cast<long>(last));
    ProbeProgramOptions o = options;
    if (!options.approaches.empty() && options.approaches.size() == plan.points.size()) {
      o.approaches.assign(options.approaches.begin() + static_cast<long>(first),
                          options.approaches.begin() + static_cast<long>(last));
    }
    o.post.title += " (batch " + std::to_string(b + 1) + " of " + std::to_string(n) + ", points " +
                    std::to_string(part.points.front().id) + "-" + std::to_string(part.points.back().id) + ")";
    FL_ASSIGN_OR_RETURN(std::string text, PostProbing(part, dialect, o));
    programs.push_back(std::move(text));
  }
  return programs;
}

Result<ReachableProbePlan> ReachableProbePoints(const metrology::ProbingPlan& plan,
                                                const ProbeProgramOptions& options) {
  ReachableProbePlan out;
  FL_RETURN_IF_ERROR(internal::Stations(plan, options, &out.left_out).status());
  out.plan = plan;
  out.approaches = options.approaches;
  if (out.left_out.empty()) return out;
  const std::size_t n = plan.points.size(), kept = n - out.left_out.size();
  if (static_cast<double>(kept) < std::ceil(kMinReachableShare * static_cast<double>(n))) {
    const UnreachableProbePoint& first = out.left_out.front();
    return Status::SafetyLimit(
        "the probe reaches only " + std::to_string(kept) + " of the plan's " + std::to_string(n) +
        " points clear of the part (at least " + FormatExact(100 * kMinReachableShare) +
        " % needed for the analysis); e.g. probe point " + std::to_string(first.id) + ": " + first.reason +
        "; no probing program was written. Fix: set the part up so the probe comes down onto the face from "
        "above (no overhang over it), or give a smaller gap (probing.min_gap_mm) or clearance (probing.clearance_mm)");
  }
  out.plan.points.clear();
  out.approaches.clear();
  std::size_t next = 0;  // of left_out, in plan order
  for (std::size_t i = 0; i < n; ++i) {
    if (next < out.left_out.size() && out.left_out[next].index == i) {
      ++next;
      continue;
    }
    out.plan.points.push_back(plan.points[i]);
    if (!options.approaches.empty()) out.approaches.push_back(options.approaches[i]);
  }
  return out;
}

Result<std::string> PostLinuxCncProbing(const metrology::ProbingPlan& plan, const ProbeProgramOptions& options) {
  return PostProbing(plan, "linuxcnc", options);
}

}  // namespace formloop::nc
