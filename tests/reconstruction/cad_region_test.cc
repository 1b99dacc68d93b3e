// A region of three CAD faces fitted as one Q (reconstruction/cad_region.h): the fit's deviation from
// the faces at random points it did not use, against the exact bump the faces were made from
// (tests/support/cad_fixtures.h), the region's trim on Q (the rectangle the strips cover), and the
// refusal of faces meeting at a crease, with the figure.

#include <cmath>
#include <cstdio>
#include <filesystem>

#include <gtest/gtest.h>
#include <BRepBuilderAPI_MakeFace.hxx>
#include <Geom_Plane.hxx>

#include "core/random.h"
#include "reconstruction/cad_io.h"
#include "reconstruction/cad_region.h"
#include "reconstruction/occt_support.h"
#include "reconstruction/trim.h"
#include "tests/support/cad_fixtures.h"
#include "tests/support/test_dir.h"

namespace formloop::recon {
namespace {

namespace fs = std::filesystem;

TEST(CadRegionTest, ThreeStripsBecomeOneQWithinAMicrometreOfTheFaces) {
  occt::KeepStdoutClean();
  const fs::path dir = formloop::testing::FreshTestDir("formloop_cad_region");
  const fs::path step = dir / "strips.step";
  ASSERT_TRUE(
      formloop::testing::WriteStepFaces(step, formloop::testing::MakeThreeStrips(), {"left", "middle", "right"}));
  const auto faces = ReadCadFaces(step, CadRegionSelector{.names = {"left", "middle", "right"}});
  ASSERT_TRUE(faces.ok()) << faces.status().ToString();
  RegionFitOptions options;
  options.max_cad_deviation_mm = 1e-3;
  const auto fit = FitCadRegion(*faces, options);
  ASSERT_TRUE(fit.ok()) << fit.status().ToString();
  std::printf(
      "[measured] 3 strips: %d samples, net %d x %d, fit rms %.3f um; deviation from the faces at %d check "
      "points: rms %.3f um, max %.3f um (face %d)\n",
      fit->samples, fit->q.u_poles(), fit->q.v_poles(), fit->report.rms_mm * 1e3, fit->check_points,
      fit->cad_deviation_rms_mm * 1e3, fit->cad_deviation_max_mm * 1e3, fit->cad_deviation_max_face);
  EXPECT_EQ(fit->loops, 1);
  EXPECT_EQ(fit->check_points, 3 * options.check_points_per_face);
  EXPECT_LT(fit->cad_deviation_max_mm, 1e-3);
  // Against the exact bump too (the faces approximate it to about 1e-6 mm).
  const Trim* trim = fit->q.trim();
  ASSERT_NE(trim, nullptr);
  EXPECT_FALSE(trim->natural());
  const ParamDomain d = fit->q.domain();
  Rng rng(17);
  int inside = 0, checked = 0;
  double worst = 0;
  for (int k = 0; k < 5000; ++k) {
    const double u = rng.Uniform(d.u_min, d.u_max), v = rng.Uniform(d.v_min, d.v_max);
    const Eigen::Vector3d p = fit->q.Point(u, v);
    const double margin = std::min({p.x() + 50, 50 - p.x(), p.y() + 40, 40 - p.y()});
    if (std::abs(margin) < 0.05) continue;  // the boundary is projected every 0.25 mm and interpolated
    ++checked;
    const bool truth = margin > 0;
    EXPECT_EQ(trim->Inside(u, v), truth) << p.transpose();
    if (truth) {
      ++inside;
      worst = std::max(worst, std::abs(p.z() - formloop::testing::StripHeight(p.x(), p.y())));
    }
  }
  std::printf("[measured] 3 strips: Q against the exact bump inside the region: max vertical %.3f um (%d points)\n",
              worst * 1e3, inside);
  EXPECT_GT(inside, 0.8 * checked);
  EXPECT_LT(worst, 2e-3);
  fs::remove_all(dir);
}

TEST(CadRegionTest, FacesMeetingAtACreaseAreRefusedWithTheFigure) {
  occt::KeepStdoutClean();
  const fs::path dir = formloop::testing::FreshTestDir("formloop_cad_region");
  // Two planar faces meeting along x = 0 at 10 degrees: no smooth Q follows the crease.
  const double slope = std::tan(10.0 * M_PI / 180);
  const Handle(Geom_Plane) flat = new Geom_Plane(gp_Pnt(0, 0, 0), gp_Dir(0, 0, 1));
  const Handle(Geom_Plane) tilted = new Geom_Plane(gp_Pnt(0, 0, 0), gp_Dir(-slope, 0, 1));
  const TopoDS_Face a = BRepBuilderAPI_MakeFace(flat, -40, 0, -30, 30, 1e-7).Face();
  // The tilted plane's parameters: its x axis is along (1, 0, slope)/|..|.
  const double len = 40 * std::sqrt(1 + slope * slope);
  const TopoDS_Face b = BRepBuilderAPI_MakeFace(tilted, 0, len, -30, 30, 1e-7).Face();
  const fs::path step = dir / "crease.step";
  ASSERT_TRUE(formloop::testing::WriteStepFaces(step, {a, b}, {"a", "b"}));
  const auto faces = ReadCadFaces(step, CadRegionSelector{.indices = {0, 1}});
  ASSERT_TRUE(faces.ok()) << faces.status().ToString();
  RegionFitOptions options;
  options.max_cad_deviation_mm = 1e-3;
  const auto fit = FitCadRegion(*faces, options);
  ASSERT_FALSE(fit.ok());
  EXPECT_EQ(fit.status().code(), StatusCode::kFailed);
  std::printf("[measured] crease: %s\n", fit.status().ToString().c_str());
  EXPECT_NE(fit.status().ToString().find("deviates from them by up to"), std::string::npos);
  EXPECT_NE(fit.status().ToString().find("limit of 1.000 um"), std::string::npos);
  fs::remove_all(dir);
}

}  // namespace
}  // namespace formloop::recon
