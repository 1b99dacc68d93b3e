// libFuzzer target for the G-code reader (nc-gen/gcode_reader.h ReadProgramPath). The first byte chooses the
// dialect (LinuxCNC, Fanuc, Sinumerik), how numbers without a point read and the block-delete switch; the rest is
// the program text. An accepted program's moves must be finite where known (a coordinate, arc or feed that
// overflowed to inf/NaN is a silent wrong result).

#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <string_view>

#include "nc-gen/gcode_reader.h"

namespace nc = formloop::nc;

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  if (size == 0) return 0;
  nc::ReaderOptions options;
  options.dialect = static_cast<nc::GcodeDialect>(data[0] % 3);
  options.no_point = static_cast<nc::NoPointUnit>((data[0] / 3) % 3);
  options.block_delete = (data[0] / 9) % 2 == 1;
  options.caller_m_codes = {57, 58, 59};
  const std::string_view text(reinterpret_cast<const char*>(data + 1), size - 1);
  const auto path = nc::ReadProgramPath(text, options, "fuzz.nc");
  if (!path.ok()) return 0;
  for (const auto& m : path->moves) {
    // Axes the program has not set yet are unknown (NaN by design, start_known / end_known clear).
    bool finite = std::isfinite(m.feed);
    for (int a = 0; a < 3; ++a) {
      if ((m.start_known >> a) & 1u) finite = finite && std::isfinite(m.start[a]);
      if ((m.end_known >> a) & 1u) finite = finite && std::isfinite(m.end[a]);
    }
    if (m.has_arc) {
      finite = finite && std::isfinite(m.arc.radius_start) && std::isfinite(m.arc.radius_end) &&
               std::isfinite(m.arc.sweep_rad);
    }
    if (!finite) {
      std::fprintf(stderr, "accepted a move that is not finite on line %ld\n", m.line);
      std::abort();
    }
  }
  return 0;
}
