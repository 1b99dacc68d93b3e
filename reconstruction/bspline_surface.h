#pragma once
// The ideal surface Q as an OpenCASCADE B-spline surface, its fit from gridded samples, STEP export
// and import, and foot-point projection (spec/reconstruction.md §1, §2, §4).
//
// Everything downstream (tool paths, deviations, compensation) works on BSplineSurface; its fit
// report travels with it so fit error is never mistaken for machining error.

#include <filesystem>
#include <memory>
#include <string>
#include <vector>

#include <Eigen/Core>
#include <Geom_BSplineSurface.hxx>
#include <nlohmann/json.hpp>

#include "core/point_set.h"
#include "core/status.h"
#include "reconstruction/analytic_surface.h"
#include "reconstruction/foot_point.h"

namespace formloop::recon {

class Trim;  // reconstruction/trim.h

class BSplineSurface {
 public:
  BSplineSurface() = default;
  explicit BSplineSurface(Handle(Geom_BSplineSurface) geom);

  bool valid() const { return !geom_.IsNull(); }
  const Handle(Geom_BSplineSurface) & geom() const { return geom_; }
  ParamDomain domain() const;
  Eigen::Vector3d Point(double u, double v) const;
  // Unit normal, oriented like the source surface (n_z > 0 for the reference surfaces).
  Eigen::Vector3d Normal(double u, double v) const;
  SurfaceDerivatives Derivatives(double u, double v) const;
  int u_degree() const;
  int v_degree() const;
  int u_poles() const;
  int v_poles() const;

  // The trimmed domain (reconstruction/trim.h): which (u, v) belong to the part, the loops that bound
  // it and the faces beside it; null when Q is the whole patch over domain(). Copies share it.
  const Trim* trim() const { return trim_.get(); }
  const std::shared_ptr<const Trim>& shared_trim() const { return trim_; }
  void set_trim(std::shared_ptr<const Trim> trim) { trim_ = std::move(trim); }

 private:
  Handle(Geom_BSplineSurface) geom_;
  std::shared_ptr<const Trim> trim_;
};

// Samples of a surface on a regular grid in parameter space, row-major: index = i_v * nu + i_u.
struct GridSamples {
  int nu = 0, nv = 0;
  ParamDomain domain;
  std::vector<Eigen::Vector3d> points;  // mm
};

// Regular grid of nu × nv samples over the surface's domain (corners included).
GridSamples SampleGrid(const AnalyticSurface& surface, int nu, int nv);
// The same samples as a PointSet with normals and scalars "u", "v", "k1", "k2".
PointSet SampleGridPoints(const AnalyticSurface& surface, int nu, int nv);

// GeomAPI_PointsToBSplineSurface::Interpolate (OpenCASCADE 7.6.3) passes through the samples but
// oscillates by 1e-2..1e-1 mm between them once a direction has 73 or more samples (measured on the
// reference surfaces, even on a plane); FitGrid refuses larger interpolation grids.
inline constexpr int kMaxInterpolationSamples = 72;

struct GridFitOptions {
  int degree_min = 3;  // cubic is the CAM norm; OpenCASCADE may raise it up to degree_max
  int degree_max = 5;
  double tolerance_mm = 1e-4;  // approximation tolerance handed to GeomAPI_PointsToBSplineSurface
  bool interpolate = false;    // true: pass through every sample (at most kMaxInterpolationSamples a side)
  Status Validate() const;
};

struct FitReport {
  std::string method;  // e.g. "occt-grid-approximation"
  int n_points = 0;
  // What rms_mm/max_mm measure; FitGrid: the parametric residual |Q(u_i, v_j) - sample_ij|.
  std::string residual = "parametric: |Q(u_i, v_j) - sample_ij| at the grid nodes (an upper bound of the distance)";
  double rms_mm = 0;  // residual at the fitted samples
  double max_mm = 0;
  Eigen::Vector3d max_at = Eigen::Vector3d::Zero();  // sample where the max residual occurs
  // Filled when an analytic truth is known: error at check points not used in the fit.
  int n_check = 0;
  double check_rms_mm = 0;
  double check_max_mm = 0;
  Eigen::Vector3d check_max_at = Eigen::Vector3d::Zero();  // check point where check_max_mm occurs
  // Method-specific facts (control net, smoothing weight, GCV score, iterations, knots inserted...),
  // copied into the JSON report as "details".
  nlohmann::json details = nlohmann::json::object();
  // Plain-language statements the user must see, e.g. that the control net cannot represent the
  // surface to the requested tolerance, with the figure reached.
  std::vector<std::string> notes;
  nlohmann::json ToJson() const;
};

// Fits a B-spline through gridded samples with GeomAPI_PointsToBSplineSurface. The B-spline's
// parameters are mapped onto samples.domain, so Q(u, v) ≈ S(u, v) at the grid nodes.
Result<BSplineSurface> FitGrid(const GridSamples& samples, const GridFitOptions& options, FitReport* report);

// Samples `surface` on an nu × nv grid, fits it, and checks against the analytic truth at
// n_check seeded random points inside the domain.
Result<BSplineSurface> FitAnalytic(const AnalyticSurface& surface, int nu, int nv, const GridFitOptions& options,
                                   int n_check, unsigned long long seed, FitReport* report);

// STEP AP214 file holding one B-spline face: the surface bounded by its parameter domain, or, when Q
// has a trim, the trimmed face (read back by ReadCadFace with the same trim). The OpenCASCADE banners
// are kept off stdout.
Status WriteStep(const std::filesystem::path& path, const BSplineSurface& surface, const std::string& name);
// Reads face `face_index` (0-based) of a STEP file and returns its underlying B-spline surface
// (converted when the face holds another surface type).
Result<BSplineSurface> ReadStep(const std::filesystem::path& path, int face_index = 0);

// Foot points on Q (spec §4): FootPoint, FootPointProjector, Project and ProjectFrom are declared in
// reconstruction/foot_point.h, included above.

}  // namespace formloop::recon
