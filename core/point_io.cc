// Points as text and the format dispatch (core/point_io.h): the CSV and XYZ readers and writers, the
// text helpers they share with the PLY reader and writer (point_io_text.h; PLY in point_io_ply.cc, PCD
// in point_io_pcd.cc), the coordinate range check and the choice of format from the file name.

#include "core/point_io.h"

#include <algorithm>
#include <array>
#include <bit>
#include <cctype>
#include <charconv>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <limits>
#include <string_view>
#include <system_error>
#include <utility>
#include <vector>

#include "core/atomic_file.h"
#include "core/csv.h"
#include "core/log.h"
#include "core/number_text.h"
#include "core/point_io_text.h"

namespace formloop {
namespace point_io_text {

// Quotes a value for a message, shortened so that a binary blob does not flood the terminal.
std::string Quote(std::string_view text) {
  constexpr std::size_t kMax = 40;
  if (text.size() <= kMax) return "'" + std::string(text) + "'";
  return "'" + std::string(text.substr(0, kMax)) + "...'";
}

void SplitWhitespace(std::string_view line, std::vector<std::string_view>* tokens) {
  tokens->clear();
  std::size_t pos = 0;
  while (true) {
    pos = line.find_first_not_of(" \t\r\f\v", pos);
    if (pos == std::string_view::npos) return;
    std::size_t end = line.find_first_of(" \t\r\f\v", pos);
    if (end == std::string_view::npos) end = line.size();
    tokens->push_back(line.substr(pos, end - pos));
    pos = end;
  }
}

std::string JoinNames(const std::vector<std::string>& names) {
  std::string out;
  for (const auto& name : names) {
    if (!out.empty()) out += ", ";
    out += name;
  }
  return out;
}

// Parses a numeric field of a text file; rejects non-numbers and NaN/inf. The Where is only built
// on error (this runs once per value).
Status ParseNumberField(std::string_view text, const std::string& file, long line, const std::string& field,
                        double* value) {
  if (!text.empty() && ParseDouble(text, value) && std::isfinite(*value)) return Status::Ok();
  const Where where{.file = file, .line = line, .field = field};
  if (text.empty()) {
    return Status::BadInput(where, "value is empty", "write a number in every column of every row");
  }
  if (NumberBeyondDoubleRange(text)) {
    return Status::BadInput(where, "value " + Quote(text) + " is beyond the range of a double (1e-308 to 1e308)",
                            "check the value and its unit");
  }
  if (!ParseDouble(text, value)) {
    return Status::BadInput(where, "value " + Quote(text) + " is not a number",
                            "write a decimal number with a '.' decimal point and no thousands separator, "
                            "such as -12.375");
  }
  return Status::BadInput(where, "value " + Quote(text) + " is not finite (NaN or infinity)",
                          "replace it with a measured value or delete the point");
}

Status ParseIdField(std::string_view text, const std::string& file, long line, const std::string& field,
                    std::int64_t* id) {
  std::string_view digits = text;
  bool plus = false;
  if (!digits.empty() && digits.front() == '+') {
    digits.remove_prefix(1);
    plus = true;
  }
  if (!digits.empty() && !(plus && (digits.front() == '-' || digits.front() == '+'))) {
    const auto [ptr, ec] = std::from_chars(digits.data(), digits.data() + digits.size(), *id);
    if (ec == std::errc() && ptr == digits.data() + digits.size()) return Status::Ok();
    if (ec == std::errc::result_out_of_range && ptr == digits.data() + digits.size()) {
      return Status::BadInput(Where{.file = file, .line = line, .field = field},
                              "id " + Quote(text) + " does not fit in a 64-bit integer",
                              "use ids between -9223372036854775808 and 9223372036854775807");
    }
  }
  return Status::BadInput(Where{.file = file, .line = line, .field = field},
                          "value " + Quote(text) + " is not an integer id",
                          "write ids as whole numbers such as 17, or rename the column if it is not an id");
}

// Checks that a double read from a binary or float-typed field is a whole number usable as an id.
bool DoubleToId(double value, std::int64_t* id) {
  if (!std::isfinite(value) || std::floor(value) != value) return false;
  if (value < -0x1p63 || value >= 0x1p63) return false;
  *id = static_cast<std::int64_t>(value);
  return true;
}

namespace {

Role RoleOf(std::string_view name) {
  if (name == "x") return Role::kX;
  if (name == "y") return Role::kY;
  if (name == "z") return Role::kZ;
  if (name == "nx") return Role::kNx;
  if (name == "ny") return Role::kNy;
  if (name == "nz") return Role::kNz;
  if (name == "id") return Role::kId;
  if (name == "t") return Role::kT;
  return Role::kScalar;
}

}  // namespace

Status MakeColumnPlan(const std::vector<std::string>& names, const Where& where, const std::string& what_columns,
                      ColumnPlan* plan) {
  plan->roles.clear();
  plan->scalar_index.clear();
  plan->scalar_names.clear();
  std::array<bool, 8> seen{};
  for (std::size_t i = 0; i < names.size(); ++i) {
    const std::string& name = names[i];
    Where at = where;
    at.field = name;
    if (name.empty()) {
      at.field = "column " + std::to_string(i + 1);
      return Status::BadInput(at, "the " + what_columns + " name is empty", "give every column a name");
    }
    for (std::size_t j = 0; j < i; ++j) {
      if (names[j] == name) {
        return Status::BadInput(at, "the " + what_columns + " name appears twice",
                                "rename or remove one of the two columns");
      }
    }
    const Role role = RoleOf(name);
    plan->roles.push_back(role);
    if (role == Role::kScalar) {
      plan->scalar_index.push_back(static_cast<int>(plan->scalar_names.size()));
      plan->scalar_names.push_back(name);
    } else {
      plan->scalar_index.push_back(-1);
      seen[static_cast<int>(role)] = true;
    }
  }
  for (const char* axis : {"x", "y", "z"}) {
    if (!seen[static_cast<int>(RoleOf(axis))]) {
      Where at = where;
      at.field = axis;
      return Status::BadInput(at,
                              std::string("no ") + what_columns + " '" + axis + "' (found: " + JoinNames(names) + ")",
                              "name the coordinate " + what_columns + "s x, y and z (lowercase)");
    }
  }
  const int normal_count = seen[3] + seen[4] + seen[5];
  if (normal_count != 0 && normal_count != 3) {
    Where at = where;
    at.field = !seen[3] ? "nx" : !seen[4] ? "ny" : "nz";
    return Status::BadInput(
        at, "normal " + what_columns + "s must come as nx, ny and nz together; '" + at.field + "' is missing",
        "add the missing normal " + what_columns + " or remove the other normal " + what_columns + "s");
  }
  plan->has_normals = normal_count == 3;
  plan->has_id = seen[6];
  plan->has_t = seen[7];
  return Status::Ok();
}

PointSet EmptySetFor(const ColumnPlan& plan, std::size_t reserve) {
  PointSet points;
  points.points.reserve(reserve);
  if (plan.has_normals) points.normals.reserve(reserve);
  if (plan.has_id) points.ids.reserve(reserve);
  if (plan.has_t) points.times_s.reserve(reserve);
  for (const auto& name : plan.scalar_names) {
    points.scalars.push_back({name, {}});
    points.scalars.back().values.reserve(reserve);
  }
  return points;
}

// Appends one point; `values` holds one number per column (ids already checked to be integral).
void AppendRow(const ColumnPlan& plan, const double* values, const std::int64_t id, PointSet* points) {
  Eigen::Vector3d p = Eigen::Vector3d::Zero();
  Eigen::Vector3d n = Eigen::Vector3d::Zero();
  double t = 0;
  for (std::size_t c = 0; c < plan.roles.size(); ++c) {
    switch (plan.roles[c]) {
      case Role::kX:
        p.x() = values[c];
        break;
      case Role::kY:
        p.y() = values[c];
        break;
      case Role::kZ:
        p.z() = values[c];
        break;
      case Role::kNx:
        n.x() = values[c];
        break;
      case Role::kNy:
        n.y() = values[c];
        break;
      case Role::kNz:
        n.z() = values[c];
        break;
      case Role::kT:
        t = values[c];
        break;
      case Role::kId:
        break;
      case Role::kScalar:
        points->scalars[plan.scalar_index[c]].values.push_back(values[c]);
        break;
    }
  }
  points->points.push_back(p);
  if (plan.has_normals) points->normals.push_back(n);
  if (plan.has_id) points->ids.push_back(id);
  if (plan.has_t) points->times_s.push_back(t);
}

// Text of one number for the text writers: fixed decimals, or shortest round-trip when precision < 0.
void AppendNumber(double value, int precision, std::string* out) {
  if (precision < 0) {
    *out += FormatExact(value);
  } else {
    *out += FormatFixed(value, precision);
  }
}

void AppendInt(std::int64_t value, std::string* out) {
  char buffer[24];
  const auto result = std::to_chars(buffer, buffer + sizeof(buffer), value);
  out->append(buffer, result.ptr);
}

// Scalar names a text format can hold: no separator, no whitespace at either end (CSV) or anywhere.
Status CheckScalarNames(const std::string& file, const PointSet& points, bool allow_inner_space,
                        const std::string& format) {
  for (const auto& column : points.scalars) {
    const std::string& name = column.name;
    bool bad = name.find_first_of(",\n\r#") != std::string::npos || TrimBlanks(name) != name;
    if (!allow_inner_space && name.find_first_of(" \t") != std::string::npos) bad = true;
    if (bad) {
      return Status::BadInput(Where{.file = file, .field = name},
                              "scalar name cannot be stored in a " + format + " file",
                              "rename the scalar to letters, digits and '_' (e.g. deviation_um)");
    }
  }
  return Status::Ok();
}

}  // namespace point_io_text

namespace {

using point_io_text::AppendInt;
using point_io_text::AppendNumber;
using point_io_text::AppendRow;
using point_io_text::CheckScalarNames;
using point_io_text::ColumnPlan;
using point_io_text::EmptySetFor;
using point_io_text::MakeColumnPlan;
using point_io_text::ParseIdField;
using point_io_text::ParseNumberField;
using point_io_text::Quote;
using point_io_text::Role;
using point_io_text::SplitWhitespace;

// One text row: x y z [nx ny nz] and, when `with_attributes`, [id] [t] [scalars...], joined by
// `separator`, newline-terminated.
void AppendTextRow(const PointSet& points, std::size_t i, char separator, int precision, bool with_attributes,
                   std::string* out) {
  for (int k = 0; k < 3; ++k) {
    if (k > 0) *out += separator;
    AppendNumber(points.points[i][k], precision, out);
  }
  if (points.has_normals()) {
    for (int k = 0; k < 3; ++k) {
      *out += separator;
      AppendNumber(points.normals[i][k], precision, out);
    }
  }
  if (!with_attributes) {
    *out += '\n';
    return;
  }
  if (points.has_ids()) {
    *out += separator;
    AppendInt(points.ids[i], out);
  }
  if (points.has_times()) {
    *out += separator;
    AppendNumber(points.times_s[i], precision, out);
  }
  for (const auto& column : points.scalars) {
    *out += separator;
    AppendNumber(column.values[i], precision, out);
  }
  *out += '\n';
}

}  // namespace

Status CheckCoordinateRange(const Eigen::Vector3d& p, Where where, const std::string& what) {
  static const char* kAxis[] = {"x", "y", "z"};
  for (int a = 0; a < 3; ++a) {
    if (std::abs(p[a]) <= kMaxCoordinateMm) continue;
    if (where.field.empty()) where.field = kAxis[a];
    return Status::BadInput(where, what + "coordinate " + FormatSignificant(p[a], 6) + " mm is beyond +-1e6 mm (1 km)",
                            "check the file's unit and export; delete points that are not measurements");
  }
  return Status::Ok();
}

Result<PointFormat> PointFormatFromPath(const std::filesystem::path& path) {
  std::string extension = path.extension().string();
  std::transform(extension.begin(), extension.end(), extension.begin(),
                 [](unsigned char c) { return static_cast<char>(std::tolower(c)); });
  if (extension == ".csv") return PointFormat::kCsv;
  if (extension == ".xyz" || extension == ".txt") return PointFormat::kXyz;
  if (extension == ".ply") return PointFormat::kPly;
  if (extension == ".pcd") return PointFormat::kPcd;
  const std::string what =
      extension.empty() ? "the point file name has no extension" : "unknown point file extension " + Quote(extension);
  return Status::BadInput(Where{.file = path.string()}, what, "use a name ending in .csv, .xyz, .txt, .ply or .pcd");
}

// ---------------------------------------------------------------------------------------------
// CSV

Result<PointSet> ReadCsv(const std::filesystem::path& path, CsvLayout* layout) {
  const std::string file = path.string();
  FL_ASSIGN_OR_RETURN(const std::string text, ReadTextFile(path));
  CsvReader rows(text);
  if (!rows.Next()) {
    return Status::BadInput(Where{.file = file}, "no points: the file has no header row and no data",
                            "write a header row such as 'x,y,z' followed by one row per point");
  }
  const long header_line = rows.line_number();
  std::vector<std::string> names(rows.cells().begin(), rows.cells().end());
  if (layout != nullptr) {
    layout->header_line = header_line;
    layout->header_text = std::string(rows.line());
    layout->row_lines.clear();
  }
  ColumnPlan plan;
  FL_RETURN_IF_ERROR(MakeColumnPlan(names, Where{.file = file, .line = header_line}, "column", &plan));

  PointSet points = EmptySetFor(plan, std::min<std::size_t>(text.size() / (2 * names.size() + 1), 1 << 24));
  std::vector<double> values(names.size(), 0.0);
  while (rows.Next()) {
    const long number = rows.line_number();
    const std::vector<std::string_view>& fields = rows.cells();
    if (fields.size() != names.size()) {
      return Status::BadInput(Where{.file = file, .line = number},
                              "the row has " + std::to_string(fields.size()) + " fields but the header (line " +
                                  std::to_string(header_line) + ") has " + std::to_string(names.size()) + " columns",
                              RaggedRowFix(rows.separator(), fields.size(), names.size()));
    }
    std::int64_t id = 0;
    for (std::size_t c = 0; c < fields.size(); ++c) {
      if (plan.roles[c] == Role::kId) {
        FL_RETURN_IF_ERROR(ParseIdField(fields[c], file, number, names[c], &id));
      } else {
        FL_RETURN_IF_ERROR(ParseNumberField(fields[c], file, number, names[c], &values[c]));
      }
    }
    AppendRow(plan, values.data(), id, &points);
    FL_RETURN_IF_ERROR(CheckCoordinateRange(points.points.back(), Where{.file = file, .line = number}));
    if (layout != nullptr) layout->row_lines.push_back(number);
  }
  if (points.empty()) {
    return Status::BadInput(Where{.file = file, .line = header_line},
                            "no points: the file has a header row but no data rows", "add one row per point");
  }
  return points;
}

Status WriteCsv(const std::filesystem::path& path, const PointSet& points, const PointWriteOptions& options) {
  const std::string file = path.string();
  FL_RETURN_IF_ERROR(points.Validate(file));
  FL_RETURN_IF_ERROR(CheckScalarNames(file, points, /*allow_inner_space=*/true, "CSV"));
  std::string out = kPointFileMarker;
  out += "x,y,z";
  if (points.has_normals()) out += ",nx,ny,nz";
  if (points.has_ids()) out += ",id";
  if (points.has_times()) out += ",t";
  for (const auto& column : points.scalars) out += "," + column.name;
  out += '\n';
  out.reserve(out.size() + points.size() * (3 + (points.has_normals() ? 3 : 0) + points.scalars.size() + 2) * 16);
  for (std::size_t i = 0; i < points.size(); ++i) {
    AppendTextRow(points, i, ',', options.precision, /*with_attributes=*/true, &out);
  }
  return WriteFileAtomic(path, out);
}

// ---------------------------------------------------------------------------------------------
// XYZ

Result<PointSet> ReadXyz(const std::filesystem::path& path) {
  static const std::vector<std::string> kNames = {"x", "y", "z", "nx", "ny", "nz"};
  const std::string file = path.string();
  FL_ASSIGN_OR_RETURN(const std::string text, ReadTextFile(path));
  TextLines lines(text);
  std::string_view line;
  std::vector<std::string_view> tokens;
  std::size_t columns = 0;
  long first_line = 0;
  PointSet points;
  double values[6] = {};
  while (lines.NextContent(&line)) {
    const long number = lines.line_number();
    SplitWhitespace(line, &tokens);
    if (columns == 0) {
      if (tokens.size() != 3 && tokens.size() != 6) {
        return Status::BadInput(Where{.file = file, .line = number},
                                "the line has " + std::to_string(tokens.size()) +
                                    " values; an XYZ file has 3 (x y z) or 6 (x y z nx ny nz) per line",
                                "write 'x y z' or 'x y z nx ny nz' separated by spaces, or use CSV with a header "
                                "for other columns");
      }
      columns = tokens.size();
      first_line = number;
    } else if (tokens.size() != columns) {
      return Status::BadInput(Where{.file = file, .line = number},
                              "the line has " + std::to_string(tokens.size()) + " values but line " +
                                  std::to_string(first_line) + " has " + std::to_string(columns),
                              "give every line the same number of values");
    }
    for (std::size_t c = 0; c < columns; ++c) {
      FL_RETURN_IF_ERROR(ParseNumberField(tokens[c], file, number, kNames[c], &values[c]));
    }
    points.points.emplace_back(values[0], values[1], values[2]);
    FL_RETURN_IF_ERROR(CheckCoordinateRange(points.points.back(), Where{.file = file, .line = number}));
    if (columns == 6) points.normals.emplace_back(values[3], values[4], values[5]);
  }
  if (points.empty()) {
    return Status::BadInput(Where{.file = file}, "no points: the file has no data lines",
                            "write one 'x y z' line per point");
  }
  return points;
}

Status WriteXyz(const std::filesystem::path& path, const PointSet& points, const PointWriteOptions& options) {
  const std::string file = path.string();
  FL_RETURN_IF_ERROR(points.Validate(file));
  if (points.has_ids() || points.has_times() || !points.scalars.empty()) {
    log::Warn("{}: XYZ holds positions and normals only; ids, times and scalars are not written (use CSV or PLY)",
              file);
  }
  std::string out = kPointFileMarker;
  out.reserve(points.size() * (points.has_normals() ? 6 : 3) * 16);
  for (std::size_t i = 0; i < points.size(); ++i) {
    AppendTextRow(points, i, ' ', options.precision, /*with_attributes=*/false, &out);
  }
  return WriteFileAtomic(path, out);
}

Result<bool> IdsFitInt32(const PointSet& points, const std::string& file, const std::string& format) {
  bool fit = true;
  for (const std::int64_t id : points.ids) {
    if (id < std::numeric_limits<std::int32_t>::min() || id > std::numeric_limits<std::int32_t>::max()) {
      fit = false;
      if (id < -(std::int64_t{1} << 53) || id > (std::int64_t{1} << 53)) {
        return Status::BadInput(Where{.file = file, .field = "id"},
                                "id " + std::to_string(id) + " cannot be stored exactly in a " + format + " file",
                                "use ids within +-2^53 or write CSV");
      }
    }
  }
  return fit;
}

// ---------------------------------------------------------------------------------------------
// Dispatch

Result<PointSet> ReadPoints(const std::filesystem::path& path) {
  FL_ASSIGN_OR_RETURN(const PointFormat format, PointFormatFromPath(path));
  switch (format) {
    case PointFormat::kCsv:
      return ReadCsv(path);
    case PointFormat::kXyz:
      return ReadXyz(path);
    case PointFormat::kPly:
      return ReadPly(path);
    case PointFormat::kPcd:
      return ReadPcd(path);
  }
  return Status::Internal("ReadPoints: unhandled point format");
}

Status WritePoints(const std::filesystem::path& path, const PointSet& points, const PointWriteOptions& options) {
  FL_ASSIGN_OR_RETURN(const PointFormat format, PointFormatFromPath(path));
  switch (format) {
    case PointFormat::kCsv:
      return WriteCsv(path, points, options);
    case PointFormat::kXyz:
      return WriteXyz(path, points, options);
    case PointFormat::kPly:
      return WritePly(path, points, options);
    case PointFormat::kPcd:
      return WritePcd(path, points, options);
  }
  return Status::Internal("WritePoints: unhandled point format");
}

}  // namespace formloop
