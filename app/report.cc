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

#include "app/report_html.h"
#include "app/report_image.h"
#include "app/report_sections.h"
#include "app/report_svg.h"
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
using namespace report;  // NOLINT: the report's own building blocks

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
  loop.machine = ReadOptionalJson(dir / "machine.json");
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
  RunData run{.analysis_folder = true, .dir = dir};
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
  RunData run{.dir = run_dir, .summary = std::move(summary).value()};
  run.retrieval = ReadOptionalJson(run_dir / "retrieval.json");
  run.plan = ReadOptionalJson(run_dir / "plan.json");
  run.sim_correction = ReadOptionalJson(run_dir / "sim_correction.json");
  run.diagnosis = ReadOptionalJson(run_dir / "loop-0" / "diagnosis" / "diagnosis.json");
  run.diagnosis_model = ReadOptionalJson(run_dir / "loop-0" / "diagnosis" / "model.json");
  run.retain = ReadOptionalJson(run_dir / "retain.json");
  run.part_mask = TrimMask(run_dir);
  for (int k = 0; fs::is_directory(run_dir / ("loop-" + std::to_string(k)), ec); ++k) {
    run.loops.push_back(ReadLoop(run_dir / ("loop-" + std::to_string(k)), k));
  }
  return run;
}

// ---- Sections ----

// Compensation loops until within tolerance: the index of the first loop within it (loop 0 is the first
// cut); -1 when none is.
long CompensationLoops(const Json& summary) {
  const Json& loops = Member(summary, "loops");
  for (std::size_t k = 0; loops.is_array() && k < loops.size(); ++k) {
    if (Member(loops[k], "within_tolerance") == Json(true)) return static_cast<long>(k);
  }
  return -1;
}

std::string Plural(long n, const char* word) { return fmt::format("{} {}{}", n, word, n == 1 ? "" : "s"); }

std::string VerdictText(const RunData& run) {
  const Json& summary = run.summary;
  const long cycles = static_cast<long>(Member(summary, "loops").size());
  if (!Member(summary, "tolerance_um").is_number()) {
    return "No tolerance given: form error " + Num(Member(Member(summary, "loops").back(), "form_error_um"), 2) + " µm";
  }
  if (Member(summary, "within_tolerance") != Json(true)) {
    return "NOT within tolerance after " + Plural(cycles, "machined cycle");
  }
  const long loops = CompensationLoops(summary);
  if (loops <= 0) return "Within tolerance at the first cut";
  return fmt::format("Within tolerance after {} ({})", Plural(loops, "compensation loop"),
                     Plural(loops + 1, "machined cycle"));
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
  const Json& loops = Member(s, "loops");
  html += fmt::format("<header>\n<h1>{} report: {}</h1>\n", run.analysis_folder ? "Analysis" : "Run",
                      Esc(StringOr(Member(s, "part"), "")));
  const bool has_tolerance = Member(s, "tolerance_um").is_number();
  html += fmt::format("<p class=\"verdict {}\">{}</p>\n",
                      !has_tolerance ? "na"
                      : ok           ? "ok"
                                     : "bad",
                      Esc(VerdictText(run)));
  if (!run.analysis_folder) {
    const std::string route_name = StringOr(Member(route, "name"), "not recorded");
    html += fmt::format(
        "<p><span class=\"badge route-{0}\">route: {0}</span>{1}</p>\n", Esc(route_name),
        Member(route, "flag_engineer") == Json(true) ? " <span class=\"badge flag\">engineer review</span>" : "");
  }
  const Json last = loops.empty() ? Json() : loops.back();
  const Json first = loops.empty() ? Json() : loops.front();
  html +=
      Table({"Surface", "Form tolerance α", "Machined cycles", "First-cycle form error", "Final form error",
             "Surface fit check (max)"},
            {{Esc(StringOr(Member(s, "surface"), "—")), Num(Member(s, "tolerance_um"), 2) + " µm",
              std::to_string(loops.size()), Num(Member(first, "form_error_um"), 2) + " µm",
              Num(Member(last, "form_error_um"), 2) + " µm",
              Member(s, "fit_check_max_um").is_number() ? Readable(Member(s, "fit_check_max_um").get<double>()) + " µm"
                                                        : "—"}});
  // Probe points the run left out of its plan (the probe cannot reach them clear of the part).
  const Json& left_out = Member(Member(s, "probing"), "left_out");
  if (left_out.is_array() && !left_out.empty()) {
    std::string ids;
    for (const Json& id : left_out) ids += (ids.empty() ? "" : ", ") + (id.is_number() ? id.dump() : std::string("?"));
    html += fmt::format(
        "<p class=\"note\"><strong>Probe points left out:</strong> {} of the {} planned: a 3-axis probe cannot "
        "reach them clear of the part (points {}; toolpath/probing_left_out.json). The deviations and the "
        "diagnosis are of the others.</p>\n",
        left_out.size(), Num(Member(Member(s, "probing"), "planned"), 0), Esc(ids));
  }
  // A region the tool path leaves uncut (Q concave below the ball radius: the ball is lifted out of it).
  const Json& toolpath = Member(s, "toolpath");
  const Json& box = Member(toolpath, "uncut_box_mm");
  if (Member(toolpath, "lifted_points").is_number() && Member(toolpath, "lifted_points").get<double>() > 0 &&
      box.is_array() && box.size() == 2) {
    html += fmt::format(
        "<p class=\"note\"><strong>Region left uncut:</strong> Q is concave below the ball radius there, so {} "
        "cutter locations are lifted out of it (by up to {} mm) and the region they cover (x {} to {} mm, y {} to "
        "{} mm) is not cut to Q; a smaller ball cuts it (toolpath/toolpath.json). Deviations there are of the "
        "lifted cut.</p>\n",
        Num(Member(toolpath, "lifted_points"), 0), Num(Member(toolpath, "max_lift_mm"), 3), Num(box[0][0], 2),
        Num(box[1][0], 2), Num(box[0][1], 2), Num(box[1][1], 2));
  }
  html +=
      "<nav class=\"toc\"><a href=\"#view3d\">3-D view</a> <a href=\"#loops\">Loops</a> <a "
      "href=\"#deviations\">Deviations</a> <a href=\"#spatial\">Spatial analysis</a>" +
      std::string(run.analysis_folder ? ""
                                      : " <a href=\"#diagnosis\">Diagnosis</a> <a href=\"#retrieval\">Retrieval</a> "
                                        "<a href=\"#plan\">Plan</a> <a href=\"#retain\">Retain</a>") +
      "</nav>\n</header>\n";
}

