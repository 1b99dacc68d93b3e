#include "nc-gen/compensation.h"

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <map>
#include <memory>
#include <string_view>
#include <system_error>

#include "core/atomic_file.h"
#include "core/csv.h"
#include "core/number_text.h"
#include "core/parallel.h"
#include "nc-gen/toolpath_io.h"

namespace formloop::nc {
namespace {

std::size_t FeedMoveCount(const std::vector<ProgramMove>& moves) {
  return static_cast<std::size_t>(
      std::count_if(moves.begin(), moves.end(), [](const ProgramMove& m) { return !m.rapid; }));
}

std::vector<const ProgramMove*> FeedMoves(const std::vector<ProgramMove>& moves) {
  std::vector<const ProgramMove*> feeds;
  for (const auto& m : moves) {
    if (!m.rapid) feeds.push_back(&m);
  }
  return feeds;
}

std::string Vec(const Eigen::Vector3d& v_mm) {
  return "(" + FormatFixed(1e3 * v_mm.x(), 3) + ", " + FormatFixed(1e3 * v_mm.y(), 3) + ", " +
         FormatFixed(1e3 * v_mm.z(), 3) + ") um";
}

constexpr const char* kSideColumns[] = {"cl_index",  "pass",      "nominal_line", "compensated_line",
                                        "nominal_x", "nominal_y", "nominal_z",    "offset_x",
                                        "offset_y",  "offset_z",  "ds_um"};
constexpr const char* kFieldColumns[] = {"u", "v", "nx", "ny", "nz"};

}  // namespace

Status CompensationOptions::Validate() const {
  if (!(max_offset_um > 0)) return Status::BadInput(Where{.field = "compensation.max_offset_um"}, "must be > 0");
  return Status::Ok();
}

namespace {

// The safety limit on one offset (SafetyLimit naming the CL point and its pass).
Status CheckOffset(double ds_mm, std::size_t k, int pass, const CompensationOptions& options) {
  if (std::abs(ds_mm) * 1e3 <= options.max_offset_um) return Status::Ok();
  return Status::SafetyLimit("compensation offset " + FormatFixed(ds_mm * 1e3, 1) + " um at CL point " +
                             std::to_string(k) + " (pass " + std::to_string(pass) + ") exceeds the limit " +
                             FormatFixed(options.max_offset_um, 1) +
                             " um; no compensated program was written. Fix: check the measurement, or raise "
                             "compensation.max_offset_um if the error is real");
}

}  // namespace

Result<Compensation> CompensateToolpath(const Toolpath& nominal, const SystematicField& systematic,
                                        const std::string& source, const CompensationOptions& options) {
  FL_RETURN_IF_ERROR(options.Validate());
  Compensation result;
  result.path = nominal;
  result.source = source;
  for (std::size_t k = 0; k < nominal.points.size(); ++k) {
    ClPoint& cl = result.path.points[k];
    // Leads are off Q: nothing to compensate; they keep their nominal place (offset 0, no field point).
    const bool on_q = cl.kind == ClKind::kCut;
    const double ds_mm = on_q ? systematic(cl.u, cl.v) : 0.0;
    FL_RETURN_IF_ERROR(CheckOffset(ds_mm, k, cl.pass, options));
    cl.cc = nominal.points[k].cc - ds_mm * cl.normal;
    CompensationEntry entry;
    entry.cl_index = k;
    entry.nominal_tip = nominal.points[k].tip;
    entry.systematic_um = ds_mm * 1e3;
    entry.pass = cl.pass;
    entry.u = cl.u;
    entry.v = cl.v;
    entry.normal = cl.normal;
    entry.has_field_point = on_q;
    entry.kind = cl.kind;
    result.entries.push_back(entry);
  }
  UpdateCutterLocations(&result.path);
  result.blocks = result.entries.size();
  for (auto& entry : result.entries) {
    entry.offset_mm = result.path.points[entry.cl_index].tip - entry.nominal_tip;
    result.max_offset_um = std::max(result.max_offset_um, 1e3 * entry.offset_mm.norm());
  }
  // Keep the nominal program's safe Z so the rapids do not change.
  result.path.safe_z_mm = std::max(result.path.safe_z_mm, nominal.safe_z_mm);
  return result;
}

Status AssignProgramLines(const std::vector<ProgramMove>& nominal, const std::vector<ProgramMove>& compensated,
                          Compensation* compensation) {
  const auto a = FeedMoves(nominal), b = FeedMoves(compensated);
  if (a.size() != compensation->entries.size() || b.size() != compensation->entries.size()) {
    return Status::Internal("programs have " + std::to_string(a.size()) + " and " + std::to_string(b.size()) +
                            " feed moves for " + std::to_string(compensation->entries.size()) + " CL points");
  }
  for (std::size_t k = 0; k < a.size(); ++k) {
    compensation->entries[k].nominal_line = a[k]->line;
    compensation->entries[k].compensated_line = b[k]->line;
  }
  return Status::Ok();
}

namespace {

// The compact side file (compensation.h): magic, version, flags, row count, source, then the rows as
// zig-zag LEB128 varints of the change from the row before and raw little-endian doubles for u, v and lambda.
constexpr char kSideMagic[8] = {'\x89', 'F', 'L', 'S', 'I', 'D', 'E', '\n'};
constexpr std::uint32_t kSideVersion = 1;
constexpr std::uint32_t kSideFlagLambda = 1;
constexpr std::size_t kSideRowCountAt = 16;  // after the magic, the version and the flags
constexpr double kTipScale = 1e6;            // nominal tip: 1 nm (10^-6 mm)
constexpr double kOffsetScale = 1e9;         // offset: 1 pm (10^-9 mm)
constexpr double kDsScale = 1e6;             // d_s: 10^-6 um
constexpr double kNormalScale = 1e9;         // unit normal: 10^-9
constexpr double kLargestQuantum = 4e18;     // |value · scale| must stay below this (int64 with room for deltas)

void PutU64(std::uint64_t value, std::string* out) {
  while (value >= 0x80) {
    out->push_back(static_cast<char>((value & 0x7f) | 0x80));
    value >>= 7;
  }
  out->push_back(static_cast<char>(value));
}
void PutI64(std::int64_t value, std::string* out) {
  PutU64((static_cast<std::uint64_t>(value) << 1) ^ static_cast<std::uint64_t>(value >> 63), out);
}
void PutFixed(std::uint64_t value, int bytes, std::string* out) {
  for (int b = 0; b < bytes; ++b) out->push_back(static_cast<char>((value >> (8 * b)) & 0xff));
}
void PutDouble(double value, std::string* out) {
  std::uint64_t bits = 0;
  std::memcpy(&bits, &value, sizeof bits);
  PutFixed(bits, 8, out);
}

std::uint8_t KindCode(ClKind kind) {
  switch (kind) {
    case ClKind::kCut:
      return 0;
    case ClKind::kLeadIn:
      return 1;
    case ClKind::kLeadOut:
      return 2;
    case ClKind::kOff:
      return 3;
  }
  return 0;
}

}  // namespace

// The last value written or read of each delta-coded quantity.
struct SideState {
  std::int64_t pass = 0, nominal_line = 0, compensated_line = 0, ds = 0;
  std::int64_t tip[3] = {0, 0, 0}, offset[3] = {0, 0, 0}, normal[3] = {0, 0, 0};
};

SideFileWriter::SideFileWriter(const std::filesystem::path& path, const std::string& source, bool program_mapped)
    : file_(path, /*binary=*/path.extension() != ".csv"),
      binary_(path.extension() != ".csv"),
      program_mapped_(program_mapped),
      state_(std::make_unique<SideState>()) {
  status_ = file_.open_status();
  if (binary_) {
    buffer_.append(kSideMagic, sizeof kSideMagic);
    PutFixed(kSideVersion, 4, &buffer_);
    PutFixed(program_mapped ? kSideFlagLambda : 0, 4, &buffer_);
    PutFixed(0, 8, &buffer_);  // the row count at kSideRowCountAt, filled in by Commit
    PutFixed(source.size(), 4, &buffer_);
    buffer_ += source;
    return;
  }
  buffer_ = "# formloop compensation side file: per CL point, the nominal tip, the applied offset, its source\n";
  buffer_ += "# source: " + source + "\n";
  buffer_ +=
      "cl_index,pass,nominal_line,compensated_line,nominal_x,nominal_y,nominal_z,offset_x,offset_y,offset_z,ds_um,"
      "u,v,nx,ny,nz,kind";
  buffer_ += program_mapped ? ",lambda\n" : "\n";
}

SideFileWriter::~SideFileWriter() = default;

void SideFileWriter::Flush() {
  if (!status_.ok()) return;
  file_.stream() << buffer_;
  buffer_.clear();
}

void SideFileWriter::Add(const CompensationEntry& e) {
  if (buffer_.size() > (1 << 16)) Flush();
  const std::uint64_t row = rows_++;
  if (!binary_) {
    buffer_ += std::to_string(e.cl_index) + "," + std::to_string(e.pass) + "," + std::to_string(e.nominal_line) + "," +
               std::to_string(e.compensated_line);
    for (int a = 0; a < 3; ++a) buffer_ += "," + FormatFixed(e.nominal_tip[a], 6);
    for (int a = 0; a < 3; ++a) buffer_ += "," + FormatFixed(e.offset_mm[a], 6);
    buffer_ += "," + FormatFixed(e.systematic_um, 4);
    buffer_ += "," + FormatExact(e.u) + "," + FormatExact(e.v);
    for (int a = 0; a < 3; ++a) buffer_ += "," + FormatFixed(e.normal[a], 9);
    buffer_ += std::string(",") + ClKindName(e.kind);
    buffer_ += program_mapped_ ? "," + FormatExact(e.lambda) + "\n" : "\n";
    return;
  }
  if (e.cl_index != row && status_.ok()) {
    status_ = Status::Internal("side file: entry " + std::to_string(row) + " names CL point " +
                               std::to_string(e.cl_index) + "; rows must list every CL point in order");
  }
  SideState& s = *state_;
  auto delta = [&](std::int64_t value, std::int64_t* last) {
    PutI64(value - *last, &buffer_);
    *last = value;
  };
  auto quantum = [&](double value, double scale, const char* what) -> std::int64_t {
    const double q = std::nearbyint(value * scale);
    if (!(std::abs(q) < kLargestQuantum) && status_.ok()) {
      status_ = Status::Internal("side file: " + std::string(what) + " of CL point " + std::to_string(row) + " (" +
                                 FormatSignificant(value, 17) + ") cannot be stored");
    }
    return std::abs(q) < kLargestQuantum ? static_cast<std::int64_t>(q) : 0;
  };
  buffer_.push_back(static_cast<char>(KindCode(e.kind)));
  delta(e.pass, &s.pass);
  delta(e.nominal_line, &s.nominal_line);
  delta(e.compensated_line, &s.compensated_line);
  for (int a = 0; a < 3; ++a) delta(quantum(e.nominal_tip[a], kTipScale, "the nominal tip"), &s.tip[a]);
  for (int a = 0; a < 3; ++a) delta(quantum(e.offset_mm[a], kOffsetScale, "the offset"), &s.offset[a]);
  delta(quantum(e.systematic_um, kDsScale, "d_s"), &s.ds);
  PutDouble(e.u, &buffer_);
  PutDouble(e.v, &buffer_);
  for (int a = 0; a < 3; ++a) delta(quantum(e.normal[a], kNormalScale, "the normal"), &s.normal[a]);
  if (program_mapped_) PutDouble(e.lambda, &buffer_);
}

Status SideFileWriter::Commit() {
  Flush();
  FL_RETURN_IF_ERROR(status_);
  if (binary_) {  // the row count, now known, into its place in the header
    std::string count;
    PutFixed(rows_, 8, &count);
    file_.stream().seekp(static_cast<std::streamoff>(kSideRowCountAt));
    file_.stream() << count;
  }
  return file_.Commit();
}

Status WriteSideFile(const std::filesystem::path& path, const Compensation& compensation) {
  // Streamed row by row into the temporary file (a million rows are ~180 MB of text or ~50 MB compact).
  SideFileWriter writer(path, compensation.source, compensation.program_mapped);
  for (const auto& e : compensation.entries) writer.Add(e);
  return writer.Commit();
}

Result<double> VerifyCompensation(const std::vector<ProgramMove>& nominal, const std::vector<ProgramMove>& compensated,
                                  const Compensation& compensation) {
  const auto a = FeedMoves(nominal), b = FeedMoves(compensated);
  if (a.size() != b.size() || a.size() != compensation.entries.size()) {
    return Status::Failed("compensation check: the programs have " + std::to_string(a.size()) + " and " +
                          std::to_string(b.size()) + " feed moves, the side file " +
                          std::to_string(compensation.entries.size()) + " entries");
  }
  double worst = 0;
  for (std::size_t k = 0; k < a.size(); ++k) {
    const Eigen::Vector3d program_offset = b[k]->tip - a[k]->tip;
    worst = std::max(worst, 1e3 * (program_offset - compensation.entries[k].offset_mm).norm());
  }
  return worst;
}

namespace {

// The compact side file (SideFileWriter) read back; every problem names the file, the row and the byte.
class SideBytes {
 public:
  SideBytes(std::string_view bytes, const std::string& source) : bytes_(bytes), source_(source) {}
  std::size_t at() const { return at_; }
  bool done() const { return at_ == bytes_.size(); }
  void Skip(std::size_t count) { at_ = std::min(bytes_.size(), at_ + count); }
  Status Fixed(int count, std::uint64_t* value, const std::string& what) {
    if (bytes_.size() - at_ < static_cast<std::size_t>(count)) return Truncated(what);
    *value = 0;
    for (int b = 0; b < count; ++b) {
      *value |= static_cast<std::uint64_t>(static_cast<unsigned char>(bytes_[at_ + b])) << (8 * b);
    }
    at_ += static_cast<std::size_t>(count);
    return Status::Ok();
  }
  Status Double(double* value, const std::string& what) {
    std::uint64_t bits = 0;
    FL_RETURN_IF_ERROR(Fixed(8, &bits, what));
    std::memcpy(value, &bits, sizeof bits);
    if (!std::isfinite(*value)) return Bad(what + " is not a finite number");
    return Status::Ok();
  }
  Status Varint(std::int64_t* value, const std::string& what) {
    std::uint64_t u = 0;
    for (int shift = 0;; shift += 7) {
      if (at_ == bytes_.size()) return Truncated(what);
      if (shift > 63) return Bad(what + ": a number longer than 64 bits");
      const auto byte = static_cast<unsigned char>(bytes_[at_++]);
      u |= static_cast<std::uint64_t>(byte & 0x7f) << shift;
      if ((byte & 0x80) == 0) break;
    }
    *value = static_cast<std::int64_t>(u >> 1) ^ -static_cast<std::int64_t>(u & 1);
    return Status::Ok();
  }
  Status Bad(const std::string& what) const {
    return Status::BadInput(Where{.file = source_}, "byte " + std::to_string(at_) + ": " + what,
                            "use the side file formloop wrote (a damaged or cut-short file cannot be checked)");
  }

