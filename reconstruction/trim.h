#pragma once
// The trimmed domain of the ideal surface Q and the geometry beside it (spec/reconstruction.md §1).
//
// A CAD face is a surface bounded by trimming loops: one outer loop and any number of inner ones
// (holes), each a closed chain of edges with a curve in the surface's parameter plane (pcurve).
// Q is the face's underlying B-spline (reconstruction/cad_io.h); a Trim says which parameter points
// of Q belong to the part and what lies around it. It is attached to Q (BSplineSurface::trim()), so
// every stage that samples Q honours it: sampling and features (retrieval/features.h), the tool path
// (nc-gen/toolpath.h: passes end at the trim, a contour pass along every loop, leads clear of the
// neighbours), the probing plans (metrology: points inside with a margin from the edge), foot points
// (reconstruction/foot_point.h: flagged outside_trim) and the report's maps.
//
// Classification is OpenCASCADE's: BRepTopAdaptor_FClass2d on the face (the 2-D classifier of the
// face's pcurves that BRepClass_FaceClassifier also rests on), with a 3-D tolerance of
// kTrimTolerance converted by the classifier into parameter tolerances. Points within it of a loop
// are kOnEdge and count as inside.
//
// Parameters. The face's pcurves live in the parameters of the face's own surface S_f. Q equals S_f
// except that Q's u may run backwards (a face whose orientation is reversed: cad_io.h reverses u so
// that Q's normal points away from the material); u_f = u_offset + u_sign·u_Q, v_f = v_Q.
//
// Distances to the edge (EdgeDistanceMm) are 3-D distances to polylines through the loops sampled at
// kTrimLoopSpacingMm on the face's pcurves (points of Q); the chord of a loop of radius of curvature
// ρ between samples lies within s²/(8ρ) of the loop: 0.03 µm at ρ = 10 mm.
//
// Neighbouring geometry: the other faces of the CAD model (not part of the region machined). The
// tool-path planner keeps the ball clear of them (NeighbourDistanceMm: exact distance by
// BRepExtrema_DistShapeShape, skipped through each face's bounding box beyond the distance asked).
//
// A "natural" trim is a face bounded by its parameter box alone: nothing is excluded, there is no
// loop to follow, and the planner and the plans behave exactly as on an untrimmed Q (only the
// neighbours, if any, are checked).

#include <memory>
#include <optional>
#include <string>
#include <vector>

#include <Eigen/Core>
#include <TopoDS_Face.hxx>
#include <nlohmann/json.hpp>

#include "core/status.h"
#include "reconstruction/analytic_surface.h"

namespace formloop::recon {

class BSplineSurface;

inline constexpr double kTrimTolerance = 1e-6;      // mm: classification tolerance (3-D)
inline constexpr double kTrimLoopSpacingMm = 0.05;  // mm: sample spacing along the loops

enum class TrimPosition { kInside, kOnEdge, kOutside };

// One closed boundary loop in Q's parameters, sampled along the face's pcurves in the order of the
// face's wire (outer loop counter-clockwise in the face's parameters, holes clockwise: the material
// on the left). The first sample is not repeated at the end.
struct TrimLoop {
  bool outer = false;
  std::vector<Eigen::Vector2d> uv;     // (u, v) of Q
  std::vector<Eigen::Vector3d> point;  // Q(u, v), mm
  double length_mm = 0;                // of the polyline through `point`, closed
};

class Trim {
 public:
  // The face whose pcurves bound Q, with u_f = u_offset + u_sign·u_Q (u_sign = ±1). Neighbours are the
  // faces beside it (may be empty). BadInput when the face has no pcurve on its surface or the
  // classifier cannot be built.
  static Result<std::shared_ptr<const Trim>> OfFace(const TopoDS_Face& face, const BSplineSurface& q, double u_offset,
                                                    double u_sign, std::vector<TopoDS_Face> neighbours = {});
  // A face on Q itself bounded by closed loops given as (u, v) points of Q (a region of several CAD
  // faces projected onto one fitted Q, cad_region.h): each loop is interpolated by a periodic 2-D
  // B-spline (Geom2dAPI_Interpolate) through its points, the face built on Q's geometry and its
  // wire orientation fixed (ShapeFix_Face), so the loop enclosing the others is the outer one.
  static Result<std::shared_ptr<const Trim>> OfLoops(const BSplineSurface& q,
                                                     const std::vector<std::vector<Eigen::Vector2d>>& loops,
                                                     std::vector<TopoDS_Face> neighbours = {});

  TrimPosition Classify(double u, double v) const;
  bool Inside(double u, double v) const { return Classify(u, v) != TrimPosition::kOutside; }
  // 3-D distance from p to the nearest loop (see the header comment), mm.
  double EdgeDistanceMm(const Eigen::Vector3d& p) const;
  // True when the face is bounded by Q's parameter box alone (see the header comment).
  bool natural() const { return natural_; }
  const std::vector<TrimLoop>& loops() const { return loops_; }
  // The face in its own surface's parameters (for STEP export: written as it was read).
  const TopoDS_Face& face() const { return face_; }
  double u_offset() const { return u_offset_; }
  double u_sign() const { return u_sign_; }
  // Area of the trimmed face (BRepGProp surface properties), mm².
  double area_mm2() const { return area_mm2_; }

  bool has_neighbours() const { return !neighbours_.empty(); }
  int neighbour_count() const { return static_cast<int>(neighbours_.size()); }
  const std::vector<TopoDS_Face>& neighbours() const { return neighbours_; }
  // Distance from p to the nearest neighbouring face, or `reach` when none is nearer than `reach`.
  double NeighbourDistanceMm(const Eigen::Vector3d& p, double reach) const;

  nlohmann::json ToJson() const;  // natural, loops (outer/holes, lengths), area, neighbours

  struct Impl;  // the classifier and the neighbours' bounding boxes (OpenCASCADE types)

 private:
  Trim() = default;
  Status Build(const BSplineSurface& q);

  TopoDS_Face face_;
  double u_offset_ = 0, u_sign_ = 1;
  bool natural_ = false;
  double area_mm2_ = 0;
  std::vector<TrimLoop> loops_;
  std::vector<TopoDS_Face> neighbours_;
  std::shared_ptr<const Impl> impl_;
};

// The parameters of the point of Q above (x, y) — S(u, v)·x̂ = x, S(u, v)·ŷ = y — by Newton from `start`
// (Q a graph over the XY plane there, as every 3-axis surface is); nullopt when it does not converge
// inside Q's domain to 1e-9 mm (no point of Q lies above (x, y), or the start is too far off).
std::optional<Eigen::Vector2d> ParametersAboveXY(const BSplineSurface& q, double x, double y, Eigen::Vector2d start);

// Parameter points of a regular nu × nv grid over Q's domain (corners included), row-major
// (index = j·nu + i), with whether each lies inside Q's trim (always true without one).
struct TrimmedGrid {
  int nu = 0, nv = 0;
  std::vector<Eigen::Vector2d> uv;
  std::vector<char> inside;
  int inside_count() const;
};
TrimmedGrid SampleTrimmedGrid(const BSplineSurface& q, int nu, int nv);

}  // namespace formloop::recon
