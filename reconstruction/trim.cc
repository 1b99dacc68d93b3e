#include "reconstruction/trim.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <list>
#include <mutex>

#include <Eigen/LU>

// CGAL's AABB tree (header-only, in doubles: no exact kernel, so no -frounding-math) bounds the distance
// to a neighbouring face from its triangulation before the exact distance is asked of OpenCASCADE.
#include <CGAL/AABB_traits.h>
#include <CGAL/AABB_tree.h>
#include <CGAL/AABB_triangle_primitive.h>
#include <CGAL/Simple_cartesian.h>

#include <BRepAdaptor_Curve.hxx>
#include <BRepBndLib.hxx>
#include <BRepBuilderAPI_Copy.hxx>
#include <BRepBuilderAPI_MakeEdge.hxx>
#include <BRepBuilderAPI_MakeFace.hxx>
#include <BRepBuilderAPI_MakeVertex.hxx>
#include <BRepBuilderAPI_MakeWire.hxx>
#include <BRepExtrema_DistShapeShape.hxx>
#include <BRepGProp.hxx>
#include <BRepLib.hxx>
#include <BRepMesh_IncrementalMesh.hxx>
#include <BRepTools.hxx>
#include <BRepTools_WireExplorer.hxx>
#include <BRepTopAdaptor_FClass2d.hxx>
#include <BRep_Tool.hxx>
#include <Bnd_Box.hxx>
#include <GCPnts_AbscissaPoint.hxx>
#include <GProp_GProps.hxx>
#include <Geom2dAPI_Interpolate.hxx>
#include <Geom2d_BSplineCurve.hxx>
#include <Geom2d_Curve.hxx>
#include <Poly_Triangulation.hxx>
#include <ShapeFix_Face.hxx>
#include <Standard_Failure.hxx>
#include <TColgp_HArray1OfPnt2d.hxx>
#include <TopExp_Explorer.hxx>
#include <TopLoc_Location.hxx>
#include <TopoDS.hxx>
#include <TopoDS_Edge.hxx>
#include <TopoDS_Wire.hxx>
#include <gp_Pnt2d.hxx>

#include "core/geometry.h"
#include "reconstruction/bspline_surface.h"
#include "reconstruction/occt_support.h"