void RetrievalSection(std::string& html, const RunData& run) {
  OpenSection(html, "retrieval", "Retrieval",
              "Which past cases of the library resemble this part, how similar they are facet by facet, and the "
              "route that similarity chose (direct reuse, simulation, or the default plan).");
  const Json route = RouteOf(run);
  html += Table({"Route", "Similarity A", "Closest case", "Rule", "Engineer review"},
                {{Esc(StringOr(Member(route, "name"), "—")), Num(Member(route, "similarity"), 3),
                  Esc(Scalar(Member(route, "case_uid"))), Esc(Scalar(Member(route, "rule"))),
                  Esc(Scalar(Member(route, "flag_engineer")))}});
  if (!run.retrieval.value) {
    NotAvailable(html, "Ranked candidates",
                 run.retrieval.note.empty() ? "this run did not search a case library" : run.retrieval.note);
    CloseSection(html);
    return;
  }
  std::vector<std::string> rows;
  const Json& ranked = Member(*run.retrieval.value, "ranked");
  for (const Json& c : ranked.is_array() ? ranked : Json::array()) {
    const Json& facets = Member(c, "facets");
    const std::size_t span = std::max<std::size_t>(facets.is_array() ? facets.size() : 0, 1);
    const std::string lead = fmt::format(
        "<td rowspan=\"{0}\">{1}</td><td rowspan=\"{0}\"><code>{2}</code></td><td rowspan=\"{0}\">{3}</td>"
        "<td rowspan=\"{0}\">{4}</td>",
        span, Esc(Scalar(Member(c, "rank"))), Esc(Scalar(Member(c, "uid"))), Esc(Scalar(Member(c, "family"))),
        Num(Member(c, "similarity"), 3));
    if (!facets.is_array() || facets.empty()) rows.push_back(lead + "<td colspan=\"5\">no facets</td>");
    for (std::size_t k = 0; facets.is_array() && k < facets.size(); ++k) {
      const Json& f = facets[k];
      rows.push_back((k == 0 ? lead : "") +
                     fmt::format("<td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td>",
                                 Esc(Scalar(Member(f, "facet"))), Esc(Scalar(Member(f, "query_concept"))),
                                 Esc(Scalar(Member(f, "case_concept"))), Esc(Scalar(Member(f, "common_node"))),
                                 Num(Member(f, "lin"), 3)));
    }
  }
  // Rows carry their own <td>s (rowspan), so the table is assembled here rather than by Table().
  html +=
      "<div class=\"tw\"><table>\n<caption>Ranked candidates</caption>\n<tr><th>Rank</th><th>Case</th><th>Family</th>"
      "<th>Similarity A</th><th>Facet</th><th>This part</th><th>The case</th><th>Common concept</th><th>Lin "
      "similarity</th></tr>\n";
  for (const auto& row : rows) html += "<tr>" + row + "</tr>\n";
  html += "</table></div>\n";
  CloseSection(html);
}

