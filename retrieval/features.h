#pragma once
// Part features of the case library (spec/case-library.md §1 part 1, §3): a fixed-length geometric
// descriptor of the ideal surface Q for the GHSOM, and the part's categorical facet concepts.
//
// Geometric descriptor: kDescriptorCount = 24 numbers, named by DescriptorNames() (stable: they
// are stored with cases and standardised per entry, so never reorder or rename them — append a new
// version instead). Sampling: a regular grid of (n+1) × (n+1) nodes over the B-spline's parameter
// domain (corners included; n = FeatureOptions::grid) for extremes and extents, and the n × n cell
// midpoints for area integrals, each with the area weight w = |S_u × S_v| Δu Δv (midpoint rule).
// Integrals are therefore surface integrals, independent of the parameterisation up to the
// discretisation error; nothing depends on the position of the part (only differences of
// coordinates), so a translation leaves every entry unchanged (to rounding). Curvature signs follow
// reconstruction/analytic_surface.h (positive = convex as seen from the tool side); the tool side is
// taken as the side of +z: when the area-weighted mean normal has n_z < 0 the normal is flipped
// (k1, k2 → −k2, −k1), so swapping u and v does not change the descriptor.
// Units: mm, 1/mm, 1/mm², mm², degrees; "size" L = sqrt(area) makes the histogram bins scale-free.
// Under a uniform scaling by s: extents ×s, area ×s², k ×1/s, K ×1/s², concave radius ×s (until
// capped); histograms, slope and aspect ratios unchanged.
//
//  #  name                      meaning
//  0  extent_x_mm               bounding box of the grid nodes along x of the part frame
//  1  extent_y_mm               ... along y
//  2  extent_z_mm               ... along z (the tool axis)
//  3  area_mm2                  Σ w over the cell midpoints
//  4  k1_min_per_mm             min of the larger principal curvature k1 over the nodes
//  5  k1_max_per_mm             max of k1 over the nodes
//  6  k1_mean_per_mm            area-weighted mean of k1
//  7  k2_min_per_mm             min of the smaller principal curvature k2 over the nodes
//  8  k2_max_per_mm             max of k2 over the nodes
//  9  k2_mean_per_mm            area-weighted mean of k2
// 10  abs_mean_curv_mean_per_mm area-weighted mean of |H|, H = (k1 + k2)/2
// 11  gauss_curv_mean_per_mm2   area-weighted mean of K = k1·k2
// 12  h_frac_concave            area fraction with h = H·L < −flat_band
// 13  h_frac_flat               area fraction with |h| ≤ flat_band
// 14  h_frac_convex             area fraction with flat_band < h ≤ strong_band
// 15  h_frac_strongly_convex    area fraction with h > strong_band
// 16  k_frac_hyperbolic         area fraction with κ = K·L² < −flat_band   (saddle-like)
// 17  k_frac_parabolic          area fraction with |κ| ≤ flat_band          (flat or developable)
// 18  k_frac_elliptic           area fraction with flat_band < κ ≤ strong_band (dome or bowl)
// 19  k_frac_strongly_elliptic  area fraction with κ > strong_band
// 20  steepest_slope_deg        max over the nodes of the angle between the normal and z, in [0, 90]
// 21  min_concave_radius_mm     min over the nodes of −1/k2 where k2 < 0, capped at
//                               concave_radius_cap_mm (the cap when nothing is concave)
// 22  aspect_xy                 min(extent_x, extent_y) / max(extent_x, extent_y), 0 if both are 0
// 23  aspect_z                  extent_z / max(extent_x, extent_y), 0 if that is 0
// Entries 12–15 and 16–19 each sum to 1.
//
// Trimmed Q (reconstruction/trim.h): only nodes and midpoints inside the trim are used, so the
// descriptor is that of the part's face, not of its underlying patch (the area is the midpoint rule
// over the cells whose midpoint is inside: within about half a cell times the trim's perimeter); the
// extents also take the trim's loops into account, so they are those of the face.
//
// Facet concepts (canonical node names of the taxonomies under data/taxonomies/, see its README):
//   shape        ← PartDescription::shape_family (a node or alias of shape.txt)
//   material     ← PartDescription::material (a node or alias of material.txt, e.g. "1.2344" → H13)
//   tolerance    ← ClassifyByBand(tolerance.txt, max_mm, form_tolerance_mm)
//   finish       ← ClassifyByBand(finish.txt, max_um, ra_um)
//   machine_tool ← ClassifyByBand(machine_tool.txt under machine_class, radius_max_mm, tool_radius_mm)
// The bands live in the taxonomy files (data, changed without recompiling, like the rule base §5).

#include <Eigen/Core>
#include <array>
#include <filesystem>
#include <limits>
#include <map>
#include <memory>
#include <nlohmann/json.hpp>
#include <string>
#include <string_view>