namespace formloop::recon {

namespace {

using MeshKernel = CGAL::Simple_cartesian<double>;
using MeshTriangles = std::list<MeshKernel::Triangle_3>;
using MeshTree =
    CGAL::AABB_tree<CGAL::AABB_traits<MeshKernel, CGAL::AABB_triangle_primitive<MeshKernel, MeshTriangles::iterator>>>;

// A neighbouring face's triangulation in an AABB tree, and how far the face may lie from it (`slack`,
// mm): the distance to the mesh less the slack is a lower bound of the distance to the face. Without a
// usable triangulation `tree` is null and every query is exact.
struct NeighbourMesh {
  MeshTriangles triangles;
  std::unique_ptr<MeshTree> tree;
  double slack = 0;
};

}  // namespace

struct Trim::Impl {
  std::unique_ptr<BRepTopAdaptor_FClass2d> classifier;
  std::vector<Bnd_Box> neighbour_boxes;
  // Loop polylines as segments (start, end) for the edge distance.
  std::vector<std::pair<Eigen::Vector3d, Eigen::Vector3d>> segments;
  // The neighbours' triangulations, built on the first distance query (a face only read or fitted never
  // meshes them); one per neighbour.
  mutable std::once_flag meshed;
  mutable std::vector<NeighbourMesh> meshes;
};

namespace {

constexpr int kMaxSamplesPerEdge = 200000;

}  // namespace

Result<std::shared_ptr<const Trim>> Trim::OfFace(const TopoDS_Face& face, const BSplineSurface& q, double u_offset,
                                                 double u_sign, std::vector<TopoDS_Face> neighbours) {
  if (!q.valid()) return Status::Internal("Trim::OfFace: no surface");
  if (u_sign != 1.0 && u_sign != -1.0) return Status::Internal("Trim::OfFace: u_sign must be +1 or -1");
  std::shared_ptr<Trim> trim(new Trim());
  trim->face_ = face;
  trim->u_offset_ = u_offset;
  trim->u_sign_ = u_sign;
  trim->neighbours_ = std::move(neighbours);
  FL_RETURN_IF_ERROR(trim->Build(q));
  return std::shared_ptr<const Trim>(std::move(trim));
}

Result<std::shared_ptr<const Trim>> Trim::OfLoops(const BSplineSurface& q,
                                                  const std::vector<std::vector<Eigen::Vector2d>>& loops,
                                                  std::vector<TopoDS_Face> neighbours) {
  if (!q.valid()) return Status::Internal("Trim::OfLoops: no surface");
  if (loops.empty()) return Status::BadInput("Trim::OfLoops: no boundary loop given");
  occt::KeepStdoutClean();
  try {
    std::vector<TopoDS_Wire> wires;
    for (std::size_t k = 0; k < loops.size(); ++k) {
      const auto& loop = loops[k];
      if (loop.size() < 3) {
        return Status::BadInput("boundary loop " + std::to_string(k) + " has " + std::to_string(loop.size()) +
                                " points; a closed loop needs at least 3");
      }
      Handle(TColgp_HArray1OfPnt2d) points = new TColgp_HArray1OfPnt2d(1, static_cast<int>(loop.size()));
      for (std::size_t i = 0; i < loop.size(); ++i) {
        points->SetValue(static_cast<int>(i) + 1, gp_Pnt2d(loop[i].x(), loop[i].y()));
      }
      Geom2dAPI_Interpolate interpolate(points, /*periodic=*/Standard_True, 1e-12);
      interpolate.Perform();
      if (!interpolate.IsDone()) {
        return Status::Failed("boundary loop " + std::to_string(k) +
                              ": no periodic curve through its points (two consecutive points coincide?)");
      }
      BRepBuilderAPI_MakeEdge edge(interpolate.Curve(), q.geom());
      if (!edge.IsDone()) return Status::Failed("boundary loop " + std::to_string(k) + ": edge on Q not built");
      TopoDS_Edge e = edge.Edge();
      BRepLib::BuildCurves3d(e);
      BRepBuilderAPI_MakeWire wire(e);
      if (!wire.IsDone()) return Status::Failed("boundary loop " + std::to_string(k) + ": wire not built");
      wires.push_back(wire.Wire());
    }
    BRepBuilderAPI_MakeFace make(q.geom(), wires.front(), Standard_True);
    for (std::size_t k = 1; k < wires.size(); ++k) make.Add(wires[k]);
    if (!make.IsDone()) return Status::Failed("the trimmed face on Q could not be built from its loops");
    ShapeFix_Face fix(make.Face());
    fix.FixOrientation();
    fix.Perform();
    return OfFace(fix.Face(), q, 0.0, 1.0, std::move(neighbours));
  } catch (const Standard_Failure& failure) {
    return Status::Failed("building the trimmed face on Q: " + occt::Message(failure));
  }
}

Status Trim::Build(const BSplineSurface& q) {
  occt::KeepStdoutClean();
  auto impl = std::make_shared<Impl>();
  const ParamDomain dom = q.domain();
  try {
    impl->classifier = std::make_unique<BRepTopAdaptor_FClass2d>(face_, kTrimTolerance);
    const TopoDS_Wire outer = BRepTools::OuterWire(face_);
    int wire_count = 0;
    bool on_box = true;
    const double tol_u = 1e-7 * std::max(dom.u_span(), 1.0), tol_v = 1e-7 * std::max(dom.v_span(), 1.0);
    for (TopExp_Explorer w(face_, TopAbs_WIRE); w.More(); w.Next()) {
      ++wire_count;
      const TopoDS_Wire wire = TopoDS::Wire(w.Current());
      TrimLoop loop;
      loop.outer = wire.IsSame(outer);
      for (BRepTools_WireExplorer e(wire, face_); e.More(); e.Next()) {
        const TopoDS_Edge& edge = e.Current();
        double first = 0, last = 0;
        const Handle(Geom2d_Curve) pcurve = BRep_Tool::CurveOnSurface(edge, face_, first, last);
        if (pcurve.IsNull()) {
          return Status::BadInput(Where{}, "an edge of the face has no curve in the surface's parameters (pcurve)",
                                  "repair the model in the CAD system (or with a STEP healer) and export again");
        }
        double length = 0;
        if (!BRep_Tool::Degenerated(edge)) {
          const BRepAdaptor_Curve curve(edge);
          length = GCPnts_AbscissaPoint::Length(curve);
        }
        // Clamped as a double: a damaged file's edge can be longer than an int counts samples (or NaN).
        const double wanted = std::ceil(length / kTrimLoopSpacingMm);
        const int n = wanted >= kMaxSamplesPerEdge ? kMaxSamplesPerEdge : wanted >= 1 ? static_cast<int>(wanted) : 1;
        const bool reversed = edge.Orientation() == TopAbs_REVERSED;
        for (int k = 0; k < n; ++k) {  // the edge's end is the next edge's start
          const double s = static_cast<double>(k) / n;
          const double t = reversed ? last - s * (last - first) : first + s * (last - first);
          const gp_Pnt2d p = pcurve->Value(t);
          const double u = (p.X() - u_offset_) / u_sign_, v = p.Y();
          loop.uv.emplace_back(u, v);
          loop.point.push_back(q.Point(std::clamp(u, dom.u_min, dom.u_max), std::clamp(v, dom.v_min, dom.v_max)));
          on_box = on_box && (std::abs(u - dom.u_min) < tol_u || std::abs(u - dom.u_max) < tol_u ||
                              std::abs(v - dom.v_min) < tol_v || std::abs(v - dom.v_max) < tol_v);
        }
      }
      if (loop.uv.empty()) continue;
      for (std::size_t i = 0; i < loop.point.size(); ++i) {
        const Eigen::Vector3d& a = loop.point[i];
        const Eigen::Vector3d& b = loop.point[(i + 1) % loop.point.size()];
        loop.length_mm += (b - a).norm();
        impl->segments.emplace_back(a, b);
      }
      loops_.push_back(std::move(loop));
    }
    if (loops_.empty()) {
      return Status::BadInput(Where{}, "the face has no boundary loop", "export the face with its trimming curves");
    }
    // The outer loop first.
    std::stable_sort(loops_.begin(), loops_.end(),
                     [](const TrimLoop& a, const TrimLoop& b) { return a.outer > b.outer; });
    natural_ = wire_count == 1 && on_box;
    GProp_GProps props;
    BRepGProp::SurfaceProperties(face_, props);
    area_mm2_ = props.Mass();
    for (const TopoDS_Face& neighbour : neighbours_) {
      Bnd_Box box;
      BRepBndLib::Add(neighbour, box);
      impl->neighbour_boxes.push_back(box);
    }
  } catch (const Standard_Failure& failure) {
    return Status::BadInput("OpenCASCADE failed on the face's trimming loops: " + occt::Message(failure));
  }
  impl_ = std::move(impl);
  return Status::Ok();
}

TrimPosition Trim::Classify(double u, double v) const {
  if (natural_) return TrimPosition::kInside;
  const TopAbs_State state = impl_->classifier->Perform(gp_Pnt2d(u_offset_ + u_sign_ * u, v), Standard_False);
  if (state == TopAbs_IN) return TrimPosition::kInside;
  if (state == TopAbs_ON) return TrimPosition::kOnEdge;
  return TrimPosition::kOutside;
}

double Trim::EdgeDistanceMm(const Eigen::Vector3d& p) const {
  double best = std::numeric_limits<double>::infinity();
  for (const auto& [a, b] : impl_->segments) best = std::min(best, SegmentDistance(p, a, b));
  return best;
}

namespace {

// Triangulates `face` (a copy: the caller's shape keeps its own triangulation) with a linear deflection
// of a thousandth of its box's diagonal (1 µm to 1 mm) and indexes the triangles. The slack is twice the
// deflection plus 1 µm: BRepMesh aims at the deflection, it does not prove it, hence the factor.
NeighbourMesh MeshOf(const TopoDS_Face& face, const Bnd_Box& box) {
  NeighbourMesh mesh;
  try {
    const double diagonal = box.IsVoid() ? 0.0 : std::sqrt(box.SquareExtent());
    const double deflection = std::clamp(1e-3 * diagonal, 1e-3, 1.0);
    const TopoDS_Face copy = TopoDS::Face(BRepBuilderAPI_Copy(face, Standard_True, Standard_False).Shape());
    BRepMesh_IncrementalMesh mesher(copy, deflection, Standard_False, 0.5, Standard_False);
    TopLoc_Location location;
    const Handle(Poly_Triangulation) triangulation = BRep_Tool::Triangulation(copy, location);
    if (!mesher.IsDone() || triangulation.IsNull() || triangulation->NbTriangles() == 0) return mesh;
    const gp_Trsf to_world = location.Transformation();
    const auto node = [&](int i) {
      const gp_Pnt n = triangulation->Node(i).Transformed(to_world);
      return MeshKernel::Point_3(n.X(), n.Y(), n.Z());
    };
    for (int t = 1; t <= triangulation->NbTriangles(); ++t) {
      int a = 0, b = 0, c = 0;
      triangulation->Triangle(t).Get(a, b, c);
      const MeshKernel::Triangle_3 triangle(node(a), node(b), node(c));
      if (!triangle.is_degenerate()) mesh.triangles.push_back(triangle);
    }
    if (mesh.triangles.empty()) return mesh;
    mesh.tree = std::make_unique<MeshTree>(mesh.triangles.begin(), mesh.triangles.end());
    mesh.tree->accelerate_distance_queries();
    mesh.slack = 2 * deflection + 1e-3;
  } catch (const Standard_Failure&) {
    mesh.tree.reset();  // exact queries only
  }
  return mesh;
}

}  // namespace

double Trim::NeighbourDistanceMm(const Eigen::Vector3d& p, double reach) const {
  double best = reach;
  if (neighbours_.empty()) return best;
  std::call_once(impl_->meshed, [&] {
    for (std::size_t k = 0; k < neighbours_.size(); ++k)
      impl_->meshes.push_back(MeshOf(neighbours_[k], impl_->neighbour_boxes[k]));
  });
  const gp_Pnt point(p.x(), p.y(), p.z());
  TopoDS_Vertex vertex;
  for (std::size_t k = 0; k < neighbours_.size(); ++k) {
    Bnd_Box box = impl_->neighbour_boxes[k];
    box.Enlarge(best);
    if (box.IsOut(point)) continue;
    // Farther from the triangulation than the slack beyond `best`: the face is too (no exact query).
    const NeighbourMesh& mesh = impl_->meshes[k];
    if (mesh.tree != nullptr &&
        std::sqrt(mesh.tree->squared_distance(MeshKernel::Point_3(p.x(), p.y(), p.z()))) - mesh.slack >= best) {
      continue;
    }
    if (vertex.IsNull()) vertex = BRepBuilderAPI_MakeVertex(point).Vertex();
    try {
      BRepExtrema_DistShapeShape distance(vertex, neighbours_[k]);
      if (distance.IsDone() && distance.NbSolution() > 0) best = std::min(best, distance.Value());
    } catch (const Standard_Failure&) {
      best = 0;  // cannot tell: treat the point as blocked rather than risk a collision
    }
  }
  return best;
}

nlohmann::json Trim::ToJson() const {
  int holes = 0;
  double outer_length = 0;
  nlohmann::json hole_lengths = nlohmann::json::array();
  for (const TrimLoop& loop : loops_) {
    if (loop.outer) {
      outer_length = loop.length_mm;
    } else {
      ++holes;
      hole_lengths.push_back(loop.length_mm);
    }
  }
  return {{"natural", natural_},
          {"classification", "OpenCASCADE BRepTopAdaptor_FClass2d on the face's pcurves"},
          {"tolerance_mm", kTrimTolerance},
          {"loops", loops_.size()},
          {"holes", holes},
          {"outer_length_mm", outer_length},
          {"hole_lengths_mm", hole_lengths},
          {"area_mm2", area_mm2_},
          {"neighbouring_faces", neighbours_.size()}};
}

std::optional<Eigen::Vector2d> ParametersAboveXY(const BSplineSurface& q, double x, double y, Eigen::Vector2d start) {
  const ParamDomain dom = q.domain();
  double u = std::clamp(start.x(), dom.u_min, dom.u_max), v = std::clamp(start.y(), dom.v_min, dom.v_max);
  for (int it = 0; it < 30; ++it) {
    const SurfaceDerivatives d = q.Derivatives(u, v);
    const Eigen::Vector2d r(d.p.x() - x, d.p.y() - y);
    if (r.lpNorm<Eigen::Infinity>() < 1e-9) return Eigen::Vector2d(u, v);
    Eigen::Matrix2d j;
    j << d.su.x(), d.sv.x(), d.su.y(), d.sv.y();
    const double det = j.determinant();
    if (!(std::abs(det) > 1e-14)) return std::nullopt;
    const Eigen::Vector2d step = j.inverse() * r;
    const double nu = std::clamp(u - step.x(), dom.u_min, dom.u_max),
                 nv = std::clamp(v - step.y(), dom.v_min, dom.v_max);
    if (nu == u && nv == v) return std::nullopt;  // held at the domain's edge: (x, y) is beyond Q
    u = nu;
    v = nv;
  }
  const Eigen::Vector3d p = q.Point(u, v);
  if (std::abs(p.x() - x) < 1e-9 && std::abs(p.y() - y) < 1e-9) return Eigen::Vector2d(u, v);
  return std::nullopt;
}

int TrimmedGrid::inside_count() const { return static_cast<int>(std::count(inside.begin(), inside.end(), 1)); }

TrimmedGrid SampleTrimmedGrid(const BSplineSurface& q, int nu, int nv) {
  TrimmedGrid g;
  g.nu = std::max(nu, 2);
  g.nv = std::max(nv, 2);
  const ParamDomain dom = q.domain();
  const Trim* trim = q.trim();
  for (int j = 0; j < g.nv; ++j) {
    for (int i = 0; i < g.nu; ++i) {
      const double u = i == g.nu - 1 ? dom.u_max : dom.u_min + dom.u_span() * i / (g.nu - 1);
      const double v = j == g.nv - 1 ? dom.v_max : dom.v_min + dom.v_span() * j / (g.nv - 1);
      g.uv.emplace_back(u, v);
      g.inside.push_back(trim == nullptr || trim->Inside(u, v) ? 1 : 0);
    }
  }
  return g;
}

}  // namespace formloop::recon
