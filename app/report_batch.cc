// The plant overview (app/report.h): one page over a batch or regression folder, a row per part
// linking its report.

#include <algorithm>
#include <cmath>
#include <map>

#include <fmt/format.h>

#include "app/report.h"
#include "app/report_html.h"
#include "core/atomic_file.h"
#include "core/number_text.h"

namespace formloop::app {
namespace {

namespace fs = std::filesystem;
using namespace report;  // NOLINT: the report's own building blocks

struct PartRow {
  std::string name;
  std::optional<Json> summary;
  std::string error;  // a failed part of a batch (batch_summary.json) or an unreadable summary.json
  bool has_report = false;
};

std::string Cell(const Json& loop, const char* key) {
  const Json& v = Member(loop, key);
  return v.is_number() ? FormatFixed(v.get<double>(), 2) : "—";
}

std::string Row(const PartRow& p) {
  const std::string link = p.has_report ? "<a href=\"" + Esc(p.name) + "/report.html\">" + Esc(p.name) + "</a>"
                                        : Esc(p.name) + "<br><small>no report.html</small>";
  if (!p.summary) {
    return "<tr class=\"failed\"><td>" + link + "</td><td colspan=\"8\">failed: " + Esc(p.error) + "</td></tr>\n";
  }
  const Json& s = *p.summary;
  const Json& loops = Member(s, "loops");
  const Json first = loops.is_array() && !loops.empty() ? loops.front() : Json();
  const Json last = loops.is_array() && !loops.empty() ? loops.back() : Json();
  const Json& route = Member(s, "route");
  const bool ok = Member(s, "within_tolerance") == Json(true);
  return fmt::format(
      "<tr><td>{}</td><td>{}</td><td class=\"n\">{}</td><td class=\"n\">{}</td><td class=\"n\">{}</td><td "
      "class=\"n\">{}</td><td class=\"n\">{}</td><td class=\"{}\">{}</td><td>{}</td></tr>\n",
      link, Esc(StringOr(Member(route, "name"), StringOr(route, "—"))), Num(Member(route, "similarity"), 3),
      Num(Member(s, "tolerance_um"), 1), Cell(first, "form_error_um"), Cell(last, "form_error_um"),
      loops.is_array() ? std::to_string(loops.size()) : "—", ok ? "ok" : "bad", ok ? "yes" : "NO",
      Esc(Scalar(Member(s, "causes"))));
}

Result<std::vector<PartRow>> ReadParts(const fs::path& dir) {
  std::error_code ec;
  if (!fs::is_directory(dir, ec)) {
    return Status::BadInput(Where{.file = dir.string()}, "not a folder",
                            "give the folder written by `formloop run` with several parts or by `formloop regress`");
  }
  std::map<std::string, PartRow> parts;  // name order
  for (const auto& entry : fs::directory_iterator(dir, ec)) {
    if (!entry.is_directory(ec) || !fs::exists(entry.path() / "summary.json", ec)) continue;
    PartRow row{.name = entry.path().filename().string()};
    Result<Json> summary = ReadJsonFile(entry.path() / "summary.json");
    if (summary.ok()) {
      row.summary = std::move(summary).value();
    } else {
      row.error = summary.status().message();
    }
    row.has_report = fs::exists(entry.path() / "report.html", ec);
    parts.emplace(row.name, std::move(row));
  }
  // A batch's failed parts have no summary.json; batch_summary.json names them.
  if (fs::exists(dir / "batch_summary.json", ec)) {
    Result<Json> batch = ReadJsonFile(dir / "batch_summary.json");
    if (!batch.ok()) return Status::BadInput(batch.status().message());
    const Json& rows = Member(*batch, "parts");
    for (const Json& r : rows.is_array() ? rows : Json::array()) {
      if (Member(r, "status") != Json("failed")) continue;
      const std::string name = StringOr(Member(r, "part"), fs::path(StringOr(Member(r, "part_file"), "?")).stem());
      if (!parts.count(name)) parts.emplace(name, PartRow{.name = name, .error = StringOr(Member(r, "error"), "")});
    }
  }
  if (parts.empty()) {
    return Status::BadInput(Where{.file = dir.string()}, "holds no run folder (no <part>/summary.json)",
                            "give the folder written by `formloop run` with several parts or by `formloop regress`");
  }
  std::vector<PartRow> out;
  for (auto& [name, row] : parts) out.push_back(std::move(row));
  return out;
}

}  // namespace

Result<std::string> RenderBatchOverview(const fs::path& dir) {
  FL_ASSIGN_OR_RETURN(const std::vector<PartRow> parts, ReadParts(dir));
  std::error_code ec;
  const std::string kind = fs::exists(dir / "batch_summary.json", ec) ? "batch run"
                           : fs::exists(dir / "kb.sqlite", ec)        ? "regression run"
                                                                      : "folder of runs";
  // The folder's own name ("runs/batch/" -> "batch"), not its path.
  std::string name = fs::weakly_canonical(dir, ec).filename().string();
  if (name.empty()) name = dir.string();
  int within = 0, failed = 0;
  for (const PartRow& p : parts) {
    if (!p.summary) {
      ++failed;
      continue;
    }
    within += Member(*p.summary, "within_tolerance") == Json(true);
  }
  std::string html = "<!DOCTYPE html>\n<html lang=\"en\">\n<head>\n<meta charset=\"utf-8\">\n";
  html += "<meta name=\"generator\" content=\"formloop\">\n";  // formloop's marker (core/output_file.h)
  html += "<meta name=\"viewport\" content=\"width=device-width, initial-scale=1\">\n";
  html += "<title>formloop plant overview: " + Esc(name) + "</title>\n";
  html += R"(<style>
*{box-sizing:border-box}
body{font-family:"DejaVu Sans",Helvetica,Arial,sans-serif;max-width:1280px;margin:1.5em auto;padding:0 1em;color:#222;line-height:1.4}
.tw{max-width:100%;overflow-x:auto}
table{border-collapse:collapse;margin:.6em 0;font-size:.92em}
th,td{border:1px solid #ccc;padding:.25em .6em;text-align:left;vertical-align:top}th{background:#f3f3f3}
td.n{text-align:right;font-variant-numeric:tabular-nums;white-space:nowrap}
td:first-child{white-space:nowrap}td.ok{color:#1b5e20;font-weight:bold}td.bad,tr.failed td{color:#b71c1c;font-weight:bold}
footer{margin-top:3em;color:#777;font-size:.85em;border-top:1px solid #ddd;padding-top:.5em}
</style>
</head>
<body>
)";
  html += "<h1>Plant overview: " + Esc(name) + "</h1>\n";
  html += fmt::format(
      "<p>A {} of {} part{}: <strong>{} within tolerance</strong>, {} not{}. Each part's name links to its "
      "report.</p>\n",
      kind, parts.size(), parts.size() == 1 ? "" : "s", within, static_cast<int>(parts.size()) - within - failed,
      failed ? fmt::format(", {} failed", failed) : "");
  html +=
      "<div class=\"tw\"><table>\n<tr><th>Part</th><th>Route</th><th>Similarity A</th><th>Tolerance α (µm)</th>"
      "<th>First-cycle form error (µm)</th><th>Final form error (µm)</th><th>Machined cycles</th><th>Within "
      "tolerance</th><th>Causes named (loop 0)</th></tr>\n";
  for (const PartRow& p : parts) html += Row(p);
  html += "</table></div>\n";
  html +=
      "<footer>formloop plant overview (the page names no absolute folder, so the same runs give the same "
      "bytes wherever they are)</footer>\n</body>\n</html>\n";
  return html;
}

Status WriteBatchOverview(const fs::path& dir, const fs::path& html_path) {
  FL_ASSIGN_OR_RETURN(std::string html, RenderBatchOverview(dir));
  return WriteFileAtomic(html_path, html);
}

}  // namespace formloop::app
