// PLY point files (Turk, "The PLY polygon file format", 1994; core/point_io.h): header parsing, ascii
// and binary (both byte orders) bodies of the vertex element, other elements skipped, and the writer.

#include <algorithm>
#include <bit>
#include <charconv>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <limits>
#include <string_view>
#include <utility>
#include <vector>

#include "core/atomic_file.h"
#include "core/csv.h"
#include "core/number_text.h"
#include "core/point_io.h"
#include "core/point_io_text.h"

namespace formloop {
namespace {

using point_io_text::AppendInt;
using point_io_text::AppendNumber;
using point_io_text::AppendRow;
using point_io_text::CheckScalarNames;
using point_io_text::ColumnPlan;
using point_io_text::DoubleToId;
using point_io_text::EmptySetFor;
using point_io_text::JoinNames;
using point_io_text::MakeColumnPlan;
using point_io_text::ParseIdField;
using point_io_text::ParseNumberField;
using point_io_text::Quote;
using point_io_text::Role;
using point_io_text::SplitWhitespace;

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

}  // namespace formloop