// What happens after a first cycle that cut below nominal: material removed cannot be put back, so the
// compensated program either re-cuts this workpiece (only where material was left) or cuts a new blank.
void NextCycleNote(std::string& html, const RunData& run) {
  if (run.loops.empty() || !run.loops.front().points || Member(run.summary, "loops").size() < 2) return;
  const std::vector<double> d = Column(*run.loops.front().points, "deviation_um");
  const double tol = ToleranceUm(run.summary);
  const double limit = std::isfinite(tol) ? -tol / 2 : 0;
  const long overcut = std::count_if(d.begin(), d.end(), [&](double v) { return v < limit; });
  const double deepest = d.empty() ? 0 : *std::min_element(d.begin(), d.end());
  const LoopData& next = run.loops.size() > 1 ? run.loops[1] : run.loops.front();
  const std::string machine = next.machine.value ? StringOr(Member(*next.machine.value, "machine"), "") : "";
  const bool virtual_machine = machine.rfind("virtual", 0) == 0;
  std::string text;
  if (overcut > 0) {
    text = fmt::format(
        "Loop 0 cut below nominal: {} of {} probe points lie more than α/2 = {} µm under the surface (deepest {} "
        "µm). Material removed cannot be put back, so loop 1's compensated program was ",
        overcut, d.size(), Readable(-limit), FormatFixed(deepest, 1));
    text += virtual_machine ? "cut on a new blank (the virtual machine machines every cycle from a new blank)."
                            : "to be cut on a new blank; a re-cut of this workpiece (with the material left as "
                              "allowance) would leave the overcut regions as they are.";
  } else {
    text = fmt::format(
        "Loop 0 left material everywhere within α/2 (deepest point {} µm), so the compensated program of loop 1 "
        "can re-cut this workpiece with the material left as allowance. ",
        FormatFixed(deepest, 1));
    text += virtual_machine ? "In this run the virtual machine cut it on a new blank (every virtual cycle starts "
                              "from a new blank)."
                            : "Whether it re-cut this workpiece or a new blank is not recorded in the run folder.";
  }
  html += "<p class=\"note\"><strong>Next cycle:</strong> " + Esc(text) + "</p>\n";
}

Status LoopHistorySection(std::string& html, const RunData& run) {
  OpenSection(html, "loops", "Loop history",
              "Each machining–probing cycle (loop 0 is the first cut, each later loop a compensation loop): the form "
              "error (max |systematic| + 2σ of the random part) against the tolerance, how strongly the deviations "
              "cluster (Moran z), the model chosen for the systematic part and what the loop decided.");
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
    labels.push_back("loop " + Scalar(Member(l, "loop")));
    errors.push_back(Member(l, "form_error_um").is_number() ? Member(l, "form_error_um").get<double>() : 0.0);
  }
  html += Table({"Loop", "Form error (µm)", "d<sub>s</sub> peak (µm)", "σ(d<sub>u</sub>) (µm)", "Raw Moran z",
                 "Chosen model", "Residual Moran z", "Within tolerance", "Decision"},
                rows);
  NextCycleNote(html, run);
  const double tol = ToleranceUm(run.summary);
  html +=
      "<div class=\"figs\"><figure>" +
      SvgBars(labels, errors, tol, "tolerance α = " + Readable(tol) + " µm", "form error (µm)", "Form error per loop") +
      "<figcaption>" +
      Esc(std::isfinite(tol) ? "Form error per loop (µm). Green bars are within the tolerance α = " +
                                   FormatFixed(tol, 2) + " µm (dashed red line), orange bars are not."
                             : std::string("Form error per loop (µm); no tolerance was given.")) +
      "</figcaption></figure></div>\n";
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

// The one colour scale of the report (maps and 3-D view): the largest |deviation| of the first and last loop.
double ReportScale(const RunData& run) {
  double scale = 1e-3;
  for (const LoopData& l : run.loops) {
    if (l.points) scale = std::max(scale, MaxAbs(Column(*l.points, "deviation_um")));
  }
  return scale;
}

