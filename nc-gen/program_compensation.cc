#include "nc-gen/program_compensation.h"

#include <algorithm>
#include <cmath>
#include <map>
#include <system_error>

#include "core/atomic_file.h"
#include "core/point_io.h"
#include "nc-gen/program_writer.h"

namespace formloop::nc {
namespace {

using internal::BlockRecord;
using internal::ProgramWriter;

bool IsFeed(Motion m) { return m == Motion::kLinear || m == Motion::kArcCw || m == Motion::kArcCcw; }

// The mirror offset at one programmed tip point (mm).
struct PointOffset {
  bool on = false;
  double u = 0, v = 0, ds_mm = 0;
  Eigen::Vector3d normal = Eigen::Vector3d::UnitZ();
  Eigen::Vector3d offset_mm = Eigen::Vector3d::Zero();
};

class Mapper {
 public:
  Mapper(const recon::FootPointProjector& q, const SystematicField& field, const ProgramCompensationOptions& o)
      : q_(q), field_(field), o_(o) {}

  Result<PointOffset> At(const Eigen::Vector3d& tip_mm, long line) const {
    PointOffset p;
    const Eigen::Vector3d centre = tip_mm + o_.ball_radius_mm * Eigen::Vector3d::UnitZ();
    FL_ASSIGN_OR_RETURN(const recon::FootPoint f, q_.Project(centre));
    p.on = !f.on_boundary && std::abs(f.deviation_mm - o_.ball_radius_mm) <= o_.contact_tolerance_mm;
    if (!p.on) return p;
    p.u = f.u;
    p.v = f.v;
    p.normal = f.normal;
    p.ds_mm = field_(f.u, f.v);
    if (!std::isfinite(p.ds_mm) || std::abs(p.ds_mm) * 1e3 > o_.max_offset_um) {
      return Status::SafetyLimit("compensation offset " + FormatFixed(p.ds_mm * 1e3, 1) + " um at line " +
                                 std::to_string(line) + " exceeds the limit " + FormatFixed(o_.max_offset_um, 1) +
                                 " um; no compensated program was written. Fix: check the measurement, or raise "
                                 "the offset limit if the error is real");
    }
    p.offset_mm = -p.ds_mm * f.normal;
    return p;
  }

