#include "simulation/plausible_ranges.h"

#include <cmath>

#include "core/json_io.h"

namespace formloop::sim {

const ParameterRange* PlausibleRanges::Find(const Effect& effect, int parameter) const {
  const std::string key = std::string(effect.name()) + "." + effect.parameters()[parameter].name;
  const auto it = by_parameter.find(key);
  return it == by_parameter.end() ? nullptr : &it->second;
}

Result<PlausibleRanges> PlausibleRanges::FromJson(const nlohmann::json& choice, const std::string& source) {
  if (!choice.is_object()) {
    return Status::BadInput(Where{.file = source, .field = kPlausibleRangesRule}, "the choice must be an object",
                            "give {\"<effect>.<parameter>\": [min, max], ...}");
  }
  PlausibleRanges out;
  for (const auto& [key, value] : choice.items()) {
    const Where where{.file = source, .field = std::string(kPlausibleRangesRule) + "." + key};
    const auto dot = key.find('.');
    const Effect* effect = dot == std::string::npos ? nullptr : FindEffect(key.substr(0, dot));
    int parameter = -1;
    if (effect != nullptr) {
      for (int k = 0; k < effect->parameter_count(); ++k) {
        if (effect->parameters()[k].name == key.substr(dot + 1)) parameter = k;
      }
    }
    if (parameter < 0) {
      return Status::BadInput(where, "names no parameter of the effect catalogue",
                              "use <effect>.<parameter>, e.g. thermal_drift_z.tau_s (effects: " + EffectNames() + ")");
    }
    if (!value.is_array() || value.size() != 2 || !value[0].is_number() || !value[1].is_number()) {
      return Status::BadInput(where, "must be [min, max]", "give two numbers in the parameter's unit");
    }
    const ParameterRange r{value[0].get<double>(), value[1].get<double>()};
    if (!std::isfinite(r.min) || !std::isfinite(r.max) || !(r.min < r.max)) {
      return Status::BadInput(where, "needs finite min < max");
    }
    if (!effect->parameters()[parameter].linear && !(r.min > 0)) {
      return Status::BadInput(where, "a nonlinear parameter (a time constant) needs min > 0");
    }
    out.by_parameter[key] = r;
  }
  return out;
}

nlohmann::json PlausibleRanges::ToJson() const {
  nlohmann::json j = nlohmann::json::object();
  for (const auto& [key, r] : by_parameter) j[key] = {r.min, r.max};
  return j;
}

Result<PlausibleRanges> ReadPlausibleRanges(const std::string& rules_path) {
  FL_ASSIGN_OR_RETURN(const Json rules, ReadJsonFile(rules_path));
  const Json& list = rules.is_object() && rules.contains("rules") ? rules["rules"] : rules;
  if (list.is_array()) {
    for (const auto& rule : list) {
      if (rule.is_object() && rule.value("name", "") == kPlausibleRangesRule && rule.contains("choice")) {
        return PlausibleRanges::FromJson(rule["choice"], rules_path);
      }
    }
  }
  return Status::BadInput(Where{.file = rules_path}, std::string("has no rule '") + kPlausibleRangesRule + "'",
                          "add it (data/starter/rules.json has the starter ranges)");
}

}  // namespace formloop::sim
