#include "retrieval/features.h"

#include <gtest/gtest.h>

#include <Geom_BSplineSurface.hxx>
#include <cmath>
#include <filesystem>
#include <gp_Pnt.hxx>
#include <gp_Vec.hxx>
#include <limits>
#include <map>
#include <memory>
#include <numbers>
#include <set>
#include <string>

#include "reconstruction/analytic_surface.h"
#include "reconstruction/bspline_surface.h"

namespace formloop::retrieval {
namespace {

const std::filesystem::path kTaxonomyDir = std::filesystem::path(FORMLOOP_SOURCE_DIR) / "data" / "taxonomies";

enum Entry {
  kExtentX,
  kExtentY,
  kExtentZ,
  kArea,
  kK1Min,
  kK1Max,
  kK1Mean,
  kK2Min,
  kK2Max,
  kK2Mean,
  kAbsH,
  kGauss,
  kHConcave,
  kHFlat,
  kHConvex,
  kHStrong,
  kKHyperbolic,
  kKParabolic,
  kKElliptic,
  kKStrong,
  kSlope,
  kConcaveR,
  kAspectXy,
  kAspectZ,
};

std::shared_ptr<const FacetTaxonomies> Taxonomies() {
  static const std::shared_ptr<const FacetTaxonomies> t = [] {
    auto loaded = FacetTaxonomies::Load(kTaxonomyDir);
    EXPECT_TRUE(loaded.ok()) << loaded.status().ToString();
    return std::make_shared<const FacetTaxonomies>(*loaded);
  }();
  return t;
}

FeatureOptions Options() {
  FeatureOptions o;
  o.taxonomies = Taxonomies();
  return o;
}

PartDescription Part(const std::string& shape = "sphere_cap") {
  PartDescription p;
  p.family_tag = "test part";
  p.shape_family = shape;
  p.material = "1.2344";
  p.form_tolerance_mm = 0.02;
  p.ra_um = 0.8;
  p.batch_size = 5;
  p.machine_class = "5-axis";
  p.tool_radius_mm = 3;
  p.strategy = "raster zig-zag";
  return p;
}

// The reference surface fitted as the project does (FitAnalytic over a 41 × 41 grid, tolerance
// 1e-4 mm). Cached: each fit takes a moment.
const recon::BSplineSurface& Fitted(const std::string& name) {
  static std::map<std::string, recon::BSplineSurface> cache;
  auto it = cache.find(name);
  if (it == cache.end()) {
    auto s = recon::MakeReferenceSurface(name);
    EXPECT_TRUE(s.ok());
    auto q = recon::FitAnalytic(**s, 41, 41, recon::GridFitOptions{}, 0, 1, nullptr);
    EXPECT_TRUE(q.ok()) << q.status().ToString();
    it = cache.emplace(name, *q).first;
  }
  return it->second;
}

// A copy of the B-spline transformed by `edit` (translate, scale, swap u and v ...).
template <typename Edit>
recon::BSplineSurface Edited(const recon::BSplineSurface& q, Edit edit) {
  Handle(Geom_BSplineSurface) copy = Handle(Geom_BSplineSurface)::DownCast(q.geom()->Copy());
  edit(copy);
  return recon::BSplineSurface(copy);
}

Eigen::VectorXd Descriptors(const recon::BSplineSurface& q, const std::string& shape = "sphere_cap") {
  auto f = ExtractFeatures(Part(shape), q, Options());
  EXPECT_TRUE(f.ok()) << f.status().ToString();
  return f.ok() ? f->descriptors : Eigen::VectorXd::Zero(kDescriptorCount);
}

TEST(Features, DescriptorNamesAreStableAndUnique) {
  const auto& names = DescriptorNames();
  std::set<std::string_view> unique(names.begin(), names.end());
  EXPECT_EQ(unique.size(), static_cast<size_t>(kDescriptorCount));
  EXPECT_EQ(names[kExtentX], "extent_x_mm");
  EXPECT_EQ(names[kArea], "area_mm2");
  EXPECT_EQ(names[kSlope], "steepest_slope_deg");
  EXPECT_EQ(names[kConcaveR], "min_concave_radius_mm");
  EXPECT_EQ(names[kAspectZ], "aspect_z");
}

TEST(Features, SphereCapMatchesHandValues) {
  // z = −80 + sqrt(100² − (x−50)² − (y−40)²) over [0,100] × [0,80]: k1 = k2 = 1/100 everywhere.
  const double r = 100;
  const Eigen::VectorXd d = Descriptors(Fitted("sphere_cap"));
  // Curvature of the fitted B-spline: the fit is within 1e-4 mm, its curvature within 0.5 % of 1/R at
  // the worst node (measured: k2_min = 0.009952 /mm at a corner); tolerance 1 %.
  for (Entry e : {kK1Min, kK1Max, kK1Mean, kK2Min, kK2Max, kK2Mean, kAbsH}) EXPECT_NEAR(d[e], 1 / r, 0.01 / r) << e;
  EXPECT_NEAR(d[kGauss], 1 / (r * r), 0.001 / (r * r));  // an area mean: measured 0.01 % off
  // Area: ∫∫ R / sqrt(R² − ρ²) dx dy by a 2000 × 2000 midpoint rule on the analytic integrand.
  double area = 0;
  const int n = 2000;
  for (int i = 0; i < n; ++i) {
    for (int j = 0; j < n; ++j) {
      const double x = (i + 0.5) * 100.0 / n - 50, y = (j + 0.5) * 80.0 / n - 40;
      area += r / std::sqrt(r * r - x * x - y * y) * (100.0 / n) * (80.0 / n);
    }
  }
  EXPECT_NEAR(d[kArea], area, 1e-4 * area);
  EXPECT_NEAR(d[kExtentX], 100, 1e-3);
  EXPECT_NEAR(d[kExtentY], 80, 1e-3);
  // z from 20 at the centre to −80 + sqrt(100² − 50² − 40²) at the corners.
  EXPECT_NEAR(d[kExtentZ], 100 - std::sqrt(r * r - 4100), 1e-3);
  // Steepest at the corners: the normal leans by asin(ρ/R), ρ = sqrt(50² + 40²).
  EXPECT_NEAR(d[kSlope], std::asin(std::sqrt(4100.0) / r) * 180 / std::numbers::pi, 0.01);
  // Convex everywhere: H·L = L/R ≈ 0.94 and K·L² ≈ 0.89 lie in the (0.05, 2] bins.
  EXPECT_EQ(d[kHConvex], 1.0);
  EXPECT_EQ(d[kKElliptic], 1.0);
  EXPECT_EQ(d[kConcaveR], 1000.0);  // nothing concave: the cap
  EXPECT_NEAR(d[kAspectXy], 0.8, 1e-5);
}

TEST(Features, PlaneAreaExtentsAndZeroCurvature) {
  // z = 0.1 x − 0.05 y + 5 over [0,100] × [0,80].
  const Eigen::VectorXd d = Descriptors(Fitted("plane"), "plane");
  EXPECT_NEAR(d[kArea], 8000 * std::sqrt(1 + 0.01 + 0.0025), 1e-6 * 8000);
  EXPECT_NEAR(d[kExtentX], 100, 1e-6);
  EXPECT_NEAR(d[kExtentY], 80, 1e-6);
  EXPECT_NEAR(d[kExtentZ], 14, 1e-6);  // 15 at (100, 0), 1 at (0, 80)
  for (Entry e : {kK1Min, kK1Max, kK1Mean, kK2Min, kK2Max, kK2Mean, kAbsH}) EXPECT_NEAR(d[e], 0, 1e-7) << e;
  EXPECT_NEAR(d[kGauss], 0, 1e-12);
  EXPECT_EQ(d[kHFlat], 1.0);
  EXPECT_EQ(d[kKParabolic], 1.0);
  EXPECT_NEAR(d[kSlope], std::atan(std::sqrt(0.0125)) * 180 / std::numbers::pi, 1e-6);
  EXPECT_EQ(d[kConcaveR], 1000.0);
  EXPECT_NEAR(d[kAspectZ], 0.14, 1e-8);
}

TEST(Features, CylinderHasZeroGaussianCurvature) {
  // z = −70 + sqrt(80² − (x−50)²), axis along y: k1 = 1/80, k2 = 0, K = 0.
  const Eigen::VectorXd d = Descriptors(Fitted("cylinder"), "cylinder");
  EXPECT_NEAR(d[kK1Mean], 1.0 / 80, 0.01 / 80);
  EXPECT_NEAR(d[kK1Min], 1.0 / 80, 0.02 / 80);
  EXPECT_NEAR(d[kK2Mean], 0, 1e-3 / 80);
  EXPECT_NEAR(d[kGauss], 0, 1e-3 / (80.0 * 80.0));
  EXPECT_EQ(d[kKParabolic], 1.0);
  EXPECT_EQ(d[kHConvex], 1.0);
  EXPECT_NEAR(d[kExtentY], 90, 1e-3);
}

TEST(Features, EggBoxConcaveRadius) {
  // z = 2 sin(2πx/40) sin(2πy/40): the troughs have radius 1/(a w²) = 40² / (2 (2π)²) = 20.26 mm; the
  // grid nodes miss the exact trough by < 0.5 mm, which changes the radius by < 0.5 % (measured 0.1 %).
  const Eigen::VectorXd d = Descriptors(Fitted("egg_box"), "egg_box");
  const double radius = 40.0 * 40.0 / (2 * 4 * std::numbers::pi * std::numbers::pi);
  EXPECT_NEAR(d[kConcaveR], radius, 0.005 * radius);
  EXPECT_NEAR(d[kK2Min], -1 / radius, 0.005 / radius);
  EXPECT_GT(d[kKHyperbolic], 0.2);  // saddle-like between the bumps
  EXPECT_GT(d[kKElliptic] + d[kKStrong], 0.2);
  EXPECT_NEAR(d[kHConcave] + d[kHFlat] + d[kHConvex] + d[kHStrong], 1.0, 1e-12);
  EXPECT_NEAR(d[kKHyperbolic] + d[kKParabolic] + d[kKElliptic] + d[kKStrong], 1.0, 1e-12);
}

TEST(Features, TranslationLeavesDescriptorsUnchanged) {
  const recon::BSplineSurface& q = Fitted("egg_box");
  const Eigen::VectorXd d0 = Descriptors(q, "egg_box");
  const Eigen::VectorXd d1 =
      Descriptors(Edited(q, [](auto& g) { g->Translate(gp_Vec(123.5, -47.25, 300)); }), "egg_box");
  for (int i = 0; i < kDescriptorCount; ++i) {
    EXPECT_NEAR(d1[i], d0[i], 1e-9 * std::max(1.0, std::abs(d0[i]))) << DescriptorNames()[i];
  }
}

TEST(Features, ScalingChangesTheSizeEntriesAsExpected) {
  const recon::BSplineSurface& q = Fitted("egg_box");
  const double s = 2.5;
  const Eigen::VectorXd d0 = Descriptors(q, "egg_box");
  const Eigen::VectorXd d1 = Descriptors(Edited(q, [&](auto& g) { g->Scale(gp_Pnt(10, 20, 30), s); }), "egg_box");
  auto near = [](double a, double b) { return std::abs(a - b) <= 1e-9 * std::max(1.0, std::abs(b)); };
  for (Entry e : {kExtentX, kExtentY, kExtentZ, kConcaveR}) EXPECT_TRUE(near(d1[e], s * d0[e])) << e;
  EXPECT_TRUE(near(d1[kArea], s * s * d0[kArea]));
  for (Entry e : {kK1Min, kK1Max, kK1Mean, kK2Min, kK2Max, kK2Mean, kAbsH}) EXPECT_TRUE(near(d1[e], d0[e] / s)) << e;
  EXPECT_TRUE(near(d1[kGauss], d0[kGauss] / (s * s)));
  for (Entry e : {kHConcave, kHFlat, kHConvex, kHStrong, kKHyperbolic, kKParabolic, kKElliptic, kKStrong, kSlope,
                  kAspectXy, kAspectZ}) {
    EXPECT_TRUE(near(d1[e], d0[e])) << e << ": " << d1[e] << " vs " << d0[e];
  }
}

TEST(Features, SwappingOrReversingParametersKeepsDescriptors) {
  // Both flip the normal (to −z); the descriptor orients it back to the tool side.
  const recon::BSplineSurface& q = Fitted("tilted_paraboloid");
  const Eigen::VectorXd d0 = Descriptors(q, "tilted_paraboloid");
  EXPECT_LT(d0[kK1Max], 0);  // a concave bowl
  auto swapped = ExtractFeatures(Part("tilted_paraboloid"), Edited(q, [](auto& g) { g->ExchangeUV(); }), Options());
  ASSERT_TRUE(swapped.ok());
  EXPECT_TRUE(swapped->normal_flipped);
  const Eigen::VectorXd d2 = Descriptors(Edited(q, [](auto& g) { g->UReverse(); }), "tilted_paraboloid");
  for (int i = 0; i < kDescriptorCount; ++i) {
    const double tol = 1e-9 * std::max(1.0, std::abs(d0[i]));
    EXPECT_NEAR(swapped->descriptors[i], d0[i], tol) << DescriptorNames()[i];
    EXPECT_NEAR(d2[i], d0[i], tol) << DescriptorNames()[i];
  }
}

TEST(Features, Deterministic) {
  const recon::BSplineSurface& q = Fitted("saddle");
  auto a = ExtractFeatures(Part("saddle"), q, Options());
  auto b = ExtractFeatures(Part("saddle"), q, Options());
  ASSERT_TRUE(a.ok() && b.ok());
  for (int i = 0; i < kDescriptorCount; ++i) EXPECT_EQ(a->descriptors[i], b->descriptors[i]) << i;
  EXPECT_EQ(a->ToJson().dump(), b->ToJson().dump());
  // Saddle z = (x² − y²)/300: H = 0 at the centre, K < 0 everywhere.
  EXPECT_EQ(a->descriptors[kKHyperbolic], 1.0);
  EXPECT_LT(a->descriptors[kGauss], 0);
}

TEST(Features, FacetConcepts) {
  auto f = ClassifyPart(Part(), *Taxonomies());
  ASSERT_TRUE(f.ok()) << f.status().ToString();
  EXPECT_EQ(f->shape, "sphere_cap");
  EXPECT_EQ(f->material, "H13");          // from its material number 1.2344
  EXPECT_EQ(f->tolerance_class, "fine");  // 0.02 mm, bound inclusive
  EXPECT_EQ(f->finish_class, "fine milled");
  EXPECT_EQ(f->machine_tool_class, "5-axis ball r<=3");
  PartDescription p = Part("dome");
  p.form_tolerance_mm = 0.004;
  p.ra_um = 5;
  p.machine_class = "3-axis";
  p.tool_radius_mm = 8;
  p.material = "Ti-6Al-4V";
  f = ClassifyPart(p, *Taxonomies());
  ASSERT_TRUE(f.ok()) << f.status().ToString();
  EXPECT_EQ(f->shape, "sphere_cap");
  EXPECT_EQ(f->tolerance_class, "ultra");
  EXPECT_EQ(f->finish_class, "rough milled");
  EXPECT_EQ(f->machine_tool_class, "3-axis ball r>6");
  EXPECT_EQ(f->Concepts().at(kMaterialFacet), "Ti-6Al-4V");
}

void ExpectBadField(const PartDescription& p, const std::string& field) {
  auto f = ExtractFeatures(p, Fitted("plane"), Options());
  ASSERT_FALSE(f.ok()) << field;
  EXPECT_EQ(f.status().code(), StatusCode::kBadInput) << f.status().ToString();
  EXPECT_NE(f.status().message().find("'" + field + "'"), std::string::npos) << f.status().message();
}

TEST(Features, BadInputNamesTheField) {
  PartDescription p = Part();
  p.form_tolerance_mm = std::numeric_limits<double>::quiet_NaN();
  ExpectBadField(p, "form_tolerance_mm");
  p = Part();
  p.material = "unobtainium";
  ExpectBadField(p, "material");
  p = Part();
  p.ra_um = -1;
  ExpectBadField(p, "ra_um");
  p = Part();
  p.tool_radius_mm = 0;
  ExpectBadField(p, "tool_radius_mm");
  p = Part();
  p.machine_class = "4-axis";
  ExpectBadField(p, "machine_class");
  p = Part();
  p.shape_family = "";
  ExpectBadField(p, "shape_family");
  p = Part();
  p.batch_size = 0;
  ExpectBadField(p, "batch_size");

  FeatureOptions no_taxonomies;
  EXPECT_NE(ExtractFeatures(Part(), Fitted("plane"), no_taxonomies).status().message().find("taxonomies"),
            std::string::npos);
  FeatureOptions bad_grid = Options();
  bad_grid.grid = 1;
  EXPECT_EQ(ExtractFeatures(Part(), Fitted("plane"), bad_grid).status().code(), StatusCode::kBadInput);
  EXPECT_EQ(ExtractFeatures(Part(), recon::BSplineSurface(), Options()).status().code(), StatusCode::kBadInput);
}

}  // namespace
}  // namespace formloop::retrieval
