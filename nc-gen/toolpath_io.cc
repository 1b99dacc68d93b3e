#include "nc-gen/toolpath_io.h"

#include <algorithm>
#include <charconv>
#include <cmath>
#include <map>
#include <string_view>
#include <vector>

#include "core/atomic_file.h"
#include "core/csv.h"
#include "core/json_io.h"
#include "core/number_text.h"
#include "core/point_io.h"

namespace formloop::nc {
namespace {

constexpr const char* kColumns[] = {"pass", "kind", "u", "v", "cc_x", "cc_y", "cc_z", "nx", "ny", "nz", "lift_mm"};
constexpr const char* kOptionsPrefix = "# options: ";
constexpr const char* kSummaryPrefix = "# summary: ";

}  // namespace

const char* ClKindName(ClKind kind) {
  switch (kind) {
    case ClKind::kLeadIn:
      return "lead-in";
    case ClKind::kLeadOut:
      return "lead-out";
    case ClKind::kOff:
      return "off";
    case ClKind::kCut:
      break;
  }
  return "cut";
}

nlohmann::json ToolpathOptionsJson(const ToolpathOptions& o) {
  return {{"tool", {{"number", o.tool.number}, {"radius_mm", o.tool.radius_mm}}},
          {"scallop_um", o.scallop_um},
          {"chord_tolerance_um", o.chord_tolerance_um},
          {"max_point_spacing_mm", o.max_point_spacing_mm},
          {"raster_angle_deg", o.raster_angle_deg},
          {"zigzag", o.zigzag},
          {"lead_mm", o.lead_mm},
          {"feed_mm_per_min", o.feed_mm_per_min},
          {"plunge_feed_mm_per_min", o.plunge_feed_mm_per_min},
          {"spindle_rpm", o.spindle_rpm},
          {"clearance_mm", o.clearance_mm}};
}

Status ReadToolpathOptions(const nlohmann::json& json, const std::string& source, ToolpathOptions* o) {
  if (!json.is_object()) return Status::BadInput(Where{.file = source}, "the tool-path options are not a JSON object");
  JsonFields f(json, source);
  FL_RETURN_IF_ERROR(
      f.CheckKnown({"tool", "scallop_um", "chord_tolerance_um", "max_point_spacing_mm", "raster_angle_deg", "zigzag",
                    "lead_mm", "feed_mm_per_min", "plunge_feed_mm_per_min", "spindle_rpm", "clearance_mm"}));
  std::optional<JsonFields> tool;
  FL_RETURN_IF_ERROR(f.Object("tool", &tool));
  if (tool) {
    FL_RETURN_IF_ERROR(tool->CheckKnown({"number", "radius_mm"}));
    long long number = o->tool.number;
    FL_RETURN_IF_ERROR(tool->OptionalInteger("number", &number, 1, 9999));
    o->tool.number = static_cast<int>(number);
    FL_RETURN_IF_ERROR(tool->OptionalNumber("radius_mm", &o->tool.radius_mm));
  }
  FL_RETURN_IF_ERROR(f.OptionalNumber("scallop_um", &o->scallop_um));
  FL_RETURN_IF_ERROR(f.OptionalNumber("chord_tolerance_um", &o->chord_tolerance_um));
  FL_RETURN_IF_ERROR(f.OptionalNumber("max_point_spacing_mm", &o->max_point_spacing_mm));
  FL_RETURN_IF_ERROR(f.OptionalNumber("raster_angle_deg", &o->raster_angle_deg));
  FL_RETURN_IF_ERROR(f.OptionalBool("zigzag", &o->zigzag));
  FL_RETURN_IF_ERROR(f.OptionalNumber("lead_mm", &o->lead_mm));
  FL_RETURN_IF_ERROR(f.OptionalNumber("feed_mm_per_min", &o->feed_mm_per_min));
  FL_RETURN_IF_ERROR(f.OptionalNumber("plunge_feed_mm_per_min", &o->plunge_feed_mm_per_min));
  FL_RETURN_IF_ERROR(f.OptionalNumber("spindle_rpm", &o->spindle_rpm));
  FL_RETURN_IF_ERROR(f.OptionalNumber("clearance_mm", &o->clearance_mm));
  if (Status s = o->Validate(); !s.ok()) return Status::BadInput(source + ": " + s.message());
  return Status::Ok();
}

Status WriteToolpathFile(const std::filesystem::path& path, const Toolpath& t) {
  std::string text =
      "# formloop tool path (spec/nc-gen.md): one row per CL point in cutting order; cc = cutter-contact point "
      "on Q (leads: the tip), n = Q's unit normal (leads: z), lift along the tool axis\n";
  text += kOptionsPrefix + ToolpathOptionsJson(t.options).dump() + "\n";
  nlohmann::json summary = {{"passes", t.passes},
                            {"step_over_mm", {{"min", t.min_step_over_mm}, {"max", t.max_step_over_mm}}},
                            {"gouge_risk_points", t.gouge_risk_points}};
  // Beside neighbouring faces: the lowest safe Z they allow (kept so a path read back retracts as high).
  if (std::isfinite(t.min_safe_z_mm)) summary["min_safe_z_mm"] = t.min_safe_z_mm;
  text += kSummaryPrefix + summary.dump() + "\n";
  text += "pass,kind,u,v,cc_x,cc_y,cc_z,nx,ny,nz,lift_mm\n";
  // Streamed in blocks into the temporary file: a million-point path is ~170 MB of text, never held whole.
  AtomicFile file(path);
  FL_RETURN_IF_ERROR(file.open_status());
  const auto number = [&text](double value) {
    char buffer[32];
    const auto result = std::to_chars(buffer, buffer + sizeof(buffer), value);
    text += ',';
    text.append(buffer, result.ptr);
  };
  for (const ClPoint& cl : t.points) {
    if (text.size() > (1 << 16)) {
      file.stream() << text;
      text.clear();
    }
    text += std::to_string(cl.pass);
    text += ',';
    text += ClKindName(cl.kind);
    number(cl.u);
    number(cl.v);
    for (int a = 0; a < 3; ++a) number(cl.cc[a]);
    for (int a = 0; a < 3; ++a) number(cl.normal[a]);
    number(cl.lift_mm);
    text += '\n';
  }
  file.stream() << text;
  return file.Commit();
}

Result<Toolpath> ParseToolpath(const std::string& text, const std::string& source) {
  Toolpath t;
  CsvReader rows(text, /*comments=*/true);
  long number = 0;
  bool have_options = false;
  std::map<std::string, std::size_t> column;
  std::size_t columns = 0;
  int last_pass = -1;
  // The column of each of kColumns, looked up once (a million rows); the cells are views into the text.
  enum Column { kPass, kKind, kU, kV, kCcX, kCcY, kCcZ, kNx, kNy, kNz, kLift, kColumnCount };
  std::size_t at[kColumnCount] = {};
  // At most one point a line: no regrowth of a million points (and no second copy of them at its peak).
  t.points.reserve(static_cast<std::size_t>(std::count(text.begin(), text.end(), '\n')) + 1);
  while (rows.Next()) {
    number = rows.line_number();
    if (rows.is_comment()) {
      const std::string s(rows.line());
      const auto json_after = [&](const char* prefix) -> Result<nlohmann::json> {
        return ParseJson(s.substr(std::string(prefix).size()), source + ":" + std::to_string(number));
      };
      if (s.rfind(kOptionsPrefix, 0) == 0) {
        FL_ASSIGN_OR_RETURN(nlohmann::json json, json_after(kOptionsPrefix));
        FL_RETURN_IF_ERROR(ReadToolpathOptions(json, source + ":" + std::to_string(number), &t.options));
        have_options = true;
      } else if (s.rfind(kSummaryPrefix, 0) == 0) {
        FL_ASSIGN_OR_RETURN(nlohmann::json json, json_after(kSummaryPrefix));
        t.min_step_over_mm = json.value("/step_over_mm/min"_json_pointer, 0.0);
        t.max_step_over_mm = json.value("/step_over_mm/max"_json_pointer, 0.0);
        t.gouge_risk_points = json.value("gouge_risk_points", 0);
        if (json.contains("min_safe_z_mm") && json["min_safe_z_mm"].is_number()) {
          t.min_safe_z_mm = json["min_safe_z_mm"].get<double>();
        }
      }
      continue;
    }
    const std::vector<std::string_view>& cells = rows.cells();
    if (columns == 0) {
      for (std::size_t c = 0; c < cells.size(); ++c) column[std::string(cells[c])] = c;
      for (const char* name : kColumns) {
        if (!column.count(name)) {
          return Status::BadInput(Where{.file = source, .line = number, .field = name}, "the header lacks this column",
                                  "use a tool-path file written by `formloop nc path --toolpath`");
        }
      }
      for (int c = 0; c < kColumnCount; ++c) at[c] = column.at(kColumns[c]);  // Column follows kColumns
      columns = cells.size();
      continue;
    }
    if (cells.size() != columns) {
      return Status::BadInput(Where{.file = source, .line = number},
                              "has " + std::to_string(cells.size()) + " fields, the header " + std::to_string(columns));
    }
    const auto num = [&](Column c, const char* name, double* out) -> Status {
      if (!ParseDouble(cells[at[c]], out) || !std::isfinite(*out)) {
        return Status::BadInput(Where{.file = source, .line = number, .field = name},
                                "value '" + std::string(cells[at[c]]) + "' is not a finite number");
      }
      return Status::Ok();
    };
    ClPoint cl;
    double pass = 0;
    FL_RETURN_IF_ERROR(num(kPass, "pass", &pass));
    if (pass != std::floor(pass) || pass < 0 || pass < last_pass || pass > last_pass + 1) {
      return Status::BadInput(Where{.file = source, .line = number, .field = "pass"},
                              "value '" + std::string(cells[at[kPass]]) + "' breaks the order of passes",
                              "passes are numbered from 0 and appear in order");
    }
    cl.pass = static_cast<int>(pass);
    const std::string_view kind = cells[at[kKind]];
    if (kind == "lead-in") {
      cl.kind = ClKind::kLeadIn;
    } else if (kind == "lead-out") {
      cl.kind = ClKind::kLeadOut;
    } else if (kind != "cut") {
      return Status::BadInput(Where{.file = source, .line = number, .field = "kind"},
                              "value '" + std::string(kind) + "' is not cut, lead-in or lead-out");
    }
    FL_RETURN_IF_ERROR(num(kU, "u", &cl.u));
    FL_RETURN_IF_ERROR(num(kV, "v", &cl.v));
    FL_RETURN_IF_ERROR(num(kCcX, "cc_x", &cl.cc.x()));
    FL_RETURN_IF_ERROR(num(kCcY, "cc_y", &cl.cc.y()));
    FL_RETURN_IF_ERROR(num(kCcZ, "cc_z", &cl.cc.z()));
    FL_RETURN_IF_ERROR(num(kNx, "nx", &cl.normal.x()));
    FL_RETURN_IF_ERROR(num(kNy, "ny", &cl.normal.y()));
    FL_RETURN_IF_ERROR(num(kNz, "nz", &cl.normal.z()));
    FL_RETURN_IF_ERROR(num(kLift, "lift_mm", &cl.lift_mm));
    if (std::abs(cl.normal.norm() - 1) > 1e-9) {
      return Status::BadInput(Where{.file = source, .line = number, .field = "nx"},
                              "the normal (nx, ny, nz) is not a unit vector");
    }
    if (cl.lift_mm < 0 || cl.lift_mm > kMaxCoordinateMm) {
      return Status::BadInput(Where{.file = source, .line = number, .field = "lift_mm"}, "must be >= 0 and plausible");
    }
    FL_RETURN_IF_ERROR(CheckCoordinateRange(cl.cc, Where{.file = source, .line = number}));
    cl.index_in_pass = (cl.pass == last_pass) ? t.points.back().index_in_pass + 1 : 0;
    last_pass = cl.pass;
    t.points.push_back(cl);
  }
  if (!have_options) {
    return Status::BadInput(Where{.file = source}, "no '# options:' line",
                            "use a tool-path file written by `formloop nc path --toolpath`");
  }
  if (columns == 0) return Status::BadInput(Where{.file = source}, "no header row");
  if (t.points.empty()) return Status::BadInput(Where{.file = source}, "no CL points");
  t.passes = last_pass + 1;
  SummariseLifted(&t);
  UpdateCutterLocations(&t);
  return t;
}

Result<Toolpath> ReadToolpathFile(const std::filesystem::path& path) {
  FL_ASSIGN_OR_RETURN(std::string text, ReadTextFile(path));
  return ParseToolpath(text, path.string());
}

}  // namespace formloop::nc
