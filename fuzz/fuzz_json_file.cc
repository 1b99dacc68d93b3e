// libFuzzer target for formloop's JSON file readers, one build per kind (FORMLOOP_FUZZ_KIND):
//   1 part file (app/part.h ReadPart), 2 effect model (simulation/model.h ReadModel),
//   3 case file (kb/library.h ReadCaseFile).
// Each input goes through the real reader (the JSON parse, the fields, their checks). Refusing is fine; a crash,
// a hang, a sanitizer report or an uncaught exception is a finding.

#include "fuzz/fuzz_input.h"

#if FORMLOOP_FUZZ_KIND == 1
#include "app/part.h"
#elif FORMLOOP_FUZZ_KIND == 2
#include "simulation/model.h"
#elif FORMLOOP_FUZZ_KIND == 3
#include "kb/library.h"
#endif

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
#if FORMLOOP_FUZZ_KIND == 1
  const auto path = formloop::fuzz::WriteInput("part.json", data, size);
  (void)formloop::app::ReadPart(path);
#elif FORMLOOP_FUZZ_KIND == 2
  const auto path = formloop::fuzz::WriteInput("model.json", data, size);
  (void)formloop::sim::ReadModel(path);
#elif FORMLOOP_FUZZ_KIND == 3
  const auto path = formloop::fuzz::WriteInput("case.json", data, size);
  (void)formloop::kb::ReadCaseFile(path);
#else
#error "FORMLOOP_FUZZ_KIND must be 1, 2 or 3"
#endif
  return 0;
}
