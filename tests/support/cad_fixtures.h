#pragma once
// Test support: CAD fixtures with known exact geometry, made through OpenCASCADE and written as STEP
// (nothing opaque is committed). Used by the reconstruction, nc-gen, metrology and app tests.
//
// - BezierTop: a bicubic Bézier patch over [-50, 50]² mm with x = u and y = v (equally spaced poles:
//   linear precision), heights from kHeights: z(u, v) = Σ z_ij B_i(s) B_j(t), s = (u + 50)/100. Its exact
//   height and derivatives are evaluated here from the Bernstein form, independently of OpenCASCADE.
// - The holed face: BezierTop trimmed to the ellipse (x/45)² + (y/35)² ≤ 1 minus the disc of radius 8
//   around (10, −5), both boundaries exact pcurves (Geom2d_Ellipse, Geom2d_Circle) in (u, v) = (x, y).
// - The pin: the lateral face of a cylinder of radius 4 standing in the hole (axis through (10, −5),
//   z from −10 to 40): neighbouring geometry the tool must stay clear of.
// - Three strips: z = StripHeight(x, y) (a smooth non-polynomial bump) over [-50, 50] × [-40, 40], split
//   at x = −15 and x = 20 into three B-spline faces, each approximated by GeomAPI_PointsToBSplineSurface
//   to 1e-6 mm over its own strip (so neighbouring faces meet at their seams to about that).

#include <array>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <string>
#include <vector>

#include <BRepBuilderAPI_MakeEdge.hxx>
#include <BRepBuilderAPI_MakeFace.hxx>
#include <BRepBuilderAPI_MakeWire.hxx>
#include <BRepLib.hxx>
#include <BRepPrimAPI_MakeCylinder.hxx>
#include <BRep_Builder.hxx>
#include <Geom2d_Circle.hxx>
#include <Geom2d_Ellipse.hxx>
#include <GeomAPI_PointsToBSplineSurface.hxx>
#include <GeomConvert.hxx>
#include <Geom_BSplineSurface.hxx>
#include <Geom_BezierSurface.hxx>
#include <IGESControl_Controller.hxx>
#include <IGESControl_Writer.hxx>
#include <Interface_Static.hxx>
#include <STEPControl_Writer.hxx>
#include <StepShape_AdvancedFace.hxx>
#include <TColgp_Array2OfPnt.hxx>
#include <TCollection_HAsciiString.hxx>
#include <TopExp_Explorer.hxx>
#include <TopoDS.hxx>
#include <TopoDS_Compound.hxx>
#include <TopoDS_Face.hxx>
#include <TransferBRep.hxx>
#include <TransferBRep_ShapeMapper.hxx>
#include <Transfer_FinderProcess.hxx>
#include <XSControl_TransferWriter.hxx>
#include <XSControl_WorkSession.hxx>
#include <gp_Ax22d.hxx>
#include <gp_Ax2d.hxx>
#include <gp_Pnt2d.hxx>

#include <Eigen/Core>

