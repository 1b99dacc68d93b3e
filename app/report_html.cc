#include "app/report_html.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <limits>
#include <utility>

#include <fmt/format.h>

#include "core/number_text.h"
#include "core/point_io.h"

namespace formloop::app::report {

namespace fs = std::filesystem;

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

std::string Num(const Json& value, int decimals) {
  return value.is_number() ? FormatFixed(value.get<double>(), decimals) : "—";
}

std::string Readable(double value) {
  if (!std::isfinite(value)) return "—";
  const double a = std::abs(value);
  if (a < 5e-7) return "0";
  if (value == std::round(value) && a < 1e15) return FormatFixed(value, 0);
  const int magnitude = static_cast<int>(std::floor(std::log10(a)));
  std::string text = FormatFixed(value, std::clamp(2 - magnitude, 0, 6));
  if (text.find('.') != std::string::npos) {
    while (text.back() == '0') text.pop_back();
    if (text.back() == '.') text.pop_back();
  }
  return text == "-0" ? "0" : text;
}

std::string Scalar(const Json& value) {
  if (value.is_null()) return "—";
  if (value.is_string()) return value.get<std::string>();
  if (value.is_boolean()) return value.get<bool>() ? "yes" : "no";
  if (value.is_number()) return Readable(value.get<double>());
  std::string out;
  if (value.is_array()) {
    if (value.empty()) return "none";
    for (const Json& v : value) out += (out.empty() ? "" : ", ") + Scalar(v);
    return out;
  }
  for (const auto& [key, v] : value.items()) {
    const KeyLabel label = LabelOf(key);
    out += (out.empty() ? "" : "; ") + label.name + ": " + Scalar(v) + (label.unit.empty() ? "" : " " + label.unit);
  }
  return out.empty() ? "—" : out;
}

std::string StringOr(const Json& value, const std::string& fallback) {
  return value.is_string() ? value.get<std::string>() : fallback;
}

std::string KeyLabel::Header() const { return Esc(unit.empty() ? name : name + " (" + unit + ")"); }

KeyLabel LabelOf(std::string_view key) {
  static constexpr std::array<std::pair<std::string_view, std::string_view>, 16> kUnits{{
      {"_mm_per_min", "mm/min"},
      {"_m_per_min", "m/min"},
      {"_um_per_m", "µm/m"},
      {"_n_per_mm2", "N/mm²"},
      {"_per_mm", "1/mm"},
      {"_mm2", "mm²"},
      {"_um2", "µm²"},
      {"_um", "µm"},
      {"_mm", "mm"},
      {"_deg", "°"},
      {"_rpm", "rpm"},
      {"_min", "min"},
      {"_s", "s"},
      {"_pct", "%"},
      {"_percent", "%"},
      {"_ra_um", "µm"},
  }};
  KeyLabel label{std::string(key), ""};
  for (const auto& [suffix, unit] : kUnits) {
    if (key.size() > suffix.size() && key.substr(key.size() - suffix.size()) == suffix) {
      label.name = std::string(key.substr(0, key.size() - suffix.size()));
      label.unit = unit;
      break;
    }
  }
  if (label.name == "tau") label.name = "τ";
  if (key == "loops") label.name = "machined_cycles";  // summary and outcome count cycles, loop 0 included
  label.symbol = label.name;
  std::replace(label.name.begin(), label.name.end(), '_', ' ');
  // Sentence case for words, not for symbols such as "tx" or "A": only names with a space or longer
  // than three letters.
  if ((label.name.find(' ') != std::string::npos || label.name.size() > 3) && label.name[0] >= 'a' &&
      label.name[0] <= 'z') {
    label.name[0] = static_cast<char>(label.name[0] - 'a' + 'A');
  }
  return label;
}

std::string Table(const std::vector<std::string>& header, const std::vector<std::vector<std::string>>& rows,
                  const std::string& caption) {
  std::string out = "<div class=\"tw\"><table>\n";
  if (!caption.empty()) out += "<caption>" + Esc(caption) + "</caption>\n";
  if (!header.empty()) {
    out += "<tr>";
    for (const std::string& h : header) out += "<th>" + h + "</th>";
    out += "</tr>\n";
  }
  for (const auto& row : rows) {
    out += "<tr>";
    for (const std::string& cell : row) out += "<td>" + cell + "</td>";
    out += "</tr>\n";
  }
  return out + "</table></div>\n";
}

namespace {

bool IsRowsOfObjects(const Json& value) {
  return value.is_array() && !value.empty() &&
         std::all_of(value.begin(), value.end(), [](const Json& v) { return v.is_object(); });
}

// A long list of numbers as "37 values, first 0.886, last 0.885"; short lists in full.
std::string ListCell(const Json& array) {
  const bool numbers = std::all_of(array.begin(), array.end(), [](const Json& v) { return v.is_number(); });
  if (numbers && array.size() > 6) {
    return fmt::format("{} values, first {}, last {}", array.size(), Readable(array.front().get<double>()),
                       Readable(array.back().get<double>()));
  }
  if (std::any_of(array.begin(), array.end(), [](const Json& v) { return v.is_array(); })) {
    return fmt::format("{} lists", array.size());
  }
  return Esc(Scalar(array));
}

std::string ValueCell(const Json& value, const std::string& unit) {
  if (value.is_array()) return ListCell(value);
  const std::string text = Esc(Scalar(value));
  return value.is_number() && !unit.empty() ? text + " " + Esc(unit) : text;
}

}  // namespace

std::string ObjectTables(const Json& object, const std::string& caption, int depth) {
  if (!object.is_object()) return Table({}, {{Esc(Scalar(object))}}, caption);
  std::vector<std::vector<std::string>> rows;
  std::string below;
  for (const auto& [key, value] : object.items()) {
    const KeyLabel label = LabelOf(key);
    if (value.is_object() && !value.empty() && depth < 2) {
      below += ObjectTables(value, caption.empty() ? label.name : caption + ": " + label.name, depth + 1);
    } else if (IsRowsOfObjects(value) && depth < 2) {
      below += RowsTable(value, caption.empty() ? label.name : caption + ": " + label.name);
    } else {
      rows.push_back({Esc(label.name), ValueCell(value, label.unit)});
    }
  }
  std::string out = rows.empty() ? "" : Table({}, rows, caption);
  return out + below;
}

std::string RowsTable(const Json& rows, const std::string& caption) {
  std::vector<std::string> columns;
  for (const Json& row : rows) {
    for (const auto& [key, value] : row.items()) {
      if (std::find(columns.begin(), columns.end(), key) == columns.end()) columns.push_back(key);
    }
  }
  std::vector<std::vector<std::string>> cells;
  for (const Json& row : rows) {
    std::vector<std::string> line;
    for (const std::string& c : columns) {
      const Json& v = Member(row, c.c_str());
      line.push_back(v.is_array() ? ListCell(v) : Esc(Scalar(v)));
    }
    cells.push_back(std::move(line));
  }
  std::vector<std::string> header;
  for (const std::string& c : columns) header.push_back(LabelOf(c).Header());
  return Table(header, cells, caption);
}

std::string FigureHtml(const std::string& svg, const std::string& caption) {
  return "<figure>" + svg + "<figcaption>" + Esc(caption) + "</figcaption></figure>\n";
}

void OpenSection(std::string& html, const std::string& id, const std::string& title, const std::string& intro) {
  html += fmt::format("<section id=\"{}\">\n<h2>{}</h2>\n<p class=\"intro\">{}</p>\n", id, Esc(title), Esc(intro));
}

void CloseSection(std::string& html) { html += "</section>\n"; }

void NotAvailable(std::string& html, const std::string& what, const std::string& why) {
  html +=
      fmt::format("<p class=\"na\">{}: not available{}.</p>\n", Esc(what), why.empty() ? "" : " (" + Esc(why) + ")");
}

OptionalJson ReadOptionalJson(const fs::path& path) {
  std::error_code ec;
  if (!fs::exists(path, ec)) return {std::nullopt, ""};
  Result<Json> json = ReadJsonFile(path);
  if (!json.ok()) return {std::nullopt, json.status().message()};
  return {std::move(json).value(), ""};
}

std::vector<double> Column(const PointSet& points, const std::string& name) {
  if (name == "x" || name == "y" || name == "z") {
    const int axis = name == "x" ? 0 : name == "y" ? 1 : 2;
    std::vector<double> out;
    out.reserve(points.points.size());
    for (const auto& p : points.points) out.push_back(p[axis]);
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

double ToleranceUm(const Json& summary) {
  const Json& t = Member(summary, "tolerance_um");
  return t.is_number() ? t.get<double>() : std::numeric_limits<double>::quiet_NaN();
}

}  // namespace formloop::app::report
