// The plan, simulation-correction, retain and diagnosis sections of the run report (report_sections.h):
// labelled tables with units, numbers as a reader wants them (report_html.h), no raw JSON.

#include <algorithm>
#include <cmath>
#include <filesystem>

#include <fmt/format.h>

#include "app/report_sections.h"
#include "core/number_text.h"

namespace formloop::app::report {
namespace {

// A number with its unit, or "—".
std::string Quantity(const Json& value, const std::string& unit, double factor = 1) {
  if (!value.is_number()) return "—";
  return Readable(value.get<double>() * factor) + (unit.empty() ? "" : " " + unit);
}

std::string Percent(double fraction) {
  const double p = 100 * fraction;
  return (std::abs(p) < 1 && p != 0 ? FormatFixed(p, 2) : FormatFixed(p, 1)) + " %";
}

// A defect list as "none" or "3: gouge, scallop, ...".
std::string Defects(const Json& list) {
  if (!list.is_array() || list.empty()) return "none";
  std::string kinds;
  for (const Json& d : list) {
    const std::string kind =
        d.is_object()
            ? StringOr(Member(d, "type"), StringOr(Member(d, "kind"), StringOr(Member(d, "defect"), "defect")))
            : Scalar(d);
    if (kinds.find(kind) == std::string::npos) kinds += (kinds.empty() ? "" : ", ") + kind;
  }
  return fmt::format("{}: {}", list.size(), kinds);
}

}  // namespace

void PlanSection(std::string& html, const RunData& run) {
  OpenSection(html, "plan", "Plan", "The process plan the run cut with: where it came from, tool, feeds and path.");
  if (!run.plan.value) {
    NotAvailable(html, "Plan", run.plan.note.empty() ? "the run recorded no plan" : run.plan.note);
    CloseSection(html);
    return;
  }
  const Json& p = *run.plan.value;
  const Json& case_plan = Member(p, "case_plan");
  std::vector<std::vector<std::string>> rows{
      {"Source", Esc(Scalar(Member(p, "source")))},
      {"Route", Esc(Scalar(Member(p, "route")))},
  };
  if (case_plan.is_object()) {
    rows.push_back({"Case", "<code>" + Esc(Scalar(Member(case_plan, "case"))) + "</code>"});
    rows.push_back({"Kept from this part", Esc(Scalar(Member(case_plan, "kept_from_part")))});
  }
  const Json& pre = Member(p, "precompensation");
  rows.push_back({"Pre-compensation",
                  pre.is_null() ? "none (the case has no learned model to pre-compensate with)" : Esc(Scalar(pre))});
  html += Table({}, rows, "Where the plan came from");
  if (Member(p, "toolpath").is_object()) html += ObjectTables(Member(p, "toolpath"), "Tool path as cut");
  if (Member(case_plan, "from_case").is_object()) {
    html +=
        ObjectTables(Member(case_plan, "from_case"), "As the case " + Scalar(Member(case_plan, "case")) + " had it");
  }
  const Json& learned = Member(p, "learned_model");
  if (learned.is_object()) html += ObjectTables(learned, "Learned model of the case");
  CloseSection(html);
}

void SimCorrectionSection(std::string& html, const RunData& run) {
  OpenSection(html, "sim-correction", "Simulation correction",
              "Defects the virtual machine predicted for the plan before and after correction, the plan applied and "
              "each round of the search.");
  if (!run.sim_correction.value) {
    NotAvailable(html, "Simulation correction",
                 run.sim_correction.note.empty() ? "the route did not call for it" : run.sim_correction.note);
    CloseSection(html);
    return;
  }
  const Json& s = *run.sim_correction.value;
  html += Table(
      {},
      {{"Corrected", Esc(Scalar(Member(s, "corrected")))},
       {"Defects predicted before → after",
        Esc(Defects(Member(s, "defects_before"))) + " → " + Esc(Defects(Member(s, "defects_after")))},
       {"Predicted form error before → after", Quantity(Member(s, "predicted_form_error_before_um"), "µm") + " → " +
                                                   Quantity(Member(s, "predicted_form_error_after_um"), "µm")},
       {"Rounds", Esc(Scalar(Member(s, "rounds")))},
       {"Pre-compensation scale", Quantity(Member(s, "precompensation_scale"), "")},
       {"Why not corrected", StringOr(Member(s, "why_not"), "").empty() ? "—" : Esc(Scalar(Member(s, "why_not")))}},
      "Outcome");
  // The plan the run cuts with (the values of plan.json and the programs), then the GA's candidate, which is that
  // plan only when the correction succeeded ("chosen" in run folders written before issue 17 item 9).
  if (Member(s, "applied").is_object()) html += ObjectTables(Member(s, "applied"), "Plan applied");
  for (const char* key : {"candidate", "chosen"}) {
    if (Member(s, key).is_object()) html += ObjectTables(Member(s, key), "The GA's candidate");
  }
  const Json& history = Member(s, "history");
  std::vector<std::vector<std::string>> rows;
  for (const Json& h : history.is_array() ? history : Json::array()) {
    const Json& check = Member(h, "check");
    const Json& best = Member(Member(h, "ga"), "best");
    const Json& genes = Member(h, "genes");
    rows.push_back({Esc(Scalar(Member(h, "round"))), Quantity(Member(check, "e_pred_mm"), "", 1000),
                    Quantity(Member(check, "peak_scallop_mm"), "", 1000),
                    Quantity(Member(check, "peak_deflection_mm"), "", 1000),
                    Quantity(Member(check, "peak_systematic_mm"), "", 1000), Esc(Defects(Member(check, "defects"))),
                    Quantity(Member(genes, "tool_radius_mm"), ""), Quantity(Member(genes, "step_over_mm"), ""),
                    Quantity(Member(genes, "feed_mm_per_min"), ""), Quantity(Member(genes, "spindle_rpm"), ""),
                    Quantity(Member(best, "time_min"), ""), Quantity(Member(best, "J"), ""),
                    Esc(Scalar(Member(best, "generations")))});
  }
  if (!rows.empty()) {
    html += Table({"Round", "Predicted error (µm)", "Peak scallop (µm)", "Peak deflection (µm)", "Peak systematic (µm)",
                   "Defects", "Tool radius (mm)", "Step-over (mm)", "Feed (mm/min)", "Spindle (rpm)",
                   "Cutting time (min)", "Objective J", "GA generations"},
                  rows, "History: one row per round of search and check");
  }
  CloseSection(html);
}

void RetainSection(std::string& html, const RunData& run) {
  OpenSection(html, "retain", "Retain", "What this run stores back into the case library for future parts.");
  if (!run.retain.value) {
    NotAvailable(html, "Retain",
                 run.retain.note.empty() ? "this run stores nothing in a case library (--no-retain "
                                           "or no library)"
                                         : run.retain.note);
    CloseSection(html);
    return;
  }
  const Json& r = *run.retain.value;
  const Json& c = Member(r, "case");
  if (!c.is_object()) {  // a retain record of another shape: its fields as they are
    html += ObjectTables(r, "Retained");
    CloseSection(html);
    return;
  }
  const Json& part = Member(c, "part");
  const std::string library = StringOr(Member(r, "library"), "");
  html += Table({},
                {{"Action", Esc(Scalar(Member(r, "action")))},
                 {"Case", "<code>" + Esc(Scalar(Member(r, "uid"))) + "</code> — " + Esc(Scalar(Member(c, "name")))},
                 {"Family", Esc(Scalar(Member(c, "family")))},
                 {"Library file", library.empty() ? "—" : Esc(std::filesystem::path(library).filename().string())}},
                "The case");
  if (Member(c, "concepts").is_object()) html += ObjectTables(Member(c, "concepts"), "Concepts (for retrieval)");
  if (Member(part, "outcome").is_object()) html += ObjectTables(Member(part, "outcome"), "Outcome recorded");
  const Json& m = Member(c, "manufacturing");
  if (m.is_object()) {
    std::vector<std::vector<std::string>> rows;
    for (const char* key : {"machine", "feeds", "strategy", "probing"}) {
      if (!Member(m, key).is_null()) rows.push_back({Esc(LabelOf(key).name), Esc(Scalar(Member(m, key)))});
    }
    html += Table({}, rows, "Manufacturing");
    if (Member(m, "tools").is_array() && !Member(m, "tools").empty()) html += RowsTable(Member(m, "tools"), "Tools");
    const Json& loops = Member(Member(m, "compensation"), "loops");
    if (loops.is_array() && !loops.empty()) html += RowsTable(loops, "Compensation loops");
  }
  const Json& learned = Member(r, "learned_model");
  if (learned.is_object() && Member(learned, "effects").is_array()) {
    std::vector<std::vector<std::string>> rows;
    for (const Json& e : Member(learned, "effects")) {
      rows.push_back({Esc(Scalar(Member(e, "name"))), Esc(Scalar(Member(e, "parameters"))),
                      Esc(Scalar(Member(e, "alias_group")))});
    }
    html += Table({"Effect", "Parameters", "Alias group"}, rows, "Learned model stored with the case");
  }
  html +=
      "<p>The case's 24-number shape descriptor and the part file for re-runs are stored too (in the library; "
      "not shown).</p>\n";
  CloseSection(html);
}

namespace {

// "name = value ± se [lo, hi]" per parameter, with units; aliased parameters say so.
std::string Parameters(const Json& cause) {
  const Json& params = Member(cause, "parameters");
  const Json& errors = Member(cause, "std_errors");
  const Json& intervals = Member(cause, "interval_95");
  const Json& aliased = Member(cause, "aliased_parameters");
  std::string out;
  if (!params.is_object()) return Esc(Scalar(params));
  for (const auto& [key, value] : params.items()) {
    const KeyLabel label = LabelOf(key);
    const std::string unit = label.unit.empty() ? "" : " " + label.unit;
    std::string line = Esc(label.symbol) + " = ";
    const bool in_group = aliased.is_array() && std::find(aliased.begin(), aliased.end(), Json(key)) != aliased.end();
    if (in_group || !value.is_number()) {
      line += "in an alias group (see below)";
    } else {
      const Json& se = Member(errors, key.c_str());
      const Json& ci = Member(intervals, key.c_str());
      line += Readable(value.get<double>()) + (se.is_number() ? " ± " + Readable(se.get<double>()) : "") + Esc(unit);
      if (ci.is_array() && ci.size() == 2 && ci[0].is_number() && ci[1].is_number()) {
        line += ", 95 % interval [" + Readable(ci[0].get<double>()) + ", " + Readable(ci[1].get<double>()) + "]";
      } else if (se.is_number()) {
        line += ", ≈95 % interval [" + Readable(value.get<double>() - 1.96 * se.get<double>()) + ", " +
                Readable(value.get<double>() + 1.96 * se.get<double>()) + "] (±1.96 std. errors)";
      }
    }
    out += (out.empty() ? "" : "<br>") + line;
  }
  return out.empty() ? "—" : out;
}

// The named effects' look-alikes (correlation of their patterns on this design).
void LookAlikes(std::string& html, const Json& d) {
  const Json& confounded = Member(d, "confounded");
  if (!confounded.is_array() || confounded.empty()) return;
  std::vector<std::vector<std::string>> rows;
  for (const Json& c : confounded) {
    rows.push_back({Esc(Scalar(Member(c, "named"))), Esc(Scalar(Member(c, "with"))), Num(Member(c, "correlation"), 3),
                    Esc(Scalar(Member(c, "separate_by")))});
  }
  html +=
      "<h3>Look-alikes</h3>\n<p>Effects whose patterns on these probe points resemble a named cause. The "
      "selection still preferred the named one, but with a correlation near 1 its share may belong partly to "
      "the other; the last column says what would separate them.</p>\n";
  html += Table({"Named", "Resembles", "Correlation", "What would separate them"}, rows);
  // A minor cause with a near-perfect look-alike is weakly determined: say so next to it.
  const Json& causes = Member(d, "causes");
  std::string weak;
  for (const Json& c : causes.is_array() ? causes : Json::array()) {
    const Json& share = Member(c, "variance_explained");
    if (!share.is_number() || share.get<double>() >= 0.05) continue;
    for (const Json& l : confounded) {
      const Json& r = Member(l, "correlation");
      if ((Member(l, "named") == Member(c, "effect") || Member(l, "with") == Member(c, "effect")) && r.is_number() &&
          std::abs(r.get<double>()) >= 0.99) {
        weak += (weak.empty() ? "" : ", ") + Scalar(Member(c, "effect"));
        break;
      }
    }
  }
  if (!weak.empty()) {
    html += "<p class=\"caveat\">Weakly determined: " + Esc(weak) +
            " explain under 5 % of the variance each and have a look-alike with correlation ≥ 0.99 on these points; "
            "their values may belong to the look-alike. Confirm them with the separating measurement before acting "
            "on them.</p>\n";
  }
}

// The earlier cases the diagnosis pooled with this part (diagnosis.json "pooled"), and the others of the
// same machine/tool/material with why they were not.
void PooledParts(std::string& html, const Json& d) {
  const Json& pooled = Member(d, "pooled");
  if (!pooled.is_object()) return;
  const Json& cases = Member(pooled, "cases");
  const bool any = cases.is_array() && !cases.empty();
  html += "<h3>Parts pooled</h3>\n<p>" +
          (any ? "Diagnosed together with the earlier case(s) " + Esc(Scalar(cases)) +
                     " of the same machine, tool and material (the shared effects fitted jointly, each part's "
                     "set-up on its own; at most " +
                     Esc(Scalar(Member(pooled, "limit"))) + ", newest first)."
               : std::string("Diagnosed alone: the case library holds no earlier part of this machine, tool and "
                             "material to pool with.")) +
          "</p>\n";
  const Json& others = Member(pooled, "not_pooled");
  if (others.is_array() && !others.empty()) {
    std::vector<std::vector<std::string>> rows;
    for (const Json& o : others) rows.push_back({Esc(Scalar(Member(o, "case"))), Esc(Scalar(Member(o, "why")))});
    html += Table({"Case", "Why not"}, rows, "Cases of this machine, tool and material not pooled");
  }
}

// Alias groups (the several-causes diagnosis): from diagnosis.json, else from the learned model.json.
void AliasGroups(std::string& html, const Json& d, const OptionalJson& model) {
  const Json& groups = Member(d, "alias_groups");
  if (groups.is_array() && !groups.empty()) {
    std::vector<std::vector<std::string>> rows;
    for (const Json& g : groups) {
      rows.push_back(
          {Esc(Scalar(Member(g, "members"))),
           Percent(Member(g, "variance_explained").is_number() ? Member(g, "variance_explained").get<double>() : 0),
           Quantity(Member(g, "combined_rms_um"), "µm"), Num(Member(g, "design_correlation"), 3),
           Esc(Scalar(Member(g, "separate_by")))});
    }
    html +=
        "<h3>Alias groups</h3>\n<p>Each group is one finding: one or more of its members acts, and these data "
        "cannot tell which. Their combined prediction is used; no member is named on its own.</p>\n";
    html += Table({"Members", "Share of residual variance (together)", "Combined RMS", "Design correlation",
                   "What would separate them"},
                  rows);
  } else if (model.value && Member(*model.value, "alias_groups").is_array() &&
             !Member(*model.value, "alias_groups").empty()) {
    html += "<h3>Alias groups</h3>\n";
    html += RowsTable(Member(*model.value, "alias_groups"), "Alias groups of the learned model");
  }
  const Json& proposals = Member(d, "proposals");
  if (proposals.is_array() && !proposals.empty()) {
    std::vector<std::vector<std::string>> rows;
    for (const Json& p : proposals) {
      rows.push_back(
          {Esc(Scalar(Member(p, "alias_group"))), Esc(Scalar(Member(p, "change"))), Quantity(Member(p, "cost_s"), "s"),
           Num(Member(p, "design_correlation_before"), 3) + " → " + Num(Member(p, "design_correlation_predicted"), 3),
           Esc(Scalar(Member(p, "predicted_to_split")))});
    }
    html += Table(
        {"Alias group", "Proposed experiment", "Cost", "Design correlation now → predicted", "Predicted to separate"},
        rows, "Experiments that would separate the alias groups");
  }
  const Json& implausible = Member(d, "implausible");
  if (implausible.is_array() && !implausible.empty()) {
    std::vector<std::vector<std::string>> rows;
    for (const Json& b : implausible) {
      rows.push_back({Esc(Scalar(Member(b, "effect"))), Esc(Scalar(Member(b, "fitted"))),
                      Esc(Scalar(Member(b, "outside_plausible_range")))});
    }
    html += Table({"Effect (not named)", "Values the data asked for", "Outside the plausible range"}, rows,
                  "Fits outside their plausible range");
  }
}

void Residual(std::string& html, const Json& d) {
  const Json& unexplained = Member(d, "unexplained");
  const Json& gain = Member(d, "gain");
  const Json& causes = Member(d, "causes");
  const Json& residual = Member(d, "residual");
  html += "<h3>What remains</h3>\n";
  if (unexplained.is_null()) {
    const double z_after = causes.is_array() && !causes.empty() && Member(causes.back(), "z_after").is_number()
                               ? causes.back()["z_after"].get<double>()
                               : std::nan("");
    html += "<p>No spatially clustered residual was detected after the findings above";
    html += std::isfinite(z_after) ? " (residual Moran z = " + FormatFixed(z_after, 2) + ")" : std::string();
    html += ": the remaining RMS is " + Quantity(Member(gain, "rms_after_um"), "µm") +
            " against an estimated noise level of σ ≈ " + Quantity(Member(residual, "noise_sigma_um"), "µm") +
            ". This is the result of one test at this probe density, not proof that nothing else acts: an effect "
            "smaller than the noise, or one the catalogue does not hold, would not show here.</p>\n";
  } else {
    html += "<p class=\"caveat\">An unexplained systematic residual remains";
    if (Member(unexplained, "z").is_number()) html += " (Moran z = " + Num(Member(unexplained, "z"), 2) + ")";
    html += ": some of the deviation follows a pattern none of the findings above accounts for.</p>\n";
    const Json& where = Member(unexplained, "where");
    if (where.is_array() && !where.empty() && where.front().is_object()) {
      html += RowsTable(where, "Where the unexplained residual clusters");
    }
  }
  html += "<h3>Gain</h3>\n";
  html +=
      Table({"", "Before (µm)", "After (µm)"},
            {{"RMS on the points fitted", Num(Member(gain, "rms_before_um"), 2), Num(Member(gain, "rms_after_um"), 2)},
             {"RMS on held-out points (block cross-validation)", Num(Member(gain, "heldout_rms_before_um"), 2),
              Num(Member(gain, "heldout_rms_after_um"), 2)}});
  const Json& hb = Member(gain, "heldout_rms_before_um");
  const Json& ha = Member(gain, "heldout_rms_after_um");
  if (hb.is_number() && ha.is_number() && hb.get<double>() > 0) {
    html += fmt::format(
        "<p>On points the fit did not see, the model of the findings above lowers the RMS by {} "
        "(from {} to {} µm).</p>\n",
        Percent(1 - ha.get<double>() / hb.get<double>()), Num(hb, 2), Num(ha, 2));
  }
  const Json& not_screened = Member(Member(d, "not_screened"), "effects");
  if (not_screened.is_array() && !not_screened.empty()) {
    html += "<p>Not tested: " + Esc(Scalar(not_screened)) + " (" +
            Esc(Scalar(Member(Member(d, "not_screened"), "reason"))) + ").</p>\n";
  }
}

}  // namespace

void DiagnosisSection(std::string& html, const RunData& run) {
  OpenSection(html, "diagnosis", "Diagnosis",
              "Which physical effects of the machine, tool, set-up or probe explain the systematic deviation of loop 0 "
              "that the case's simulation did not predict, how large each is and how sure, what the data cannot "
              "separate, and how much a model of them gains on points it was not fitted to.");
  if (!run.diagnosis.value) {
    NotAvailable(html, "Diagnosis",
                 run.diagnosis.note.empty() ? "the run did not diagnose its first cycle" : run.diagnosis.note);
    CloseSection(html);
    return;
  }
  const Json& d = *run.diagnosis.value;
  if (Member(d, "explained_by_baseline") == Json(true)) {
    html += "<p>The case's simulation already explains the deviations of loop 0: no further cause is named.</p>\n";
  }
  std::vector<std::vector<std::string>> rows;
  const Json& causes = Member(d, "causes");
  double largest = 0;
  for (const Json& c : causes.is_array() ? causes : Json::array()) {
    if (Member(c, "variance_explained").is_number()) largest = std::max(largest, c["variance_explained"].get<double>());
  }
  for (const Json& c : causes.is_array() ? causes : Json::array()) {
    const double share = Member(c, "variance_explained").is_number() ? c["variance_explained"].get<double>() : 0;
    std::string effect = "<strong>" + Esc(Scalar(Member(c, "effect"))) + "</strong>";
    if (Member(c, "part").is_string()) effect += " (set-up of " + Esc(Scalar(Member(c, "part"))) + ")";
    std::string share_cell = Percent(share);
    if (largest > 0 && share < 0.05 * largest) share_cell += "<br><small>minor beside the leading cause</small>";
    rows.push_back(
        {effect, share_cell, Parameters(c), Num(Member(c, "z_before"), 2) + " → " + Num(Member(c, "z_after"), 2)});
  }
  if (rows.empty()) {
    const bool groups = Member(d, "alias_groups").is_array() && !Member(d, "alias_groups").empty();
    html += std::string(
                "<p>No single effect of the catalogue was named: none explains the systematic deviation "
                "significantly and identifiably on its own") +
            (groups ? " (the alias groups below do, together)." : ".") + "</p>\n";
  } else {
    html += Table({"Cause", "Share of the residual variance", "Parameters (value ± std. error, interval)",
                   "Moran z before → after"},
                  rows, "Named causes, in the order the selection took them");
    html +=
        "<p>The share is the fraction of the variance of loop 0's residual (after the case's simulation) that "
        "the cause removes given the causes above it; small shares are real but carry little of the "
        "error.</p>\n";
  }
  LookAlikes(html, d);
  PooledParts(html, d);
  AliasGroups(html, d, run.diagnosis_model);
  Residual(html, d);
  CloseSection(html);
}

}  // namespace formloop::app::report
