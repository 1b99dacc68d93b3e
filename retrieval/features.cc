#include "retrieval/features.h"

#include <Eigen/Geometry>
#include <algorithm>
#include <cmath>
#include <numbers>

#include "core/number_text.h"
#include "reconstruction/trim.h"

namespace formloop::retrieval {
namespace {

Status PositiveFinite(double value, const std::string& field, const std::string& fix) {
  if (!std::isfinite(value) || value <= 0) {
    return Status::BadInput(Where{.field = field}, "value " + FormatExact(value) + " is not a finite number > 0", fix);
  }
  return Status::Ok();
}

// Node lookup whose error names the PartDescription field.
Result<int> RequireConcept(const Taxonomy& taxonomy, const std::string& value, const std::string& field) {
  if (value.empty()) {
    return Status::BadInput(Where{.field = field}, "empty",
                            "name a concept of the taxonomy '" + taxonomy.root_name() + "'");
  }
  auto id = taxonomy.Require(value, field);
  if (!id.ok()) return Status::BadInput(FormatWhere(Where{.field = field}) + id.status().message());
  return id;
}

struct Sample {
  double k1 = 0, k2 = 0;  // tool-side sign convention
  Eigen::Vector3d p, n;
  double weight = 0;  // area weight (midpoints only)
};

}  // namespace

const std::array<std::string_view, kDescriptorCount>& DescriptorNames() {
  static const std::array<std::string_view, kDescriptorCount> names = {
      "extent_x_mm",
      "extent_y_mm",
      "extent_z_mm",
      "area_mm2",
      "k1_min_per_mm",
      "k1_max_per_mm",
      "k1_mean_per_mm",
      "k2_min_per_mm",
      "k2_max_per_mm",
      "k2_mean_per_mm",
      "abs_mean_curv_mean_per_mm",
      "gauss_curv_mean_per_mm2",
      "h_frac_concave",
      "h_frac_flat",
      "h_frac_convex",
      "h_frac_strongly_convex",
      "k_frac_hyperbolic",
      "k_frac_parabolic",
      "k_frac_elliptic",
      "k_frac_strongly_elliptic",
      "steepest_slope_deg",
      "min_concave_radius_mm",
      "aspect_xy",
      "aspect_z",
  };
  return names;
}

bool DescriptorIsMagnitude(int k) {
  if (k < 0 || k >= kDescriptorCount) return false;
  const std::string_view name = DescriptorNames()[static_cast<std::size_t>(k)];
  return !name.starts_with("h_frac_") && !name.starts_with("k_frac_");
}

Result<FacetTaxonomies> FacetTaxonomies::Load(const std::filesystem::path& dir) {
  FacetTaxonomies t;
  FL_ASSIGN_OR_RETURN(t.shape, Taxonomy::Load(dir / "shape.txt"));
  FL_ASSIGN_OR_RETURN(t.material, Taxonomy::Load(dir / "material.txt"));
  FL_ASSIGN_OR_RETURN(t.tolerance, Taxonomy::Load(dir / "tolerance.txt"));
  FL_ASSIGN_OR_RETURN(t.finish, Taxonomy::Load(dir / "finish.txt"));
  FL_ASSIGN_OR_RETURN(t.machine_tool, Taxonomy::Load(dir / "machine_tool.txt"));
  return t;
}

std::map<std::string, Taxonomy> FacetTaxonomies::ByFacet() const {
  return {{kShapeFacet, shape},
          {kMaterialFacet, material},
          {kToleranceFacet, tolerance},
          {kFinishFacet, finish},
          {kMachineToolFacet, machine_tool}};
}

Status FeatureOptions::Validate() const {
  if (grid < 2 || grid > 1000) {
    return Status::BadInput(Where{.field = "grid"}, "grid " + std::to_string(grid) + " is outside [2, 1000]");
  }
  if (!std::isfinite(concave_radius_cap_mm) || concave_radius_cap_mm <= 0) {
    return Status::BadInput(Where{.field = "concave_radius_cap_mm"},
                            "cap " + FormatExact(concave_radius_cap_mm) + " is not a finite number > 0");
  }
  if (!std::isfinite(flat_band) || !std::isfinite(strong_band) || !(flat_band > 0) || !(flat_band < strong_band)) {
    return Status::BadInput(Where{.field = "flat_band"}, "histogram edges flat_band = " + FormatExact(flat_band) +
                                                             ", strong_band = " + FormatExact(strong_band) +
                                                             " do not satisfy 0 < flat_band < strong_band");
  }
  if (!taxonomies) {
    return Status::BadInput(Where{.field = "taxonomies"}, "no facet taxonomies given",
                            "load them with FacetTaxonomies::Load(<source>/data/taxonomies)");
  }
  return Status::Ok();
}

std::map<std::string, std::string> PartFeatures::Concepts() const {
  return {{kShapeFacet, shape},
          {kMaterialFacet, material},
          {kToleranceFacet, tolerance_class},
          {kFinishFacet, finish_class},
          {kMachineToolFacet, machine_tool_class}};
}

nlohmann::json PartFeatures::ToJson() const {
  nlohmann::json d = nlohmann::json::object();
  for (int i = 0; i < descriptors.size() && i < kDescriptorCount; ++i) {
    d[std::string(DescriptorNames()[i])] = descriptors[i];
  }
  nlohmann::json out = {{"descriptors", d},
                        {"concepts", Concepts()},
                        {"size_mm", size_mm},
                        {"normal_flipped", normal_flipped},
                        {"nodes_skipped", nodes_skipped}};
  if (samples_outside_trim > 0) out["samples_outside_trim"] = samples_outside_trim;
  return out;
}

Result<PartFeatures> ClassifyPart(const PartDescription& part, const FacetTaxonomies& taxonomies) {
  PartFeatures f;
  FL_RETURN_IF_ERROR(PositiveFinite(part.form_tolerance_mm, "form_tolerance_mm",
                                    "give the form tolerance of the surface in mm, e.g. 0.02"));
  FL_RETURN_IF_ERROR(PositiveFinite(part.ra_um, "ra_um", "give the required roughness Ra in µm, e.g. 0.8"));
  FL_RETURN_IF_ERROR(
      PositiveFinite(part.tool_radius_mm, "tool_radius_mm", "give the ball-end mill radius in mm, e.g. 3"));
  if (part.batch_size < 1) {
    return Status::BadInput(Where{.field = "batch_size"}, "batch size " + std::to_string(part.batch_size) + " < 1");
  }
  if (!std::isfinite(part.raster_angle_deg)) {
    return Status::BadInput(Where{.field = "raster_angle_deg"}, "raster angle is not finite");
  }
  FL_ASSIGN_OR_RETURN(const int shape, RequireConcept(taxonomies.shape, part.shape_family, "shape_family"));
  FL_ASSIGN_OR_RETURN(const int material, RequireConcept(taxonomies.material, part.material, "material"));
  FL_ASSIGN_OR_RETURN(const int machine, RequireConcept(taxonomies.machine_tool, part.machine_class, "machine_class"));
  FL_ASSIGN_OR_RETURN(const int tolerance, ClassifyByBand(taxonomies.tolerance, taxonomies.tolerance.root_name(),
                                                          "max_mm", part.form_tolerance_mm, "form_tolerance_mm"));
  FL_ASSIGN_OR_RETURN(const int finish,
                      ClassifyByBand(taxonomies.finish, taxonomies.finish.root_name(), "max_um", part.ra_um, "ra_um"));
  FL_ASSIGN_OR_RETURN(const int tool, ClassifyByBand(taxonomies.machine_tool, taxonomies.machine_tool.name(machine),
                                                     "radius_max_mm", part.tool_radius_mm, "tool_radius_mm"));
  f.shape = taxonomies.shape.name(shape);
  f.material = taxonomies.material.name(material);
  f.tolerance_class = taxonomies.tolerance.name(tolerance);
  f.finish_class = taxonomies.finish.name(finish);
  f.machine_tool_class = taxonomies.machine_tool.name(tool);
  return f;
}

Result<PartFeatures> ExtractFeatures(const PartDescription& part, const recon::BSplineSurface& surface,
                                     const FeatureOptions& options) {
  FL_RETURN_IF_ERROR(options.Validate());
  FL_ASSIGN_OR_RETURN(PartFeatures f, ClassifyPart(part, *options.taxonomies));
  if (!surface.valid()) return Status::BadInput(Where{.field = "surface"}, "the surface is empty");
  const recon::ParamDomain dom = surface.domain();
  if (!(dom.u_span() > 0) || !(dom.v_span() > 0)) {
    return Status::BadInput(Where{.field = "surface"}, "the surface's parameter domain is empty");
  }
  const int n = options.grid;
  const double du = dom.u_span() / n, dv = dom.v_span() / n;

  // Evaluates one sample; false where the normal is undefined (degenerate point).
  auto evaluate = [&](double u, double v, Sample* s) {
    const recon::SurfaceDerivatives d = surface.Derivatives(u, v);
    const Eigen::Vector3d cross = d.su.cross(d.sv);
    const double jac = cross.norm();
    if (!(jac > 0) || !std::isfinite(jac)) return false;
    const recon::PrincipalCurvatures c = recon::CurvaturesFromDerivatives(d);
    if (!std::isfinite(c.k1) || !std::isfinite(c.k2)) return false;
    s->p = d.p;
    s->n = cross / jac;
    s->k1 = c.k1;
    s->k2 = c.k2;
    s->weight = jac * du * dv;
    return true;
  };
  // On a trimmed Q only samples inside the trim count (reconstruction/trim.h): nodes and midpoints
  // outside it are left out of every extreme, extent and integral.
  const recon::Trim* trim = surface.trim() != nullptr && !surface.trim()->natural() ? surface.trim() : nullptr;
  const auto inside = [&](double u, double v) {
    if (trim == nullptr || trim->Inside(u, v)) return true;
    ++f.samples_outside_trim;
    return false;
  };
  std::vector<Sample> nodes, mids;
  nodes.reserve(static_cast<size_t>((n + 1) * (n + 1)));
  mids.reserve(static_cast<size_t>(n * n));
  for (int j = 0; j <= n; ++j) {
    for (int i = 0; i <= n; ++i) {
      // The last node is placed exactly on the domain's end.
      const double u = i == n ? dom.u_max : dom.u_min + i * du;
      const double v = j == n ? dom.v_max : dom.v_min + j * dv;
      Sample s;
      if (!inside(u, v)) {
      } else if (evaluate(u, v, &s)) {
        nodes.push_back(s);
      } else {
        ++f.nodes_skipped;
      }
      if (i < n && j < n) {
        const double um = dom.u_min + (i + 0.5) * du, vm = dom.v_min + (j + 0.5) * dv;
        if (!inside(um, vm)) {
        } else if (evaluate(um, vm, &s)) {
          mids.push_back(s);
        } else {
          ++f.nodes_skipped;
        }
      }
    }
  }
  if (nodes.empty() || mids.empty()) {
    return Status::Failed("features: no sample of the surface has a defined normal (degenerate surface)");
  }

  // Orientation: the tool side is +z.
  Eigen::Vector3d mean_normal = Eigen::Vector3d::Zero();
  for (const Sample& s : mids) mean_normal += s.weight * s.n;
  f.normal_flipped = mean_normal.z() < 0;
  if (f.normal_flipped) {
    for (auto* set : {&nodes, &mids}) {
      for (Sample& s : *set) {
        const double k1 = -s.k2, k2 = -s.k1;
        s.k1 = k1;
        s.k2 = k2;
        s.n = -s.n;
      }
    }
  }

  Eigen::VectorXd d = Eigen::VectorXd::Zero(kDescriptorCount);
  Eigen::Vector3d lo = nodes.front().p, hi = nodes.front().p;
  double k1_min = nodes.front().k1, k1_max = k1_min, k2_min = nodes.front().k2, k2_max = k2_min;
  double max_slope = 0, min_concave = options.concave_radius_cap_mm;
  for (const Sample& s : nodes) {
    lo = lo.cwiseMin(s.p);
    hi = hi.cwiseMax(s.p);
    k1_min = std::min(k1_min, s.k1);
    k1_max = std::max(k1_max, s.k1);
    k2_min = std::min(k2_min, s.k2);
    k2_max = std::max(k2_max, s.k2);
    max_slope = std::max(max_slope, std::acos(std::clamp(std::abs(s.n.z()), 0.0, 1.0)));
    if (s.k2 < 0) min_concave = std::min(min_concave, -1.0 / s.k2);
  }
  // On a trimmed Q the extents come from the trim's loops too (the grid's nodes stop up to a cell short).
  if (trim != nullptr) {
    for (const recon::TrimLoop& loop : trim->loops()) {
      for (const Eigen::Vector3d& p : loop.point) {
        lo = lo.cwiseMin(p);
        hi = hi.cwiseMax(p);
      }
    }
  }
  double area = 0;
  for (const Sample& s : mids) area += s.weight;
  if (!(area > 0)) return Status::Failed("features: the surface has zero area");
  const double size = std::sqrt(area);
  double k1_sum = 0, k2_sum = 0, abs_h_sum = 0, k_sum = 0;
  std::array<double, 4> h_bins{}, k_bins{};
  auto bin = [&](double x) {
    if (x < -options.flat_band) return 0;
    if (x <= options.flat_band) return 1;
    if (x <= options.strong_band) return 2;
    return 3;
  };
  for (const Sample& s : mids) {
    const double h = 0.5 * (s.k1 + s.k2), k = s.k1 * s.k2;
    k1_sum += s.weight * s.k1;
    k2_sum += s.weight * s.k2;
    abs_h_sum += s.weight * std::abs(h);
    k_sum += s.weight * k;
    h_bins[bin(h * size)] += s.weight;
    k_bins[bin(k * size * size)] += s.weight;
  }
  const Eigen::Vector3d extent = hi - lo;
  d[0] = extent.x();
  d[1] = extent.y();
  d[2] = extent.z();
  d[3] = area;
  d[4] = k1_min;
  d[5] = k1_max;
  d[6] = k1_sum / area;
  d[7] = k2_min;
  d[8] = k2_max;
  d[9] = k2_sum / area;
  d[10] = abs_h_sum / area;
  d[11] = k_sum / area;
  for (int b = 0; b < 4; ++b) {
    d[12 + b] = h_bins[b] / area;
    d[16 + b] = k_bins[b] / area;
  }
  d[20] = max_slope * 180.0 / std::numbers::pi;
  d[21] = min_concave;
  const double footprint = std::max(extent.x(), extent.y());
  d[22] = footprint > 0 ? std::min(extent.x(), extent.y()) / footprint : 0.0;
  d[23] = footprint > 0 ? extent.z() / footprint : 0.0;
  f.descriptors = d;
  f.size_mm = size;
  return f;
}

}  // namespace formloop::retrieval
