// Probing plans on a trimmed face with a hole (tests/support/cad_fixtures.h): every planned point is
// classified inside the face by OpenCASCADE (BRepTopAdaptor_FClass2d on the face read straight from the
// STEP file) and against the exact domain, and lies at least the stated margin (3-D distance) from the
// exact outer loop and the hole's edge.

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <vector>

#include <gtest/gtest.h>
#include <BRepTopAdaptor_FClass2d.hxx>
#include <STEPControl_Reader.hxx>

#include "metrology/probe.h"
#include "metrology/probing_plan.h"
#include "reconstruction/cad_io.h"
#include "reconstruction/occt_support.h"
#include "tests/support/cad_fixtures.h"
#include "tests/support/test_dir.h"

namespace formloop::metrology {
namespace {

namespace fs = std::filesystem;
using formloop::testing::BezierTop;
using formloop::testing::HoledDomain;

// Smallest 3-D distance from p to the exact loops (sampled every ~0.006 mm).
double ExactEdgeDistance(const Eigen::Vector3d& p) {
  static const std::vector<Eigen::Vector3d> loops = [] {
    std::vector<Eigen::Vector3d> out;
    for (int k = 0; k < 40000; ++k) {
      const double t = 2 * M_PI * k / 40000;
      out.push_back(BezierTop::Point(HoledDomain::kA * std::cos(t), HoledDomain::kB * std::sin(t)));
      if (k % 4 == 0) {
        out.push_back(BezierTop::Point(HoledDomain::kHoleX + HoledDomain::kHoleR * std::cos(t),
                                       HoledDomain::kHoleY + HoledDomain::kHoleR * std::sin(t)));
      }
    }
    return out;
  }();
  double best = 1e300;
  for (const Eigen::Vector3d& l : loops) best = std::min(best, (l - p).squaredNorm());
  return std::sqrt(best);
}

TEST(TrimmedProbingPlanTest, PointsLieInsideTheFaceWithTheStatedMargin) {
  recon::occt::KeepStdoutClean();
  const fs::path dir = formloop::testing::FreshTestDir("formloop_trimmed_probing");
  const fs::path step = dir / "holed.step";
  ASSERT_TRUE(formloop::testing::WriteStepFaces(step, {formloop::testing::MakeHoledFace()}, {"top"}));
  const auto face = recon::ReadCadFace(step, {});
  ASSERT_TRUE(face.ok()) << face.status().ToString();
  STEPControl_Reader reader;
  ASSERT_EQ(reader.ReadFile(step.string().c_str()), IFSelect_RetDone);
  reader.TransferRoots();
  TopExp_Explorer it(reader.OneShape(), TopAbs_FACE);
  const BRepTopAdaptor_FClass2d classifier(TopoDS::Face(it.Current()), 1e-5);

  const auto grid = PlanProbingGrid(face->surface, 20, 20, 0.05);
  ASSERT_TRUE(grid.ok()) << grid.status().ToString();
  const auto weighted = PlanProbingCurvatureWeighted(face->surface, 150, 0.0, 1.0);
  ASSERT_TRUE(weighted.ok()) << weighted.status().ToString();
  for (const ProbingPlan* plan : {&*grid, &*weighted}) {
    EXPECT_TRUE(plan->trimmed);
    EXPECT_EQ(plan->edge_margin_mm, kProbeEdgeMarginMm);
    EXPECT_GT(plan->left_out, 0);
    double nearest = 1e300;
    for (const ProbePoint& p : plan->points) {
      // The face's surface has u = x, v = y.
      ASSERT_EQ(classifier.Perform(gp_Pnt2d(p.point.x(), p.point.y()), Standard_False), TopAbs_IN) << p.id;
      ASSERT_TRUE(HoledDomain::Inside(p.point.x(), p.point.y())) << p.id;
      nearest = std::min(nearest, ExactEdgeDistance(p.point));
    }
    std::printf("[measured] %zu probe points (%d left out), nearest to the trim's edge %.3f mm (margin %.1f mm)\n",
                plan->points.size(), plan->left_out, nearest, plan->edge_margin_mm);
    EXPECT_GE(nearest, kProbeEdgeMarginMm - 1e-3);
    EXPECT_EQ(plan->ToJson()["trim"]["edge_margin_mm"], kProbeEdgeMarginMm);
  }
  EXPECT_EQ(grid->points.size() + static_cast<std::size_t>(grid->left_out), 400u);
  // A margin nothing fits in is refused naming the field.
  const auto none = PlanProbingGrid(face->surface, 6, 6, 0.05, 40.0);
  ASSERT_FALSE(none.ok());
  EXPECT_NE(none.status().ToString().find("probing.grid"), std::string::npos) << none.status().ToString();
  fs::remove_all(dir);
}

}  // namespace
}  // namespace formloop::metrology