// "d_s (µm)" with a real subscript.
const char* kDsLabel = "d<tspan class=\"sub\" dy=\"4\">s</tspan><tspan dy=\"-4\"> (µm)</tspan>";

void DeviationFigures(std::string& html, const RunData& run, const LoopData& first, const LoopData& last,
                      double scale) {
  const double tol = ToleranceUm(run.summary);
  html += "<div class=\"figs\">";
  std::vector<const LoopData*> shown{&first};
  if (last.loop != first.loop) shown.push_back(&last);
  for (const LoopData* loop : shown) {
    const MapField field = FieldOf(*loop);
    const std::vector<double> x = Column(*loop->points, "x"), y = Column(*loop->points, "y");
    const FieldGrid grid = InterpolateField(x, y, field.values, 160, run.part_mask);
    const std::string when = loop == &first ? "before compensation" : "after compensation";
    const std::string what = field.systematic ? "Systematic field" : "Deviation";
    html += FigureHtml(
        SvgFieldMap(grid, x, y, scale, what + " of loop " + std::to_string(loop->loop),
                    field.systematic ? std::string(kDsLabel) : "deviation (µm)"),
        what + " of loop " + std::to_string(loop->loop) + " (" + when + ")" +
            (field.systematic ? ", d_s as the analysis fitted it" : ", the measured deviations") +
            ", interpolated between the probe points (dots). Red = material left, blue = removed beyond nominal; "
            "scale ±" +
            FormatFixed(scale, 2) + " µm, the same in every map and the 3-D view.");
  }
  const std::vector<double> d0 = Column(*first.points, "deviation_um"), d1 = Column(*last.points, "deviation_um");
  std::vector<HistogramSeries> series{{d0, "loop " + std::to_string(first.loop), HexColour(0xe66101)}};
  if (last.loop != first.loop) series.push_back({d1, "loop " + std::to_string(last.loop), HexColour(0x5e3c99)});
  html += FigureHtml(SvgHistogram(series, tol, "Deviation histogram"),
                     "Distribution of the measured deviations (µm), loop " + std::to_string(first.loop) + " (orange)" +
                         (last.loop != first.loop ? " and loop " + std::to_string(last.loop) + " (purple)" : "") +
                         (std::isfinite(tol) ? "; dashed lines at ±α = ±" + FormatFixed(tol, 2) + " µm."
                                             : std::string("; no tolerance was given.")));
  html += "</div>\n";
}

Status DeviationsSection(std::string& html, const RunData& run, double scale) {
  OpenSection(html, "deviations", "Deviations before and after",
              "Where the surface deviates from the ideal shape before compensation (loop 0) and after the last loop, "
              "and the distribution of the deviations against the tolerance.");
  if (run.loops.empty() || !run.loops.front().points) {
    NotAvailable(html, "Deviations of loop 0",
                 run.loops.empty() ? std::string("the run has no cycle") : run.loops.front().points_note);
    CloseSection(html);
    return Status::Ok();
  }
  const LoopData* last = &run.loops.front();
  for (const LoopData& l : run.loops) {
    if (l.points) last = &l;
  }
  std::vector<std::vector<std::string>> rows{DeviationStats(run.loops.front())};
  if (last->loop != 0) rows.push_back(DeviationStats(*last));
  html += Table({"Loop", "Probe points", "Mean (µm)", "RMS (µm)", "Min (µm)", "Max (µm)"}, rows);
  if (last->loop == 0) html += "<p>Only loop 0 has deviations, so there is no after-compensation map.</p>\n";
  DeviationFigures(html, run, run.loops.front(), *last, scale);
  CloseSection(html);
  return Status::Ok();
}