 private:
  const recon::FootPointProjector& q_;
  const SystematicField& field_;
  const ProgramCompensationOptions& o_;
};

Status Refuse(const std::string& source, long line, const std::string& code, const std::string& what,
              const std::string& fix) {
  return Status::BadInput(Where{.file = source, .line = line}, code + ": " + what + "; nothing was written", fix);
}

}  // namespace

Status ProgramCompensationOptions::Validate() const {
  FL_RETURN_IF_ERROR(reader.Validate());
  if (!(ball_radius_mm > 0)) {
    return Status::BadInput(Where{.field = "--ball-radius-mm"}, "the ball radius must be > 0",
                            "give the ball-end tool's radius in mm");
  }
  if (!(contact_tolerance_mm > 0)) return Status::BadInput(Where{.field = "contact_tolerance_mm"}, "must be > 0");
  if (!(chord_tolerance_mm > 0)) return Status::BadInput(Where{.field = "--chord-tol"}, "must be > 0");
  FL_RETURN_IF_ERROR(internal::CheckWrittenDecimals(reader.dialect, decimals_mm, decimals_inch));
  if (!(max_offset_um > 0)) return Status::BadInput(Where{.field = "--max-offset-um"}, "must be > 0");
  return Status::Ok();
}

nlohmann::json ProgramCompensationReport::ToJson() const {
  return {{"program", program},
          {"output", output},
          {"side_file", side_file},
          {"source", source},
          {"lines", lines},
          {"feed_blocks", feed_blocks},
          {"corrected_blocks", corrected_blocks},
          {"points", points},
          {"points_on_q", on_surface},
          {"points_off_q", off_surface},
          {"arcs_kept", arcs_kept},
          {"arcs_split", arcs_split},
          {"segments_written", segments},
          {"max_offset_um", max_offset_um},
          {"max_line_midpoint_um", max_line_midpoint_um},
          {"read", read.ToJson()}};
}

Result<ProgramCompensation> CompensateProgramText(std::string_view nominal_text, const std::string& source,
                                                  const recon::FootPointProjector& q, const SystematicField& field,
                                                  const std::string& field_source,
                                                  const ProgramCompensationOptions& options) {
  FL_RETURN_IF_ERROR(options.Validate());
  ProgramCompensation result;
  result.side.program_mapped = true;
  result.side.source = field_source;
  ProgramCompensationReport& report = result.report;
  report.program = source;
  report.source = field_source;
  GcodeReader reader(options.reader, source);
  ProgramWriter writer(options.reader.dialect, [&result](std::string_view t) { result.program.append(t); });
  const Mapper mapper(q, field, options);
  LineSource lines = LineSource::FromText(nominal_text);
  Block block;
  BlockRecord rec;
  std::string_view line, eol;
  PointOffset previous;  // offset where the controller stands (off Q after a rapid)
  int pass = 0;
  bool cutting = false;
  std::vector<Eigen::Vector3d> vertices;
  std::vector<PointOffset> offsets;
  std::vector<double> lambdas;
  auto add_row = [&](long nominal_line, long compensated_line, const Eigen::Vector3d& nominal_mm,
                     const Eigen::Vector3d& written_mm, const PointOffset& p, double lambda) {
    CompensationEntry e;
    e.cl_index = result.side.entries.size();
    e.pass = pass;
    e.nominal_line = nominal_line;
    e.compensated_line = compensated_line;
    e.nominal_tip = nominal_mm;
    e.offset_mm = written_mm - nominal_mm;
    e.systematic_um = 1e3 * p.ds_mm;
    e.u = p.u;
    e.v = p.v;
    e.normal = p.normal;
    e.has_field_point = p.on;
    e.kind = p.on ? ClKind::kCut : ClKind::kOff;
    e.lambda = lambda;
    result.side.entries.push_back(e);
    report.max_offset_um = std::max(report.max_offset_um, 1e3 * e.offset_mm.norm());
    ++report.points;
    (p.on ? report.on_surface : report.off_surface)++;
  };
  while (lines.Next(&line, &eol)) {
    FL_RETURN_IF_ERROR(reader.Read(line, &block));
    rec.Assign(block, eol);
    for (const Note& note : block.notes) {
      if (note.kind == NoteKind::kUnknown) {
        return Refuse(source, block.line, "E_UNKNOWN_WORD", "'" + note.word + "': " + note.what,
                      "correct or remove the word: formloop writes no program it cannot read in full");
      }
    }
    if (!IsFeed(block.motion)) {
      writer.Unchanged(rec);
      if (block.motion == Motion::kRapid) {
        previous = PointOffset{};  // the rapid ends where the program says: no offset there
        if (cutting) ++pass;
        cutting = false;
      }
      continue;
    }
    const long l = block.line;
    for (const Note& note : block.notes) {
      if (note.kind != NoteKind::kUnknown) {
        return Refuse(source, l, "E_UNSUPPORTED", note.word + " on a feed block (" + note.what + ")",
                      "the tool-tip path must be the programmed path: remove it or expand it into G1/G2/G3");
      }
    }
    if (block.cutter_comp != 40) {
      return Refuse(source, l, "E_UNSUPPORTED",
                    "feed block under cutter radius compensation G" + std::to_string(block.cutter_comp),
                    "post the program for the tool-tip path (G40)");
    }
    if (!block.ends_known() || ((block.motion != Motion::kLinear) && !block.has_arc)) {
      return Refuse(source, l, "E_POSITION_UNKNOWN", "a feed block starts or ends where the program does not say",
                    "program X, Y and Z absolutely before the cut");
    }
    if (block.slash) {
      return Refuse(source, l, "E_UNSUPPORTED", "optional block '/' on a feed move",
                    "the compensated path must not depend on the block delete switch: remove the '/'");
    }
    cutting = true;
    ++report.feed_blocks;
    const double unit = block.mm_per_unit();
    const int decimals = block.units == Units::kInch ? options.decimals_inch : options.decimals_mm;
    const double q_units = std::pow(10.0, -decimals);
    FL_ASSIGN_OR_RETURN(const PointOffset end, mapper.At(block.end * unit, l));
    const Eigen::Vector3d o_start = previous.offset_mm / unit, o_end = end.offset_mm / unit;
    if (!block.has_arc) {
      if (previous.on && end.on) {  // a cut along Q: how far the straight move strays from the mirrored path
        FL_ASSIGN_OR_RETURN(const PointOffset mid, mapper.At(0.5 * (block.start + block.end) * unit, l));
        if (mid.on) {
          report.max_line_midpoint_um = std::max(
              report.max_line_midpoint_um, 1e3 * (mid.offset_mm - 0.5 * (previous.offset_mm + end.offset_mm)).norm());
        }
      }
      if (writer.MoveEnd(rec, block.end + o_end, nullptr, decimals)) ++report.corrected_blocks;
      add_row(l, writer.lines(), block.end * unit, (block.end + writer.residual()) * unit, end, 1.0);
      previous = end;
      continue;
    }
    // Arcs: kept when the offsets along the arc are the linear blend of the end offsets to q/2.
    const ArcGeometry& arc = block.arc;
    const PlaneAxes ax = AxesOf(arc.plane);
    bool keep =
        std::abs(o_end[ax.u] - o_start[ax.u]) < 0.5 * q_units && std::abs(o_end[ax.v] - o_start[ax.v]) < 0.5 * q_units;
    for (int j = 1; j < 16 && keep; ++j) {
      const double lambda = j / 16.0;
      FL_ASSIGN_OR_RETURN(const PointOffset p, mapper.At(arc.PointAt(lambda) * unit, l));
      const Eigen::Vector3d blend = o_start + lambda * (o_end - o_start);
      keep = ((p.offset_mm / unit - blend).cwiseAbs().maxCoeff() < 0.5 * q_units);
    }
    const Eigen::Vector3d centre = arc.centre + o_start;
    if (keep &&
        writer.KeepsArc(rec, block.end + o_end, centre, decimals, options.reader.arc_radius_tolerance_mm / unit)) {
      if (writer.MoveEnd(rec, block.end + o_end, &centre, decimals)) ++report.corrected_blocks;
      add_row(l, writer.lines(), block.end * unit, (block.end + writer.residual()) * unit, end, 1.0);
      ++report.arcs_kept;
      previous = end;
      continue;
    }
    // Split: the moved points of the arc, doubled until each chord's middle is within ε of the curve.
    const double eps = options.chord_tolerance_mm / unit;
    int n = internal::ChordSegments(arc, eps);
    for (int round = 0;; ++round) {
      vertices.assign(1, arc.start + o_start);
      offsets.assign(1, previous);
      lambdas.assign(1, 0.0);
      for (int i = 1; i <= n; ++i) {
        const double lambda = static_cast<double>(i) / n;
        const Eigen::Vector3d nominal = arc.PointAt(lambda);
        PointOffset p = end;
        if (i < n) {
          FL_ASSIGN_OR_RETURN(p, mapper.At(nominal * unit, l));
        }
        vertices.push_back(nominal + p.offset_mm / unit);
        offsets.push_back(p);
        lambdas.push_back(lambda);
      }
      double worst = 0;
      for (int i = 1; i <= n; ++i) {
        const double mid_lambda = 0.5 * (lambdas[i - 1] + lambdas[i]);
        const Eigen::Vector3d nominal = arc.PointAt(mid_lambda);
        FL_ASSIGN_OR_RETURN(const PointOffset p, mapper.At(nominal * unit, l));
        const Eigen::Vector3d curve = nominal + p.offset_mm / unit;
        const Eigen::Vector3d a = vertices[i - 1], b = vertices[i];
        const double t = std::clamp((curve - a).dot(b - a) / std::max((b - a).squaredNorm(), 1e-300), 0.0, 1.0);
        worst = std::max(worst, (a + t * (b - a) - curve).norm());
      }
      if (worst <= eps || round >= 6) break;
      n *= 2;
    }
    vertices.erase(vertices.begin());
    offsets.erase(offsets.begin());
    lambdas.erase(lambdas.begin());
    const long first_line = writer.lines() + 1;
    writer.Split(rec, vertices, decimals);
    ++report.corrected_blocks;
    ++report.arcs_split;
    report.segments += vertices.size();
    for (std::size_t i = 0; i < vertices.size(); ++i) {
      Eigen::Vector3d written;
      for (int a = 0; a < 3; ++a) written[a] = RoundCoordinate(vertices[i][a], decimals);
      if (block.incremental && i + 1 == vertices.size()) written = block.end + writer.residual();
      add_row(l, first_line + static_cast<long>(i), arc.PointAt(lambdas[i]) * unit, written * unit, offsets[i],
              lambdas[i]);
    }
    previous = end;
  }
  FL_RETURN_IF_ERROR(lines.status());
  report.read = reader.report();
  report.lines = report.read.lines;
  result.side.max_offset_um = report.max_offset_um;
  return result;
}

Result<CheckReport> CheckProgramCompensation(std::string_view nominal_text, std::string_view compensated_text,
                                             const SideFile& side, const SystematicField& field,
                                             const ReaderOptions& reader, const CheckOptions& options) {
  if (options.program_decimals < 0 || options.program_decimals > 9) {
    return Status::BadInput(Where{.field = "program_decimals"}, "must be 0..9");
  }
  FL_ASSIGN_OR_RETURN(const ProgramPath nominal, ReadProgramPath(nominal_text, reader, "nominal program"));
  FL_ASSIGN_OR_RETURN(const ProgramPath compensated, ReadProgramPath(compensated_text, reader, "compensated program"));
  std::vector<const PathMove*> nominal_feeds, compensated_feeds;
  std::map<long, const PathMove*> nominal_by_line;
  for (const PathMove& m : nominal.moves) {
    if (!IsFeed(m.motion)) continue;
    nominal_feeds.push_back(&m);
    nominal_by_line[m.line] = &m;
  }
  for (const PathMove& m : compensated.moves) {
    if (IsFeed(m.motion)) compensated_feeds.push_back(&m);
  }
  if (compensated_feeds.size() != side.entries.size()) {
    return Status::Failed("compensation check: the compensated program has " +
                          std::to_string(compensated_feeds.size()) + " feed blocks, the side file " +
                          std::to_string(side.entries.size()) + " rows; they must be equal");
  }
  CheckReport report;
  report.blocks = side.entries.size();
  report.field_checked = static_cast<bool>(field) && side.has_field_points;
  report.tolerance_um =
      options.tolerance_um > 0 ? options.tolerance_um : ProgramOffsetToleranceUm(options.program_decimals);
  // Every nominal feed block is covered, in order, its last row at lambda 1.
  std::size_t next_nominal = 0;
  for (std::size_t k = 0; k < side.entries.size(); ++k) {
    const CompensationEntry& e = side.entries[k];
    const PathMove& c = *compensated_feeds[k];
    auto problem = [&](const std::string& text) {
      BlockCheck b;
      b.cl_index = k;
      b.pass = e.pass;
      b.nominal_line = e.nominal_line;
      b.compensated_line = c.line;
      b.problems.push_back(text);
      report.disagreeing.push_back(b);
    };
    const auto it = nominal_by_line.find(e.nominal_line);
    if (it == nominal_by_line.end()) {
      problem("the side file names nominal line " + std::to_string(e.nominal_line) +
              ", which is no feed block of the nominal program");
      continue;
    }
    const PathMove& m = *it->second;
    if (next_nominal < nominal_feeds.size() && nominal_feeds[next_nominal] == &m && e.lambda == 1) ++next_nominal;
    if (m.start_known != 7u || m.end_known != 7u || c.end_known != 7u || (m.motion != Motion::kLinear && !m.has_arc)) {
      problem("a feed block does not state all three axes");
      continue;
    }
    const Eigen::Vector3d nominal_point =
        m.has_arc ? m.arc.PointAt(e.lambda) : Eigen::Vector3d(m.start + e.lambda * (m.end - m.start));
    const double unit = m.units == Units::kInch ? kMmPerInch : 1.0;
    CheckRow(k, e, nominal_point * unit, m.line, c.end * (c.units == Units::kInch ? kMmPerInch : 1.0), c.line, field,
             &report);
  }
  if (next_nominal != nominal_feeds.size()) {
    BlockCheck b;
    b.cl_index = side.entries.size();
    b.nominal_line = next_nominal < nominal_feeds.size() ? nominal_feeds[next_nominal]->line : 0;
    b.problems.push_back(
        "the side file does not end a row at lambda 1 on every feed block of the nominal program, "
        "in order (first missing: nominal line " +
        std::to_string(b.nominal_line) + ")");
    report.disagreeing.push_back(b);
  }
  return report;
}

Result<ProgramCompensationReport> WriteCompensatedShopProgram(
    const std::filesystem::path& program, const recon::FootPointProjector& q, const SystematicField& field,
    const std::string& field_source, const ProgramCompensationOptions& options, const std::filesystem::path& out,
    const std::filesystem::path& side_path) {
  std::error_code ec;
  for (const auto& target : {out, side_path}) {
    if (std::filesystem::weakly_canonical(program, ec) == std::filesystem::weakly_canonical(target, ec)) {
      return Status::BadInput(Where{.field = "--out"}, "'" + target.string() + "' is the input program",
                              "write the compensated program and its side file to new files");
    }
  }
  FL_ASSIGN_OR_RETURN(const std::string text, ReadFile(program));
  FL_ASSIGN_OR_RETURN(ProgramCompensation result,
                      CompensateProgramText(text, program.string(), q, field, field_source, options));
  SideFile side{.source = field_source, .entries = result.side.entries, .has_field_points = true, .has_lambda = true};
  const int decimals = std::min(options.decimals_mm, options.decimals_inch);
  FL_ASSIGN_OR_RETURN(
      const CheckReport check,
      CheckProgramCompensation(text, result.program, side, field, options.reader, {.program_decimals = decimals}));
  if (!check.ok()) {
    return Status::Internal("compensated program fails its own check: " + check.disagreeing.front().Describe() +
                            "; nothing was written");
  }
  FL_RETURN_IF_ERROR(WriteSideFile(side_path, result.side));
  if (Status s = WriteFileAtomic(out, result.program, /*binary=*/true); !s.ok()) {
    std::filesystem::remove(side_path, ec);
    return s;
  }
  result.report.output = out.string();
  result.report.side_file = side_path.string();
  return result.report;
}

}  // namespace formloop::nc
