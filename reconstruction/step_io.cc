// STEP export and import of the ideal surface Q (spec/reconstruction.md §1).
//
// OpenCASCADE notes:
// - The STEP translators print banners through Message::DefaultMessenger(), whose default printer
//   writes to std::cout. formloop keeps stdout for machine-readable output, so the first use
//   replaces that printer with one on std::cerr that only passes failures.
// - Interface_Static parameters are process-wide; "write.step.unit" is set to MM on every write.
// - Reals are written with 12 digits after the point in fixed notation for |x| in [0.1, 1000) and as
//   %.12E otherwise (Interface_FloatWriter defaults), which keeps poles far below 1e-9 mm.
// - The reader converts lengths from the file's unit to the session unit "xstep.cascade.unit",
//   which is MM by default.

#include <TopExp_Explorer.hxx>
#include <TopoDS.hxx>
#include <TopoDS_Face.hxx>
#include <TopoDS_Shape.hxx>

#include <APIHeaderSection_MakeHeader.hxx>
#include <BRepBuilderAPI_MakeFace.hxx>
#include <BRepTools.hxx>
#include <BRep_Tool.hxx>
#include <GeomConvert.hxx>
#include <Geom_RectangularTrimmedSurface.hxx>
#include <IFSelect_ReturnStatus.hxx>
#include <Interface_InterfaceModel.hxx>
#include <Interface_Static.hxx>
#include <StepBasic_Product.hxx>
#include <Message.hxx>
#include <Message_Messenger.hxx>
#include <Message_PrinterOStream.hxx>
#include <Precision.hxx>
#include <STEPControl_Reader.hxx>
#include <STEPControl_Writer.hxx>
#include <Standard_Failure.hxx>
#include <StepData_StepModel.hxx>
#include <TCollection_HAsciiString.hxx>

#include <mutex>
#include <system_error>

#include "core/atomic_file.h"
#include "reconstruction/bspline_surface.h"

