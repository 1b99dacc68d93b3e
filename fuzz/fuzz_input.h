#pragma once
// What every fuzz target shares: the readers take paths, so each input is written to one file per target
// and process (in $TMPDIR, replaced on every input, removed at exit) and read back through the real reader.
// Logging is off: a reader's warnings are not findings, and stderr belongs to libFuzzer's reports.

#include <cstddef>
#include <cstdint>
#include <filesystem>
#include <string>

namespace formloop::fuzz {

// Writes `data` to the process's input file for `name` (e.g. "points.csv": the extension is what the
// reader dispatches on) and returns its path. Aborts when the file cannot be written (a broken harness,
// not a finding).
std::filesystem::path WriteInput(const std::string& name, const std::uint8_t* data, std::size_t size);

}  // namespace formloop::fuzz
