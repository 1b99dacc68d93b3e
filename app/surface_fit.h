#pragma once
// `formloop fit` and `formloop project` as library functions (spec/reconstruction.md): the ideal
// surface Q from points, CAD or an analytic reference surface, always as a B-spline with its fit
// report; and the foot points of measured points on Q.
//
// Outputs are all-or-nothing: the STEP file and the JSON report are written through temporary files
// and renamed only when the whole fit has succeeded; a failure leaves no output file behind.

#include <optional>
#include <string>

#include <nlohmann/json.hpp>

#include "core/point_set.h"
#include "core/status.h"
#include "reconstruction/bspline_surface.h"
#include "reconstruction/cad_io.h"
#include "reconstruction/scattered_fit.h"

namespace formloop::app {

enum class FitMethod {
  kCad,               // the CAD face itself (converted to a B-spline when it is another surface type)
  kGrid,              // GeomAPI_PointsToBSplineSurface on a row-major grid of points
  kScattered,         // our least squares with thin-plate smoothing and parameter correction
  kAdaptive,          // kScattered with knot refinement where the residual exceeds the tolerance
  kQuadricAlgebraic,  // x² + a y² + b z² + c x + d y + e z + f = 0 by linear least squares
  kQuadricGeometric,  // the same quadric by orthogonal distances, started from the algebraic fit
};
Result<FitMethod> ParseFitMethod(const std::string& text);
std::string FitMethodName(FitMethod method);

struct FitRequest {
  // A point file (.csv .ply .xyz .pcd), a CAD file (.step .stp .iges .igs) or "analytic:NAME" for
  // a reference surface (see `formloop surfaces list`).
  std::string input;
  // Empty: cad for CAD files, grid for analytic surfaces, scattered for point files.
  std::optional<FitMethod> method;
  recon::CadFaceSelector face;  // CAD input only
  // Grid method: the row-major layout of a point file (nu points per row, nv rows); 0 × 0 = a square
  // grid inferred from the count. Analytic input: samples per side (default 50 × 50).
  int grid_nu = 0, grid_nv = 0;
  // Analytic input with a scattered method: seeded uniform samples over the domain.
  int scattered_samples = 5000;
  unsigned long long seed = 1;
  // Analytic input: seeded random check points at which Q is compared with the exact surface.
  int check_points = 10000;
  recon::GridFitOptions grid;
  recon::ScatteredFitOptions scattered;
  double quadric_tolerance_mm = 1e-4;  // B-spline conversion tolerance of a fitted quadric
  std::string out_step;                // required
  std::string out_report;              // optional
  std::string name;                    // STEP product and face name; default: from the input
  bool force = false;                  // --force: replace output files formloop wrote (core/output_file.h)
};

struct FitOutcome {
  recon::BSplineSurface surface;
  nlohmann::json report;  // what --report writes
};

// Reads the input, fits, checks against the truth when it is known; writes nothing.
Result<FitOutcome> FitSurface(const FitRequest& request);
// FitSurface, then the STEP file and the report (both or neither).
Status RunFit(const FitRequest& request);

struct ProjectRequest {
  std::string surface;  // STEP/IGES file holding Q (e.g. from `formloop fit`)
  recon::CadFaceSelector face;
  std::string points;  // point file
  std::string out;     // deviations: .csv .ply .xyz .pcd
  bool force = false;  // --force: replace an output file formloop wrote (core/output_file.h)
};

// Foot points of every input point: the output keeps the input points, ids and times, sets the
// normals to the unit normals of Q at the foot points and adds the scalars deviation_mm (signed,
// positive = material left), foot_u, foot_v, foot_x, foot_y, foot_z and on_boundary (1 when the foot point
// is clamped to the edge of Q's domain), and for a trimmed face outside_trim (1 when the foot point lies over
// a hole or past the face's edge). The summary says how many, RMS and max |deviation|.
struct ProjectOutcome {
  PointSet deviations;
  nlohmann::json summary;
};
Result<ProjectOutcome> ProjectPoints(const ProjectRequest& request);
// ProjectPoints, then writes the deviations and prints the summary (JSON) on stdout.
Status RunProject(const ProjectRequest& request);

}  // namespace formloop::app
