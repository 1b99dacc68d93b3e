#pragma once
// Point-set files: CSV, XYZ, PLY (ASCII and binary) and PCD (through PCL).
//
// CSV: read by the one CSV reader (core/csv.h: '#' and blank lines skipped, cells trimmed): a header
//   row naming the columns, then one row per point. Columns x, y, z are required; nx, ny, nz (all
//   three or none), id and t are optional; every other column becomes a named scalar. Numbers are
//   parsed without the locale.
// XYZ: whitespace-separated "x y z" or "x y z nx ny nz" per line, '#' comments, no header.
// PLY: element "vertex" with properties x, y, z, optional nx, ny, nz, id, t and any other scalar
//   properties (char..double types); ascii, binary_little_endian and binary_big_endian are read;
//   ascii or binary_little_endian are written (doubles). Other elements (faces) are skipped on read.
// PCD: through pcl::PCDReader / pcl::PCDWriter; fields map like PLY properties.
//
// Readers reject bad files with a message naming file, line (or byte offset) and field: missing
// columns, non-numbers, NaN/inf, empty files, truncated binary data. Writers write atomically
// (core/atomic_file.h): on error no output file is left.

#include <filesystem>
#include <string>
#include <vector>

#include "core/number_text.h"
#include "core/point_set.h"
#include "core/status.h"

namespace formloop {

enum class PointFormat { kCsv, kXyz, kPly, kPcd };

// From the extension (.csv .xyz .txt .ply .pcd, case-insensitive); BadInput names the path otherwise.
Result<PointFormat> PointFormatFromPath(const std::filesystem::path& path);

// The comment formloop writes as the first line of its CSV and XYZ point files and after PCD's first line: its
// marker as the writer of the file (core/output_file.h). Every reader skips '#' lines.
inline constexpr const char* kPointFileMarker = "# formloop point file\n";

struct PointWriteOptions {
  bool binary = true;  // PLY and PCD: binary (little-endian) rather than ASCII
  int precision = 9;   // CSV/XYZ/ASCII PLY/ASCII PCD: digits after the decimal point (mm -> 1 nm at 6);
                       // negative: shortest text that reads back exactly (FormatExact)
};

// Every reader refuses a coordinate beyond ±kMaxCoordinateMm (1 km): no machine or part is that large, and
// such a value (1e300 typed or exported by mistake) breaks every kd-tree and fit downstream.
inline constexpr double kMaxCoordinateMm = 1e6;
// BadInput at `where` (its field set to the axis) when a coordinate of p is beyond kMaxCoordinateMm;
// `what` names the point ("vertex 12: ") when the line is unknown.
Status CheckCoordinateRange(const Eigen::Vector3d& p, Where where, const std::string& what = "");

// Where the rows of a CSV point file stand in it, for messages about them (ReadCsv fills it).
struct CsvLayout {
  long header_line = 0;
  std::string header_text;      // the header line as written (trimmed)
  std::vector<long> row_lines;  // 1-based file line of each point
};
Result<PointSet> ReadCsv(const std::filesystem::path& path, CsvLayout* layout = nullptr);
Result<PointSet> ReadXyz(const std::filesystem::path& path);
Result<PointSet> ReadPly(const std::filesystem::path& path);
Result<PointSet> ReadPcd(const std::filesystem::path& path);
Status WriteCsv(const std::filesystem::path& path, const PointSet& points, const PointWriteOptions& options = {});
Status WriteXyz(const std::filesystem::path& path, const PointSet& points, const PointWriteOptions& options = {});
Status WritePly(const std::filesystem::path& path, const PointSet& points, const PointWriteOptions& options = {});
Status WritePcd(const std::filesystem::path& path, const PointSet& points, const PointWriteOptions& options = {});

// Dispatch on the extension.
Result<PointSet> ReadPoints(const std::filesystem::path& path);
Status WritePoints(const std::filesystem::path& path, const PointSet& points, const PointWriteOptions& options = {});

// Binary PLY/PCD store ids as 4-byte ints when every id fits, else as doubles (exact to ±2^53).
// Returns whether they fit; BadInput naming the file when an id cannot be stored exactly.
Result<bool> IdsFitInt32(const PointSet& points, const std::string& file, const std::string& format);

}  // namespace formloop
