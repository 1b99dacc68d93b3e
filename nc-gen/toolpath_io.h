#pragma once
// The tool-path file: the machine-independent result of planning (spec/nc-gen.md §1–2), so that
// planning, posting for a controller and compensating are separate steps (`formloop nc path
// --toolpath`, `nc post`, `nc compensate`).
//
// CSV, one row per CL point in cutting order, every number in its shortest exact text, so a path read
// back posts byte-identically to the planned one:
//   # formloop tool path: ...
//   # options: {"tool": {...}, "scallop_um": ..., "raster_angle_deg": ..., ...}   (ToolpathOptionsJson)
//   # summary: {"passes": ..., "step_over_mm": {"min": ..., "max": ...}, "gouge_risk_points": ...[, "min_safe_z_mm":
//   ...]} pass,kind,u,v,cc_x,cc_y,cc_z,nx,ny,nz,lift_mm
// kind = cut | lead-in | lead-out. Centres, tips, lengths, times and safe Z are recomputed on reading
// (UpdateCutterLocations); the lifted-region summary is rebuilt from lift_mm.

#include <filesystem>
#include <string>

#include <nlohmann/json.hpp>

#include "core/status.h"
#include "nc-gen/toolpath.h"

namespace formloop::nc {

nlohmann::json ToolpathOptionsJson(const ToolpathOptions& options);
// Reads the members present in `json` over the defaults in *options; unknown keys and bad values are
// BadInput naming `source` and the key. Validates the result.
Status ReadToolpathOptions(const nlohmann::json& json, const std::string& source, ToolpathOptions* options);

const char* ClKindName(ClKind kind);

Status WriteToolpathFile(const std::filesystem::path& path, const Toolpath& toolpath);
Result<Toolpath> ReadToolpathFile(const std::filesystem::path& path);
// The same from text; `source` names it in messages.
Result<Toolpath> ParseToolpath(const std::string& text, const std::string& source);

}  // namespace formloop::nc
