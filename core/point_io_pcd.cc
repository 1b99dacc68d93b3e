// PCD reading and writing through PCL (pcl::PCDReader, pcl::PCDWriter header generation).
//
// Fields written: x y z [normal_x normal_y normal_z] [id] [t] [scalars...], all F 8 (double) except id,
// which is I 4 when every id fits in int32 and F 8 otherwise. On read, normals are taken from
// normal_x/normal_y/normal_z (or nx/ny/nz), padding fields "_" are skipped, every other single-value
// field becomes a named scalar, and any numeric type is accepted.

#include <pcl/PCLPointCloud2.h>
#include <pcl/console/print.h>
#include <pcl/io/pcd_io.h>

#include <algorithm>
#include <cctype>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <exception>
#include <fstream>
#include <limits>
#include <string>
#include <vector>

#include "core/atomic_file.h"
#include "core/point_io.h"

namespace formloop {
namespace {

// PCL prints its errors to the console; formloop reports them as Status instead. Restores the previous
// level on destruction.
class QuietPcl {
 public:
  QuietPcl() : previous_(pcl::console::getVerbosityLevel()) { pcl::console::setVerbosityLevel(pcl::console::L_ALWAYS); }
  ~QuietPcl() { pcl::console::setVerbosityLevel(previous_); }
  QuietPcl(const QuietPcl&) = delete;
  QuietPcl& operator=(const QuietPcl&) = delete;

