#include "nc-gen/compensation.h"

#include <algorithm>
#include <cmath>
#include <map>
#include <system_error>

#include "core/atomic_file.h"
#include "core/csv.h"
#include "core/number_text.h"
#include "nc-gen/toolpath_io.h"

namespace formloop::nc {
namespace {

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
    if (std::abs(ds_mm) * 1e3 > options.max_offset_um) {
      return Status::SafetyLimit("compensation offset " + FormatFixed(ds_mm * 1e3, 1) + " um at CL point " +
                                 std::to_string(k) + " (pass " + std::to_string(cl.pass) + ") exceeds the limit " +
                                 FormatFixed(options.max_offset_um, 1) +
                                 " um; no compensated program was written. Fix: check the measurement, or raise "
                                 "compensation.max_offset_um if the error is real");
    }
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

Status WriteSideFile(const std::filesystem::path& path, const Compensation& compensation) {
  std::string text =
      "# formloop compensation side file: per CL point, the nominal tip, the applied offset, its source\n";
  text += "# source: " + compensation.source + "\n";
  text +=
      "cl_index,pass,nominal_line,compensated_line,nominal_x,nominal_y,nominal_z,offset_x,offset_y,offset_z,ds_um,"
      "u,v,nx,ny,nz,kind";
  text += compensation.program_mapped ? ",lambda\n" : "\n";
  for (const auto& e : compensation.entries) {
    text += std::to_string(e.cl_index) + "," + std::to_string(e.pass) + "," + std::to_string(e.nominal_line) + "," +
            std::to_string(e.compensated_line);
    for (int a = 0; a < 3; ++a) text += "," + FormatFixed(e.nominal_tip[a], 6);
    for (int a = 0; a < 3; ++a) text += "," + FormatFixed(e.offset_mm[a], 6);
    text += "," + FormatFixed(e.systematic_um, 4);
    text += "," + FormatExact(e.u) + "," + FormatExact(e.v);
    for (int a = 0; a < 3; ++a) text += "," + FormatFixed(e.normal[a], 9);
    text += std::string(",") + ClKindName(e.kind);
    text += compensation.program_mapped ? "," + FormatExact(e.lambda) + "\n" : "\n";
  }
  return WriteFileAtomic(path, text);
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

Result<SideFile> ParseSideFile(const std::string& text, const std::string& source) {
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
  FL_ASSIGN_OR_RETURN(std::string text, ReadTextFile(path));
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
  for (std::size_t k = 0; k < a.size(); ++k) {
    if (!a[k]->tip.allFinite() || !b[k]->tip.allFinite()) {
      BlockCheck block;
      block.cl_index = k;
      block.pass = side.entries[k].pass;
      block.nominal_line = a[k]->line;
      block.compensated_line = b[k]->line;
      block.problems.push_back("a feed block does not program all three axes");
      report.disagreeing.push_back(block);
      continue;
    }
    CheckRow(k, side.entries[k], a[k]->tip, a[k]->line, b[k]->tip, b[k]->line, field, &report);
  }
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

Result<Compensation> WriteCompensatedProgram(const Toolpath& nominal, const std::string& nominal_program,
                                             const SystematicField& systematic, const std::string& source,
                                             const CompensationOptions& options, const PostOptions& post,
                                             const std::filesystem::path& program_path,
                                             const std::filesystem::path& side_path, std::string_view dialect) {
  FL_ASSIGN_OR_RETURN(Compensation compensation, CompensateToolpath(nominal, systematic, source, options));
  FL_ASSIGN_OR_RETURN(const MoveList list, BuildMoveList(compensation.path));
  FL_ASSIGN_OR_RETURN(std::string program, Post(list, dialect, post));
  FL_ASSIGN_OR_RETURN(std::vector<ProgramMove> nominal_moves, ReadProgram(nominal_program, dialect, "nominal program"));
  FL_ASSIGN_OR_RETURN(std::vector<ProgramMove> moves, ReadProgram(program, dialect, "compensated program"));
  FL_RETURN_IF_ERROR(AssignProgramLines(nominal_moves, moves, &compensation));
  SideFile side{.source = source, .entries = compensation.entries, .has_field_points = true};
  FL_ASSIGN_OR_RETURN(CheckReport report,
                      CheckCompensation(nominal_moves, moves, side, systematic, {.program_decimals = post.decimals}));
  if (!report.ok()) {
    return Status::Internal("compensated program fails its own check: " + report.disagreeing.front().Describe() +
                            "; nothing was written");
  }
  FL_RETURN_IF_ERROR(WriteSideFile(side_path, compensation));
  if (Status s = WriteFileAtomic(program_path, program); !s.ok()) {
    std::error_code ec;
    std::filesystem::remove(side_path, ec);
    return s;
  }
  compensation.program = std::move(program);
  compensation.program_moves = std::move(moves);
  compensation.check_max_disagreement_um = report.max_side_difference_um;
  return compensation;
}

}  // namespace formloop::nc
