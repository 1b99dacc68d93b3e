#include "nc-gen/raster_estimate.h"

#include <algorithm>
#include <cmath>

#include <Eigen/Geometry>

namespace formloop::nc {

RasterEstimate EstimateRaster(const DerivativesAt& surface, const recon::ParamDomain& domain,
                              const ToolpathOptions& options) {
  constexpr int kSamples = 33;
  RasterEstimate e;
  const double h = options.scallop_um * 1e-3;
  const double chord = options.chord_tolerance_um * 1e-3;
  const double r = options.tool.radius_mm;
  const double step_over = std::sqrt(8.0 * h * r);
  const double du = domain.u_span() / (kSamples - 1), dv = domain.v_span() / (kSamples - 1);
  double points_per_mm2 = 0;  // sum over samples of area / (step-over * spacing)
  for (int i = 0; i < kSamples; ++i) {
    for (int j = 0; j < kSamples; ++j) {
      const double u = domain.u_min + du * i, v = domain.v_min + dv * j;
      const recon::SurfaceDerivatives d = surface(u, v);
      // Trapezoidal weights: the edge samples stand for half a cell.
      const double w = (i == 0 || i == kSamples - 1 ? 0.5 : 1.0) * (j == 0 || j == kSamples - 1 ? 0.5 : 1.0);
      const double area = w * d.su.cross(d.sv).norm() * du * dv;
      if (!std::isfinite(area)) continue;
      const recon::PrincipalCurvatures k = recon::CurvaturesFromDerivatives(d);
      const double kappa = std::max(std::abs(k.k1), std::abs(k.k2));
      double spacing = options.max_point_spacing_mm;
      if (std::isfinite(kappa) && kappa > 0) spacing = std::min(spacing, std::sqrt(8.0 * chord / kappa));
      e.area_mm2 += area;
      points_per_mm2 += area / (step_over * spacing);
    }
  }
  e.step_over_mm = step_over;
  e.length_mm = e.area_mm2 / step_over;
  e.spacing_mm = points_per_mm2 > 0 ? e.length_mm / points_per_mm2 : options.max_point_spacing_mm;
  const double extent = std::sqrt(std::max(e.area_mm2, 0.0));
  e.passes = extent / step_over;
  e.cl_points = points_per_mm2;
  e.cutting_s = e.length_mm / options.feed_mm_per_min * 60.0;
  return e;
}

RasterEstimate EstimateRaster(const recon::BSplineSurface& q, const ToolpathOptions& options) {
  return EstimateRaster([&q](double u, double v) { return q.Derivatives(u, v); }, q.domain(), options);
}

double ProbingSeconds(double points, double clearance_mm, double search_mm, double probe_feed_mm_per_min) {
  return points * (clearance_mm + search_mm) / probe_feed_mm_per_min * 60.0;
}

}  // namespace formloop::nc
