#include "reconstruction/surface_family.h"

#include <cmath>
#include <limits>
#include <memory>
#include <numbers>

#include "core/number_text.h"
#include "core/random.h"

namespace formloop::recon {
namespace {

double Param(const std::map<std::string, double>& p, const std::string& name) {
  auto it = p.find(name);
  return it == p.end() ? std::numeric_limits<double>::quiet_NaN() : it->second;
}

double Franke(double x, double y) {
  return 0.75 * std::exp(-(std::pow(9 * x - 2, 2) + std::pow(9 * y - 2, 2)) / 4) +
         0.75 * std::exp(-std::pow(9 * x + 1, 2) / 49 - (9 * y + 1) / 10) +
         0.5 * std::exp(-(std::pow(9 * x - 7, 2) + std::pow(9 * y - 3, 2)) / 4) -
         0.2 * std::exp(-std::pow(9 * x - 4, 2) - std::pow(9 * y - 7, 2));
}

// A parametric kind: its parameters, its formula, and the height function with its extent (sx, sy).
struct Kind {
  const char* name;
  std::vector<std::string> parameters;
  const char* formula;
  std::function<double(double, double)> (*make)(const std::map<std::string, double>& p, double* sx, double* sy);
};

const std::vector<Kind>& Kinds() {
  static const std::vector<Kind> kKinds = {
      {"sphere_cap",
       {"size_mm", "radius_ratio"},
       "z = sqrt(R^2 - x^2 - y^2), R = radius_ratio s, s x s",
       [](const std::map<std::string, double>& p, double* sx, double* sy) -> std::function<double(double, double)> {
         const double s = Param(p, "size_mm"), r = Param(p, "radius_ratio") * s;
         *sx = *sy = s;
         return [r](double x, double y) { return std::sqrt(r * r - x * x - y * y); };
       }},
      {"ellipsoid_cap",
       {"size_mm", "aspect", "height_ratio"},
       "z = c sqrt(1 - (x/a)^2 - (y/b)^2), s x aspect s, a = 0.75 s, b = 0.75 aspect s, c = height_ratio s",
       [](const std::map<std::string, double>& p, double* sx, double* sy) -> std::function<double(double, double)> {
         const double s = Param(p, "size_mm"), aspect = Param(p, "aspect");
         const double a = 0.75 * s, b = 0.75 * aspect * s, c = Param(p, "height_ratio") * s;
         *sx = s;
         *sy = aspect * s;
         return [a, b, c](double x, double y) { return c * std::sqrt(1 - (x / a) * (x / a) - (y / b) * (y / b)); };
       }},
      {"paraboloid",
       {"size_mm", "radius_ratio", "tilt"},
       "z = (x^2 + y^2)/(2R) + tilt x, R = radius_ratio s",
       [](const std::map<std::string, double>& p, double* sx, double* sy) -> std::function<double(double, double)> {
         const double s = Param(p, "size_mm"), r = Param(p, "radius_ratio") * s, t = Param(p, "tilt");
         *sx = *sy = s;
         return [r, t](double x, double y) { return (x * x + y * y) / (2 * r) + t * x; };
       }},
      {"gaussian_pocket",
       {"size_mm", "depth_ratio", "width_ratio"},
       "z = -D exp(-(x^2 + y^2)/w^2), D = depth_ratio s, w = width_ratio s",
       [](const std::map<std::string, double>& p, double* sx, double* sy) -> std::function<double(double, double)> {
         const double s = Param(p, "size_mm"), d = Param(p, "depth_ratio") * s, w = Param(p, "width_ratio") * s;
         *sx = *sy = s;
         return [d, w](double x, double y) { return -d * std::exp(-(x * x + y * y) / (w * w)); };
       }},
      {"saddle",
       {"size_mm", "curvature_x", "curvature_ratio"},
       "z = (c_x x^2 - c_x ratio y^2)/2",
       [](const std::map<std::string, double>& p, double* sx, double* sy) -> std::function<double(double, double)> {
         const double s = Param(p, "size_mm"), cx = Param(p, "curvature_x"), cy = cx * Param(p, "curvature_ratio");
         *sx = *sy = s;
         return [cx, cy](double x, double y) { return 0.5 * (cx * x * x - cy * y * y); };
       }},
      {"egg_box",
       {"size_mm", "amplitude_ratio", "wavelength_ratio"},
       "z = A sin(2 pi x/l) sin(2 pi y/l), A = amplitude_ratio s, l = wavelength_ratio s",
       [](const std::map<std::string, double>& p, double* sx, double* sy) -> std::function<double(double, double)> {
         const double s = Param(p, "size_mm"), a = Param(p, "amplitude_ratio") * s,
                      l = Param(p, "wavelength_ratio") * s;
         *sx = *sy = s;
         return [a, l](double x, double y) {
           return a * std::sin(2 * std::numbers::pi * x / l) * std::sin(2 * std::numbers::pi * y / l);
         };
       }},
      {"franke",
       {"size_mm", "amplitude_ratio"},
       "z = A franke(x/s + 1/2, y/s + 1/2), A = amplitude_ratio s",
       [](const std::map<std::string, double>& p, double* sx, double* sy) -> std::function<double(double, double)> {
         const double s = Param(p, "size_mm"), a = Param(p, "amplitude_ratio") * s;
         *sx = *sy = s;
         return [s, a](double x, double y) { return a * Franke(x / s + 0.5, y / s + 0.5); };
       }},
      {"cylinder",
       {"size_mm", "length_ratio", "radius_ratio"},
       "z = sqrt(R^2 - x^2), s across, length_ratio s long, R = radius_ratio s",
       [](const std::map<std::string, double>& p, double* sx, double* sy) -> std::function<double(double, double)> {
         const double s = Param(p, "size_mm"), r = Param(p, "radius_ratio") * s;
         *sx = s;
         *sy = Param(p, "length_ratio") * s;
         return [r](double x, double) { return std::sqrt(r * r - x * x); };
       }},
      {"twisted_ruled",
       {"chord_mm", "span_ratio", "twist_deg"},
       "z = x tan(twist (y/span)), span = span_ratio chord",
       [](const std::map<std::string, double>& p, double* sx, double* sy) -> std::function<double(double, double)> {
         const double c = Param(p, "chord_mm"), span = Param(p, "span_ratio") * c;
         const double twist = Param(p, "twist_deg") * std::numbers::pi / 180;
         *sx = c;
         *sy = span;
         return [span, twist](double x, double y) { return x * std::tan(twist * (y / span)); };
       }},
  };
  return kKinds;
}

}  // namespace

const char* SurfaceFamilyKindName(SurfaceFamilyKind kind) {
  return kind == SurfaceFamilyKind::kReference ? "reference" : "parametric";
}

std::vector<SurfaceFamily> SurfaceFamilies() {
  std::vector<SurfaceFamily> out;
  for (const std::string& name : ReferenceSurfaceNames()) {
    const auto surface = MakeReferenceSurface(name);
    out.push_back({name, SurfaceFamilyKind::kReference, {}, surface.ok() ? (*surface)->description() : ""});
  }
  for (const Kind& k : Kinds()) out.push_back({k.name, SurfaceFamilyKind::kParametric, k.parameters, k.formula});
  return out;
}

const SurfaceFamily* FindSurfaceFamily(SurfaceFamilyKind kind, std::string_view name) {
  static const std::vector<SurfaceFamily> kFamilies = SurfaceFamilies();
  for (const SurfaceFamily& f : kFamilies) {
    if (f.kind == kind && f.name == name) return &f;
  }
  return nullptr;
}

Result<HeightSurface> ParametricSurface(const std::string& kind, const std::map<std::string, double>& p) {
  const Where where{.field = "surface." + kind};
  const Kind* found = nullptr;
  for (const Kind& k : Kinds()) {
    if (kind == k.name) found = &k;
  }
  if (found == nullptr) {
    std::string names;
    for (const Kind& k : Kinds()) names += (names.empty() ? "" : ", ") + std::string(k.name);
    return Status::BadInput(where, "unknown surface kind", "use " + names);
  }
  double sx = 0, sy = 0;
  std::function<double(double, double)> f = found->make(p, &sx, &sy);
  if (!(sx > 0) || !(sy > 0) || !std::isfinite(sx) || !std::isfinite(sy)) {
    return Status::BadInput(where, "missing or non-positive size parameter");
  }
  return HeightSurface{std::move(f), {-sx / 2, sx / 2, -sy / 2, sy / 2}};
}

Result<GridSamples> ParametricGrid(const std::string& kind, const std::map<std::string, double>& p, int samples) {
  const Where where{.field = "surface." + kind};
  if (samples < 2) return Status::BadInput(where, "needs at least 2 samples per direction");
  FL_ASSIGN_OR_RETURN(const HeightSurface height, ParametricSurface(kind, p));
  const double sx = height.domain.u_span(), sy = height.domain.v_span();
  GridSamples g;
  g.nu = g.nv = samples;
  g.domain = height.domain;
  g.points.reserve(static_cast<size_t>(samples * samples));
  for (int j = 0; j < samples; ++j) {
    for (int i = 0; i < samples; ++i) {
      const double x = g.domain.u_min + sx * i / (samples - 1), y = g.domain.v_min + sy * j / (samples - 1);
      const double z = height.z(x, y);
      if (!std::isfinite(z)) {
        return Status::BadInput(where, "the parameters give no surface at (" + FormatSignificant(x, 4) + ", " +
                                           FormatSignificant(y, 4) + ") (e.g. a radius smaller than the footprint)");
      }
      g.points.emplace_back(x, y, z);
    }
  }
  return g;
}

Result<BSplineSurface> FitParametric(const std::string& kind, const std::map<std::string, double>& p, int samples) {
  FL_ASSIGN_OR_RETURN(const GridSamples g, ParametricGrid(kind, p, samples));
  GridFitOptions options;
  options.tolerance_mm = 1e-3;
  FitReport report;
  return FitGrid(g, options, &report);
}

Result<FamilySurface> BuildFamilySurface(const FamilySurfaceOptions& options) {
  FamilySurface s;
  if (options.kind == SurfaceFamilyKind::kReference) {
    FL_ASSIGN_OR_RETURN(std::unique_ptr<AnalyticSurface> reference, MakeReferenceSurface(options.name));
    s.samples = SampleGridPoints(*reference, options.samples_u, options.samples_v);
    FL_ASSIGN_OR_RETURN(s.q, FitAnalytic(*reference, options.samples_u, options.samples_v, options.fit,
                                         options.check_points, options.seed, &s.report));
    s.description = {{"reference", reference->name()}, {"description", reference->description()}};
  } else {
    FL_ASSIGN_OR_RETURN(const HeightSurface height, ParametricSurface(options.name, options.params));
    FL_ASSIGN_OR_RETURN(const GridSamples g, ParametricGrid(options.name, options.params, options.samples));
    s.samples.points = g.points;
    FL_ASSIGN_OR_RETURN(s.q, FitGrid(g, options.fit, &s.report));
    Rng rng(options.seed);
    double sum2 = 0;
    for (int k = 0; k < options.check_points; ++k) {
      const double u = g.domain.u_min + g.domain.u_span() * rng.Uniform();
      const double v = g.domain.v_min + g.domain.v_span() * rng.Uniform();
      const Eigen::Vector3d p = s.q.Point(u, v);
      const double e = std::abs(p.z() - height.z(p.x(), p.y()));
      sum2 += e * e;
      if (e > s.report.check_max_mm) {
        s.report.check_max_mm = e;
        s.report.check_max_at = p;
      }
    }
    s.report.n_check = options.check_points;
    s.report.check_rms_mm = options.check_points > 0 ? std::sqrt(sum2 / options.check_points) : 0.0;
    s.description = {{"kind", options.name},
                     {"params", options.params},
                     {"check", "vertical distance to z = f(x, y) at random points"}};
  }
  s.description["fit"] = s.report.ToJson();
  s.description["bspline"] = {{"u_degree", s.q.u_degree()},
                              {"v_degree", s.q.v_degree()},
                              {"u_poles", s.q.u_poles()},
                              {"v_poles", s.q.v_poles()}};
  return s;
}

}  // namespace formloop::recon
