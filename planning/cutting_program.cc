#include "planning/cutting_program.h"

#include <algorithm>
#include <cmath>
#include <map>

#include "core/file_hash.h"
#include "core/json_io.h"
#include "core/number_text.h"
#include "core/point_io.h"
#include "core/random.h"
#include "planning/program_edit.h"

namespace formloop::planning {
namespace {

// One engaged block of the program.
struct EngagedBlock {
  std::size_t line = 0, move = 0;
  double a_p_mm = 0, a_e_mm = 0, length_mm = 0;
};

std::string Mm(double v) { return FormatFixed(v, 3); }

// RS274NGC and Fanuc programs are read as shop programs (arcs, helices, G91, G20); Sinumerik programs are
// formloop's own output, read with its reader.
ProgramReading ReadingOf(const std::string& dialect) {
  return dialect == "sinumerik" ? ProgramReading::kFormloopSubset : ProgramReading::kShopProgram;
}

Result<std::vector<EngagedBlock>> Locate(const EditableProgram& program, const std::string& source,
                                         const std::vector<BlockEngagement>& engagement) {
  const bool numbered = program.NumberedBlocks();
  std::map<long, std::size_t> line_of_block;
  for (std::size_t i = 0; i < program.lines().size(); ++i) {
    const long id = numbered ? program.lines()[i].number : static_cast<long>(i + 1);
    if (id >= 0) line_of_block.emplace(id, i);
  }
  std::vector<EngagedBlock> out;
  std::map<long, std::size_t> seen;
  for (std::size_t k = 0; k < engagement.size(); ++k) {
    const BlockEngagement& e = engagement[k];
    const Where where{.file = "engagement", .field = "blocks[" + std::to_string(k) + "].block"};
    const std::string name = numbered ? "N" + std::to_string(e.block) : "line " + std::to_string(e.block);
    auto it = line_of_block.find(e.block);
    if (it == line_of_block.end()) {
      return Status::BadInput(where, name + " is not a block of " + source,
                              numbered ? "give the block's N number" : "the program has no N words: give its line");
    }
    const ProgramLine& line = program.lines()[it->second];
    if (line.move < 0 || program.moves()[static_cast<std::size_t>(line.move)].rapid) {
      return Status::BadInput(where, name + " of " + source + " is not a feed move",
                              "give engagement for G1 blocks only");
    }
    if (!seen.emplace(e.block, k).second) {
      return Status::BadInput(where, name + " appears twice", "give one row per block");
    }
    const auto move = static_cast<std::size_t>(line.move);
    const double length = program.MoveLengthMm(move);
    if (!std::isfinite(length)) {
      return Status::BadInput(where,
                              name + " of " + source +
                                  " starts or ends where the program's position is not known (none programmed before "
                                  "it, or after G28, G30, G53, G92 or a work-offset change): its length and volume "
                                  "are unknown",
                              "state X, Y and Z absolutely before the block");
    }
    out.push_back({it->second, move, e.a_p_mm, e.a_e_mm, length});
  }
  std::sort(out.begin(), out.end(), [](const EngagedBlock& a, const EngagedBlock& b) { return a.line < b.line; });
  return out;
}

// One tool operation per program: S is written on every spindle line, so a second tool would get this
// tool's speed. Refused, naming the line of the second tool.
Status CheckOneTool(const EditableProgram& program, const std::string& source) {
  std::string t, first;
  for (std::size_t i = 0; i < program.lines().size(); ++i) {
    if (!program.GetWord(i, 'T', &t)) continue;
    if (first.empty()) first = t;
    double tool = 0, first_tool = 0;
    const bool both = ParseDouble(t, &tool) && ParseDouble(first, &first_tool);
    if (!both || tool != first_tool) {
      return Status::BadInput(Where{.file = source, .line = static_cast<long>(i + 1)},
                              program.BlockName(i) + " selects tool T" + t + " after T" + first +
                                  ": Level 1 optimises one tool operation, and its S would reach the other tool",
                              "give the program of one tool operation");
    }
  }
  return Status::Ok();
}

int ToolNumber(const EditableProgram& program) {
  std::string t;
  for (std::size_t i = 0; i < program.lines().size(); ++i) {
    if (program.GetWord(i, 'T', &t)) return std::atoi(t.c_str());
  }
  return 0;
}

Status DepthCheck(const EditableProgram& program, const std::vector<EngagedBlock>& blocks,
                  const CuttingCoefficients& k) {
  std::string failures;
  int count = 0;
  const int tool = ToolNumber(program);
  for (const EngagedBlock& b : blocks) {
    if (b.a_e_mm == 0 && b.a_p_mm >= 0) continue;  // not cutting
    const DepthOfCutLimits lim = DepthOfCutLimitsFor(k, b.a_e_mm);
    const bool ap_ok = b.a_p_mm > 0 && b.a_p_mm <= lim.a_p_max_mm;
    const bool ae_ok = b.a_e_mm > 0 && b.a_e_mm <= lim.a_e_max_mm;
    if (ap_ok && ae_ok) continue;
    ++count;
    failures += "\n  " + program.BlockName(b.line) + " (tool T" + std::to_string(tool) + ", " + lim.operation +
                "): a_p = " + Mm(b.a_p_mm) + " mm (limit 0 < a_p <= " + Mm(lim.a_p_max_mm) +
                "), a_e = " + Mm(b.a_e_mm) + " mm (limit 0 < a_e <= " + Mm(lim.a_e_max_mm) + ")";
  }
  if (count == 0) return Status::Ok();
  return Status::SafetyLimit("L1-DOC-RANGE: " + std::to_string(count) +
                             " block(s) cut outside the tool's depth limits (a_p,max = min(0.9 L_c, k_ap d), "
                             "a_e,max = d); nothing optimised, nothing written:" +
                             failures + "\nFix: split the cut into shallower passes or use a tool for this depth");
}

}  // namespace

Result<std::vector<BlockEngagement>> BlockEngagementFromJson(const nlohmann::json& json, const std::string& source) {
  if (!json.is_object() || !json.contains("blocks") || !json["blocks"].is_array()) {
    return Status::BadInput(Where{.file = source, .field = "blocks"}, "expected {\"blocks\": [...]}",
                            "one object per cutting block: {\"block\": N, \"a_p_mm\": ..., \"a_e_mm\": ...}");
  }
  std::vector<BlockEngagement> out;
  const nlohmann::json& rows = json["blocks"];
  for (std::size_t i = 0; i < rows.size(); ++i) {
    const std::string prefix = "blocks[" + std::to_string(i) + "].";
    if (!rows[i].is_object()) return Status::BadInput(Where{.file = source, .field = prefix}, "must be an object");
    JsonFields f(rows[i], source, prefix);
    FL_RETURN_IF_ERROR(f.CheckKnown({"block", "a_p_mm", "a_e_mm"}));
    BlockEngagement e;
    long long block = 0;
    FL_RETURN_IF_ERROR(f.Integer("block", &block, 0));
    e.block = static_cast<long>(block);
    FL_RETURN_IF_ERROR(f.Number("a_p_mm", &e.a_p_mm));
    FL_RETURN_IF_ERROR(f.Number("a_e_mm", &e.a_e_mm, {.min = 0}));
    out.push_back(e);
  }
  return out;
}

DepthOfCutLimits DepthOfCutLimitsFor(const CuttingCoefficients& k, double a_e_mm) {
  const double d = k.base.diameter_mm;
  const bool slot = a_e_mm >= d * (1 - 1e-9);
  const double k_ap = slot ? k.tool.k_ap_slotting : k.tool.k_ap_side_milling;
  return {std::min(0.9 * k.tool.flute_length_mm, k_ap * d), d, slot ? "slotting" : "side_milling"};
}

Status CuttingProgramOptions::Validate() const {
  FL_RETURN_IF_ERROR(ga.Validate());
  if (!(group_tolerance >= 0 && group_tolerance < 0.5)) {
    return Status::BadInput(Where{.field = "group_tolerance"}, "must lie in [0, 0.5)");
  }
  if (!(model_credibility >= 0 && model_credibility <= 1)) {
    return Status::BadInput(Where{.field = "model_credibility"}, "must lie in [0, 1]");
  }
  return Status::Ok();
}

nlohmann::json CuttingGroup::ToJson() const {
  return {{"a_p_mm", a_p_mm},
          {"a_e_mm", a_e_mm},
          {"blocks", blocks},
          {"volume_mm3", volume_mm3},
          {"model_optimum", model.ToJson()},
          {"written", state.ToJson()},
          {"sets_spindle", sets_spindle}};
}

nlohmann::json CuttingProgramReport::ToJson() const {
  nlohmann::json g = nlohmann::json::array();
  for (const CuttingGroup& group : groups) g.push_back(group.ToJson());
  return {{"parent_sha256", parent_sha256},
          {"coefficient_set", coefficient_set},
          {"seed", seed},
          {"tool", tool_number},
          {"spindle_rpm", spindle_rpm},
          {"fusion", fusion.ToJson()},
          {"groups", g},
          {"cutting_blocks", cutting_blocks},
          {"lines_changed", lines_changed},
          {"cutting_time_before_min", cutting_time_before_min},
          {"cutting_time_after_min", cutting_time_after_min},
          {"warnings", warnings}};
}

Status CheckDepthOfCut(const std::string& program_text, const std::string& dialect, const std::string& source,
                       const std::vector<BlockEngagement>& engagement, const CuttingCoefficients& coefficients) {
  FL_ASSIGN_OR_RETURN(EditableProgram program,
                      EditableProgram::Parse(program_text, dialect, source, ReadingOf(dialect)));
  FL_ASSIGN_OR_RETURN(std::vector<EngagedBlock> blocks, Locate(program, source, engagement));
  return DepthCheck(program, blocks, coefficients);
}

Result<CuttingProgramReport> OptimiseCuttingProgram(const std::string& program_text, const std::string& dialect,
                                                    const std::string& source,
                                                    const std::vector<BlockEngagement>& engagement,
                                                    const CuttingCoefficients& coefficients,
                                                    const CuttingProgramOptions& options) {
  FL_RETURN_IF_ERROR(options.Validate());
  FL_ASSIGN_OR_RETURN(EditableProgram program,
                      EditableProgram::Parse(program_text, dialect, source, ReadingOf(dialect)));
  FL_ASSIGN_OR_RETURN(std::vector<EngagedBlock> blocks, Locate(program, source, engagement));
  FL_RETURN_IF_ERROR(DepthCheck(program, blocks, coefficients));
  FL_RETURN_IF_ERROR(CheckOneTool(program, source));

  CuttingProgramReport report;
  report.parent_sha256 = Sha256Hex(program_text);
  report.coefficient_set = coefficients.base.coefficient_set;
  report.seed = options.seed;
  report.tool_number = ToolNumber(program);
  report.warnings = coefficients.base.Warnings();
  for (const std::string& w : program.warnings()) report.warnings.push_back(w);

  // Groups by (a_p, a_e) within the tolerance, first fit in program order.
  std::vector<EngagedBlock> cutting;
  for (const EngagedBlock& b : blocks) {
    if (b.a_e_mm > 0) cutting.push_back(b);
  }
  report.cutting_blocks = static_cast<int>(cutting.size());
  if (cutting.empty()) return Status::BadInput(Where{.file = source}, "no block has a radial engagement a_e > 0");
  std::vector<std::vector<std::size_t>> members;
  std::vector<std::pair<double, double>> reference;  // the first block's (a_p, a_e) of each group
  std::vector<int> group_of(cutting.size());
  const double tol = options.group_tolerance;
  for (std::size_t i = 0; i < cutting.size(); ++i) {
    std::size_t g = 0;
    for (; g < reference.size(); ++g) {
      if (std::abs(cutting[i].a_p_mm - reference[g].first) <= tol * reference[g].first &&
          std::abs(cutting[i].a_e_mm - reference[g].second) <= tol * reference[g].second) {
        break;
      }
    }
    if (g == reference.size()) {
      reference.emplace_back(cutting[i].a_p_mm, cutting[i].a_e_mm);
      members.emplace_back();
    }
    members[g].push_back(i);
    group_of[i] = static_cast<int>(g);
  }

  // The GA per group, each from its own fork of the seed.
  Rng rng(options.seed);
  std::vector<CuttingCase> cases;
  for (std::size_t g = 0; g < members.size(); ++g) {
    CuttingGroup group;
    for (std::size_t i : members[g]) {
      group.a_p_mm = std::max(group.a_p_mm, cutting[i].a_p_mm);
      group.a_e_mm = std::max(group.a_e_mm, cutting[i].a_e_mm);
      group.volume_mm3 += cutting[i].length_mm * cutting[i].a_p_mm * cutting[i].a_e_mm;
      group.blocks.push_back(program.BlockName(cutting[i].line));
    }
    CuttingCase c = coefficients.base;
    c.a_p_mm = group.a_p_mm;
    c.a_e_mm = group.a_e_mm;
    auto opt = CuttingOptimumGa(c, rng.Fork(), options.ga);
    if (!opt.ok()) {
      return Status(opt.status().code(), "blocks " + group.blocks.front() + " .. " + group.blocks.back() + " (a_p = " +
                                             Mm(c.a_p_mm) + ", a_e = " + Mm(c.a_e_mm) + "): " + opt.status().message());
    }
    group.model = *opt;
    cases.push_back(c);
    report.groups.push_back(std::move(group));
  }

  // n_op from the group that removes the most volume, fused with the case library's data.
  std::size_t lead = 0;
  for (std::size_t g = 1; g < report.groups.size(); ++g) {
    if (report.groups[g].volume_mm3 > report.groups[lead].volume_mm3) lead = g;
  }
  report.groups[lead].sets_spindle = true;
  const CuttingCase& lead_case = cases[lead];
  const std::optional<CuttingDataMatch> match =
      MatchCuttingData(options.cutting_data, coefficients.tool, lead_case.diameter_mm,
                       DepthOfCutLimitsFor(coefficients, lead_case.a_e_mm).operation);
  report.fusion = FuseWithDatabase(lead_case, report.groups[lead].model.state, match, options.model_credibility);
  for (const std::string& w : report.fusion.warnings) report.warnings.push_back(w);
  const double n_op = std::clamp(std::round(report.fusion.state.n_rpm), std::ceil(lead_case.n_min_rpm),
                                 std::floor(lead_case.n_max_rpm));
  report.spindle_rpm = n_op;

  // The feed of each group at n_op, rounded down to whole mm/min.
  std::vector<double> feed(report.groups.size());
  for (std::size_t g = 0; g < report.groups.size(); ++g) {
    const CuttingCase& c = cases[g];
    const double cap = CuttingFeedCap(c, n_op);
    double f_z = std::min(c.f_z_max_mm, cap);
    if (g == lead) f_z = std::min(report.fusion.state.f_z_mm, cap);
    const double v_f = std::floor(f_z * c.flutes * n_op);
    if (cap < c.f_z_min_mm || v_f / (c.flutes * n_op) < c.f_z_min_mm) {
      return Status::BadInput("L1-INFEASIBLE: blocks " + report.groups[g].blocks.front() + " .. " +
                              report.groups[g].blocks.back() + " (a_p = " + Mm(c.a_p_mm) + ", a_e = " + Mm(c.a_e_mm) +
                              ") admit no feed per tooth >= f_z,min at the operation's spindle speed " +
                              FormatFixed(n_op, 0) +
                              " rpm. Fix: split them into a separate operation or relax "
                              "the limits");
    }
    feed[g] = v_f;
    report.groups[g].state = EvaluateCutting(c, v_f / (c.flutes * n_op), n_op);
  }

  // Edit: S on every spindle line, F where the feed must change.
  std::vector<std::string> before;
  for (const ProgramLine& l : program.lines()) before.push_back(l.text);
  std::string word;
  for (std::size_t i = 0; i < program.lines().size(); ++i) {
    // A shop program may set S on a move line ("G0 X0 Y0 S12000 M3"); formloop's own output never does.
    const bool spindle_line = program.lines()[i].move < 0 || ReadingOf(dialect) == ProgramReading::kShopProgram;
    if (spindle_line && program.GetWord(i, 'S', &word)) program.SetWord(i, 'S', FeedWord(n_op));
  }
  std::map<std::size_t, double> desired;  // move index -> feed
  for (std::size_t i = 0; i < cutting.size(); ++i) {
    desired[cutting[i].move] = feed[static_cast<std::size_t>(group_of[i])];
    const double original = program.moves()[cutting[i].move].feed_mm_per_min;
    report.cutting_time_before_min += cutting[i].length_mm / original;
    report.cutting_time_after_min += cutting[i].length_mm / feed[static_cast<std::size_t>(group_of[i])];
  }
  program.SetFeeds(desired);
  for (std::size_t i = 0; i < before.size(); ++i) report.lines_changed += before[i] != program.lines()[i].text;
  program.InsertHeaderComments({"formloop optimise cutting: parent sha256 " + report.parent_sha256,
                                "coefficient set " + report.coefficient_set + ", seed " + std::to_string(options.seed) +
                                    ", w_m " + FormatFixed(report.fusion.w_m, 3) + ", S " + FeedWord(n_op) + " rpm, " +
                                    std::to_string(report.groups.size()) + " engagement group(s)"});
  FL_ASSIGN_OR_RETURN(report.program, program.Verified(source + " (optimised)"));
  return report;
}

}  // namespace formloop::planning
