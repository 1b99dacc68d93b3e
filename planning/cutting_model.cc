#include "planning/cutting_model.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <numbers>
#include <optional>
#include <tuple>

#include "core/json_io.h"
#include "core/point_io.h"

namespace formloop::planning {
namespace {

constexpr double kPi = std::numbers::pi;

// Numbers in messages, without the locale.
std::string Num(double v) { return FormatFixed(v, 4); }

double PowerAvailable(const CuttingCase& c, double n) {
  const double share = c.base_speed_rpm > 0 ? std::min(1.0, n / c.base_speed_rpm) : 1.0;
  return c.efficiency * c.rated_power_kw * share;
}

// Force without the f_z and n factors: K_F C_F a_p^x_F a_e^u_F z / d^q_F.
double ForceFactor(const CuttingCase& c) {
  const ForceLaw& f = c.force;
  return f.K_F * f.C_F * std::pow(c.a_p_mm, f.x_F) * std::pow(c.a_e_mm, f.u_F) * c.flutes /
         std::pow(c.diameter_mm, f.q_F);
}

// Tool-life right-hand side of v T^m = C without v and f_z: C_v d^q_v K_v / (a_p^x_v a_e^u_v z^p_v).
double LifeFactor(const CuttingCase& c) {
  const ToolLifeLaw& l = c.life;
  return l.C_v * std::pow(c.diameter_mm, l.q_v) * l.K_v /
         (std::pow(c.a_p_mm, l.x_v) * std::pow(c.a_e_mm, l.u_v) * std::pow(c.flutes, l.p_v));
}

// One log-space row α u + β w ≤ γ (u = ln f_z, w = ln n), §1.7.
struct Row {
  double alpha, beta, gamma;
  const char* name;
};

std::vector<Row> LogRows(const CuttingCase& c) {
  const double t_min = c.TMinMin();
  const double life = 1000 * LifeFactor(c) / (kPi * c.diameter_mm * std::pow(t_min, c.life.m));
  const double force = ForceFactor(c);
  const double power = 6e7 * c.efficiency * c.rated_power_kw / (kPi * c.diameter_mm * force);
  std::vector<Row> rows = {
      {c.life.y_v, 1, std::log(life), "T_min"},
      {1, 1, std::log(c.max_feed_mm_per_min / c.flutes), "v_f_max"},
      {c.force.y_F, -c.force.w_F, std::log(c.max_force_n / force), "F_max"},
      {c.force.y_F, 1 - c.force.w_F, std::log(power), "P"},
      {-1, 0, -std::log(c.f_z_min_mm), "f_z_min"},
      {1, 0, std::log(c.f_z_max_mm), "f_z_max"},
      {0, -1, -std::log(c.n_min_rpm), "n_min"},
      {0, 1, std::log(c.n_max_rpm), "n_max"},
  };
  // Below n_base the available power falls with n: P_c ≤ η P_rated n / n_base.
  if (c.base_speed_rpm > 0) rows.push_back({c.force.y_F, -c.force.w_F, std::log(power / c.base_speed_rpm), "P"});
  return rows;
}

// Non-negative least squares of (1, 1) on the rows' (α, β) (§1.7 KKT certificate). In two dimensions an
// optimal support has at most two columns, so trying every support of one and two columns is exact.
void Kkt(const std::vector<Row>& rows, CuttingOptimum* out) {
  double best = std::numeric_limits<double>::infinity();
  std::vector<double> lambda(rows.size(), 0.0);
  for (std::size_t i = 0; i < rows.size(); ++i) {
    const double a = rows[i].alpha, b = rows[i].beta;
    const double l = std::max(0.0, (a + b) / (a * a + b * b));
    const double r = std::hypot(1 - l * a, 1 - l * b);
    if (r < best) {
      best = r;
      std::fill(lambda.begin(), lambda.end(), 0.0);
      lambda[i] = l;
    }
    for (std::size_t j = i + 1; j < rows.size(); ++j) {
      const double det = a * rows[j].beta - b * rows[j].alpha;
      if (std::abs(det) < 1e-12) continue;
      const double li = (rows[j].beta - rows[j].alpha) / det;  // Cramer on [a αj; b βj] λ = (1, 1)
      const double lj = (a - b) / det;
      if (li < 0 || lj < 0) continue;
      const double rr = std::hypot(1 - li * a - lj * rows[j].alpha, 1 - li * b - lj * rows[j].beta);
      if (rr < best) {
        best = rr;
        std::fill(lambda.begin(), lambda.end(), 0.0);
        lambda[i] = li;
        lambda[j] = lj;
      }
    }
  }
  out->kkt_residual = best;
  out->kkt_multipliers = lambda;
  out->kkt_passed = best <= 1e-9;
}

Status Positive(double value, const char* field) {
  if (std::isfinite(value) && value > 0) return Status::Ok();
  return Status::BadInput(Where{.field = field}, "must be a finite number > 0, got " + Num(value));
}

Status Finite(double value, const char* field) {
  if (std::isfinite(value)) return Status::Ok();
  return Status::BadInput(Where{.field = field}, "must be a finite number");
}

// One numeric member of a section of the coefficient file.
struct NumberMember {
  const char* key;
  double* out;
  NumberRange range;
  bool required = true;
};

// Reads the object `section` of root: its members, and nothing else.
Status ReadNumbers(const JsonFields& root, const char* section, std::initializer_list<NumberMember> members) {
  std::optional<JsonFields> f;
  FL_RETURN_IF_ERROR(root.Object(section, &f));
  std::vector<std::string> known;
  for (const NumberMember& m : members) known.emplace_back(m.key);
  FL_RETURN_IF_ERROR(f->CheckKnown(known));
  for (const NumberMember& m : members) {
    FL_RETURN_IF_ERROR(m.required ? f->Number(m.key, m.out, m.range) : f->OptionalNumber(m.key, m.out, m.range));
  }
  return Status::Ok();
}

}  // namespace

CuttingCase CuttingCase::S1() {
  CuttingCase c;
  c.coefficient_set = "S1";
  c.life = {.C_v = 234, .q_v = 0.44, .x_v = 0.10, .y_v = 0.26, .u_v = 0.24, .p_v = 0.13, .m = 0.37, .K_v = 1};
  c.force = {.C_F = 125, .x_F = 1.0, .y_F = 0.75, .u_F = 0.85, .q_F = 0.73, .w_F = -0.13, .K_F = 1};
  return c;
}

double MaxProductionToolLifeMin(const CuttingCase& c) { return (1 / c.life.m - 1) * c.tool_change_min; }

double MinCostToolLifeMin(const CuttingCase& c) {
  return (1 / c.life.m - 1) * (c.tool_change_min + c.cost_per_edge / c.machine_cost_per_min);
}

double CuttingCase::TMinMin() const { return std::isnan(t_min_min) ? MinCostToolLifeMin(*this) : t_min_min; }

Status CuttingCase::Validate() const {
  // Coefficients and exponents: (value, field, must be > 0; else only finite).
  const std::tuple<double, const char*, bool> laws[] = {
      {life.C_v, "tool_life.C_v", true}, {life.q_v, "tool_life.q_v", false}, {life.x_v, "tool_life.x_v", false},
      {life.y_v, "tool_life.y_v", true}, {life.u_v, "tool_life.u_v", false}, {life.p_v, "tool_life.p_v", false},
      {life.K_v, "tool_life.K_v", true}, {force.C_F, "force.C_F", true},     {force.x_F, "force.x_F", false},
      {force.y_F, "force.y_F", true},    {force.u_F, "force.u_F", false},    {force.q_F, "force.q_F", false},
      {force.w_F, "force.w_F", false},   {force.K_F, "force.K_F", true}};
  for (const auto& [value, field, positive] : laws)
    FL_RETURN_IF_ERROR(positive ? Positive(value, field) : Finite(value, field));
  if (!(life.m > 0 && life.m < 1)) {
    return Status::BadInput(Where{.field = "tool_life.m"}, "Taylor exponent must lie in (0, 1), got " + Num(life.m));
  }
  FL_RETURN_IF_ERROR(Positive(diameter_mm, "tool.diameter_mm"));
  if (flutes < 1) return Status::BadInput(Where{.field = "tool.flutes"}, "must be at least 1");
  FL_RETURN_IF_ERROR(Positive(a_p_mm, "a_p_mm"));
  FL_RETURN_IF_ERROR(Positive(a_e_mm, "a_e_mm"));
  FL_RETURN_IF_ERROR(Positive(f_z_min_mm, "tool.f_z_min_mm"));
  FL_RETURN_IF_ERROR(Positive(f_z_max_mm, "tool.f_z_max_mm"));
  if (f_z_max_mm < f_z_min_mm) return Status::BadInput(Where{.field = "tool.f_z_max_mm"}, "must be >= f_z_min_mm");
  FL_RETURN_IF_ERROR(Positive(n_min_rpm, "machine.n_min_rpm"));
  FL_RETURN_IF_ERROR(Positive(n_max_rpm, "machine.n_max_rpm"));
  if (n_max_rpm < n_min_rpm) return Status::BadInput(Where{.field = "machine.n_max_rpm"}, "must be >= n_min_rpm");
  FL_RETURN_IF_ERROR(Positive(max_feed_mm_per_min, "machine.max_feed_mm_per_min"));
  FL_RETURN_IF_ERROR(Positive(max_force_n, "limits.max_force_n"));
  FL_RETURN_IF_ERROR(Positive(rated_power_kw, "machine.rated_power_kw"));
  if (!(std::isfinite(base_speed_rpm) && base_speed_rpm >= 0)) {
    return Status::BadInput(Where{.field = "machine.base_speed_rpm"}, "must be >= 0 (0: no constant-torque range)");
  }
  if (!(efficiency > 0 && efficiency <= 1)) {
    return Status::BadInput(Where{.field = "machine.efficiency"}, "must lie in (0, 1]");
  }
  FL_RETURN_IF_ERROR(Positive(tool_change_min, "tool.tool_change_min"));
  if (!(std::isfinite(cost_per_edge) && cost_per_edge >= 0)) {
    return Status::BadInput(Where{.field = "tool.cost_per_edge"}, "must be >= 0");
  }
  FL_RETURN_IF_ERROR(Positive(machine_cost_per_min, "machine.cost_per_min"));
  if (!std::isnan(t_min_min)) {
    FL_RETURN_IF_ERROR(Positive(t_min_min, "limits.t_min_min"));
    const double t_p = MaxProductionToolLifeMin(*this);
    if (t_min_min < t_p) {
      return Status::BadInput(Where{.field = "limits.t_min_min"},
                              "T_min = " + Num(t_min_min) +
                                  " min is below the maximum-production tool life T_p = (1/m - 1) t_ct = " + Num(t_p) +
                                  " min (wearing the tool faster never pays)",
                              "set t_min_min >= T_p, or leave it out for the minimum-cost life T_c");
    }
  }
  return Status::Ok();
}

std::vector<std::string> CuttingCase::Warnings() const {
  std::vector<std::string> out;
  if (!(1 > life.y_v && life.y_v > life.x_v)) {
    out.push_back("coefficient set " + coefficient_set +
                  ": expected 1 > y_v > x_v (tool life depends on v more than on f_z, on f_z more than on a_p)");
  }
  return out;
}

nlohmann::json CuttingCase::ToJson() const {
  return {{"coefficient_set", coefficient_set},
          {"tool_life",
           {{"C_v", life.C_v},
            {"q_v", life.q_v},
            {"x_v", life.x_v},
            {"y_v", life.y_v},
            {"u_v", life.u_v},
            {"p_v", life.p_v},
            {"m", life.m},
            {"K_v", life.K_v}}},
          {"force",
           {{"C_F", force.C_F},
            {"x_F", force.x_F},
            {"y_F", force.y_F},
            {"u_F", force.u_F},
            {"q_F", force.q_F},
            {"w_F", force.w_F},
            {"K_F", force.K_F}}},
          {"diameter_mm", diameter_mm},
          {"flutes", flutes},
          {"a_p_mm", a_p_mm},
          {"a_e_mm", a_e_mm},
          {"f_z_min_mm", f_z_min_mm},
          {"f_z_max_mm", f_z_max_mm},
          {"n_min_rpm", n_min_rpm},
          {"n_max_rpm", n_max_rpm},
          {"max_feed_mm_per_min", max_feed_mm_per_min},
          {"max_force_n", max_force_n},
          {"rated_power_kw", rated_power_kw},
          {"base_speed_rpm", base_speed_rpm},
          {"efficiency", efficiency},
          {"tool_change_min", tool_change_min},
          {"cost_per_edge", cost_per_edge},
          {"machine_cost_per_min", machine_cost_per_min},
          {"t_min_min", TMinMin()},
          {"t_min_is_min_cost_life", std::isnan(t_min_min)}};
}

CuttingState EvaluateCutting(const CuttingCase& c, double f_z, double n) {
  CuttingState s;
  s.f_z_mm = f_z;
  s.n_rpm = n;
  s.v_f_mm_per_min = f_z * c.flutes * n;
  s.q_mm3_per_min = c.a_e_mm * c.a_p_mm * s.v_f_mm_per_min;
  s.v_m_per_min = kPi * c.diameter_mm * n / 1000;
  s.tool_life_min = std::pow(LifeFactor(c) / (s.v_m_per_min * std::pow(f_z, c.life.y_v)), 1 / c.life.m);
  s.force_n = ForceFactor(c) * std::pow(f_z, c.force.y_F) / std::pow(n, c.force.w_F);
  s.power_kw = s.force_n * s.v_m_per_min / 60000;
  s.power_available_kw = PowerAvailable(c, n);
  return s;
}

nlohmann::json CuttingState::ToJson() const {
  return {{"f_z_mm", f_z_mm},
          {"n_rpm", n_rpm},
          {"q_mm3_per_min", q_mm3_per_min},
          {"v_m_per_min", v_m_per_min},
          {"v_f_mm_per_min", v_f_mm_per_min},
          {"tool_life_min", tool_life_min},
          {"force_n", force_n},
          {"power_kw", power_kw},
          {"power_available_kw", power_available_kw}};
}

std::vector<ConstraintValue> CuttingConstraints(const CuttingCase& c, const CuttingState& s) {
  return {
      {"T_min", "g1 tool life T >= T_min", c.TMinMin() / s.tool_life_min - 1},
      {"n_min", "g2 spindle speed n >= n_min", c.n_min_rpm / s.n_rpm - 1},
      {"n_max", "g2 spindle speed n <= n_max", s.n_rpm / c.n_max_rpm - 1},
      {"v_f_max", "g3 feed rate v_f <= v_f,max", s.v_f_mm_per_min / c.max_feed_mm_per_min - 1},
      {"F_max", "g4 cutting force F_c <= F_max", s.force_n / c.max_force_n - 1},
      {"P", "g5 cutting power P_c <= eta P_rated min(1, n/n_base)", s.power_kw / s.power_available_kw - 1},
      {"f_z_min", "g6 feed per tooth f_z >= f_z,min", c.f_z_min_mm / s.f_z_mm - 1},
      {"f_z_max", "g6 feed per tooth f_z <= f_z,max", s.f_z_mm / c.f_z_max_mm - 1},
  };
}

std::vector<std::string> ActiveConstraints(const CuttingCase& c, const CuttingState& s, double tolerance) {
  std::vector<std::string> out;
  for (const ConstraintValue& g : CuttingConstraints(c, s)) {
    if (std::abs(g.relative) <= tolerance) out.push_back(g.name);
  }
  return out;
}

bool SatisfiesConstraints(const CuttingCase& c, const CuttingState& s, double slack) {
  for (const ConstraintValue& g : CuttingConstraints(c, s)) {
    if (!(g.relative <= slack)) return false;
  }
  return true;
}

double CuttingFeedCap(const CuttingCase& c, double n, std::string* limiting) {
  const double v = kPi * c.diameter_mm * n / 1000;
  const double force = ForceFactor(c);
  const std::pair<double, const char*> caps[] = {
      {c.f_z_max_mm, "f_z_max"},
      {c.max_feed_mm_per_min / (c.flutes * n), "v_f_max"},
      {std::pow(LifeFactor(c) / (v * std::pow(c.TMinMin(), c.life.m)), 1 / c.life.y_v), "T_min"},
      {std::pow(c.max_force_n * std::pow(n, c.force.w_F) / force, 1 / c.force.y_F), "F_max"},
      {std::pow(60000 * PowerAvailable(c, n) * std::pow(n, c.force.w_F) / (force * v), 1 / c.force.y_F), "P"},
  };
  const auto* best = &caps[0];
  for (const auto& cap : caps) {
    if (cap.first < best->first) best = &cap;
  }
  if (limiting != nullptr) *limiting = best->second;
  return best->first;
}

Status InfeasibleStatus(const CuttingCase& c) {
  const CuttingState s = EvaluateCutting(c, c.f_z_min_mm, c.n_min_rpm);
  std::vector<ConstraintValue> g = CuttingConstraints(c, s);
  const auto worst = std::max_element(
      g.begin(), g.end(), [](const ConstraintValue& a, const ConstraintValue& b) { return a.relative < b.relative; });
  return Status::BadInput(
      "L1-INFEASIBLE: no feed per tooth and spindle speed satisfy every constraint (coefficient set " +
      c.coefficient_set + ", a_p = " + Num(c.a_p_mm) + " mm, a_e = " + Num(c.a_e_mm) + " mm); at (f_z,min, n_min) = (" +
      Num(c.f_z_min_mm) + ", " + Num(c.n_min_rpm) + ") the largest relative violation is " + worst->label + " (" +
      worst->name + ", " + Num(100 * worst->relative) +
      " % over). Fix: relax that limit, or change the tool, a_p or a_e");
}

nlohmann::json CuttingOptimum::ToJson() const {
  nlohmann::json j = state.ToJson();
  j["active"] = active;
  j["method"] = method;
  if (method == "lp") {
    j["kkt"] = {{"passed", kkt_passed}, {"residual", kkt_residual}, {"multipliers", kkt_multipliers}};
  }
  if (method == "ga") j["generations"] = generations;
  return j;
}

Result<CuttingOptimum> CuttingOptimumExact(const CuttingCase& c) {
  const std::vector<Row> rows = LogRows(c);
  auto feasible = [&](double u, double w) {
    for (const Row& r : rows) {
      if (r.alpha * u + r.beta * w - r.gamma > 1e-9) return false;
    }
    return true;
  };
  std::optional<std::pair<double, double>> best;
  auto better = [&](double u, double w) {
    const double obj = u + w, best_obj = best->first + best->second;
    if (std::abs(obj - best_obj) > 1e-9) return obj > best_obj;
    return c.life.y_v * u + w < c.life.y_v * best->first + best->second;  // tie: the longer tool life
  };
  for (std::size_t i = 0; i < rows.size(); ++i) {
    for (std::size_t j = i + 1; j < rows.size(); ++j) {
      const Row &a = rows[i], &b = rows[j];
      const double det = a.alpha * b.beta - a.beta * b.alpha;
      if (std::abs(det) < 1e-12) continue;
      const double u = (a.gamma * b.beta - a.beta * b.gamma) / det;
      const double w = (a.alpha * b.gamma - a.gamma * b.alpha) / det;
      if (!feasible(u, w)) continue;
      if (!best || better(u, w)) best = {u, w};
    }
  }
  if (!best) return InfeasibleStatus(c);
  CuttingOptimum out;
  out.method = "lp";
  // Clamp the exponentials onto the box so rounding never puts a bound a few ulps outside.
  const double f_z = std::clamp(std::exp(best->first), c.f_z_min_mm, c.f_z_max_mm);
  const double n = std::clamp(std::exp(best->second), c.n_min_rpm, c.n_max_rpm);
  out.state = EvaluateCutting(c, f_z, n);
  out.active = ActiveConstraints(c, out.state);
  std::vector<Row> binding;
  for (const Row& r : rows) {
    if (std::abs(r.alpha * best->first + r.beta * best->second - r.gamma) <= 1e-7) binding.push_back(r);
  }
  Kkt(binding, &out);
  return out;
}

CuttingOptimum CuttingOptimumGrid(const CuttingCase& c, int points_per_axis) {
  CuttingOptimum out;
  out.method = "grid";
  const int m = std::max(2, points_per_axis);
  for (int i = 0; i < m; ++i) {
    const double n = c.n_min_rpm * std::pow(c.n_max_rpm / c.n_min_rpm, static_cast<double>(i) / (m - 1));
    for (int j = 0; j < m; ++j) {
      const double f_z = c.f_z_min_mm * std::pow(c.f_z_max_mm / c.f_z_min_mm, static_cast<double>(j) / (m - 1));
      const CuttingState s = EvaluateCutting(c, f_z, n);
      if (!SatisfiesConstraints(c, s)) continue;
      const double q = s.q_mm3_per_min, q_best = out.state.q_mm3_per_min;
      const bool tie = std::abs(q - q_best) <= 1e-9 * q;
      if ((!tie && q > q_best) || (tie && s.tool_life_min > out.state.tool_life_min)) out.state = s;
    }
  }
  out.active = ActiveConstraints(c, out.state);
  return out;
}

nlohmann::json CuttingCoefficients::ToJson() const {
  nlohmann::json j = base.ToJson();
  j["tool"] = {{"family", tool.family},
               {"grade", tool.grade},
               {"flute_length_mm", tool.flute_length_mm},
               {"k_ap_side_milling", tool.k_ap_side_milling},
               {"k_ap_slotting", tool.k_ap_slotting}};
  j["material"] = {{"name", tool.material}, {"iso_group", tool.iso_group}, {"hardness_hb", tool.hardness_hb}};
  return j;
}

Result<CuttingCoefficients> CuttingCoefficientsFromJson(const nlohmann::json& json, const std::string& source) {
  if (!json.is_object()) return Status::BadInput(Where{.file = source}, "the coefficient file must be a JSON object");
  CuttingCoefficients out;
  CuttingCase& c = out.base;
  JsonFields root(json, source);
  FL_RETURN_IF_ERROR(root.CheckKnown({"id", "tool", "material", "tool_life", "force", "machine", "limits", "comment"}));
  FL_RETURN_IF_ERROR(root.String("id", &c.coefficient_set));
  const NumberRange positive{.min = 0, .exclusive_min = true};
  const NumberRange any{};

  std::optional<JsonFields> tool, material;
  FL_RETURN_IF_ERROR(root.Object("tool", &tool));
  FL_RETURN_IF_ERROR(tool->CheckKnown({"diameter_mm", "flutes", "flute_length_mm", "f_z_min_mm", "f_z_max_mm",
                                       "tool_change_min", "cost_per_edge", "family", "grade"}));
  FL_RETURN_IF_ERROR(tool->Number("diameter_mm", &c.diameter_mm, positive));
  long long flutes = 0;
  FL_RETURN_IF_ERROR(tool->Integer("flutes", &flutes, 1, 64));
  c.flutes = static_cast<int>(flutes);
  FL_RETURN_IF_ERROR(tool->Number("flute_length_mm", &out.tool.flute_length_mm, positive));
  FL_RETURN_IF_ERROR(tool->Number("f_z_min_mm", &c.f_z_min_mm, positive));
  FL_RETURN_IF_ERROR(tool->Number("f_z_max_mm", &c.f_z_max_mm, positive));
  FL_RETURN_IF_ERROR(tool->Number("tool_change_min", &c.tool_change_min, positive));
  FL_RETURN_IF_ERROR(tool->Number("cost_per_edge", &c.cost_per_edge, {.min = 0}));
  FL_RETURN_IF_ERROR(tool->OptionalString("family", &out.tool.family));
  FL_RETURN_IF_ERROR(tool->OptionalString("grade", &out.tool.grade));

  FL_RETURN_IF_ERROR(root.Object("material", &material));
  FL_RETURN_IF_ERROR(material->CheckKnown({"name", "iso_group", "hardness_hb", "k_ap_side_milling", "k_ap_slotting"}));
  FL_RETURN_IF_ERROR(material->OptionalString("name", &out.tool.material));
  FL_RETURN_IF_ERROR(material->String("iso_group", &out.tool.iso_group));
  static const std::string kGroups = "PMKNSH";
  if (out.tool.iso_group.size() != 1 || kGroups.find(out.tool.iso_group[0]) == std::string::npos) {
    return Status::BadInput(Where{.file = source, .field = "material.iso_group"},
                            "'" + out.tool.iso_group + "' is not an ISO 513 group", "write one of P, M, K, N, S, H");
  }
  FL_RETURN_IF_ERROR(material->OptionalNumber("hardness_hb", &out.tool.hardness_hb, {.min = 0}));
  FL_RETURN_IF_ERROR(material->Number("k_ap_side_milling", &out.tool.k_ap_side_milling, positive));
  FL_RETURN_IF_ERROR(material->Number("k_ap_slotting", &out.tool.k_ap_slotting, positive));

  const NumberRange non_negative{.min = 0};
  FL_RETURN_IF_ERROR(ReadNumbers(root, "tool_life",
                                 {{"C_v", &c.life.C_v, positive},
                                  {"q_v", &c.life.q_v, any},
                                  {"x_v", &c.life.x_v, any},
                                  {"y_v", &c.life.y_v, positive},
                                  {"u_v", &c.life.u_v, any},
                                  {"p_v", &c.life.p_v, any},
                                  {"m", &c.life.m, positive},
                                  {"K_v", &c.life.K_v, positive, false}}));
  FL_RETURN_IF_ERROR(ReadNumbers(root, "force",
                                 {{"C_F", &c.force.C_F, positive},
                                  {"x_F", &c.force.x_F, any},
                                  {"y_F", &c.force.y_F, positive},
                                  {"u_F", &c.force.u_F, any},
                                  {"q_F", &c.force.q_F, any},
                                  {"w_F", &c.force.w_F, any},
                                  {"K_F", &c.force.K_F, positive, false}}));
  FL_RETURN_IF_ERROR(ReadNumbers(root, "machine",
                                 {{"n_min_rpm", &c.n_min_rpm, positive},
                                  {"n_max_rpm", &c.n_max_rpm, positive},
                                  {"max_feed_mm_per_min", &c.max_feed_mm_per_min, positive},
                                  {"rated_power_kw", &c.rated_power_kw, positive},
                                  {"base_speed_rpm", &c.base_speed_rpm, non_negative, false},
                                  {"efficiency", &c.efficiency, {.min = 0, .max = 1, .exclusive_min = true}},
                                  {"cost_per_min", &c.machine_cost_per_min, positive}}));
  FL_RETURN_IF_ERROR(ReadNumbers(
      root, "limits", {{"max_force_n", &c.max_force_n, positive}, {"t_min_min", &c.t_min_min, positive, false}}));

  Status valid = c.Validate();
  if (!valid.ok()) return Status(valid.code(), source + ": " + valid.message());
  return out;
}

}  // namespace formloop::planning
