// The one surface-family registry (reconstruction/surface_family.h): reference surfaces and parametric
// kinds listed together with their parameters; a parametric kind's grid refuses parameters that give no
// surface and unknown kinds naming the field; a part's ideal surface from either family is fitted and
// checked against its defining function.

#include "reconstruction/surface_family.h"

#include <set>
#include <string>

#include <gtest/gtest.h>

namespace formloop::recon {
namespace {

TEST(SurfaceFamilyTest, OneRegistryListsReferenceSurfacesAndParametricKinds) {
  const std::vector<SurfaceFamily> families = SurfaceFamilies();
  std::set<std::string> reference, parametric;
  for (const SurfaceFamily& f : families) {
    (f.kind == SurfaceFamilyKind::kReference ? reference : parametric).insert(f.name);
    EXPECT_FALSE(f.description.empty()) << f.name;
    EXPECT_EQ(f.parameters.empty(), f.kind == SurfaceFamilyKind::kReference) << f.name;
  }
  EXPECT_EQ(reference.size(), ReferenceSurfaceNames().size());
  EXPECT_EQ(parametric, (std::set<std::string>{"sphere_cap", "ellipsoid_cap", "paraboloid", "gaussian_pocket", "saddle",
                                               "egg_box", "franke", "cylinder", "twisted_ruled"}));
  // "saddle" is both a reference surface and a parametric kind; the kind says which.
  ASSERT_NE(FindSurfaceFamily(SurfaceFamilyKind::kReference, "saddle"), nullptr);
  const SurfaceFamily* saddle = FindSurfaceFamily(SurfaceFamilyKind::kParametric, "saddle");
  ASSERT_NE(saddle, nullptr);
  EXPECT_EQ(saddle->parameters, (std::vector<std::string>{"size_mm", "curvature_x", "curvature_ratio"}));
  EXPECT_EQ(FindSurfaceFamily(SurfaceFamilyKind::kParametric, "blade"), nullptr);
}

TEST(SurfaceFamilyTest, ParametricGridsRefuseWhatGivesNoSurface) {
  const auto unknown = ParametricGrid("no_such_kind", {{"size_mm", 10}}, 10);
  ASSERT_FALSE(unknown.ok());
  EXPECT_NE(unknown.status().message().find("surface.no_such_kind"), std::string::npos);
  // A sphere radius smaller than the footprint has no surface at the corners.
  const auto corners = ParametricGrid("sphere_cap", {{"size_mm", 100}, {"radius_ratio", 0.5}}, 10);
  ASSERT_FALSE(corners.ok());
  EXPECT_NE(corners.status().message().find("give no surface"), std::string::npos) << corners.status().message();
  EXPECT_FALSE(ParametricGrid("saddle", {{"curvature_x", 0.01}}, 10).ok());  // no size
  const auto grid = ParametricGrid("saddle", {{"size_mm", 80}, {"curvature_x", 0.01}, {"curvature_ratio", 1}}, 5);
  ASSERT_TRUE(grid.ok());
  EXPECT_EQ(grid->points.size(), 25u);
  EXPECT_DOUBLE_EQ(grid->points.front().z(), 0.5 * (0.01 * 40 * 40 - 0.01 * 40 * 40));
}

TEST(SurfaceFamilyTest, IdealSurfacesFromEitherFamilyAreCheckedAgainstTheirDefinition) {
  FamilySurfaceOptions reference;
  reference.name = "saddle";
  reference.check_points = 200;
  const auto r = BuildFamilySurface(reference);
  ASSERT_TRUE(r.ok()) << r.status().ToString();
  EXPECT_EQ(r->description["reference"], "saddle");
  EXPECT_LT(r->report.check_max_mm, 1e-4);
  FamilySurfaceOptions kind;
  kind.kind = SurfaceFamilyKind::kParametric;
  kind.name = "gaussian_pocket";
  kind.params = {{"size_mm", 60}, {"depth_ratio", 0.1}, {"width_ratio", 0.3}};
  kind.check_points = 200;
  const auto k = BuildFamilySurface(kind);
  ASSERT_TRUE(k.ok()) << k.status().ToString();
  EXPECT_EQ(k->samples.points.size(), 41u * 41u);
  EXPECT_EQ(k->report.n_check, 200);
  EXPECT_LT(k->report.check_max_mm, 1e-3);  // vertical distance to z = f(x, y)
}

}  // namespace
}  // namespace formloop::recon
