#include "nc-gen/cutter_locations.h"

#include <cmath>

#include "core/number_text.h"

namespace formloop::nc {

std::vector<sim::CutterLocation> CutterLocationsOf(const Toolpath& toolpath) {
  std::vector<sim::CutterLocation> out;
  out.reserve(toolpath.points.size());
  for (std::size_t k = 0; k < toolpath.points.size(); ++k) {
    const ClPoint& p = toolpath.points[k];
    sim::CutterLocation cl;
    cl.centre = p.centre;
    cl.path_length_mm = p.path_length_mm;
    cl.time_s = p.time_s;
    cl.pass = p.pass;
    cl.fed_from_previous = k > 0 && toolpath.points[k - 1].pass == p.pass;
    out.push_back(cl);
  }
  return out;
}

std::vector<sim::CutterLocation> CutterLocationsOfProgram(const std::vector<ProgramMove>& moves, double radius_mm) {
  std::vector<sim::CutterLocation> out;
  double length = 0, time = 0;
  const ProgramMove* previous = nullptr;
  for (const auto& m : moves) {
    if (!m.rapid) {
      if (previous != nullptr && !previous->rapid) {
        const double d = (m.tip - previous->tip).norm();
        length += d;
        time += d / (m.feed_mm_per_min / 60.0);
      }
      sim::CutterLocation cl;
      cl.centre = m.tip + radius_mm * Eigen::Vector3d::UnitZ();
      cl.path_length_mm = length;
      cl.time_s = time;
      cl.line = m.line;
      cl.fed_from_previous = previous != nullptr && !previous->rapid;
      out.push_back(cl);
    }
    previous = &m;
  }
  return out;
}

Result<std::vector<sim::CutterLocation>> ReplannedCutterLocations(const recon::BSplineSurface& q, ToolpathOptions plan,
                                                                  double turn_deg, double feed_scale,
                                                                  std::string* skipped) {
  plan.raster_angle_deg = std::fmod(plan.raster_angle_deg + turn_deg, 360.0);
  plan.feed_mm_per_min *= feed_scale;
  Result<Toolpath> path = PlanRaster(q, plan);
  if (path.status().code() == StatusCode::kBadInput) {
    *skipped = "the path at raster angle " + FormatFixed(plan.raster_angle_deg, 1) + " deg" +
               (feed_scale != 1 ? ", feed x " + FormatFixed(feed_scale, 2) : std::string()) +
               ", cannot be planned on this part: " + path.status().message();
    return std::vector<sim::CutterLocation>{};
  }
  FL_RETURN_IF_ERROR(path.status());
  return CutterLocationsOf(*path);
}

}  // namespace formloop::nc
