#pragma once
// A free-form region of several CAD faces as one ideal surface Q (spec/reconstruction.md §1, §2).
//
// The choice: the faces are sampled and one B-spline Q is fitted over the whole region with the
// scattered fit (scattered_fit.h), rather than planning the tool path across the faces. Everything
// after the tool path lives in Q's single parameter plane: probe points and their (u, v), the spatial
// weights of Moran's I, the decomposition's fields, the mirror compensation as a field over (u, v), the
// virtual machine's association of points with passes, the features for retrieval. Planning across the
// faces would give a tool path but leave each of those with one parameterisation per face and a seam
// between them. The price is the fit's deviation from the CAD faces, which is measured and reported, and
// a run refuses the fit when it exceeds a stated fraction of the form tolerance (app part description,
// `fit.max_cad_deviation_fraction`): faces meeting at a crease a smooth Q cannot follow are refused
// with the figure, not machined wrong.
//
// Method:
//  1. Samples: on each face a grid of cell midpoints over its parameter box at about sample_spacing_mm
//     (3-D), kept where the face's trim holds them (so no two faces give the same point at a seam), plus
//     the region's free boundary (step 3) every sample_spacing_mm.
//  2. Q = FitScattered(samples, options.fit); its FitReport is the fit's own (orthogonal residuals).
//  3. The region's trim on Q: the faces are sewn (BRepBuilderAPI_Sewing, tolerance sewing_tolerance_mm),
//     their free boundary is chained into closed wires (ShapeAnalysis_FreeBounds), each wire sampled every
//     boundary_spacing_mm and its points projected onto Q (FootPointProjector), and Trim::OfLoops builds the
//     trimmed face on Q from those loops. The faces of the file that were not chosen are its neighbours.
//  4. Deviation from the CAD faces: check_points_per_face seeded random points on each face, inside its
//     trim and not used by the fit, projected onto Q: the distance's RMS and max (and where, which face).
//     With max_cad_deviation_mm > 0 a larger max is refused (Failed, with the figure and where).

#include <vector>

#include "core/status.h"
#include "reconstruction/bspline_surface.h"
#include "reconstruction/cad_io.h"
#include "reconstruction/scattered_fit.h"

namespace formloop::recon {

struct RegionFitOptions {
  double sample_spacing_mm = 1.0;     // between the fit's samples on each face (3-D, about)
  double boundary_spacing_mm = 0.25;  // between the boundary points projected onto Q for the trim
  double sewing_tolerance_mm = 1e-3;  // faces within this of each other share an edge (not a free boundary)
  int check_points_per_face = 2000;
  unsigned long long seed = 1;      // of the check points
  double max_cad_deviation_mm = 0;  // refuse a larger deviation from the faces (0: report only)
  ScatteredFitOptions fit;
  Status Validate() const;
};

struct RegionFit {
  BSplineSurface q;  // with the region's trim
  FitReport report;  // the scattered fit's report; details gain "region" (the figures below)
  int faces = 0;
  int samples = 0;
  int loops = 0;  // boundary loops of the region (1 + its holes)
  int check_points = 0;
  double cad_deviation_rms_mm = 0, cad_deviation_max_mm = 0;
  Eigen::Vector3d cad_deviation_max_at = Eigen::Vector3d::Zero();
  int cad_deviation_max_face = -1;  // CadFaceInfo::index of the face where the max occurs
};

// Needs at least two faces (one face is its own Q: cad_io.h). BadInput for invalid options or faces;
// Failed when the faces do not make one region (no closed free boundary), the fit fails, or the
// deviation exceeds max_cad_deviation_mm.
Result<RegionFit> FitCadRegion(const std::vector<CadFace>& faces, const RegionFitOptions& options);

}  // namespace formloop::recon
