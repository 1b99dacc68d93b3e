#include "reconstruction/cad_io.h"

#include <algorithm>
#include <atomic>
#include <cctype>
#include <memory>
#include <optional>
#include <sstream>
#include <system_error>

#include <BRepAdaptor_Surface.hxx>
#include <BRepBndLib.hxx>
#include <BRepBuilderAPI_NurbsConvert.hxx>
#include <BRepGProp.hxx>
#include <BRepTools.hxx>
#include <BRep_Tool.hxx>
#include <BinTools.hxx>
#include <Bnd_Box.hxx>
#include <GProp_GProps.hxx>
#include <Geom_BSplineSurface.hxx>
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

#include "core/child_process.h"
#include "core/number_text.h"
#include "reconstruction/occt_support.h"
#include "reconstruction/trim.h"

namespace formloop::recon {
namespace {

std::atomic<double> cad_read_timeout_s{kDefaultCadReadTimeout_s};

std::string Lower(std::string s) {
  std::transform(s.begin(), s.end(), s.begin(), [](unsigned char c) { return static_cast<char>(std::tolower(c)); });
  return s;
}

std::string Trimmed(const Handle(TCollection_HAsciiString) & text) {
  if (text.IsNull()) return "";
  std::string s = text->ToCString();
  const auto not_space = [](unsigned char c) { return !std::isspace(c); };
  s.erase(s.begin(), std::find_if(s.begin(), s.end(), not_space));
  s.erase(std::find_if(s.rbegin(), s.rend(), not_space).base(), s.end());
  return s;
}

// A file read and transferred, with its faces in explorer order.
struct LoadedCad {
  CadFormat format = CadFormat::kStep;
  std::vector<TopoDS_Face> faces;
  std::vector<CadFaceInfo> infos;
  std::string file_unit;
};

// The reader with the file's transferred shape, inside the child process (ReadInChild).
struct ReaderCad {
  std::unique_ptr<XSControl_Reader> reader;
  CadFormat format = CadFormat::kStep;
};

std::string FaceName(const ReaderCad& cad, const TopoDS_Face& face) {
  const Handle(XSControl_TransferReader) transfer = cad.reader->WS()->TransferReader();
  if (transfer.IsNull()) return "";
  // Mode 1 finds faces transferred on their own (a solid's); faces of open shells or compounds are found
  // only by exploring every result (mode -1).
  Handle(Standard_Transient) entity = transfer->EntityFromShapeResult(face, 1);
  if (entity.IsNull()) entity = transfer->EntityFromShapeResult(face, -1);
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

std::string FileUnit(const ReaderCad& cad) {
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

// IGES 5.3 global section: parameter 14 is the unit flag (1 inch, 2 mm, 3 named in parameter 15, 4 ft,
// ..., 11 µm) and 15 the unit's name. OpenCASCADE reads a missing flag as its default, 1 (inch), with no
// name; a file whose name is missing and whose flag says nothing else states no unit, and reading it
// as inches would scale a part drawn in mm by 25.4.
Status CheckIgesUnit(const std::filesystem::path& path, XSControl_Reader& reader) {
  const Handle(IGESData_IGESModel) model = Handle(IGESData_IGESModel)::DownCast(reader.Model());
  if (model.IsNull()) return Status::Ok();
  const IGESData_GlobalSection& global = model->GlobalSection();
  const int flag = global.UnitFlag();
  const std::string name = Trimmed(global.UnitName());
  if (flag < 1 || flag > 11) {
    return Status::BadInput(Where{.file = path.string(), .field = "global section parameter 14 (units flag)"},
                            "unit flag " + std::to_string(flag) + " is not one of IGES 5.3's codes 1..11",
                            "export the IGES file again with its length unit (e.g. mm)");
  }
  if (name.empty() && (flag == 1 || flag == 3)) {
    return Status::BadInput(Where{.file = path.string(), .field = "global section parameters 14-15 (units)"},
                            "the file states no length unit (no unit name, and the unit flag is missing or at "
                            "its default, which IGES reads as inches)",
                            "export the IGES file again with its length unit (e.g. mm), or export STEP");
  }
  return Status::Ok();
}

// The child's answer to the parent (ReadInChild): netstrings "<length>:<bytes>", first "ok" or the error's
// StatusCode and message; after "ok" the file's unit, the face count, each face's name and surface type, and
// the transferred shape in OpenCASCADE's binary BRep format (BinTools: every double as its 8 bytes, so the
// shape the parent reads back is the one the reader built, bit for bit).
void PutField(std::string& out, const std::string& field) {
  out += std::to_string(field.size());
  out += ':';
  out += field;
}

// The next field of `in` from `at` (advanced past it); nullopt when the message is cut short or malformed.
std::optional<std::string> TakeField(const std::string& in, std::size_t& at) {
  const std::size_t colon = in.find(':', at);
  if (colon == std::string::npos || colon == at || colon - at > 18) return std::nullopt;
  std::size_t length = 0;
  for (std::size_t k = at; k < colon; ++k) {
    if (!std::isdigit(static_cast<unsigned char>(in[k]))) return std::nullopt;
    length = length * 10 + static_cast<std::size_t>(in[k] - '0');
  }
  if (length > in.size() - colon - 1) return std::nullopt;
  at = colon + 1 + length;
  return in.substr(colon + 1, length);
}

std::string ErrorMessage(const Status& status) {
  std::string out;
  PutField(out, std::to_string(static_cast<int>(status.code())));
  PutField(out, status.message());
  return out;
}

// Reads and transfers the file with OpenCASCADE and describes the result (the child's side).
std::string ReadInChild(const std::filesystem::path& path, CadFormat format, const std::string& kind) {
  occt::KeepStdoutClean();
  ReaderCad cad;
  cad.format = format;
  try {
    if (format == CadFormat::kStep) {
      cad.reader = std::make_unique<STEPControl_Reader>();
    } else {
      cad.reader = std::make_unique<IGESControl_Reader>();
    }
    if (cad.reader->ReadFile(path.string().c_str()) != IFSelect_RetDone) {
      return ErrorMessage(Status::BadInput(
          Where{.file = path.string()}, "OpenCASCADE could not read this as a " + kind + " file",
          format == CadFormat::kStep ? "export the part as STEP AP203/AP214/AP242" : "export the part as IGES 5.3"));
    }
    if (format == CadFormat::kIges) {
      if (const Status unit = CheckIgesUnit(path, *cad.reader); !unit.ok()) return ErrorMessage(unit);
    }
    cad.reader->TransferRoots();
    const TopoDS_Shape shape = cad.reader->OneShape();
    std::vector<TopoDS_Face> faces;
    for (TopExp_Explorer it(shape, TopAbs_FACE); it.More(); it.Next()) faces.push_back(TopoDS::Face(it.Current()));
    if (faces.empty()) {
      return ErrorMessage(Status::BadInput(Where{.file = path.string()}, "the " + kind + " file holds no face",
                                           "export a surface, a shell or a solid, not only curves or points"));
    }
    std::string out;
    PutField(out, "ok");
    PutField(out, FileUnit(cad));
    PutField(out, std::to_string(faces.size()));
    for (const TopoDS_Face& face : faces) {
      PutField(out, FaceName(cad, face));
      TopLoc_Location location;
      const Handle(Geom_Surface) geom = BRep_Tool::Surface(face, location);
      PutField(out, geom.IsNull() ? "none" : geom->DynamicType()->Name());
    }
    std::ostringstream brep(std::ios::binary);
    BinTools::Write(shape, brep);
    PutField(out, brep.str());
    return out;
  } catch (const Standard_Failure& failure) {
    return ErrorMessage(
        Status::BadInput(Where{.file = path.string()}, "OpenCASCADE failed while reading: " + occt::Message(failure)));
  }
}

// The parent's side: the child's message back into a LoadedCad (or its error).
Result<LoadedCad> FromChild(const std::filesystem::path& path, CadFormat format, const std::string& message) {
  const Status garbled = Status::Internal("the " + path.string() + " reader process sent an incomplete answer");
  std::size_t at = 0;
  const auto head = TakeField(message, at);
  if (!head) return garbled;
  if (*head != "ok") {
    const auto text = TakeField(message, at);
    int code = 0;
    for (const char c : *head) code = std::isdigit(static_cast<unsigned char>(c)) ? code * 10 + (c - '0') : -1;
    if (!text || code <= 0 || code > static_cast<int>(StatusCode::kInternal)) return garbled;
    return Status(static_cast<StatusCode>(code), *text);
  }
  LoadedCad cad;
  cad.format = format;
  const auto unit = TakeField(message, at);
  const auto count_text = TakeField(message, at);
  if (!unit || !count_text || count_text->empty() || count_text->size() > 9) return garbled;
  cad.file_unit = *unit;
  std::size_t count = 0;
  for (const char c : *count_text) {
    if (!std::isdigit(static_cast<unsigned char>(c))) return garbled;
    count = count * 10 + static_cast<std::size_t>(c - '0');
  }
  for (std::size_t k = 0; k < count; ++k) {
    const auto name = TakeField(message, at);
    const auto type = TakeField(message, at);
    if (!name || !type) return garbled;
    cad.infos.push_back(CadFaceInfo{.index = static_cast<int>(k), .name = *name, .surface_type = *type});
  }
  const auto brep = TakeField(message, at);
  if (!brep || at != message.size()) return garbled;
  try {
    std::istringstream in(*brep, std::ios::binary);
    TopoDS_Shape shape;
    BinTools::Read(shape, in);
    for (TopExp_Explorer it(shape, TopAbs_FACE); it.More(); it.Next()) cad.faces.push_back(TopoDS::Face(it.Current()));
  } catch (const Standard_Failure& failure) {
    return Status::Internal("the shape of " + path.string() + " could not be passed on: " + occt::Message(failure));
  }
  if (cad.faces.size() != count) return garbled;
  return cad;
}

// OpenCASCADE's readers crash on some damaged files (a null dereference in the STEP translation, an
// out-of-bounds read in the IGES parser; fuzz/corpus/fuzz_step|fuzz_iges/crash-*). They run in a child
// process (core/child_process.h): a crash there is an error naming the file, and formloop carries on.
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
  ChildFailure failure;
  const double limit_s = CadReadTimeoutSeconds();
  auto message = RunInChildProcess([&] { return ReadInChild(path, format, kind); }, &failure, limit_s);
  if (!message.ok()) {
    if (message.status().code() == StatusCode::kIoError) return message.status();
    if (failure.timed_out) {
      return Status::BadInput(Where{.file = path.string()},
                              "could not be read: OpenCASCADE's " + kind + " reader took longer than " +
                                  FormatSignificant(limit_s, 6) + " s and was stopped (a damaged file can make it " +
                                  "loop; a valid file this large is rare)",
                              "check the file in a CAD system or export it again; if it is valid and large, allow the "
                              "reader more time with the global option --cad-timeout-s SECONDS (0 = no limit)");
    }
    return Status::BadInput(
        Where{.file = path.string()},
        "could not be read: OpenCASCADE's " + kind + " reader crashed on it (" + failure.Describe() + ")",
        "check the file in a CAD system, or export it again");
  }
  return FromChild(path, format, *message);
}

}  // namespace

void SetCadReadTimeoutSeconds(double seconds) { cad_read_timeout_s.store(seconds); }
double CadReadTimeoutSeconds() { return cad_read_timeout_s.load(); }

namespace {

std::string FaceList(const std::vector<CadFaceInfo>& infos) {
  std::string list;
  for (const CadFaceInfo& info : infos) {
    if (!list.empty()) list += ", ";
    list +=
        std::to_string(info.index) + (info.name.empty() ? "" : " '" + info.name + "'") + " (" + info.surface_type + ")";
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
  if (selector.index < -1) {  // -1: not given
    return Status::BadInput(Where{.file = path.string(), .field = "face index"},
                            "face index " + std::to_string(selector.index) + " is negative", "use a 0-based index");
  }
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
                              "face '" + selector.name + "' has index " + std::to_string(matches.front()) + ", not " +
                                  std::to_string(selector.index),
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
  // Where each face is and which way it looks, so a face can be chosen without fitting each one.
  for (std::size_t k = 0; k < cad.faces.size() && k < cad.infos.size(); ++k) {
    const TopoDS_Face& face = cad.faces[k];
    CadFaceInfo& info = cad.infos[k];
    try {
      Bnd_Box box;
      BRepBndLib::Add(face, box);
      if (!box.IsVoid())
        box.Get(info.box_min_mm[0], info.box_min_mm[1], info.box_min_mm[2], info.box_max_mm[0], info.box_max_mm[1],
                info.box_max_mm[2]);
      GProp_GProps props;
      BRepGProp::SurfaceProperties(face, props);
      info.area_mm2 = props.Mass();
      // The normal's z, area-weighted over a 17 x 17 grid of the face's parameter box (its trim not applied),
      // oriented away from the material as the face is oriented in the file.
      BRepAdaptor_Surface surface(face);
      double u1, u2, v1, v2;
      BRepTools::UVBounds(face, u1, u2, v1, v2);
      double weighted = 0, weight = 0;
      constexpr int kGrid = 17;
      for (int j = 0; j < kGrid; ++j) {
        for (int i = 0; i < kGrid; ++i) {
          gp_Pnt p;
          gp_Vec du, dv;
          surface.D1(u1 + (u2 - u1) * i / (kGrid - 1), v1 + (v2 - v1) * j / (kGrid - 1), p, du, dv);
          gp_Vec n = du.Crossed(dv);
          const double dA = n.Magnitude();
          if (!(dA > 0)) continue;
          if (face.Orientation() == TopAbs_REVERSED) n.Reverse();
          weighted += n.Z();  // = (n_z / |n|) · dA
          weight += dA;
        }
      }
      if (weight > 0) info.mean_normal_z = weighted / weight;
    } catch (const Standard_Failure&) {
      // A face OpenCASCADE cannot measure is still listed; its box, area and normal stay unknown.
    }
  }
  return cad.infos;
}

namespace {

// Q and its trim for face `index` of a loaded file; `chosen` are the faces of the region (the others
// are the trim's neighbours).
Result<CadFace> MakeCadFace(const std::filesystem::path& path, const LoadedCad& cad, int index,
                            const std::vector<int>& chosen, bool reverse = false) {
  TopoDS_Face face = cad.faces[static_cast<std::size_t>(index)];
  CadFace result;
  result.info = cad.infos[static_cast<std::size_t>(index)];
  result.file_unit = cad.file_unit;
  const std::string which =
      "face " + std::to_string(index) + (result.info.name.empty() ? "" : " '" + result.info.name + "'");
  try {
    TopLoc_Location location;
    if (BRep_Tool::Surface(face, location).IsNull()) {
      return Status::BadInput(Where{.file = path.string()}, which + " has no underlying surface",
                              "choose another face");
    }
    if (Handle(Geom_BSplineSurface)::DownCast(BRep_Tool::Surface(face, location)).IsNull()) {
      // Surface and pcurves converted together, so the trimming loops stay valid on Q.
      BRepBuilderAPI_NurbsConvert convert(face, Standard_True);
      face = TopoDS::Face(convert.Shape());
      result.converted = true;
    }
    Handle(Geom_BSplineSurface) bspline = Handle(Geom_BSplineSurface)::DownCast(BRep_Tool::Surface(face));
    if (bspline.IsNull()) {
      return Status::BadInput(
          Where{.file = path.string()},
          which + " of type " + result.info.surface_type + " could not be converted to a B-spline surface",
          "convert the face to a NURBS surface in the CAD system");
    }
    bspline = Handle(Geom_BSplineSurface)::DownCast(bspline->Copy());  // Q must not alias the reader's model
    // Restrict Q to the face's parameter box (exact): the rest of a large underlying patch is never used.
    double u1, u2, v1, v2, bu1, bu2, bv1, bv2;
    BRepTools::UVBounds(face, u1, u2, v1, v2);
    bspline->Bounds(bu1, bu2, bv1, bv2);
    u1 = std::max(u1, bu1), u2 = std::min(u2, bu2), v1 = std::max(v1, bv1), v2 = std::min(v2, bv2);
    const double eu = 1e-9 * (bu2 - bu1), ev = 1e-9 * (bv2 - bv1);
    if (u2 > u1 && v2 > v1 && (u1 > bu1 + eu || u2 < bu2 - eu || v1 > bv1 + ev || v2 < bv2 - ev)) {
      if (bspline->IsUPeriodic()) bspline->SetUNotPeriodic();
      if (bspline->IsVPeriodic()) bspline->SetVNotPeriodic();
      bspline->Segment(u1, u2, v1, v2);
    }
    double u_offset = 0, u_sign = 1;
    if ((face.Orientation() == TopAbs_REVERSED) != reverse) {
      // The face's material side is opposite to S_u × S_v (or the user turned the face over); reverse u
      // so Q's normal points away from the material as the rest of formloop assumes
      // (u_Q = first + last − u_face).
      bspline->Bounds(bu1, bu2, bv1, bv2);
      bspline->UReverse();
      u_offset = bu1 + bu2;
      u_sign = -1;
    }
    result.surface = BSplineSurface(bspline);
    result.face = face;
    std::vector<TopoDS_Face> neighbours;
    for (std::size_t k = 0; k < cad.faces.size(); ++k) {
      if (std::find(chosen.begin(), chosen.end(), static_cast<int>(k)) == chosen.end()) {
        neighbours.push_back(cad.faces[k]);
      }
    }
    auto trim = Trim::OfFace(face, result.surface, u_offset, u_sign, std::move(neighbours));
    if (!trim.ok()) return Status::BadInput(Where{.file = path.string()}, which + ": " + trim.status().message());
    if (!(*trim)->natural() || (*trim)->has_neighbours()) result.surface.set_trim(*trim);
  } catch (const Standard_Failure& failure) {
    return Status::BadInput(Where{.file = path.string()},
                            "OpenCASCADE failed while converting " + which + ": " + occt::Message(failure));
  }
  return result;
}

}  // namespace

Result<CadFace> ReadCadFace(const std::filesystem::path& path, const CadFaceSelector& selector) {
  FL_ASSIGN_OR_RETURN(LoadedCad cad, Load(path));
  FL_ASSIGN_OR_RETURN(const int index, ChooseFace(path, cad.infos, selector));
  return MakeCadFace(path, cad, index, {index}, selector.reverse);
}

Result<std::vector<CadFace>> ReadCadFaces(const std::filesystem::path& path, const CadRegionSelector& selector) {
  const bool by_name = !selector.names.empty();
  const std::string field = by_name ? "face_names" : "faces";
  if (selector.indices.empty() && selector.names.empty()) {
    return Status::BadInput(Where{.file = path.string(), .field = "faces"}, "no face chosen",
                            "give \"faces\": [indices] or \"face_names\": [names]");
  }
  if (!selector.indices.empty() && by_name) {
    return Status::BadInput(Where{.file = path.string(), .field = "faces"},
                            "both face indices and face names are given", "give one of the two");
  }
  FL_ASSIGN_OR_RETURN(LoadedCad cad, Load(path));
  std::vector<int> chosen;
  const std::size_t count = by_name ? selector.names.size() : selector.indices.size();
  for (std::size_t k = 0; k < count; ++k) {
    CadFaceSelector one;
    if (by_name) {
      one.name = selector.names[k];
    } else {
      one.index = selector.indices[k];
      if (one.index < 0) {
        return Status::BadInput(Where{.file = path.string(), .field = field + "[" + std::to_string(k) + "]"},
                                "face index " + std::to_string(one.index) + " is negative", "use 0-based indices");
      }
    }
    auto index = ChooseFace(path, cad.infos, one);
    if (!index.ok()) {
      return Status::BadInput(FormatWhere(Where{.field = field + "[" + std::to_string(k) + "]"}) +
                              index.status().message());
    }
    if (std::find(chosen.begin(), chosen.end(), *index) != chosen.end()) {
      return Status::BadInput(Where{.file = path.string(), .field = field + "[" + std::to_string(k) + "]"},
                              "face " + std::to_string(*index) + " is chosen twice", "list each face once");
    }
    chosen.push_back(*index);
  }
  std::vector<CadFace> faces;
  for (const int index : chosen) {
    FL_ASSIGN_OR_RETURN(CadFace face, MakeCadFace(path, cad, index, chosen));
    faces.push_back(std::move(face));
  }
  return faces;
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
