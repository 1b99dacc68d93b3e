// The tool path on a trimmed face with a hole and a pin standing in it (tests/support/cad_fixtures.h),
// checked independently of the planner: every cutting CL's contact point classified by OpenCASCADE
// (BRepTopAdaptor_FClass2d, which hands points near an edge to BRepClass_FaceClassifier) on the face read
// straight from the STEP file, and against the exact domain,
// (in the face's parameters, which are x and y for this surface), every ball (cut, lead and the vertical
// retract above each lead) kept clear of the pin (exact cylinder
// distance), and scallop and gouge judged on the exact surface inside the face by the swept-ball checker
// of tests/support/swept_ball.h within the bounds of the untrimmed tests (scallop target + chord
// tolerance, gouge 1 µm).

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>

#include <gtest/gtest.h>
#include <BRepBuilderAPI_MakeFace.hxx>
#include <BRepTopAdaptor_FClass2d.hxx>
#include <STEPControl_Reader.hxx>
#include <gp_Pln.hxx>

#include "nc-gen/toolpath.h"
#include "nc-gen/toolpath_io.h"
#include "reconstruction/cad_io.h"
#include "reconstruction/occt_support.h"
#include "reconstruction/trim.h"
#include "tests/support/cad_fixtures.h"
#include "tests/support/swept_ball.h"
#include "tests/support/test_dir.h"

