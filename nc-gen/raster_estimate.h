#pragma once
// How big a section-plane raster (nc-gen/toolpath.h) will be, estimated from the surface and the plan
// before planning it, so a scallop typed in the wrong unit is refused in a second instead of planning for
// hours (core/work_estimate.h).
//
// Q is sampled on a 33 x 33 parameter grid. The passes are l = sqrt(8 h r) apart on the surface (the flat
// step-over of PlanRaster's rule; curvature changes it by a factor of order one), so the path is about
// A / l long (A the area of Q), cut at the feed. Points along a pass are at most max_point_spacing_mm
// apart and closer where the chord tolerance c needs it on a pass of curvature kappa: sqrt(8 c / kappa)
// for the largest principal curvature at each sample. The figures are estimates within a factor of
// about two (the demo part: 306 passes, 66,750 points planned; estimated 300 and 65,000).

#include <functional>

#include "core/work_estimate.h"
#include "nc-gen/toolpath.h"
#include "reconstruction/analytic_surface.h"

namespace formloop::nc {

struct RasterEstimate {
  double area_mm2 = 0;
  double step_over_mm = 0;  // flat step-over sqrt(8 h r)
  double spacing_mm = 0;    // mean point spacing along a pass
  double passes = 0;
  double length_mm = 0;  // cutting path
  double cl_points = 0;
  double cutting_s = 0;  // at the feed, rapids and leads aside
  // The option that sets the point count: "chord_tolerance_um" when the chord tolerance packs the points
  // closer than the step-over, else "scallop_um".
  const char* driver() const { return spacing_mm < step_over_mm ? "chord_tolerance_um" : "scallop_um"; }
};

using DerivativesAt = std::function<recon::SurfaceDerivatives(double u, double v)>;

RasterEstimate EstimateRaster(const DerivativesAt& surface, const recon::ParamDomain& domain,
                              const ToolpathOptions& options);
RasterEstimate EstimateRaster(const recon::BSplineSurface& q, const ToolpathOptions& options);

// Probing time of `points` points: each approached from the clearance and probed to the search distance
// at the probing feed (rapids aside).
double ProbingSeconds(double points, double clearance_mm, double search_mm, double probe_feed_mm_per_min);

// Memory and output per cutter location, measured on the demo part (formloop run: about 2.4 kB of peak
// memory and 0.4 kB written per planned point; a program alone about 0.1 kB per line).
inline constexpr double kRunBytesPerClPoint = 2500;
inline constexpr double kRunOutputBytesPerClPoint = 400;
inline constexpr double kPathBytesPerClPoint = 800;

}  // namespace formloop::nc
