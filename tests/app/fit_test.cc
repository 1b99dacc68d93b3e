// `formloop fit` and `formloop project` (app/surface_fit.h): every input kind and method end to end,
// the bad-input cases of issue 3 (clear error, no output file), and the binary's stdout/exit codes.

#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <string>

#include <unistd.h>
#include <BRepBuilderAPI_MakeVertex.hxx>
#include <BRepPrimAPI_MakeBox.hxx>
#include <STEPControl_Writer.hxx>
#include <StepData_StepModel.hxx>
#include <StepShape_AdvancedFace.hxx>
#include <TCollection_HAsciiString.hxx>
#include <gp_Pnt.hxx>

#include <gtest/gtest.h>

#include "app/surface_fit.h"
#include "core/json_io.h"
#include "core/log.h"
#include "core/point_io.h"
#include "core/random.h"
#include "reconstruction/analytic_surface.h"
#include "reconstruction/occt_support.h"
#include "tests/support/run_binary.h"

namespace formloop::app {
namespace {

namespace fs = std::filesystem;

class FitTest : public ::testing::Test {
 protected:
  void SetUp() override {
    log::SetLevel(log::Level::kWarn);
    recon::occt::KeepStdoutClean();
    dir_ = fs::temp_directory_path() / ("formloop-fit-" + std::to_string(::getpid()) + "-" +
                                        ::testing::UnitTest::GetInstance()->current_test_info()->name());
    fs::remove_all(dir_);
    fs::create_directories(dir_);
  }
  void TearDown() override { fs::remove_all(dir_); }

