// libFuzzer target for the point-file readers (core/point_io.h), one build per format: FORMLOOP_FUZZ_EXT is the
// extension ReadPoints dispatches on ("csv", "xyz", "ply", "pcd"). Beyond not crashing, a point set the reader
// accepts must be what the readers promise: valid (finite, consistent sizes) and within ±kMaxCoordinateMm.

#include <cmath>
#include <cstdio>
#include <cstdlib>

#include "core/point_io.h"
#include "fuzz/fuzz_input.h"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  const auto path = formloop::fuzz::WriteInput(std::string("points.") + FORMLOOP_FUZZ_EXT, data, size);
  const auto points = formloop::ReadPoints(path);
  if (!points.ok()) return 0;
  if (const auto valid = points->Validate(path.string()); !valid.ok()) {
    std::fprintf(stderr, "accepted an invalid point set: %s\n", valid.ToString().c_str());
    std::abort();
  }
  for (const auto& p : points->points) {
    if (!(p.cwiseAbs().maxCoeff() <= formloop::kMaxCoordinateMm)) {
      std::fprintf(stderr, "accepted a coordinate beyond the limit: %g %g %g\n", p.x(), p.y(), p.z());
      std::abort();
    }
  }
  return 0;
}