 private:
  Status Truncated(const std::string& what) const { return Bad("the file ends inside " + what + " (cut short?)"); }
  std::string_view bytes_;
  const std::string& source_;
  std::size_t at_ = 0;
};

bool IsCompactSideFile(std::string_view bytes) {
  return bytes.size() >= sizeof kSideMagic && bytes.compare(0, sizeof kSideMagic, {kSideMagic, sizeof kSideMagic}) == 0;
}

Result<SideFile> ParseCompactSideFile(std::string_view bytes, const std::string& source) {
  SideBytes in(bytes, source);
  std::uint64_t magic = 0, version = 0, flags = 0, rows = 0, source_bytes = 0;
  FL_RETURN_IF_ERROR(in.Fixed(8, &magic, "the magic"));
  FL_RETURN_IF_ERROR(in.Fixed(4, &version, "the version"));
  if (version != kSideVersion) {
    return in.Bad("format version " + std::to_string(version) + "; this formloop reads version " +
                  std::to_string(kSideVersion) + " (and the CSV side files)");
  }
  FL_RETURN_IF_ERROR(in.Fixed(4, &flags, "the flags"));
  if ((flags & ~static_cast<std::uint64_t>(kSideFlagLambda)) != 0) return in.Bad("unknown flags");
  FL_RETURN_IF_ERROR(in.Fixed(8, &rows, "the row count"));
  FL_RETURN_IF_ERROR(in.Fixed(4, &source_bytes, "the source's length"));
  if (bytes.size() - in.at() < source_bytes) return in.Bad("the file ends inside the source text (cut short?)");
  SideFile side;
  side.source = std::string(bytes.substr(in.at(), source_bytes));
  in.Skip(source_bytes);
  SideBytes& rest = in;
  const std::size_t base = in.at();
  side.has_field_points = true;
  side.has_lambda = (flags & kSideFlagLambda) != 0;
  // A row takes at least 20 bytes: a count beyond that is a damaged header, not a reason to reserve memory.
  if (rows > (bytes.size() - base) / 20 + 1) {
    return in.Bad("the header counts " + std::to_string(rows) + " rows, more than the " +
                  std::to_string(bytes.size() - base) + " bytes after it hold (cut short or damaged?)");
  }
  side.entries.reserve(static_cast<std::size_t>(rows));
  SideState s;
  for (std::uint64_t row = 0; row < rows; ++row) {
    const std::string where = "row " + std::to_string(row);
    auto delta = [&](std::int64_t* last, const char* what) -> Status {
      std::int64_t change = 0;
      FL_RETURN_IF_ERROR(rest.Varint(&change, where + " " + what));
      *last += change;
      return Status::Ok();
    };
    CompensationEntry e;
    e.cl_index = static_cast<std::size_t>(row);
    std::uint64_t kind = 0;
    FL_RETURN_IF_ERROR(rest.Fixed(1, &kind, where + " kind"));
    if (kind > 3)
      return rest.Bad(where + ": kind " + std::to_string(kind) + " is not 0..3 (cut, lead-in, lead-out, off)");
    e.kind = kind == 0 ? ClKind::kCut : kind == 1 ? ClKind::kLeadIn : kind == 2 ? ClKind::kLeadOut : ClKind::kOff;
    FL_RETURN_IF_ERROR(delta(&s.pass, "pass"));
    FL_RETURN_IF_ERROR(delta(&s.nominal_line, "nominal_line"));
    FL_RETURN_IF_ERROR(delta(&s.compensated_line, "compensated_line"));
    if (s.pass < 0 || s.pass > INT32_MAX || s.nominal_line < 0 || s.compensated_line < 0) {
      return rest.Bad(where + ": a negative pass or line");
    }
    e.pass = static_cast<int>(s.pass);
    e.nominal_line = static_cast<long>(s.nominal_line);
    e.compensated_line = static_cast<long>(s.compensated_line);
    for (int a = 0; a < 3; ++a) {
      FL_RETURN_IF_ERROR(delta(&s.tip[a], "nominal tip"));
      e.nominal_tip[a] = static_cast<double>(s.tip[a]) / kTipScale;
    }
    for (int a = 0; a < 3; ++a) {
      FL_RETURN_IF_ERROR(delta(&s.offset[a], "offset"));
      e.offset_mm[a] = static_cast<double>(s.offset[a]) / kOffsetScale;
    }
    FL_RETURN_IF_ERROR(delta(&s.ds, "ds"));
    e.systematic_um = static_cast<double>(s.ds) / kDsScale;
    FL_RETURN_IF_ERROR(rest.Double(&e.u, where + " u"));
    FL_RETURN_IF_ERROR(rest.Double(&e.v, where + " v"));
    for (int a = 0; a < 3; ++a) {
      FL_RETURN_IF_ERROR(delta(&s.normal[a], "normal"));
      e.normal[a] = static_cast<double>(s.normal[a]) / kNormalScale;
    }
    if (std::abs(e.normal.norm() - 1) > 1e-6) return rest.Bad(where + ": the normal is not a unit vector");
    if (side.has_lambda) {
      FL_RETURN_IF_ERROR(rest.Double(&e.lambda, where + " lambda"));
      if (!(e.lambda > 0 && e.lambda <= 1)) return rest.Bad(where + ": lambda is not in (0, 1]");
    }
    e.has_field_point = e.kind == ClKind::kCut;
    side.entries.push_back(e);
  }
  if (!rest.done()) return rest.Bad("bytes after the last of the " + std::to_string(rows) + " rows");
  return side;
}

}  // namespace

Result<SideFile> ParseSideFile(const std::string& text, const std::string& source) {
  if (IsCompactSideFile(text)) return ParseCompactSideFile(text, source);
  SideFile side;
  CsvReader rows(text, /*comments=*/true);
  long number = 0;
  std::map<std::string, std::size_t> column;
  std::size_t columns = 0;
  while (rows.Next()) {
    number = rows.line_number();
    if (rows.is_comment()) {
      if (rows.line().rfind("# source:", 0) == 0) side.source = std::string(TrimBlanks(rows.line().substr(9)));
      continue;
    }
    const std::vector<std::string> cells(rows.cells().begin(), rows.cells().end());
    if (columns == 0) {
      for (std::size_t c = 0; c < cells.size(); ++c) column[cells[c]] = c;
      for (const char* name : kSideColumns) {
        if (!column.count(name)) {
          return Status::BadInput(Where{.file = source, .line = number, .field = name}, "the header lacks this column",
                                  "use the side file formloop wrote");
        }
      }
      int field_columns = 0;
      for (const char* name : kFieldColumns) field_columns += column.count(name) ? 1 : 0;
      if (field_columns != 0 && field_columns != 5) {
        return Status::BadInput(Where{.file = source, .line = number},
                                "the header has only some of the columns u, v, nx, ny, nz", "give all five or none");
      }
      side.has_field_points = field_columns == 5;
      columns = cells.size();
      continue;
    }
    if (cells.size() != columns) {
      return Status::BadInput(Where{.file = source, .line = number},
                              "has " + std::to_string(cells.size()) + " fields, the header " + std::to_string(columns));
    }
    auto number_of = [&](const char* name, double* value) -> Status {
      const std::string& cell = cells[column[name]];
      if (!ParseDouble(cell, value) || !std::isfinite(*value)) {
        return Status::BadInput(Where{.file = source, .line = number, .field = name},
                                "value '" + cell + "' is not a finite number");
      }
      return Status::Ok();
    };
    auto integer_of = [&](const char* name, long* value) -> Status {
      double x = 0;
      FL_RETURN_IF_ERROR(number_of(name, &x));
      if (x != std::floor(x) || x < 0 || x > 1e15) {
        return Status::BadInput(Where{.file = source, .line = number, .field = name},
                                "value '" + cells[column[name]] + "' is not a non-negative integer");
      }
      *value = static_cast<long>(x);
      return Status::Ok();
    };
    CompensationEntry e;
    long index = 0, pass = 0;
    FL_RETURN_IF_ERROR(integer_of("cl_index", &index));
    FL_RETURN_IF_ERROR(integer_of("pass", &pass));
    FL_RETURN_IF_ERROR(integer_of("nominal_line", &e.nominal_line));
    FL_RETURN_IF_ERROR(integer_of("compensated_line", &e.compensated_line));
    e.cl_index = static_cast<std::size_t>(index);
    e.pass = static_cast<int>(pass);
    FL_RETURN_IF_ERROR(number_of("nominal_x", &e.nominal_tip.x()));
    FL_RETURN_IF_ERROR(number_of("nominal_y", &e.nominal_tip.y()));
    FL_RETURN_IF_ERROR(number_of("nominal_z", &e.nominal_tip.z()));
    FL_RETURN_IF_ERROR(number_of("offset_x", &e.offset_mm.x()));
    FL_RETURN_IF_ERROR(number_of("offset_y", &e.offset_mm.y()));
    FL_RETURN_IF_ERROR(number_of("offset_z", &e.offset_mm.z()));
    FL_RETURN_IF_ERROR(number_of("ds_um", &e.systematic_um));
    if (column.count("kind")) {
      const std::string& kind = cells[column["kind"]];
      if (kind == "lead-in") {
        e.kind = ClKind::kLeadIn;
      } else if (kind == "lead-out") {
        e.kind = ClKind::kLeadOut;
      } else if (kind == "off") {
        e.kind = ClKind::kOff;
      } else if (kind != "cut") {
        return Status::BadInput(Where{.file = source, .line = number, .field = "kind"},
                                "value '" + kind + "' is not cut, lead-in, lead-out or off");
      }
    }
    if (column.count("lambda")) {
      side.has_lambda = true;
      FL_RETURN_IF_ERROR(number_of("lambda", &e.lambda));
      if (!(e.lambda > 0 && e.lambda <= 1)) {
        return Status::BadInput(Where{.file = source, .line = number, .field = "lambda"},
                                "value '" + cells[column["lambda"]] + "' is not in (0, 1]");
      }
    }
    e.has_field_point = side.has_field_points && e.kind == ClKind::kCut;
    if (side.has_field_points) {
      FL_RETURN_IF_ERROR(number_of("u", &e.u));
      FL_RETURN_IF_ERROR(number_of("v", &e.v));
      FL_RETURN_IF_ERROR(number_of("nx", &e.normal.x()));
      FL_RETURN_IF_ERROR(number_of("ny", &e.normal.y()));
      FL_RETURN_IF_ERROR(number_of("nz", &e.normal.z()));
      if (std::abs(e.normal.norm() - 1) > 1e-6) {
        return Status::BadInput(Where{.file = source, .line = number, .field = "nx"},
                                "the normal (nx, ny, nz) is not a unit vector");
      }
    }
    if (e.cl_index != side.entries.size()) {
      return Status::BadInput(
          Where{.file = source, .line = number, .field = "cl_index"},
          "expected CL point " + std::to_string(side.entries.size()) + ", found " + std::to_string(e.cl_index),
          "rows must list every CL point in order from 0");
    }
    side.entries.push_back(e);
  }
  if (columns == 0) return Status::BadInput(Where{.file = source}, "no header row", "use the side file formloop wrote");
  return side;
}

Result<SideFile> ReadSideFile(const std::filesystem::path& path) {
  {
    FL_ASSIGN_OR_RETURN(const std::string bytes, ReadFile(path));
    if (IsCompactSideFile(bytes)) return ParseCompactSideFile(bytes, path.string());
  }
  FL_ASSIGN_OR_RETURN(std::string text, ReadTextFile(path));  // the text checks (encoding, NUL bytes)
  return ParseSideFile(text, path.string());
}

double ProgramOffsetToleranceUm(int decimals) {
  return 1e3 * std::sqrt(3.0) * std::pow(10.0, -std::max(decimals, 0)) + 0.002;
}

std::string BlockCheck::Describe() const {
  std::string text = "block " + std::to_string(cl_index) + " (pass " + std::to_string(pass) + ", nominal line " +
                     std::to_string(nominal_line) + ", compensated line " + std::to_string(compensated_line) + "): ";
  for (std::size_t k = 0; k < problems.size(); ++k) text += (k ? "; " : "") + problems[k];
  return text;
}

nlohmann::json CheckReport::ToJson() const {
  nlohmann::json blocks_json = nlohmann::json::array();
  auto vec = [](const Eigen::Vector3d& v) { return nlohmann::json::array({1e3 * v.x(), 1e3 * v.y(), 1e3 * v.z()}); };
  for (const auto& b : disagreeing) {
    nlohmann::json j = {{"cl_index", b.cl_index},
                        {"pass", b.pass},
                        {"nominal_line", b.nominal_line},
                        {"compensated_line", b.compensated_line},
                        {"program_offset_um", vec(b.program_offset_mm)},
                        {"side_offset_um", vec(b.side_offset_mm)},
                        {"side_difference_um", b.side_difference_um},
                        {"nominal_tip_difference_um", b.nominal_tip_difference_um},
                        {"problems", b.problems}};
    if (b.field_checked) {
      j["field_offset_um"] = vec(b.field_offset_mm);
      j["field_difference_um"] = b.field_difference_um;
    }
    blocks_json.push_back(j);
  }
  return {{"ok", ok()},
          {"blocks", blocks},
          {"field_checked", field_checked},
          {"tolerance_um", tolerance_um},
          {"max_side_difference_um", max_side_difference_um},
          {"max_field_difference_um", max_field_difference_um},
          {"disagreeing_blocks", blocks_json}};
}

namespace {

// Side row k against the k-th feed block of each program (CheckRow, after both blocks state every axis).
void CheckBlock(std::size_t k, const CompensationEntry& entry, const ProgramMove& a, const ProgramMove& b,
                const SystematicField& field, CheckReport* report) {
  if (!a.tip.allFinite() || !b.tip.allFinite()) {
    BlockCheck block;
    block.cl_index = k;
    block.pass = entry.pass;
    block.nominal_line = a.line;
    block.compensated_line = b.line;
    block.problems.push_back("a feed block does not program all three axes");
    report->disagreeing.push_back(block);
    return;
  }
  CheckRow(k, entry, a.tip, a.line, b.tip, b.line, field, report);
}

}  // namespace

Result<CheckReport> CheckCompensation(const std::vector<ProgramMove>& nominal,
                                      const std::vector<ProgramMove>& compensated, const SideFile& side,
                                      const SystematicField& field, const CheckOptions& options) {
  if (options.program_decimals < 0 || options.program_decimals > 9) {
    return Status::BadInput(Where{.field = "program_decimals"}, "must be 0..9");
  }
  if (!(options.tolerance_um >= 0)) return Status::BadInput(Where{.field = "tolerance_um"}, "must be >= 0");
  const auto a = FeedMoves(nominal), b = FeedMoves(compensated);
  if (a.size() != b.size() || a.size() != side.entries.size()) {
    return Status::Failed("compensation check: the nominal program has " + std::to_string(a.size()) +
                          " feed blocks, the compensated program " + std::to_string(b.size()) + ", the side file " +
                          std::to_string(side.entries.size()) + " rows; they must be equal");
  }
  CheckReport report;
  report.blocks = a.size();
  report.field_checked = static_cast<bool>(field) && side.has_field_points;
  report.tolerance_um =
      options.tolerance_um > 0 ? options.tolerance_um : ProgramOffsetToleranceUm(options.program_decimals);
  for (std::size_t k = 0; k < a.size(); ++k) CheckBlock(k, side.entries[k], *a[k], *b[k], field, &report);
  return report;
}

void CheckRow(std::size_t index, const CompensationEntry& e, const Eigen::Vector3d& nominal_tip, long nominal_line,
              const Eigen::Vector3d& compensated_tip, long compensated_line, const SystematicField& field,
              CheckReport* report) {
  const double tol = report->tolerance_um;
  BlockCheck block;
  block.cl_index = index;
  block.pass = e.pass;
  block.nominal_line = nominal_line;
  block.compensated_line = compensated_line;
  block.program_offset_mm = compensated_tip - nominal_tip;
  block.side_offset_mm = e.offset_mm;
  block.side_difference_um = 1e3 * (block.program_offset_mm - e.offset_mm).norm();
  report->max_side_difference_um = std::max(report->max_side_difference_um, block.side_difference_um);
  if (block.side_difference_um > tol) {
    block.problems.push_back("program offset " + Vec(block.program_offset_mm) + " vs side file " + Vec(e.offset_mm) +
                             ": differ by " + FormatFixed(block.side_difference_um, 3) + " um");
  }
  block.nominal_tip_difference_um = 1e3 * (nominal_tip - e.nominal_tip).norm();
  if (block.nominal_tip_difference_um > tol) {
    block.problems.push_back("nominal program tip differs from the side file's by " +
                             FormatFixed(block.nominal_tip_difference_um, 3) + " um");
  }
  if ((e.nominal_line != 0 && e.nominal_line != nominal_line) ||
      (e.compensated_line != 0 && e.compensated_line != compensated_line)) {
    block.problems.push_back("side file names lines " + std::to_string(e.nominal_line) + "/" +
                             std::to_string(e.compensated_line) + ", the programs " + std::to_string(nominal_line) +
                             "/" + std::to_string(compensated_line));
  }
  if (report->field_checked && e.has_field_point) {
    block.field_checked = true;
    const double ds_mm = field(e.u, e.v);
    block.field_offset_mm = -ds_mm * e.normal;
    block.field_difference_um = 1e3 * (block.program_offset_mm - block.field_offset_mm).norm();
    report->max_field_difference_um = std::max(report->max_field_difference_um, block.field_difference_um);
    if (!(block.field_difference_um <= tol)) {
      block.problems.push_back("program offset " + Vec(block.program_offset_mm) + " vs -d_s*n from the field " +
                               Vec(block.field_offset_mm) + " (d_s " + FormatFixed(1e3 * ds_mm, 3) +
                               " um): differ by " + FormatFixed(block.field_difference_um, 3) + " um");
    }
  }
  if (!block.problems.empty()) report->disagreeing.push_back(block);
}

Result<Compensation> WriteCompensatedProgram(const Toolpath& nominal, const std::vector<ProgramMove>& nominal_moves,
                                             const SystematicField& systematic, const std::string& source,
                                             const CompensationOptions& options, const PostOptions& post,
                                             const std::filesystem::path& program_path,
                                             const std::filesystem::path& side_path, std::string_view dialect) {
  FL_RETURN_IF_ERROR(options.Validate());
  const std::size_t n = nominal.points.size();
  if (const std::size_t feeds = FeedMoveCount(nominal_moves); feeds != n) {
    return Status::Failed("the nominal program has " + std::to_string(feeds) + " feed moves for the tool path's " +
                          std::to_string(n) + " CL points: it is not this path's program");
  }
  // d_s once per CL point on Q (leads are off Q: offset 0), on every core in fixed chunks (each value is the
  // field's at its own point: the same bits for any thread count); the check below reuses the values. The
  // first offset over the limit in cutting order is the one refused.
  std::vector<double> ds_mm(n, 0.0);
  ParallelFor(static_cast<long>(n), kCompensationChunk, [&](long begin, long end) {
    for (long k = begin; k < end; ++k) {
      const ClPoint& cl = nominal.points[static_cast<std::size_t>(k)];
      if (cl.kind == ClKind::kCut) ds_mm[static_cast<std::size_t>(k)] = systematic(cl.u, cl.v);
    }
  });
  for (std::size_t k = 0; k < n; ++k) FL_RETURN_IF_ERROR(CheckOffset(ds_mm[k], k, nominal.points[k].pass, options));
  // The compensated tips (A = i − d_s·n, then the cutter location as UpdateCutterLocations places it),
  // computed where they are needed rather than held (the same expression, the same bits), and the safe Z
  // of the compensated path, never below the nominal program's (its rapids do not change).
  const double r = nominal.options.tool.radius_mm;
  const TipOfPoint tip_of = [&](std::size_t k) {
    const ClPoint& cl = nominal.points[k];
    return TipOf(BallCentre(cl.cc - ds_mm[k] * cl.normal, cl.normal, cl.lift_mm, r), r);
  };
  double max_tip_z = -1e300;
  for (std::size_t k = 0; k < n; ++k) max_tip_z = std::max(max_tip_z, tip_of(k).z());
  double safe_z_mm = max_tip_z + nominal.options.clearance_mm;
  if (std::isfinite(nominal.min_safe_z_mm)) safe_z_mm = std::max(safe_z_mm, nominal.min_safe_z_mm);
  safe_z_mm = std::max(safe_z_mm, nominal.safe_z_mm);
  // The program from the moves as they are made (no list of a million moves), read back from its text: the
  // check below compares what the text says, not what was meant.
  std::string program;
  {
    FL_ASSIGN_OR_RETURN(const ToolpathMoves moves, ToolpathMoves::Of(nominal, tip_of, safe_z_mm));
    FL_ASSIGN_OR_RETURN(program, Post(moves, dialect, post));
  }
  FL_ASSIGN_OR_RETURN(std::vector<ProgramMove> moves, ReadProgram(program, dialect, "compensated program"));
  if (const std::size_t feeds = FeedMoveCount(moves); feeds != n) {
    return Status::Internal("the compensated program has " + std::to_string(feeds) + " feed moves for " +
                            std::to_string(n) + " CL points");
  }
  // Row by row: the side file's entry, checked against both programs and the field's value, then streamed
  // into the side file's temporary file (renamed into place only when every row passed). The k-th feed move
  // of each program is CL point k: two cursors step over the rapids.
  Compensation compensation;
  compensation.source = source;
  compensation.blocks = n;
  SideFileWriter side(side_path, source, /*program_mapped=*/false);
  CheckReport report;
  report.blocks = n;
  report.field_checked = true;
  report.tolerance_um = ProgramOffsetToleranceUm(post.decimals);
  std::size_t row = 0;
  const SystematicField taken = [&](double u, double v) {
    const ClPoint& cl = nominal.points[row];
    return u == cl.u && v == cl.v ? ds_mm[row] : systematic(u, v);
  };
  auto a = nominal_moves.cbegin(), b = moves.cbegin();
  for (row = 0; row < n; ++row, ++a, ++b) {
    while (a->rapid) ++a;
    while (b->rapid) ++b;
    const ClPoint& cl = nominal.points[row];
    CompensationEntry e;
    e.cl_index = row;
    e.nominal_line = a->line;
    e.compensated_line = b->line;
    e.nominal_tip = cl.tip;
    e.offset_mm = tip_of(row) - cl.tip;
    e.systematic_um = ds_mm[row] * 1e3;
    e.pass = cl.pass;
    e.u = cl.u;
    e.v = cl.v;
    e.normal = cl.normal;
    e.has_field_point = cl.kind == ClKind::kCut;
    e.kind = cl.kind;
    compensation.max_offset_um = std::max(compensation.max_offset_um, 1e3 * e.offset_mm.norm());
    CheckBlock(row, e, *a, *b, taken, &report);
    side.Add(e);
  }
  if (!report.ok()) {
    return Status::Internal("compensated program fails its own check: " + report.disagreeing.front().Describe() +
                            "; nothing was written");
  }
  FL_RETURN_IF_ERROR(side.Commit());
  if (Status s = WriteFileAtomic(program_path, program); !s.ok()) {
    std::error_code ec;
    std::filesystem::remove(side_path, ec);
    return s;
  }
  compensation.program_moves = std::move(moves);
  compensation.check_max_disagreement_um = report.max_side_difference_um;
  return compensation;
}

}  // namespace formloop::nc
