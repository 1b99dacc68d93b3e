#pragma once
// Ideal surfaces given as files in the part description (app/part.h): CAD faces and scans.
//
//   "surface": {"cad": "part.step"}                          a file holding one face
//   "surface": {"cad": "part.step", "faces": [3, 4, 7]}       faces by 0-based index (the order of
//                                                             `formloop fit part.step --list-faces`)
//   "surface": {"cad": "part.igs", "face_names": ["top"]}     faces by name
//   "surface": {"points": "scan.ply"}                          any point file formloop reads (.csv .xyz .ply .pcd)
//
// Paths are relative to the part file. Parsing reads the file's list of faces (or its points), so a
// missing file, a face index out of range, a face name that does not exist (the message lists the faces),
// a unit-less IGES file or a point file that cannot be read is refused before a run folder exists, with
// the field named. The run keeps a copy of the file in its inputs/ folder with its SHA-256; the resolved
// part names the copy and its hash ("sha256"), so a run repeated from its folder reads the same bytes,
// and a file whose hash no longer matches is refused.
//
// Q: one face is its own B-spline with its trim (reconstruction/cad_io.h). Several faces become one Q over
// the region by the scattered fit (reconstruction/cad_region.h, which says why), refused when it deviates
// from the faces by more than max_deviation_fraction × the form tolerance (default 0.1: the fit then
// stays an order of magnitude below the tolerance, the rule the regression runs hold every surface to). A
// scan becomes Q by the scattered fit ("method": "scattered", the default, or "adaptive" with knots
// inserted where the residual exceeds "tolerance_mm"), restricted to the points' parameter box so nothing
// beyond the data is machined; its fit report travels with Q.
//
// A face is machined on the side its normal points to, away from the material: the file's orientation
// (a solid's face points out of it). "reverse": true turns one face over, for a face without a solid
// written with its normal into the material; PlanRaster refuses a face that faces down.
//
// More fields: "sample_spacing_mm" (region: between the samples on the faces, default 1), "poles"
// [nu, nv] (scan: control net, default automatic), "sha256" (the file's hash, checked when given).

#include <filesystem>
#include <limits>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "core/json_io.h"
#include "core/status.h"
#include "reconstruction/bspline_surface.h"

namespace formloop::app {

struct SurfaceFile {
  enum class Kind { kCad, kPoints };
  Kind kind = Kind::kCad;
  std::string name;                     // as the part file gives it ("part.step", "../cad/part.step")
  std::filesystem::path path;           // resolved against the part file's folder
  std::string sha256;                   // of the file, computed when the part is parsed
  std::vector<int> faces;               // CAD: chosen by index ...
  std::vector<std::string> face_names;  // ... or by name (neither: the file's only face)
  double sample_spacing_mm = 1.0;       // CAD region
  double max_deviation_fraction = 0.1;
  bool reverse = false;              // CAD, one face: turned over (recon::CadFaceSelector::reverse)
  std::string method = "scattered";  // scan: scattered | adaptive
  int u_poles = 0, v_poles = 0;      // scan: control net (0: automatic)
  double fit_tolerance_mm = 1e-3;    // scan, adaptive: residual limit for knot insertion
  // The file's name inside a run folder's inputs/ (its base name).
  std::string CopyName() const;
  // The resolved "surface" member; `name` is written as given (inputs/part.json gives CopyName()).
  nlohmann::json ToJson(const std::string& name) const;
  std::string Describe() const;  // "cad:part.step[3,4]", "scan:scan.ply"
};

// True when a part's "surface" object names a file ("cad" or "points").
bool IsSurfaceFile(const nlohmann::json& surface);
// `surface` is the part's "surface" object, `part_source` the part file (relative paths start at its folder).
Result<SurfaceFile> ParseSurfaceFile(const JsonFields& surface, const std::string& part_source);

struct SurfaceFromFile {
  recon::BSplineSurface q;
  recon::FitReport report;
  nlohmann::json description;  // for surface/surface.json
  // The largest known distance between Q and the given surface: 0 for one CAD face (Q is the face), the
  // region fit's deviation from the faces; NaN for a scan (the true surface is not known).
  double fit_check_max_mm = std::numeric_limits<double>::quiet_NaN();
};
Result<SurfaceFromFile> BuildSurfaceFromFile(const SurfaceFile& file, double tolerance_mm);

// Copies the file into `dir` as CopyName() after checking that its hash is still the parsed one.
Status CopySurfaceFile(const SurfaceFile& file, const std::filesystem::path& dir);

}  // namespace formloop::app
