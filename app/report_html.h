#pragma once
// The HTML building blocks of the run report and the plant overview (app/report.h): escaping,
// locale-free number formats a reader can take in at a glance, labelled tables, sections, and the run
// folder as the report reads it. Internal to app/report*.cc.

#include <filesystem>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include "app/report_charts.h"
#include "core/json_io.h"
#include "core/point_set.h"

namespace formloop::app::report {

// ---- Text ----

std::string Esc(std::string_view text);
// The member `key` of an object, or null (also when `object` is not an object).
const Json& Member(const Json& object, const char* key);
// A number with fixed decimals, "—" when absent or not a number.
std::string Num(const Json& value, int decimals);
// A number as a reader wants it: 3 significant digits but never an exponent and never fewer than the
// integer digits ("21208", "813", "3.4", "0.0203", "0"); integers as integers. "—" for NaN.
std::string Readable(double value);
// Any JSON value as cell text: Readable numbers, yes/no, lists joined by ", ", "—" for null; objects as
// "key: value; ..." of their scalars (never raw JSON).
std::string Scalar(const Json& value);
std::string StringOr(const Json& value, const std::string& fallback);

// A JSON key with its unit split off the name: "feed_mm_per_min" -> {"Feed", "mm/min"}, "tz_um" ->
// {"Tz", "µm"}, "spindle_rpm" -> {"Spindle", "rpm"}, "raster_angle_deg" -> {"Raster angle", "°"}.
struct KeyLabel {
  std::string name, unit;
  std::string symbol;          // the key without its unit, as written ("k_w" of "k_w_um_per_m"; "τ" for tau)
  std::string Header() const;  // "Feed (mm/min)", HTML-escaped
};
KeyLabel LabelOf(std::string_view key);

// ---- Tables and sections ----

// A table with a header row; cells are already HTML. Wide tables scroll inside their own box, so the
// page never gets wider than the window.
std::string Table(const std::vector<std::string>& header, const std::vector<std::vector<std::string>>& rows,
                  const std::string& caption = "");
// An object's scalars as a two-column table (quantity with its unit, value); nested objects as their own
// labelled tables below (depth-limited), arrays of objects as row tables, arrays of numbers summarised.
std::string ObjectTables(const Json& object, const std::string& caption, int depth = 0);
// An array of objects as one table, columns in order of first appearance, headers with units.
std::string RowsTable(const Json& rows, const std::string& caption);

// A figure: the SVG and its caption (plain text).
std::string FigureHtml(const std::string& svg, const std::string& caption);

void OpenSection(std::string& html, const std::string& id, const std::string& title, const std::string& intro);
void CloseSection(std::string& html);
// "<what>: not available (<why>)." — why may be empty.
void NotAvailable(std::string& html, const std::string& what, const std::string& why);

// ---- The run folder ----

// An optional input: the parsed JSON, or why it is absent (empty: the file does not exist).
struct OptionalJson {
  std::optional<Json> value;
  std::string note;
};
OptionalJson ReadOptionalJson(const std::filesystem::path& path);

struct LoopData {
  int loop = 0;
  std::optional<PointSet> points;  // loop-K/deviations.csv
  std::string points_note;
  OptionalJson analysis;  // loop-K/analysis.json
  OptionalJson machine;   // loop-K/machine.json
};

struct RunData {
  bool analysis_folder = false;  // a `formloop analyse` folder: one cycle, no run-only sections
  std::filesystem::path dir;
  Json summary;
  OptionalJson retrieval, plan, sim_correction, diagnosis, diagnosis_model, retain;
  std::vector<LoopData> loops;  // loop-0, loop-1, ... as long as the folders exist
  MapMask part_mask;            // a run on a trimmed Q: (x, y) over the part (TrimMask); empty otherwise
};

// A column of a point set ("x", "y", "z" or a scalar); empty when absent.
std::vector<double> Column(const PointSet& points, const std::string& name);
std::vector<int> Clusters(const PointSet& points);
double MaxAbs(const std::vector<double>& values);
// The tolerance α in µm; NaN when none was given.
double ToleranceUm(const Json& summary);

}  // namespace formloop::app::report
