// libFuzzer target for the probe-log reader (metrology/probe.h ReadProbeLog). An accepted log must hold finite
// centres within ±kMaxCoordinateMm, unit approach vectors (rescaled by the reader) and no repeated id.

#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <set>

#include "core/point_io.h"
#include "fuzz/fuzz_input.h"
#include "metrology/probe.h"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  const auto path = formloop::fuzz::WriteInput("probe.csv", data, size);
  const auto log = formloop::metrology::ReadProbeLog(path);
  if (!log.ok()) return 0;
  std::set<std::int64_t> ids;
  for (const auto& r : log->records) {
    const bool centre_ok = r.centre.allFinite() && r.centre.cwiseAbs().maxCoeff() <= formloop::kMaxCoordinateMm;
    const bool approach_ok = r.approach.allFinite() && std::abs(r.approach.norm() - 1) <= 1e-12;
    if (!centre_ok || !approach_ok || !std::isfinite(r.t_s) || !ids.insert(r.id).second) {
      std::fprintf(stderr, "accepted a bad record at line %ld (id %lld)\n", r.line, static_cast<long long>(r.id));
      std::abort();
    }
  }
  return 0;
}
