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
// surfaces...) are trimmed to the face's parameter box and converted with
// GeomConvert::SurfaceToBSplineSurface; the source type is reported. The face's trimming curves
// are not kept: Q is the whole underlying patch over that box.

#include <filesystem>
#include <string>
#include <vector>

#include "core/status.h"
#include "reconstruction/bspline_surface.h"

namespace formloop::recon {

enum class CadFormat { kStep, kIges };

// From the extension (.step .stp .iges .igs, any case); BadInput naming the file otherwise.
Result<CadFormat> CadFormatFromPath(const std::filesystem::path& path);
// True when the extension names a CAD format (used to tell CAD files from point files).
bool IsCadPath(const std::filesystem::path& path);

struct CadFaceInfo {
  int index = 0;            // 0-based, TopExp_Explorer order
  std::string name;         // "" when the file gives none
  std::string surface_type; // OpenCASCADE type of the underlying surface, e.g. "Geom_Plane"
};

struct CadFace {
  BSplineSurface surface;   // in mm
  CadFaceInfo info;
  std::string file_unit;    // the file's length unit: "mm", "inch", "m", ... (Q itself is always in mm)
  bool converted = false;   // the face's surface was converted to a B-spline
};

// Selects a face: by name when `name` is not empty, else by `index`. With neither (index < 0 and
// no name), a file with exactly one face gives that face and a file with several is an error that
// lists them.
struct CadFaceSelector {
  int index = -1;
  std::string name;
};

// Every face of the file, for listing. BadInput (naming the file) when it cannot be read or holds
// no face.
Result<std::vector<CadFaceInfo>> ListCadFaces(const std::filesystem::path& path);
Result<CadFace> ReadCadFace(const std::filesystem::path& path, const CadFaceSelector& selector);

}  // namespace formloop::recon
