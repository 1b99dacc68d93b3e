#pragma once
// Case-library jobs shared by `formloop kb` and `formloop regress`.

#include <filesystem>
#include <string>

#include <nlohmann/json.hpp>

#include "core/status.h"
#include "retrieval/ghsom.h"

namespace formloop::app {

// Fills an empty library at `path` with the starter cases (data_dir/starter/families.json), writes the
// starter rule base (data_dir/starter/rules.json) and trains the GHSOM with `ghsom`. Returns the report
// `kb init --starter` prints.
Result<nlohmann::json> FillStarterLibrary(const std::string& path, const std::filesystem::path& data_dir,
                                          const retrieval::GhsomOptions& ghsom);

// InitLibrary + FillStarterLibrary with the library defaults (retrieval::LibraryGhsomDefaults).
Result<nlohmann::json> CreateStarterLibrary(const std::string& path, const std::filesystem::path& data_dir);

}  // namespace formloop::app
