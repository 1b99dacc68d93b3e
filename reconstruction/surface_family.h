#pragma once
// The surface families formloop knows, in one registry (spec/reconstruction.md §1):
//
//   reference   fixed analytic surfaces with exact derivatives and curvatures (analytic_surface.h:
//               plane, sphere_cap, cylinder, ellipsoid_cap, saddle, egg_box, franke, blade,
//               tilted_paraboloid); a part names one as {"surface": {"reference": NAME}}
//   parametric  graph surfaces z = f(x, y; parameters) over a rectangle centred at the origin, the kinds
//               of the starter library's families; a part names one as
//               {"surface": {"kind": NAME, "params": {...}, "samples": N}}
//
// Parametric kinds (lengths in mm; s = size_mm):
//   sphere_cap       size_mm, radius_ratio           z = sqrt(R² − x² − y²), R = radius_ratio · s, square s × s
//   ellipsoid_cap    size_mm, aspect, height_ratio   z = c·sqrt(1 − (x/a)² − (y/b)²), s × aspect·s,
//                                                    a = 0.75 s, b = 0.75 aspect s, c = height_ratio · s
//   paraboloid       size_mm, radius_ratio, tilt     z = (x² + y²)/(2R) + tilt·x, R = radius_ratio · s (concave)
//   gaussian_pocket  size_mm, depth_ratio, width_ratio  z = −D·exp(−(x² + y²)/w²), D, w = ratios · s
//   saddle           size_mm, curvature_x, curvature_ratio  z = (c_x x² − c_x·ratio·y²)/2
//   egg_box          size_mm, amplitude_ratio, wavelength_ratio  z = A sin(2πx/λ) sin(2πy/λ)
//   franke           size_mm, amplitude_ratio        z = A·franke(x/s + ½, y/s + ½) (Franke 1979)
//   cylinder         size_mm, length_ratio, radius_ratio  z = sqrt(R² − x²), s across, length_ratio·s long
//   twisted_ruled    chord_mm, span_ratio, twist_deg z = x·tan(twist·(y/span)) (a ruled, twisted blade)
// Adding one is an entry in surface_family.cc's table with its height function, and a test.

#include <cstdint>
#include <functional>
#include <map>
#include <string>
#include <string_view>
#include <vector>

#include <nlohmann/json.hpp>

#include "core/point_set.h"
#include "core/status.h"
#include "reconstruction/analytic_surface.h"
#include "reconstruction/bspline_surface.h"

namespace formloop::recon {

enum class SurfaceFamilyKind { kReference, kParametric };
const char* SurfaceFamilyKindName(SurfaceFamilyKind kind);  // "reference", "parametric"

struct SurfaceFamily {
  std::string name;
  SurfaceFamilyKind kind = SurfaceFamilyKind::kReference;
  std::vector<std::string> parameters;  // empty for a reference surface
  std::string description;
};

// Every family: the reference surfaces in their registry order, then the parametric kinds.
std::vector<SurfaceFamily> SurfaceFamilies();
// nullptr when there is no such family of that kind (a name may be both: "saddle", "franke").
const SurfaceFamily* FindSurfaceFamily(SurfaceFamilyKind kind, std::string_view name);

// A parametric kind with its parameters: its height function and rectangle (x = u, y = v). BadInput
// naming "surface.<kind>" for an unknown kind or a missing or non-positive size.
struct HeightSurface {
  std::function<double(double, double)> z;
  ParamDomain domain;
};
Result<HeightSurface> ParametricSurface(const std::string& kind, const std::map<std::string, double>& params);

// samples × samples grid points of a parametric kind over its rectangle; BadInput naming
// "surface.<kind>" where the parameters give no surface (e.g. a radius below the footprint).
Result<GridSamples> ParametricGrid(const std::string& kind, const std::map<std::string, double>& params, int samples);

// The kind fitted from samples × samples grid points (FitGrid, tolerance 1 µm).
Result<BSplineSurface> FitParametric(const std::string& kind, const std::map<std::string, double>& params, int samples);

// The ideal surface Q of a part from its family, fitted as a B-spline and checked against the defining
// function at check_points random points not used in the fit (seeded): a reference surface through
// FitAnalytic on a samples_u × samples_v grid (checked by distance to the exact surface), a parametric
// kind through FitGrid on its samples × samples grid (checked by vertical distance to z = f(x, y)).
struct FamilySurfaceOptions {
  SurfaceFamilyKind kind = SurfaceFamilyKind::kReference;
  std::string name;
  std::map<std::string, double> params;  // parametric kinds
  int samples_u = 50, samples_v = 50;    // reference surfaces
  int samples = 41;                      // parametric kinds, per direction
  GridFitOptions fit;
  int check_points = 2000;
  std::uint64_t seed = 1;
};
struct FamilySurface {
  BSplineSurface q;
  FitReport report;
  PointSet samples;            // the points the fit used
  nlohmann::json description;  // the family, its parameters and how the fit was checked
};
Result<FamilySurface> BuildFamilySurface(const FamilySurfaceOptions& options);

}  // namespace formloop::recon
