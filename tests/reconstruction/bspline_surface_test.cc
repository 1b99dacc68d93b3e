// B-spline fits of the reference surfaces, STEP round trips and foot-point projection.
//
// Fit check errors measured with a 61 × 61 grid, approximation tolerance 1e-4 mm, 400 check points
// (OpenCASCADE 7.6.3), max distance from S(u, v) to Q, mm: plane 7e-14, sphere_cap 7.1e-5, cylinder
// 4.4e-5, ellipsoid_cap 8.5e-5, saddle 3e-14, egg_box 1.33e-4, franke 9.5e-5, blade 5.0e-5,
// tilted_paraboloid 6e-14 (grid residual max up to 1.46e-4 on franke: OCCT's tolerance is not a hard
// bound). kFitBoundMm = 3e-4 is about twice the worst. STEP round trip: poles within 7.5e-12 mm.

#include <unistd.h>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <string>
#include <vector>

#include <gtest/gtest.h>
#include <BRepBuilderAPI_MakeFace.hxx>
#include <GeomAPI_ProjectPointOnSurf.hxx>
#include <Interface_Static.hxx>
#include <Precision.hxx>
#include <STEPControl_Writer.hxx>
#include <TColStd_Array1OfInteger.hxx>
#include <TColStd_Array1OfReal.hxx>
#include <TColgp_Array2OfPnt.hxx>
#include <TopoDS_Face.hxx>

#include "core/random.h"
#include "reconstruction/bspline_surface.h"

namespace formloop::recon {
namespace {

using Eigen::Vector3d;

// Bound on check_max_mm for every reference surface with a 61 × 61 grid and tolerance 1e-4 mm.
constexpr double kFitBoundMm = 3e-4;

std::unique_ptr<AnalyticSurface> Make(const std::string& name) {
  auto made = MakeReferenceSurface(name);
  EXPECT_TRUE(made.ok()) << made.status().ToString();
  return std::move(made).value();
}

class TempDir {
 public:
  TempDir() {
    Rng rng(static_cast<std::uint64_t>(::getpid()) * 7919u + counter_++);
    path_ = std::filesystem::temp_directory_path() /
            ("formloop_recon_test_" + std::to_string(::getpid()) + "_" + std::to_string(rng.NextU64() % 1000000007));
    std::filesystem::create_directories(path_);
  }
  ~TempDir() {
    std::error_code ignored;
    std::filesystem::remove_all(path_, ignored);
  }
  const std::filesystem::path& path() const { return path_; }

