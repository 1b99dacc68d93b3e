// STEP export of the ideal surface Q (spec/reconstruction.md §1); reading is in cad_io.cc.
//
// OpenCASCADE notes:
// - Interface_Static parameters are process-wide; "write.step.unit" is set to MM on every write.
//   (It only labels the file: the numbers are written as they are, in mm.)
// - Reals are written with 12 digits after the point in fixed notation for |x| in [0.1, 1000) and as
//   %.12E otherwise (Interface_FloatWriter defaults), which keeps poles far below 1e-9 mm.

#include <APIHeaderSection_MakeHeader.hxx>
#include <BRepBuilderAPI_MakeFace.hxx>
#include <IFSelect_ReturnStatus.hxx>
#include <Interface_InterfaceModel.hxx>
#include <Interface_Static.hxx>
#include <Precision.hxx>
#include <STEPControl_Writer.hxx>
#include <Standard_Failure.hxx>
#include <StepBasic_Product.hxx>
#include <StepData_StepModel.hxx>
#include <StepRepr_RepresentationItem.hxx>
#include <StepShape_AdvancedFace.hxx>
#include <TCollection_HAsciiString.hxx>
#include <TopoDS_Face.hxx>

#include "core/atomic_file.h"
#include "reconstruction/bspline_surface.h"
#include "reconstruction/occt_support.h"
#include "reconstruction/trim.h"

namespace formloop::recon {

Status WriteStep(const std::filesystem::path& path, const BSplineSurface& surface, const std::string& name) {
  const std::string where = "writing STEP '" + path.string() + "'";
  if (!surface.valid()) return Status::Internal(where + ": the surface is empty");
  occt::KeepStdoutClean();
  // The temporary file is created (and removed on failure) by AtomicFile; OpenCASCADE writes it by
  // name. The AtomicFile stream stays open and empty, so Commit() only flushes nothing and renames.
  AtomicFile file(path);
  FL_RETURN_IF_ERROR(file.open_status());
  try {
    const ParamDomain dom = surface.domain();
    TopoDS_Face face;
    if (surface.trim() != nullptr && !surface.trim()->natural()) {
      face = surface.trim()->face();  // the trimmed face as it was read (or built on Q)
    } else {
      BRepBuilderAPI_MakeFace make_face(surface.geom(), dom.u_min, dom.u_max, dom.v_min, dom.v_max,
                                        Precision::Confusion());
      if (!make_face.IsDone()) {
        return Status::Internal(where + ": BRepBuilderAPI_MakeFace failed (error " +
                                std::to_string(static_cast<int>(make_face.Error())) + ")");
      }
      face = make_face.Face();
    }
    STEPControl_Writer writer;  // initialises the STEP controller and its static parameters
    Interface_Static::SetCVal("write.step.unit", "MM");
    Interface_Static::SetCVal("write.step.product.name", name.empty() ? "formloop_surface" : name.c_str());
    if (writer.Transfer(face, STEPControl_AsIs) != IFSelect_RetDone) {
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
      const Handle(Standard_Transient) entity = model->Value(i);
      if (const Handle(StepBasic_Product) product = Handle(StepBasic_Product)::DownCast(entity); !product.IsNull()) {
        product->SetId(product_name);
        product->SetName(product_name);
      }
      // The face carries the name too, so `formloop fit Q.step --face NAME` finds it.
      if (const Handle(StepShape_AdvancedFace) advanced = Handle(StepShape_AdvancedFace)::DownCast(entity);
          !advanced.IsNull()) {
        advanced->SetName(product_name);
      }
    }
    if (writer.Write(file.temp_path().string().c_str()) != IFSelect_RetDone) {
      return Status::IoError(where + ": OpenCASCADE could not write the file. Check that the folder is writable");
    }
  } catch (const Standard_Failure& failure) {
    return Status::Internal(where + ": OpenCASCADE failed: " + occt::Message(failure));
  }
  return file.Commit();
}

}  // namespace formloop::recon