#include "core/status.h"
#include "reconstruction/bspline_surface.h"
#include "retrieval/taxonomy.h"

namespace formloop::retrieval {

inline constexpr int kDescriptorCount = 24;
// The 24 descriptor names in order (table above).
const std::array<std::string_view, kDescriptorCount>& DescriptorNames();
// True for the magnitudes (lengths, area, curvatures, radius, slope, aspect ratios), false for the area
// fractions (h_frac_*, k_frac_*). Retrieval compares magnitudes on a logarithmic scale (retrieve.h).
bool DescriptorIsMagnitude(int k);

// Facet names, as used by CaseConcepts::categorical and SimilarityOptions::facet_weights.
inline constexpr char kShapeFacet[] = "shape";
inline constexpr char kMaterialFacet[] = "material";
inline constexpr char kToleranceFacet[] = "tolerance";
inline constexpr char kFinishFacet[] = "finish";
inline constexpr char kMachineToolFacet[] = "machine_tool";

// The five categorical taxonomies.
struct FacetTaxonomies {
  Taxonomy shape, material, tolerance, finish, machine_tool;
  // Loads shape.txt, material.txt, tolerance.txt, finish.txt and machine_tool.txt from `dir`
  // (normally <source>/data/taxonomies).
  static Result<FacetTaxonomies> Load(const std::filesystem::path& dir);
  // Facet name → taxonomy, for CaseSimilarityIndex::Build.
  std::map<std::string, Taxonomy> ByFacet() const;
};

// The design requirements of a part (spec §1 part 1) that the features are taken from. Numbers
// default to NaN so a forgotten field is an error, not a silent 0.
struct PartDescription {
  std::string family_tag;    // free text, e.g. "door-handle die, left"; carried, not classified
  std::string shape_family;  // node or alias of the shape taxonomy, e.g. "sphere_cap" or "dome"
  std::string material;      // node or alias of the material taxonomy, e.g. "H13" or "1.2344"
  double form_tolerance_mm = std::numeric_limits<double>::quiet_NaN();  // > 0
  double ra_um = std::numeric_limits<double>::quiet_NaN();              // > 0
  int batch_size = 1;                                                   // ≥ 1
  std::string machine_class;  // node of the machine/tool taxonomy: "3-axis" or "5-axis"
  double tool_radius_mm = std::numeric_limits<double>::quiet_NaN();  // ball-end radius, > 0
  std::string strategy;                                              // e.g. "raster zig-zag"; carried, not classified
  double raster_angle_deg = 0;
};

struct FeatureOptions {
  // Cells per parameter direction: (grid+1)² nodes, grid² midpoints. 48 puts a node every ~2 mm
  // on a 100 mm part, which resolves the 20 mm crest radius of the egg box to ~1 %.
  int grid = 48;
  // Cap of min_concave_radius_mm: beyond 1 m a surface is flat for any milling tool.
  double concave_radius_cap_mm = 1000;
  // Histogram edges in the scale-free units h = H·L and κ = K·L² (L = sqrt(area)): |h| ≤ 0.05 means
  // a radius of curvature above 10 part sizes (flat); h > 2 a radius below half the part size.
  double flat_band = 0.05;
  double strong_band = 2.0;
  // Required: the facet taxonomies (FacetTaxonomies::Load). Shared so options copy cheaply.
  std::shared_ptr<const FacetTaxonomies> taxonomies;
  // BadInput naming the option: grid < 2 or > 1000, non-positive cap, 0 < flat_band < strong_band
  // violated, taxonomies missing.
  Status Validate() const;
};

struct PartFeatures {
  Eigen::VectorXd descriptors;  // kDescriptorCount entries, the table above
  // Canonical concept names per facet.
  std::string shape, material, tolerance_class, finish_class, machine_tool_class;
  double size_mm = 0;            // L = sqrt(area)
  bool normal_flipped = false;   // the surface's normal pointed to −z and was flipped
  int nodes_skipped = 0;         // grid nodes/midpoints with an undefined normal (degenerate), left out
  int samples_outside_trim = 0;  // grid nodes/midpoints outside Q's trim, left out
  // Facet name → concept, ready for CaseConcepts::categorical.
  std::map<std::string, std::string> Concepts() const;
  nlohmann::json ToJson() const;
};

// The facet concepts alone (no surface needed). BadInput/NotFound naming the PartDescription field.
Result<PartFeatures> ClassifyPart(const PartDescription& part, const FacetTaxonomies& taxonomies);

// Descriptors and concepts. BadInput naming the field for a bad description (NaN tolerance, unknown
// material ...), for invalid options, or for an invalid surface; Failed when no sample of the
// surface has a defined normal.
Result<PartFeatures> ExtractFeatures(const PartDescription& part, const recon::BSplineSurface& surface,
                                     const FeatureOptions& options);

}  // namespace formloop::retrieval