  FitRequest Request(const std::string& input, const std::string& out = "Q.step") const {
    FitRequest r;
    r.input = input;
    r.out_step = (dir_ / out).string();
    r.out_report = (dir_ / "fit.json").string();
    return r;
  }
  // Nothing but the inputs the test wrote itself.
  void ExpectNoOutputs() const {
    EXPECT_FALSE(fs::exists(dir_ / "Q.step"));
    EXPECT_FALSE(fs::exists(dir_ / "fit.json"));
    for (const auto& entry : fs::directory_iterator(dir_)) {
      EXPECT_EQ(entry.path().string().find(".tmp"), std::string::npos) << "left behind: " << entry.path();
    }
  }
  fs::path dir_;
};

// Seeded uniform samples of a reference surface, optionally offset along the normal by `offset_mm`.
PointSet Samples(const std::string& name, int n, unsigned long long seed, double offset_mm = 0) {
  auto surface = recon::MakeReferenceSurface(name);
  EXPECT_TRUE(surface.ok());
  const recon::ParamDomain d = (*surface)->domain();
  Rng rng(seed);
  PointSet set;
  for (int k = 0; k < n; ++k) {
    const double u = rng.Uniform(d.u_min, d.u_max), v = rng.Uniform(d.v_min, d.v_max);
    set.points.push_back((*surface)->Point(u, v) + offset_mm * (*surface)->Normal(u, v));
  }
  return set;
}

// A 10 × 20 × 30 mm box as STEP with faces named face_0 ... face_5.
void WriteBox(const fs::path& path) {
  STEPControl_Writer writer;
  ASSERT_EQ(writer.Transfer(BRepPrimAPI_MakeBox(10, 20, 30).Shape(), STEPControl_AsIs), IFSelect_RetDone);
  const Handle(StepData_StepModel) model = writer.Model();
  int k = 0;
  for (Standard_Integer i = 1; i <= model->NbEntities(); ++i) {
    const Handle(StepShape_AdvancedFace) face = Handle(StepShape_AdvancedFace)::DownCast(model->Value(i));
    if (!face.IsNull()) face->SetName(new TCollection_HAsciiString(("face_" + std::to_string(k++)).c_str()));
  }
  ASSERT_EQ(writer.Write(path.string().c_str()), IFSelect_RetDone);
}

TEST_F(FitTest, AnalyticGridFitIsCheckedAgainstTheTruth) {
  ASSERT_TRUE(RunFit(Request("analytic:franke")).ok());
  const auto report = ReadJsonFile(dir_ / "fit.json");
  ASSERT_TRUE(report.ok());
  EXPECT_EQ((*report)["method"], "grid");
  EXPECT_EQ((*report)["input"]["surface"], "franke");
  EXPECT_EQ((*report)["fit"]["n_check"], 10000);
  EXPECT_LT((*report)["fit"]["check_max_mm"].get<double>(), 1e-3);
  EXPECT_EQ((*report)["fit"]["max_at_mm"].size(), 3u);
  const auto q = recon::ReadCadFace(dir_ / "Q.step", {.name = "franke"});
  ASSERT_TRUE(q.ok()) << q.status().ToString();
}

TEST_F(FitTest, ScatteredPointsFitThenProjectGivesTheOffsets) {
  const fs::path points = dir_ / "scan.csv";
  ASSERT_TRUE(WritePoints(points, Samples("saddle", 5000, 11)).ok());
  FitRequest request = Request(points.string());
  ASSERT_TRUE(RunFit(request).ok());
  const auto report = ReadJsonFile(dir_ / "fit.json");
  ASSERT_TRUE(report.ok());
  EXPECT_EQ((*report)["method"], "scattered");
  EXPECT_LT((*report)["fit"]["max_mm"].get<double>(), 1e-3);

  // Points 0.2 mm above the saddle project with deviation +0.2 mm (within the fit's micrometre).
  const fs::path probed = dir_ / "probed.csv";
  ASSERT_TRUE(WritePoints(probed, Samples("saddle", 500, 12, 0.2)).ok());
  ProjectRequest project;
  project.surface = (dir_ / "Q.step").string();
  project.points = probed.string();
  project.out = (dir_ / "dev.csv").string();
  const auto outcome = ProjectPoints(project);
  ASSERT_TRUE(outcome.ok()) << outcome.status().ToString();
  const std::vector<double>* dev = outcome->deviations.FindScalar("deviation_mm");
  ASSERT_NE(dev, nullptr);
  for (double d : *dev) EXPECT_NEAR(d, 0.2, 1e-3);
  EXPECT_NEAR(outcome->summary["rms_deviation_mm"].get<double>(), 0.2, 1e-3);
  ASSERT_TRUE(RunProject(project).ok());
  const auto back = ReadPoints(dir_ / "dev.csv");
  ASSERT_TRUE(back.ok());
  EXPECT_EQ(back->size(), 500u);
  for (const char* column : {"deviation_mm", "foot_u", "foot_v", "foot_x", "foot_y", "foot_z", "on_boundary"}) {
    EXPECT_NE(back->FindScalar(column), nullptr) << column;
  }
  EXPECT_TRUE(back->has_normals());
}

TEST_F(FitTest, QuadricMethodsReportBothFits) {
  // An ellipsoid cap: (x/60)² + (y/45)² + ((z + 20)/30)² = 1, z > 0 part.
  Rng rng(5);
  PointSet cap;
  while (cap.size() < 3000) {
    const double x = rng.Uniform(-35, 35), y = rng.Uniform(-25, 25);
    const double w = 1 - (x / 60) * (x / 60) - (y / 45) * (y / 45);
    if (w <= 0) continue;
    cap.points.emplace_back(x, y, 30 * std::sqrt(w) - 20);
  }
  const fs::path points = dir_ / "cap.xyz";
  ASSERT_TRUE(WritePoints(points, cap).ok());
  FitRequest request = Request(points.string());
  request.method = FitMethod::kQuadricGeometric;
  const Status status = RunFit(request);
  ASSERT_TRUE(status.ok()) << status.ToString();
  const auto report = ReadJsonFile(dir_ / "fit.json");
  ASSERT_TRUE(report.ok());
  ASSERT_TRUE(report->contains("quadric"));
  EXPECT_TRUE((*report)["quadric"].contains("algebraic"));
  EXPECT_TRUE((*report)["quadric"].contains("geometric"));
  EXPECT_LT((*report)["fit"]["max_mm"].get<double>(), 1e-3);
}

TEST_F(FitTest, CadFaceByNameIsWrittenAsQ) {
  const fs::path box = dir_ / "box.step";
  WriteBox(box);
  FitRequest request = Request(box.string());
  request.face.name = "face_2";
  ASSERT_TRUE(RunFit(request).ok());
  const auto report = ReadJsonFile(dir_ / "fit.json");
  ASSERT_TRUE(report.ok());
  EXPECT_EQ((*report)["method"], "cad");
  EXPECT_EQ((*report)["input"]["face_name"], "face_2");
  EXPECT_EQ((*report)["input"]["surface_type"], "Geom_Plane");
  EXPECT_EQ((*report)["input"]["file_unit"], "mm");
}

TEST_F(FitTest, BadInputIsRefusedWithAClearErrorAndNoOutput) {
  struct Case {
    std::string label;
    FitRequest request;
    std::string expect;  // a piece of the message
  };
  std::vector<Case> cases;

  const fs::path point_step = dir_ / "point.step";
  {
    STEPControl_Writer writer;
    ASSERT_EQ(writer.Transfer(BRepBuilderAPI_MakeVertex(gp_Pnt(1, 2, 3)).Vertex(), STEPControl_AsIs), IFSelect_RetDone);
    ASSERT_EQ(writer.Write(point_step.string().c_str()), IFSelect_RetDone);
  }
  cases.push_back({"no faces", Request(point_step.string()), "holds no face"});

  const fs::path box = dir_ / "box.step";
  WriteBox(box);
  FitRequest missing_name = Request(box.string());
  missing_name.face.name = "top";
  cases.push_back({"missing face name", missing_name, "no face is named 'top'"});
  cases.push_back({"several faces, none chosen", Request(box.string()), "has 6 faces"});
  FitRequest cad_scattered = Request(box.string());
  cad_scattered.method = FitMethod::kScattered;
  cad_scattered.face.index = 0;
  cases.push_back({"CAD with a point method", cad_scattered, "taken as it is"});

  const fs::path few = dir_ / "few.csv";
  ASSERT_TRUE(WritePoints(few, Samples("saddle", 12, 3)).ok());
  cases.push_back({"fewer points than unknowns", Request(few.string()), "12"});

  const fs::path nan = dir_ / "nan.csv";
  std::ofstream(nan) << "x,y,z\n0,0,0\n1,0,0\n0,nan,1\n1,1,1\n";
  cases.push_back({"NaN", Request(nan.string()), "nan.csv"});

  PointSet duplicated = Samples("saddle", 2000, 4);
  duplicated.points[1500] = duplicated.points[17];
  const fs::path dup = dir_ / "dup.csv";
  ASSERT_TRUE(WritePoints(dup, duplicated).ok());
  cases.push_back({"duplicated points", Request(dup.string()), "1500"});

  PointSet line;
  for (int k = 0; k < 2500; ++k) line.points.emplace_back(0.01 * k, 0.02 * k, -0.005 * k);
  const fs::path collinear = dir_ / "line.csv";
  ASSERT_TRUE(WritePoints(collinear, line).ok());
  cases.push_back({"collinear, scattered", Request(collinear.string()), "collinear"});
  FitRequest collinear_grid = Request(collinear.string());
  collinear_grid.method = FitMethod::kGrid;
  cases.push_back({"collinear, grid", collinear_grid, "collinear"});
  FitRequest collinear_quadric = Request(collinear.string());
  collinear_quadric.method = FitMethod::kQuadricAlgebraic;
  cases.push_back({"collinear, quadric", collinear_quadric, "collinear"});

  FitRequest layout = Request(dup.string());
  layout.method = FitMethod::kGrid;
  layout.grid_nu = 30;
  layout.grid_nv = 30;
  cases.push_back({"grid layout mismatch", layout, "does not match"});

  cases.push_back({"unknown surface", Request("analytic:teapot"), "teapot"});
  cases.push_back({"output not STEP", Request("analytic:plane", "Q.iges"), "STEP"});

  for (const Case& c : cases) {
    const auto outcome = FitSurface(c.request);
    ASSERT_FALSE(outcome.ok()) << c.label;
    EXPECT_TRUE(outcome.status().code() == StatusCode::kBadInput || outcome.status().code() == StatusCode::kNotFound)
        << c.label << ": " << outcome.status().ToString();
    EXPECT_EQ(outcome.status().ExitCode(), 2) << c.label;
    EXPECT_NE(outcome.status().ToString().find(c.expect), std::string::npos)
        << c.label << ": '" << outcome.status().ToString() << "' should mention '" << c.expect << "'";
    EXPECT_FALSE(RunFit(c.request).ok()) << c.label;
    ExpectNoOutputs();
  }
}

int RunBinary(const std::string& args, std::string* out, std::string* err, const fs::path&) {
  return testing::RunFormloop(args, out, err);
}

// The global --threads: the scattered fit (its parameter correction projects in parallel) and
// `project` write the same bytes on one and two threads.
TEST_F(FitTest, ScatteredFitAndProjectAreTheSameBytesOnOneAndTwoThreads) {
  ASSERT_TRUE(WritePoints(dir_ / "p.csv", Samples("egg_box", 6000, 26)).ok());
  ASSERT_TRUE(WritePoints(dir_ / "near.csv", Samples("egg_box", 5000, 27, 0.3)).ok());
  std::string bytes[2][2], out, err;
  for (int threads : {1, 2}) {
    const std::string t = std::to_string(threads);
    // The same file names in separate folders: the STEP header names the file.
    fs::create_directories(dir_ / t);
    const fs::path q = dir_ / t / "Q.step", dev = dir_ / t / "dev.csv";
    ASSERT_EQ(testing::RunFormloop("--threads " + t + " fit " + (dir_ / "p.csv").string() + " --out " + q.string(),
                                   &out, &err),
              0)
        << err;
    ASSERT_EQ(testing::RunFormloop("--threads " + t + " project --surface " + q.string() + " --points " +
                                       (dir_ / "near.csv").string() + " --out " + dev.string(),
                                   &out, &err),
              0)
        << err;
    for (int f = 0; f < 2; ++f) {
      std::ifstream in(f == 0 ? q : dev, std::ios::binary);
      bytes[threads - 1][f] = std::string(std::istreambuf_iterator<char>(in), {});
    }
  }
  EXPECT_GT(bytes[0][1].size(), 5000u * 20);
  EXPECT_TRUE(bytes[0][0] == bytes[1][0]) << "the fitted STEP differs between 1 and 2 threads";
  EXPECT_TRUE(bytes[0][1] == bytes[1][1]) << "the deviations differ between 1 and 2 threads";
}

TEST_F(FitTest, BinaryFitAndProject) {
  std::string out, err;
  const std::string q = (dir_ / "Q.step").string();
  ASSERT_EQ(
      RunBinary("fit analytic:egg_box --out " + q + " --report " + (dir_ / "fit.json").string(), &out, &err, dir_), 0)
      << err;
  EXPECT_TRUE(out.empty()) << "stdout is for JSON only: " << out;
  ASSERT_TRUE(WritePoints(dir_ / "p.csv", Samples("egg_box", 100, 9, -0.05)).ok());
  ASSERT_EQ(RunBinary("project --surface " + q + " --points " + (dir_ / "p.csv").string() + " --out " +
                          (dir_ / "dev.ply").string(),
                      &out, &err, dir_),
            0)
      << err;
  const auto summary = ParseJson(out, "stdout");
  ASSERT_TRUE(summary.ok()) << out;
  EXPECT_EQ((*summary)["n_points"], 100);
  EXPECT_NEAR((*summary)["rms_deviation_mm"].get<double>(), 0.05, 1e-3);
  EXPECT_TRUE(fs::exists(dir_ / "dev.ply"));
  // The samples of `surfaces sample` carry u, v columns of their own; the output keeps them.
  ASSERT_EQ(RunBinary("surfaces sample egg_box --nu 20 --nv 20 --out " + (dir_ / "s.csv").string(), &out, &err, dir_),
            0);
  ASSERT_EQ(RunBinary("project --surface " + q + " --points " + (dir_ / "s.csv").string() + " --out " +
                          (dir_ / "s_dev.csv").string(),
                      &out, &err, dir_),
            0)
      << err;
  const auto sampled = ReadPoints(dir_ / "s_dev.csv");
  ASSERT_TRUE(sampled.ok());
  EXPECT_NE(sampled->FindScalar("u"), nullptr);
  EXPECT_NE(sampled->FindScalar("foot_u"), nullptr);

  const fs::path box = dir_ / "box.step";
  WriteBox(box);
  ASSERT_EQ(RunBinary("fit " + box.string() + " --list-faces", &out, &err, dir_), 0) << err;
  const auto faces = ParseJson(out, "stdout");
  ASSERT_TRUE(faces.ok()) << out;
  EXPECT_EQ(faces->size(), 6u);

  // Bad input: exit code 2, the message names the file and the face, nothing written.
  EXPECT_EQ(RunBinary("fit " + box.string() + " --face-name top --out " + (dir_ / "B.step").string(), &out, &err, dir_),
            2);
  EXPECT_NE(err.find("box.step"), std::string::npos) << err;
  EXPECT_NE(err.find("'top'"), std::string::npos) << err;
  EXPECT_FALSE(fs::exists(dir_ / "B.step"));
  EXPECT_EQ(RunBinary("fit analytic:plane --method spline --out " + (dir_ / "B.step").string(), &out, &err, dir_), 2);
  EXPECT_NE(err.find("--method"), std::string::npos) << err;
}

}  // namespace
}  // namespace formloop::app
