// Why one file of ~950 lines: the CSV, XYZ and PLY readers and writers share the text helpers at the top
// (number and id fields, column plans, scalar names). Its seam is the PLY format (header parsing, ascii and
// binary bodies, about half the file), which goes to point_io_ply.cc like point_io_pcd.cc; that move waits
// until issue 17's edits to this file have landed, so the two do not collide.

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

namespace formloop {
namespace {

// ---------------------------------------------------------------------------------------------
// Shared text helpers

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

enum class Role { kX, kY, kZ, kNx, kNy, kNz, kId, kT, kScalar };

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

// Roles of a file's columns / properties and the checks shared by CSV and PLY: x, y, z present and
// the normals complete.
struct ColumnPlan {
  std::vector<Role> roles;
  std::vector<int> scalar_index;  // per column: index into PointSet::scalars, -1 otherwise
  std::vector<std::string> scalar_names;
  bool has_normals = false;
  bool has_id = false;
  bool has_t = false;
};

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

// ---------------------------------------------------------------------------------------------
// PLY

enum class PlyType { kInt8, kUint8, kInt16, kUint16, kInt32, kUint32, kFloat32, kFloat64 };

bool ParsePlyType(std::string_view name, PlyType* type) {
  static constexpr std::pair<std::string_view, PlyType> kTypes[] = {
      {"char", PlyType::kInt8},      {"int8", PlyType::kInt8},       {"uchar", PlyType::kUint8},
      {"uint8", PlyType::kUint8},    {"short", PlyType::kInt16},     {"int16", PlyType::kInt16},
      {"ushort", PlyType::kUint16},  {"uint16", PlyType::kUint16},   {"int", PlyType::kInt32},
      {"int32", PlyType::kInt32},    {"uint", PlyType::kUint32},     {"uint32", PlyType::kUint32},
      {"float", PlyType::kFloat32},  {"float32", PlyType::kFloat32}, {"double", PlyType::kFloat64},
      {"float64", PlyType::kFloat64}};
  for (const auto& [text, value] : kTypes) {
    if (name == text) {
      *type = value;
      return true;
    }
  }
  return false;
}

std::size_t PlySize(PlyType type) {
  switch (type) {
    case PlyType::kInt8:
    case PlyType::kUint8:
      return 1;
    case PlyType::kInt16:
    case PlyType::kUint16:
      return 2;
    case PlyType::kInt32:
    case PlyType::kUint32:
    case PlyType::kFloat32:
      return 4;
    case PlyType::kFloat64:
      return 8;
  }
  return 0;
}

bool IsFloatType(PlyType type) { return type == PlyType::kFloat32 || type == PlyType::kFloat64; }

template <typename U>
U LoadUnsigned(const char* data, bool swap) {
  U value;
  std::memcpy(&value, data, sizeof(U));
  if (swap) {
    if constexpr (sizeof(U) == 2) value = __builtin_bswap16(value);
    if constexpr (sizeof(U) == 4) value = __builtin_bswap32(value);
    if constexpr (sizeof(U) == 8) value = __builtin_bswap64(value);
  }
  return value;
}

double LoadPly(const char* data, PlyType type, bool swap) {
  switch (type) {
    case PlyType::kInt8:
      return static_cast<std::int8_t>(data[0]);
    case PlyType::kUint8:
      return static_cast<std::uint8_t>(data[0]);
    case PlyType::kInt16:
      return static_cast<std::int16_t>(LoadUnsigned<std::uint16_t>(data, swap));
    case PlyType::kUint16:
      return LoadUnsigned<std::uint16_t>(data, swap);
    case PlyType::kInt32:
      return static_cast<std::int32_t>(LoadUnsigned<std::uint32_t>(data, swap));
    case PlyType::kUint32:
      return LoadUnsigned<std::uint32_t>(data, swap);
    case PlyType::kFloat32:
      return std::bit_cast<float>(LoadUnsigned<std::uint32_t>(data, swap));
    case PlyType::kFloat64:
      return std::bit_cast<double>(LoadUnsigned<std::uint64_t>(data, swap));
  }
  return 0;
}

struct PlyProperty {
  std::string name;
  PlyType type = PlyType::kFloat64;
  bool is_list = false;
  PlyType count_type = PlyType::kUint8;
  long line = 0;
};

struct PlyElement {
  std::string name;
  std::uint64_t count = 0;
  long line = 0;
  std::vector<PlyProperty> properties;
};

enum class PlyEncoding { kAscii, kBinaryLittle, kBinaryBig };

struct PlyHeader {
  PlyEncoding encoding = PlyEncoding::kAscii;
  std::vector<PlyElement> elements;
  std::size_t data_offset = 0;  // first byte after end_header
  long data_line = 0;           // line number of the first data line (ASCII)
};

Status ParsePlyHeader(const std::string& file, std::string_view text, PlyHeader* header) {
  const std::string kFixHeader = "write a PLY header as in http://paulbourke.net/dataformats/ply/";
  TextLines lines(text);
  std::string_view line;
  if (!lines.Next(&line)) {
    return Status::BadInput(Where{.file = file}, "no points: the file is empty",
                            "export the point cloud again; a PLY file starts with the line 'ply'");
  }
  if (TrimBlanks(line) != "ply") {
    return Status::BadInput(Where{.file = file, .line = 1}, "not a PLY file: the first line is " + Quote(line),
                            "a PLY file starts with the line 'ply'; check the file or its extension");
  }
  bool have_format = false;
  bool have_end = false;
  std::vector<std::string_view> tokens;
  while (lines.Next(&line)) {
    const long number = lines.line_number();
    SplitWhitespace(line, &tokens);
    if (tokens.empty()) continue;
    const std::string_view keyword = tokens[0];
    const Where where{.file = file, .line = number};
    if (keyword == "comment" || keyword == "obj_info") continue;
    if (keyword == "end_header") {
      have_end = true;
      break;
    }
    if (keyword == "format") {
      if (tokens.size() != 3 || tokens[2] != "1.0") {
        return Status::BadInput(where, "format line " + Quote(line) + " is not understood",
                                "write 'format ascii 1.0' or 'format binary_little_endian 1.0'");
      }
      if (tokens[1] == "ascii") {
        header->encoding = PlyEncoding::kAscii;
      } else if (tokens[1] == "binary_little_endian") {
        header->encoding = PlyEncoding::kBinaryLittle;
      } else if (tokens[1] == "binary_big_endian") {
        header->encoding = PlyEncoding::kBinaryBig;
      } else {
        return Status::BadInput(where, "unknown PLY format " + Quote(tokens[1]),
                                "use ascii, binary_little_endian or binary_big_endian");
      }
      have_format = true;
    } else if (keyword == "element") {
      std::uint64_t count = 0;
      if (tokens.size() != 3 || std::from_chars(tokens[2].data(), tokens[2].data() + tokens[2].size(), count).ptr !=
                                    tokens[2].data() + tokens[2].size()) {
        return Status::BadInput(where, "element line " + Quote(line) + " is not understood",
                                "write 'element <name> <count>', e.g. 'element vertex 1000'");
      }
      header->elements.push_back({std::string(tokens[1]), count, number, {}});
    } else if (keyword == "property") {
      if (header->elements.empty()) {
        return Status::BadInput(where, "property before any element line", kFixHeader);
      }
      PlyProperty property;
      property.line = number;
      bool ok = false;
      if (tokens.size() == 5 && tokens[1] == "list") {
        property.is_list = true;
        property.name = std::string(tokens[4]);
        ok = ParsePlyType(tokens[2], &property.count_type) && ParsePlyType(tokens[3], &property.type) &&
             !IsFloatType(property.count_type);
      } else if (tokens.size() == 3) {
        property.name = std::string(tokens[2]);
        ok = ParsePlyType(tokens[1], &property.type);
      }
      if (!ok) {
        Where at = where;
        at.field = tokens.size() >= 3 ? std::string(tokens.back()) : "";
        return Status::BadInput(at, "property line " + Quote(line) + " is not understood",
                                "use 'property <type> <name>' with type char, uchar, short, ushort, int, uint, "
                                "float or double (or int8 ... float64)");
      }
      header->elements.back().properties.push_back(std::move(property));
    } else {
      return Status::BadInput(where, "unknown header line " + Quote(line), kFixHeader);
    }
  }
  if (!have_end) {
    return Status::BadInput(Where{.file = file, .line = lines.line_number()}, "the header has no 'end_header' line",
                            "the file is truncated or not a PLY file");
  }
  if (!have_format) {
    return Status::BadInput(Where{.file = file}, "the header has no 'format' line",
                            "add 'format ascii 1.0' or 'format binary_little_endian 1.0' after 'ply'");
  }
  header->data_offset = lines.position();
  header->data_line = lines.line_number() + 1;
  return Status::Ok();
}

// Binary: skips one element's data; false when the file ends first.
bool SkipBinaryElement(std::string_view data, const PlyElement& element, bool swap, std::size_t* pos) {
  for (std::uint64_t i = 0; i < element.count; ++i) {
    for (const auto& property : element.properties) {
      if (property.is_list) {
        const std::size_t count_size = PlySize(property.count_type);
        if (data.size() - *pos < count_size) return false;
        const double count = LoadPly(data.data() + *pos, property.count_type, swap);
        *pos += count_size;
        if (count < 0) return false;
        const std::uint64_t bytes = static_cast<std::uint64_t>(count) * PlySize(property.type);
        if (data.size() - *pos < bytes) return false;
        *pos += bytes;
      } else {
        if (data.size() - *pos < PlySize(property.type)) return false;
        *pos += PlySize(property.type);
      }
    }
  }
  return true;
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
  std::string out = "x,y,z";
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
  std::string out;
  out.reserve(points.size() * (points.has_normals() ? 6 : 3) * 16);
  for (std::size_t i = 0; i < points.size(); ++i) {
    AppendTextRow(points, i, ' ', options.precision, /*with_attributes=*/false, &out);
  }
  return WriteFileAtomic(path, out);
}

// ---------------------------------------------------------------------------------------------
// PLY

Result<PointSet> ReadPly(const std::filesystem::path& path) {
  const std::string file = path.string();
  FL_ASSIGN_OR_RETURN(const std::string text, ReadFile(path));
  PlyHeader header;
  FL_RETURN_IF_ERROR(ParsePlyHeader(file, text, &header));

  std::size_t vertex_index = header.elements.size();
  for (std::size_t e = 0; e < header.elements.size(); ++e) {
    if (header.elements[e].name == "vertex") {
      vertex_index = e;
      break;
    }
  }
  if (vertex_index == header.elements.size()) {
    return Status::BadInput(Where{.file = file}, "no points: the header has no 'element vertex'",
                            "export the point cloud with its vertices");
  }
  const PlyElement& vertex = header.elements[vertex_index];
  std::vector<std::string> names;
  for (const auto& property : vertex.properties) {
    if (property.is_list) {
      return Status::BadInput(Where{.file = file, .line = property.line, .field = property.name},
                              "list properties on the vertex element are not supported",
                              "export the vertices with scalar properties only");
    }
    names.push_back(property.name == "normal_x"   ? "nx"
                    : property.name == "normal_y" ? "ny"
                    : property.name == "normal_z" ? "nz"
                                                  : property.name);
  }
  ColumnPlan plan;
  FL_RETURN_IF_ERROR(MakeColumnPlan(names, Where{.file = file, .line = vertex.line}, "property", &plan));
  if (vertex.count == 0) {
    return Status::BadInput(Where{.file = file, .line = vertex.line}, "no points: 'element vertex 0'",
                            "export a point cloud with at least one point");
  }
  const std::size_t columns = names.size();
  std::vector<double> values(columns, 0.0);
  PointSet points;

  if (header.encoding == PlyEncoding::kAscii) {
    TextLines lines(std::string_view(text).substr(header.data_offset));
    const long line_base = header.data_line - 1;
    std::string_view line;
    std::vector<std::string_view> tokens;
    for (std::size_t e = 0; e < vertex_index; ++e) {
      for (std::uint64_t i = 0; i < header.elements[e].count; ++i) {
        if (!lines.NextContent(&line)) {
          return Status::BadInput(Where{.file = file, .line = line_base + lines.line_number() + 1},
                                  "the file ends inside element '" + header.elements[e].name + "'",
                                  "the file is truncated; export it again");
        }
      }
    }
    points = EmptySetFor(plan, std::min<std::uint64_t>(vertex.count, text.size() / (2 * columns)));
    for (std::uint64_t i = 0; i < vertex.count; ++i) {
      if (!lines.NextContent(&line)) {
        return Status::BadInput(
            Where{.file = file, .line = line_base + lines.line_number() + 1},
            "the file ends after " + std::to_string(i) + " of " + std::to_string(vertex.count) + " vertices",
            "the file is truncated; export it again or correct the count in 'element vertex'");
      }
      const long number = line_base + lines.line_number();
      SplitWhitespace(line, &tokens);
      if (tokens.size() != columns) {
        return Status::BadInput(Where{.file = file, .line = number},
                                "vertex " + std::to_string(i) + " has " + std::to_string(tokens.size()) +
                                    " values but the header declares " + std::to_string(columns) + " properties (" +
                                    JoinNames(names) + ")",
                                "write one value per vertex property on each line");
      }
      std::int64_t id = 0;
      for (std::size_t c = 0; c < columns; ++c) {
        const std::string& field = vertex.properties[c].name;
        if (plan.roles[c] == Role::kId) {
          FL_RETURN_IF_ERROR(ParseIdField(tokens[c], file, number, field, &id));
        } else {
          FL_RETURN_IF_ERROR(ParseNumberField(tokens[c], file, number, field, &values[c]));
        }
      }
      AppendRow(plan, values.data(), id, &points);
      FL_RETURN_IF_ERROR(CheckCoordinateRange(points.points.back(), Where{.file = file, .line = number}));
    }
    return points;
  }

  const bool file_little = header.encoding == PlyEncoding::kBinaryLittle;
  const bool swap = file_little != (std::endian::native == std::endian::little);
  const std::string_view data(text);
  std::size_t pos = header.data_offset;
  for (std::size_t e = 0; e < vertex_index; ++e) {
    if (!SkipBinaryElement(data, header.elements[e], swap, &pos)) {
      return Status::BadInput(Where{.file = file},
                              "binary data ends inside element '" + header.elements[e].name + "' (before byte " +
                                  std::to_string(data.size()) + ")",
                              "the file is truncated; export it again");
    }
  }
  std::vector<std::size_t> offsets;
  std::size_t stride = 0;
  for (const auto& property : vertex.properties) {
    offsets.push_back(stride);
    stride += PlySize(property.type);
  }
  const std::size_t available = data.size() - pos;
  if (vertex.count > available / stride) {
    const std::uint64_t complete = available / stride;
    const std::string expected = vertex.count > std::numeric_limits<std::uint64_t>::max() / stride
                                     ? "more than 2^64"
                                     : std::to_string(vertex.count * stride);
    return Status::BadInput(Where{.file = file},
                            "binary vertex data is truncated at vertex " + std::to_string(complete) + " (byte offset " +
                                std::to_string(pos + complete * stride) + "): expected " + expected + " bytes for " +
                                std::to_string(vertex.count) + " vertices of " + std::to_string(stride) +
                                " bytes, only " + std::to_string(available) + " bytes are available",
                            "the file is incomplete (interrupted copy or export?); export it again");
  }
  points = EmptySetFor(plan, vertex.count);
  for (std::uint64_t i = 0; i < vertex.count; ++i) {
    const char* base = data.data() + pos + i * stride;
    std::int64_t id = 0;
    for (std::size_t c = 0; c < columns; ++c) {
      const PlyProperty& property = vertex.properties[c];
      values[c] = LoadPly(base + offsets[c], property.type, swap);
      if (!IsFloatType(property.type)) {
        if (plan.roles[c] == Role::kId) id = static_cast<std::int64_t>(values[c]);
        continue;
      }
      const bool finite = std::isfinite(values[c]);
      if (finite && (plan.roles[c] != Role::kId || DoubleToId(values[c], &id))) continue;
      const std::string at =
          "vertex " + std::to_string(i) + " (byte offset " + std::to_string(pos + i * stride + offsets[c]) + "): ";
      if (!finite) {
        return Status::BadInput(Where{.file = file, .field = property.name},
                                at + "value " + FormatExact(values[c]) + " is not finite (NaN or infinity)",
                                "remove invalid points before export");
      }
      return Status::BadInput(Where{.file = file, .field = property.name},
                              at + "id " + FormatExact(values[c]) + " is not an integer",
                              "store ids as whole numbers (an int property)");
    }
    AppendRow(plan, values.data(), id, &points);
    FL_RETURN_IF_ERROR(
        CheckCoordinateRange(points.points.back(), Where{.file = file}, "vertex " + std::to_string(i) + ": "));
  }
  return points;
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

Status WritePly(const std::filesystem::path& path, const PointSet& points, const PointWriteOptions& options) {
  const std::string file = path.string();
  FL_RETURN_IF_ERROR(points.Validate(file));
  FL_RETURN_IF_ERROR(CheckScalarNames(file, points, /*allow_inner_space=*/false, "PLY"));
  // ids as 'int' when they fit, else as 'double' (exact up to 2^53).
  FL_ASSIGN_OR_RETURN(const bool ids_fit_int, IdsFitInt32(points, file, "PLY"));
  std::string out = "ply\nformat ";
  out += options.binary ? "binary_little_endian 1.0\n" : "ascii 1.0\n";
  out += "comment generated by formloop\n";
  out += "element vertex " + std::to_string(points.size()) + "\n";
  out += "property double x\nproperty double y\nproperty double z\n";
  if (points.has_normals()) out += "property double nx\nproperty double ny\nproperty double nz\n";
  if (points.has_ids()) out += ids_fit_int ? "property int id\n" : "property double id\n";
  if (points.has_times()) out += "property double t\n";
  for (const auto& column : points.scalars) out += "property double " + column.name + "\n";
  out += "end_header\n";

  if (options.binary) {
    const std::size_t stride =
        8 * (3 + (points.has_normals() ? 3 : 0) + (points.has_times() ? 1 : 0) + points.scalars.size()) +
        (points.has_ids() ? (ids_fit_int ? 4 : 8) : 0);
    const std::size_t header_size = out.size();
    out.resize(header_size + stride * points.size());
    char* cursor = out.data() + header_size;
    auto put_double = [&cursor](double value) {
      std::uint64_t bits = std::bit_cast<std::uint64_t>(value);
      if constexpr (std::endian::native == std::endian::big) bits = __builtin_bswap64(bits);
      std::memcpy(cursor, &bits, 8);
      cursor += 8;
    };
    for (std::size_t i = 0; i < points.size(); ++i) {
      for (int k = 0; k < 3; ++k) put_double(points.points[i][k]);
      if (points.has_normals()) {
        for (int k = 0; k < 3; ++k) put_double(points.normals[i][k]);
      }
      if (points.has_ids()) {
        if (ids_fit_int) {
          std::uint32_t bits = static_cast<std::uint32_t>(static_cast<std::int32_t>(points.ids[i]));
          if constexpr (std::endian::native == std::endian::big) bits = __builtin_bswap32(bits);
          std::memcpy(cursor, &bits, 4);
          cursor += 4;
        } else {
          put_double(static_cast<double>(points.ids[i]));
        }
      }
      if (points.has_times()) put_double(points.times_s[i]);
      for (const auto& column : points.scalars) put_double(column.values[i]);
    }
    return WriteFileAtomic(path, out, /*binary=*/true);
  }

  for (std::size_t i = 0; i < points.size(); ++i) {
    for (int k = 0; k < 3; ++k) {
      if (k > 0) out += ' ';
      AppendNumber(points.points[i][k], options.precision, &out);
    }
    if (points.has_normals()) {
      for (int k = 0; k < 3; ++k) {
        out += ' ';
        AppendNumber(points.normals[i][k], options.precision, &out);
      }
    }
    if (points.has_ids()) {
      out += ' ';
      AppendInt(points.ids[i], &out);
    }
    if (points.has_times()) {
      out += ' ';
      AppendNumber(points.times_s[i], options.precision, &out);
    }
    for (const auto& column : points.scalars) {
      out += ' ';
      AppendNumber(column.values[i], options.precision, &out);
    }
    out += '\n';
  }
  return WriteFileAtomic(path, out, /*binary=*/true);
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
