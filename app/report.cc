#include "app/report.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <memory>
#include <optional>
#include <string_view>
#include <unordered_map>
#include <utility>
#include <vector>

#include <fmt/format.h>

#include "app/report_charts.h"
#include "app/report_image.h"
#include "core/atomic_file.h"
#include "core/json_io.h"
#include "core/number_text.h"
#include "core/point_io.h"
#include "core/point_set.h"
#include "reconstruction/cad_io.h"
#include "reconstruction/trim.h"

namespace formloop::app {
namespace {

namespace fs = std::filesystem;

constexpr const char* kNotAvailable = "not available";

// An optional input: the parsed JSON, or why it is absent (empty: the file does not exist).
struct OptionalJson {
  std::optional<Json> value;
  std::string note;
};

struct LoopData {
  int loop = 0;
  std::optional<PointSet> points;  // loop-K/deviations.csv
  std::string points_note;
  OptionalJson analysis;  // loop-K/analysis.json
};

struct RunData {
  bool analysis_folder = false;  // a `formloop analyse` folder: one cycle, no run-only sections
  Json summary;
  OptionalJson retrieval, plan, sim_correction, diagnosis, retain;
  std::vector<LoopData> loops;  // loop-0, loop-1, ... as long as the folders exist
  MapMask part_mask;            // a run on a trimmed Q: (x, y) over the part (TrimMask); empty otherwise
};

// For a trimmed Q (surface/Q.step holds the trimmed face): whether the point of Q above (x, y) lies inside
// the trim, so the deviation maps stay blank outside the face and over its holes. Results are kept per
// 0.05 mm cell (every map of the report asks for the same pixels); Newton starts from the previous answer
// or else the nearest of 33 × 33 samples of Q.
MapMask TrimMask(const fs::path& run_dir) {
  std::error_code ec;
  if (!fs::exists(run_dir / "surface" / "Q.step", ec)) return {};
  auto face = recon::ReadCadFace(run_dir / "surface" / "Q.step", {});
  if (!face.ok() || face->surface.trim() == nullptr || face->surface.trim()->natural()) return {};
  struct State {
    recon::BSplineSurface q;
    std::vector<std::pair<Eigen::Vector2d, Eigen::Vector2d>> starts;  // (x, y) -> (u, v)
    std::optional<Eigen::Vector2d> last;
    std::unordered_map<long long, bool> cache;
  };
  auto state = std::make_shared<State>();
  state->q = face->surface;
  const recon::ParamDomain d = state->q.domain();
  for (int j = 0; j <= 32; ++j) {
    for (int i = 0; i <= 32; ++i) {
      const Eigen::Vector2d uv(d.u_min + d.u_span() * i / 32, d.v_min + d.v_span() * j / 32);
      state->starts.emplace_back(state->q.Point(uv.x(), uv.y()).head<2>(), uv);
    }
  }
  return [state](double x, double y) {
    const long long key = std::llround(x / 0.05) * 1000003LL + std::llround(y / 0.05);
    if (const auto it = state->cache.find(key); it != state->cache.end()) return it->second;
    std::optional<Eigen::Vector2d> uv;
    if (state->last) uv = recon::ParametersAboveXY(state->q, x, y, *state->last);
    if (!uv) {
      const Eigen::Vector2d xy(x, y);
      const auto nearest = std::min_element(
          state->starts.begin(), state->starts.end(),
          [&](const auto& a, const auto& b) { return (a.first - xy).squaredNorm() < (b.first - xy).squaredNorm(); });
      uv = recon::ParametersAboveXY(state->q, x, y, nearest->second);
    }
    if (uv) state->last = uv;
    const bool inside = uv && state->q.trim()->Inside(uv->x(), uv->y());
    state->cache.emplace(key, inside);
    return inside;
  };
}

OptionalJson ReadOptionalJson(const fs::path& path) {
  std::error_code ec;
  if (!fs::exists(path, ec)) return {std::nullopt, ""};
  Result<Json> json = ReadJsonFile(path);
  if (!json.ok()) return {std::nullopt, json.status().message()};
  return {std::move(json).value(), ""};
}

Status CheckSummary(const Json& summary, const std::string& source) {
  if (!summary.is_object()) {
    return Status::BadInput(Where{.file = source}, "summary.json must be a JSON object",
                            "point `formloop report` at a run folder written by `formloop run`");
  }
  JsonFields fields(summary, source);
  std::string text;
  double number = 0;
  FL_RETURN_IF_ERROR(fields.String("part", &text));
  FL_RETURN_IF_ERROR(fields.Number("tolerance_um", &number));
  if (!summary.contains("loops") || !summary["loops"].is_array()) {
    return Status::BadInput(Where{.file = source, .field = "loops"}, "missing or not an array",
                            "write the per-loop records as an array \"loops\": [...]");
  }
  return Status::Ok();
}

// ---- Text and number formatting (locale-free) ----

std::string Esc(std::string_view text) {
  std::string out;
  out.reserve(text.size());
  for (char c : text) {
    switch (c) {
      case '&':
        out += "&amp;";
        break;
      case '<':
        out += "&lt;";
        break;
      case '>':
        out += "&gt;";
        break;
      case '"':
        out += "&quot;";
        break;
      default:
        out += c;
    }
  }
  return out;
}

const Json& Member(const Json& object, const char* key) {
  static const Json kNull;
  if (!object.is_object()) return kNull;
  const auto it = object.find(key);
  return it == object.end() ? kNull : *it;
}

// A number with fixed decimals, "—" when absent or not a number.
std::string Num(const Json& value, int decimals) {
  return value.is_number() ? FormatFixed(value.get<double>(), decimals) : "—";
}

// Any JSON value as table-cell text: 4 significant digits for floats, yes/no, compact JSON otherwise.
std::string Scalar(const Json& value) {
  if (value.is_null()) return "—";
  if (value.is_string()) return value.get<std::string>();
  if (value.is_boolean()) return value.get<bool>() ? "yes" : "no";
  if (value.is_number_integer() || value.is_number_unsigned()) return value.dump();
  if (value.is_number_float()) return fmt::format("{:.4g}", value.get<double>());
  if (value.is_array() && std::all_of(value.begin(), value.end(), [](const Json& v) { return v.is_primitive(); })) {
    std::string out;
    for (const Json& v : value) out += (out.empty() ? "" : ", ") + Scalar(v);
    return out;
  }
  return value.dump();
}

std::string StringOr(const Json& value, const std::string& fallback) {
  return value.is_string() ? value.get<std::string>() : fallback;
}

// ---- Reading the folder ----

LoopData ReadLoop(const fs::path& dir, int k) {
  std::error_code ec;
  LoopData loop{.loop = k};
  if (fs::exists(dir / "deviations.csv", ec)) {
    Result<PointSet> points = ReadCsv(dir / "deviations.csv");
    if (points.ok() && points->FindScalar("deviation_um") != nullptr) {
      loop.points = std::move(points).value();
    } else {
      loop.points_note = points.ok() ? "deviations.csv has no deviation_um column" : points.status().message();
    }
  }
  loop.analysis = ReadOptionalJson(dir / "analysis.json");
  return loop;
}

// A `formloop analyse` folder read as a run of one cycle: the summary from its analysis.json.
Result<RunData> LoadAnalysis(const fs::path& dir, const Json& analysis, const std::string& source) {
  if (!analysis.is_object() || !analysis.contains("decomposition") || !analysis["decomposition"].is_object()) {
    return Status::BadInput(Where{.file = source, .field = "decomposition"}, "missing or not an object",
                            "point `formloop report` at a folder written by `formloop analyse`");
  }
  const Json& evaluation = Member(analysis, "evaluation");
  const Json& dec = analysis["decomposition"];
  Json loop = {{"loop", 0},
               {"form_error_um", Member(analysis, "form_error_um")},
               {"systematic_peak_um", Member(analysis, "systematic_peak_um")},
               {"random_sigma_um", Member(analysis, "random_sigma_um")},
               {"raw_moran_z", Member(Member(analysis, "raw_moran"), "z_normality")},
               {"chosen_model", Member(analysis, "chosen_model")},
               {"residual_moran_z", Member(dec, "residual_moran_z")},
               {"within_tolerance", Member(evaluation, "within_tolerance")},
               {"decision", evaluation.is_object() ? Member(evaluation, "decision") : Json("no tolerance given")}};
  const Json& inputs = Member(analysis, "inputs");
  RunData run{.analysis_folder = true};
  run.summary = {{"part", "analysis of " + StringOr(Member(Member(inputs, "probe_log"), "file"), "a probe log")},
                 {"surface", Member(Member(inputs, "surface"), "file")},
                 {"tolerance_um", Member(evaluation, "tolerance_um")},
                 {"loops", Json::array({loop})},
                 {"within_tolerance", Member(evaluation, "within_tolerance")}};
  LoopData only = ReadLoop(dir, 0);
  only.analysis = {analysis, ""};
  run.loops.push_back(std::move(only));
  return run;
}

Result<RunData> LoadRun(const fs::path& run_dir) {
  const fs::path summary_path = run_dir / "summary.json";
  const fs::path analysis_path = run_dir / "analysis.json";
  std::error_code ec;
  if (!fs::exists(summary_path, ec) && fs::exists(analysis_path, ec)) {
    Result<Json> analysis = ReadJsonFile(analysis_path);
    if (!analysis.ok()) return Status::BadInput(analysis.status().message());
    if (Member(*analysis, "format") == Json("formloop part analysis")) {
      return LoadAnalysis(run_dir, *analysis, analysis_path.string());
    }
  }
  if (!fs::exists(summary_path, ec)) {
    return Status::BadInput(Where{.file = summary_path.string()}, "the run folder has no summary.json",
                            "give the folder written by `formloop run` (it holds summary.json) or by `formloop "
                            "analyse` (it holds analysis.json)");
  }
  Result<Json> summary = ReadJsonFile(summary_path);
  if (!summary.ok()) return Status::BadInput(summary.status().message());
  FL_RETURN_IF_ERROR(CheckSummary(*summary, summary_path.string()));
  RunData run{.summary = std::move(summary).value()};
  run.retrieval = ReadOptionalJson(run_dir / "retrieval.json");
  run.plan = ReadOptionalJson(run_dir / "plan.json");
  run.sim_correction = ReadOptionalJson(run_dir / "sim_correction.json");
  run.diagnosis = ReadOptionalJson(run_dir / "loop-0" / "diagnosis" / "diagnosis.json");
  run.retain = ReadOptionalJson(run_dir / "retain.json");
  run.part_mask = TrimMask(run_dir);
  for (int k = 0; fs::is_directory(run_dir / ("loop-" + std::to_string(k)), ec); ++k) {
    run.loops.push_back(ReadLoop(run_dir / ("loop-" + std::to_string(k)), k));
  }
  return run;
}

// ---- HTML building blocks ----

void OpenSection(std::string& html, const std::string& id, const std::string& title, const std::string& intro) {
  html += fmt::format("<section id=\"{}\">\n<h2>{}</h2>\n<p class=\"intro\">{}</p>\n", id, Esc(title), Esc(intro));
}

void CloseSection(std::string& html) { html += "</section>\n"; }

// "<what>: not available (<why>)." — why may be empty (the file simply does not exist).
void NotAvailable(std::string& html, const std::string& what, const std::string& why) {
  html += fmt::format("<p class=\"na\">{}: {}{}.</p>\n", Esc(what), kNotAvailable,
                      why.empty() ? "" : " (" + Esc(why) + ")");
}

// Table with a header row; cells are already HTML.
std::string Table(const std::vector<std::string>& header, const std::vector<std::vector<std::string>>& rows) {
  std::string out = "<table>\n<tr>";
  for (const std::string& h : header) out += "<th>" + h + "</th>";
  out += "</tr>\n";
  for (const auto& row : rows) {
    out += "<tr>";
    for (const std::string& cell : row) out += "<td>" + cell + "</td>";
    out += "</tr>\n";
  }
  return out + "</table>\n";
}

bool IsTableOfObjects(const Json& value) {
  return value.is_array() && !value.empty() &&
         std::all_of(value.begin(), value.end(), [](const Json& v) { return v.is_object(); });
}

// Scalars (and nested objects' scalars, with dotted keys) into key/value rows; arrays of objects
// are collected for their own tables.
void Flatten(const Json& object, const std::string& prefix, std::vector<std::vector<std::string>>* rows,
             std::vector<std::pair<std::string, const Json*>>* tables) {
  for (const auto& [key, value] : object.items()) {
    const std::string path = prefix.empty() ? key : prefix + "." + key;
    if (value.is_object() && !value.empty()) {
      Flatten(value, path, rows, tables);
    } else if (IsTableOfObjects(value)) {
      tables->emplace_back(path, &value);
    } else {
      rows->push_back({"<code>" + Esc(path) + "</code>", Esc(Scalar(value))});
    }
  }
}

// An array of objects as one table, columns in order of first appearance.
std::string ObjectsTable(const Json& array) {
  std::vector<std::string> columns;
  for (const Json& row : array) {
    for (const auto& [key, value] : row.items()) {
      if (std::find(columns.begin(), columns.end(), key) == columns.end()) columns.push_back(key);
    }
  }
  std::vector<std::vector<std::string>> rows;
  for (const Json& row : array) {
    std::vector<std::string> cells;
    for (const std::string& c : columns) cells.push_back(Esc(Scalar(Member(row, c.c_str()))));
    rows.push_back(std::move(cells));
  }
  std::vector<std::string> header;
  for (const std::string& c : columns) header.push_back(Esc(c));
  return Table(header, rows);
}

// Any JSON object: a key/value table of its scalars, then one table per array of objects.
std::string GenericJson(const Json& object) {
  std::vector<std::vector<std::string>> rows;
  std::vector<std::pair<std::string, const Json*>> tables;
  if (object.is_object()) {
    Flatten(object, "", &rows, &tables);
  } else {
    rows.push_back({"value", Esc(Scalar(object))});
  }
  std::string out = rows.empty() ? "" : Table({"key", "value"}, rows);
  for (const auto& [path, array] : tables) out += "<h3>" + Esc(path) + "</h3>\n" + ObjectsTable(*array);
  return out;
}

Result<std::string> Figure(const Canvas& canvas, const std::string& alt, const std::string& caption) {
  FL_ASSIGN_OR_RETURN(std::string png, EncodePng(canvas));
  return fmt::format(
      "<figure><img src=\"data:image/png;base64,{}\" width=\"{}\" height=\"{}\" alt=\"{}\">"
      "<figcaption>{}</figcaption></figure>\n",
      Base64(png), canvas.width(), canvas.height(), Esc(alt), Esc(caption));
}

// ---- Point columns ----

std::vector<double> Column(const PointSet& points, const std::string& name) {
  if (name == "x" || name == "y") {
    std::vector<double> out;
    for (const auto& p : points.points) out.push_back(name == "x" ? p.x() : p.y());
    return out;
  }
  const std::vector<double>* column = points.FindScalar(name);
  return column != nullptr ? *column : std::vector<double>{};
}

std::vector<int> Clusters(const PointSet& points) {
  std::vector<int> out;
  const std::vector<double>* lisa = points.FindScalar("lisa_cluster");
  if (lisa == nullptr) lisa = points.FindScalar("lisa");  // run folders written before the one analysis
  if (lisa != nullptr) {
    for (double v : *lisa) out.push_back(static_cast<int>(std::lround(v)));
  }
  return out;
}

double MaxAbs(const std::vector<double>& values) {
  double m = 0;
  for (double v : values) m = std::max(m, std::abs(v));
  return m;
}

// ---- Sections ----

// The tolerance α in µm; NaN when none was given (an `analyse` folder without --tolerance-um).
double ToleranceUm(const Json& summary) {
  const Json& t = Member(summary, "tolerance_um");
  return t.is_number() ? t.get<double>() : std::numeric_limits<double>::quiet_NaN();
}

std::string VerdictText(const Json& summary) {
  if (!Member(summary, "tolerance_um").is_number()) {
    return "No tolerance given: form error " + Num(Member(Member(summary, "loops").back(), "form_error_um"), 2) + " µm";
  }
  if (Member(summary, "within_tolerance") != Json(true)) return "NOT within tolerance";
  const Json& n = Member(summary, "loops_to_tolerance");
  const long loops = n.is_number() ? n.get<long>() : static_cast<long>(Member(summary, "loops").size());
  return fmt::format("Within tolerance after {} loop{}", loops, loops == 1 ? "" : "s");
}

// The route as written by the run (summary.json) or by retrieval (retrieval.json); the latter adds the rule.
Json RouteOf(const RunData& run) {
  Json route = Member(run.summary, "route");
  if (run.retrieval.value) {
    const Json& r = Member(*run.retrieval.value, "route");
    if (r.is_object()) {
      if (!route.is_object()) route = Json::object();
      for (const auto& [key, value] : r.items()) route[key] = value;
    }
  }
  return route;
}

void HeaderSection(std::string& html, const RunData& run) {
  const Json& s = run.summary;
  const bool ok = Member(s, "within_tolerance") == Json(true);
  const Json route = RouteOf(run);
  const std::string route_name = StringOr(Member(route, "name"), "not recorded");
  const Json& loops = Member(s, "loops");
  html += fmt::format("<header>\n<h1>{} report: {}</h1>\n", run.analysis_folder ? "Analysis" : "Run",
                      Esc(StringOr(Member(s, "part"), "")));
  const bool has_tolerance = Member(s, "tolerance_um").is_number();
  html += fmt::format("<p class=\"verdict {}\">{}</p>\n",
                      !has_tolerance ? "na"
                      : ok           ? "ok"
                                     : "bad",
                      Esc(VerdictText(s)));
  if (!run.analysis_folder) {
    html += fmt::format(
        "<p><span class=\"badge route-{0}\">route: {0}</span>{1}</p>\n", Esc(route_name),
        Member(route, "flag_engineer") == Json(true) ? " <span class=\"badge flag\">engineer review</span>" : "");
  }
  const Json last = loops.empty() ? Json() : loops.back();
  html += Table({"surface", "form tolerance α", "loops run", "final form error", "fit check max"},
                {{Esc(StringOr(Member(s, "surface"), "—")), Num(Member(s, "tolerance_um"), 2) + " µm",
                  std::to_string(loops.size()), Num(Member(last, "form_error_um"), 2) + " µm",
                  Num(Member(s, "fit_check_max_um"), 3) + " µm"}});
  html += "</header>\n";
}

void RetrievalSection(std::string& html, const RunData& run) {
  OpenSection(html, "retrieval", "Retrieval",
              "Which past cases of the library resemble this part, how similar they are facet by facet, and the "
              "route that similarity chose (direct reuse, simulation, or the default plan).");
  const Json route = RouteOf(run);
  html += Table({"route", "similarity A", "closest case", "rule", "engineer review"},
                {{Esc(StringOr(Member(route, "name"), "—")), Num(Member(route, "similarity"), 3),
                  Esc(Scalar(Member(route, "case_uid"))), Esc(Scalar(Member(route, "rule"))),
                  Esc(Scalar(Member(route, "flag_engineer")))}});
  if (!run.retrieval.value) {
    NotAvailable(html, "Ranked candidates (retrieval.json)", run.retrieval.note);
    CloseSection(html);
    return;
  }
  std::vector<std::vector<std::string>> rows;
  const Json& ranked = Member(*run.retrieval.value, "ranked");
  for (const Json& c : ranked.is_array() ? ranked : Json::array()) {
    const Json& facets = Member(c, "facets");
    const std::size_t span = std::max<std::size_t>(facets.is_array() ? facets.size() : 0, 1);
    const std::string lead = fmt::format(
        "<td rowspan=\"{0}\">{1}</td><td rowspan=\"{0}\"><code>{2}</code></td><td rowspan=\"{0}\">{3}</td>"
        "<td rowspan=\"{0}\">{4}</td>",
        span, Esc(Scalar(Member(c, "rank"))), Esc(Scalar(Member(c, "uid"))), Esc(Scalar(Member(c, "family"))),
        Num(Member(c, "similarity"), 3));
    if (!facets.is_array() || facets.empty()) rows.push_back({lead + "<td colspan=\"5\">no facets</td>"});
    for (std::size_t k = 0; facets.is_array() && k < facets.size(); ++k) {
      const Json& f = facets[k];
      rows.push_back(
          {(k == 0 ? lead : "") + fmt::format("<td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td>",
                                              Esc(Scalar(Member(f, "facet"))), Esc(Scalar(Member(f, "query_concept"))),
                                              Esc(Scalar(Member(f, "case_concept"))),
                                              Esc(Scalar(Member(f, "common_node"))), Num(Member(f, "lin"), 3))});
    }
  }
  // Rows carry their own <td>s (rowspan), so the table is assembled here rather than by Table().
  html +=
      "<table>\n<tr><th>rank</th><th>case uid</th><th>family</th><th>similarity A</th><th>facet</th>"
      "<th>query concept</th><th>case concept</th><th>common node</th><th>Lin similarity</th></tr>\n";
  for (const auto& row : rows) html += "<tr>" + row[0] + "</tr>\n";
  html += "</table>\n";
  CloseSection(html);
}

void GenericSection(std::string& html, const std::string& id, const std::string& title, const std::string& intro,
                    const OptionalJson& input, const std::string& file) {
  OpenSection(html, id, title, intro);
  if (input.value) {
    html += GenericJson(*input.value);
  } else {
    NotAvailable(html, file, input.note);
  }
  CloseSection(html);
}

Status LoopHistorySection(std::string& html, const RunData& run) {
  OpenSection(html, "loops", "Loop history",
              "Each machining–probing loop: the form error (max |systematic| + 2σ of the random part) against the "
              "tolerance, how strongly the deviations cluster (Moran z), the model chosen for the systematic part "
              "and what the loop decided.");
  const Json& loops = Member(run.summary, "loops");
  std::vector<std::vector<std::string>> rows;
  std::vector<std::string> labels;
  std::vector<double> errors;
  for (const Json& l : loops) {  // an array: CheckSummary
    rows.push_back({Esc(Scalar(Member(l, "loop"))), Num(Member(l, "form_error_um"), 2),
                    Num(Member(l, "systematic_peak_um"), 2), Num(Member(l, "random_sigma_um"), 2),
                    Num(Member(l, "raw_moran_z"), 2), Esc(Scalar(Member(l, "chosen_model"))),
                    Num(Member(l, "residual_moran_z"), 2), Esc(Scalar(Member(l, "within_tolerance"))),
                    Esc(Scalar(Member(l, "decision")))});
    labels.push_back("LOOP " + Scalar(Member(l, "loop")));
    errors.push_back(Member(l, "form_error_um").is_number() ? Member(l, "form_error_um").get<double>() : 0.0);
  }
  html += Table({"loop", "form error (µm)", "d<sub>s</sub> peak (µm)", "σ(d<sub>u</sub>) (µm)", "raw Moran z",
                 "chosen model", "residual Moran z", "within tolerance", "decision"},
                rows);
  const double tol = ToleranceUm(run.summary);
  FL_ASSIGN_OR_RETURN(
      std::string figure,
      Figure(DrawBars(labels, errors, tol, "TOLERANCE " + FormatFixed(tol, 1) + " µm", "FORM ERROR (µm)",
                      "FORM ERROR PER LOOP"),
             "Bar chart of the form error of each loop with the tolerance as a dashed line",
             std::isfinite(tol) ? "Form error per loop (µm). Green bars are within the tolerance α = " +
                                      FormatFixed(tol, 2) + " µm (dashed red line), orange bars are not."
                                : std::string("Form error per loop (µm); no tolerance was given.")));
  html += figure;
  CloseSection(html);
  return Status::Ok();
}

// Mean, rms, min, max of the deviations of one loop, one table row.
std::vector<std::string> DeviationStats(const LoopData& loop) {
  const std::vector<double>& d = *loop.points->FindScalar("deviation_um");
  double sum = 0, sum_sq = 0;
  for (double v : d) sum += v, sum_sq += v * v;
  const double n = std::max<double>(static_cast<double>(d.size()), 1);
  const auto [lo, hi] = std::minmax_element(d.begin(), d.end());
  return {std::to_string(loop.loop),
          std::to_string(d.size()),
          FormatFixed(sum / n, 2),
          FormatFixed(std::sqrt(sum_sq / n), 2),
          d.empty() ? "—" : FormatFixed(*lo, 2),
          d.empty() ? "—" : FormatFixed(*hi, 2)};
}

Status DeviationFigures(std::string& html, const LoopData& first, const LoopData& last, double tol,
                        const MapMask& part_mask) {
  const PointSet& p0 = *first.points;
  const PointSet& p1 = *last.points;
  const std::vector<double> d0 = Column(p0, "deviation_um"), d1 = Column(p1, "deviation_um");
  const double scale = std::max({MaxAbs(d0), MaxAbs(d1), 1e-3});
  const std::string common =
      "Both maps share one symmetric colour scale (±" + FormatFixed(scale, 2) +
      " µm): red = material left, blue = material removed beyond nominal; dots are probe points.";
  std::vector<const LoopData*> shown{&first};
  if (last.loop != first.loop) shown.push_back(&last);
  for (const LoopData* loop : shown) {
    const std::string when = loop == &first ? "before compensation" : "after compensation";
    FL_ASSIGN_OR_RETURN(
        std::string fig,
        Figure(
            DrawFieldMap(Column(*loop->points, "x"), Column(*loop->points, "y"), Column(*loop->points, "deviation_um"),
                         scale, "DEVIATION LOOP " + std::to_string(loop->loop), "DEVIATION (µm)", part_mask),
            "Colour map of the deviations of loop " + std::to_string(loop->loop) + " " + when,
            "Deviation of loop " + std::to_string(loop->loop) + " (" + when + "). " + common));
    html += fig;
  }
  const std::vector<double> ds = Column(p0, "systematic_um");
  if (ds.empty()) {
    NotAvailable(html, "Systematic field map", "deviations.csv of loop 0 has no systematic_um column");
  } else {
    FL_ASSIGN_OR_RETURN(std::string fig,
                        Figure(DrawFieldMap(Column(p0, "x"), Column(p0, "y"), ds, std::max(MaxAbs(ds), 1e-3),
                                            "SYSTEMATIC FIELD LOOP 0", "d_s (µm)", part_mask),
                               "Colour map of the systematic deviation field of loop 0",
                               "Systematic field d_s of loop 0 (the part compensation acts on), on its own symmetric "
                               "scale ±" +
                                   FormatFixed(MaxAbs(ds), 2) + " µm."));
    html += fig;
  }
  std::vector<HistogramSeries> series{{d0, "LOOP " + std::to_string(first.loop), HexColour(0xe66101)}};
  if (last.loop != first.loop) series.push_back({d1, "LOOP " + std::to_string(last.loop), HexColour(0x5e3c99)});
  FL_ASSIGN_OR_RETURN(
      std::string hist,
      Figure(DrawHistogram(series, tol, "DEVIATION HISTOGRAM"),
             "Histogram of the deviations before and after compensation with the tolerance limits",
             "Distribution of the deviations (µm), loop " + std::to_string(first.loop) + " (orange)" +
                 (last.loop != first.loop ? " and loop " + std::to_string(last.loop) + " (purple)" : "") +
                 (std::isfinite(tol) ? "; dashed lines at ±α = ±" + FormatFixed(tol, 2) + " µm."
                                     : std::string("; no tolerance was given."))));
  html += hist;
  return Status::Ok();
}

Status DeviationsSection(std::string& html, const RunData& run) {
  OpenSection(html, "deviations", "Deviations before and after",
              "Where the surface deviates from the ideal shape before compensation (loop 0) and after the last loop, "
              "the systematic part of loop 0 and the distribution of the deviations against the tolerance.");
  if (run.loops.empty() || !run.loops.front().points) {
    NotAvailable(html, "Deviations of loop 0 (loop-0/deviations.csv)",
                 run.loops.empty() ? std::string("no loop-0 folder") : run.loops.front().points_note);
    CloseSection(html);
    return Status::Ok();
  }
  const LoopData* last = &run.loops.front();
  for (const LoopData& l : run.loops) {
    if (l.points) last = &l;
  }
  std::vector<std::vector<std::string>> rows{DeviationStats(run.loops.front())};
  if (last->loop != 0) rows.push_back(DeviationStats(*last));
  html += Table({"loop", "points", "mean (µm)", "rms (µm)", "min (µm)", "max (µm)"}, rows);
  if (last->loop == 0) html += "<p>Only loop 0 has deviations, so there is no after-compensation map.</p>\n";
  FL_RETURN_IF_ERROR(DeviationFigures(html, run.loops.front(), *last, ToleranceUm(run.summary), run.part_mask));
  CloseSection(html);
  return Status::Ok();
}

// Moran scatter of loop 0; "not available" without lag_um.
Status MoranScatter(std::string& html, const LoopData& loop, double moran_i) {
  const std::vector<double> d = Column(*loop.points, "deviation_um");
  const std::vector<double> lag = Column(*loop.points, "lag_um");
  if (lag.empty() || d.empty()) {
    NotAvailable(html, "Moran scatter plot", "deviations.csv of loop 0 has no lag_um column");
    return Status::Ok();
  }
  double mean = 0, var = 0;
  for (double v : d) mean += v;
  mean /= static_cast<double>(d.size());
  for (double v : d) var += (v - mean) * (v - mean);
  // Population standard deviation, as in Moran's I; lag_um is already centred (Σ w_ij (d_j − mean)).
  const double sd = std::sqrt(var / static_cast<double>(d.size()));
  std::vector<double> z, lag_z;
  for (std::size_t i = 0; i < d.size(); ++i) {
    z.push_back(sd > 0 ? (d[i] - mean) / sd : 0);
    lag_z.push_back(sd > 0 ? lag[i] / sd : 0);
  }
  FL_ASSIGN_OR_RETURN(std::string fig,
                      Figure(DrawMoranScatter(z, lag_z, Clusters(*loop.points), moran_i,
                                              "MORAN SCATTER LOOP 0  I = " + FormatFixed(moran_i, 3)),
                             "Moran scatter plot of loop 0: standardised deviation against its spatial lag",
                             "Moran scatter of loop 0: each point's standardised deviation z against the average z of "
                             "its neighbours; the red line has slope I = " +
                                 FormatFixed(moran_i, 3) + ". Points in HH/LL quadrants sit in like neighbourhoods."));
  html += fig;
  return Status::Ok();
}

Status LisaMap(std::string& html, const LoopData& loop) {
  const std::vector<int> clusters = Clusters(*loop.points);
  if (clusters.empty()) {
    NotAvailable(html, "LISA cluster map", "deviations.csv of loop 0 has no lisa column");
    return Status::Ok();
  }
  FL_ASSIGN_OR_RETURN(
      std::string fig,
      Figure(DrawClusterMap(Column(*loop.points, "x"), Column(*loop.points, "y"), clusters, "LISA CLUSTERS LOOP 0"),
             "Map of the local Moran (LISA) clusters of loop 0",
             "LISA clusters of loop 0: HH = high deviation among high neighbours (red), LL = low among "
             "low (blue), LH/HL = outliers, grey = not significant or island."));
  html += fig;
  std::vector<int> counts(kLisaClusterCount, 0);
  for (int k : clusters) {
    if (k >= 0 && k < kLisaClusterCount) ++counts[static_cast<std::size_t>(k)];
  }
  std::vector<std::vector<std::string>> rows;
  for (int k = 0; k < kLisaClusterCount; ++k) {
    rows.push_back({LisaName(k), std::to_string(counts[static_cast<std::size_t>(k)])});
  }
  html += Table({"LISA cluster", "points"}, rows);
  return Status::Ok();
}

Status SpatialSection(std::string& html, const RunData& run) {
  OpenSection(html, "spatial", "Spatial analysis",
              "Whether the deviations of loop 0 cluster in space (global Moran's I) and where (local Moran, LISA): "
              "clustered deviations are systematic and can be compensated; scattered ones are random.");
  if (run.loops.empty() || !run.loops.front().points) {
    NotAvailable(html, "Spatial analysis of loop 0", "no deviations for loop 0");
    CloseSection(html);
    return Status::Ok();
  }
  const LoopData& loop = run.loops.front();
  const Json moran = loop.analysis.value ? Member(*loop.analysis.value, "raw_moran") : Json();
  html += Table({"Moran's I", "expected E[I]", "z (normality)", "chosen model"},
                {{Num(Member(moran, "I"), 4), Num(Member(moran, "expected"), 4), Num(Member(moran, "z_normality"), 2),
                  loop.analysis.value ? Esc(Scalar(Member(*loop.analysis.value, "chosen_model"))) : "—"}});
  if (!Member(moran, "I").is_number()) {
    NotAvailable(html, "Moran scatter plot", "loop-0/analysis.json has no raw_moran.I");
  } else {
    FL_RETURN_IF_ERROR(MoranScatter(html, loop, Member(moran, "I").get<double>()));
  }
  FL_RETURN_IF_ERROR(LisaMap(html, loop));
  CloseSection(html);
  return Status::Ok();
}

// "name = value ± se" per parameter; parameters and std_errors may be objects or arrays.
std::string Parameters(const Json& cause) {
  const Json& params = Member(cause, "parameters");
  const Json& errors = Member(cause, "std_errors");
  std::string out;
  std::size_t index = 0;
  for (auto it = params.begin(); (params.is_object() || params.is_array()) && it != params.end(); ++it, ++index) {
    const std::string name = params.is_object() ? it.key() : "p" + std::to_string(index);
    Json se;
    if (errors.is_object() && params.is_object()) se = Member(errors, it.key().c_str());
    if (errors.is_array() && index < errors.size()) se = errors[index];
    out += (out.empty() ? "" : "<br>") + Esc(name) + " = " + Esc(Scalar(*it)) +
           (se.is_number() ? " ± " + Esc(Scalar(se)) : "");
  }
  return out.empty() ? Esc(Scalar(params)) : out;
}

void DiagnosisSection(std::string& html, const RunData& run) {
  OpenSection(
      html, "diagnosis", "Diagnosis",
      "Which physical effects of the machine, tool, set-up or probe explain the systematic deviation of loop 0, "
      "with their fitted parameters, and how much a model of them reduces the error.");
  if (!run.diagnosis.value) {
    NotAvailable(html, "Diagnosis (loop-0/diagnosis/diagnosis.json)", run.diagnosis.note);
    CloseSection(html);
    return;
  }
  const Json& d = *run.diagnosis.value;
  std::vector<std::vector<std::string>> rows;
  const Json& causes = Member(d, "causes");
  for (const Json& c : causes.is_array() ? causes : Json::array()) {
    rows.push_back({Esc(Scalar(Member(c, "effect"))), Parameters(c), Num(Member(c, "variance_explained"), 3),
                    Num(Member(c, "z_before"), 2) + " → " + Num(Member(c, "z_after"), 2)});
  }
  if (rows.empty()) {
    html += "<p>No effect of the catalogue explains the systematic deviation.</p>\n";
  } else {
    html += Table({"effect", "parameters ± std. error", "variance explained", "Moran z before → after"}, rows);
  }
  const Json& unexplained = Member(d, "unexplained");
  html += "<h3>Unexplained residual</h3>\n";
  html += unexplained.is_null() ? "<p>None: the causes above account for the systematic deviation.</p>\n"
                                : GenericJson(unexplained);
  const Json& gain = Member(d, "gain");
  html += "<h3>Gain</h3>\n";
  html += Table(
      {"", "before (µm)", "after (µm)"},
      {{"rms", Num(Member(gain, "rms_before_um"), 2), Num(Member(gain, "rms_after_um"), 2)},
       {"held-out rms", Num(Member(gain, "heldout_rms_before_um"), 2), Num(Member(gain, "heldout_rms_after_um"), 2)}});
  CloseSection(html);
}

constexpr const char* kStyle = R"(<style>
body{font-family:"DejaVu Sans",Helvetica,Arial,sans-serif;max-width:1280px;margin:2em auto;padding:0 1em;color:#222;line-height:1.4}
h1{margin-bottom:.2em}h2{border-bottom:2px solid #ddd;padding-bottom:.2em;margin-top:2em}
.intro{color:#555;font-style:italic}
table{border-collapse:collapse;margin:.6em 0;font-size:.92em}
th,td{border:1px solid #ccc;padding:.25em .6em;text-align:left;vertical-align:top}th{background:#f3f3f3}
.verdict{font-size:1.4em;font-weight:bold;padding:.4em .8em;border-radius:6px;display:inline-block}
.verdict.ok{background:#e3f4e1;color:#1b5e20}.verdict.bad{background:#fde2e1;color:#b71c1c}
.badge{display:inline-block;padding:.15em .6em;border-radius:1em;background:#e0e7f1;color:#1f3b63;font-size:.9em;margin-right:.4em}
.badge.flag{background:#fff1cc;color:#7a5200}
.na{color:#8a6d3b;background:#fcf8e3;padding:.3em .6em;display:inline-block}
figure{display:inline-block;margin:.6em 1em .6em 0;vertical-align:top;max-width:calc(50% - 1.5em)}
figcaption{font-size:.88em;color:#444}
img{border:1px solid #ddd;max-width:100%;height:auto}footer{margin-top:3em;color:#777;font-size:.85em;border-top:1px solid #ddd;padding-top:.5em}
code{font-size:.92em}
</style>
)";

// Records how many pictures decoded, for headless checks (tests/app/report_test.cc).
constexpr const char* kScript = R"(<script>
window.addEventListener("load", function () {
  var images = document.images, loaded = 0;
  for (var i = 0; i < images.length; ++i) if (images[i].complete && images[i].naturalWidth > 0) ++loaded;
  document.body.dataset.imagesLoaded = loaded + "/" + images.length;
});
</script>
)";

// The run folder's own name ("runs/demo/" -> "demo"), not its absolute path, so a report does not
// change when the folder moves.

}  // namespace

Result<std::string> RenderRunReport(const fs::path& run_dir) {
  FL_ASSIGN_OR_RETURN(RunData run, LoadRun(run_dir));
  std::string html = "<!DOCTYPE html>\n<html lang=\"en\">\n<head>\n<meta charset=\"utf-8\">\n";
  html += "<title>formloop report: " + Esc(StringOr(Member(run.summary, "part"), "")) + "</title>\n";
  html += kStyle;
  html += kScript;
  html += "</head>\n<body>\n";
  HeaderSection(html, run);
  if (!run.analysis_folder) {
    RetrievalSection(html, run);
    GenericSection(html, "plan", "Plan", "The process plan the run used (tool, feeds, step-over, probing ...).",
                   run.plan, "Plan (plan.json)");
    GenericSection(html, "sim-correction", "Simulation correction",
                   "Defects the virtual machine predicted for the plan before and after correction, the plan chosen "
                   "and why.",
                   run.sim_correction, "Simulation correction (sim_correction.json)");
  }
  FL_RETURN_IF_ERROR(LoopHistorySection(html, run));
  FL_RETURN_IF_ERROR(DeviationsSection(html, run));
  FL_RETURN_IF_ERROR(SpatialSection(html, run));
  if (!run.analysis_folder) {
    DiagnosisSection(html, run);
    GenericSection(html, "retain", "Retain", "What this run stores back into the case library for future parts.",
                   run.retain, "Retain (retain.json)");
  }
  if (run.analysis_folder) {
    html += "<footer>formloop analyse — report of the <code>" + Esc(StringOr(Member(run.summary, "part"), "?")) +
            "</code> (the report names no folder, so the same analysis gives the same bytes wherever it is "
            "written)</footer>\n";
  } else {
    html +=
        "<footer>formloop " + Esc(StringOr(Member(run.summary, "formloop_version"), "unknown version")) +
        " — report of part <code>" + Esc(StringOr(Member(run.summary, "part"), "?")) +
        "</code> (the report names no folder, so the same run gives the same bytes wherever it is written)</footer>\n";
  }
  html += "</body>\n</html>\n";
  return html;
}

Status WriteRunReport(const fs::path& run_dir, const fs::path& html_path) {
  FL_ASSIGN_OR_RETURN(std::string html, RenderRunReport(run_dir));
  return WriteFileAtomic(html_path, html);
}

}  // namespace formloop::app
