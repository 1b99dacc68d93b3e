// CAD input of the ideal surface (reconstruction/cad_io.h): faces by index and by name, units,
// IGES, and the bad-input cases (no faces, missing name, several faces without a choice).
//
// The fixtures are made here with OpenCASCADE's own writers (a box for several planar faces, the
// saddle reference surface for a B-spline face), so nothing opaque is committed.

#include <algorithm>
#include <filesystem>
#include <fstream>
#include <set>
#include <sstream>
#include <string>

#include <gtest/gtest.h>
#include <BRepBuilderAPI_MakeFace.hxx>
#include <BRepBuilderAPI_MakeVertex.hxx>
#include <BRepPrimAPI_MakeBox.hxx>
#include <IGESControl_Controller.hxx>
#include <IGESControl_Writer.hxx>
#include <IGESData_IGESEntity.hxx>
#include <IGESData_IGESModel.hxx>
#include <Interface_Static.hxx>
#include <Precision.hxx>
#include <STEPControl_Writer.hxx>
#include <StepData_StepModel.hxx>
#include <StepShape_AdvancedFace.hxx>
#include <TCollection_HAsciiString.hxx>
#include <gp_Pnt.hxx>

#include "core/random.h"
#include "reconstruction/analytic_surface.h"
#include "reconstruction/bspline_surface.h"
#include "reconstruction/cad_io.h"
#include "reconstruction/occt_support.h"
#include "reconstruction/trim.h"
#include "tests/support/cad_fixtures.h"

