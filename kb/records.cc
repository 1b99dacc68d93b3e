// The case library's values without the database (kb/library.h): the case record and its checks, the
// case file, the rule base (parse, problems, thresholds) and the reports' JSON. library.cc holds the
// Library over them (on SQLite or PostgreSQL).

#include <algorithm>
#include <filesystem>
#include <optional>
#include <set>
#include <sstream>
#include <string>
#include <vector>

#include "core/json_io.h"
#include "kb/library.h"

namespace formloop::kb {
namespace {

using nlohmann::json;

Status FieldError(const Where& source, const std::string& field, const std::string& what, const std::string& fix = "") {
  Where where = source;
  where.field = field;
  return Status::BadInput(where, what, fix);
}

bool ValidUid(const std::string& uid) {
  if (uid.empty() || uid.size() > 128) return false;
  return std::all_of(uid.begin(), uid.end(), [](char c) {
    return (c >= 'a' && c <= 'z') || (c >= 'A' && c <= 'Z') || (c >= '0' && c <= '9') || c == '.' || c == '_' ||
           c == ':' || c == '-';
  });
}

bool ValidFacet(const std::string& facet) {
  if (facet.empty() || facet.size() > 64) return false;
  return std::all_of(facet.begin(), facet.end(), [](char c) { return (c >= 'a' && c <= 'z') || c == '_'; });
}

Status NonEmptyString(const JsonFields& f, const std::string& key, std::string* out) {
  FL_RETURN_IF_ERROR(f.String(key, out));
  if (out->empty()) {
    return Status::BadInput(Where{.file = f.source(), .field = f.Path(key)}, "must be a non-empty string");
  }
  return Status::Ok();
}

// The three knowledge parts are free-form JSON; what formloop itself reads from them is checked here.
constexpr NumberRange kPositive{.min = 0, .exclusive_min = true};

Status ValidatePart(const JsonFields& part) {
  double number = 0;
  long long integer = 0;
  std::string text;
  FL_RETURN_IF_ERROR(part.OptionalNumber("tolerance_mm", &number, kPositive));
  FL_RETURN_IF_ERROR(part.OptionalNumber("finish_ra_um", &number, kPositive));
  FL_RETURN_IF_ERROR(part.OptionalInteger("batch_size", &integer, 1));
  return part.OptionalString("material", &text);
}

Status ValidateSimulation(const JsonFields& sim) {
  if (!sim.Has("effect_models")) return Status::Ok();
  std::vector<JsonFields> models;
  FL_RETURN_IF_ERROR(sim.ObjectArray("effect_models", &models));
  for (const JsonFields& model : models) {
    if (!model.Has("effects")) continue;
    std::vector<JsonFields> effects;
    FL_RETURN_IF_ERROR(model.ObjectArray("effects", &effects));
    for (const JsonFields& effect : effects) {
      std::string name;
      double number = 0;
      FL_RETURN_IF_ERROR(NonEmptyString(effect, "name", &name));
      FL_RETURN_IF_ERROR(effect.Number("estimate", &number));
      FL_RETURN_IF_ERROR(effect.Number("standard_error", &number, {.min = 0}));
    }
  }
  return Status::Ok();
}

Status ValidateManufacturing(const JsonFields& mfg) {
  if (mfg.Has("tools")) {
    std::vector<JsonFields> tools;
    FL_RETURN_IF_ERROR(mfg.ObjectArray("tools", &tools));
    double radius = 0;
    for (const JsonFields& tool : tools) FL_RETURN_IF_ERROR(tool.OptionalNumber("radius_mm", &radius, kPositive));
  }
  std::optional<JsonFields> part;
  for (const char* key : {"strategy", "reconstruction"}) FL_RETURN_IF_ERROR(mfg.Object(key, &part));
  std::optional<JsonFields> compensation;
  FL_RETURN_IF_ERROR(mfg.Object("compensation", &compensation));
  if (compensation && compensation->Has("loops")) {
    std::vector<JsonFields> loops;
    FL_RETURN_IF_ERROR(compensation->ObjectArray("loops", &loops));
  }
  return Status::Ok();
}

}  // namespace

const std::vector<std::string>& KnownFacets() {
  static const std::vector<std::string> kFacets = {"shape", "material", "tolerance", "finish", "machine_tool"};
  return kFacets;
}

// ---------------------------------------------------------------------------------------------- CaseRecord

json CaseRecord::ToJson() const {
  json j = {{"uid", uid},
            {"name", name},
            {"family", family},
            {"part", part},
            {"simulation", simulation},
            {"manufacturing", manufacturing}};
  if (descriptor) j["descriptor"] = *descriptor;
  if (!concepts.empty()) j["concepts"] = concepts;
  if (!created_at.empty()) j["created_at"] = created_at;
  if (!updated_at.empty()) j["updated_at"] = updated_at;
  return j;
}

Result<CaseRecord> CaseRecord::FromJson(const json& j, const Where& source) {
  if (!j.is_object()) return Status::BadInput(source, "a case must be a JSON object", "see kb/library.h");
  // The source as messages name it ("cases.jsonl:3" for a line of an export file).
  const JsonFields f(j, source.line > 0 ? source.file + ":" + std::to_string(source.line) : source.file);
  FL_RETURN_IF_ERROR(f.CheckKnown({"uid", "name", "family", "part", "simulation", "manufacturing", "descriptor",
                                   "concepts", "created_at", "updated_at"}));
  CaseRecord r;
  FL_RETURN_IF_ERROR(NonEmptyString(f, "uid", &r.uid));
  if (!ValidUid(r.uid)) {
    return FieldError(source, "uid", "'" + r.uid + "' is not a valid uid",
                      "use 1-128 characters from A-Z a-z 0-9 . _ : -");
  }
  FL_RETURN_IF_ERROR(NonEmptyString(f, "name", &r.name));
  FL_RETURN_IF_ERROR(NonEmptyString(f, "family", &r.family));
  std::optional<JsonFields> part, simulation, manufacturing;
  FL_RETURN_IF_ERROR(f.RequiredObject("part", &part));
  FL_RETURN_IF_ERROR(f.RequiredObject("simulation", &simulation));
  FL_RETURN_IF_ERROR(f.RequiredObject("manufacturing", &manufacturing));
  FL_RETURN_IF_ERROR(ValidatePart(*part));
  FL_RETURN_IF_ERROR(ValidateSimulation(*simulation));
  FL_RETURN_IF_ERROR(ValidateManufacturing(*manufacturing));
  r.part = part->json();
  r.simulation = simulation->json();
  r.manufacturing = manufacturing->json();
  if (f.Has("descriptor") && !j["descriptor"].is_null()) {
    std::vector<double> values;
    FL_RETURN_IF_ERROR(f.NumberArray("descriptor", &values));
    if (values.empty()) return FieldError(source, "descriptor", "must be a non-empty array of numbers");
    r.descriptor = std::move(values);
  }
  std::optional<JsonFields> concepts;
  FL_RETURN_IF_ERROR(f.Object("concepts", &concepts));
  if (concepts) {
    for (const auto& [facet, concept_value] : concepts->json().items()) {
      if (!ValidFacet(facet)) {
        return FieldError(source, "concepts." + facet, "facet names are lowercase letters and '_'",
                          "known facets: shape, material, tolerance, finish, machine_tool");
      }
      FL_RETURN_IF_ERROR(NonEmptyString(*concepts, facet, &r.concepts[facet]));
    }
  }
  FL_RETURN_IF_ERROR(f.OptionalString("created_at", &r.created_at));
  FL_RETURN_IF_ERROR(f.OptionalString("updated_at", &r.updated_at));
  return r;
}

Result<CaseRecord> ReadCaseFile(const std::filesystem::path& path) {
  FL_ASSIGN_OR_RETURN(json j, ReadJsonFile(path));
  // The messages name the case too, when its uid can be read.
  const bool has_uid = j.is_object() && j.contains("uid") && j["uid"].is_string();
  return CaseRecord::FromJson(
      j, Where{.file = path.string() + (has_uid ? " (case '" + j["uid"].get<std::string>() + "')" : "")});
}

// ---------------------------------------------------------------------------------------------- rules

json Rule::ToJson() const {
  return {{"version", version}, {"name", name}, {"condition", condition}, {"choice", choice}, {"active", active}};
}

json RuleSet::ToJson() const {
  json rules_json = json::array();
  for (const Rule& r : rules)
    rules_json.push_back({{"name", r.name}, {"condition", r.condition}, {"choice", r.choice}});
  return {{"version", version}, {"rules", rules_json}};
}

const Rule* RuleSet::Find(const std::string& name) const {
  for (const Rule& r : rules) {
    if (r.name == name) return &r;
  }
  return nullptr;
}

namespace {

const Rule* FindRule(const std::vector<Rule>& rules, const std::string& name) {
  for (const Rule& r : rules) {
    if (r.name == name) return &r;
  }
  return nullptr;
}

std::optional<double> Bound(const Rule* rule, const char* op) {
  if (rule == nullptr || !rule->condition.contains("similarity")) return std::nullopt;
  const json& s = rule->condition["similarity"];
  if (!s.is_object()) return std::nullopt;
  double bound = 0;
  if (!JsonFields(s, "rule " + rule->name, "similarity.").Number(op, &bound).ok()) return std::nullopt;
  return bound;
}

}  // namespace

std::vector<std::string> RuleSetProblems(const std::vector<Rule>& rules) {
  std::vector<std::string> problems;
  const Rule* direct = FindRule(rules, "route.direct");
  const Rule* simulate = FindRule(rules, "route.simulate");
  const Rule* fallback = FindRule(rules, "route.default");
  if (direct == nullptr) problems.push_back("rule 'route.direct' is missing");
  if (simulate == nullptr) problems.push_back("rule 'route.simulate' is missing");
  if (fallback == nullptr) problems.push_back("rule 'route.default' is missing");
  const auto high = Bound(direct, "gt");
  const auto low = Bound(simulate, "ge");
  const auto sim_high = Bound(simulate, "le");
  const auto default_low = Bound(fallback, "lt");
  if (direct != nullptr && !high)
    problems.push_back("rule 'route.direct' needs condition {\"similarity\": {\"gt\": high}}");
  if (simulate != nullptr && (!low || !sim_high)) {
    problems.push_back("rule 'route.simulate' needs condition {\"similarity\": {\"ge\": low, \"le\": high}}");
  }
  if (fallback != nullptr && !default_low) {
    problems.push_back("rule 'route.default' needs condition {\"similarity\": {\"lt\": low}}");
  }
  if (high && low) {
    if (!(*low > 0 && *low < *high && *high <= 1)) {
      std::ostringstream out;
      out << "route thresholds must satisfy 0 < low < high <= 1 (low " << *low << ", high " << *high << ")";
      problems.push_back(out.str());
    }
    if (sim_high && *sim_high != *high) problems.push_back("route.simulate 'le' differs from route.direct 'gt'");
    if (default_low && *default_low != *low) problems.push_back("route.default 'lt' differs from route.simulate 'ge'");
  }
  const Rule* weights = FindRule(rules, "facet.weights");
  if (weights == nullptr) {
    problems.push_back("rule 'facet.weights' is missing");
  } else {
    double sum = 0;
    const JsonFields fields(weights->choice, "rule facet.weights");
    for (const auto& item : weights->choice.items()) {
      double w = 0;
      if (!fields.Number(item.key(), &w, {.min = 0}).ok()) {
        problems.push_back("facet weight '" + item.key() + "' must be a number >= 0");
      } else {
        sum += w;
      }
    }
    if (!(sum > 0)) problems.push_back("facet weights must have a positive sum");
  }
  return problems;
}

Result<RouteThresholds> ThresholdsOf(const std::vector<Rule>& rules) {
  const auto problems = RuleSetProblems(rules);
  if (!problems.empty()) return Status::BadInput("rule base: " + problems.front());
  RouteThresholds t;
  t.high = *Bound(FindRule(rules, "route.direct"), "gt");
  t.low = *Bound(FindRule(rules, "route.simulate"), "ge");
  return t;
}

// ---------------------------------------------------------------------------------------------- reports

json GhsomStatus::ToJson() const {
  json j = {{"present", present}};
  if (present) {
    j["id"] = id;
    j["created_at"] = created_at;
    j["case_count"] = case_count;
    j["trained_at_changes"] = trained_at_changes;
    j["current_changes"] = current_changes;
    j["stale"] = stale;
  }
  return j;
}

json LibraryStats::ToJson() const {
  return {{"schema_version", schema_version},
          {"cases", cases},
          {"cases_with_descriptor", cases_with_descriptor},
          {"per_family", per_family},
          {"per_facet_concept", per_facet_concept},
          {"rules_version", rules_version},
          {"case_changes", case_changes},
          {"ghsom", ghsom.ToJson()}};
}

json CheckReport::ToJson() const {
  return {{"clean", clean()},
          {"integrity", integrity},
          {"foreign_key_violations", foreign_key_violations},
          {"orphan_concepts", orphan_concepts},
          {"cases_missing_descriptor", cases_missing_descriptor},
          {"rule_problems", rule_problems},
          {"ghsom", ghsom.ToJson()},
          {"problems", problems},
          {"warnings", warnings}};
}

json ImportReport::ToJson() const {
  json j = {{"cases_added", cases_added},
            {"cases_replaced", cases_replaced},
            {"rules", rules},
            {"taxonomy_nodes", taxonomy_nodes}};
  if (part_records > 0) j["part_records"] = part_records;
  return j;
}

// ---------------------------------------------------------------------------------------------- rule base input

Result<std::vector<Rule>> ParseRules(const json& input, const std::string& source) {
  const json* list = &input;
  if (input.is_object()) {
    if (!input.contains("rules")) return Status::BadInput(Where{.file = source, .field = "rules"}, "missing");
    list = &input["rules"];
  }
  const json wrapper = {{"rules", *list}};
  std::vector<JsonFields> items;
  FL_RETURN_IF_ERROR(JsonFields(wrapper, source).ObjectArray("rules", &items));
  std::vector<Rule> rules;
  std::set<std::string> names;
  for (const JsonFields& r : items) {
    Rule rule;
    FL_RETURN_IF_ERROR(NonEmptyString(r, "name", &rule.name));
    if (!names.insert(rule.name).second) {
      return Status::BadInput(Where{.file = source, .field = r.Path("name")}, "'" + rule.name + "' appears twice");
    }
    std::optional<JsonFields> condition, choice;
    FL_RETURN_IF_ERROR(r.RequiredObject("condition", &condition));
    FL_RETURN_IF_ERROR(r.RequiredObject("choice", &choice));
    rule.condition = condition->json();
    rule.choice = choice->json();
    rule.active = true;
    rules.push_back(std::move(rule));
  }
  return rules;
}
}  // namespace formloop::kb
