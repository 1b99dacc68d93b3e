#pragma once
// Physically plausible ranges of effect parameters (spec/simulation.md §5, issue 20): a fitted value
// outside its range is not named as a cause — the diagnosis says which value the data asked for and
// why it is not believed (a 9-hour thermal time constant, a tool that grows as it cuts). The ranges are
// data in the rule base: the rule "diagnose.plausible_ranges" of data/starter/rules.json (and of a case
// library's active rule set), its choice an object
//
//   {"thermal_drift_z.tau_s": [60, 14400], "tool_wear.k_w_um_per_m": [0, 50], ...}
//
// keyed "<effect>.<parameter>" as in the catalogue (effects.h). A parameter without an entry is not
// limited. Nonlinear parameters (τ) are also searched only inside their range.

#include <map>
#include <string>
#include <string_view>

#include <nlohmann/json.hpp>

#include "core/status.h"
#include "simulation/effects.h"

namespace formloop::sim {

inline constexpr const char* kPlausibleRangesRule = "diagnose.plausible_ranges";

struct ParameterRange {
  double min = 0, max = 0;
  bool Contains(double value) const { return value >= min && value <= max; }
};

struct PlausibleRanges {
  std::map<std::string, ParameterRange, std::less<>> by_parameter;  // "<effect>.<parameter>"
  // nullptr when the parameter is not limited.
  const ParameterRange* Find(const Effect& effect, int parameter) const;
  // The rule's choice object; `source` names it in messages (file and rule). Every key must name a
  // catalogue parameter and every value be [min, max] with min < max, finite.
  static Result<PlausibleRanges> FromJson(const nlohmann::json& choice, const std::string& source);
  nlohmann::json ToJson() const;
};

// The rule "diagnose.plausible_ranges" of a rules file ({"rules": [...]} as data/starter/rules.json).
Result<PlausibleRanges> ReadPlausibleRanges(const std::string& rules_path);

}  // namespace formloop::sim