namespace formloop::recon {
namespace {

namespace fs = std::filesystem;

class CadIoTest : public ::testing::Test {
 protected:
  void SetUp() override {
    const auto* info = ::testing::UnitTest::GetInstance()->current_test_info();
    dir_ = fs::temp_directory_path() / ("formloop_cad_io_" + std::string(info->name()));
    fs::remove_all(dir_);
    fs::create_directories(dir_);
    occt::KeepStdoutClean();
  }
  void TearDown() override { fs::remove_all(dir_); }
  fs::path dir_;
};

std::string ReadText(const fs::path& path) {
  std::ifstream in(path);
  std::stringstream text;
  text << in.rdbuf();
  return text.str();
}

// A 10 × 20 × 30 mm box written as STEP in `unit` ("MM" or "INCH"); its six ADVANCED_FACEs are named
// face_0 ... face_5 in model order (face_3 is given twice when `duplicate_name`).
void WriteBoxStep(const fs::path& path, const char* unit, bool duplicate_name = false) {
  const TopoDS_Shape box = BRepPrimAPI_MakeBox(10, 20, 30).Shape();
  STEPControl_Writer writer;
  Interface_Static::SetCVal("write.step.unit", unit);
  ASSERT_EQ(writer.Transfer(box, STEPControl_AsIs), IFSelect_RetDone);
  const Handle(StepData_StepModel) model = writer.Model();
  int k = 0;
  for (Standard_Integer i = 1; i <= model->NbEntities(); ++i) {
    const Handle(StepShape_AdvancedFace) face = Handle(StepShape_AdvancedFace)::DownCast(model->Value(i));
    if (face.IsNull()) continue;
    const int label = duplicate_name && k == 4 ? 3 : k;
    face->SetName(new TCollection_HAsciiString(("face_" + std::to_string(label)).c_str()));
    ++k;
  }
  ASSERT_EQ(k, 6);
  ASSERT_EQ(writer.Write(path.string().c_str()), IFSelect_RetDone);
  Interface_Static::SetCVal("write.step.unit", "MM");
}

BSplineSurface SaddleQ() {
  auto saddle = MakeReferenceSurface("saddle");
  EXPECT_TRUE(saddle.ok());
  FitReport report;
  auto q = FitAnalytic(**saddle, 21, 21, GridFitOptions{}, 0, 1, &report);
  EXPECT_TRUE(q.ok()) << q.status().ToString();
  return *q;
}

double MaxPoleDistance(const BSplineSurface& a, const BSplineSurface& b) {
  double max = 0;
  for (int i = 1; i <= a.u_poles(); ++i) {
    for (int j = 1; j <= a.v_poles(); ++j) max = std::max(max, a.geom()->Pole(i, j).Distance(b.geom()->Pole(i, j)));
  }
  return max;
}

TEST_F(CadIoTest, ListsFacesWithNamesAndTypes) {
  const fs::path path = dir_ / "box.step";
  WriteBoxStep(path, "MM");
  const auto faces = ListCadFaces(path);
  ASSERT_TRUE(faces.ok()) << faces.status().ToString();
  ASSERT_EQ(faces->size(), 6u);
  std::set<std::string> names;
  for (const CadFaceInfo& info : *faces) {
    EXPECT_EQ(info.surface_type, "Geom_Plane");
    names.insert(info.name);
  }
  EXPECT_EQ(names, (std::set<std::string>{"face_0", "face_1", "face_2", "face_3", "face_4", "face_5"}));
  // Each face's box, area and the way it looks (away from the material): the 10 x 20 x 30 box's faces
  // look along ±x, ±y, ±z, so one looks up, one down and four sideways.
  double area = 0;
  std::vector<double> normal_z;
  for (const CadFaceInfo& info : *faces) {
    area += info.area_mm2;
    normal_z.push_back(std::round(info.mean_normal_z * 1e9) / 1e9);
    for (int a = 0; a < 3; ++a) {
      EXPECT_GE(info.box_min_mm[a], -1e-3);
      EXPECT_LE(info.box_max_mm[a], (a == 0 ? 10 : a == 1 ? 20 : 30) + 1e-3);
    }
    if (normal_z.back() == 1) {
      EXPECT_NEAR(info.box_min_mm[2], 30, 1e-3);
    }
  }
  EXPECT_NEAR(area, 2 * (10 * 20 + 20 * 30 + 10 * 30), 1e-6);
  std::sort(normal_z.begin(), normal_z.end());
  EXPECT_EQ(normal_z, (std::vector<double>{-1, 0, 0, 0, 0, 1}));
}

TEST_F(CadIoTest, ChoosesAFaceByNameOrIndexAndConvertsPlanes) {
  const fs::path path = dir_ / "box.step";
  WriteBoxStep(path, "MM");
  const auto faces = ListCadFaces(path);
  ASSERT_TRUE(faces.ok());
  for (const CadFaceInfo& info : *faces) {
    const auto by_name = ReadCadFace(path, CadFaceSelector{.name = info.name});
    ASSERT_TRUE(by_name.ok()) << by_name.status().ToString();
    EXPECT_EQ(by_name->info.index, info.index);
    EXPECT_TRUE(by_name->converted);
    EXPECT_EQ(by_name->file_unit, "mm");
    const auto by_index = ReadCadFace(path, CadFaceSelector{.index = info.index});
    ASSERT_TRUE(by_index.ok());
    EXPECT_EQ(by_index->info.name, info.name);
    // A box face: its centre lies on one of the six planes and its normal points out of the box.
    const ParamDomain d = by_name->surface.domain();
    const double u = 0.5 * (d.u_min + d.u_max), v = 0.5 * (d.v_min + d.v_max);
    const Eigen::Vector3d p = by_name->surface.Point(u, v);
    const Eigen::Vector3d n = by_name->surface.Normal(u, v);
    const Eigen::Vector3d centre(5, 10, 15);
    EXPECT_GT((p - centre).dot(n), 4.9) << "face " << info.name << " normal points into the material";
  }
}

TEST_F(CadIoTest, HonoursTheFileUnit) {
  // The writer labels the file with the unit and writes the numbers as they are, so the same box
  // labelled INCH is a box 25.4 times larger once read back in mm.
  const fs::path mm = dir_ / "box_mm.step", inch = dir_ / "box_inch.step";
  WriteBoxStep(mm, "MM");
  WriteBoxStep(inch, "INCH");
  EXPECT_NE(ReadText(inch).find("CONVERSION_BASED_UNIT('INCH'"), std::string::npos);
  for (int index = 0; index < 6; ++index) {
    const auto a = ReadCadFace(mm, CadFaceSelector{.index = index});
    const auto b = ReadCadFace(inch, CadFaceSelector{.index = index});
    ASSERT_TRUE(a.ok() && b.ok());
    EXPECT_EQ(b->file_unit, "inch");
    const ParamDomain da = a->surface.domain(), db = b->surface.domain();
    const Eigen::Vector3d pa = a->surface.Point(da.u_max, da.v_max), pb = b->surface.Point(db.u_max, db.v_max);
    EXPECT_LT((pb - 25.4 * pa).norm(), 1e-9) << pa.transpose() << " vs " << pb.transpose();
  }
}

TEST_F(CadIoTest, StepRoundTripKeepsTheNameAndTheSurface) {
  const BSplineSurface q = SaddleQ();
  const fs::path path = dir_ / "q.step";
  ASSERT_TRUE(WriteStep(path, q, "saddle_top").ok());
  const auto face = ReadCadFace(path, CadFaceSelector{.name = "saddle_top"});
  ASSERT_TRUE(face.ok()) << face.status().ToString();
  EXPECT_FALSE(face->converted);
  EXPECT_EQ(face->info.surface_type, "Geom_BSplineSurface");
  EXPECT_LT(MaxPoleDistance(q, face->surface), 1e-9);
  // Only one face: no selector needed.
  EXPECT_TRUE(ReadCadFace(path, CadFaceSelector{}).ok());
}

// "reverse" turns a face over: the same points, the normal the other way (for a face without a solid
// written with its normal into the material; the planner cuts the side the normal points to).
TEST_F(CadIoTest, AReversedFaceHasTheSamePointsAndTheOppositeNormal) {
  const BSplineSurface q = SaddleQ();
  const fs::path path = dir_ / "q.step";
  ASSERT_TRUE(WriteStep(path, q, "saddle_top").ok());
  const auto as_written = ReadCadFace(path, CadFaceSelector{});
  const auto turned = ReadCadFace(path, CadFaceSelector{.reverse = true});
  ASSERT_TRUE(as_written.ok() && turned.ok()) << turned.status().ToString();
  const ParamDomain d = as_written->surface.domain(), e = turned->surface.domain();
  for (const double s : {0.1, 0.5, 0.8}) {
    for (const double t : {0.2, 0.7}) {
      const double u = d.u_min + s * d.u_span(), v = d.v_min + t * d.v_span();
      const double u_turned = e.u_max - s * e.u_span();  // u runs the other way
      EXPECT_LT((as_written->surface.Point(u, v) - turned->surface.Point(u_turned, v)).norm(), 1e-9);
      EXPECT_LT((as_written->surface.Normal(u, v) + turned->surface.Normal(u_turned, v)).norm(), 1e-9);
    }
  }
  EXPECT_GT(as_written->surface.Normal(d.u_min + 0.5 * d.u_span(), d.v_min + 0.5 * d.v_span()).z(), 0);
}

TEST_F(CadIoTest, ReadsIgesByIndexAndName) {
  const BSplineSurface q = SaddleQ();
  const ParamDomain d = q.domain();
  const fs::path path = dir_ / "q.igs";
  {
    IGESControl_Controller::Init();
    IGESControl_Writer writer("MM", 0);
    BRepBuilderAPI_MakeFace face(q.geom(), d.u_min, d.u_max, d.v_min, d.v_max, Precision::Confusion());
    ASSERT_TRUE(writer.AddShape(face.Face()));
    writer.ComputeModel();
    const Handle(IGESData_IGESModel) model = writer.Model();
    for (Standard_Integer i = 1; i <= model->NbEntities(); ++i) {
      model->Entity(i)->SetLabel(new TCollection_HAsciiString("SADDLE"));
    }
    ASSERT_TRUE(writer.Write(path.string().c_str()));
  }
  const auto faces = ListCadFaces(path);
  ASSERT_TRUE(faces.ok()) << faces.status().ToString();
  ASSERT_EQ(faces->size(), 1u);
  EXPECT_EQ(faces->front().name, "SADDLE");
  const auto face = ReadCadFace(path, CadFaceSelector{.name = "SADDLE"});
  ASSERT_TRUE(face.ok()) << face.status().ToString();
  EXPECT_EQ(face->file_unit, "mm");
  // IGES keeps the poles; compare points over the domain rather than the pole layout.
  const ParamDomain e = face->surface.domain();
  Rng rng(7);
  double max = 0;
  for (int k = 0; k < 200; ++k) {
    const double s = rng.Uniform(0, 1), t = rng.Uniform(0, 1);
    const Eigen::Vector3d a = q.Point(d.u_min + s * d.u_span(), d.v_min + t * d.v_span());
    const Eigen::Vector3d b = face->surface.Point(e.u_min + s * e.u_span(), e.v_min + t * e.v_span());
    max = std::max(max, (a - b).norm());
  }
  EXPECT_LT(max, 1e-7);
}

TEST_F(CadIoTest, BadInputGivesClearErrors) {
  const fs::path box = dir_ / "box.step";
  WriteBoxStep(box, "MM", /*duplicate_name=*/true);

  const auto missing = ReadCadFace(box, CadFaceSelector{.name = "top"});
  ASSERT_FALSE(missing.ok());
  EXPECT_EQ(missing.status().code(), StatusCode::kBadInput);
  EXPECT_NE(missing.status().ToString().find("no face is named 'top'"), std::string::npos);
  EXPECT_NE(missing.status().ToString().find("face_0"), std::string::npos) << "the error lists the faces";

  const auto twice = ReadCadFace(box, CadFaceSelector{.name = "face_3"});
  ASSERT_FALSE(twice.ok());
  EXPECT_NE(twice.status().ToString().find("2 faces are named 'face_3'"), std::string::npos);

  const auto unchosen = ReadCadFace(box, CadFaceSelector{});
  ASSERT_FALSE(unchosen.ok());
  EXPECT_NE(unchosen.status().ToString().find("has 6 faces"), std::string::npos);

  const auto range = ReadCadFace(box, CadFaceSelector{.index = 6});
  ASSERT_FALSE(range.ok());
  EXPECT_NE(range.status().ToString().find("from 0 to 5"), std::string::npos);

  // A STEP file holding only a point.
  const fs::path point = dir_ / "point.step";
  {
    STEPControl_Writer writer;
    ASSERT_EQ(writer.Transfer(BRepBuilderAPI_MakeVertex(gp_Pnt(1, 2, 3)).Vertex(), STEPControl_AsIs), IFSelect_RetDone);
    ASSERT_EQ(writer.Write(point.string().c_str()), IFSelect_RetDone);
  }
  const auto no_faces = ReadCadFace(point, CadFaceSelector{.index = 0});
  ASSERT_FALSE(no_faces.ok());
  EXPECT_EQ(no_faces.status().code(), StatusCode::kBadInput);
  EXPECT_NE(no_faces.status().ToString().find("holds no face"), std::string::npos);
  EXPECT_NE(no_faces.status().ToString().find("point.step"), std::string::npos);

  // Not STEP at all, a missing file, and a wrong extension.
  const fs::path junk = dir_ / "junk.stp";
  std::ofstream(junk) << "this is not a STEP file\n";
  EXPECT_EQ(ReadCadFace(junk, {}).status().code(), StatusCode::kBadInput);
  EXPECT_EQ(ReadCadFace(dir_ / "absent.step", {}).status().code(), StatusCode::kNotFound);
  EXPECT_EQ(ReadCadFace(dir_ / "q.txt", {}).status().code(), StatusCode::kBadInput);
}

// A reader that does not answer within the time limit (a damaged file can make OpenCASCADE loop) is stopped
// and the file named with the limit and the fix. A limit of 1 us expires before any child can answer, so the
// time-out path runs deterministically; the child itself is killed and reaped (core/child_process_test.cc).
TEST_F(CadIoTest, AReaderPastItsTimeLimitIsStoppedAndTheFileNamed) {
  const fs::path box = dir_ / "box.step";
  WriteBoxStep(box, "MM");
  EXPECT_EQ(CadReadTimeoutSeconds(), 120.0);
  SetCadReadTimeoutSeconds(1e-6);
  const auto slow = ListCadFaces(box);
  SetCadReadTimeoutSeconds(kDefaultCadReadTimeout_s);
  ASSERT_FALSE(slow.ok());
  EXPECT_EQ(slow.status().code(), StatusCode::kBadInput);
  const std::string message = slow.status().ToString();
  EXPECT_NE(message.find("box.step"), std::string::npos) << message;
  EXPECT_NE(message.find("STEP reader took longer than 1e-06 s and was stopped"), std::string::npos) << message;
  EXPECT_NE(message.find("--cad-timeout-s"), std::string::npos) << message;
  // Within the default limit the same file reads, and 0 (no limit) reads too.
  EXPECT_EQ(ListCadFaces(box).value().size(), 6u);
  SetCadReadTimeoutSeconds(0);
  EXPECT_EQ(ListCadFaces(box).value().size(), 6u);
  SetCadReadTimeoutSeconds(kDefaultCadReadTimeout_s);
}

// fuzz_iges found a face whose edge is about 1.2e10 sampling steps long: the sample count was cast to int before
// it was clamped (undefined; in practice one sample). It is clamped first: the edge gets the cap of samples.
TEST_F(CadIoTest, AnEdgeTooLongForAnIntSampleCountIsSampledAtTheCap) {
  const fs::path path =
      fs::path(FORMLOOP_SOURCE_DIR) / "fuzz/corpus/fuzz_iges/crash-trim-edge-sample-count-overflow.igs";
  const auto face = ReadCadFace(path, CadFaceSelector{.index = 0});
  ASSERT_TRUE(face.ok()) << face.status().ToString();
  // The face is its whole patch (no trim kept on Q): its loops built again from the face as read.
  const auto trim = Trim::OfFace(face->face, face->surface, 0, 1, {});
  ASSERT_TRUE(trim.ok()) << trim.status().ToString();
  std::size_t most = 0;
  for (const TrimLoop& loop : (*trim)->loops()) most = std::max(most, loop.uv.size());
  EXPECT_GE(most, 200000u);
}

TEST_F(CadIoTest, IgesWithoutAUnitIsRefusedNamingTheField) {
  const fs::path with_unit = dir_ / "q.igs", without = dir_ / "q_no_unit.igs";
  ASSERT_TRUE(formloop::testing::WriteIgesWithAndWithoutUnit(with_unit, without));
  ASSERT_TRUE(ReadCadFace(with_unit, {}).ok());
  const auto refused = ReadCadFace(without, {});
  ASSERT_FALSE(refused.ok());
  EXPECT_EQ(refused.status().code(), StatusCode::kBadInput);
  const std::string message = refused.status().ToString();
  EXPECT_NE(message.find("q_no_unit.igs"), std::string::npos) << message;
  EXPECT_NE(message.find("global section parameters 14-15 (units)"), std::string::npos) << message;
  EXPECT_NE(message.find("inches"), std::string::npos) << message;
  EXPECT_FALSE(ListCadFaces(without).ok()) << "listing refuses it too";
}

}  // namespace
}  // namespace formloop::recon
