#include "nc-gen/path_deviation.h"

#include <algorithm>
#include <cmath>
#include <numbers>
#include <set>

#include "core/atomic_file.h"
#include "core/csv.h"
#include "core/number_text.h"
#include "core/point_io.h"
#include "nc-gen/program_writer.h"

namespace formloop::nc {
namespace {

using internal::BlockRecord;
using internal::ProgramWriter;

std::string Lower(std::string s) {
  for (char& c : s) c = static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
  return s;
}

std::string VecText(const Eigen::Vector3d& v, int decimals) {
  return FormatCoordinate(v.x(), decimals) + ", " + FormatCoordinate(v.y(), decimals) + ", " +
         FormatCoordinate(v.z(), decimals);
}

nlohmann::json Json(const Eigen::Vector3d& v) { return nlohmann::json::array({v.x(), v.y(), v.z()}); }

}  // namespace

// ---------------------------------------------------------------------------------------------------
// Deviation table

Status DeviationTable::Add(const DeviationEntry& entry) {
  const Where where{.file = source_, .line = entry.line, .field = "index"};
  if (entry.index < 1 || entry.index > 9999) {
    return Status::BadInput(where, "key point index " + std::to_string(entry.index) + " is outside 1..9999",
                            "number key points from 1");
  }
  if (!entry.d_mm.allFinite()) {
    return Status::BadInput(Where{.file = source_, .line = entry.line, .field = "dx"},
                            "E_DEVIATION_LIMIT: deviation of key point " + std::to_string(entry.index) +
                                " is not a finite number (suspected probing fault)",
                            "probe the point again");
  }
  if (const auto it = entries_.find(entry.index); it != entries_.end()) {
    return Status::BadInput(where,
                            "key point " + std::to_string(entry.index) + " appears twice (also line " +
                                std::to_string(it->second.line) + ")",
                            "keep one row per key point");
  }
  entries_.emplace(entry.index, entry);
  return Status::Ok();
}

const DeviationEntry* DeviationTable::Find(long index) const {
  const auto it = entries_.find(index);
  return it == entries_.end() ? nullptr : &it->second;
}

Result<DeviationTable> DeviationTable::Parse(std::string_view text, const std::string& source) {
  DeviationTable table;
  table.source_ = source;
  FL_ASSIGN_OR_RETURN(CsvTable csv, ParseCsvTable(text, source, /*require_rows=*/false));
  if (csv.header_line == 0) {
    return Status::BadInput(Where{.file = source}, "no header row", "start the table with: index,dx,dy,dz");
  }
  for (std::string& name : csv.header) name = Lower(name);  // Index, DX, ... as well
  FL_ASSIGN_OR_RETURN(const int index_column, csv.Column("index", "index"));
  int d_column[3];
  const char* names[3] = {"dx", "dy", "dz"};
  for (int a = 0; a < 3; ++a) {
    FL_ASSIGN_OR_RETURN(const int c, csv.Column(names[a], names[a]));
    d_column[a] = c;
  }
  const int unit_column = csv.Find("unit"), session_column = csv.Find("session"),
            timestamp_column = csv.Find("timestamp");
  for (std::size_t r = 0; r < csv.rows.size(); ++r) {
    const std::vector<std::string>& cells = csv.rows[r];
    DeviationEntry e;
    e.line = csv.lines[r];
    double index = 0;
    FL_RETURN_IF_ERROR(csv.Number(r, index_column, &index));
    if (index != std::floor(index)) {
      return Status::BadInput(Where{.file = source, .line = e.line, .field = "index"},
                              "value '" + cells[index_column] + "' is not an integer", "number key points 1, 2, ...");
    }
    e.index = static_cast<long>(index);
    for (int a = 0; a < 3; ++a) {  // a NaN passes here and is refused by Add as E_DEVIATION_LIMIT
      if (!ParseDouble(cells[d_column[a]], &e.d_mm[a])) FL_RETURN_IF_ERROR(csv.Number(r, d_column[a], &e.d_mm[a]));
    }
    if (unit_column >= 0) {
      const std::string unit = Lower(cells[unit_column]);
      if (unit == "inch" || unit == "in") {
        e.d_mm *= kMmPerInch;
      } else if (unit != "mm" && !unit.empty()) {
        return Status::BadInput(Where{.file = source, .line = e.line, .field = "unit"},
                                "unit '" + unit + "' is neither mm nor inch", "write mm or inch");
      }
    }
    if (session_column >= 0) e.session = cells[session_column];
    if (timestamp_column >= 0) e.timestamp = cells[timestamp_column];
    FL_RETURN_IF_ERROR(table.Add(e));
  }
  return table;
}

Result<DeviationTable> ReadDeviationTable(const std::filesystem::path& path) {
  FL_ASSIGN_OR_RETURN(const std::string text, ReadFile(path));
  return DeviationTable::Parse(text, path.string());
}

// ---------------------------------------------------------------------------------------------------
// Options and reports

Status DistributeOptions::Validate() const {
  FL_RETURN_IF_ERROR(reader.Validate());
  if (marker_start == marker_end || marker_start == marker_key || marker_end == marker_key) {
    return Status::BadInput(Where{.field = "markers"}, "the three marker M-codes must differ");
  }
  FL_RETURN_IF_ERROR(internal::CheckWrittenDecimals(reader.dialect, decimals_mm, decimals_inch));
  if (!(chord_tolerance_mm > 0)) return Status::BadInput(Where{.field = "chord_tolerance_mm"}, "must be > 0");
  if (!(max_deviation_mm > 0)) return Status::BadInput(Where{.field = "max_deviation_mm"}, "must be > 0");
  if (!(max_gradient > 0)) return Status::BadInput(Where{.field = "max_gradient"}, "must be > 0");
  if (!(min_interval_mm > 0)) return Status::BadInput(Where{.field = "min_interval_mm"}, "must be > 0");
  if (buffer_max < 1) return Status::BadInput(Where{.field = "buffer_max"}, "must be >= 1");
  return Status::Ok();
}

nlohmann::json IntervalReport::ToJson() const {
  return {{"begin_line", begin_line},       {"end_line", end_line},
          {"key_index", key_index},         {"d_begin_mm", Json(d_begin_mm)},
          {"d_end_mm", Json(d_end_mm)},     {"length_mm", length_mm},
          {"gradient", gradient},           {"blocks", blocks},
          {"motion_blocks", motion_blocks}, {"corrected", corrected},
          {"arcs_kept", arcs_kept},         {"arcs_split", arcs_split},
          {"segments", segments},           {"max_abs_delta_mm", max_abs_delta_mm}};
}

nlohmann::json DistributeReport::ToJson() const {
  nlohmann::json list = nlohmann::json::array();
  for (const auto& i : interval_list) list.push_back(i.ToJson());
  return {{"program", program},
          {"output", output},
          {"lines_in", lines_in},
          {"lines_out", lines_out},
          {"regions", regions},
          {"intervals", intervals},
          {"corrected_blocks", corrected},
          {"arcs_kept", arcs_kept},
          {"arcs_split", arcs_split},
          {"segments_written", segments},
          {"max_abs_delta_mm", max_abs_delta_mm},
          {"interval_list", list},
          {"intervals_listed", interval_list.size()},
          {"warnings", warnings},
          {"read", read.ToJson()}};
}

// ---------------------------------------------------------------------------------------------------
// The filter

struct DeviationDistributor::Impl {
  Impl(const DeviationTable& t, const DistributeOptions& o, std::string src, Sink sink)
      : table(t),
        options(o),
        source(std::move(src)),
        reader(ReaderOptionsOf(o), source),
        writer(o.reader.dialect, std::move(sink)) {
    report.program = source;
  }

