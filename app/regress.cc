#include "app/regress.h"

#include <algorithm>
#include <cmath>

#include <fmt/format.h>

#include "app/kb_jobs.h"
#include "app/machine_profile.h"
#include "core/atomic_file.h"
#include "core/json_io.h"
#include "core/log.h"
#include "core/output_folder.h"
#include "core/progress.h"
#include "retrieval/starter.h"

namespace formloop::app {
namespace fs = std::filesystem;
using nlohmann::json;

namespace {

std::vector<std::string> DefectKinds(const json& list) {
  std::vector<std::string> kinds;
  if (!list.is_array()) return kinds;
  for (const auto& d : list) kinds.push_back(d.value("kind", "?"));
  std::sort(kinds.begin(), kinds.end());
  return kinds;
}

bool Within(double value, double golden, const FigureTolerance& t) {
  return std::abs(value - golden) <= t.abs + t.rel * std::abs(golden);
}

const FigureTolerance* ToleranceOf(const std::string& figure) {
  for (const auto& [name, t] : FigureTolerances()) {
    if (name == figure) return &t;
  }
  return nullptr;
}

}  // namespace

const std::vector<std::pair<std::string, FigureTolerance>>& FigureTolerances() {
  // Same inputs give the same figures bit for bit; these bands are for deliberate changes elsewhere
  // (a library upgrade, a better fit) that should not fail the regression, while a real change of
  // behaviour (another route, a cause lost, a form error 10 % worse) does.
  static const std::vector<std::pair<std::string, FigureTolerance>> t = {
      {"similarity", {.abs = 0.002}},
      {"fit_rms_um", {.abs = 0.05, .rel = 0.2}},
      {"fit_check_max_um", {.abs = 0.05, .rel = 0.2}},
      {"scallop_um", {.abs = 0.05}},
      {"raw_moran_z", {.abs = 0.5, .rel = 0.1}},
      {"form_error_um", {.abs = 0.5, .rel = 0.1}},
  };
  return t;
}

Result<json> KeyFigures(const fs::path& run_dir) {
  FL_ASSIGN_OR_RETURN(Json summary, ReadJsonFile(run_dir / "summary.json"));
  FL_ASSIGN_OR_RETURN(Json plan, ReadJsonFile(run_dir / "plan.json"));
  FL_ASSIGN_OR_RETURN(Json surface, ReadJsonFile(run_dir / "surface" / "surface.json"));
  json errors = json::array();
  for (const auto& l : summary["loops"]) errors.push_back(l["form_error_um"]);
  json f = {{"route", summary["route"]["name"]},
            {"similarity", summary["route"]["similarity"]},
            {"case_uid", summary["route"]["case_uid"]},
            {"fit_rms_um", surface["fit"]["rms_mm"].get<double>() * 1e3},
            {"fit_check_max_um", summary["fit_check_max_um"]},
            {"scallop_um", plan["toolpath"]["scallop_um"]},
            {"tool_radius_mm", plan["toolpath"]["tool_radius_mm"]},
            {"raw_moran_z", summary["loops"][0]["raw_moran_z"]},
            {"causes", summary["causes"]},
            {"form_error_um", errors},
            {"loops_to_tolerance", summary["loops_to_tolerance"]},
            {"within_tolerance", summary["within_tolerance"]},
            {"precompensated", summary["precompensated"]}};
  std::error_code ec;
  if (fs::exists(run_dir / "sim_correction.json", ec)) {
    FL_ASSIGN_OR_RETURN(Json sc, ReadJsonFile(run_dir / "sim_correction.json"));
    f["sim_correction"] = {{"corrected", sc.value("corrected", false)},
                           {"defects_before", DefectKinds(sc.value("defects_before", json::array()))},
                           {"defects_after", DefectKinds(sc.value("defects_after", json::array()))}};
  } else {
    f["sim_correction"] = nullptr;
  }
  return f;
}

std::vector<FigureDifference> CompareFigures(const json& golden, const json& value) {
  std::vector<FigureDifference> out;
  for (const auto& [name, g] : golden.items()) {
    const json v = value.contains(name) ? value[name] : json();
    const FigureTolerance* t = ToleranceOf(name);
    bool same = false;
    std::string allowed = "exact";
    if (t != nullptr) {
      allowed = fmt::format("±({:g} + {:g}·|golden|)", t->abs, t->rel);
      if (g.is_number() && v.is_number()) {
        same = Within(v.get<double>(), g.get<double>(), *t);
      } else if (g.is_array() && v.is_array() && g.size() == v.size()) {
        same = true;
        for (std::size_t k = 0; k < g.size(); ++k) {
          same = same && g[k].is_number() && v[k].is_number() && Within(v[k].get<double>(), g[k].get<double>(), *t);
        }
      } else {
        same = g == v;
      }
    } else {
      same = g == v;
    }
    if (!same) out.push_back({name, g, v, allowed});
  }
  return out;
}

Result<json> TruthCheck(const fs::path& run_dir, const sim::Model& truth) {
  FL_ASSIGN_OR_RETURN(Json d, ReadJsonFile(run_dir / "loop-0" / "diagnosis" / "diagnosis.json"));
  auto effect_of = [](const std::string& label) { return label.substr(0, label.find_first_of("@(")); };
  std::vector<std::string> baseline;
  if (d.contains("baseline_model") && d["baseline_model"].is_object()) {
    for (const auto& e : d["baseline_model"].value("effects", json::array())) baseline.push_back(e.value("name", ""));
  }
  std::vector<std::string> grouped;
  json groups = json::array();
  for (const auto& g : d.value("alias_groups", json::array())) {
    groups.push_back(g.value("members", json::array()));
    for (const auto& m : g.value("members", json::array())) grouped.push_back(effect_of(m.get<std::string>()));
  }
  json named = json::array(), not_in_profile = json::array(), outside = json::array();
  int parameters = 0;
  std::vector<std::string> named_effects;
  for (const auto& c : d.value("causes", json::array())) {
    const std::string effect = c.value("effect", "");
    named.push_back(effect);
    named_effects.push_back(effect);
    const sim::EffectInstance* t = truth.Find(effect);
    if (t == nullptr) {
      not_in_profile.push_back(effect);
      continue;
    }
    const auto& spec = t->effect->parameters();
    for (std::size_t k = 0; k < spec.size(); ++k) {
      const json& interval = c["interval_95"][spec[k].name];
      if (!interval.is_array() || !interval[0].is_number() || !interval[1].is_number()) continue;  // aliased
      ++parameters;
      const double lo = interval[0].get<double>(), hi = interval[1].get<double>();
      if (t->values[k] < lo || t->values[k] > hi) {
        outside.push_back(
            {{"effect", effect}, {"parameter", spec[k].name}, {"truth", t->values[k]}, {"interval", {lo, hi}}});
      }
    }
  }
  json true_effects = json::array(), missed = json::array();
  for (const auto& e : truth.effects) {
    if (e.effect->kind() == sim::EffectKind::kNoise) continue;
    const std::string name(e.effect->name());
    true_effects.push_back(name);
    const bool found = std::count(named_effects.begin(), named_effects.end(), name) +
                           std::count(grouped.begin(), grouped.end(), name) +
                           std::count(baseline.begin(), baseline.end(), name) >
                       0;
    if (!found) missed.push_back(name);
  }
  return json{{"true_effects", true_effects},
              {"baseline", baseline},
              {"named", named},
              {"alias_groups", groups},
              {"named_not_in_profile", not_in_profile},
              {"true_missed", missed},
              {"parameters", parameters},
              {"parameters_outside", outside}};
}

json RegressResult::ToJson() const {
  return {{"parts", table},
          {"regressions", regressions},
          {"within_tolerance_after_at_most_one_compensation", within_one_loop},
          {"count", parts},
          {"truth",
           {{"named_not_in_profile", named_not_in_profile},
            {"true_effects", true_effects},
            {"true_missed", true_missed},
            {"parameters", parameters},
            {"parameters_outside", parameters_outside}}}};
}

Result<RegressResult> RunRegress(const RegressOptions& options) {
  const fs::path data_dir = options.data_dir.empty() ? retrieval::DefaultDataDir() : options.data_dir;
  std::vector<fs::path> files;
  std::error_code ec;
  for (const auto& entry : fs::directory_iterator(options.parts, ec)) {
    if (entry.path().extension() == ".json") files.push_back(entry.path());
  }
  if (ec)
    return Status::BadInput(Where{.file = options.parts.string()}, "cannot list the reference parts: " + ec.message());
  std::sort(files.begin(), files.end());
  if (files.empty()) return Status::BadInput(Where{.file = options.parts.string()}, "no reference parts (*.json)");

  for (const std::string& name : options.only) {
    const bool known = std::any_of(files.begin(), files.end(), [&](const fs::path& f) { return f.stem() == name; });
    if (!known) {
      return Status::BadInput(Where{.file = options.parts.string(), .field = "--only"},
                              "no reference part '" + name + "'",
                              "name parts as their files are named (without .json)");
    }
  }
  // A fresh starter library: the regression must not depend on what earlier runs stored. The old folder
  // goes only when formloop wrote it and it holds neither the parts, the goldens nor the data.
  const std::vector<NamedPath> inputs = {
      {"--parts", options.parts}, {"--goldens", options.goldens}, {"data folder", data_dir}};
  FL_RETURN_IF_ERROR(CheckOutputsNotInputs({}, inputs, {{"--out", options.out}}));
  FL_RETURN_IF_ERROR(OutputFolder::Remove(options.out, "--out", inputs));
  FL_RETURN_IF_ERROR(OutputFolder::Create(options.out, "--out", "regress"));
  const fs::path kb = options.out / "kb.sqlite";
  FL_RETURN_IF_ERROR(CreateStarterLibrary(kb.string(), data_dir).status());
  if (options.update) FL_RETURN_IF_ERROR(MakeDirectories(options.goldens));

  RegressResult result;
  Progress progress("regress", files.size());
  for (const fs::path& file : files) {
    FL_ASSIGN_OR_RETURN(PartSpec part, ReadPart(file));
    if (!options.only.empty() && std::find(options.only.begin(), options.only.end(), part.name) == options.only.end()) {
      progress.Advance();
      continue;
    }
    ++result.parts;
    RunOptions run;
    run.out = options.out / part.name;
    run.force = true;
    run.part_source = file.string();
    run.kb = kb.string();
    run.machine = "virtual";
    run.data_dir = data_dir;
    json row = {{"part", part.name}};
    auto summary = RunPart(part, run);
    if (!summary.ok()) {
      row["status"] = "FAILED";
      row["error"] = summary.status().ToString();
      ++result.regressions;
      result.table.push_back(row);
      progress.Advance();
      continue;
    }
    FL_ASSIGN_OR_RETURN(json figures, KeyFigures(run.out));
    row["figures"] = figures;
    // The truth line: the named causes against the virtual machine's profile (never a golden figure).
    if (auto profile = ReadMachineProfile(part.machine_name, data_dir); profile.ok()) {
      if (auto truth = TruthCheck(run.out, profile->model); truth.ok()) {
        row["truth"] = *truth;
        result.named_not_in_profile += static_cast<int>((*truth)["named_not_in_profile"].size());
        result.true_effects += static_cast<int>((*truth)["true_effects"].size());
        result.true_missed += static_cast<int>((*truth)["true_missed"].size());
        result.parameters += (*truth)["parameters"].get<int>();
        result.parameters_outside += static_cast<int>((*truth)["parameters_outside"].size());
      } else {
        row["truth"] = {{"error", truth.status().ToString()}};
      }
    }
    const int to_tolerance = summary->LoopsToTolerance();
    if (to_tolerance >= 0 && to_tolerance <= 1) ++result.within_one_loop;
    const fs::path golden_path = options.goldens / (part.name + ".json");
    json golden;
    if (fs::exists(golden_path, ec)) {
      FL_ASSIGN_OR_RETURN(Json g, ReadJsonFile(golden_path));
      golden = g.value("figures", json::object());
    }
    const auto differences = golden.is_null() ? std::vector<FigureDifference>{} : CompareFigures(golden, figures);
    json diff_json = json::array();
    for (const auto& d : differences) {
      diff_json.push_back({{"figure", d.figure}, {"golden", d.golden}, {"value", d.value}, {"allowed", d.allowed}});
    }
    row["differences"] = diff_json;
    if (options.update) {
      // What --update changes: every figure that differs from the old golden at all.
      json changes = json::array();
      for (const auto& [name, v] : figures.items()) {
        const json g = golden.is_object() && golden.contains(name) ? golden[name] : json();
        if (g != v) changes.push_back({{"figure", name}, {"golden", g}, {"value", v}});
      }
      row["changes"] = changes;
      const bool changed = golden.is_null() || golden != figures;
      row["status"] = golden.is_null() ? "golden created" : (changed ? "golden updated" : "golden unchanged");
      if (changed) {
        FL_RETURN_IF_ERROR(WriteJsonFile(golden_path, {{"part", part.name}, {"figures", figures}}));
      }
    } else if (golden.is_null()) {
      row["status"] = "NO GOLDEN";
      ++result.regressions;
    } else {
      row["status"] = differences.empty() ? "pass" : "REGRESSION";
      if (!differences.empty()) ++result.regressions;
    }
    result.table.push_back(row);
    progress.Advance();
  }
  progress.Finish();
  return result;
}

}  // namespace formloop::app
