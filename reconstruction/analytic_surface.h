#pragma once
// Analytic reference surfaces (spec/reconstruction.md §1): exact point, unit normal and principal
// curvatures on a stated parameter domain. Used by regression runs and tests as ground truth.
//
// Frames and units: every surface lives in the part frame, mm. Parameters (u, v) are in mm too; for
// graph surfaces (z = f(x, y)) u = x and v = y.
//
// Orientation: the unit normal n = (S_u × S_v)/|S_u × S_v| points away from the material (upwards,
// n_z > 0, for every reference surface), which is the side the tool and the probe come from.
//
// Curvature sign: a normal curvature is positive where the surface bends away from n (convex as seen
// by the tool, e.g. a sphere cap) and negative where it bends towards n (concave: a ball of radius r
// gouges where a principal curvature is below -1/r).

#include <memory>
#include <string>
#include <vector>

#include <Eigen/Core>

#include "core/status.h"

namespace formloop::recon {

struct ParamDomain {
  double u_min = 0, u_max = 1, v_min = 0, v_max = 1;  // mm
  bool Contains(double u, double v, double tol = 0) const {
    return u >= u_min - tol && u <= u_max + tol && v >= v_min - tol && v <= v_max + tol;
  }
  double u_span() const { return u_max - u_min; }
  double v_span() const { return v_max - v_min; }
};

// S and its partial derivatives up to second order at (u, v).
struct SurfaceDerivatives {
  Eigen::Vector3d p, su, sv, suu, suv, svv;
};

struct PrincipalCurvatures {
  double k1 = 0, k2 = 0;       // 1/mm, k1 >= k2, sign as in the header comment
  Eigen::Vector3d dir1, dir2;  // unit principal directions in 3-D (tangent to the surface)
  double mean() const { return 0.5 * (k1 + k2); }
  double gaussian() const { return k1 * k2; }
};

// Unit normal and principal curvatures from exact derivatives (first and second fundamental forms).
Eigen::Vector3d NormalFromDerivatives(const SurfaceDerivatives& d);
PrincipalCurvatures CurvaturesFromDerivatives(const SurfaceDerivatives& d);

class AnalyticSurface {
 public:
  virtual ~AnalyticSurface() = default;
  virtual std::string name() const = 0;         // stable identifier, e.g. "saddle"
  virtual std::string description() const = 0;  // formula and parameters, one line
  virtual ParamDomain domain() const = 0;
  // True when u = x and v = y (z = f(x, y)).
  virtual bool is_graph() const = 0;
  // Exact analytic derivatives; valid on domain() (and a little beyond).
  virtual SurfaceDerivatives Derivatives(double u, double v) const = 0;

  Eigen::Vector3d Point(double u, double v) const { return Derivatives(u, v).p; }
  Eigen::Vector3d Normal(double u, double v) const { return NormalFromDerivatives(Derivatives(u, v)); }
  PrincipalCurvatures Curvatures(double u, double v) const { return CurvaturesFromDerivatives(Derivatives(u, v)); }
};

// The registry of reference surfaces: plane, sphere_cap, cylinder, ellipsoid_cap, saddle, egg_box,
// franke, blade, tilted_paraboloid. Adding one is a class, a registry line and a test.
std::vector<std::string> ReferenceSurfaceNames();
Result<std::unique_ptr<AnalyticSurface>> MakeReferenceSurface(const std::string& name);

}  // namespace formloop::recon
