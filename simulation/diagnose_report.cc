// diagnosis.json and the readable summary of a Diagnosis (diagnose.h).

#include <algorithm>
#include <cmath>

#include <fmt/format.h>

#include "simulation/diagnose.h"

namespace formloop::sim {
namespace {

std::string Joined(const std::vector<std::string>& names) {
  std::string out;
  for (const auto& n : names) out += (out.empty() ? "" : ", ") + n;
  return out;
}

}  // namespace

std::string AliasGroup::Message() const {
  std::string out = "one or more of: " + Joined(members) + "; these data cannot tell them apart";
  for (const auto& u : undetermined) out += "; " + u.Text();
  return out;
}

std::string AliasGroup::Undetermined::Text() const {
  std::string names, values;
  for (std::size_t j = 0; j < parameters.size() && j < coefficients.size(); ++j) {
    names += (j == 0 ? "" : " : ") + parameters[j];
    values += (j == 0 ? "" : " : ") + fmt::format("{:.2f}", coefficients[j]);
  }
  return names + " = " + values + " changes nothing these points see";
}

bool Diagnosis::InAliasGroup(std::string_view effect) const {
  for (const auto& g : alias_groups) {
    for (const auto& m : g.members) {
      if (m == effect ||
          (m.size() > effect.size() && m.compare(0, effect.size(), effect) == 0 && m[effect.size()] == '@')) {
        return true;
      }
    }
  }
  return false;
}

nlohmann::json Diagnosis::ToJson() const {
  nlohmann::json causes_json = nlohmann::json::array();
  for (const auto& c : causes) {
    nlohmann::json params = nlohmann::json::object(), errors = nlohmann::json::object(),
                   intervals = nlohmann::json::object();
    for (std::size_t k = 0; k < c.parameter_names.size(); ++k) {
      params[c.parameter_names[k]] = c.parameters[k];
      errors[c.parameter_names[k]] = c.std_errors[k];
      intervals[c.parameter_names[k]] = {c.lower[k], c.upper[k]};
    }
    nlohmann::json aliased = nlohmann::json::array();
    for (std::size_t k = 0; k < c.aliased.size(); ++k) {
      if (c.aliased[k]) aliased.push_back(c.parameter_names[k]);
    }
    nlohmann::json entry = {
        {"effect", c.effect},     {"parameters", params},     {"aliased_parameters", aliased},
        {"std_errors", errors},   {"interval_95", intervals}, {"variance_explained", c.variance_explained},
        {"z_before", c.z_before}, {"z_after", c.z_after}};
    if (!c.part.empty()) entry["part"] = c.part;
    causes_json.push_back(entry);
  }
  nlohmann::json groups_json = nlohmann::json::array();
  for (const auto& g : alias_groups) {
    groups_json.push_back({{"finding", g.Message()},
                           {"members", g.members},
                           {"carried_by", g.in_model},
                           {"variance_explained", g.variance_explained},
                           {"combined_rms_um", g.combined_rms_um},
                           {"design_correlation", g.max_correlation},
                           {"separate_by", g.separate_by},
                           {"undetermined",
                            [&] {
                              nlohmann::json u = nlohmann::json::array();
                              for (const auto& c : g.undetermined) {
                                u.push_back({{"parameters", c.parameters}, {"coefficients", c.coefficients}});
                              }
                              return u;
                            }()}});
  }
  nlohmann::json implausible_json = nlohmann::json::array();
  for (const auto& b : implausible) {
    nlohmann::json params = nlohmann::json::object();
    for (std::size_t k = 0; k < b.parameter_names.size(); ++k) params[b.parameter_names[k]] = b.parameters[k];
    nlohmann::json entry = {{"effect", b.effect},
                            {"fitted", params},
                            {"outside_plausible_range", b.violations},
                            {"finding", "the data fit " + b.effect +
                                            " best with values outside its plausible range "
                                            "(rule diagnose.plausible_ranges): not named, and the diagnosis ran again "
                                            "without it"}};
    if (!b.part.empty()) entry["part"] = b.part;
    implausible_json.push_back(entry);
  }
  nlohmann::json screening_json = nlohmann::json::array();
  for (const auto& step : screening) {
    nlohmann::json rows = nlohmann::json::array();
    for (const auto& s : step) {
      rows.push_back({{"effect", s.effect},
                      {"parameters", s.parameters},
                      {"std_errors", s.std_errors},
                      {"rss_drop_um2", s.rss_drop},
                      {"F", s.f},
                      {"p", s.p_value},
                      {"delta_bic", s.delta_bic},
                      {"share_of_systematic", s.share},
                      {"z_after", s.z_after},
                      {"significant", s.significant}});
    }
    screening_json.push_back(rows);
  }
  nlohmann::json confounded_json = nlohmann::json::array();
  for (const auto& c : confounded) {
    confounded_json.push_back(
        {{"named", c.named}, {"with", c.other}, {"correlation", c.correlation}, {"separate_by", c.separate_by}});
  }
  nlohmann::json unexplained_json = nullptr;
  if (unexplained) {
    unexplained_json = {{"message", "unexplained systematic residual"}, {"z", z_after}, {"where", unexplained_where}};
  }
  nlohmann::json out = {{"format", "formloop-diagnosis"},
                        {"version", 2},
                        {"n", n},
                        {"residual", {{"rms_um", rms_before_um}, {"z", z_before}, {"noise_sigma_um", noise_sigma_um}}},
                        {"explained_by_baseline", explained_by_baseline},
                        {"causes", causes_json},
                        {"alias_groups", groups_json},
                        {"implausible", implausible_json},
                        {"unexplained", unexplained_json},
                        {"confounded", confounded_json},
                        {"not_screened",
                         {{"effects", not_screened},
                          {"reason", not_screened.empty() ? "" : "needs the tool path (give the run folder)"}}},
                        {"gain",
                         {{"rms_before_um", rms_before_um},
                          {"rms_after_um", rms_after_um},
                          {"heldout_rms_before_um", heldout_rms_before_um},
                          {"heldout_rms_after_um", heldout_rms_after_um}}},
                        {"screening", screening_json},
                        {"extended_model", extended.ToJson()}};
  if (parts.size() > 1) out["parts"] = parts;
  if (!direct.empty()) {
    // Only when given: diagnoses without direct measurements keep their schema.
    nlohmann::json list = nlohmann::json::array();
    for (std::size_t k = 0; k < direct.size(); ++k) {
      nlohmann::json entry = direct[k].ToJson();
      const double fitted = k < direct_fitted.size() ? direct_fitted[k] : std::nan("");
      entry["fitted"] = std::isnan(fitted) ? nlohmann::json() : nlohmann::json(fitted);
      list.push_back(entry);
    }
    out["direct_measurements"] = list;
  }
  return out;
}

std::string Diagnosis::Summary() const {
  std::string s = fmt::format("diagnose: {} points{}, residual rms {:.2f} um, Moran z {:.2f}, noise sigma ~{:.2f} um\n",
                              n, parts.size() > 1 ? fmt::format(" of {} parts", parts.size()) : "", rms_before_um,
                              z_before, noise_sigma_um);
  for (std::size_t k = 0; k < direct.size(); ++k) {
    const double fitted = k < direct_fitted.size() ? direct_fitted[k] : std::nan("");
    s += fmt::format("  measured directly{}: {}.{} = {:.4g} +- {:.2g}{}\n",
                     direct[k].by.empty() ? "" : " (" + direct[k].by + ")", direct[k].effect, direct[k].parameter,
                     direct[k].value, direct[k].sigma,
                     std::isnan(fitted) ? std::string("; not named") : fmt::format("; fitted {:.4g}", fitted));
  }
  if (explained_by_baseline) return s + "  the simulation explains the data: no cause named\n";
  for (const auto& c : causes) {
    s += fmt::format("  cause: {} (", c.Label());
    for (std::size_t k = 0; k < c.parameter_names.size(); ++k) {
      if (k < c.aliased.size() && c.aliased[k]) {
        s += fmt::format("{}{}: in an alias group below", k ? ", " : "", c.parameter_names[k]);
        continue;
      }
      s += fmt::format("{}{} = {:.4g} +- {:.2g} [{:.4g}, {:.4g}]", k ? ", " : "", c.parameter_names[k], c.parameters[k],
                       c.std_errors[k], c.lower[k], c.upper[k]);
    }
    s += fmt::format("); explains {:.0f}% of the residual variance; Moran z {:.2f} -> {:.2f}\n",
                     100 * c.variance_explained, c.z_before, c.z_after);
  }
  for (const auto& g : alias_groups) {
    s += fmt::format(
        "  {}: together they explain {:.0f}% of the residual variance (combined rms {:.2f} um, design "
        "correlation {:.3f}); to separate: {}\n",
        g.Message(), 100 * g.variance_explained, g.combined_rms_um, g.max_correlation, g.separate_by);
  }
  for (const auto& b : implausible) {
    s += fmt::format("  not named: {}{} fits best with {} (outside its plausible range)\n", b.effect,
                     b.part.empty() ? "" : "@" + b.part, Joined(b.violations));
  }
  for (const auto& c : confounded) {
    s += fmt::format("  look-alike: {} resembles {} (correlation {:.3f}) but the data separate them\n", c.named,
                     c.other, c.correlation);
  }
  if (unexplained)
    s += fmt::format("  unexplained systematic residual (Moran z {:.2f} after the named causes)\n", z_after);
  s += fmt::format("  gain: rms {:.2f} -> {:.2f} um; held-out (block CV) {:.2f} -> {:.2f} um\n", rms_before_um,
                   rms_after_um, heldout_rms_before_um, heldout_rms_after_um);
  return s;
}

}  // namespace formloop::sim