 private:
  static inline unsigned counter_ = 0;
  std::filesystem::path path_;
};

class BSplineFitTest : public ::testing::TestWithParam<std::string> {};

TEST_P(BSplineFitTest, FitAnalyticIsWithinBound) {
  const auto s = Make(GetParam());
  GridFitOptions options;
  options.tolerance_mm = 1e-4;
  FitReport report;
  const auto q = FitAnalytic(*s, 61, 61, options, 400, 20240611, &report);
  ASSERT_TRUE(q.ok()) << q.status().ToString();
  std::printf(
      "[ measured ] %-18s degree %d x %d, poles %3d x %3d, grid rms %.3e max %.3e, check rms %.3e max %.3e mm\n",
      GetParam().c_str(), q->u_degree(), q->v_degree(), q->u_poles(), q->v_poles(), report.rms_mm, report.max_mm,
      report.check_rms_mm, report.check_max_mm);
  EXPECT_EQ(report.n_points, 61 * 61);
  EXPECT_EQ(report.n_check, 400);
  EXPECT_LE(report.check_max_mm, kFitBoundMm);
  EXPECT_LE(report.max_mm, kFitBoundMm);
  EXPECT_LE(report.check_rms_mm, report.check_max_mm);
  // The fit keeps the parameter domain and the orientation of the source.
  const ParamDomain d = q->domain(), sd = s->domain();
  EXPECT_DOUBLE_EQ(d.u_min, sd.u_min);
  EXPECT_DOUBLE_EQ(d.u_max, sd.u_max);
  EXPECT_DOUBLE_EQ(d.v_min, sd.v_min);
  EXPECT_DOUBLE_EQ(d.v_max, sd.v_max);
  Rng rng(7);
  for (int k = 0; k < 50; ++k) {
    const double u = rng.Uniform(sd.u_min, sd.u_max), v = rng.Uniform(sd.v_min, sd.v_max);
    EXPECT_LE((q->Point(u, v) - s->Point(u, v)).norm(), kFitBoundMm);
    EXPECT_GT(q->Normal(u, v).dot(s->Normal(u, v)), 0.9999);
    EXPECT_GT(q->Normal(u, v).z(), 0);
  }
  const nlohmann::json json = report.ToJson();
  EXPECT_EQ(json.at("n_check"), 400);
  EXPECT_DOUBLE_EQ(json.at("check_max_mm").get<double>(), report.check_max_mm);
}

TEST_P(BSplineFitTest, StepRoundTripKeepsTheSurface) {
  const auto s = Make(GetParam());
  GridFitOptions options;
  const auto q = FitAnalytic(*s, 61, 61, options, 0, 1, nullptr);
  ASSERT_TRUE(q.ok()) << q.status().ToString();
  TempDir dir;
  const auto path = dir.path() / (GetParam() + ".step");
  ::testing::internal::CaptureStdout();
  const Status written = WriteStep(path, *q, GetParam());
  const auto read = ReadStep(path);
  const std::string out = ::testing::internal::GetCapturedStdout();
  ASSERT_TRUE(written.ok()) << written.ToString();
  ASSERT_TRUE(read.ok()) << read.status().ToString();
  EXPECT_EQ(out, "") << "OpenCASCADE printed on stdout";
  for (const auto& entry : std::filesystem::directory_iterator(dir.path())) {
    EXPECT_EQ(entry.path().filename(), path.filename()) << "stray file " << entry.path();
  }

  const Handle(Geom_BSplineSurface)& a = q->geom();
  const Handle(Geom_BSplineSurface)& b = read->geom();
  ASSERT_EQ(a->UDegree(), b->UDegree());
  ASSERT_EQ(a->VDegree(), b->VDegree());
  ASSERT_EQ(a->NbUKnots(), b->NbUKnots());
  ASSERT_EQ(a->NbVKnots(), b->NbVKnots());
  ASSERT_EQ(a->NbUPoles(), b->NbUPoles());
  ASSERT_EQ(a->NbVPoles(), b->NbVPoles());
  EXPECT_EQ(a->IsURational(), b->IsURational());
  double max_knot = 0, max_pole = 0, max_point = 0;
  for (int i = 1; i <= a->NbUKnots(); ++i) {
    max_knot = std::max(max_knot, std::abs(a->UKnot(i) - b->UKnot(i)));
    EXPECT_EQ(a->UMultiplicity(i), b->UMultiplicity(i));
  }
  for (int j = 1; j <= a->NbVKnots(); ++j) {
    max_knot = std::max(max_knot, std::abs(a->VKnot(j) - b->VKnot(j)));
    EXPECT_EQ(a->VMultiplicity(j), b->VMultiplicity(j));
  }
  for (int i = 1; i <= a->NbUPoles(); ++i) {
    for (int j = 1; j <= a->NbVPoles(); ++j) max_pole = std::max(max_pole, a->Pole(i, j).Distance(b->Pole(i, j)));
  }
  const ParamDomain d = q->domain();
  Rng rng(99);
  for (int k = 0; k < 100; ++k) {
    const double u = rng.Uniform(d.u_min, d.u_max), v = rng.Uniform(d.v_min, d.v_max);
    max_point = std::max(max_point, (q->Point(u, v) - read->Point(u, v)).norm());
  }
  std::printf("[ measured ] %-18s STEP round trip: knots %.1e, poles %.1e, points %.1e mm\n", GetParam().c_str(),
              max_knot, max_pole, max_point);
  EXPECT_LE(max_knot, 1e-9);
  EXPECT_LE(max_pole, 1e-9);
  EXPECT_LE(max_point, 1e-9);
}

// A point p = S(u, v) + d n(u, v) lies at signed distance d from S; its foot point on a fine B-spline
// Q recovers d to within the fit error. OpenCASCADE's interpolation is capped at 72 samples a side
// (kMaxInterpolationSamples) and leaves up to 8e-5 mm on franke at 61 × 61, so the fine Q is a
// 101 × 101 approximation with tolerance 1e-7 mm (measured check max <= 1.1e-7 mm, franke 8e-8).
TEST_P(BSplineFitTest, ProjectRecoversNormalOffsets) {
  const auto s = Make(GetParam());
  GridFitOptions options;
  options.tolerance_mm = 1e-7;
  options.degree_max = 8;
  FitReport report;
  const auto q = FitAnalytic(*s, 101, 101, options, 200, 3, &report);
  ASSERT_TRUE(q.ok()) << q.status().ToString();
  ASSERT_LE(report.check_max_mm, 2e-7) << "fit too coarse for a 1e-6 mm test";
  const ParamDomain d = s->domain();
  Rng rng(11);
  double worst = 0;
  for (int k = 0; k < 60; ++k) {
    const double u = rng.Uniform(d.u_min + 5, d.u_max - 5), v = rng.Uniform(d.v_min + 5, d.v_max - 5);
    const double offset = (k % 2 == 0 ? 1 : -1) * rng.Uniform(0.001, 2.0);
    const Vector3d p = s->Point(u, v) + offset * s->Normal(u, v);
    const auto global = Project(*q, p);
    const auto local = ProjectFrom(*q, p, u + 1, v - 1);
    ASSERT_TRUE(global.ok()) << global.status().ToString();
    ASSERT_TRUE(local.ok()) << local.status().ToString();
    EXPECT_NEAR(global->deviation_mm, offset, 1e-6) << "at (" << u << ", " << v << ")";
    EXPECT_NEAR(local->deviation_mm, offset, 1e-6);
    EXPECT_NEAR(global->u, u, 1e-4);
    EXPECT_NEAR(global->v, v, 1e-4);
    EXPECT_FALSE(global->on_boundary);
    EXPECT_NEAR(global->normal.norm(), 1, 1e-12);
    EXPECT_LE((global->foot - (p - global->deviation_mm * global->normal)).norm(), 1e-9);
    worst = std::max(worst, std::abs(global->deviation_mm - offset));

    // Cross-check with OpenCASCADE's extrema on the same point (spec §4).
    GeomAPI_ProjectPointOnSurf occt(gp_Pnt(p.x(), p.y(), p.z()), q->geom());
    ASSERT_GT(occt.NbPoints(), 0);
    double ou, ov;
    occt.LowerDistanceParameters(ou, ov);
    EXPECT_NEAR(occt.LowerDistance(), std::abs(global->deviation_mm), 1e-9);
    EXPECT_NEAR(ou, global->u, 1e-6);
    EXPECT_NEAR(ov, global->v, 1e-6);
  }
  std::printf("[ measured ] %-18s projection |d - offset| max %.1e mm (interpolation check max %.1e mm)\n",
              GetParam().c_str(), worst, report.check_max_mm);
}

TEST_P(BSplineFitTest, ProjectClampsAndFlagsBoundaryPoints) {
  const auto s = Make(GetParam());
  const auto q = FitAnalytic(*s, 41, 41, GridFitOptions{}, 0, 1, nullptr);
  ASSERT_TRUE(q.ok()) << q.status().ToString();
  const ParamDomain d = s->domain();
  const double v_mid = 0.5 * (d.v_min + d.v_max), u_mid = 0.5 * (d.u_min + d.u_max);
  // Beyond the u_max edge, along the outward tangent, and lifted along the normal.
  const SurfaceDerivatives e = s->Derivatives(d.u_max, v_mid);
  const Vector3d outside = e.p + 5 * e.su.normalized() + 0.5 * NormalFromDerivatives(e);
  const auto foot = Project(*q, outside);
  ASSERT_TRUE(foot.ok()) << foot.status().ToString();
  EXPECT_TRUE(foot->on_boundary);
  EXPECT_DOUBLE_EQ(foot->u, d.u_max);
  EXPECT_NEAR(foot->v, v_mid, 0.5);
  // Beyond the v_min edge.
  const SurfaceDerivatives f = s->Derivatives(u_mid, d.v_min);
  const auto foot2 = ProjectFrom(*q, f.p - 3 * f.sv.normalized(), u_mid, d.v_min + 10);
  ASSERT_TRUE(foot2.ok()) << foot2.status().ToString();
  EXPECT_TRUE(foot2->on_boundary);
  EXPECT_DOUBLE_EQ(foot2->v, d.v_min);
  // Inside: not flagged.
  const auto inside = Project(*q, s->Point(u_mid, v_mid) + Vector3d(0, 0, 1));
  ASSERT_TRUE(inside.ok());
  EXPECT_FALSE(inside->on_boundary);
}

INSTANTIATE_TEST_SUITE_P(ReferenceSurfaces, BSplineFitTest, ::testing::ValuesIn(ReferenceSurfaceNames()),
                         [](const auto& test_param) { return test_param.param; });

TEST(FitGrid, InterpolationPassesThroughTheSamples) {
  const auto s = Make("franke");
  GridFitOptions options;
  options.interpolate = true;
  FitReport report;
  const auto q = FitGrid(SampleGrid(*s, 31, 25), options, &report);
  ASSERT_TRUE(q.ok()) << q.status().ToString();
  EXPECT_EQ(report.method, "occt-grid-interpolation");
  EXPECT_LE(report.max_mm, 1e-9);
}

TEST(FitGrid, RefusesInterpolationGridsWhereOcctOscillates) {
  const auto s = Make("plane");
  GridFitOptions options;
  options.interpolate = true;
  FitReport report;
  const auto ok = FitAnalytic(*s, kMaxInterpolationSamples, kMaxInterpolationSamples, options, 200, 5, &report);
  ASSERT_TRUE(ok.ok()) << ok.status().ToString();
  EXPECT_LE(report.check_max_mm, 1e-8);
  const auto refused = FitAnalytic(*s, kMaxInterpolationSamples + 1, 20, options, 0, 5, nullptr);
  ASSERT_FALSE(refused.ok());
  EXPECT_EQ(refused.status().code(), StatusCode::kBadInput);
  EXPECT_NE(refused.status().message().find("approximation"), std::string::npos);
}

TEST(FitGrid, RejectsBadOptionsAndGrids) {
  GridFitOptions options;
  options.degree_max = 2;
  EXPECT_EQ(options.Validate().code(), StatusCode::kBadInput);
  options = GridFitOptions{};
  options.tolerance_mm = 0;
  EXPECT_EQ(options.Validate().code(), StatusCode::kBadInput);
  EXPECT_TRUE(GridFitOptions{}.Validate().ok());
  GridSamples tiny;
  tiny.nu = 1;
  tiny.nv = 5;
  tiny.points.assign(5, Vector3d::Zero());
  EXPECT_EQ(FitGrid(tiny, GridFitOptions{}, nullptr).status().code(), StatusCode::kBadInput);
  GridSamples bad = SampleGrid(*Make("plane"), 5, 5);
  bad.points[3].z() = std::nan("");
  EXPECT_EQ(FitGrid(bad, GridFitOptions{}, nullptr).status().code(), StatusCode::kBadInput);
}

TEST(SampleGridPoints, CarriesNormalsAndCurvatures) {
  const auto s = Make("sphere_cap");
  const PointSet set = SampleGridPoints(*s, 7, 5);
  ASSERT_EQ(set.size(), 35u);
  EXPECT_TRUE(set.Validate("test").ok());
  ASSERT_TRUE(set.has_normals());
  ASSERT_NE(set.FindScalar("k1"), nullptr);
  ASSERT_NE(set.FindScalar("u"), nullptr);
  EXPECT_DOUBLE_EQ((*set.FindScalar("u"))[6], s->domain().u_max);
  EXPECT_DOUBLE_EQ((*set.FindScalar("v"))[34], s->domain().v_max);
  EXPECT_NEAR((*set.FindScalar("k2"))[17], 0.01, 1e-14);
  EXPECT_GT(set.normals[0].z(), 0);
}

TEST(Step, ReadErrorsAreClear) {
  TempDir dir;
  const auto missing = ReadStep(dir.path() / "nope.step");
  ASSERT_FALSE(missing.ok());
  EXPECT_EQ(missing.status().code(), StatusCode::kNotFound);
  EXPECT_NE(missing.status().message().find("nope.step"), std::string::npos);

  const auto text = dir.path() / "not_step.step";
  std::ofstream(text) << "x,y,z\n1,2,3\n";
  ::testing::internal::CaptureStdout();
  const auto garbage = ReadStep(text);
  const std::string out = ::testing::internal::GetCapturedStdout();
  ASSERT_FALSE(garbage.ok());
  EXPECT_EQ(garbage.status().code(), StatusCode::kBadInput);
  EXPECT_NE(garbage.status().message().find("not_step.step"), std::string::npos) << garbage.status().message();
  EXPECT_EQ(out, "");

  const auto q = FitAnalytic(*Make("saddle"), 21, 21, GridFitOptions{}, 0, 1, nullptr);
  ASSERT_TRUE(q.ok());
  const auto path = dir.path() / "saddle.step";
  ASSERT_TRUE(WriteStep(path, *q, "saddle").ok());
  const auto out_of_range = ReadStep(path, 1);
  ASSERT_FALSE(out_of_range.ok());
  EXPECT_EQ(out_of_range.status().code(), StatusCode::kBadInput);
  EXPECT_NE(out_of_range.status().message().find("1 face"), std::string::npos) << out_of_range.status().message();
  EXPECT_EQ(ReadStep(path, -1).status().code(), StatusCode::kBadInput);
  // The product carries the name.
  std::ifstream in(path);
  const std::string content((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  EXPECT_NE(content.find("PRODUCT('saddle"), std::string::npos);  // OpenCASCADE appends " 1"
  EXPECT_NE(content.find("SI_UNIT(.MILLI.,.METRE.)"), std::string::npos);
}

TEST(Step, FailedWriteLeavesNoFile) {
  TempDir dir;
  const auto q = FitAnalytic(*Make("plane"), 11, 11, GridFitOptions{}, 0, 1, nullptr);
  ASSERT_TRUE(q.ok());
  const auto path = dir.path() / "missing_folder" / "q.step";
  const Status status = WriteStep(path, *q, "plane");
  EXPECT_FALSE(status.ok());
  EXPECT_FALSE(std::filesystem::exists(path));
  EXPECT_FALSE(WriteStep(dir.path() / "empty.step", BSplineSurface(), "x").ok());
  EXPECT_TRUE(std::filesystem::is_empty(dir.path()));
}

// The reader honours the unit the file declares and converts to mm. (OpenCASCADE 7.6.3's writer
// only relabels: with write.step.unit = M it declares metres but writes the mm values unchanged, so
// the file reads back 1000 times larger. WriteStep therefore always writes MM.)
TEST(Step, ReaderConvertsTheFileUnitToMillimetres) {
  TempDir dir;
  const auto q = FitAnalytic(*Make("egg_box"), 21, 21, GridFitOptions{}, 0, 1, nullptr);
  ASSERT_TRUE(q.ok());
  const auto path = dir.path() / "metres.step";
  ASSERT_TRUE(WriteStep(path, *q, "egg").ok());  // initialises the controller and the printers
  {
    BRepBuilderAPI_MakeFace face(q->geom(), Precision::Confusion());
    STEPControl_Writer writer;
    Interface_Static::SetCVal("write.step.unit", "M");
    ASSERT_EQ(writer.Transfer(face.Face(), STEPControl_AsIs), IFSelect_RetDone);
    ASSERT_EQ(writer.Write(path.string().c_str()), IFSelect_RetDone);
    Interface_Static::SetCVal("write.step.unit", "MM");
  }
  std::ifstream in(path);
  const std::string content((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  ASSERT_NE(content.find("SI_UNIT($,.METRE.)"), std::string::npos) << "file does not declare metres";
  const auto read = ReadStep(path);
  ASSERT_TRUE(read.ok()) << read.status().ToString();
  double max_pole = 0;
  for (int i = 1; i <= q->u_poles(); ++i) {
    for (int j = 1; j <= q->v_poles(); ++j) {
      const gp_Pnt a = q->geom()->Pole(i, j), b = read->geom()->Pole(i, j);
      max_pole = std::max(max_pole, gp_Pnt(a.XYZ() * 1000).Distance(b));
    }
  }
  EXPECT_LE(max_pole, 1e-6);
  EXPECT_NEAR(read->domain().u_max, q->domain().u_max, 1e-9);  // parameters are not lengths: unchanged
}

TEST(Project, RejectsNonFinitePointsAndEmptySurfaces) {
  const auto q = FitAnalytic(*Make("plane"), 11, 11, GridFitOptions{}, 0, 1, nullptr);
  ASSERT_TRUE(q.ok());
  const auto bad = Project(*q, Vector3d(1, std::nan(""), 0));
  ASSERT_FALSE(bad.ok());
  EXPECT_EQ(bad.status().code(), StatusCode::kBadInput);
  EXPECT_NE(bad.status().message().find("nan"), std::string::npos) << bad.status().message();
  EXPECT_FALSE(Project(BSplineSurface(), Vector3d::Zero()).ok());
}

}  // namespace
}  // namespace formloop::recon
