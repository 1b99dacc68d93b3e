#include "planning/cutting_optimisation.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <numbers>

#include "core/json_io.h"
#include "core/point_io.h"

namespace formloop::planning {
namespace {

struct Decoded {
  double f_z = 0, n = 0, fitness = 0;
  bool feasible = false;
};

Decoded DecodeGenes(const CuttingCase& c, double q_bar, double xi_n, double xi_f) {
  Decoded d;
  d.n = c.n_min_rpm * std::pow(c.n_max_rpm / c.n_min_rpm, xi_n);
  const double cap = CuttingFeedCap(c, d.n);
  if (cap < c.f_z_min_mm) {
    d.f_z = c.f_z_min_mm;
    d.fitness = -(c.f_z_min_mm / cap - 1);
    return d;
  }
  d.f_z = c.f_z_min_mm * std::pow(cap / c.f_z_min_mm, xi_f);
  d.fitness = c.a_e_mm * c.a_p_mm * d.f_z * c.flutes * d.n / q_bar;
  d.feasible = true;
  return d;
}

// Membership of L, M, H on [0, 1].
std::array<double, 3> Lmh(double x) {
  x = std::clamp(x, 0.0, 1.0);
  return {std::max(0.0, 1 - x / 0.5), std::max(0.0, 1 - std::abs(x - 0.5) / 0.5), std::max(0.0, (x - 0.5) / 0.5)};
}

bool SameText(const std::string& a, const std::string& b) {
  if (a.size() != b.size()) return false;
  for (std::size_t i = 0; i < a.size(); ++i) {
    if (std::tolower(static_cast<unsigned char>(a[i])) != std::tolower(static_cast<unsigned char>(b[i]))) return false;
  }
  return true;
}

}  // namespace

AgaOptions CuttingGaDefaults() { return AgaOptions{.population = 40, .generations = 100, .elites = 2}; }

Result<CuttingOptimum> CuttingOptimumGa(const CuttingCase& c, std::uint64_t seed, const AgaOptions& options) {
  FL_RETURN_IF_ERROR(c.Validate());
  FL_RETURN_IF_ERROR(options.Validate());
  const double q_bar = c.a_e_mm * c.a_p_mm * c.flutes * c.f_z_max_mm * c.n_max_rpm;
  const AgaObjective objective = [&](const std::vector<double>& xi) {
    const Decoded d = DecodeGenes(c, q_bar, xi[0], xi[1]);
    // Ties on Q go to the longer tool life.
    return AgaScore{d.fitness, d.feasible ? EvaluateCutting(c, d.f_z, d.n).tool_life_min : 0.0};
  };
  const AgaResult run = RunAga(2, objective, options, seed);
  const Decoded best = DecodeGenes(c, q_bar, run.genes[0], run.genes[1]);
  if (!best.feasible) return InfeasibleStatus(c);
  CuttingOptimum out;
  out.method = "ga";
  out.state = EvaluateCutting(c, best.f_z, best.n);
  out.active = ActiveConstraints(c, out.state);
  out.generations = run.generations;
  return out;
}

nlohmann::json CuttingDataRecord::ToJson() const {
  return {{"tool_family", tool_family},
          {"grade", grade},
          {"material", material},
          {"iso_group", iso_group},
          {"operation", operation},
          {"d_min_mm", d_min_mm},
          {"d_max_mm", d_max_mm},
          {"hardness_hb", hardness_hb},
          {"v_c_nom_m_per_min", v_c_nom_m_per_min},
          {"f_z_nom_mm", f_z_nom_mm},
          {"a_p_max_mm", a_p_max_mm},
          {"a_e_max_mm", a_e_max_mm},
          {"source", source}};
}

Result<std::vector<CuttingDataRecord>> CuttingDataFromJson(const nlohmann::json& array, const std::string& source) {
  if (!array.is_array()) {
    return Status::BadInput(Where{.file = source}, "cutting data must be a JSON array of records");
  }
  std::vector<CuttingDataRecord> out;
  const NumberRange positive{.min = 0, .exclusive_min = true};
  for (std::size_t i = 0; i < array.size(); ++i) {
    const std::string prefix = "[" + std::to_string(i) + "].";
    if (!array[i].is_object()) {
      return Status::BadInput(Where{.file = source, .field = prefix}, "each record must be a JSON object");
    }
    JsonFields f(array[i], source, prefix);
    FL_RETURN_IF_ERROR(
        f.CheckKnown({"tool_family", "grade", "material", "iso_group", "operation", "d_min_mm", "d_max_mm",
                      "hardness_hb", "v_c_nom_m_per_min", "f_z_nom_mm", "a_p_max_mm", "a_e_max_mm", "source"}));
    CuttingDataRecord r;
    FL_RETURN_IF_ERROR(f.String("tool_family", &r.tool_family));
    FL_RETURN_IF_ERROR(f.OptionalString("grade", &r.grade));
    FL_RETURN_IF_ERROR(f.OptionalString("material", &r.material));
    FL_RETURN_IF_ERROR(f.String("iso_group", &r.iso_group));
    FL_RETURN_IF_ERROR(f.String("operation", &r.operation));
    if (r.operation != "side_milling" && r.operation != "slotting") {
      return Status::BadInput(Where{.file = source, .field = prefix + "operation"},
                              "'" + r.operation + "' is not an operation", "write side_milling or slotting");
    }
    FL_RETURN_IF_ERROR(f.Number("d_min_mm", &r.d_min_mm, positive));
    FL_RETURN_IF_ERROR(f.Number("d_max_mm", &r.d_max_mm, {.min = r.d_min_mm}));
    FL_RETURN_IF_ERROR(f.OptionalNumber("hardness_hb", &r.hardness_hb, {.min = 0}));
    FL_RETURN_IF_ERROR(f.Number("v_c_nom_m_per_min", &r.v_c_nom_m_per_min, positive));
    FL_RETURN_IF_ERROR(f.Number("f_z_nom_mm", &r.f_z_nom_mm, positive));
    FL_RETURN_IF_ERROR(f.OptionalNumber("a_p_max_mm", &r.a_p_max_mm, {.min = 0}));
    FL_RETURN_IF_ERROR(f.OptionalNumber("a_e_max_mm", &r.a_e_max_mm, {.min = 0}));
    r.source = source + "[" + std::to_string(i) + "]";
    FL_RETURN_IF_ERROR(f.OptionalString("source", &r.source));
    out.push_back(std::move(r));
  }
  return out;
}

std::optional<CuttingDataMatch> MatchCuttingData(const std::vector<CuttingDataRecord>& records,
                                                 const ToolDescription& tool, double diameter_mm,
                                                 const std::string& operation) {
  std::optional<CuttingDataMatch> best;
  for (const CuttingDataRecord& r : records) {
    if (!SameText(r.iso_group, tool.iso_group) || r.operation != operation) continue;
    CuttingDataMatch m{r, 0.4, "iso_group"};
    const bool family = !tool.family.empty() && SameText(r.tool_family, tool.family);
    const bool in_range = diameter_mm >= r.d_min_mm && diameter_mm <= r.d_max_mm;
    if (family && in_range && !tool.grade.empty() && SameText(r.grade, tool.grade) && !tool.material.empty() &&
        SameText(r.material, tool.material)) {
      m.credibility = 1.0;
      m.level = "exact";
    } else if (family && tool.hardness_hb > 0 && r.hardness_hb > 0 &&
               std::abs(r.hardness_hb - tool.hardness_hb) <= 0.1 * tool.hardness_hb) {
      m.credibility = 0.7;
      m.level = "family";
    }
    if (!best || m.credibility > best->credibility) best = m;  // the first of equals wins
  }
  return best;
}

double ModelCredibility(const std::vector<double>& predicted_a, const std::vector<double>& measured_a) {
  const std::size_t n = std::min(predicted_a.size(), measured_a.size());
  if (n < 20) return 0.3;
  double sum = 0;
  for (std::size_t i = 0; i < n; ++i) {
    const double rel = (predicted_a[i] - measured_a[i]) / measured_a[i];
    sum += rel * rel;
  }
  const double rmse_rel = std::sqrt(sum / static_cast<double>(n));
  return std::clamp(1 - rmse_rel / 0.3, 0.0, 1.0);
}

double ModelWeight(double c_model, double c_db) {
  static constexpr double kW[3][3] = {{0.5, 0.3, 0.1}, {0.7, 0.5, 0.3}, {0.9, 0.7, 0.5}};
  const std::array<double, 3> m = Lmh(c_model), d = Lmh(c_db);
  double num = 0, den = 0;
  for (int i = 0; i < 3; ++i) {
    for (int j = 0; j < 3; ++j) {
      const double alpha = std::min(m[static_cast<std::size_t>(i)], d[static_cast<std::size_t>(j)]);
      num += alpha * kW[i][j];
      den += alpha;
    }
  }
  return num / den;  // den > 0: the memberships of each input sum to 1
}

nlohmann::json FusedCuttingPoint::ToJson() const {
  nlohmann::json j = {
      {"w_m", w_m}, {"state", state.ToJson()}, {"database_used", database_used}, {"warnings", warnings}};
  if (match) {
    j["database"] = {{"record", match->record.ToJson()},
                     {"credibility", match->credibility},
                     {"level", match->level},
                     {"f_z_db_mm", f_z_db_mm},
                     {"n_db_rpm", n_db_rpm}};
  }
  return j;
}

FusedCuttingPoint FuseWithDatabase(const CuttingCase& c, const CuttingState& model,
                                   const std::optional<CuttingDataMatch>& match, double c_model) {
  FusedCuttingPoint out;
  out.state = model;
  out.match = match;
  if (!match) return out;  // no entry: w_m = 1
  const double d = c.diameter_mm, a_e = c.a_e_mm;
  const double k_ct = a_e < d / 2 ? std::min(3.0, d / (2 * std::sqrt(a_e * (d - a_e)))) : 1.0;
  out.n_db_rpm = std::clamp(1000 * match->record.v_c_nom_m_per_min / (std::numbers::pi * d), c.n_min_rpm, c.n_max_rpm);
  out.f_z_db_mm = std::clamp(match->record.f_z_nom_mm * k_ct, c.f_z_min_mm, c.f_z_max_mm);
  out.w_m = ModelWeight(c_model, match->credibility);
  out.database_used = true;
  const double n = std::exp((1 - out.w_m) * std::log(out.n_db_rpm) + out.w_m * std::log(model.n_rpm));
  double f_z = std::exp((1 - out.w_m) * std::log(out.f_z_db_mm) + out.w_m * std::log(model.f_z_mm));
  const double cap = CuttingFeedCap(c, n);
  if (cap < c.f_z_min_mm) {
    out.warnings.push_back("the fused speed n = " + FormatFixed(n, 0) +
                           " rpm admits no feed per tooth in range: the model optimum is used");
  } else {
    f_z = std::clamp(f_z, c.f_z_min_mm, cap);
    out.state = EvaluateCutting(c, f_z, n);
  }
  if (std::abs(std::log(model.n_rpm / out.n_db_rpm)) > std::log(1.5) ||
      std::abs(std::log(model.f_z_mm / out.f_z_db_mm)) > std::log(2.0)) {
    out.warnings.push_back("L1-DB-DISAGREE: model optimum (n = " + FormatFixed(model.n_rpm, 0) +
                           " rpm, f_z = " + FormatFixed(model.f_z_mm, 4) + " mm) and database point (n = " +
                           FormatFixed(out.n_db_rpm, 0) + " rpm, f_z = " + FormatFixed(out.f_z_db_mm, 4) + " mm, " +
                           match->record.source + ") differ by more than 1.5x in speed or 2x in feed");
  }
  return out;
}

}  // namespace formloop::planning