namespace formloop::testing {

struct BezierTop {
  static constexpr double kLo = -50, kHi = 50;
  static constexpr std::array<std::array<double, 4>, 4> kHeights = {
      {{0.0, 3.0, 2.0, 0.5}, {2.0, 9.0, 7.0, 1.0}, {1.0, 8.0, 10.0, 3.0}, {0.0, 2.0, 4.0, 1.5}}};
  static double Bernstein(int i, double t) {
    static constexpr double kBinomial[4] = {1, 3, 3, 1};
    return kBinomial[i] * std::pow(t, i) * std::pow(1 - t, 3 - i);
  }
  static double Height(double u, double v) {
    const double s = (u - kLo) / (kHi - kLo), t = (v - kLo) / (kHi - kLo);
    double z = 0;
    for (int i = 0; i < 4; ++i) {
      for (int j = 0; j < 4; ++j) z += kHeights[i][j] * Bernstein(i, s) * Bernstein(j, t);
    }
    return z;
  }
  static Eigen::Vector3d Point(double u, double v) { return {u, v, Height(u, v)}; }
  // mirror_u: x = −u (S_u × S_v then points to −z), for a face that must be reversed to face +z.
  static Handle(Geom_BSplineSurface) Geom(bool mirror_u = false) {
    TColgp_Array2OfPnt poles(1, 4, 1, 4);
    for (int i = 0; i < 4; ++i) {
      for (int j = 0; j < 4; ++j) {
        const int ix = mirror_u ? 3 - i : i;
        poles(i + 1, j + 1) = gp_Pnt(kLo + (kHi - kLo) * ix / 3.0, kLo + (kHi - kLo) * j / 3.0, kHeights[ix][j]);
      }
    }
    Handle(Geom_BezierSurface) bezier = new Geom_BezierSurface(poles);
    Handle(Geom_BSplineSurface) bspline = GeomConvert::SurfaceToBSplineSurface(bezier);
    // Bézier parameters run over [0, 1]; map them onto [-50, 50] so that u = x and v = y.
    TColStd_Array1OfReal uk(1, bspline->NbUKnots()), vk(1, bspline->NbVKnots());
    bspline->UKnots(uk);
    bspline->VKnots(vk);
    for (int k = uk.Lower(); k <= uk.Upper(); ++k) uk(k) = kLo + (kHi - kLo) * uk(k);
    for (int k = vk.Lower(); k <= vk.Upper(); ++k) vk(k) = kLo + (kHi - kLo) * vk(k);
    bspline->SetUKnots(uk);
    bspline->SetVKnots(vk);
    return bspline;
  }
};

// The holed face's exact domain in (x, y).
struct HoledDomain {
  static constexpr double kA = 45, kB = 35;                      // outer ellipse semi-axes
  static constexpr double kHoleX = 10, kHoleY = -5, kHoleR = 8;  // the hole
  static constexpr double kPinR = 4, kPinZ0 = -10, kPinZ1 = 40;  // the pin standing in it
  static double EllipseLevel(double x, double y) { return (x / kA) * (x / kA) + (y / kB) * (y / kB); }
  static double HoleDistance(double x, double y) { return std::hypot(x - kHoleX, y - kHoleY); }
  static bool Inside(double x, double y) { return EllipseLevel(x, y) < 1 && HoleDistance(x, y) > kHoleR; }
  // True within `band` mm (in x, y; first order for the ellipse) of either boundary.
  static bool NearBoundary(double x, double y, double band) {
    const double level = EllipseLevel(x, y);
    const double gradient = std::hypot(2 * x / (kA * kA), 2 * y / (kB * kB));
    return std::abs(level - 1) < band * gradient || std::abs(HoleDistance(x, y) - kHoleR) < band;
  }
  // Distance (in x, y) from a point to the pin's axis.
  static double PinAxisDistance(double x, double y) { return std::hypot(x - kHoleX, y - kHoleY); }
};

inline bool NearHoledBoundary(double x, double y, double band) { return HoledDomain::NearBoundary(x, y, band); }

// reversed: the surface is parametrised with x = −u (its S_u × S_v points to −z) and the face is
// REVERSED, so the side away from the material is still +z (what a CAD system writes for such a face).
inline TopoDS_Face MakeHoledFace(bool reversed = false) {
  const Handle(Geom_BSplineSurface) surface = BezierTop::Geom(reversed);
  const Handle(Geom2d_Ellipse) outer =
      new Geom2d_Ellipse(gp_Ax22d(gp_Pnt2d(0, 0), gp_Dir2d(1, 0), gp_Dir2d(0, 1)), HoledDomain::kA, HoledDomain::kB);
  const double hole_u = reversed ? -HoledDomain::kHoleX : HoledDomain::kHoleX;
  const Handle(Geom2d_Circle) hole =
      new Geom2d_Circle(gp_Ax2d(gp_Pnt2d(hole_u, HoledDomain::kHoleY), gp_Dir2d(1, 0)), HoledDomain::kHoleR);
  const TopoDS_Edge outer_edge = BRepBuilderAPI_MakeEdge(outer, surface).Edge();
  TopoDS_Edge hole_edge = BRepBuilderAPI_MakeEdge(hole, surface).Edge();
  hole_edge.Reverse();  // clockwise: the material on its left
  BRepBuilderAPI_MakeFace make(surface, BRepBuilderAPI_MakeWire(outer_edge).Wire(), Standard_True);
  make.Add(BRepBuilderAPI_MakeWire(hole_edge).Wire());
  TopoDS_Face face = make.Face();
  BRepLib::BuildCurves3d(face);
  if (reversed) face.Reverse();
  return face;
}

inline TopoDS_Face MakePin() {
  const gp_Ax2 axis(gp_Pnt(HoledDomain::kHoleX, HoledDomain::kHoleY, HoledDomain::kPinZ0), gp_Dir(0, 0, 1));
  const TopoDS_Shape cylinder =
      BRepPrimAPI_MakeCylinder(axis, HoledDomain::kPinR, HoledDomain::kPinZ1 - HoledDomain::kPinZ0).Shape();
  for (TopExp_Explorer it(cylinder, TopAbs_FACE); it.More(); it.Next()) {
    const TopoDS_Face face = TopoDS::Face(it.Current());
    if (BRep_Tool::Surface(face)->DynamicType()->Name() == std::string("Geom_CylindricalSurface")) return face;
  }
  return {};
}

// Smooth bump of the three-strip region (mm).
inline double StripHeight(double x, double y) {
  return 8.0 * std::exp(-((x - 5) * (x - 5) + (y + 8) * (y + 8)) / (2 * 28.0 * 28.0)) + 0.03 * x - 0.02 * y;
}
inline constexpr std::array<double, 4> kStripEdges = {-50, -15, 20, 50};
inline constexpr double kStripY0 = -40, kStripY1 = 40;

inline std::vector<TopoDS_Face> MakeThreeStrips() {
  std::vector<TopoDS_Face> faces;
  for (int k = 0; k < 3; ++k) {
    const double x0 = kStripEdges[k], x1 = kStripEdges[k + 1];
    const int nu = 29, nv = 61;
    TColgp_Array2OfPnt points(1, nu, 1, nv);
    for (int i = 1; i <= nu; ++i) {
      for (int j = 1; j <= nv; ++j) {
        const double x = x0 + (x1 - x0) * (i - 1) / (nu - 1), y = kStripY0 + (kStripY1 - kStripY0) * (j - 1) / (nv - 1);
        points(i, j) = gp_Pnt(x, y, StripHeight(x, y));
      }
    }
    GeomAPI_PointsToBSplineSurface fit;
    fit.Init(points, 3, 5, GeomAbs_C2, 1e-6);
    faces.push_back(BRepBuilderAPI_MakeFace(fit.Surface(), 1e-7).Face());
  }
  return faces;
}

// Writes the faces as one STEP compound, naming each ADVANCED_FACE (names may be empty).
inline bool WriteStepFaces(const std::filesystem::path& path, const std::vector<TopoDS_Face>& faces,
                           const std::vector<std::string>& names = {}) {
  TopoDS_Compound compound;
  BRep_Builder builder;
  builder.MakeCompound(compound);
  for (const TopoDS_Face& face : faces) builder.Add(compound, face);
  STEPControl_Writer writer;
  Interface_Static::SetCVal("write.step.unit", "MM");
  if (writer.Transfer(compound, STEPControl_AsIs) != IFSelect_RetDone) return false;
  const Handle(Transfer_FinderProcess) finder = writer.WS()->TransferWriter()->FinderProcess();
  for (std::size_t k = 0; k < faces.size() && k < names.size(); ++k) {
    const Handle(TransferBRep_ShapeMapper) mapper = TransferBRep::ShapeMapper(finder, faces[k]);
    Handle(Standard_Transient) entity;
    if (!finder->FindTypedTransient(mapper, STANDARD_TYPE(StepShape_AdvancedFace), entity)) return false;
    Handle(StepShape_AdvancedFace)::DownCast(entity)->SetName(new TCollection_HAsciiString(names[k].c_str()));
  }
  return writer.Write(path.string().c_str()) == IFSelect_RetDone;
}

// The holed face as IGES in mm (`with_unit`) and the same file with the global section's unit flag and
// unit name blanked (`without_unit`): a unit-less IGES file. False when the writer's global section is not
// the expected one.
inline bool WriteIgesWithAndWithoutUnit(const std::filesystem::path& with_unit,
                                        const std::filesystem::path& without_unit) {
  IGESControl_Controller::Init();
  IGESControl_Writer writer("MM", 0);
  if (!writer.AddShape(MakeHoledFace())) return false;
  writer.ComputeModel();
  if (!writer.Write(with_unit.string().c_str())) return false;
  std::stringstream text;
  text << std::ifstream(with_unit).rdbuf();
  std::string iges = text.str();
  const std::size_t at = iges.find(",2,2HMM,");  // parameters 14 (unit flag 2 = mm) and 15 (unit name)
  if (at == std::string::npos) return false;
  iges.replace(at, 8, ",,,     ");  // same columns
  std::ofstream(without_unit) << iges;
  return true;
}

// A point file with too few points for any fit (9).
inline void WriteNinePoints(const std::filesystem::path& path) {
  std::ofstream few(path);
  few << "x,y,z\n";
  for (int k = 0; k < 9; ++k) few << k << "," << (k * 7) % 5 << "," << 0.1 * k << "\n";
}

}  // namespace formloop::testing
