// The checks of a GHSOM's options and its stored form (retrieval/ghsom.h): the standardiser, the options,
// the training report and the tree as JSON, written byte-identically and read back with every field checked
// through core's JsonFields (messages name the key path, "maps[2].rows"). ghsom.cc trains, descends and
// inserts.

#include <cmath>
#include <cstddef>
#include <cstdint>
#include <limits>
#include <optional>
#include <set>
#include <string>
#include <vector>

#include "core/json_io.h"
#include "core/number_text.h"
#include "retrieval/ghsom.h"

namespace formloop::retrieval {
namespace {

using nlohmann::json;

// Bounds of the option checks: far beyond any useful value, they only catch typos and overflow.
constexpr int kMaxDepthLimit = 64;
constexpr int kMaxUnitsLimit = 100000;
constexpr int kMaxEpochsLimit = 100000;

std::string Num(double x) { return FormatSignificant(x, 6); }

Status Bad(const std::string& field, const std::string& what, const std::string& fix = "") {
  return Status::BadInput(Where{.field = field}, "ghsom: " + what, fix);
}

// ---- JSON reading with paths ----

// Typed reading of a stored map through core's JsonFields; messages name the key path ("maps[2].rows").
constexpr const char* kSource = "ghsom";

JsonFields FieldsAt(const json& j, const std::string& path) {
  return JsonFields(j, kSource, path.empty() ? "" : path + ".");
}

std::string Join(const std::string& path, const char* key) { return path.empty() ? key : path + "." + key; }

Result<const json*> Field(const json& j, const std::string& path, const char* key) {
  if (!j.is_object()) return Bad(path, "expected an object");
  const auto it = j.find(key);
  if (it == j.end()) return Bad(Join(path, key), "missing");
  return &*it;
}

Status ReadDouble(const json& j, const std::string& path, const char* key, double* out) {
  return FieldsAt(j, path).Number(key, out);
}

Status ReadInt(const json& j, const std::string& path, const char* key, int* out) {
  long long value = 0;
  FL_RETURN_IF_ERROR(
      FieldsAt(j, path).Integer(key, &value, std::numeric_limits<int>::min(), std::numeric_limits<int>::max()));
  *out = static_cast<int>(value);
  return Status::Ok();
}

Status ReadVector(const json& v, const std::string& path, Eigen::Index expected, Eigen::VectorXd* out) {
  std::vector<double> values;
  FL_RETURN_IF_ERROR(
      ReadNumberArray(v, kSource, path, &values,
                      expected >= 0 ? std::optional<std::size_t>(static_cast<std::size_t>(expected)) : std::nullopt));
  *out = Eigen::Map<const Eigen::VectorXd>(values.data(), static_cast<Eigen::Index>(values.size()));
  return Status::Ok();
}

Status ReadIntArray(const json& v, const std::string& path, std::vector<int>* out) {
  std::vector<long long> values;
  FL_RETURN_IF_ERROR(
      ReadIntegerArray(v, kSource, path, &values, std::numeric_limits<int>::min(), std::numeric_limits<int>::max()));
  out->assign(values.begin(), values.end());
  return Status::Ok();
}

json VectorJson(const Eigen::VectorXd& v) {
  json a = json::array();
  for (Eigen::Index k = 0; k < v.size(); ++k) a.push_back(v(k));
  return a;
}

}  // namespace

// ---------------------------------------------------------------------------------------------
// Standardiser

nlohmann::json Standardiser::ToJson() const {
  return json{{"mean", VectorJson(mean)}, {"std", VectorJson(std)}, {"constant_components", constant_components}};
}

Result<Standardiser> Standardiser::FromJson(const nlohmann::json& j) {
  Standardiser s;
  FL_ASSIGN_OR_RETURN(const json* mean_json, Field(j, "standardiser", "mean"));
  FL_RETURN_IF_ERROR(ReadVector(*mean_json, "standardiser.mean", -1, &s.mean));
  if (s.mean.size() < 1) return Bad("standardiser.mean", "empty");
  FL_ASSIGN_OR_RETURN(const json* std_json, Field(j, "standardiser", "std"));
  FL_RETURN_IF_ERROR(ReadVector(*std_json, "standardiser.std", s.mean.size(), &s.std));
  for (Eigen::Index k = 0; k < s.std.size(); ++k) {
    if (!(s.std(k) > 0)) return Bad("standardiser.std[" + std::to_string(k) + "]", "must be > 0");
  }
  FL_ASSIGN_OR_RETURN(const json* constant_json, Field(j, "standardiser", "constant_components"));
  FL_RETURN_IF_ERROR(ReadIntArray(*constant_json, "standardiser.constant_components", &s.constant_components));
  for (std::size_t k = 0; k < s.constant_components.size(); ++k) {
    const int c = s.constant_components[k];
    if (c < 0 || c >= s.mean.size() || (k > 0 && c <= s.constant_components[k - 1])) {
      return Bad("standardiser.constant_components[" + std::to_string(k) + "]",
                 "component indices must be ascending and in [0, " + std::to_string(s.mean.size()) + ")");
    }
  }
  return s;
}

// ---------------------------------------------------------------------------------------------
// Options and report

Status GhsomOptions::Validate() const {
  if (!(tau1 > 0 && tau1 <= 1)) return Bad("tau1", "must be in (0, 1], got " + Num(tau1));
  if (!(tau2 > 0 && tau2 <= 1)) return Bad("tau2", "must be in (0, 1], got " + Num(tau2));
  if (min_inputs_for_child < 4) {
    return Bad("min_inputs_for_child", "must be >= 4 (a 2 x 2 child map), got " + std::to_string(min_inputs_for_child));
  }
  if (max_depth < 1 || max_depth > kMaxDepthLimit) {
    return Bad("max_depth", "must be in [1, " + std::to_string(kMaxDepthLimit) + "], got " + std::to_string(max_depth));
  }
  if (max_units_per_map < 4 || max_units_per_map > kMaxUnitsLimit) {
    return Bad("max_units_per_map",
               "must be in [4, " + std::to_string(kMaxUnitsLimit) + "], got " + std::to_string(max_units_per_map));
  }
  if (epochs < 1 || epochs > kMaxEpochsLimit) {
    return Bad("epochs", "must be in [1, " + std::to_string(kMaxEpochsLimit) + "], got " + std::to_string(epochs));
  }
  if (!(std::isfinite(sigma_start_units) && sigma_start_units > 0)) {
    return Bad("sigma_start_units", "must be finite and > 0, got " + Num(sigma_start_units));
  }
  if (!(std::isfinite(sigma_end_units) && sigma_end_units > 0 && sigma_end_units <= sigma_start_units)) {
    return Bad("sigma_end_units", "must be in (0, sigma_start_units], got " + Num(sigma_end_units));
  }
  if (!(std::isfinite(init_offset) && init_offset > 0)) {
    return Bad("init_offset", "must be finite and > 0, got " + Num(init_offset));
  }
  return Status::Ok();
}

nlohmann::json GhsomOptions::ToJson() const {
  return json{{"tau1", tau1},
              {"tau2", tau2},
              {"min_inputs_for_child", min_inputs_for_child},
              {"max_depth", max_depth},
              {"max_units_per_map", max_units_per_map},
              {"epochs", epochs},
              {"sigma_start_units", sigma_start_units},
              {"sigma_end_units", sigma_end_units},
              {"init_offset", init_offset},
              {"seed", seed}};
}

Result<GhsomOptions> GhsomOptions::FromJson(const nlohmann::json& j) {
  GhsomOptions o;
  const std::string p = "options";
  FL_RETURN_IF_ERROR(ReadDouble(j, p, "tau1", &o.tau1));
  FL_RETURN_IF_ERROR(ReadDouble(j, p, "tau2", &o.tau2));
  FL_RETURN_IF_ERROR(ReadInt(j, p, "min_inputs_for_child", &o.min_inputs_for_child));
  FL_RETURN_IF_ERROR(ReadInt(j, p, "max_depth", &o.max_depth));
  FL_RETURN_IF_ERROR(ReadInt(j, p, "max_units_per_map", &o.max_units_per_map));
  FL_RETURN_IF_ERROR(ReadInt(j, p, "epochs", &o.epochs));
  FL_RETURN_IF_ERROR(ReadDouble(j, p, "sigma_start_units", &o.sigma_start_units));
  FL_RETURN_IF_ERROR(ReadDouble(j, p, "sigma_end_units", &o.sigma_end_units));
  FL_RETURN_IF_ERROR(ReadDouble(j, p, "init_offset", &o.init_offset));
  FL_RETURN_IF_ERROR(FieldsAt(j, p).Unsigned("seed", &o.seed));
  FL_RETURN_IF_ERROR(o.Validate().WithContext("options"));
  return o;
}

nlohmann::json GhsomReport::ToJson() const {
  json rows = json::array();
  for (const auto& m : maps) {
    rows.push_back({{"id", m.id},
                    {"depth", m.depth},
                    {"rows", m.rows},
                    {"cols", m.cols},
                    {"inputs", m.inputs},
                    {"insertions", m.insertions},
                    {"mqe", m.mqe},
                    {"qe", m.qe},
                    {"te", m.te},
                    {"training_time_s", m.training_time_s},
                    {"unit_cap_reached", m.unit_cap_reached}});
  }
  return json{{"maps", rows},       {"unit_count", unit_count},   {"leaf_count", leaf_count}, {"max_depth", max_depth},
              {"leaf_qe", leaf_qe}, {"wall_time_s", wall_time_s}, {"cpu_time_s", cpu_time_s}};
}

// ---------------------------------------------------------------------------------------------
// Serialisation

nlohmann::json Ghsom::ToJson() const {
  json inputs = json::array();
  const auto dim = static_cast<Eigen::Index>(dimension());
  for (int i = 0; i < input_count(); ++i) {
    json row = json::array();
    for (Eigen::Index k = 0; k < dim; ++k) row.push_back(data_[static_cast<std::size_t>(i * dim + k)]);
    inputs.push_back(std::move(row));
  }
  json maps = json::array();
  for (const auto& m : maps_) {
    json units = json::array();
    for (int u = 0; u < m.unit_count(); ++u) {
      const GhsomUnit& unit = m.units[static_cast<std::size_t>(u)];
      units.push_back({{"weight", VectorJson(m.weights.row(u).transpose())},
                       {"inputs", unit.inputs},
                       {"mqe", unit.mqe},
                       {"radius", unit.radius},
                       {"child_map", unit.child_map}});
    }
    maps.push_back({{"id", m.id},
                    {"parent_map", m.parent_map},
                    {"parent_unit", m.parent_unit},
                    {"depth", m.depth},
                    {"rows", m.rows},
                    {"cols", m.cols},
                    {"mqe_parent", m.mqe_parent},
                    {"mqe", m.mqe},
                    {"qe", m.qe},
                    {"te", m.te},
                    {"input_count", m.input_count},
                    {"insertions", m.insertions},
                    {"topographic_errors", m.topographic_errors},
                    {"units", std::move(units)}});
  }
  return json{{"format", "formloop.ghsom"},        {"version", 1},
              {"options", options_.ToJson()},      {"dimension", dimension()},
              {"root_weight", VectorJson(mean0_)}, {"mqe0", mqe0_},
              {"next_map_id", next_map_id_},       {"input_ids", ids_},
              {"inputs", std::move(inputs)},       {"maps", std::move(maps)}};
}

Result<Ghsom> Ghsom::FromJson(const nlohmann::json& j) {
  Ghsom g;
  FL_ASSIGN_OR_RETURN(const json* format, Field(j, "", "format"));
  if (!format->is_string() || format->get<std::string>() != "formloop.ghsom") {
    return Bad("format", "expected \"formloop.ghsom\"", "load a file written by Ghsom::ToJson");
  }
  int version = 0;
  FL_RETURN_IF_ERROR(ReadInt(j, "", "version", &version));
  if (version != 1) return Bad("version", "unsupported version " + std::to_string(version) + " (this build reads 1)");
  FL_ASSIGN_OR_RETURN(const json* options_json, Field(j, "", "options"));
  FL_ASSIGN_OR_RETURN(g.options_, GhsomOptions::FromJson(*options_json));
  int dim = 0;
  FL_RETURN_IF_ERROR(ReadInt(j, "", "dimension", &dim));
  if (dim < 1) return Bad("dimension", "must be >= 1");
  FL_ASSIGN_OR_RETURN(const json* root_json, Field(j, "", "root_weight"));
  FL_RETURN_IF_ERROR(ReadVector(*root_json, "root_weight", dim, &g.mean0_));
  FL_RETURN_IF_ERROR(ReadDouble(j, "", "mqe0", &g.mqe0_));
  if (g.mqe0_ < 0) return Bad("mqe0", "must be >= 0");
  FL_RETURN_IF_ERROR(ReadInt(j, "", "next_map_id", &g.next_map_id_));

  FL_ASSIGN_OR_RETURN(const json* ids_json, Field(j, "", "input_ids"));
  if (!ids_json->is_array()) return Bad("input_ids", "expected an array of integers");
  std::set<std::int64_t> seen;
  for (std::size_t i = 0; i < ids_json->size(); ++i) {
    const json& v = (*ids_json)[i];
    if (!v.is_number_integer()) return Bad("input_ids[" + std::to_string(i) + "]", "expected an integer");
    g.ids_.push_back(v.get<std::int64_t>());
    if (!seen.insert(g.ids_.back()).second) return Bad("input_ids[" + std::to_string(i) + "]", "id repeats");
  }
  FL_ASSIGN_OR_RETURN(const json* inputs_json, Field(j, "", "inputs"));
  if (!inputs_json->is_array() || inputs_json->size() != g.ids_.size()) {
    return Bad("inputs", "expected an array of " + std::to_string(g.ids_.size()) + " rows (one per input id)");
  }
  g.data_.reserve(g.ids_.size() * static_cast<std::size_t>(dim));
  Eigen::VectorXd row;
  for (std::size_t i = 0; i < inputs_json->size(); ++i) {
    FL_RETURN_IF_ERROR(ReadVector((*inputs_json)[i], "inputs[" + std::to_string(i) + "]", dim, &row));
    g.data_.insert(g.data_.end(), row.data(), row.data() + row.size());
  }
  const int n_inputs = static_cast<int>(g.ids_.size());

  FL_ASSIGN_OR_RETURN(const json* maps_json, Field(j, "", "maps"));
  if (!maps_json->is_array() || maps_json->empty()) return Bad("maps", "expected a non-empty array");
  for (std::size_t i = 0; i < maps_json->size(); ++i) {
    const json& mj = (*maps_json)[i];
    const std::string p = "maps[" + std::to_string(i) + "]";
    GhsomMap m;
    FL_RETURN_IF_ERROR(ReadInt(mj, p, "id", &m.id));
    FL_RETURN_IF_ERROR(ReadInt(mj, p, "parent_map", &m.parent_map));
    FL_RETURN_IF_ERROR(ReadInt(mj, p, "parent_unit", &m.parent_unit));
    FL_RETURN_IF_ERROR(ReadInt(mj, p, "depth", &m.depth));
    FL_RETURN_IF_ERROR(ReadInt(mj, p, "rows", &m.rows));
    FL_RETURN_IF_ERROR(ReadInt(mj, p, "cols", &m.cols));
    FL_RETURN_IF_ERROR(ReadDouble(mj, p, "mqe_parent", &m.mqe_parent));
    FL_RETURN_IF_ERROR(ReadDouble(mj, p, "mqe", &m.mqe));
    FL_RETURN_IF_ERROR(ReadDouble(mj, p, "qe", &m.qe));
    FL_RETURN_IF_ERROR(ReadDouble(mj, p, "te", &m.te));
    FL_RETURN_IF_ERROR(ReadInt(mj, p, "input_count", &m.input_count));
    FL_RETURN_IF_ERROR(ReadInt(mj, p, "insertions", &m.insertions));
    FL_RETURN_IF_ERROR(ReadInt(mj, p, "topographic_errors", &m.topographic_errors));
    if (m.id < 0 || m.id >= g.next_map_id_ || (!g.maps_.empty() && m.id <= g.maps_.back().id)) {
      return Bad(p + ".id", "map ids must ascend and stay below next_map_id");
    }
    if (i == 0 && (m.parent_map != -1 || m.depth != 1)) {
      return Bad(p, "the first map must be the layer-1 map (parent_map -1, depth 1)");
    }
    if (m.rows < 1 || m.cols < 1 || static_cast<long>(m.rows) * m.cols > kMaxUnitsLimit) {
      return Bad(p + ".rows", "grid " + std::to_string(m.rows) + " x " + std::to_string(m.cols) + " is not valid");
    }
    if (m.qe < 0 || m.mqe < 0 || m.te < 0 || m.te > 1 || m.input_count < 0 || m.topographic_errors < 0 ||
        m.topographic_errors > m.input_count) {
      return Bad(p,
                 "negative or out-of-range statistics (qe, mqe, te, "
                 "input_count, topographic_errors)");
    }
    if (i > 0) {
      const GhsomMap* parent = g.map(m.parent_map);
      if (parent == nullptr || m.parent_unit < 0 || m.parent_unit >= parent->unit_count() ||
          parent->units[static_cast<std::size_t>(m.parent_unit)].child_map != m.id || m.depth != parent->depth + 1) {
        return Bad(p + ".parent_map", "map " + std::to_string(m.id) +
                                          " does not hang under an earlier "
                                          "map's unit that names it as child");
      }
    }
    FL_ASSIGN_OR_RETURN(const json* units_json, Field(mj, p, "units"));
    if (!units_json->is_array() || static_cast<int>(units_json->size()) != m.rows * m.cols) {
      return Bad(p + ".units", "expected rows x cols = " + std::to_string(m.rows * m.cols) + " units");
    }
    m.weights.resize(m.rows * m.cols, dim);
    int total_inputs = 0;
    for (std::size_t u = 0; u < units_json->size(); ++u) {
      const json& uj = (*units_json)[u];
      const std::string up = p + ".units[" + std::to_string(u) + "]";
      GhsomUnit unit;
      FL_ASSIGN_OR_RETURN(const json* weight_json, Field(uj, up, "weight"));
      FL_RETURN_IF_ERROR(ReadVector(*weight_json, up + ".weight", dim, &row));
      m.weights.row(static_cast<Eigen::Index>(u)) = row.transpose();
      FL_ASSIGN_OR_RETURN(const json* unit_inputs, Field(uj, up, "inputs"));
      FL_RETURN_IF_ERROR(ReadIntArray(*unit_inputs, up + ".inputs", &unit.inputs));
      for (std::size_t k = 0; k < unit.inputs.size(); ++k) {
        if (unit.inputs[k] < 0 || unit.inputs[k] >= n_inputs || (k > 0 && unit.inputs[k] <= unit.inputs[k - 1])) {
          return Bad(up + ".inputs[" + std::to_string(k) + "]",
                     "input rows must ascend and lie in [0, " + std::to_string(n_inputs) + ")");
        }
      }
      total_inputs += static_cast<int>(unit.inputs.size());
      FL_RETURN_IF_ERROR(ReadDouble(uj, up, "mqe", &unit.mqe));
      FL_RETURN_IF_ERROR(ReadDouble(uj, up, "radius", &unit.radius));
      FL_RETURN_IF_ERROR(ReadInt(uj, up, "child_map", &unit.child_map));
      if (unit.mqe < 0) return Bad(up + ".mqe", "must be >= 0");
      if (!(unit.radius >= kMinLeafRadius)) return Bad(up + ".radius", "must be >= " + Num(kMinLeafRadius));
      if (unit.child_map != -1 && (unit.child_map <= m.id || unit.child_map >= g.next_map_id_)) {
        return Bad(up + ".child_map", "must be -1 or the id of a later map");
      }
      m.units.push_back(std::move(unit));
    }
    if (total_inputs != m.input_count) {
      return Bad(p + ".input_count", "is " + std::to_string(m.input_count) + " but the units hold " +
                                         std::to_string(total_inputs) + " inputs");
    }
    if (i == 0 && m.input_count != n_inputs) {
      return Bad(p + ".input_count", "the layer-1 map must hold all " + std::to_string(n_inputs) + " inputs");
    }
    g.maps_.push_back(std::move(m));
  }
  // Every child link must point at a map that exists (the parent check above covers the converse).
  for (std::size_t i = 0; i < g.maps_.size(); ++i) {
    for (std::size_t u = 0; u < g.maps_[i].units.size(); ++u) {
      const int child = g.maps_[i].units[u].child_map;
      if (child >= 0 && g.map(child) == nullptr) {
        return Bad("maps[" + std::to_string(i) + "].units[" + std::to_string(u) + "].child_map",
                   "names map " + std::to_string(child) + ", which is not in the file");
      }
    }
  }
  return g;
}

}  // namespace formloop::retrieval
