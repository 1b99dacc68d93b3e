#include "reconstruction/cad_region.h"

#include <algorithm>
#include <cmath>
#include <string>

#include <BRepAdaptor_Curve.hxx>
#include <BRepBuilderAPI_Sewing.hxx>
#include <BRepTools_WireExplorer.hxx>
#include <BRep_Tool.hxx>
#include <GCPnts_AbscissaPoint.hxx>
#include <ShapeAnalysis_FreeBounds.hxx>
#include <Standard_Failure.hxx>
#include <TopExp_Explorer.hxx>
#include <TopoDS.hxx>
#include <TopoDS_Compound.hxx>
#include <TopoDS_Edge.hxx>
#include <TopoDS_Wire.hxx>
#include <gp_Pnt.hxx>

#include "core/number_text.h"
#include "core/random.h"
#include "reconstruction/foot_point.h"
#include "reconstruction/occt_support.h"
#include "reconstruction/trim.h"

namespace formloop::recon {
namespace {

constexpr std::size_t kMaxRegionSamples = 400000;

// 3-D length of Q's iso-line through the middle of its domain along u (or v), 32 chords.
double MiddleIsoLength(const BSplineSurface& q, bool along_u) {
  const ParamDomain d = q.domain();
  double length = 0;
  Eigen::Vector3d previous;
  for (int k = 0; k <= 32; ++k) {
    const double t = static_cast<double>(k) / 32;
    const Eigen::Vector3d p = along_u ? q.Point(d.u_min + t * d.u_span(), 0.5 * (d.v_min + d.v_max))
                                      : q.Point(0.5 * (d.u_min + d.u_max), d.v_min + t * d.v_span());
    if (k > 0) length += (p - previous).norm();
    previous = p;
  }
  return length;
}

bool InsideFace(const CadFace& face, double u, double v) {
  const Trim* trim = face.surface.trim();
  return trim == nullptr || trim->Inside(u, v);
}

// Points along a wire every `spacing` (3-D), in the wire's order, the closing point not repeated.
std::vector<Eigen::Vector3d> SampleWire(const TopoDS_Wire& wire, double spacing) {
  std::vector<Eigen::Vector3d> out;
  for (BRepTools_WireExplorer e(wire); e.More(); e.Next()) {
    const TopoDS_Edge& edge = e.Current();
    if (BRep_Tool::Degenerated(edge)) continue;
    const BRepAdaptor_Curve curve(edge);
    const double length = GCPnts_AbscissaPoint::Length(curve);
    const int n = std::max(2, static_cast<int>(std::ceil(length / spacing)));
    const bool reversed = edge.Orientation() == TopAbs_REVERSED;
    const double first = curve.FirstParameter(), last = curve.LastParameter();
    for (int k = 0; k < n; ++k) {  // the edge's end is the next edge's start
      const double s = static_cast<double>(k) / n;
      const gp_Pnt p = curve.Value(reversed ? last - s * (last - first) : first + s * (last - first));
      out.emplace_back(p.X(), p.Y(), p.Z());
    }
  }
  return out;
}

}  // namespace

Status RegionFitOptions::Validate() const {
  const auto positive = [](double x) { return std::isfinite(x) && x > 0; };
  if (!positive(sample_spacing_mm)) return Status::BadInput(Where{.field = "sample_spacing_mm"}, "must be > 0");
  if (!positive(boundary_spacing_mm)) return Status::BadInput(Where{.field = "boundary_spacing_mm"}, "must be > 0");
  if (!positive(sewing_tolerance_mm)) return Status::BadInput(Where{.field = "sewing_tolerance_mm"}, "must be > 0");
  if (check_points_per_face < 1) return Status::BadInput(Where{.field = "check_points_per_face"}, "must be >= 1");
  if (!(max_cad_deviation_mm >= 0)) return Status::BadInput(Where{.field = "max_cad_deviation_mm"}, "must be >= 0");
  return fit.Validate();
}

Result<RegionFit> FitCadRegion(const std::vector<CadFace>& faces, const RegionFitOptions& options) {
  FL_RETURN_IF_ERROR(options.Validate().WithContext("region fit options"));
  if (faces.size() < 2) return Status::BadInput(Where{.field = "faces"}, "a region needs at least two faces");
  occt::KeepStdoutClean();
  RegionFit out;
  out.faces = static_cast<int>(faces.size());

  // 1. Samples: cell midpoints inside each face's trim.
  std::vector<Eigen::Vector3d> points;
  for (const CadFace& face : faces) {
    const ParamDomain d = face.surface.domain();
    const int nu = std::clamp(
        static_cast<int>(std::ceil(MiddleIsoLength(face.surface, true) / options.sample_spacing_mm)), 2, 4000);
    const int nv = std::clamp(
        static_cast<int>(std::ceil(MiddleIsoLength(face.surface, false) / options.sample_spacing_mm)), 2, 4000);
    for (int j = 0; j < nv; ++j) {
      for (int i = 0; i < nu; ++i) {
        const double u = d.u_min + d.u_span() * (i + 0.5) / nu, v = d.v_min + d.v_span() * (j + 0.5) / nv;
        if (InsideFace(face, u, v)) points.push_back(face.surface.Point(u, v));
      }
    }
    if (points.size() > kMaxRegionSamples) {
      return Status::BadInput(Where{.field = "sample_spacing_mm"},
                              "more than " + std::to_string(kMaxRegionSamples) + " samples at " +
                                  FormatExact(options.sample_spacing_mm) + " mm",
                              "sample the faces more coarsely");
    }
  }

  // The free boundary of the sewn faces, as closed wires.
  std::vector<std::vector<Eigen::Vector3d>> boundary;
  std::vector<TopoDS_Face> neighbours;
  if (const Trim* trim = faces.front().surface.trim(); trim != nullptr) neighbours = trim->neighbours();
  try {
    BRepBuilderAPI_Sewing sewing(options.sewing_tolerance_mm);
    for (const CadFace& face : faces) sewing.Add(face.face);
    sewing.Perform();
    ShapeAnalysis_FreeBounds free_bounds(sewing.SewedShape(), options.sewing_tolerance_mm, Standard_False,
                                         Standard_True);
    for (TopExp_Explorer it(free_bounds.GetClosedWires(), TopAbs_WIRE); it.More(); it.Next()) {
      std::vector<Eigen::Vector3d> loop = SampleWire(TopoDS::Wire(it.Current()), options.boundary_spacing_mm);
      if (loop.size() >= 3) boundary.push_back(std::move(loop));
    }
    int open = 0;
    for (TopExp_Explorer it(free_bounds.GetOpenWires(), TopAbs_WIRE); it.More(); it.Next()) ++open;
    if (boundary.empty() || open > 0) {
      return Status::Failed(
          "the " + std::to_string(faces.size()) + " faces do not bound one region: " + std::to_string(boundary.size()) +
          " closed and " + std::to_string(open) + " open free boundaries at a sewing tolerance of " +
          FormatExact(options.sewing_tolerance_mm) + " mm. Choose faces that meet edge to edge (or heal the model)");
    }
  } catch (const Standard_Failure& failure) {
    return Status::Failed("sewing the region's faces: " + occt::Message(failure));
  }
  const double step =
      std::max(1, static_cast<int>(std::lround(options.sample_spacing_mm / options.boundary_spacing_mm)));
  for (const auto& loop : boundary) {
    for (std::size_t k = 0; k < loop.size(); k += static_cast<std::size_t>(step)) points.push_back(loop[k]);
  }
  out.samples = static_cast<int>(points.size());

  // 2. One Q over the region.
  FL_ASSIGN_OR_RETURN(out.q, FitScattered(points, options.fit, &out.report));

  // 3. The region's trim on Q.
  FL_ASSIGN_OR_RETURN(const FootPointProjector projector, FootPointProjector::Build(out.q));
  std::vector<std::vector<Eigen::Vector2d>> loops;
  for (const auto& loop : boundary) {
    std::vector<Eigen::Vector2d> uv;
    for (std::size_t k = 0; k < loop.size(); ++k) {
      FL_ASSIGN_OR_RETURN(const FootPoint foot, k == 0 ? projector.Project(loop[k])
                                                       : projector.ProjectFrom(loop[k], uv.back().x(), uv.back().y()));
      const Eigen::Vector2d p(foot.u, foot.v);
      if (uv.empty() || (p - uv.back()).norm() > 1e-9) uv.push_back(p);
    }
    while (uv.size() > 1 && (uv.back() - uv.front()).norm() <= 1e-9) uv.pop_back();
    loops.push_back(std::move(uv));
  }
  FL_ASSIGN_OR_RETURN(std::shared_ptr<const Trim> trim, Trim::OfLoops(out.q, loops, neighbours));
  out.q.set_trim(trim);
  out.loops = static_cast<int>(loops.size());

  // 4. Deviation of Q from the faces at random points not used by the fit.
  Rng rng(options.seed);
  double sum2 = 0;
  for (const CadFace& face : faces) {
    const ParamDomain d = face.surface.domain();
    int placed = 0;
    for (int attempt = 0; placed < options.check_points_per_face && attempt < 100 * options.check_points_per_face;
         ++attempt) {
      const double u = rng.Uniform(d.u_min, d.u_max), v = rng.Uniform(d.v_min, d.v_max);
      if (!InsideFace(face, u, v)) continue;
      ++placed;
      const Eigen::Vector3d p = face.surface.Point(u, v);
      FL_ASSIGN_OR_RETURN(const FootPoint foot, projector.Project(p));
      const double e = foot.distance_mm;
      sum2 += e * e;
      ++out.check_points;
      if (e > out.cad_deviation_max_mm) {
        out.cad_deviation_max_mm = e;
        out.cad_deviation_max_at = p;
        out.cad_deviation_max_face = face.info.index;
      }
    }
  }
  out.cad_deviation_rms_mm = out.check_points > 0 ? std::sqrt(sum2 / out.check_points) : 0.0;
  out.report.details["region"] = {
      {"method",
       "faces sampled inside their trims, one scattered B-spline fit, region trim from the sewn faces' "
       "free boundary projected onto Q"},
      {"faces", out.faces},
      {"samples", out.samples},
      {"boundary_loops", out.loops},
      {"check_points", out.check_points},
      {"cad_deviation_rms_mm", out.cad_deviation_rms_mm},
      {"cad_deviation_max_mm", out.cad_deviation_max_mm},
      {"cad_deviation_max_at_mm",
       {out.cad_deviation_max_at.x(), out.cad_deviation_max_at.y(), out.cad_deviation_max_at.z()}},
      {"cad_deviation_max_face", out.cad_deviation_max_face},
      {"trim", trim->ToJson()}};
  if (options.max_cad_deviation_mm > 0 && out.cad_deviation_max_mm > options.max_cad_deviation_mm) {
    return Status::Failed(
        "the one B-spline fitted over the " + std::to_string(faces.size()) + " faces deviates from them by up to " +
        FormatFixed(out.cad_deviation_max_mm * 1e3, 3) + " um (at face " + std::to_string(out.cad_deviation_max_face) +
        ", (" + FormatFixed(out.cad_deviation_max_at.x(), 3) + ", " + FormatFixed(out.cad_deviation_max_at.y(), 3) +
        ", " + FormatFixed(out.cad_deviation_max_at.z(), 3) + ")), more than the limit of " +
        FormatFixed(options.max_cad_deviation_mm * 1e3, 3) +
        " um. Fix: the faces probably meet at a crease; machine them as separate parts, or sample "
        "them more densely (fit.sample_spacing_mm)");
  }
  return out;
}

}  // namespace formloop::recon