 private:
  pcl::console::VERBOSITY_LEVEL previous_;
};

enum class PcdRole { kX, kY, kZ, kNx, kNy, kNz, kId, kT, kScalar, kSkip };

PcdRole PcdRoleOf(const std::string& name) {
  if (name == "x") return PcdRole::kX;
  if (name == "y") return PcdRole::kY;
  if (name == "z") return PcdRole::kZ;
  if (name == "normal_x" || name == "nx") return PcdRole::kNx;
  if (name == "normal_y" || name == "ny") return PcdRole::kNy;
  if (name == "normal_z" || name == "nz") return PcdRole::kNz;
  if (name == "id") return PcdRole::kId;
  if (name == "t") return PcdRole::kT;
  if (name == "_") return PcdRole::kSkip;
  return PcdRole::kScalar;
}

std::size_t PcdTypeSize(std::uint8_t datatype) {
  switch (datatype) {
    case pcl::PCLPointField::INT8:
    case pcl::PCLPointField::UINT8:
      return 1;
    case pcl::PCLPointField::INT16:
    case pcl::PCLPointField::UINT16:
      return 2;
    case pcl::PCLPointField::INT32:
    case pcl::PCLPointField::UINT32:
    case pcl::PCLPointField::FLOAT32:
      return 4;
    case pcl::PCLPointField::INT64:
    case pcl::PCLPointField::UINT64:
    case pcl::PCLPointField::FLOAT64:
      return 8;
    default:
      return 0;
  }
}

template <typename T>
T LoadAs(const std::uint8_t* data) {
  T value;
  std::memcpy(&value, data, sizeof(T));
  return value;
}

// PCLPointCloud2::data holds native-endian values.
double LoadPcd(const std::uint8_t* data, std::uint8_t datatype) {
  switch (datatype) {
    case pcl::PCLPointField::INT8:
      return LoadAs<std::int8_t>(data);
    case pcl::PCLPointField::UINT8:
      return LoadAs<std::uint8_t>(data);
    case pcl::PCLPointField::INT16:
      return LoadAs<std::int16_t>(data);
    case pcl::PCLPointField::UINT16:
      return LoadAs<std::uint16_t>(data);
    case pcl::PCLPointField::INT32:
      return LoadAs<std::int32_t>(data);
    case pcl::PCLPointField::UINT32:
      return LoadAs<std::uint32_t>(data);
    case pcl::PCLPointField::INT64:
      return static_cast<double>(LoadAs<std::int64_t>(data));
    case pcl::PCLPointField::UINT64:
      return static_cast<double>(LoadAs<std::uint64_t>(data));
    case pcl::PCLPointField::FLOAT32:
      return LoadAs<float>(data);
    case pcl::PCLPointField::FLOAT64:
      return LoadAs<double>(data);
    default:
      return 0;
  }
}

bool IsIntegerType(std::uint8_t datatype) {
  return datatype != pcl::PCLPointField::FLOAT32 && datatype != pcl::PCLPointField::FLOAT64;
}

std::int64_t LoadPcdId(const std::uint8_t* data, std::uint8_t datatype) {
  switch (datatype) {
    case pcl::PCLPointField::INT64:
      return LoadAs<std::int64_t>(data);
    case pcl::PCLPointField::UINT64:
      return static_cast<std::int64_t>(LoadAs<std::uint64_t>(data));
    default:
      return static_cast<std::int64_t>(LoadPcd(data, datatype));
  }
}

std::string FixCheckPcd() {
  return "check that the file is a complete PCD v0.7 file (open it in a text editor to see the header) or "
         "export it again";
}

// The PCD v0.7 header (https://pointclouds.org/documentation/tutorials/pcd_file_format.html), checked before PCL
// sees the file: pcl::PCDReader trusts the header and crashes on some malformed ones (a line that only starts with
// a keyword, no DATA line, entry counts that disagree: found by fuzz/fuzz_points_pcd). Every line up to DATA is a
// '#' comment or one of the keywords, in order, with its entries: FIELDS, SIZE (1, 2, 4 or 8), TYPE (I, U or F;
// F of size 4 or 8), COUNT (optional, ≥ 1) with one entry per field, WIDTH, HEIGHT and POINTS (WIDTH × HEIGHT)
// positive, VIEWPOINT seven numbers, DATA ascii, binary or binary_compressed.
// What the body of a checked header must hold.
struct PcdLayout {
  long header_lines = 0;             // lines up to and including DATA
  std::size_t values_per_point = 0;  // the sum of COUNT
  unsigned long long points = 0;
  std::string data;  // ascii, binary or binary_compressed
};

// `file_size` bounds POINTS: an ascii point takes at least 2 bytes, a compressed one more than 1/100 byte (LZF).
Status CheckPcdHeader(const std::string& file, const std::string& text, std::uintmax_t file_size, PcdLayout* layout) {
  static const char* const kOrder[] = {"VERSION", "FIELDS", "SIZE",      "TYPE",   "COUNT",
                                       "WIDTH",   "HEIGHT", "VIEWPOINT", "POINTS", "DATA"};
  constexpr int kKeys = static_cast<int>(std::size(kOrder));
  const std::string fix =
      "write the header as PCD v0.7 defines it (VERSION, FIELDS, SIZE, TYPE, COUNT, WIDTH, "
      "HEIGHT, VIEWPOINT, POINTS, DATA, one per line) or export the point cloud again";
  std::vector<std::vector<std::string>> entries(kKeys);
  bool seen[kKeys] = {};
  int last = -1;
  long line_number = 0;
  std::size_t pos = 0;
  auto positive = [](const std::string& t, unsigned long long max) {
    if (t.empty() || t.size() > 12 || t.find_first_not_of("0123456789") != std::string::npos) return false;
    const unsigned long long v = std::stoull(t);
    return v >= 1 && v <= max;
  };
  while (pos < text.size()) {
    const std::size_t end = std::min(text.find('\n', pos), text.size());
    std::string line = text.substr(pos, end - pos);
    pos = end + 1;
    ++line_number;
    if (!line.empty() && line.back() == '\r') line.pop_back();
    if (line.empty() || line[0] == '#') continue;
    // Header lines are printable ASCII (PCL mis-parsed a field name of 0xff bytes into a use-after-free).
    for (const char c : line) {
      if (!(c == '\t' || (c >= 0x20 && c <= 0x7e))) {
        return Status::BadInput(Where{.file = file, .line = line_number, .field = ""},
                                "the header line holds a byte that is not printable ASCII", fix);
      }
    }
    std::vector<std::string> tokens;
    for (std::size_t i = 0; i < line.size();) {
      while (i < line.size() && (line[i] == ' ' || line[i] == '\t')) ++i;
      std::size_t j = i;
      while (j < line.size() && line[j] != ' ' && line[j] != '\t') ++j;
      if (j > i) tokens.push_back(line.substr(i, j - i));
      i = j;
    }
    if (tokens.empty()) continue;
    const Where where{.file = file, .line = line_number, .field = tokens[0]};
    int key = -1;
    for (int k = 0; k < kKeys; ++k) {
      if (tokens[0] == kOrder[k]) key = k;
    }
    if (key < 0) {
      return Status::BadInput(where, "not a PCD header line: '" + line.substr(0, 60) + "'", fix);
    }
    if (seen[key] || key < last) {
      return Status::BadInput(where, std::string(kOrder[key]) + " is repeated or out of order", fix);
    }
    seen[key] = true;
    last = key;
    entries[key].assign(tokens.begin() + 1, tokens.end());
    if (entries[key].empty()) return Status::BadInput(where, "has no value", fix);
    if (tokens[0] == "DATA") {
      layout->header_lines = line_number;
      break;
    }
  }
  auto index = [&](const char* name) {
    for (int k = 0; k < kKeys; ++k) {
      if (std::string(kOrder[k]) == name) return k;
    }
    return 0;
  };
  for (const char* required : {"FIELDS", "SIZE", "TYPE", "WIDTH", "POINTS", "DATA"}) {
    if (!seen[index(required)]) {
      return Status::BadInput(Where{.file = file, .field = required},
                              std::string("the header has no ") + required + " line", fix);
    }
  }
  const auto& fields = entries[index("FIELDS")];
  for (const std::string& name : fields) {
    const bool identifier = !std::isdigit(static_cast<unsigned char>(name[0])) &&
                            std::all_of(name.begin(), name.end(),
                                        [](char c) { return std::isalnum(static_cast<unsigned char>(c)) || c == '_'; });
    if (!identifier) {
      return Status::BadInput(Where{.file = file, .field = "FIELDS"}, "field name '" + name + "' is not a name",
                              "name each field with letters, digits and '_' (x y z normal_x ...)");
    }
  }
  const auto& sizes = entries[index("SIZE")];
  const auto& types = entries[index("TYPE")];
  const auto& counts = entries[index("COUNT")];
  if (sizes.size() != fields.size() || types.size() != fields.size() ||
      (seen[index("COUNT")] && counts.size() != fields.size())) {
    return Status::BadInput(Where{.file = file, .field = "FIELDS"},
                            std::to_string(fields.size()) + " fields, but " + std::to_string(sizes.size()) + " SIZE, " +
                                std::to_string(types.size()) + " TYPE and " + std::to_string(counts.size()) +
                                " COUNT entries",
                            "give SIZE, TYPE and COUNT one entry per field");
  }
  for (std::size_t f = 0; f < fields.size(); ++f) {
    const std::string& size = sizes[f];
    const std::string& type = types[f];
    const bool size_ok = size == "1" || size == "2" || size == "4" || size == "8";
    const bool type_ok = type == "I" || type == "U" || (type == "F" && (size == "4" || size == "8"));
    if (!size_ok || !type_ok || (seen[index("COUNT")] && !positive(counts[f], 1u << 20))) {
      return Status::BadInput(Where{.file = file, .field = fields[f]},
                              "field '" + fields[f] + "' has SIZE " + size + ", TYPE " + type +
                                  (seen[index("COUNT")] ? ", COUNT " + counts[f] : std::string()),
                              "SIZE is 1, 2, 4 or 8 bytes, TYPE I, U or F (F of 4 or 8 bytes), COUNT at least 1");
    }
  }
  const auto& width = entries[index("WIDTH")];
  const auto& points = entries[index("POINTS")];
  const auto& height = entries[index("HEIGHT")];
  constexpr unsigned long long kMaxPoints = 1ull << 40;
  if (width.size() != 1 || points.size() != 1 || !positive(width[0], kMaxPoints) || !positive(points[0], kMaxPoints) ||
      (seen[index("HEIGHT")] && (height.size() != 1 || !positive(height[0], kMaxPoints)))) {
    return Status::BadInput(Where{.file = file, .field = "WIDTH"},
                            "WIDTH, HEIGHT and POINTS must each be one positive whole number",
                            "a PCD file with no point holds nothing to read; export the point cloud again");
  }
  const unsigned long long h = seen[index("HEIGHT")] ? std::stoull(height[0]) : 1;
  if (std::stoull(width[0]) * h != std::stoull(points[0])) {
    return Status::BadInput(
        Where{.file = file, .field = "POINTS"},
        "POINTS " + points[0] + " is not WIDTH × HEIGHT (" + width[0] + " × " + std::to_string(h) + ")", fix);
  }
  if (seen[index("VIEWPOINT")] && entries[index("VIEWPOINT")].size() != 7) {
    return Status::BadInput(Where{.file = file, .field = "VIEWPOINT"}, "needs 7 numbers (tx ty tz qw qx qy qz)", fix);
  }
  const auto& data = entries[index("DATA")];
  if (data.size() != 1 || (data[0] != "ascii" && data[0] != "binary" && data[0] != "binary_compressed")) {
    return Status::BadInput(Where{.file = file, .field = "DATA"}, "must be ascii, binary or binary_compressed", fix);
  }
  const unsigned long long n = std::stoull(points[0]);
  if ((data[0] == "ascii" && n > file_size / 2) || (data[0] == "binary_compressed" && n / 100 > file_size)) {
    return Status::BadInput(
        Where{.file = file, .field = "POINTS"},
        "declares " + points[0] + " points, more than the file's " + std::to_string(file_size) + " bytes can hold",
        "the file is truncated or its header wrong; export the point cloud again");
  }
  layout->points = n;
  layout->data = data[0];
  layout->values_per_point = 0;
  for (std::size_t f = 0; f < fields.size(); ++f) {
    layout->values_per_point += seen[index("COUNT")] ? std::stoull(counts[f]) : 1;
  }
  return Status::Ok();
}

// The body of an ascii PCD, checked before PCL reads it (pcl::PCDReader trusted a body that held header lines and
// allocated terabytes: found by fuzz/fuzz_points_pcd): POINTS lines after DATA, each with one number per value
// (the sum of COUNT), blank lines aside.
Status CheckPcdAsciiBody(const std::filesystem::path& path, const PcdLayout& layout) {
  const std::string file = path.string();
  std::ifstream in(path, std::ios::binary);
  std::string line;
  long line_number = 0;
  unsigned long long rows = 0;
  while (std::getline(in, line)) {
    if (++line_number <= layout.header_lines) continue;
    if (!line.empty() && line.back() == '\r') line.pop_back();
    std::size_t values = 0;
    bool numbers = true;
    for (std::size_t i = 0; i < line.size();) {
      while (i < line.size() && (line[i] == ' ' || line[i] == '\t')) ++i;
      std::size_t j = i;
      while (j < line.size() && line[j] != ' ' && line[j] != '\t') ++j;
      if (j > i) {
        ++values;
        const char c = line[i];
        numbers = numbers && (std::isdigit(static_cast<unsigned char>(c)) || c == '-' || c == '+' || c == '.' ||
                              c == 'n' || c == 'N' || c == 'i' || c == 'I');
      }
      i = j;
    }
    if (values == 0) continue;
    const Where where{.file = file, .line = line_number, .field = ""};
    if (++rows > layout.points) {
      return Status::BadInput(where, "more point lines than the header's POINTS " + std::to_string(layout.points),
                              "make POINTS the number of points, or remove what follows them");
    }
    if (values != layout.values_per_point || !numbers) {
      return Status::BadInput(where,
                              "a point line needs " + std::to_string(layout.values_per_point) +
                                  " numbers (one per field and COUNT), found " + std::to_string(values) +
                                  (numbers ? " values" : " values, not all numbers"),
                              "check the FIELDS and COUNT lines against the data, or export the point cloud again");
    }
  }
  if (rows != layout.points) {
    return Status::BadInput(
        Where{.file = file, .line = line_number, .field = "POINTS"},
        "the file ends after " + std::to_string(rows) + " of the header's " + std::to_string(layout.points) + " points",
        "the file is incomplete (interrupted copy or export?); export it again");
  }
  return Status::Ok();
}

Result<PointSet> ReadPcdQuiet(const std::filesystem::path& path) {
  const std::string file = path.string();
  std::error_code ec;
  if (!std::filesystem::exists(path, ec)) {
    return Status::NotFound("file '" + file + "' does not exist. Check the path");
  }
  if (std::filesystem::is_directory(path, ec)) {
    return Status::BadInput("'" + file + "' is a folder, expected a PCD file");
  }
  const std::uintmax_t file_size = std::filesystem::file_size(path, ec);
  if (ec) return Status::IoError("cannot read the size of '" + file + "': " + ec.message());
  if (file_size == 0) {
    return Status::BadInput(Where{.file = file}, "no points: the file is empty",
                            "export the point cloud again; a PCD file starts with a header");
  }

  {
    // The header is at most a few hundred bytes; 64 KiB leaves room for long comments and many fields.
    std::ifstream in(path, std::ios::binary);
    std::string head(std::min<std::uintmax_t>(file_size, 64 * 1024), '\0');
    in.read(head.data(), static_cast<std::streamsize>(head.size()));
    head.resize(static_cast<std::size_t>(std::max<std::streamsize>(in.gcount(), 0)));
    PcdLayout layout;
    FL_RETURN_IF_ERROR(CheckPcdHeader(file, head, file_size, &layout));
    if (layout.data == "ascii") FL_RETURN_IF_ERROR(CheckPcdAsciiBody(path, layout));
  }
  pcl::PCDReader reader;
  pcl::PCLPointCloud2 cloud;
  Eigen::Vector4f origin;
  Eigen::Quaternionf orientation;
  int version = 0;
  int data_type = 0;
  unsigned int data_index = 0;
  if (reader.readHeader(file, cloud, origin, orientation, version, data_type, data_index) < 0) {
    return Status::BadInput(Where{.file = file}, "PCL cannot read the PCD header (or it declares no points)",
                            FixCheckPcd());
  }
  const std::uint64_t count = static_cast<std::uint64_t>(cloud.width) * cloud.height;
  if (count == 0) {
    return Status::BadInput(Where{.file = file}, "no points: the header declares 0 points",
                            "export a point cloud with at least one point");
  }
  if (data_type == 1) {  // binary: a truncated body is reported with byte counts
    const std::uint64_t expected = count * cloud.point_step;
    const std::uint64_t available = file_size > data_index ? file_size - data_index : 0;
    if (available < expected) {
      const std::uint64_t complete = cloud.point_step == 0 ? 0 : available / cloud.point_step;
      return Status::BadInput(Where{.file = file},
                              "binary point data is truncated at point " + std::to_string(complete) + " (byte offset " +
                                  std::to_string(data_index + complete * cloud.point_step) + "): expected " +
                                  std::to_string(expected) + " bytes for " + std::to_string(count) + " points of " +
                                  std::to_string(cloud.point_step) + " bytes, only " + std::to_string(available) +
                                  " bytes are available",
                              "the file is incomplete (interrupted copy or export?); export it again");
    }
  }
  cloud = pcl::PCLPointCloud2();
  if (reader.read(file, cloud, origin, orientation, version) < 0) {
    return Status::BadInput(Where{.file = file}, "PCL cannot read the PCD data (corrupt or truncated)", FixCheckPcd());
  }
  const std::uint64_t n = static_cast<std::uint64_t>(cloud.width) * cloud.height;
  if (n == 0) {
    return Status::BadInput(Where{.file = file}, "no points: the file holds 0 points",
                            "export a point cloud with at least one point");
  }
  if (cloud.data.size() < n * cloud.point_step) {
    return Status::BadInput(Where{.file = file},
                            "PCL returned " + std::to_string(cloud.data.size()) + " bytes for " + std::to_string(n) +
                                " points of " + std::to_string(cloud.point_step) + " bytes",
                            FixCheckPcd());
  }

  // Plan: one role per field.
  std::vector<PcdRole> roles;
  std::vector<int> scalar_index;
  PointSet points;
  bool seen[8] = {};
  for (std::size_t f = 0; f < cloud.fields.size(); ++f) {
    const pcl::PCLPointField& field = cloud.fields[f];
    const PcdRole role = PcdRoleOf(field.name);
    roles.push_back(role);
    scalar_index.push_back(-1);
    if (role == PcdRole::kSkip) continue;
    const Where where{.file = file, .field = field.name};
    for (std::size_t g = 0; g < f; ++g) {
      if (cloud.fields[g].name == field.name || (role != PcdRole::kScalar && PcdRoleOf(cloud.fields[g].name) == role)) {
        return Status::BadInput(where,
                                "the field appears twice (as '" + cloud.fields[g].name + "' and '" + field.name + "')",
                                "rename or remove one of the two fields");
      }
    }
    if (field.count != 1) {
      return Status::BadInput(
          where,
          "the field has " + std::to_string(field.count) + " values per point; only single-value fields are read",
          "export the points without multi-value fields (e.g. descriptors)");
    }
    if (PcdTypeSize(field.datatype) == 0 ||
        field.offset + PcdTypeSize(field.datatype) > static_cast<std::size_t>(cloud.point_step)) {
      return Status::BadInput(where, "the field has an unsupported type (" + std::to_string(field.datatype) + ")",
                              "store the field as I, U or F of size 1, 2, 4 or 8");
    }
    if (role == PcdRole::kScalar) {
      scalar_index.back() = static_cast<int>(points.scalars.size());
      points.scalars.push_back({field.name, {}});
      points.scalars.back().values.reserve(n);
    } else {
      seen[static_cast<int>(role)] = true;
    }
  }
  for (const char* axis : {"x", "y", "z"}) {
    if (!seen[static_cast<int>(PcdRoleOf(axis))]) {
      std::string found;
      for (const auto& field : cloud.fields) found += (found.empty() ? "" : ", ") + field.name;
      return Status::BadInput(Where{.file = file, .field = axis},
                              "no field '" + std::string(axis) + "' (found: " + found + ")",
                              "store the coordinates in fields named x, y and z");
    }
  }
  const int normal_count = seen[3] + seen[4] + seen[5];
  if (normal_count != 0 && normal_count != 3) {
    const char* missing = !seen[3] ? "normal_x" : !seen[4] ? "normal_y" : "normal_z";
    return Status::BadInput(Where{.file = file, .field = missing},
                            "normal fields must come as normal_x, normal_y and normal_z together; '" +
                                std::string(missing) + "' is missing",
                            "add the missing normal field or remove the other normal fields");
  }
  const bool has_normals = normal_count == 3;
  const bool has_id = seen[6];
  const bool has_t = seen[7];
  points.points.reserve(n);
  if (has_normals) points.normals.reserve(n);
  if (has_id) points.ids.reserve(n);
  if (has_t) points.times_s.reserve(n);

  for (std::uint64_t i = 0; i < n; ++i) {
    const std::uint8_t* base = cloud.data.data() + i * cloud.point_step;
    Eigen::Vector3d p = Eigen::Vector3d::Zero();
    Eigen::Vector3d normal = Eigen::Vector3d::Zero();
    double t = 0;
    std::int64_t id = 0;
    for (std::size_t f = 0; f < cloud.fields.size(); ++f) {
      if (roles[f] == PcdRole::kSkip) continue;
      const pcl::PCLPointField& field = cloud.fields[f];
      const std::uint8_t* at = base + field.offset;
      if (roles[f] == PcdRole::kId && IsIntegerType(field.datatype)) {
        id = LoadPcdId(at, field.datatype);
        continue;
      }
      const double value = LoadPcd(at, field.datatype);
      if (!std::isfinite(value)) {
        return Status::BadInput(Where{.file = file, .field = field.name},
                                "point " + std::to_string(i) + " (byte offset " +
                                    std::to_string(data_index + i * cloud.point_step + field.offset) +
                                    " for binary data): value is not finite (NaN or infinity)",
                                "remove invalid points first (PCL marks missing points of organized clouds with "
                                "NaN; pcl::removeNaNFromPointCloud drops them)");
      }
      switch (roles[f]) {
        case PcdRole::kX:
          p.x() = value;
          break;
        case PcdRole::kY:
          p.y() = value;
          break;
        case PcdRole::kZ:
          p.z() = value;
          break;
        case PcdRole::kNx:
          normal.x() = value;
          break;
        case PcdRole::kNy:
          normal.y() = value;
          break;
        case PcdRole::kNz:
          normal.z() = value;
          break;
        case PcdRole::kT:
          t = value;
          break;
        case PcdRole::kId:
          if (std::floor(value) != value || std::abs(value) >= 0x1p63) {
            return Status::BadInput(Where{.file = file, .field = field.name},
                                    "point " + std::to_string(i) + ": id " + FormatExact(value) + " is not an integer",
                                    "store ids as whole numbers");
          }
          id = static_cast<std::int64_t>(value);
          break;
        case PcdRole::kScalar:
          points.scalars[scalar_index[f]].values.push_back(value);
          break;
        case PcdRole::kSkip:
          break;
      }
    }
    FL_RETURN_IF_ERROR(CheckCoordinateRange(p, Where{.file = file}, "point " + std::to_string(i) + ": "));
    points.points.push_back(p);
    if (has_normals) points.normals.push_back(normal);
    if (has_id) points.ids.push_back(id);
    if (has_t) points.times_s.push_back(t);
  }
  return points;
}

void AddField(const std::string& name, std::uint8_t datatype, pcl::PCLPointCloud2* cloud) {
  pcl::PCLPointField field;
  field.name = name;
  field.offset = cloud->point_step;
  field.datatype = datatype;
  field.count = 1;
  cloud->fields.push_back(field);
  cloud->point_step += static_cast<pcl::uindex_t>(PcdTypeSize(datatype));
}

Status WritePcdQuiet(const std::filesystem::path& path, const PointSet& points, const PointWriteOptions& options) {
  const std::string file = path.string();
  FL_RETURN_IF_ERROR(points.Validate(file));
  for (const auto& column : points.scalars) {
    if (column.name.find_first_of(" \t\r\n") != std::string::npos || column.name == "_" ||
        PcdRoleOf(column.name) != PcdRole::kScalar) {
      return Status::BadInput(Where{.file = file, .field = column.name},
                              "scalar name cannot be stored as a PCD field name",
                              "rename the scalar to letters, digits and '_' (e.g. deviation_um)");
    }
  }
  // ids as I 4 when they fit, else as F 8 (exact up to 2^53).
  FL_ASSIGN_OR_RETURN(const bool ids_fit_int, IdsFitInt32(points, file, "PCD"));

  const std::size_t n = points.size();
  if (n > std::numeric_limits<std::uint32_t>::max()) {
    return Status::BadInput(Where{.file = file}, "PCD holds at most 2^32-1 points", "split the point set");
  }
  pcl::PCLPointCloud2 cloud;
  cloud.height = 1;
  cloud.width = static_cast<pcl::uindex_t>(n);
  cloud.is_dense = true;
  constexpr std::uint8_t kF8 = pcl::PCLPointField::FLOAT64;
  constexpr std::uint8_t kI4 = pcl::PCLPointField::INT32;
  for (const char* name : {"x", "y", "z"}) AddField(name, kF8, &cloud);
  if (points.has_normals()) {
    for (const char* name : {"normal_x", "normal_y", "normal_z"}) AddField(name, kF8, &cloud);
  }
  if (points.has_ids()) AddField("id", ids_fit_int ? kI4 : kF8, &cloud);
  if (points.has_times()) AddField("t", kF8, &cloud);
  for (const auto& column : points.scalars) AddField(column.name, kF8, &cloud);
  cloud.row_step = cloud.point_step * cloud.width;

  pcl::PCDWriter writer;
  const Eigen::Vector4f origin = Eigen::Vector4f::Zero();
  const Eigen::Quaternionf orientation = Eigen::Quaternionf::Identity();
  std::string out;
  if (options.binary) {
    // PCDWriter::writeBinary appends the DATA line itself; generateHeaderBinary stops before it.
    out = writer.generateHeaderBinary(cloud, origin, orientation) + "DATA binary\n";
    const std::size_t header_size = out.size();
    out.resize(header_size + static_cast<std::size_t>(cloud.point_step) * n);
    char* cursor = out.data() + header_size;
    auto put_double = [&cursor](double value) {
      std::memcpy(cursor, &value, 8);
      cursor += 8;
    };
    for (std::size_t i = 0; i < n; ++i) {
      for (int k = 0; k < 3; ++k) put_double(points.points[i][k]);
      if (points.has_normals()) {
        for (int k = 0; k < 3; ++k) put_double(points.normals[i][k]);
      }
      if (points.has_ids()) {
        if (ids_fit_int) {
          const std::int32_t id = static_cast<std::int32_t>(points.ids[i]);
          std::memcpy(cursor, &id, 4);
          cursor += 4;
        } else {
          put_double(static_cast<double>(points.ids[i]));
        }
      }
      if (points.has_times()) put_double(points.times_s[i]);
      for (const auto& column : points.scalars) put_double(column.values[i]);
    }
  } else {
    out = writer.generateHeaderASCII(cloud, origin, orientation) + "DATA ascii\n";
    auto number = [&](double value) {
      return options.precision < 0 ? FormatExact(value) : FormatFixed(value, options.precision);
    };
    for (std::size_t i = 0; i < n; ++i) {
      std::string line =
          number(points.points[i].x()) + " " + number(points.points[i].y()) + " " + number(points.points[i].z());
      if (points.has_normals()) {
        for (int k = 0; k < 3; ++k) line += " " + number(points.normals[i][k]);
      }
      if (points.has_ids()) line += " " + std::to_string(points.ids[i]);
      if (points.has_times()) line += " " + number(points.times_s[i]);
      for (const auto& column : points.scalars) line += " " + number(column.values[i]);
      out += line;
      out += '\n';
    }
  }
  // formloop's marker after PCL's "# .PCD v0.7" line (readers skip '#' lines in the header).
  out.insert(out.find('\n') + 1, kPointFileMarker);
  return WriteFileAtomic(path, out, /*binary=*/true);
}

}  // namespace

Result<PointSet> ReadPcd(const std::filesystem::path& path) {
  QuietPcl quiet;
  try {
    return ReadPcdQuiet(path);
  } catch (const std::exception& e) {
    return Status::BadInput(Where{.file = path.string()}, std::string("PCL failed to read the file: ") + e.what(),
                            FixCheckPcd());
  }
}

Status WritePcd(const std::filesystem::path& path, const PointSet& points, const PointWriteOptions& options) {
  QuietPcl quiet;
  try {
    return WritePcdQuiet(path, points, options);
  } catch (const std::exception& e) {
    return Status::Internal("writing '" + path.string() + "' through PCL failed: " + e.what());
  }
}

}  // namespace formloop