// Moran scatter of loop 0; "not available" without lag_um.
std::string MoranScatter(const LoopData& loop, double moran_i) {
  const std::vector<double> d = Column(*loop.points, "deviation_um");
  const std::vector<double> lag = Column(*loop.points, "lag_um");
  if (lag.empty() || d.empty()) {
    std::string html;
    NotAvailable(html, "Moran scatter plot", "the analysis wrote no spatial lag for loop 0");
    return html;
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
  return FigureHtml(SvgMoranScatter(z, lag_z, Clusters(*loop.points), moran_i,
                                    "Moran scatter of loop 0 (I = " + FormatFixed(moran_i, 3) + ")"),
                    "Each point's standardised deviation z against the average z of its neighbours; the red line has "
                    "slope I = " +
                        FormatFixed(moran_i, 3) + ". Points in the HH/LL quadrants sit in like neighbourhoods.");
}

Status SpatialSection(std::string& html, const RunData& run) {
  OpenSection(html, "spatial", "Spatial analysis",
              "Whether the deviations of loop 0 cluster in space (global Moran's I) and where (local Moran, LISA): "
              "clustered deviations are systematic and can be compensated; scattered ones are random.");
  if (run.loops.empty() || !run.loops.front().points) {
    NotAvailable(html, "Spatial analysis of loop 0", "loop 0 has no deviations");
    CloseSection(html);
    return Status::Ok();
  }
  const LoopData& loop = run.loops.front();
  const Json moran = loop.analysis.value ? Member(*loop.analysis.value, "raw_moran") : Json();
  html += Table({"Moran's I", "Expected E[I]", "z (normality)", "Chosen model"},
                {{Num(Member(moran, "I"), 4), Num(Member(moran, "expected"), 4), Num(Member(moran, "z_normality"), 2),
                  loop.analysis.value ? Esc(Scalar(Member(*loop.analysis.value, "chosen_model"))) : "—"}});
  html += "<div class=\"figs\">";
  if (!Member(moran, "I").is_number()) {
    NotAvailable(html, "Moran scatter plot", "the analysis of loop 0 recorded no Moran's I");
  } else {
    html += MoranScatter(loop, Member(moran, "I").get<double>());
  }
  const std::vector<int> clusters = Clusters(*loop.points);
  if (clusters.empty()) {
    NotAvailable(html, "LISA cluster map", "the analysis wrote no LISA clusters for loop 0");
  } else {
    html += FigureHtml(
        SvgClusterMap(Column(*loop.points, "x"), Column(*loop.points, "y"), clusters, "LISA clusters of loop 0"),
        "HH = high deviation among high neighbours (red), LL = low among low (blue), LH/HL = "
        "outliers, grey = not significant or island.");
  }
  html += "</div>\n";
  CloseSection(html);
  return Status::Ok();
}

constexpr const char* kStyle = R"(<style>
*{box-sizing:border-box}
body{font-family:"DejaVu Sans",Helvetica,Arial,sans-serif;max-width:1280px;margin:1.5em auto;padding:0 1em;color:#222;line-height:1.4}
h1{margin-bottom:.2em;overflow-wrap:anywhere}h2{border-bottom:2px solid #ddd;padding-bottom:.2em;margin-top:2em}
h3{margin-bottom:.3em}
.intro{color:#555;font-style:italic}
.tw{max-width:100%;overflow-x:auto}
table{border-collapse:collapse;margin:.6em 0;font-size:.92em}
caption{text-align:left;font-weight:bold;padding:.2em 0}
th,td{border:1px solid #ccc;padding:.25em .6em;text-align:left;vertical-align:top;overflow-wrap:break-word}th{background:#f3f3f3}
td.n{text-align:right;font-variant-numeric:tabular-nums;white-space:nowrap}
.verdict{font-size:1.4em;font-weight:bold;padding:.4em .8em;border-radius:6px;display:inline-block}
.verdict.ok{background:#e3f4e1;color:#1b5e20}.verdict.bad{background:#fde2e1;color:#b71c1c}
.badge{display:inline-block;padding:.15em .6em;border-radius:1em;background:#e0e7f1;color:#1f3b63;font-size:.9em;margin-right:.4em}
.badge.flag{background:#fff1cc;color:#7a5200}
.na{color:#8a6d3b;background:#fcf8e3;padding:.3em .6em;display:inline-block}.na:empty{display:none}
.note{background:#eef4fb;border-left:4px solid #4a78b0;padding:.4em .8em}
.caveat{background:#fff8e6;border-left:4px solid #d8a200;padding:.4em .8em}
.toc a{margin-right:1em}
.figs{display:grid;grid-template-columns:repeat(auto-fill,minmax(400px,1fr));gap:1em}
figure{margin:.6em 0;min-width:0}
figcaption{font-size:.88em;color:#444}
svg.chart{max-width:100%;height:auto;display:block}
svg.chart text{font-family:"DejaVu Sans",Helvetica,Arial,sans-serif;font-size:14px}
svg.chart text.title{font-size:16px;font-weight:bold}svg.chart text.axis{font-size:14px;font-weight:bold}
svg.chart text.quadrant{font-size:18px}svg.chart .sub{font-size:10px}
svg.scalebar{max-width:100%;height:auto;display:block}svg.scalebar text{font-family:"DejaVu Sans",Helvetica,Arial,sans-serif;font-size:13px}
footer{margin-top:3em;color:#777;font-size:.85em;border-top:1px solid #ddd;padding-top:.5em}
code{font-size:.92em;overflow-wrap:break-word}
#view3d .stage{position:relative;width:100%;max-width:900px;aspect-ratio:4/3;border:1px solid #ccc;background:#fafafa}
#view3d canvas{width:100%;height:100%;display:block;touch-action:none}
#view3d .tip{position:absolute;pointer-events:none;background:rgba(255,255,255,.92);border:1px solid #999;padding:2px 6px;font-size:.85em;display:none;white-space:nowrap}
#view3d .controls label{margin-right:1em;white-space:nowrap}
#view3d .print-only{display:none}
@media print{#view3d .stage,#view3d .controls{display:none}#view3d .print-only{display:block}}
</style>
)";

// Records in <body data-*> what rendered, for headless checks (tests/app/report_test.cc): how many SVG
// charts have a size, how many of their embedded rasters decoded, and every script error.
constexpr const char* kScript = R"(<script>
window.formloopErrors = [];
window.addEventListener("error", function (e) { window.formloopErrors.push(String(e.message)); });
window.addEventListener("load", function () {
  var charts = document.querySelectorAll("svg.chart"), drawn = 0;
  for (var i = 0; i < charts.length; ++i) { var r = charts[i].getBoundingClientRect(); if (r.width > 0 && r.height > 0) ++drawn; }
  var rasters = document.querySelectorAll("svg.chart image"), pending = rasters.length, decoded = 0;
  function done() {
    document.body.dataset.chartsDrawn = drawn + "/" + charts.length;
    document.body.dataset.rastersDecoded = decoded + "/" + rasters.length;
    var wide = [], limit = document.documentElement.clientWidth;
    document.querySelectorAll("body *").forEach(function (el) {
      var r = el.getBoundingClientRect();
      if (r.right > limit + 1 && !el.closest(".tw")) wide.push(el.tagName.toLowerCase() + (el.id ? "#" + el.id : ""));
    });
    document.body.dataset.tooWide = wide.slice(0, 5).join(" ") || "none";
    document.body.dataset.errors = window.formloopErrors.join(" | ") || "none";
    document.body.dataset.pageHeight = document.documentElement.scrollHeight;
    document.body.dataset.renderMs = Math.round(performance.now());
  }
  if (pending === 0) done();
  for (var k = 0; k < rasters.length; ++k) {
    var img = new Image();
    img.onload = function () { ++decoded; if (--pending === 0) done(); };
    img.onerror = function () { if (--pending === 0) done(); };
    img.src = rasters[k].getAttribute("href");
  }
});
</script>
)";

}  // namespace

namespace report {

MapField FieldOf(const LoopData& loop) {
  std::vector<double> ds = Column(*loop.points, "systematic_um");
  if (!ds.empty()) return {std::move(ds), true};
  return {Column(*loop.points, "deviation_um"), false};
}

}  // namespace report

Result<std::string> RenderRunReport(const fs::path& run_dir) {
  FL_ASSIGN_OR_RETURN(RunData run, LoadRun(run_dir));
  const double scale = ReportScale(run);
  std::string html = "<!DOCTYPE html>\n<html lang=\"en\">\n<head>\n<meta charset=\"utf-8\">\n";
  html += "<meta name=\"generator\" content=\"formloop\">\n";  // formloop's marker (core/output_file.h)
  html += "<meta name=\"viewport\" content=\"width=device-width, initial-scale=1\">\n";
  html += "<title>formloop report: " + Esc(StringOr(Member(run.summary, "part"), "")) + "</title>\n";
  html += kStyle;
  html += kScript;
  html += "</head>\n<body>\n";
  html += ScaleDefinitions();
  HeaderSection(html, run);
  FL_RETURN_IF_ERROR(View3dSection(html, run, scale));
  FL_RETURN_IF_ERROR(LoopHistorySection(html, run));
  FL_RETURN_IF_ERROR(DeviationsSection(html, run, scale));
  FL_RETURN_IF_ERROR(SpatialSection(html, run));
  if (!run.analysis_folder) {
    DiagnosisSection(html, run);
    RetrievalSection(html, run);
    PlanSection(html, run);
    SimCorrectionSection(html, run);
    RetainSection(html, run);
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
