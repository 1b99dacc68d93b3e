#pragma once
// The ideal surface Q from CAD (spec/reconstruction.md §1): one face of a STEP (AP203/AP214/AP242)
// or IGES file, chosen by 0-based index or by name, delivered as a B-spline surface in mm.
//
// Units: OpenCASCADE's readers scale every length from the file's unit (STEP: the
// LENGTH_UNIT of the representation context; IGES: the global section's unit flag) to the session
// unit "xstep.cascade.unit", which formloop keeps at MM. The file's own unit is reported.
//
// Names: a STEP face's name is the name of its ADVANCED_FACE (or FACE_SURFACE) entity; an IGES
// face's name is the entity's name property or its 8-character entity label. Faces are numbered in
// TopExp_Explorer order over the transferred shape, which is the order `formloop fit --list-faces`
// prints.
//
// Faces whose surface is not a B-spline (planes, cylinders, cones, surfaces of revolution, offset
// surfaces...) are converted with their trimming curves by BRepBuilderAPI_NurbsConvert (surface and
// pcurves together, so the trim stays valid); the source type is reported. Q is the underlying
// B-spline restricted (Geom_BSplineSurface::Segment, exact) to the face's parameter box, and the
// face's trimming loops and the file's other faces travel with it as its Trim
// (reconstruction/trim.h): outside the outer loop and inside holes is not part of the part.
//
// Crashes: the file is read and transferred in a child process (core/child_process.h), because OpenCASCADE
// 7.6's readers crash on some damaged files; the child sends the shape back in OpenCASCADE's binary BRep
// format (exact), so the faces are the reader's bit for bit. A child that ends by a signal is BadInput
// naming the file ("could not be read: OpenCASCADE's STEP reader crashed on it (signal 11, ...)").
//
// Hangs: the child has CadReadTimeoutSeconds() to answer (default kDefaultCadReadTimeout_s = 120 s, far above
// what a part's file needs: the test parts take well under a second; the CLI's global option --cad-timeout-s
// sets it, 0 = no limit). A child still reading then is killed with SIGKILL and reaped, and the read is
// BadInput naming the file ("OpenCASCADE's STEP reader took longer than 120 s and was stopped"), with the fix:
// a larger limit for a large valid file, or a check of the file in a CAD system.
//
// IGES files must state their length unit: a global section whose unit flag is missing or not one
// of IGES 5.3's codes 1..11 (the standard then assumes inches, which for a part drawn in mm is a
// factor 25.4) is refused, naming the field.

#include <filesystem>
#include <limits>
#include <string>
#include <vector>

#include <TopoDS_Face.hxx>

#include "core/status.h"
#include "reconstruction/bspline_surface.h"

namespace formloop::recon {

enum class CadFormat { kStep, kIges };

// The time limit of one read (listing or reading a file), process-wide; <= 0: no limit.
inline constexpr double kDefaultCadReadTimeout_s = 120.0;
void SetCadReadTimeoutSeconds(double seconds);
double CadReadTimeoutSeconds();

// From the extension (.step .stp .iges .igs, any case); BadInput naming the file otherwise.
Result<CadFormat> CadFormatFromPath(const std::filesystem::path& path);
// True when the extension names a CAD format (used to tell CAD files from point files).
bool IsCadPath(const std::filesystem::path& path);

struct CadFaceInfo {
  int index = 0;             // 0-based, TopExp_Explorer order
  std::string name;          // "" when the file gives none
  std::string surface_type;  // OpenCASCADE type of the underlying surface, e.g. "Geom_Plane"
  // ListCadFaces only (to choose a face without fitting each): the face's bounding box (mm, from its
  // triangulation-free BRepBndLib box, so a little larger than the face), its area (mm²) and the mean of
  // its normal's z over the face (away from the material: +1 faces up, −1 down; NaN when not computed).
  double box_min_mm[3] = {0, 0, 0}, box_max_mm[3] = {0, 0, 0};
  double area_mm2 = 0;
  double mean_normal_z = std::numeric_limits<double>::quiet_NaN();
};

struct CadFace {
  BSplineSurface surface;  // in mm, with its trim (null when the face is its whole patch and alone in the file)
  TopoDS_Face face;        // the face as read (after NURBS conversion), in mm
  CadFaceInfo info;
  std::string file_unit;   // the file's length unit: "mm", "inch", "m", ... (Q itself is always in mm)
  bool converted = false;  // the face's surface was converted to a B-spline
};

// Selects a face: by name when `name` is not empty, else by `index`. With neither (index < 0 and
// no name), a file with exactly one face gives that face and a file with several is an error that
// lists them.
struct CadFaceSelector {
  int index = -1;
  std::string name;
  // Turn the face over: its material on the other side than the file says (a face without a solid,
  // whose orientation carries no meaning, written with its normal into the material).
  bool reverse = false;
};

// Every face of the file, for listing. BadInput (naming the file) when it cannot be read or holds
// no face.
Result<std::vector<CadFaceInfo>> ListCadFaces(const std::filesystem::path& path);
Result<CadFace> ReadCadFace(const std::filesystem::path& path, const CadFaceSelector& selector);

// Several faces (a free-form region): by 0-based indices or by names (one of the two). Each is read
// as ReadCadFace reads one; the neighbours of each face's trim are the faces not chosen. BadInput
// naming the field ("faces" / "face_names") for an empty list, a repeated face, an index out of
// range or a name that does not exist (the message lists the file's faces).
struct CadRegionSelector {
  std::vector<int> indices;
  std::vector<std::string> names;
};
Result<std::vector<CadFace>> ReadCadFaces(const std::filesystem::path& path, const CadRegionSelector& selector);

}  // namespace formloop::recon
