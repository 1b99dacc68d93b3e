#include "reconstruction/bspline_surface.h"

#include <algorithm>
#include <cmath>

#include <Approx_ParametrizationType.hxx>
#include <GeomAPI_PointsToBSplineSurface.hxx>
#include <Standard_Failure.hxx>
#include <TColStd_Array1OfReal.hxx>
#include <TColgp_Array2OfPnt.hxx>
#include <gp_Pnt.hxx>
#include <gp_Vec.hxx>

#include <Eigen/Dense>

#include "core/random.h"
#include "reconstruction/point_checks.h"

namespace formloop::recon {
namespace {

Eigen::Vector3d ToEigen(const gp_Pnt& p) { return {p.X(), p.Y(), p.Z()}; }
Eigen::Vector3d ToEigen(const gp_Vec& v) { return {v.X(), v.Y(), v.Z()}; }

std::string OcctMessage(const Standard_Failure& failure) {
  const char* text = failure.GetMessageString();
  std::string message = failure.DynamicType()->Name();
  if (text != nullptr && *text != '\0') message += ": " + std::string(text);
  return message;
}

// Maps the knots of one direction linearly so that [first knot, last knot] becomes [lo, hi].
void RemapKnots(const Handle(Geom_BSplineSurface) & geom, bool u_direction, double lo, double hi) {
  TColStd_Array1OfReal knots(1, u_direction ? geom->NbUKnots() : geom->NbVKnots());
  if (u_direction) {
    geom->UKnots(knots);
  } else {
    geom->VKnots(knots);
  }
  const double k0 = knots(knots.Lower()), k1 = knots(knots.Upper());
  for (int i = knots.Lower(); i <= knots.Upper(); ++i) {
    knots(i) = i == knots.Lower() ? lo : i == knots.Upper() ? hi : lo + (knots(i) - k0) / (k1 - k0) * (hi - lo);
  }
  if (u_direction) {
    geom->SetUKnots(knots);
  } else {
    geom->SetVKnots(knots);
  }
}

}  // namespace

// ---------------------------------------------------------------------------------------------
// BSplineSurface

BSplineSurface::BSplineSurface(Handle(Geom_BSplineSurface) geom) : geom_(std::move(geom)) {}

ParamDomain BSplineSurface::domain() const {
  ParamDomain d;
  geom_->Bounds(d.u_min, d.u_max, d.v_min, d.v_max);
  return d;
}

Eigen::Vector3d BSplineSurface::Point(double u, double v) const { return ToEigen(geom_->Value(u, v)); }

Eigen::Vector3d BSplineSurface::Normal(double u, double v) const {
  // n = S_u × S_v / |S_u × S_v|: the fits keep the source's parameter directions (grid index i
  // along u, j along v), so this agrees with the analytic orientation.
  gp_Pnt p;
  gp_Vec su, sv;
  geom_->D1(u, v, p, su, sv);
  SurfaceDerivatives d;
  d.su = ToEigen(su);
  d.sv = ToEigen(sv);
  return NormalFromDerivatives(d);
}

SurfaceDerivatives BSplineSurface::Derivatives(double u, double v) const {
  gp_Pnt p;
  gp_Vec su, sv, suu, svv, suv;
  geom_->D2(u, v, p, su, sv, suu, svv, suv);
  SurfaceDerivatives d;
  d.p = ToEigen(p);
  d.su = ToEigen(su);
  d.sv = ToEigen(sv);
  d.suu = ToEigen(suu);
  d.suv = ToEigen(suv);
  d.svv = ToEigen(svv);
  return d;
}

int BSplineSurface::u_degree() const { return geom_->UDegree(); }
int BSplineSurface::v_degree() const { return geom_->VDegree(); }
int BSplineSurface::u_poles() const { return geom_->NbUPoles(); }
int BSplineSurface::v_poles() const { return geom_->NbVPoles(); }

// ---------------------------------------------------------------------------------------------
// Sampling

namespace {
double GridParam(double lo, double hi, int i, int n) {
  if (n <= 1) return lo;
  if (i == n - 1) return hi;  // exact corner
  return lo + (hi - lo) * static_cast<double>(i) / (n - 1);
}
}  // namespace

GridSamples SampleGrid(const AnalyticSurface& surface, int nu, int nv) {
  GridSamples samples;
  samples.nu = nu;
  samples.nv = nv;
  samples.domain = surface.domain();
  samples.points.reserve(static_cast<std::size_t>(std::max(nu, 0)) * static_cast<std::size_t>(std::max(nv, 0)));
  for (int j = 0; j < nv; ++j) {
    const double v = GridParam(samples.domain.v_min, samples.domain.v_max, j, nv);
    for (int i = 0; i < nu; ++i) {
      samples.points.push_back(surface.Point(GridParam(samples.domain.u_min, samples.domain.u_max, i, nu), v));
    }
  }
  return samples;
}

PointSet SampleGridPoints(const AnalyticSurface& surface, int nu, int nv) {
  PointSet set;
  const ParamDomain dom = surface.domain();
  std::vector<double> us, vs, k1s, k2s;
  for (int j = 0; j < nv; ++j) {
    const double v = GridParam(dom.v_min, dom.v_max, j, nv);
    for (int i = 0; i < nu; ++i) {
      const double u = GridParam(dom.u_min, dom.u_max, i, nu);
      const SurfaceDerivatives d = surface.Derivatives(u, v);
      const PrincipalCurvatures k = CurvaturesFromDerivatives(d);
      set.points.push_back(d.p);
      set.normals.push_back(NormalFromDerivatives(d));
      us.push_back(u);
      vs.push_back(v);
      k1s.push_back(k.k1);
      k2s.push_back(k.k2);
    }
  }
  set.SetScalar("u", std::move(us));
  set.SetScalar("v", std::move(vs));
  set.SetScalar("k1", std::move(k1s));
  set.SetScalar("k2", std::move(k2s));
  return set;
}

// ---------------------------------------------------------------------------------------------
// Fitting

Status GridFitOptions::Validate() const {
  if (degree_min < 1 || degree_min > 25) {
    return Status::BadInput(Where{.field = "degree_min"}, "degree " + std::to_string(degree_min) + " is out of range",
                            "use a degree between 1 and 25 (3 = cubic)");
  }
  if (degree_max < degree_min || degree_max > 25) {
    return Status::BadInput(Where{.field = "degree_max"},
                            "degree_max " + std::to_string(degree_max) +
                                " must lie in [degree_min = " + std::to_string(degree_min) + ", 25]",
                            "raise degree_max or lower degree_min");
  }
  if (!(tolerance_mm > 0) || !std::isfinite(tolerance_mm)) {
    return Status::BadInput(Where{.field = "tolerance_mm"}, "tolerance must be a positive finite number of mm",
                            "use e.g. 1e-4");
  }
  return Status::Ok();
}

nlohmann::json FitReport::ToJson() const {
  return nlohmann::json{
      {"method", method},
      {"n_points", n_points},
      {"residual", residual},
      {"rms_mm", rms_mm},
      {"max_mm", max_mm},
      {"max_at_mm", {max_at.x(), max_at.y(), max_at.z()}},
      {"n_check", n_check},
      {"check", "distance from the analytic S(u, v) to its foot point on Q at seeded random (u, v)"},
      {"check_rms_mm", check_rms_mm},
      {"check_max_mm", check_max_mm},
      {"check_max_at_mm", {check_max_at.x(), check_max_at.y(), check_max_at.z()}},
      {"details", details},
      {"notes", notes},
  };
}

Result<BSplineSurface> FitGrid(const GridSamples& samples, const GridFitOptions& options, FitReport* report) {
  FL_RETURN_IF_ERROR(options.Validate().WithContext("grid fit options"));
  if (samples.nu < 2 || samples.nv < 2) {
    return Status::BadInput("grid fit: need at least 2 × 2 samples, got " + std::to_string(samples.nu) + " × " +
                            std::to_string(samples.nv));
  }
  if (samples.points.size() != static_cast<std::size_t>(samples.nu) * static_cast<std::size_t>(samples.nv)) {
    return Status::Internal("grid fit: " + std::to_string(samples.points.size()) + " points for a " +
                            std::to_string(samples.nu) + " × " + std::to_string(samples.nv) + " grid");
  }
  const ParamDomain& dom = samples.domain;
  if (!(dom.u_max > dom.u_min) || !(dom.v_max > dom.v_min)) {
    return Status::BadInput("grid fit: empty parameter domain");
  }
  if (options.interpolate && (samples.nu < 4 || samples.nv < 4)) {
    return Status::BadInput("grid fit: cubic interpolation needs at least 4 × 4 samples");
  }
  if (options.interpolate && (samples.nu > kMaxInterpolationSamples || samples.nv > kMaxInterpolationSamples)) {
    return Status::BadInput("grid fit: OpenCASCADE 7.6 interpolation is unstable beyond " +
                            std::to_string(kMaxInterpolationSamples) + " samples per direction (got " +
                            std::to_string(samples.nu) + " × " + std::to_string(samples.nv) +
                            "): it passes through the samples but wiggles by up to 0.1 mm between them. Fix: "
                            "use approximation (interpolate = false) with a small tolerance, or a coarser grid");
  }
  for (std::size_t k = 0; k < samples.points.size(); ++k) {
    if (!samples.points[k].allFinite()) {
      return Status::BadInput("grid fit: sample " + std::to_string(k) + " is not finite");
    }
  }
  FL_RETURN_IF_ERROR(CheckSpansASurface(samples.points).WithContext("grid fit"));

  TColgp_Array2OfPnt grid(1, samples.nu, 1, samples.nv);
  for (int j = 0; j < samples.nv; ++j) {
    for (int i = 0; i < samples.nu; ++i) {
      const Eigen::Vector3d& p = samples.points[static_cast<std::size_t>(j) * samples.nu + i];
      grid(i + 1, j + 1) = gp_Pnt(p.x(), p.y(), p.z());
    }
  }

  Handle(Geom_BSplineSurface) geom;
  try {
    GeomAPI_PointsToBSplineSurface fit;
    if (options.interpolate) {
      fit.Interpolate(grid, Approx_IsoParametric);
    } else {
      fit.Init(grid, Approx_IsoParametric, options.degree_min, options.degree_max, GeomAbs_C2, options.tolerance_mm);
    }
    if (!fit.IsDone()) {
      return Status::Failed("grid fit: GeomAPI_PointsToBSplineSurface did not converge on " +
                            std::to_string(samples.nu) + " × " + std::to_string(samples.nv) +
                            " samples. Try a larger tolerance or a higher degree_max");
    }
    geom = Handle(Geom_BSplineSurface)::DownCast(fit.Surface()->Copy());
    // Iso-parametric parameters are uniform over [first, last knot]; map them onto the domain so
    // that Q(u_i, v_j) ≈ sample_ij.
    RemapKnots(geom, true, dom.u_min, dom.u_max);
    RemapKnots(geom, false, dom.v_min, dom.v_max);
  } catch (const Standard_Failure& failure) {
    return Status::Internal("grid fit: OpenCASCADE failed: " + OcctMessage(failure));
  }
  BSplineSurface surface(geom);

  if (report != nullptr) {
    report->method = options.interpolate ? "occt-grid-interpolation" : "occt-grid-approximation";
    report->n_points = static_cast<int>(samples.points.size());
    double sum2 = 0, max = -1;
    for (int j = 0; j < samples.nv; ++j) {
      const double v = GridParam(dom.v_min, dom.v_max, j, samples.nv);
      for (int i = 0; i < samples.nu; ++i) {
        const Eigen::Vector3d& p = samples.points[static_cast<std::size_t>(j) * samples.nu + i];
        const double e = (surface.Point(GridParam(dom.u_min, dom.u_max, i, samples.nu), v) - p).norm();
        sum2 += e * e;
        if (e > max) {
          max = e;
          report->max_at = p;
        }
      }
    }
    report->rms_mm = std::sqrt(sum2 / static_cast<double>(samples.points.size()));
    report->max_mm = max;
  }
  return surface;
}

Result<BSplineSurface> FitAnalytic(const AnalyticSurface& surface, int nu, int nv, const GridFitOptions& options,
                                   int n_check, unsigned long long seed, FitReport* report) {
  if (n_check < 0) return Status::BadInput("fit check: n_check must be >= 0, got " + std::to_string(n_check));
  const GridSamples samples = SampleGrid(surface, nu, nv);
  FitReport local;
  FL_ASSIGN_OR_RETURN(BSplineSurface q, FitGrid(samples, options, &local));
  const ParamDomain dom = surface.domain();
  Rng rng(seed);
  double sum2 = 0, max = 0;
  for (int k = 0; k < n_check; ++k) {
    const double u = rng.Uniform(dom.u_min, dom.u_max);
    const double v = rng.Uniform(dom.v_min, dom.v_max);
    const Eigen::Vector3d p = surface.Point(u, v);
    FL_ASSIGN_OR_RETURN(FootPoint foot, ProjectFrom(q, p, u, v));
    const double e = (p - foot.foot).norm();
    sum2 += e * e;
    if (e > max) {
      max = e;
      local.check_max_at = p;
    }
  }
  local.n_check = n_check;
  local.check_rms_mm = n_check > 0 ? std::sqrt(sum2 / n_check) : 0;
  local.check_max_mm = max;
  if (report != nullptr) *report = local;
  return q;
}

// Foot points (FootPoint, Project, ProjectFrom) live in foot_point.cc.

}  // namespace formloop::recon
