#include "simulation/model.h"

#include <algorithm>
#include <cmath>
#include <optional>

#include "core/atomic_file.h"
#include "core/json_io.h"
#include "core/number_text.h"

namespace formloop::sim {
namespace {
constexpr const char* kFormat = "formloop-model";
constexpr int kVersion = 1;
}  // namespace

const EffectInstance* Model::Find(std::string_view name) const {
  for (const auto& e : effects) {
    if (e.effect->name() == name) return &e;
  }
  return nullptr;
}

bool Model::Names(std::string_view name) const {
  const EffectInstance* e = Find(name);
  return e != nullptr && e->alias_group.empty();
}

Status Model::Set(std::string_view name, std::vector<double> values, std::vector<double> std_errors) {
  const Effect* effect = FindEffect(name);
  if (effect == nullptr) {
    return Status::BadInput("unknown effect '" + std::string(name) + "'. Fix: use one of " + EffectNames());
  }
  if (static_cast<int>(values.size()) != effect->parameter_count()) {
    return Status::BadInput("effect '" + std::string(name) + "' takes " + std::to_string(effect->parameter_count()) +
                            " parameter(s), got " + std::to_string(values.size()));
  }
  if (std_errors.empty()) std_errors.assign(values.size(), 0.0);
  if (std_errors.size() != values.size()) return Status::Internal("std_errors size mismatch for " + std::string(name));
  for (auto& e : effects) {
    if (e.effect == effect) {
      e.values = std::move(values);
      e.std_errors = std::move(std_errors);
      return Status::Ok();
    }
  }
  effects.push_back({effect, std::move(values), std::move(std_errors), {}});
  return Status::Ok();
}

double Model::SurfaceDeviationUm(const PointContext& c) const {
  double sum = c.scallop_um;
  for (const auto& e : effects) {
    if (e.effect->kind() == EffectKind::kSurface) sum += e.effect->DeviationUm(c, e.values);
  }
  return sum;
}

double Model::DeviationUm(const PointContext& c) const {
  double sum = SurfaceDeviationUm(c);
  for (const auto& e : effects) {
    if (e.effect->kind() == EffectKind::kMeasurement) sum += e.effect->DeviationUm(c, e.values);
  }
  return sum;
}

Model Model::WithoutNoise() const {
  Model m;
  m.provenance = provenance;
  m.alias_groups = alias_groups;
  for (const EffectInstance& e : effects) {
    if (e.effect->name() != "noise") m.effects.push_back(e);
  }
  return m;
}

double Model::surface_sigma_um() const {
  const EffectInstance* n = Find("noise");
  return n == nullptr ? 0.0 : n->values[0];
}
double Model::probe_sigma_um() const {
  const EffectInstance* n = Find("noise");
  return n == nullptr ? 0.0 : n->values[1];
}

nlohmann::json Model::ToJson() const {
  nlohmann::json list = nlohmann::json::array();
  for (const auto& e : effects) {
    nlohmann::json params = nlohmann::json::object(), errors = nlohmann::json::object();
    const auto& spec = e.effect->parameters();
    for (std::size_t k = 0; k < spec.size(); ++k) {
      params[spec[k].name] = e.values[k];
      errors[spec[k].name] = e.std_errors[k];
    }
    nlohmann::json entry = {{"name", std::string(e.effect->name())}, {"parameters", params}, {"std_errors", errors}};
    if (!e.alias_group.empty()) entry["alias_group"] = e.alias_group;
    list.push_back(entry);
  }
  nlohmann::json out = {{"format", kFormat}, {"version", kVersion}, {"effects", list}, {"provenance", provenance}};
  if (!alias_groups.empty()) {
    nlohmann::json groups = nlohmann::json::array();
    for (const auto& g : alias_groups) {
      groups.push_back({{"id", g.id},
                        {"members", g.members},
                        {"note",
                         "the data could not tell these effects apart: the entries of this group carry their "
                         "combined prediction, not estimates of each"}});
    }
    out["alias_groups"] = groups;
  }
  return out;
}

Result<Model> Model::FromJson(const nlohmann::json& json, const std::string& source) {
  auto bad = [&](const std::string& field, const std::string& what, const std::string& fix = "") {
    return Status::BadInput(Where{.file = source, .field = field}, what, fix);
  };
  if (!json.is_object()) return bad("", "a model must be a JSON object", "see simulation/model.h for the format");
  const JsonFields f(json, source);
  std::string format;
  FL_RETURN_IF_ERROR(f.OptionalString("format", &format));
  if (format != kFormat) {
    return bad("format", "expected \"formloop-model\"",
               "write models with formloop or add \"format\": \"formloop-model\"");
  }
  long long version = 0;
  FL_RETURN_IF_ERROR(f.Integer("version", &version, 1));
  if (version > kVersion) {
    return bad("version",
               "model format version " + std::to_string(version) + " is newer than this formloop reads (" +
                   std::to_string(kVersion) + ")",
               "upgrade formloop");
  }
  std::vector<JsonFields> items;
  FL_RETURN_IF_ERROR(f.ObjectArray("effects", &items));
  Model model;
  for (const JsonFields& item : items) {
    std::string name;
    FL_RETURN_IF_ERROR(item.String("name", &name));
    const Effect* effect = FindEffect(name);
    if (effect == nullptr)
      return bad(item.Path("name"), "unknown effect '" + name + "'", "use one of " + EffectNames());
    if (model.Has(name)) return bad(item.Path("name"), "effect '" + name + "' is listed twice");
    const nlohmann::json empty = nlohmann::json::object();
    std::optional<JsonFields> params, errors;
    FL_RETURN_IF_ERROR(item.Object("parameters", &params));
    FL_RETURN_IF_ERROR(item.Object("std_errors", &errors));
    if (!params) params.emplace(empty, source, item.Path("parameters."));
    std::vector<std::string> names;
    std::vector<double> values, ses;
    for (const auto& p : effect->parameters()) {
      names.push_back(p.name);
      if (!params->Has(p.name)) {
        return bad(params->Path(p.name), "missing", "effect '" + name + "' needs it (" + p.doc + ")");
      }
      double value = 0, se = 0;
      FL_RETURN_IF_ERROR(params->Number(p.name, &value));
      // A value a thousand times beyond the effect's typical range is a wrong unit or a typo, and would
      // move the simulated surface by metres.
      const double scale = std::max({std::abs(p.typical_min), std::abs(p.typical_max), 1.0});
      if (std::abs(value) > 1000 * scale) {
        return bad(params->Path(p.name),
                   "is " + FormatSignificant(value, 6) + ", beyond 1000 times the effect's typical range (" +
                       FormatSignificant(p.typical_min, 4) + " .. " + FormatSignificant(p.typical_max, 4) + ")",
                   "check the value and its unit");
      }
      if (errors) FL_RETURN_IF_ERROR(errors->OptionalNumber(p.name, &se, {.min = 0}));
      values.push_back(value);
      ses.push_back(se);
    }
    FL_RETURN_IF_ERROR(params->CheckKnown(names).WithContext("effect '" + name + "'"));
    if (name == "noise" && (values[0] < 0 || values[1] < 0)) return bad(item.Path("parameters"), "sigmas must be >= 0");
    if (name == "thermal_drift_z" && !(values[1] > 0)) return bad(item.Path("parameters.tau_s"), "must be > 0");
    std::string group;
    FL_RETURN_IF_ERROR(item.OptionalString("alias_group", &group));
    if (item.Has("alias_group") && group.empty()) {
      return bad(item.Path("alias_group"), "must be a non-empty string (the id of an entry of alias_groups)");
    }
    model.effects.push_back({effect, std::move(values), std::move(ses), std::move(group)});
  }
  std::vector<JsonFields> groups;
  if (f.Has("alias_groups")) FL_RETURN_IF_ERROR(f.ObjectArray("alias_groups", &groups));
  for (const JsonFields& g : groups) {
    ModelAliasGroup group;
    FL_RETURN_IF_ERROR(g.String("id", &group.id));
    if (group.id.empty()) return bad(g.Path("id"), "must be a non-empty string");
    for (const auto& other : model.alias_groups) {
      if (other.id == group.id) return bad(g.Path("id"), "alias group '" + group.id + "' is listed twice");
    }
    std::vector<std::string> members;
    FL_RETURN_IF_ERROR(g.StringArray("members", &members));
    if (members.size() < 2) return bad(g.Path("members"), "must list at least two effects");
    for (const std::string& member : members) {
      if (FindEffect(member.substr(0, member.find_first_of("@("))) == nullptr) {
        return bad(g.Path("members"), "unknown effect '" + member + "'", "use one of " + EffectNames());
      }
    }
    group.members = std::move(members);
    model.alias_groups.push_back(std::move(group));
  }
  for (const auto& e : model.effects) {
    if (e.alias_group.empty()) continue;
    bool found = false;
    for (const auto& g : model.alias_groups) found = found || g.id == e.alias_group;
    if (!found) {
      return bad("effects", "effect '" + std::string(e.effect->name()) + "' names alias group '" + e.alias_group +
                                "', which alias_groups does not list");
    }
  }
  model.provenance = json.value("provenance", nlohmann::json::object());
  return model;
}

Result<Model> ReadModel(const std::filesystem::path& path) {
  FL_ASSIGN_OR_RETURN(const nlohmann::json json, ReadJsonFile(path));
  return Model::FromJson(json, path.string());
}

Status WriteModel(const std::filesystem::path& path, const Model& model) {
  return WriteFileAtomic(path, model.ToJson().dump(2) + "\n");
}

}  // namespace formloop::sim
