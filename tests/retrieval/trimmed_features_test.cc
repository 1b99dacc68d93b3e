// Features of a trimmed Q (retrieval/features.h): only the face counts, not the patch it is cut from.
// The holed face of tests/support/cad_fixtures.h (an ellipse 90 × 70 mm with a hole of radius 8 on a
// 100 × 100 mm Bézier patch): extents, area and the concave/convex histograms of the face, against the
// exact domain and OpenCASCADE's area of the face.

#include <cmath>
#include <cstdio>
#include <filesystem>

#include <gtest/gtest.h>

#include "reconstruction/cad_io.h"
#include "reconstruction/occt_support.h"
#include "reconstruction/trim.h"
#include "retrieval/features.h"
#include "tests/support/cad_fixtures.h"
#include "tests/support/test_dir.h"

namespace formloop::retrieval {
namespace {

namespace fs = std::filesystem;
using formloop::testing::HoledDomain;

TEST(TrimmedFeatures, DescribeTheFaceNotTheUnderlyingPatch) {
  recon::occt::KeepStdoutClean();
  const fs::path dir = formloop::testing::FreshTestDir("formloop_trimmed_features");
  ASSERT_TRUE(formloop::testing::WriteStepFaces(dir / "holed.step", {formloop::testing::MakeHoledFace()}, {"top"}));
  const auto face = recon::ReadCadFace(dir / "holed.step", {});
  ASSERT_TRUE(face.ok()) << face.status().ToString();
  auto taxonomies = FacetTaxonomies::Load(fs::path(FORMLOOP_SOURCE_DIR) / "data" / "taxonomies");
  ASSERT_TRUE(taxonomies.ok());
  FeatureOptions options;
  options.taxonomies = std::make_shared<const FacetTaxonomies>(*taxonomies);
  PartDescription part;
  part.shape_family = "free-form";
  part.material = "H13";
  part.form_tolerance_mm = 0.02;
  part.ra_um = 0.8;
  part.machine_class = "3-axis";
  part.tool_radius_mm = 3;
  const auto trimmed = ExtractFeatures(part, face->surface, options);
  ASSERT_TRUE(trimmed.ok()) << trimmed.status().ToString();
  const auto whole = ExtractFeatures(part, recon::BSplineSurface(face->surface.geom()), options);
  ASSERT_TRUE(whole.ok());
  const Eigen::VectorXd& d = trimmed->descriptors;
  const double area = face->surface.trim()->area_mm2();
  // The grid has 48 cells per direction over the 90 × 70 mm box: cells of 1.9 × 1.5 mm, so the
  // midpoint rule is within about half a cell times the loops' length (≈ 300 mm) of the face's area.
  std::printf(
      "[measured] holed face: area %.1f mm2 (trimmed features) vs %.1f mm2 (OpenCASCADE) vs %.1f mm2 (whole "
      "patch); extents %.2f x %.2f mm (exact 90 x 70); %d samples outside the trim\n",
      d[3], area, whole->descriptors[3], d[0], d[1], trimmed->samples_outside_trim);
  EXPECT_NEAR(d[3], area, 0.02 * area);
  EXPECT_GT(whole->descriptors[3], 1.2 * area);
  EXPECT_NEAR(d[0], 2 * HoledDomain::kA, 1e-3);
  EXPECT_NEAR(d[1], 2 * HoledDomain::kB, 1e-3);
  EXPECT_GT(trimmed->samples_outside_trim, 0);
  EXPECT_EQ(whole->samples_outside_trim, 0);
  EXPECT_NE(trimmed->ToJson().dump(), whole->ToJson().dump());
  fs::remove_all(dir);
}

}  // namespace
}  // namespace formloop::retrieval
