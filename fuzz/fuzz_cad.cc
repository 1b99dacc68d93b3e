// libFuzzer target for CAD import through OpenCASCADE (reconstruction/cad_io.h), one build per format
// (FORMLOOP_FUZZ_EXT "step" or "iges"): the file's faces are listed and the first is read as formloop reads a
// part's surface (unit checks, NURBS conversion, B-spline and trim). Refusing is fine; a crash, a hang or a
// sanitizer report is a finding. An accepted face must have a finite control net.

#include <cmath>
#include <cstdio>
#include <cstdlib>

#include <Geom_BSplineSurface.hxx>

#include "fuzz/fuzz_input.h"
#include "reconstruction/cad_io.h"

// Each read's child has 6 s (reconstruction/cad_io.h's time limit), so listing and reading (12 s) stay well under the
// 20 s that scripts/fuzz.sh gives libFuzzer per input: a reader that is slow under ASan on a loaded machine, or loops,
// ends as a refused file (as `formloop fit` reports it), not as a libFuzzer time-out. A hang in formloop's own code is
// still one.
extern "C" int LLVMFuzzerInitialize(int*, char***) {
  formloop::recon::SetCadReadTimeoutSeconds(6.0);
  return 0;
}

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  const auto path = formloop::fuzz::WriteInput(std::string("part.") + FORMLOOP_FUZZ_EXT, data, size);
  const auto faces = formloop::recon::ListCadFaces(path);
  if (!faces.ok() || faces->empty()) return 0;
  const auto face = formloop::recon::ReadCadFace(path, formloop::recon::CadFaceSelector{.index = 0, .name = ""});
  if (!face.ok()) return 0;
  const auto& geom = face->surface.geom();
  if (!face->surface.valid()) {
    std::fprintf(stderr, "accepted a face without a surface\n");
    std::abort();
  }
  for (int i = 1; i <= geom->NbUPoles(); ++i) {
    for (int j = 1; j <= geom->NbVPoles(); ++j) {
      const gp_Pnt p = geom->Pole(i, j);
      if (!std::isfinite(p.X()) || !std::isfinite(p.Y()) || !std::isfinite(p.Z())) {
        std::fprintf(stderr, "accepted a face with a pole that is not finite (%d, %d)\n", i, j);
        std::abort();
      }
    }
  }
  return 0;
}
