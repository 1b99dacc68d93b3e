#include "nc-gen/probe_program.h"

#include <sstream>

#include "core/point_io.h"

namespace formloop::nc {

Status ProbeProgramOptions::Validate() const {
  if (!(ball_radius_mm > 0)) return Status::BadInput(Where{.field = "probe.ball_radius_mm"}, "must be > 0");
  if (!(clearance_mm > 0)) return Status::BadInput(Where{.field = "probe.clearance_mm"}, "must be > 0");
  if (!(search_mm > 0)) return Status::BadInput(Where{.field = "probe.search_mm"}, "must be > 0");
  if (!(probe_feed_mm_per_min > 0)) return Status::BadInput(Where{.field = "probe.feed_mm_per_min"}, "must be > 0");
  return post.limits.Validate();
}

Result<std::string> PostLinuxCncProbing(const metrology::ProbingPlan& plan, const ProbeProgramOptions& options) {
  FL_RETURN_IF_ERROR(options.Validate());
  if (plan.points.empty()) return Status::BadInput("the probing plan has no points");
  const int dec = options.post.decimals;
  auto xyz = [dec](const Eigen::Vector3d& p) {
    return "X" + FormatFixed(p.x(), dec) + " Y" + FormatFixed(p.y(), dec) + " Z" + FormatFixed(p.z(), dec);
  };
  if (options.probe_feed_mm_per_min > options.post.limits.max_feed_mm_per_min) {
    return Status::SafetyLimit("probe feed exceeds the machine's feed limit; no probing program was written");
  }
  std::ostringstream out;
  out << "%\n(" << CommentText(options.post.title) << ")\n";
  out << "(stylus ball radius " << FormatFixed(options.ball_radius_mm, 4)
      << " mm; programmed point = ball centre; " << plan.points.size() << " points)\n";
  out << "G21 G90 G17 G94 G40 G49 G80\n";
  out << "G0 Z" << FormatFixed(options.safe_z_mm, dec) << "\n";
  out << "(PROBEOPEN " << CommentText(options.results_file) << ")\n";
  for (const metrology::ProbePoint& p : plan.points) {
    const Eigen::Vector3d centre_on_surface = p.point + options.ball_radius_mm * p.normal;
    const Eigen::Vector3d start = centre_on_surface + options.clearance_mm * p.normal;
    const Eigen::Vector3d target = centre_on_surface - options.search_mm * p.normal;
    Eigen::Vector3d above = start;
    above.z() = options.safe_z_mm;
    const std::string what = "probe point " + std::to_string(p.id);
    FL_RETURN_IF_ERROR(CheckTravel(options.post.limits, above, what));
    FL_RETURN_IF_ERROR(CheckTravel(options.post.limits, start, what));
    FL_RETURN_IF_ERROR(CheckTravel(options.post.limits, target, what));
    out << "(point " << p.id << ")\n";
    out << "G0 X" << FormatFixed(start.x(), dec) << " Y" << FormatFixed(start.y(), dec) << "\n";
    out << "G0 Z" << FormatFixed(start.z(), dec) << "\n";
    out << "G38.2 " << xyz(target) << " F" << FormatFixed(options.probe_feed_mm_per_min, 0) << "\n";
    out << "G0 " << xyz(start) << "\n";
    out << "G0 Z" << FormatFixed(options.safe_z_mm, dec) << "\n";
  }
  out << "(PROBECLOSE)\nM30\n%\n";
  return out.str();
}

}  // namespace formloop::nc
