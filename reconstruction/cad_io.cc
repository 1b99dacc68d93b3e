#include "reconstruction/cad_io.h"

#include <algorithm>
#include <cctype>
#include <memory>
#include <system_error>

#include <BRepTools.hxx>
#include <BRep_Tool.hxx>
#include <GeomConvert.hxx>
#include <Geom_RectangularTrimmedSurface.hxx>
#include <IFSelect_ReturnStatus.hxx>
#include <IGESControl_Reader.hxx>
#include <IGESData_GlobalSection.hxx>
#include <IGESData_IGESEntity.hxx>
#include <IGESData_IGESModel.hxx>
#include <STEPControl_Reader.hxx>
#include <StepRepr_RepresentationItem.hxx>
#include <StepShape_FaceSurface.hxx>
#include <TColStd_SequenceOfAsciiString.hxx>
#include <TCollection_HAsciiString.hxx>
#include <TopExp_Explorer.hxx>
#include <TopoDS.hxx>
#include <TopoDS_Face.hxx>
#include <TopoDS_Shape.hxx>
#include <Transfer_TransientProcess.hxx>
#include <XSControl_TransferReader.hxx>
#include <XSControl_WorkSession.hxx>

#include "reconstruction/occt_support.h"

namespace formloop::recon {
namespace {

std::string Lower(std::string s) {
  std::transform(s.begin(), s.end(), s.begin(), [](unsigned char c) { return static_cast<char>(std::tolower(c)); });
  return s;
}

std::string Trimmed(const Handle(TCollection_HAsciiString)& text) {
  if (text.IsNull()) return "";
  std::string s = text->ToCString();
  const auto not_space = [](unsigned char c) { return !std::isspace(c); };
  s.erase(s.begin(), std::find_if(s.begin(), s.end(), not_space));
  s.erase(std::find_if(s.rbegin(), s.rend(), not_space).base(), s.end());
  return s;
}

// A file read and transferred, with its faces in explorer order.
struct LoadedCad {
  std::unique_ptr<XSControl_Reader> reader;
  CadFormat format = CadFormat::kStep;
  std::vector<TopoDS_Face> faces;
  std::vector<CadFaceInfo> infos;
  std::string file_unit;
};

std::string FaceName(const LoadedCad& cad, const TopoDS_Face& face) {
  const Handle(XSControl_TransferReader) transfer = cad.reader->WS()->TransferReader();
  if (transfer.IsNull()) return "";
  const Handle(Standard_Transient) entity = transfer->EntityFromShapeResult(face, 1);
  if (entity.IsNull()) return "";
  if (cad.format == CadFormat::kStep) {
    const Handle(StepRepr_RepresentationItem) item = Handle(StepRepr_RepresentationItem)::DownCast(entity);
    return item.IsNull() ? "" : Trimmed(item->Name());
  }
  const Handle(IGESData_IGESEntity) item = Handle(IGESData_IGESEntity)::DownCast(entity);
  return item.IsNull() || !item->HasName() ? "" : Trimmed(item->NameValue());
}

// The unit names the files use ("millimetre", "MM", "INCH", "IN", ...) as short lower-case
// symbols: mm, inch, m, cm, um, ft; anything else is passed on in lower case.
std::string UnitSymbol(const std::string& name) {
  const std::string n = Lower(name);
  if (n == "mm" || n == "millimetre" || n == "millimeter") return "mm";
  if (n == "in" || n == "inch") return "inch";
  if (n == "m" || n == "metre" || n == "meter") return "m";
  if (n == "cm" || n == "centimetre" || n == "centimeter") return "cm";
  if (n == "um" || n == "micrometre" || n == "micrometer" || n == "micron") return "um";
  if (n == "ft" || n == "foot" || n == "feet") return "ft";
  return n;
}

std::string FileUnit(LoadedCad& cad) {
  if (cad.format == CadFormat::kStep) {
    TColStd_SequenceOfAsciiString lengths, angles, solid_angles;
    static_cast<STEPControl_Reader&>(*cad.reader).FileUnits(lengths, angles, solid_angles);
    if (lengths.IsEmpty()) return "";
    std::string units;
    for (int i = lengths.Lower(); i <= lengths.Upper(); ++i) {
      const std::string unit = UnitSymbol(lengths(i).ToCString());
      if (units.find(unit) == std::string::npos) units += (units.empty() ? "" : ",") + unit;
    }
    return units;
  }
  const Handle(IGESData_IGESModel) model = Handle(IGESData_IGESModel)::DownCast(cad.reader->Model());
  return model.IsNull() ? "" : UnitSymbol(Trimmed(model->GlobalSection().UnitName()));
}

Result<LoadedCad> Load(const std::filesystem::path& path) {
  FL_ASSIGN_OR_RETURN(const CadFormat format, CadFormatFromPath(path));
  const std::string kind = format == CadFormat::kStep ? "STEP" : "IGES";
  std::error_code ec;
  if (!std::filesystem::exists(path, ec)) {
    return Status::NotFound(kind + " file '" + path.string() + "' does not exist. Check the path");
  }
  if (!std::filesystem::is_regular_file(path, ec)) {
    return Status::BadInput("'" + path.string() + "' is not a regular file, expected a " + kind + " file");
  }
  occt::KeepStdoutClean();
  LoadedCad cad;
  cad.format = format;
  try {
    if (format == CadFormat::kStep) {
      cad.reader = std::make_unique<STEPControl_Reader>();
    } else {
      cad.reader = std::make_unique<IGESControl_Reader>();
    }
    if (cad.reader->ReadFile(path.string().c_str()) != IFSelect_RetDone) {
      return Status::BadInput(Where{.file = path.string()}, "OpenCASCADE could not read this as a " + kind + " file",
                              format == CadFormat::kStep ? "export the part as STEP AP203/AP214/AP242"
                                                         : "export the part as IGES 5.3");
    }
    cad.reader->TransferRoots();
    const TopoDS_Shape shape = cad.reader->OneShape();
    for (TopExp_Explorer it(shape, TopAbs_FACE); it.More(); it.Next()) cad.faces.push_back(TopoDS::Face(it.Current()));
    if (cad.faces.empty()) {
      return Status::BadInput(Where{.file = path.string()}, "the " + kind + " file holds no face",
                              "export a surface, a shell or a solid, not only curves or points");
    }
    for (std::size_t i = 0; i < cad.faces.size(); ++i) {
      CadFaceInfo info;
      info.index = static_cast<int>(i);
      info.name = FaceName(cad, cad.faces[i]);
      TopLoc_Location location;
      const Handle(Geom_Surface) geom = BRep_Tool::Surface(cad.faces[i], location);
      info.surface_type = geom.IsNull() ? "none" : geom->DynamicType()->Name();
      cad.infos.push_back(std::move(info));
    }
    cad.file_unit = FileUnit(cad);
  } catch (const Standard_Failure& failure) {
    return Status::BadInput(Where{.file = path.string()}, "OpenCASCADE failed while reading: " + occt::Message(failure));
  }
  return cad;
}

std::string FaceList(const std::vector<CadFaceInfo>& infos) {
  std::string list;
  for (const CadFaceInfo& info : infos) {
    if (!list.empty()) list += ", ";
    list += std::to_string(info.index) + (info.name.empty() ? "" : " '" + info.name + "'") + " (" +
            info.surface_type + ")";
    if (list.size() > 400) {
      list += ", ...";
      break;
    }
  }
  return list;
}

Result<int> ChooseFace(const std::filesystem::path& path, const std::vector<CadFaceInfo>& infos,
                       const CadFaceSelector& selector) {
  const int count = static_cast<int>(infos.size());
  if (!selector.name.empty()) {
    std::vector<int> matches;
    for (const CadFaceInfo& info : infos) {
      if (info.name == selector.name) matches.push_back(info.index);
    }
    if (matches.empty()) {
      return Status::BadInput(Where{.file = path.string(), .field = "face name"},
                              "no face is named '" + selector.name + "'; the faces are: " + FaceList(infos),
                              "use one of these names or choose the face by index");
    }
    if (matches.size() > 1) {
      return Status::BadInput(Where{.file = path.string(), .field = "face name"},
                              std::to_string(matches.size()) + " faces are named '" + selector.name + "'",
                              "choose the face by index instead");
    }
    if (selector.index >= 0 && selector.index != matches.front()) {
      return Status::BadInput(Where{.file = path.string(), .field = "face"},
                              "face '" + selector.name + "' has index " + std::to_string(matches.front()) +
                                  ", not " + std::to_string(selector.index),
                              "give either the name or the index");
    }
    return matches.front();
  }
  if (selector.index < 0) {
    if (count == 1) return 0;
    return Status::BadInput(Where{.file = path.string(), .field = "face"},
                            "the file has " + std::to_string(count) + " faces: " + FaceList(infos),
                            "choose one by index (0-based) or by name");
  }
  if (selector.index >= count) {
    return Status::BadInput(Where{.file = path.string(), .field = "face index"},
                            "face index " + std::to_string(selector.index) + " is out of range: the file has " +
                                std::to_string(count) + (count == 1 ? " face" : " faces"),
                            "use an index from 0 to " + std::to_string(count - 1));
  }
  return selector.index;
}

}  // namespace

Result<CadFormat> CadFormatFromPath(const std::filesystem::path& path) {
  const std::string ext = Lower(path.extension().string());
  if (ext == ".step" || ext == ".stp") return CadFormat::kStep;
  if (ext == ".iges" || ext == ".igs") return CadFormat::kIges;
  return Status::BadInput(Where{.file = path.string()}, "'" + ext + "' is not a CAD extension",
                          "use a .step/.stp or .iges/.igs file");
}

bool IsCadPath(const std::filesystem::path& path) { return CadFormatFromPath(path).ok(); }

Result<std::vector<CadFaceInfo>> ListCadFaces(const std::filesystem::path& path) {
  FL_ASSIGN_OR_RETURN(LoadedCad cad, Load(path));
  return cad.infos;
}

Result<CadFace> ReadCadFace(const std::filesystem::path& path, const CadFaceSelector& selector) {
  FL_ASSIGN_OR_RETURN(LoadedCad cad, Load(path));
  FL_ASSIGN_OR_RETURN(const int index, ChooseFace(path, cad.infos, selector));
  const TopoDS_Face& face = cad.faces[static_cast<std::size_t>(index)];
  CadFace result;
  result.info = cad.infos[static_cast<std::size_t>(index)];
  result.file_unit = cad.file_unit;
  const std::string which = "face " + std::to_string(index) + (result.info.name.empty() ? "" : " '" + result.info.name + "'");
  try {
    const Handle(Geom_Surface) geom = BRep_Tool::Surface(face);  // with the face location applied
    if (geom.IsNull()) {
      return Status::BadInput(Where{.file = path.string()}, which + " has no underlying surface",
                              "choose another face");
    }
    Handle(Geom_BSplineSurface) bspline = Handle(Geom_BSplineSurface)::DownCast(geom);
    if (bspline.IsNull()) {
      // Trim to the face's parameter box so unbounded surfaces (planes, cylinders) convert.
      double u1, u2, v1, v2;
      BRepTools::UVBounds(face, u1, u2, v1, v2);
      Handle(Geom_Surface) trimmed = geom;
      if (!geom->IsKind(STANDARD_TYPE(Geom_RectangularTrimmedSurface))) {
        trimmed = new Geom_RectangularTrimmedSurface(geom, u1, u2, v1, v2);
      }
      bspline = GeomConvert::SurfaceToBSplineSurface(trimmed);
      if (bspline.IsNull()) {
        return Status::BadInput(Where{.file = path.string()},
                                which + " of type " + result.info.surface_type +
                                    " could not be converted to a B-spline surface",
                                "convert the face to a NURBS surface in the CAD system");
      }
      result.converted = true;
    } else {
      bspline = Handle(Geom_BSplineSurface)::DownCast(bspline->Copy());  // Q must not alias the reader's model
    }
    if (face.Orientation() == TopAbs_REVERSED) {
      // The face's material side is opposite to S_u × S_v; reverse u so Q's normal points away
      // from the material as the rest of formloop assumes.
      bspline->UReverse();
    }
    result.surface = BSplineSurface(bspline);
  } catch (const Standard_Failure& failure) {
    return Status::BadInput(Where{.file = path.string()},
                            "OpenCASCADE failed while converting " + which + ": " + occt::Message(failure));
  }
  return result;
}

Result<BSplineSurface> ReadStep(const std::filesystem::path& path, int face_index) {
  if (face_index < 0) {
    return Status::BadInput(Where{.file = path.string(), .field = "face_index"},
                            "face index " + std::to_string(face_index) + " is negative", "use a 0-based index");
  }
  FL_ASSIGN_OR_RETURN(CadFace face, ReadCadFace(path, CadFaceSelector{.index = face_index}));
  return std::move(face.surface);
}

}  // namespace formloop::recon
