#include "app/optimise_jobs.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <ctime>
#include <filesystem>
#include <map>
#include <optional>
#include <vector>

#include "app/report_charts.h"
#include "app/report_image.h"
#include "app/run_folder.h"
#include "core/atomic_file.h"
#include "core/file_hash.h"
#include "core/json_io.h"
#include "core/log.h"
#include "core/number_text.h"
#include "core/point_io.h"
#include "kb/library.h"
#include "nc-gen/post.h"
#include "planning/cutting_program.h"
#include "planning/feed_control.h"
#include "planning/inspection_adjustment.h"
#include "planning/program_edit.h"
#include "planning/tool_path_engagement.h"
#include "reconstruction/cad_io.h"
#include "reconstruction/foot_point.h"

namespace formloop::app {
namespace {

namespace fs = std::filesystem;
using nlohmann::json;

constexpr const char* kMarker = "optimise.json";

bool Inside(const fs::path& file, const fs::path& folder) {
  std::error_code ec;
  const fs::path f = fs::weakly_canonical(file, ec);
  const fs::path d = fs::weakly_canonical(folder, ec);
  auto fi = f.begin();
  for (auto di = d.begin(); di != d.end(); ++di, ++fi) {
    if (di->empty()) continue;  // a trailing separator
    if (fi == f.end() || *fi != *di) return false;
  }
  return true;
}

// The staging folder "<out>.partial" after the checks of the header; `inputs` are the files read.
Result<fs::path> BeginOutput(const OptimiseOutput& output, const std::vector<std::string>& inputs) {
  if (output.out.empty()) return Status::BadInput(Where{.field = "--out"}, "an output folder is required");
  const fs::path out(output.out);
  std::error_code ec;
  if (fs::exists(out, ec)) {
    if (!output.force) {
      return Status::BadInput(Where{.field = "--out"}, "'" + out.string() + "' exists",
                              "choose a new folder, or --force to replace an earlier optimise folder");
    }
    if (!fs::is_directory(out, ec) || !fs::exists(out / kMarker, ec)) {
      return Status::BadInput(
          Where{.field = "--out"},
          "'" + out.string() + "' was not written by `formloop optimise` (no " + kMarker + "); it is not replaced",
          "choose a new folder");
    }
  }
  for (const std::string& in : inputs) {
    if (!in.empty() && (Inside(in, out) || Inside(in, out.string() + ".partial"))) {
      return Status::BadInput(Where{.file = in, .field = "--out"}, "the input lies inside the output folder",
                              "write the output elsewhere");
    }
  }
  const fs::path staging = out.string() + ".partial";
  fs::remove_all(staging, ec);
  FL_RETURN_IF_ERROR(MakeDirectories(staging));
  return staging;
}

Status FinishOutput(const fs::path& staging, const OptimiseOutput& output) {
  const fs::path out(output.out);
  std::error_code ec;
  fs::remove_all(out, ec);  // only an earlier optimise folder gets here (BeginOutput)
  fs::rename(staging, out, ec);
  if (ec) return Status::IoError("cannot move '" + staging.string() + "' to '" + out.string() + "': " + ec.message());
  return Status::Ok();
}

// {"path": sha256} of every input file given.
Result<json> InputHashes(const std::vector<std::string>& files) {
  json out = json::object();
  for (const std::string& f : files) {
    if (f.empty()) continue;
    FL_ASSIGN_OR_RETURN(const std::string sha, Sha256OfFile(f));
    out[f] = sha;
  }
  return out;
}

Result<std::string> ProgramExtension(const std::string& dialect) {
  const nc::PostDialect* post = nc::FindPost(dialect);
  if (post == nullptr) {
    return Status::BadInput(Where{.field = "--dialect"}, "unknown dialect '" + dialect + "'",
                            "use linuxcnc, fanuc, heidenhain or sinumerik");
  }
  return std::string(post->FileExtension());
}

// The case library's recommended cutting data and/or a file of records.
Result<std::vector<planning::CuttingDataRecord>> CuttingData(const OptimiseCuttingArgs& args,
                                                             std::vector<std::string>* notes) {
  std::vector<planning::CuttingDataRecord> out;
  if (!args.cutting_data.empty()) {
    FL_ASSIGN_OR_RETURN(const json records, ReadJsonFile(args.cutting_data));
    FL_ASSIGN_OR_RETURN(out, planning::CuttingDataFromJson(records, args.cutting_data));
  }
  if (args.library.empty() != args.case_uid.empty()) {
    return Status::BadInput(Where{.field = args.library.empty() ? "--library" : "--case"},
                            "--library and --case go together",
                            "name the case library and the case whose "
                            "manufacturing.cutting_data to use");
  }
  if (!args.library.empty()) {
    FL_ASSIGN_OR_RETURN(auto library, kb::Library::Open(args.library));
    FL_ASSIGN_OR_RETURN(const kb::CaseRecord record, library->GetCase(args.case_uid));
    if (!record.manufacturing.contains("cutting_data")) {
      notes->push_back("case " + args.case_uid + " keeps no manufacturing.cutting_data: the model optimum is used");
    } else {
      FL_ASSIGN_OR_RETURN(
          std::vector<planning::CuttingDataRecord> from_case,
          planning::CuttingDataFromJson(record.manufacturing["cutting_data"],
                                        args.library + ": case " + args.case_uid + " manufacturing.cutting_data"));
      for (planning::CuttingDataRecord& r : from_case) out.push_back(std::move(r));
    }
  }
  return out;
}

// One cut (no program): GA, exact LP, Taylor lives, constraints, fusion.
Result<json> OptimiseOneCut(const OptimiseCuttingArgs& args, const planning::CuttingCoefficients& coefficients,
                            const std::vector<planning::CuttingDataRecord>& records) {
  for (const auto& [value, option] : {std::pair{args.a_p_mm, "--a-p-mm"}, std::pair{args.a_e_mm, "--a-e-mm"}}) {
    if (!(value > 0) || !std::isfinite(value)) {
      return Status::BadInput(Where{.field = option}, "needs a depth of cut > 0 mm (or give --program)");
    }
  }
  planning::CuttingCase c = coefficients.base;
  c.a_p_mm = args.a_p_mm;
  c.a_e_mm = args.a_e_mm;
  FL_RETURN_IF_ERROR(c.Validate());
  const planning::DepthOfCutLimits limits = planning::DepthOfCutLimitsFor(coefficients, c.a_e_mm);
  if (c.a_p_mm > limits.a_p_max_mm || c.a_e_mm > limits.a_e_max_mm) {
    return Status::SafetyLimit("L1-DOC-RANGE: the cut a_p " + FormatFixed(c.a_p_mm, 3) + " mm, a_e " +
                               FormatFixed(c.a_e_mm, 3) + " mm is beyond the tool's limits for " + limits.operation +
                               " (a_p <= " + FormatFixed(limits.a_p_max_mm, 3) +
                               " mm, a_e <= " + FormatFixed(limits.a_e_max_mm, 3) + " mm); fix --a-p-mm/--a-e-mm");
  }
  FL_ASSIGN_OR_RETURN(const planning::CuttingOptimum ga, planning::CuttingOptimumGa(c, args.seed));
  FL_ASSIGN_OR_RETURN(const planning::CuttingOptimum exact, planning::CuttingOptimumExact(c));
  json constraints = json::array();
  for (const planning::ConstraintValue& g : planning::CuttingConstraints(c, ga.state)) {
    constraints.push_back(
        {{"name", g.name}, {"label", g.label}, {"relative", g.relative}, {"satisfied", g.relative <= 1e-9}});
  }
  const auto match = planning::MatchCuttingData(records, coefficients.tool, c.diameter_mm, limits.operation);
  const planning::FusedCuttingPoint fused = planning::FuseWithDatabase(c, ga.state, match, args.model_credibility);
  const double shortfall = 100 * (1 - ga.state.q_mm3_per_min / exact.state.q_mm3_per_min);
  log::Info(
      "optimise cutting: Q {:.0f} mm3/min by the GA (seed {}), {:.0f} by the exact LP ({:.4f} % short), "
      "T_p {:.2f} min, T_c {:.2f} min",
      ga.state.q_mm3_per_min, args.seed, exact.state.q_mm3_per_min, shortfall, planning::MaxProductionToolLifeMin(c),
      planning::MinCostToolLifeMin(c));
  return json{{"case", c.ToJson()},
              {"warnings", c.Warnings()},
              {"depth_of_cut_limits",
               {{"operation", limits.operation}, {"a_p_max_mm", limits.a_p_max_mm}, {"a_e_max_mm", limits.a_e_max_mm}}},
              {"taylor",
               {{"T_p_min", planning::MaxProductionToolLifeMin(c)},
                {"T_c_min", planning::MinCostToolLifeMin(c)},
                {"T_min_in_effect_min", c.TMinMin()}}},
              {"ga", ga.ToJson()},
              {"exact", exact.ToJson()},
              {"ga_shortfall_percent", shortfall},
              {"constraints_at_ga", constraints},
              {"fusion", fused.ToJson()}};
}

}  // namespace

Result<json> RunOptimiseCutting(const OptimiseCuttingArgs& args) {
  if (args.coefficients.empty()) {
    return Status::BadInput(Where{.field = "--coefficients"}, "a coefficient file is required",
                            "see data/cutting/s1.json");
  }
  FL_ASSIGN_OR_RETURN(const json coefficient_json, ReadJsonFile(args.coefficients));
  FL_ASSIGN_OR_RETURN(const planning::CuttingCoefficients coefficients,
                      planning::CuttingCoefficientsFromJson(coefficient_json, args.coefficients));
  std::vector<std::string> notes;
  FL_ASSIGN_OR_RETURN(const std::vector<planning::CuttingDataRecord> records, CuttingData(args, &notes));
  const std::vector<std::string> inputs = {args.coefficients, args.program, args.engagement, args.stock,
                                           args.cutting_data};
  json result = {{"command", "optimise cutting"}, {"seed", args.seed}, {"notes", notes}};
  FL_ASSIGN_OR_RETURN(result["inputs"], InputHashes(inputs));
  std::string program_name, program_text;
  if (args.program.empty()) {
    if (!args.engagement.empty() || !args.stock.empty()) {
      return Status::BadInput(Where{.field = "--program"}, "--engagement and --stock describe a program's cut",
                              "give the program too");
    }
    FL_ASSIGN_OR_RETURN(result["cut"], OptimiseOneCut(args, coefficients, records));
  } else {
    if (args.engagement.empty() == args.stock.empty()) {
      return Status::BadInput(
          Where{.field = "--engagement"},
          "a program needs its engagement: either --engagement ENGAGEMENT.json or --stock STOCK.json");
    }
    FL_ASSIGN_OR_RETURN(const std::string ext, ProgramExtension(args.dialect));
    FL_ASSIGN_OR_RETURN(const std::string text, ReadFile(args.program));
    std::vector<planning::BlockEngagement> engagement;
    if (!args.engagement.empty()) {
      FL_ASSIGN_OR_RETURN(const json e, ReadJsonFile(args.engagement));
      FL_ASSIGN_OR_RETURN(engagement, planning::BlockEngagementFromJson(e, args.engagement));
    } else {
      FL_ASSIGN_OR_RETURN(const json s, ReadJsonFile(args.stock));
      FL_ASSIGN_OR_RETURN(const planning::StockDescription stock, planning::StockFromJson(s, args.stock));
      FL_ASSIGN_OR_RETURN(
          const planning::ProgramEngagement cut,
          planning::EngagementOfProgram(text, args.dialect, args.program, stock, coefficients.base.diameter_mm / 2));
      FL_ASSIGN_OR_RETURN(engagement, planning::BlockEngagementOfProgram(text, args.dialect, args.program, cut));
    }
    planning::CuttingProgramOptions options;
    options.seed = args.seed;
    options.model_credibility = args.model_credibility;
    options.cutting_data = records;
    FL_ASSIGN_OR_RETURN(
        const planning::CuttingProgramReport report,
        planning::OptimiseCuttingProgram(text, args.dialect, args.program, engagement, coefficients, options));
    result["program"] = report.ToJson();
    program_name = "program" + ext;
    program_text = report.program;
    result["program"]["file"] = program_name;
    log::Info(
        "optimise cutting: {} cutting blocks in {} groups, n_op {:.0f} rpm, cutting time {:.2f} -> {:.2f} min, "
        "{} lines changed",
        report.cutting_blocks, report.groups.size(), report.spindle_rpm, report.cutting_time_before_min,
        report.cutting_time_after_min, report.lines_changed);
  }
  if (args.output.out.empty()) {
    if (!args.program.empty()) return Status::BadInput(Where{.field = "--out"}, "a program is written into --out");
    return result;
  }
  FL_ASSIGN_OR_RETURN(const fs::path staging, BeginOutput(args.output, inputs));
  if (!program_name.empty()) FL_RETURN_IF_ERROR(WriteFileAtomic(staging / program_name, program_text));
  FL_RETURN_IF_ERROR(WriteJsonFile(staging / kMarker, result));
  FL_RETURN_IF_ERROR(FinishOutput(staging, args.output));
  return result;
}

namespace {

std::string SamplesCsv(const std::vector<std::pair<std::string, const planning::FeedControlResult*>>& runs) {
  std::string out =
      "run,t_s,s_mm,current_a,measured_a,voltage_v,feed_command_mm_per_min,feed_actual_mm_per_min,"
      "a_e_mm,a_p_mm,mode\n";
  for (const auto& [name, run] : runs) {
    for (const planning::FeedSample& s : run->samples) {
      out += name + "," + FormatFixed(s.t_s, 4) + "," + FormatFixed(s.s_mm, 4) + "," + FormatFixed(s.current_a, 4) +
             "," + FormatFixed(s.measured_a, 4) + "," + FormatFixed(s.voltage_v, 2) + "," +
             FormatFixed(s.feed_command, 2) + "," + FormatFixed(s.feed_actual, 2) + "," + FormatFixed(s.a_e_mm, 4) +
             "," + FormatFixed(s.a_p_mm, 4) + "," + planning::FeedModeName(s.mode) + "\n";
    }
  }
  return out;
}

Canvas FeedPlot(const planning::FeedControlResult& adaptive, const planning::FeedControlResult& constant,
                double constant_feed) {
  auto series = [](const planning::FeedControlResult& run, bool current, const std::string& label, Rgb colour) {
    TimeSeries s{.label = label, .colour = colour};
    for (const planning::FeedSample& x : run.samples) {
      s.t_s.push_back(x.t_s);
      s.values.push_back(current ? x.current_a : x.feed_actual);
    }
    return s;
  };
  const Rgb fuzzy = HexColour(0x2166ac), fixed = HexColour(0xff7f00), limit = HexColour(0xd7191c);
  const planning::FeedControlFigures& f = adaptive.figures;
  TimePanel current{
      .series = {series(constant, true, "constant feed " + FormatFixed(constant_feed, 0) + " mm/min", fixed),
                 series(adaptive, true, "fuzzy feed control", fuzzy)},
      .levels = {{f.reference_a, "I ref " + FormatFixed(f.reference_a, 2) + " A", HexColour(0x4daf4a)},
                 {f.overload_a, "I over " + FormatFixed(f.overload_a, 2) + " A", limit}},
      .y_label = "spindle current (A)"};
  TimePanel feed{
      .series = {series(constant, false, "constant feed", fixed), series(adaptive, false, "fuzzy feed control", fuzzy)},
      .levels = {},
      .y_label = "feed (mm/min)"};
  return DrawTimePanels({current, feed}, "feed control: spindle current and feed over time");
}

std::string HtmlEscape(const std::string& text) {
  std::string out;
  for (char ch : text) {
    if (ch == '<')
      out += "&lt;";
    else if (ch == '>')
      out += "&gt;";
    else if (ch == '&')
      out += "&amp;";
    else
      out += ch;
  }
  return out;
}

std::string FeedReportHtml(const json& result, const std::string& png) {
  const json& a = result["fuzzy"];
  const json& c = result["constant"];
  const json& k = result["criteria"];
  auto row = [](const std::string& name, const std::string& fuzzy, const std::string& constant) {
    return "<tr><td>" + HtmlEscape(name) + "</td><td>" + HtmlEscape(fuzzy) + "</td><td>" + HtmlEscape(constant) +
           "</td></tr>\n";
  };
  auto num = [](const json& v, int decimals) { return v.is_number() ? FormatFixed(v.get<double>(), decimals) : "-"; };
  std::string html =
      "<!DOCTYPE html>\n<html><head><meta charset=\"utf-8\"><title>formloop optimise feed</title>\n"
      "<style>body{font-family:sans-serif;margin:2em}table{border-collapse:collapse}td,th{border:1px solid #ccc;"
      "padding:4px 8px;text-align:right}td:first-child{text-align:left}</style></head><body>\n"
      "<h1>Fuzzy feed control (spec/process-optimization.md &sect;2)</h1>\n<p>Path: " +
      HtmlEscape(result["path"]["source"].get<std::string>()) + " (" + num(result["path"]["length_mm"], 1) +
      " mm of cutting path). Plant: the &sect;2.6 reference spindle (tool S1, " +
      num(result["plant"]["spindle_rpm"], 0) + " rpm), noise seed " +
      std::to_string(result["noise_seed"].get<std::uint64_t>()) +
      ".</p>\n<img alt=\"spindle current and feed over time\" src=\"data:image/png;base64," + Base64(png) +
      "\">\n<table><tr><th></th><th>fuzzy feed control</th><th>constant feed</th></tr>\n";
  html += row("machining time (s)", num(a["machining_time_s"], 2), num(c["machining_time_s"], 2));
  html += row("peak current (A)", num(a["peak_a"], 2), num(c["peak_a"], 2));
  html += row("time above I_over (s)", num(a["above_overload_s"], 3), num(c["above_overload_s"], 3));
  html += row("largest regulation error (%)", num(json(100 * a["max_regulation_error"].get<double>()), 2), "-");
  html += row("engagement steps", std::to_string(a["steps"].size()), std::to_string(c["steps"].size()));
  html += "</table>\n<h2>Criteria (&sect;2.7)</h2>\n<table><tr><th>criterion</th><th>value</th><th>met</th></tr>\n";
  for (const json& item : k) {
    html += "<tr><td>" + HtmlEscape(item["criterion"].get<std::string>()) + "</td><td>" +
            HtmlEscape(item["value"].get<std::string>()) + "</td><td>" + (item["met"].get<bool>() ? "yes" : "NO") +
            "</td></tr>\n";
  }
  html += "</table>\n</body></html>\n";
  return html;
}

}  // namespace

Result<json> RunOptimiseFeed(const OptimiseFeedArgs& args) {
  planning::FeedControlOptions options = planning::ReferenceFeedControlOptions();
  options.noise_seed = args.noise_seed;
  std::optional<planning::ProgramEngagement> path;
  std::string source;
  std::string scenario_program;  // the scenario's program and stock, written to inputs/ for reuse
  json scenario_stock;
  if (!args.scenario.empty()) {
    if (args.scenario != "wall-step") {
      return Status::BadInput(Where{.field = "--scenario"}, "unknown scenario '" + args.scenario + "'",
                              "the scenario is wall-step");
    }
    if (!args.program.empty() || !args.stock.empty()) {
      return Status::BadInput(Where{.field = "--scenario"}, "give either --scenario or --program with --stock");
    }
    FL_ASSIGN_OR_RETURN(const planning::WallStepScenario wall, planning::WallStepEngagement());
    path = wall;
    scenario_program = wall.program;
    scenario_stock = {{"cell_mm", wall.stock.cell_mm}, {"prisms", json::array()}};
    for (const planning::StockPrism& prism : wall.stock.prisms) {
      json outline = json::array();
      for (const Eigen::Vector2d& v : prism.outline_mm) outline.push_back({v.x(), v.y()});
      scenario_stock["prisms"].push_back({{"outline_mm", outline}, {"top_z_mm", prism.top_z_mm}});
    }
    source = "scenario wall-step: formloop raster over a 5 mm wall, a_e 1 -> 3 mm at x = 100, back to 1 mm by x = 300";
  } else {
    if (args.program.empty() || args.stock.empty()) {
      return Status::BadInput(Where{.field = args.program.empty() ? "--program" : "--stock"},
                              "feed control needs a program and the stock it cuts (or --scenario wall-step)");
    }
    FL_ASSIGN_OR_RETURN(const std::string text, ReadFile(args.program));
    FL_ASSIGN_OR_RETURN(const json s, ReadJsonFile(args.stock));
    FL_ASSIGN_OR_RETURN(const planning::StockDescription stock, planning::StockFromJson(s, args.stock));
    FL_ASSIGN_OR_RETURN(
        path, planning::EngagementOfProgram(text, args.dialect, args.program, stock, options.plant.diameter_mm / 2));
    source = args.program + " cutting " + args.stock;
  }
  const sim::EngagementProfile& profile = path->engagement.profile;
  FL_ASSIGN_OR_RETURN(const planning::FeedControlResult fuzzy, planning::RunFeedControl(profile, options));
  const double constant_feed = planning::ConservativeFeed(profile, options);
  FL_ASSIGN_OR_RETURN(const planning::FeedControlResult constant,
                      planning::RunConstantFeed(profile, options, constant_feed));
  const planning::FeedControlFigures& a = fuzzy.figures;
  const planning::FeedControlFigures& c = constant.figures;
  double worst_settle = 0;
  for (const planning::StepResponse& s : a.steps) worst_settle = std::max(worst_settle, s.settle_s);
  const double time_ratio = a.machining_time_s / c.machining_time_s;
  json criteria = json::array();
  auto criterion = [&](const std::string& name, const std::string& value, bool met) {
    criteria.push_back({{"criterion", name}, {"value", value}, {"met", met}});
  };
  criterion("every engagement step settles within +-5 % of I_ref in <= 1 s",
            std::to_string(a.steps.size()) + " steps, worst " + FormatFixed(worst_settle, 3) + " s",
            worst_settle <= 1.0);
  criterion("regulation outside the steps within +-5 %", FormatFixed(100 * a.max_regulation_error, 2) + " %",
            a.max_regulation_error <= 0.05);
  criterion("the fuzzy run never exceeds I_over",
            "peak " + FormatFixed(a.peak_a, 2) + " A, " + FormatFixed(a.above_overload_s, 3) + " s above",
            a.above_overload_s == 0);
  criterion("the constant feed never exceeds I_over either",
            "peak " + FormatFixed(c.peak_a, 2) + " A, " + FormatFixed(c.above_overload_s, 3) + " s above",
            c.above_overload_s == 0);
  criterion("machining time >= 20 % shorter than the constant feed",
            FormatFixed(a.machining_time_s, 2) + " s vs " + FormatFixed(c.machining_time_s, 2) + " s (" +
                FormatFixed(100 * (1 - time_ratio), 1) + " % shorter)",
            time_ratio <= 0.8);
  criterion("both runs finish the path", std::string(a.finished ? "yes" : "no") + " / " + (c.finished ? "yes" : "no"),
            a.finished && c.finished);
  bool all = true;
  for (const json& k : criteria) all = all && k["met"].get<bool>();
  json result = {{"command", "optimise feed"},
                 {"noise_seed", args.noise_seed},
                 {"path", {{"source", source}, {"length_mm", profile.length_mm()}, {"moves", path->tips.size()}}},
                 {"plant", {{"spindle_rpm", options.plant.spindle_rpm}, {"diameter_mm", options.plant.diameter_mm}}},
                 {"constant_feed_mm_per_min", constant_feed},
                 {"fuzzy", a.ToJson()},
                 {"constant", c.ToJson()},
                 {"time_ratio", time_ratio},
                 {"criteria", criteria},
                 {"all_criteria_met", all},
                 {"files", {"feed.csv", "feed.png", "report.html", kMarker}}};
  if (!scenario_program.empty()) {
    result["files"].push_back("inputs/program.ngc");
    result["files"].push_back("inputs/stock.json");
  }
  FL_ASSIGN_OR_RETURN(result["inputs"], InputHashes({args.program, args.stock}));
  log::Info(
      "optimise feed: {:.2f} s with fuzzy control vs {:.2f} s at the constant {:.0f} mm/min ({:.1f} % shorter); "
      "peak {:.2f} A (I_over {:.2f} A), worst settle {:.3f} s over {} steps, regulation {:.2f} %",
      a.machining_time_s, c.machining_time_s, constant_feed, 100 * (1 - time_ratio), a.peak_a, a.overload_a,
      worst_settle, a.steps.size(), 100 * a.max_regulation_error);
  FL_ASSIGN_OR_RETURN(const fs::path staging, BeginOutput(args.output, {args.program, args.stock}));
  FL_ASSIGN_OR_RETURN(const std::string png, EncodePng(FeedPlot(fuzzy, constant, constant_feed)));
  FL_RETURN_IF_ERROR(WriteFileAtomic(staging / "feed.csv", SamplesCsv({{"fuzzy", &fuzzy}, {"constant", &constant}})));
  FL_RETURN_IF_ERROR(WriteFileAtomic(staging / "feed.png", png, /*binary=*/true));
  if (!scenario_program.empty()) {
    FL_RETURN_IF_ERROR(MakeDirectories(staging / "inputs"));
    FL_RETURN_IF_ERROR(WriteFileAtomic(staging / "inputs" / "program.ngc", scenario_program));
    FL_RETURN_IF_ERROR(WriteJsonFile(staging / "inputs" / "stock.json", scenario_stock));
  }
  FL_RETURN_IF_ERROR(WriteFileAtomic(staging / "report.html", FeedReportHtml(result, png)));
  FL_RETURN_IF_ERROR(WriteJsonFile(staging / kMarker, result));
  FL_RETURN_IF_ERROR(FinishOutput(staging, args.output));
  return result;
}

Result<json> RunOptimiseProgram(const OptimiseProgramArgs& args) {
  // The nominal surface, tool, tolerance and dialect: from the run folder, or given one by one.
  recon::BSplineSurface q;
  std::string dialect = args.dialect, part_name = "part", program_path = args.program,
              inspection_path = args.inspection;
  double radius = args.ball_radius_mm, tolerance = args.tolerance_mm;
  if (args.run.empty() == args.surface.empty()) {
    return Status::BadInput(Where{.field = "--run"},
                            "give either the `formloop run` folder that made the part (--run) or its nominal surface "
                            "(--surface Q.step with --program, --inspection, --ball-radius-mm and --tolerance-mm)");
  }
  if (!args.run.empty()) {
    FL_ASSIGN_OR_RETURN(RunFolder run, ReadRunFolder(args.run));
    q = std::move(run.q);
    dialect = run.part.dialect;
    part_name = run.part.name;
    FL_ASSIGN_OR_RETURN(const std::string ext, ProgramExtension(dialect));
    if (program_path.empty()) program_path = (fs::path(args.run) / "toolpath" / ("program" + ext)).string();
    if (inspection_path.empty()) inspection_path = (fs::path(args.run) / "loop-0" / "deviations.csv").string();
    if (radius <= 0) radius = run.toolpath.options.tool.radius_mm;
    if (tolerance <= 0) tolerance = run.part.tolerance_mm;
  } else {
    for (const auto& [missing, option] :
         {std::pair{program_path.empty(), "--program"}, std::pair{inspection_path.empty(), "--inspection"},
          std::pair{!(radius > 0), "--ball-radius-mm"}, std::pair{!(tolerance > 0), "--tolerance-mm"}}) {
      if (missing) return Status::BadInput(Where{.field = option}, "required with --surface (no run folder)");
    }
    FL_ASSIGN_OR_RETURN(const recon::CadFace face, recon::ReadCadFace(args.surface, {}));
    q = face.surface;
  }
  FL_ASSIGN_OR_RETURN(const std::string ext, ProgramExtension(dialect));
  FL_ASSIGN_OR_RETURN(const std::string text, ReadFile(program_path));
  FL_ASSIGN_OR_RETURN(const planning::EditableProgram program,
                      planning::EditableProgram::Parse(text, dialect, program_path));
  FL_ASSIGN_OR_RETURN(const PointSet table, ReadPoints(inspection_path));
  FL_ASSIGN_OR_RETURN(const std::vector<metrology::Deviation> points,
                      planning::DeviationsFromTable(table, inspection_path));
  std::map<std::string, double> load;
  if (!args.load.empty()) {
    FL_ASSIGN_OR_RETURN(const json l, ReadJsonFile(args.load));
    if (!l.is_object()) return Status::BadInput(Where{.file = args.load}, "needs an object {\"N120\": load, ...}");
    for (const auto& [block, value] : l.items()) {
      if (!value.is_number()) return Status::BadInput(Where{.file = args.load, .field = block}, "not a number");
      load[block] = value.get<double>();
    }
  }
  planning::InspectionOptions options;
  options.tolerance_mm = tolerance;
  options.inspection_id = args.inspection_id.empty() ? "inspection-1" : args.inspection_id;
  options.part_id = args.part_id.empty() ? part_name : args.part_id;
  options.operation_id = args.operation_id.empty() ? fs::path(program_path).filename().string() : args.operation_id;
  options.probe_calibration_id = args.probe_calibration_id;
  FL_RETURN_IF_ERROR(options.Validate());
  FL_ASSIGN_OR_RETURN(const recon::FootPointProjector nominal, recon::FootPointProjector::Build(q));
  FL_ASSIGN_OR_RETURN(const planning::InspectionEvaluation evaluation, planning::EvaluateInspection(points, options));
  FL_ASSIGN_OR_RETURN(const planning::ProgramGeometry geometry,
                      planning::BuildProgramGeometry(program, nominal, radius, std::min(0.5, evaluation.h_mm / 4)));
  FL_ASSIGN_OR_RETURN(
      planning::InspectionAdjustment adjustment,
      planning::AdjustProgramFromInspection(program, geometry, nominal, points, load, options, inspection_path));
  json result = {{"command", "optimise program"}, {"run", args.run},
                 {"surface", args.surface},       {"program", program_path},
                 {"inspection", inspection_path}, {"tolerance_mm", options.tolerance_mm},
                 {"ball_radius_mm", radius},      {"adjustment", adjustment.ToJson()}};
  FL_ASSIGN_OR_RETURN(result["inputs"], InputHashes({program_path, inspection_path, args.load, args.surface}));
  const std::string program_name = "program" + ext;
  if (!adjustment.program.empty()) result["adjustment"]["file"] = program_name;
  log::Info(
      "optimise program: {} points, Moran z {:.2f} ({}), {} region(s), program {}, {} CL points shifted, "
      "{} feeds changed, max shift {:.4f} mm",
      points.size(), adjustment.evaluation.moran_z,
      adjustment.evaluation.systematic ? "systematic" : "not systematic: report only", adjustment.regions.size(),
      adjustment.kind, adjustment.cl_points_shifted, adjustment.feeds_changed, adjustment.max_shift_mm);
  for (const std::string& alarm : adjustment.alarms) log::Warn("{}", alarm);
  FL_ASSIGN_OR_RETURN(const fs::path staging,
                      BeginOutput(args.output, {program_path, inspection_path, args.load, args.log, args.surface}));
  if (!adjustment.program.empty()) FL_RETURN_IF_ERROR(WriteFileAtomic(staging / program_name, adjustment.program));
  FL_RETURN_IF_ERROR(WriteJsonFile(staging / "adjustment.json", result["adjustment"]));
  FL_RETURN_IF_ERROR(WriteJsonFile(staging / kMarker, result));
  FL_RETURN_IF_ERROR(FinishOutput(staging, args.output));
  if (!args.log.empty()) {
    json record = adjustment.log_record;
    if (record["time"].get<std::string>().empty()) {
      const std::time_t now = std::chrono::system_clock::to_time_t(std::chrono::system_clock::now());
      std::tm utc{};
      gmtime_r(&now, &utc);
      char stamp[32];
      std::strftime(stamp, sizeof stamp, "%Y-%m-%dT%H:%M:%SZ", &utc);
      record["time"] = stamp;
    }
    FL_RETURN_IF_ERROR(planning::AppendInspectionLog(args.log, record));
    result["inspection_log"] = args.log;
  }
  return result;
}

}  // namespace formloop::app