namespace formloop::nc {
namespace {

namespace fs = std::filesystem;
using formloop::testing::BezierTop;
using formloop::testing::HoledDomain;

ToolpathOptions Options() {
  ToolpathOptions o;
  o.tool.radius_mm = 3.0;
  o.scallop_um = 5.0;
  o.chord_tolerance_um = 1.0;
  o.max_point_spacing_mm = 0.5;
  o.lead_mm = 2.0;
  return o;
}

// Distance from a ball centre to the pin's lateral face (vertical cylinder, finite height).
double PinDistance(const Eigen::Vector3d& c) {
  const double radial = HoledDomain::PinAxisDistance(c.x(), c.y()) - HoledDomain::kPinR;
  const double below = HoledDomain::kPinZ0 - c.z(), above = c.z() - HoledDomain::kPinZ1;
  const double axial = std::max({below, above, 0.0});
  return std::hypot(std::abs(radial), axial);
}

class TrimmedToolpathTest : public ::testing::Test {
 protected:
  void SetUp() override {
    recon::occt::KeepStdoutClean();
    dir_ = formloop::testing::FreshTestDir("formloop_trimmed_toolpath");
    step_ = dir_ / "holed_pin.step";
    ASSERT_TRUE(formloop::testing::WriteStepFaces(
        step_, {formloop::testing::MakeHoledFace(), formloop::testing::MakePin()}, {"top", "pin"}));
  }
  void TearDown() override { fs::remove_all(dir_); }
  fs::path dir_, step_;
};

TEST_F(TrimmedToolpathTest, CutsOnlyInsideTheFaceLeadsClearThePinAndMeetsTheScallopBounds) {
  const auto face = recon::ReadCadFace(step_, recon::CadFaceSelector{.name = "top"});
  ASSERT_TRUE(face.ok()) << face.status().ToString();
  const ToolpathOptions o = Options();
  const auto path = PlanRaster(face->surface, o);
  ASSERT_TRUE(path.ok()) << path.status().ToString();
  EXPECT_TRUE(path->trimmed);
  EXPECT_EQ(path->contour_passes, 2) << "one contour along the ellipse, one around the hole";
  EXPECT_GT(path->leads_vertical + path->leads_along_normal, 0) << "some arc leads over the hole would reach the pin";
  EXPECT_GT(path->safe_z_mm, HoledDomain::kPinZ1 + o.clearance_mm - 1e-9) << "rapids run above the pin";

  // The face straight from the file, for OpenCASCADE's own 3-D point classifier.
  STEPControl_Reader reader;
  ASSERT_EQ(reader.ReadFile(step_.string().c_str()), IFSelect_RetDone);
  reader.TransferRoots();
  TopoDS_Face top;
  for (TopExp_Explorer it(reader.OneShape(), TopAbs_FACE); it.More(); it.Next()) {
    if (BRep_Tool::Surface(TopoDS::Face(it.Current()))->IsKind(STANDARD_TYPE(Geom_BSplineSurface))) {
      top = TopoDS::Face(it.Current());
    }
  }
  ASSERT_FALSE(top.IsNull());

  const BRepTopAdaptor_FClass2d classifier(top, 1e-5);  // 10 nm
  const double r = o.tool.radius_mm;
  int cut = 0, on_edge = 0;
  double min_pin = 1e300, min_lead_pin = 1e300;
  for (std::size_t k = 0; k < path->points.size(); ++k) {
    const ClPoint& cl = path->points[k];
    if (cl.kind == ClKind::kCut) {
      ++cut;
      // The face's surface has u = x and v = y: the contact point's (x, y) are its parameters there.
      // FClass2d classifies against the face's polygons and hands points near an edge to
      // BRepClass_FaceClassifier.
      const TopAbs_State state = classifier.Perform(gp_Pnt2d(cl.cc.x(), cl.cc.y()), Standard_False);
      ASSERT_TRUE(state == TopAbs_IN || state == TopAbs_ON) << "CL " << k << " at " << cl.cc.transpose();
      on_edge += state == TopAbs_ON;
      ASSERT_TRUE(HoledDomain::Inside(cl.cc.x(), cl.cc.y()) ||
                  formloop::testing::NearHoledBoundary(cl.cc.x(), cl.cc.y(), 1e-3))
          << "CL " << k << " at " << cl.cc.transpose();
      EXPECT_NEAR(cl.cc.z(), BezierTop::Height(cl.cc.x(), cl.cc.y()), 1e-7);
      min_pin = std::min(min_pin, PinDistance(cl.centre));
    } else {
      min_lead_pin = std::min(min_lead_pin, PinDistance(cl.centre));
      // The vertical retract above the outer end of every lead, up to safe Z.
      const bool outer_end = (k + 1 == path->points.size() || path->points[k + 1].pass != cl.pass) ||
                             (k == 0 || path->points[k - 1].pass != cl.pass);
      if (outer_end) {
        for (double z = cl.centre.z(); z <= path->safe_z_mm + r; z += 0.25) {
          min_lead_pin = std::min(min_lead_pin, PinDistance(Eigen::Vector3d(cl.centre.x(), cl.centre.y(), z)));
        }
      }
    }
  }
  std::printf(
      "[measured] holed face: %zu CL (%d cutting, %d on the trim), %d passes (%d contour), leads changed "
      "%d along n + %d vertical; nearest ball to the pin %.3f mm (cutting), %.3f mm (leads, retracts); "
      "safe Z %.2f mm\n",
      path->points.size(), cut, on_edge, path->passes, path->contour_passes, path->leads_along_normal,
      path->leads_vertical, min_pin, min_lead_pin, path->safe_z_mm);
  EXPECT_GT(on_edge, 100) << "passes start and end at the trim";
  EXPECT_GE(min_pin, r - 1e-3);
  EXPECT_GE(min_lead_pin, r - 1e-3);

  // Scallop and gouge on the exact surface inside the face (0.1 mm along the passes, an eighth of the
  // smallest step-over across them), where the trim matters: a 6 mm ring around the hole, the outer band
  // (ellipse level above 0.8), and two interior windows.
  const formloop::testing::MachinedSurface machined(*path, r);
  double max_scallop = 0, max_gouge = 0;
  int samples = 0, uncovered = 0;
  const double dy = path->min_step_over_mm / 8;
  const auto sampled = [](double x, double y) {
    return HoledDomain::HoleDistance(x, y) < HoledDomain::kHoleR + 6 || HoledDomain::EllipseLevel(x, y) > 0.8 ||
           (std::abs(x + 20) < 4 && std::abs(y - 10) < 3) || (std::abs(x - 25) < 4 && std::abs(y + 5) < 3);
  };
  for (double y = -HoledDomain::kB; y <= HoledDomain::kB; y += dy) {
    for (double x = -HoledDomain::kA; x <= HoledDomain::kA; x += 0.1) {
      if (!HoledDomain::Inside(x, y) || !sampled(x, y)) continue;
      const double z = machined.Height(x, y);
      ++samples;
      if (!std::isfinite(z)) {
        ++uncovered;
        continue;
      }
      const double e = 1e-6;
      const Eigen::Vector3d n =
          Eigen::Vector3d(-(BezierTop::Height(x + e, y) - BezierTop::Height(x - e, y)) / (2 * e),
                          -(BezierTop::Height(x, y + e) - BezierTop::Height(x, y - e)) / (2 * e), 1)
              .normalized();
      const double normal_um = (z - BezierTop::Height(x, y)) * n.z() * 1e3;
      max_scallop = std::max(max_scallop, normal_um);
      max_gouge = std::max(max_gouge, -normal_um);
    }
  }
  std::printf(
      "[measured] holed face: %d samples inside, %d uncovered; max scallop %.3f um, max gouge %.3f um "
      "(bounds %.1f and 1.0)\n",
      samples, uncovered, max_scallop, max_gouge, o.scallop_um + o.chord_tolerance_um);
  EXPECT_EQ(uncovered, 0);
  EXPECT_LE(max_scallop, o.scallop_um + o.chord_tolerance_um);
  EXPECT_LE(max_gouge, 1.0);

  // The path file keeps the raised safe Z.
  ASSERT_TRUE(WriteToolpathFile(dir_ / "path.csv", *path).ok());
  const auto read = ReadToolpathFile(dir_ / "path.csv");
  ASSERT_TRUE(read.ok()) << read.status().ToString();
  EXPECT_EQ(read->safe_z_mm, path->safe_z_mm);
}

TEST_F(TrimmedToolpathTest, ABallTooLargeForTheGapStopsShortOfThePin) {
  // A ball of 5 mm radius in a hole of radius 8 around a pin of radius 4: the annulus is 4 mm wide, so no
  // ball touching the hole's edge clears the pin. The passes are cut back where the ball would reach it,
  // the hole's contour is left out, and every ball (cutting, leads, retracts) stays clear.
  const auto face = recon::ReadCadFace(step_, recon::CadFaceSelector{.name = "top"});
  ASSERT_TRUE(face.ok());
  ToolpathOptions o = Options();
  o.tool.radius_mm = 5.0;
  o.scallop_um = 20;
  const auto path = PlanRaster(face->surface, o);
  ASSERT_TRUE(path.ok()) << path.status().ToString();
  EXPECT_GT(path->neighbour_blocked_samples, 0);
  EXPECT_EQ(path->contour_passes, 1) << "only the outer loop";
  double nearest = 1e300;
  for (const ClPoint& cl : path->points) nearest = std::min(nearest, PinDistance(cl.centre));
  std::printf("[measured] r = 5 mm: %d samples blocked by the pin, nearest ball %.4f mm, leads changed %d + %d\n",
              path->neighbour_blocked_samples, nearest, path->leads_along_normal, path->leads_vertical);
  EXPECT_GE(nearest, 5.0 - 1e-3);
}

// A face the ball reaches nowhere (a ceiling at z = 8 mm over a face from z = 0 to 5.7, nearer than the ball's
// diameter everywhere) is refused naming the tool radius and the face's size. Before, this trimmed face
// gave "failed: no part of the trimmed face is reachable by the ball", and a face without a trim of its
// own "internal error: no section plane met Q" (public CAD files: a 0.3 mm fillet of OCCT's
// linkrods.step with a 0.5 mm ball).
TEST_F(TrimmedToolpathTest, AFaceTheBallReachesNowhereIsRefusedNamingTheToolRadius) {
  const fs::path step = dir_ / "under_a_ceiling.step";
  const TopoDS_Face ceiling = BRepBuilderAPI_MakeFace(gp_Pln(gp_Pnt(0, 0, 8), gp_Dir(0, 0, -1)), -60, 60, -60, 60);
  ASSERT_TRUE(formloop::testing::WriteStepFaces(step, {formloop::testing::MakeHoledFace(), ceiling}, {"top", "lid"}));
  const auto face = recon::ReadCadFace(step, recon::CadFaceSelector{.name = "top"});
  ASSERT_TRUE(face.ok()) << face.status().ToString();
  ToolpathOptions o = Options();
  o.tool.radius_mm = 5;
  o.scallop_um = 50;
  const auto path = PlanRaster(face->surface, o);
  ASSERT_FALSE(path.ok());
  EXPECT_EQ(path.status().code(), StatusCode::kBadInput) << path.status().ToString();
  for (const char* text :
       {"tool.radius_mm", "a ball of radius 5 mm reaches no part of the face", "neighbouring face", "smaller ball"}) {
    EXPECT_NE(path.status().ToString().find(text), std::string::npos) << text << ": " << path.status().ToString();
  }
  // The same face alone is planned.
  const fs::path alone = dir_ / "alone.step";
  ASSERT_TRUE(formloop::testing::WriteStepFaces(alone, {formloop::testing::MakeHoledFace()}, {"top"}));
  const auto free_face = recon::ReadCadFace(alone, recon::CadFaceSelector{.name = "top"});
  ASSERT_TRUE(free_face.ok());
  EXPECT_TRUE(PlanRaster(free_face->surface, o).ok());
}

}  // namespace
}  // namespace formloop::nc