namespace formloop::recon {
namespace {

void KeepStdoutClean() {
  static std::once_flag once;
  std::call_once(once, [] {
    const Handle(Message_Messenger)& messenger = Message::DefaultMessenger();
    messenger->RemovePrinters(STANDARD_TYPE(Message_PrinterOStream));
    messenger->AddPrinter(new Message_PrinterOStream("cerr", Standard_False, Message_Fail));
  });
}

std::string OcctMessage(const Standard_Failure& failure) {
  const char* text = failure.GetMessageString();
  std::string message = failure.DynamicType()->Name();
  if (text != nullptr && *text != '\0') message += ": " + std::string(text);
  return message;
}

}  // namespace

Status WriteStep(const std::filesystem::path& path, const BSplineSurface& surface, const std::string& name) {
  const std::string where = "writing STEP '" + path.string() + "'";
  if (!surface.valid()) return Status::Internal(where + ": the surface is empty");
  KeepStdoutClean();
  // The temporary file is created (and removed on failure) by AtomicFile; OpenCASCADE writes it by
  // name. The AtomicFile stream stays open and empty, so Commit() only flushes nothing and renames.
  AtomicFile file(path);
  FL_RETURN_IF_ERROR(file.open_status());
  try {
    const ParamDomain dom = surface.domain();
    BRepBuilderAPI_MakeFace make_face(surface.geom(), dom.u_min, dom.u_max, dom.v_min, dom.v_max,
                                      Precision::Confusion());
    if (!make_face.IsDone()) {
      return Status::Internal(where + ": BRepBuilderAPI_MakeFace failed (error " +
                              std::to_string(static_cast<int>(make_face.Error())) + ")");
    }
    STEPControl_Writer writer;  // initialises the STEP controller and its static parameters
    Interface_Static::SetCVal("write.step.unit", "MM");
    Interface_Static::SetCVal("write.step.product.name", name.empty() ? "formloop_surface" : name.c_str());
    if (writer.Transfer(make_face.Face(), STEPControl_AsIs) != IFSelect_RetDone) {
      return Status::Internal(where + ": the STEP translator refused the face");
    }
    APIHeaderSection_MakeHeader header(writer.Model());
    header.SetName(new TCollection_HAsciiString(path.filename().string().c_str()));
    header.SetOriginatingSystem(new TCollection_HAsciiString("formloop"));
    // Reproducible files: OpenCASCADE stamps the wall-clock time and numbers products with a
    // process-wide counter ("name 1", "name 2", ...). Both are replaced by fixed values.
    header.SetTimeStamp(new TCollection_HAsciiString("2000-01-01T00:00:00"));
    const Handle(TCollection_HAsciiString) product_name =
        new TCollection_HAsciiString(name.empty() ? "formloop_surface" : name.c_str());
    const Handle(Interface_InterfaceModel) model = writer.Model();
    for (Standard_Integer i = 1; i <= model->NbEntities(); ++i) {
      const Handle(StepBasic_Product) product = Handle(StepBasic_Product)::DownCast(model->Value(i));
      if (product.IsNull()) continue;
      product->SetId(product_name);
      product->SetName(product_name);
    }
    if (writer.Write(file.temp_path().string().c_str()) != IFSelect_RetDone) {
      return Status::IoError(where + ": OpenCASCADE could not write the file. Check that the folder is writable");
    }
  } catch (const Standard_Failure& failure) {
    return Status::Internal(where + ": OpenCASCADE failed: " + OcctMessage(failure));
  }
  return file.Commit();
}

Result<BSplineSurface> ReadStep(const std::filesystem::path& path, int face_index) {
  std::error_code ec;
  if (!std::filesystem::exists(path, ec)) {
    return Status::NotFound("STEP file '" + path.string() + "' does not exist. Check the path");
  }
  if (!std::filesystem::is_regular_file(path, ec)) {
    return Status::BadInput("'" + path.string() + "' is not a regular file, expected a STEP file");
  }
  if (face_index < 0) {
    return Status::BadInput(Where{.file = path.string(), .field = "face_index"},
                            "face index " + std::to_string(face_index) + " is negative", "use a 0-based index");
  }
  KeepStdoutClean();
  try {
    STEPControl_Reader reader;
    if (reader.ReadFile(path.string().c_str()) != IFSelect_RetDone) {
      return Status::BadInput(Where{.file = path.string()}, "OpenCASCADE could not read this as a STEP file",
                              "export the part as STEP AP203/AP214/AP242");
    }
    if (reader.TransferRoots() <= 0) {
      return Status::BadInput(Where{.file = path.string()}, "the STEP file holds no transferable shape",
                              "export the surface or solid as STEP geometry");
    }
    const TopoDS_Shape shape = reader.OneShape();
    int count = 0;
    TopoDS_Face chosen;
    for (TopExp_Explorer it(shape, TopAbs_FACE); it.More(); it.Next(), ++count) {
      if (count == face_index) chosen = TopoDS::Face(it.Current());
    }
    if (count == 0) {
      return Status::BadInput(Where{.file = path.string()}, "the STEP file holds no face",
                              "export a surface or a solid, not only curves or points");
    }
    if (face_index >= count) {
      return Status::BadInput(Where{.file = path.string(), .field = "face_index"},
                              "face index " + std::to_string(face_index) + " is out of range: the file has " +
                                  std::to_string(count) + (count == 1 ? " face" : " faces"),
                              "use an index from 0 to " + std::to_string(count - 1));
    }
    const Handle(Geom_Surface) geom = BRep_Tool::Surface(chosen);  // with the face location applied
    if (geom.IsNull()) {
      return Status::BadInput(Where{.file = path.string()},
                              "face " + std::to_string(face_index) + " has no underlying surface");
    }
    Handle(Geom_BSplineSurface) bspline = Handle(Geom_BSplineSurface)::DownCast(geom);
    if (bspline.IsNull()) {
      // Trim to the face's parameter box so unbounded surfaces (planes, cylinders) convert.
      double u1, u2, v1, v2;
      BRepTools::UVBounds(chosen, u1, u2, v1, v2);
      Handle(Geom_Surface) trimmed = geom;
      if (!geom->IsKind(STANDARD_TYPE(Geom_RectangularTrimmedSurface))) {
        trimmed = new Geom_RectangularTrimmedSurface(geom, u1, u2, v1, v2);
      }
      bspline = GeomConvert::SurfaceToBSplineSurface(trimmed);
      if (bspline.IsNull()) {
        return Status::BadInput(Where{.file = path.string()},
                                "face " + std::to_string(face_index) + " of type " + geom->DynamicType()->Name() +
                                    " could not be converted to a B-spline surface");
      }
    }
    return BSplineSurface(bspline);
  } catch (const Standard_Failure& failure) {
    return Status::BadInput(Where{.file = path.string()}, "OpenCASCADE failed while reading: " + OcctMessage(failure));
  }
}

}  // namespace formloop::recon
