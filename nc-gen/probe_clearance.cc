#include "nc-gen/probe_clearance.h"

#include <algorithm>
#include <cmath>
#include <functional>
#include <limits>
#include <string>

#include "core/number_text.h"

namespace formloop::nc::internal {
namespace {

// The gap between a ball of `radius` centred at x and the part: the signed foot-point distance minus
// the radius (negative: the ball overlaps the part); beyond Q's edge the unsigned distance (header).
Result<double> BallGap(const recon::FootPointProjector& part, const Eigen::Vector3d& x, double radius) {
  FL_ASSIGN_OR_RETURN(const recon::FootPoint f, part.Project(x));
  const bool inside = f.deviation_mm < 0 && !f.on_boundary;
  return (inside ? -f.distance_mm : f.distance_mm) - radius;
}

// The sample of a traced segment with the least margin (gap − required).
struct Shortfall {
  double margin = std::numeric_limits<double>::infinity();
  double gap = 0, required = 0;
  Eigen::Vector3d where = Eigen::Vector3d::Zero();
  bool short_of_it() const { return margin < 0; }
};

using GapAt = std::function<Result<double>(const Eigen::Vector3d&)>;

// Sphere tracing from → to (header comment); the requirement runs linearly from req_from to req_to.
// Clear: a Shortfall that is not short of it. Otherwise, from the first sample short of its requirement
// (with the sampling allowance where it steps short) the rest of the move is sampled every
// kProbeReportStepMm for the least gap, which the refusal reports.
Result<Shortfall> Trace(const Eigen::Vector3d& from, const Eigen::Vector3d& to, double req_from, double req_to,
                        const GapAt& gap) {
  const double length = (to - from).norm();
  const double slope = length > 0 ? std::abs(req_to - req_from) / length : 0;
  const auto at = [&](double t) { return from + (length > 0 ? t / length : 0.0) * (to - from); };
  const auto required_at = [&](double t) { return req_from + (length > 0 ? t / length : 0.0) * (req_to - req_from); };
  double t = 0;
  Shortfall worst;
  for (;;) {
    FL_ASSIGN_OR_RETURN(const double g, gap(at(t)));
    const double required = required_at(t);
    const double reach = (g - required) / (1 + slope);  // clear within this distance of the sample
    // The least step beyond the reach: this sample answers for half of it, so it must clear half a
    // step's change more.
    const double allowance = reach < kProbeTraceFineStepMm ? 0.5 * (1 + slope) * kProbeTraceFineStepMm : 0.0;
    if (g - required - allowance < 0) {
      worst = {g - required - allowance, g, required, at(t)};
      break;
    }
    if (t >= length) return worst;
    t = std::min(length, t + std::max(reach, kProbeTraceFineStepMm));
  }
  for (double s = t; s < length;) {
    s = std::min(length, s + kProbeReportStepMm);
    FL_ASSIGN_OR_RETURN(const double g, gap(at(s)));
    const double required = required_at(s);
    if (g - required < worst.margin) worst = {g - required, g, required, at(s)};
  }
  return worst;
}

std::string Point(const Eigen::Vector3d& p) {
  return "(" + FormatFixed(p.x(), 3) + ", " + FormatFixed(p.y(), 3) + ", " + FormatFixed(p.z(), 3) + ")";
}

Status Refusal(const ProbeStation& s, const std::string& body, const std::string& move, const Shortfall& w,
               std::string* finding) {
  const std::string how = w.gap < 0 ? "would enter the part by " + FormatFixed(-w.gap, 3) + " mm"
                                    : "would come within " + FormatFixed(w.gap, 3) + " mm of the part";
  std::string found = "the " + body + " " + how + " (" + FormatFixed(w.required, 3) + " mm required) " + move +
                      ", at " + Point(w.where);
  const std::string message = "probe point " + std::to_string(s.id) + ": " + found +
                              "; the part is in the way; no probing program was written. Fix: leave the point out of "
                              "the plan or probe it with a smaller tilt";
  if (finding != nullptr) *finding = std::move(found);
  return Status::SafetyLimit(message);
}

}  // namespace

Status CheckProbeClearance(const recon::FootPointProjector& part, const ProbeStation& s, const ProbeStation* previous,
                           const ProbeProgramOptions& options, std::string* finding) {
  const double clearance = s.clearance_mm;
  const double g = options.min_gap_mm;
  const double g_probe = std::min(g, 0.5 * clearance * -s.approach.dot(s.normal));
  const Eigen::Vector3d contact = s.surface + options.ball_radius_mm * s.normal;
  const GapAt ball = [&part, &options](const Eigen::Vector3d& x) { return BallGap(part, x, options.ball_radius_mm); };
  if (previous != nullptr) {
    FL_ASSIGN_OR_RETURN(const Shortfall w, Trace(previous->above, s.above, g, g, ball));
    if (w.short_of_it()) {
      return Refusal(s, "stylus ball", "on the traverse at safe Z from point " + std::to_string(previous->id), w,
                     finding);
    }
  }
  {
    FL_ASSIGN_OR_RETURN(const Shortfall w, Trace(s.above, s.start, g_probe, g_probe, ball));
    if (w.short_of_it()) return Refusal(s, "stylus ball", "on the descent from safe Z to its start point", w, finding);
  }
  {
    const Eigen::Vector3d touch_zone = contact - kProbeTouchZone * clearance * s.approach;
    FL_ASSIGN_OR_RETURN(const Shortfall w, Trace(s.start, touch_zone, g_probe, kProbeTouchZone * g_probe, ball));
    if (w.short_of_it())
      return Refusal(s, "stylus ball", "on the probing move before it reaches the surface", w, finding);
  }
  if (options.shank_radius_mm <= 0) return Status::Ok();
  const GapAt shank_ball = [&part, &options](const Eigen::Vector3d& x) {
    return BallGap(part, x, options.shank_radius_mm);
  };
  // The shank above a ball centre x: its axis from x up to safe Z.
  auto shank = [&](const Eigen::Vector3d& x, double required) {
    const Eigen::Vector3d top(x.x(), x.y(), std::max(x.z(), options.safe_z_mm));
    return Trace(x, top, required, required, shank_ball);
  };
  {
    FL_ASSIGN_OR_RETURN(const Shortfall w, shank(s.start, g_probe));
    if (w.short_of_it()) return Refusal(s, "stylus shank", "on the descent from safe Z to its start point", w, finding);
  }
  const int lines = std::max(1, static_cast<int>(std::ceil(clearance / kProbeShankSpacingMm)));
  const double spacing = clearance / lines;
  for (int i = 0; i <= lines; ++i) {
    const double to_go = clearance - i * spacing;
    FL_ASSIGN_OR_RETURN(const Shortfall w,
                        shank(contact - to_go * s.approach, g_probe * to_go / clearance + 0.5 * spacing));
    if (w.short_of_it()) return Refusal(s, "stylus shank", "on the probing move", w, finding);
  }
  return Status::Ok();
}

}  // namespace formloop::nc::internal