  static ReaderOptions ReaderOptionsOf(const DistributeOptions& o) {
    ReaderOptions r = o.reader;
    r.caller_m_codes = {o.marker_start, o.marker_end, o.marker_key};
    return r;
  }

  Status Error(long line, const std::string& code, const std::string& what, const std::string& fix) const {
    std::string text = code + ": " + what;
    if (block.line == line && block.n_word >= 0) text += " (N" + std::to_string(block.n_word) + ")";
    return Status::BadInput(Where{.file = source, .line = line}, text + "; nothing was written", fix);
  }

  int Decimals(Units units) const { return units == Units::kInch ? options.decimals_inch : options.decimals_mm; }
  double UnitMm() const { return region_units == Units::kInch ? kMmPerInch : 1.0; }

  Status Push(std::string_view line, std::string_view eol);
  Status Marker(int code, std::string_view eol);
  Status Region(std::string_view eol);
  Status Flush(const Eigen::Vector3d& d_end_mm, long end_line, long key_index);
  Status EmitArc(const BlockRecord& r, const Eigen::Vector3d& delta_prev, const Eigen::Vector3d& delta, int decimals,
                 IntervalReport* ir, bool* changed);
  std::string MarkerComment(const std::string& what) const;

  const DeviationTable& table;
  DistributeOptions options;
  std::string source;
  GcodeReader reader;
  ProgramWriter writer;
  Block block;
  BlockRecord pass;  // scratch for blocks written at once
  DistributeReport report;
  bool active = false, ended = false;
  int percent = 0;
  long region_line = 0, interval_line = 0;
  Units region_units = Units::kMm;
  int region_cutter = 40, region_work = 54;
  double region_length_comp = 49;
  Eigen::Vector3d d_begin_mm = Eigen::Vector3d::Zero();
  double total_mm = 0;
  std::vector<BlockRecord> buffer;
  std::size_t count = 0;
  std::set<long> keys;
  long key_counter = 0;
  std::vector<Eigen::Vector3d> vertices;
};

std::string DeviationDistributor::Impl::MarkerComment(const std::string& what) const {
  std::string head(block.text.substr(0, block.head_end));
  if (!head.empty() && head.back() != ' ' && head.back() != '\t') head += ' ';
  if (options.reader.dialect == GcodeDialect::kSinumerik) return head + "; " + what + " - APPLIED BY FORMLOOP";
  return head + "(" + what + " - APPLIED BY FORMLOOP)";
}

Status DeviationDistributor::Impl::Push(std::string_view line, std::string_view eol) {
  if (ended) {  // after the end of the program: written as it is
    ++report.lines_in;
    writer.Line(line, eol);
    return Status::Ok();
  }
  FL_RETURN_IF_ERROR(reader.Read(line, &block));
  ++report.lines_in;
  for (const Note& note : block.notes) {
    if (note.kind == NoteKind::kUnknown) {
      return Error(block.line, "E_UNKNOWN_WORD", "'" + note.word + "': " + note.what,
                   "correct or remove the word: formloop writes no program it cannot read in full");
    }
  }
  const bool end_of_program = block.program_end || (block.percent && ++percent == 2);
  if (end_of_program && active) {
    return Error(block.line, "E_MISSING_M58",
                 "the program ends while the region opened by M" + std::to_string(options.marker_start) + " at line " +
                     std::to_string(region_line) + " is still open",
                 "close the region with M" + std::to_string(options.marker_end) + " after the retract");
  }
  int markers = 0, code = 0;
  for (int m : block.m_codes) {
    if (m == options.marker_start || m == options.marker_end || m == options.marker_key) {
      ++markers;
      code = m;
    }
  }
  if (markers > 0) {
    if (markers > 1 || block.m_codes.size() > 1 || block.slash) {
      return Error(block.line, "E_MARKER_BLOCK", "a marker block holds one marker M-code and nothing else",
                   "put each marker on a block of its own");
    }
    FL_RETURN_IF_ERROR(Marker(code, eol));
  } else if (active) {
    FL_RETURN_IF_ERROR(Region(eol));
  } else {
    pass.Assign(block, eol);
    writer.Unchanged(pass);
  }
  if (end_of_program) ended = true;
  return Status::Ok();
}

// A block between M57 and M58: checked, then held until the interval closes.
Status DeviationDistributor::Impl::Region(std::string_view eol) {
  const long l = block.line;
  if (block.slash) {
    return Error(l, "E_UNSUPPORTED_IN_REGION", "optional block '/' inside a compensated region",
                 "the corrected path must not depend on the block delete switch: remove the '/'");
  }
  for (const Note& note : block.notes) {
    if (note.kind == NoteKind::kUnmodelled) {
      return Error(l, "E_UNSUPPORTED_IN_REGION", note.word + " inside a compensated region (" + note.what + ")",
                   "move it before M" + std::to_string(options.marker_start) + " or after M" +
                       std::to_string(options.marker_end));
    }
  }
  if (block.units != region_units) {
    return Error(l, "E_UNIT_CHANGE",
                 std::string("unit change to ") + (block.units == Units::kInch ? "G20" : "G21") +
                     " inside the region opened at line " + std::to_string(region_line),
                 "change units before M" + std::to_string(options.marker_start));
  }
  if (block.work_system != region_work || block.HasG(10)) {
    return Error(l, "E_UNSUPPORTED_IN_REGION", "work coordinate system or offset change inside a compensated region",
                 "select the work system before M" + std::to_string(options.marker_start));
  }
  if (!options.allow_comp_change &&
      (block.cutter_comp != region_cutter || std::abs(block.length_comp - region_length_comp) > 1e-9)) {
    return Error(
        l, "E_COMP_CHANGE", "cutter or tool length compensation changes inside the region",
        "set G40-G42 and G43/G49 before M" + std::to_string(options.marker_start) + " (or allow it explicitly)");
  }
  if (block.rotary_moved && !block.tcp && !options.deviation_frame_program) {
    return Error(l, "E_ROTARY_NO_TCP",
                 "a rotary axis moves inside the region without tool centre point control (G43.4/G43.5): "
                 "the table's work coordinates no longer match the programmed X, Y, Z",
                 "activate TCP, or declare the table in programmed coordinates (--deviation-frame program)");
  }
  if (block.motion != Motion::kNone) {
    if (!block.ends_known() ||
        ((block.motion == Motion::kArcCw || block.motion == Motion::kArcCcw) && !block.has_arc)) {
      return Error(l, "E_POSITION_UNKNOWN", "a motion inside the region starts or ends where the program does not say",
                   "program X, Y and Z absolutely before the region");
    }
    if (block.has_arc && block.incremental) {
      return Error(l, "E_INCREMENTAL_ARC",
                   "arc in incremental distance mode (G91) inside a compensated region: this rewriter writes "
                   "incremental output for straight moves only",
                   "program the region's arcs in G90 (absolute)");
    }
  }
  if (count >= options.buffer_max) {
    return Error(interval_line, "E_BUFFER_OVERFLOW",
                 "more than " + std::to_string(options.buffer_max) + " blocks after the marker at line " +
                     std::to_string(interval_line) + " before the next one",
                 "add key points (M" + std::to_string(options.marker_key) + ") or raise the buffer size");
  }
  if (count == buffer.size()) buffer.emplace_back();
  BlockRecord& r = buffer[count++];
  r.Assign(block, eol);
  if (block.motion != Motion::kNone) {
    const double length = (block.motion == Motion::kRapid && !options.count_rapids) ? 0.0 : block.LengthMm();
    total_mm += length;
    r.length_mm = length;
    r.s_end_mm = total_mm;
  } else {
    r.length_mm = 0;
    r.s_end_mm = total_mm;
  }
  return Status::Ok();
}

Status DeviationDistributor::Impl::Marker(int code, std::string_view eol) {
  const long l = block.line;
  // Only N, the marker, its P (key) or I/J/K (explicit deviation) and comments.
  for (const Word& w : block.words) {
    const bool ok = w.letter == 'M' || (code == options.marker_key &&
                                        (w.letter == 'P' || w.letter == 'I' || w.letter == 'J' || w.letter == 'K'));
    if (!ok || w.expression) {
      return Error(l, "E_MARKER_BLOCK",
                   std::string("word ") + w.letter + " in a marker block (M" + std::to_string(code) + ")",
                   "a marker block may hold only N, the M-code, P (or I, J, K for M" +
                       std::to_string(options.marker_key) + ") and a comment");
    }
  }
  const std::string m = "M" + std::to_string(code);
  if (code == options.marker_start) {
    if (active) {
      return Error(l, "E_NESTED_M57",
                   m + " while the region opened at line " + std::to_string(region_line) + " is open",
                   "close it with M" + std::to_string(options.marker_end) + " first");
    }
    if (reader.position_known() != 7u) {
      return Error(l, "E_POSITION_UNKNOWN", "the position at " + m + " is not known",
                   "program X, Y and Z absolutely before the region");
    }
    if (block.transform_active || block.cycle_active) {
      return Error(l, "E_UNSUPPORTED_IN_REGION",
                   "a transform (polar, scaling, mirror, rotation) or canned cycle is still modal at " + m,
                   "cancel it before the region");
    }
    active = true;
    region_line = interval_line = l;
    region_units = block.units;
    region_cutter = block.cutter_comp;
    region_length_comp = block.length_comp;
    region_work = block.work_system;
    d_begin_mm.setZero();
    total_mm = 0;
    count = 0;
    keys.clear();
    key_counter = 0;
    ++report.regions;
    writer.Line(MarkerComment(m + " COMPENSATED REGION START"), eol);
    return Status::Ok();
  }
  if (code == options.marker_end) {
    if (!active) {
      return Error(l, "E_M58_OUTSIDE", m + " without an open region",
                   "open the region with M" + std::to_string(options.marker_start));
    }
    FL_RETURN_IF_ERROR(Flush(Eigen::Vector3d::Zero(), l, -1));
    active = false;
    writer.Line(MarkerComment(m + " COMPENSATED REGION END"), eol);
    return Status::Ok();
  }
  // Key point.
  if (!active) {
    return Error(l, "E_M59_OUTSIDE", m + " outside a compensated region",
                 "put key points between M" + std::to_string(options.marker_start) + " and M" +
                     std::to_string(options.marker_end));
  }
  ++key_counter;
  const Word* p = block.Find('P');
  const Word* words[3] = {block.Find('I'), block.Find('J'), block.Find('K')};
  const bool explicit_words = words[0] || words[1] || words[2];
  Eigen::Vector3d d_mm = Eigen::Vector3d::Zero();
  long index = -1;
  std::string what;
  if (p != nullptr && explicit_words) {
    return Error(l, "E_MARKER_BLOCK", m + " with both P and I/J/K", "give the table index P or the deviation words");
  }
  if (explicit_words) {
    for (int a = 0; a < 3; ++a) {
      if (words[a] != nullptr) d_mm[a] = words[a]->value * (block.units == Units::kInch ? kMmPerInch : 1.0);
    }
    what = m + " KEY POINT";
  } else {
    if (p == nullptr && !options.implicit_sequential) {
      return Error(l, "E_NO_DEVIATION", m + " without P (the key point's index in the deviation table)",
                   "write " + m + " P<n>");
    }
    index = p != nullptr ? std::lround(p->value) : key_counter;
    if (p != nullptr && std::abs(p->value - static_cast<double>(index)) > 1e-9) {
      return Error(l, "E_NO_DEVIATION", "P" + FormatExact(p->value) + " is not an integer index", "write P<n>");
    }
    const DeviationEntry* e = table.Find(index);
    if (e == nullptr) {
      return Error(l, "E_NO_DEVIATION",
                   "key point P" + std::to_string(index) + " is not in the deviation table " + table.source() + " (" +
                       std::to_string(table.size()) + " entries)",
                   "probe the point, or correct the index");
    }
    d_mm = e->d_mm;
    if (!keys.insert(index).second) {
      report.warnings.push_back(source + ":" + std::to_string(l) + ": key point P" + std::to_string(index) +
                                " used twice in the region opened at line " + std::to_string(region_line));
    }
    what = m + " P" + std::to_string(index) + " KEY POINT";
  }
  if (!d_mm.allFinite() || d_mm.norm() > options.max_deviation_mm) {
    return Error(l, "E_DEVIATION_LIMIT",
                 "deviation (" + VecText(d_mm, 4) + ") mm exceeds the limit " +
                     FormatFixed(options.max_deviation_mm, 3) + " mm (suspected probing fault)",
                 "check the probing; raise the limit only if the deviation is real");
  }
  FL_RETURN_IF_ERROR(Flush(d_mm, l, index));
  d_begin_mm = d_mm;
  total_mm = 0;
  interval_line = l;
  const int d = Decimals(block.units);
  const double to_unit = block.units == Units::kInch ? 1.0 / kMmPerInch : 1.0;
  writer.Line(
      MarkerComment(what + " DEVIATION X" + FormatCoordinate(d_mm.x() * to_unit, d + 1) + " Y" +
                    FormatCoordinate(d_mm.y() * to_unit, d + 1) + " Z" + FormatCoordinate(d_mm.z() * to_unit, d + 1) +
                    (block.units == Units::kInch ? " IN" : " MM")),
      eol);
  return Status::Ok();
}

Status DeviationDistributor::Impl::Flush(const Eigen::Vector3d& d_end_mm, long end_line, long key_index) {
  IntervalReport ir;
  ir.begin_line = interval_line;
  ir.end_line = end_line;
  ir.key_index = key_index;
  ir.d_begin_mm = d_begin_mm;
  ir.d_end_mm = d_end_mm;
  ir.length_mm = total_mm;
  ir.blocks = count;
  const double unit_mm = UnitMm();
  const Eigen::Vector3d change_mm = d_end_mm - d_begin_mm;
  Eigen::Vector3d rate = Eigen::Vector3d::Zero();  // program units of deviation per mm of path
  bool unchanged = false;
  if (total_mm < options.min_interval_mm) {
    if (change_mm.norm() > 1e-9) {
      return Error(end_line, "E_ZERO_LENGTH",
                   "the deviation changes from (" + VecText(d_begin_mm, 4) + ") to (" + VecText(d_end_mm, 4) +
                       ") mm with no path between line " + std::to_string(interval_line) + " and line " +
                       std::to_string(end_line),
                   "put motion between the two markers, or remove one");
    }
    unchanged = true;  // spec §4: nothing to distribute over no path
  } else {
    ir.gradient = change_mm.norm() / total_mm;
    if (ir.gradient > options.max_gradient) {
      return Error(end_line, "E_GRADIENT",
                   "the deviation changes by " + FormatFixed(1e3 * change_mm.norm(), 3) + " um over " +
                       FormatFixed(total_mm, 4) + " mm of path between line " + std::to_string(interval_line) +
                       " and line " + std::to_string(end_line) + ": " + FormatFixed(ir.gradient, 5) +
                       " mm/mm, more than the limit " + FormatFixed(options.max_gradient, 5),
                   "check the probing of the two key points, or add key points between them");
    }
    rate = change_mm / total_mm / unit_mm;
  }
  const Eigen::Vector3d d_begin = d_begin_mm / unit_mm;  // program units
  for (std::size_t k = 0; k < count; ++k) {
    const BlockRecord& r = buffer[k];
    if (r.motion == Motion::kNone || unchanged) {
      writer.Unchanged(r);
      if (r.motion != Motion::kNone) ++ir.motion_blocks;
      continue;
    }
    ++ir.motion_blocks;
    const Eigen::Vector3d delta = d_begin + rate * r.s_end_mm;
    const Eigen::Vector3d delta_prev = d_begin + rate * (r.s_end_mm - r.length_mm);
    ir.max_abs_delta_mm = std::max(ir.max_abs_delta_mm, delta.norm() * unit_mm);
    const int decimals = Decimals(r.units);
    bool changed = false;
    if (r.has_arc) {
      FL_RETURN_IF_ERROR(EmitArc(r, delta_prev, delta, decimals, &ir, &changed));
    } else {
      changed = writer.MoveEnd(r, r.end + delta, nullptr, decimals);
    }
    if (changed) ++ir.corrected;
  }
  count = 0;
  ++report.intervals;
  report.corrected += ir.corrected;
  report.arcs_kept += ir.arcs_kept;
  report.arcs_split += ir.arcs_split;
  report.segments += ir.segments;
  report.max_abs_delta_mm = std::max(report.max_abs_delta_mm, ir.max_abs_delta_mm);
  if (report.interval_list.size() < DistributeReport::kIntervalsListed) report.interval_list.push_back(ir);
  return Status::Ok();
}

Status DeviationDistributor::Impl::EmitArc(const BlockRecord& r, const Eigen::Vector3d& delta_prev,
                                           const Eigen::Vector3d& delta, int decimals, IntervalReport* ir,
                                           bool* changed) {
  const ArcGeometry& arc = r.arc;
  const PlaneAxes ax = AxesOf(arc.plane);
  const Eigen::Vector3d drift = delta - delta_prev;
  const double q = std::pow(10.0, -decimals);
  const double unit_mm = r.units == Units::kInch ? kMmPerInch : 1.0;
  // KEEP_IF_EXACT: the arc moved by Δ_(k−1) in its plane, drifting along w, when the in-plane drift is
  // below q/2 and the controller will run the same arc from its rounded ends.
  const Eigen::Vector3d centre = arc.centre + delta_prev;
  if (std::abs(drift[ax.u]) < 0.5 * q && std::abs(drift[ax.v]) < 0.5 * q &&
      writer.KeepsArc(r, r.end + delta, centre, decimals, options.reader.arc_radius_tolerance_mm / unit_mm)) {
    *changed = writer.MoveEnd(r, r.end + delta, &centre, decimals);
    ++ir->arcs_kept;
    return Status::Ok();
  }
  if (r.feed_mode == FeedMode::kInverseTime) {
    return Error(r.line, "E_INVERSE_TIME",
                 "an arc under inverse-time feed (G93) would have to be split, and its F word is its time",
                 "program the region in G94");
  }
  // SEGMENT: chords within ε of the corrected curve (spec §5: the drift is linear in λ on the curve and
  // on each chord, so the gap is the arc's own sagitta).
  const int n = internal::ChordSegments(arc, options.chord_tolerance_mm / unit_mm);
  vertices.resize(static_cast<std::size_t>(n));
  for (int i = 1; i <= n; ++i) {
    const double lambda = static_cast<double>(i) / n;
    vertices[static_cast<std::size_t>(i - 1)] = arc.PointAt(lambda) + delta_prev + lambda * drift;
  }
  writer.Split(r, vertices, decimals);
  *changed = true;
  ++ir->arcs_split;
  ir->segments += static_cast<std::size_t>(n);
  return Status::Ok();
}

DeviationDistributor::DeviationDistributor(const DeviationTable& table, const DistributeOptions& options,
                                           std::string source, Sink sink)
    : impl_(std::make_unique<Impl>(table, options, std::move(source), std::move(sink))) {}

DeviationDistributor::~DeviationDistributor() = default;

Status DeviationDistributor::Push(std::string_view line, std::string_view eol) { return impl_->Push(line, eol); }

Status DeviationDistributor::Finish() {
  Impl& s = *impl_;
  if (s.active) {
    return Status::BadInput(Where{.file = s.source, .line = s.region_line},
                            "E_MISSING_M58: the program ends while the region opened by M" +
                                std::to_string(s.options.marker_start) + " here is still open; nothing was written",
                            "close the region with M" + std::to_string(s.options.marker_end));
  }
  s.report.read = s.reader.report();
  s.report.lines_out = static_cast<std::size_t>(s.writer.lines());
  return Status::Ok();
}

const DistributeReport& DeviationDistributor::report() const { return impl_->report; }

Result<DistributeReport> DistributeProgram(const std::filesystem::path& program, const std::filesystem::path& out,
                                           const DeviationTable& table, const DistributeOptions& options) {
  FL_RETURN_IF_ERROR(options.Validate());
  std::error_code ec;
  if (std::filesystem::weakly_canonical(program, ec) == std::filesystem::weakly_canonical(out, ec) ||
      (std::filesystem::exists(out, ec) && std::filesystem::equivalent(program, out, ec))) {
    return Status::BadInput(Where{.field = "--out"}, "the output '" + out.string() + "' is the input program",
                            "write the corrected program to a new file");
  }
  FL_ASSIGN_OR_RETURN(LineSource lines, LineSource::Open(program));
  AtomicFile file(out, /*binary=*/true);
  FL_RETURN_IF_ERROR(file.open_status());
  std::string chunk;
  chunk.reserve(1 << 20);
  auto flush = [&file, &chunk] {
    file.stream().write(chunk.data(), static_cast<std::streamsize>(chunk.size()));
    chunk.clear();
  };
  DeviationDistributor distributor(table, options, program.string(), [&](std::string_view text) {
    chunk.append(text);
    if (chunk.size() >= (1u << 20)) flush();
  });
  std::string_view line, eol;
  while (lines.Next(&line, &eol)) FL_RETURN_IF_ERROR(distributor.Push(line, eol));
  FL_RETURN_IF_ERROR(lines.status());
  FL_RETURN_IF_ERROR(distributor.Finish());
  flush();
  FL_RETURN_IF_ERROR(file.Commit());
  DistributeReport report = distributor.report();
  report.output = out.string();
  return report;
}

Result<std::string> DistributeText(std::string_view text, const DeviationTable& table, const DistributeOptions& options,
                                   DistributeReport* report) {
  FL_RETURN_IF_ERROR(options.Validate());
  std::string out;
  DeviationDistributor distributor(table, options, "program", [&out](std::string_view t) { out.append(t); });
  LineSource lines = LineSource::FromText(text);
  std::string_view line, eol;
  while (lines.Next(&line, &eol)) FL_RETURN_IF_ERROR(distributor.Push(line, eol));
  FL_RETURN_IF_ERROR(distributor.Finish());
  if (report != nullptr) *report = distributor.report();
  return out;
}

}  // namespace formloop::nc
