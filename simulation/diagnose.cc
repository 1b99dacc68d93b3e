// Diagnose's data kinds (diagnose.h): probe logs of one part or of several parts of one machine, and a
// plan and log without the run. Each builds the engine's Problem (diagnose_engine.h).

#include "simulation/diagnose.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <map>

#include "core/json_io.h"
#include "metrology/deviations.h"
#include "simulation/diagnose_engine.h"
#include "simulation/virtual_machine.h"

namespace formloop::sim {
namespace {

Eigen::MatrixXd ProbeJacobian(const std::vector<PointContext>& contexts, const Effect* e,
                              const std::vector<double>& theta) {
  const int p = e->parameter_count();
  Eigen::MatrixXd j(contexts.size(), p);
  std::vector<double> row(p);
  for (std::size_t i = 0; i < contexts.size(); ++i) {
    e->Jacobian(contexts[i], theta, row);
    for (int k = 0; k < p; ++k) j(static_cast<Eigen::Index>(i), k) = row[k];
  }
  return j;
}

}  // namespace

namespace detail {

Result<Problem> BuildProbeProblem(const std::vector<PartRows>& sets, const std::vector<std::string>& labels, int knn,
                                  const std::vector<DirectMeasurement>& direct) {
  Problem prob;
  int n = 0, parts = 0;
  bool fixed_sigma = false;
  for (std::size_t p = 0; p < sets.size(); ++p) {
    const int m = static_cast<int>(sets[p].contexts->size());
    if (sets[p].residual_um->size() != m) return Status::Internal("residuals and contexts differ in size");
    const MeasurementSensitivity* s = sets[p].sensitivity;
    if (s != nullptr && (s->surface.size() != m || s->radius.size() != m)) {
      return Status::Internal("measurement sensitivities and contexts differ in size");
    }
    parts = std::max(parts, (sets[p].part >= 0 ? sets[p].part : static_cast<int>(p)) + 1);
    fixed_sigma = fixed_sigma || sets[p].sigma_um > 0;
    n += m;
  }
  if (static_cast<int>(labels.size()) != parts) return Status::Internal("BuildProbeProblem: one label per part");
  prob.r.resize(n);
  prob.weight = Eigen::VectorXd::Ones(n);
  prob.xy.resize(n, 2);
  prob.pos.resize(n, 3);
  prob.part_names = parts > 1 ? labels : std::vector<std::string>{""};
  double t_max = 0;
  std::vector<double> sigma_of_row;
  for (std::size_t p = 0, row = 0; p < sets.size(); ++p) {
    for (std::size_t i = 0; i < sets[p].contexts->size(); ++i, ++row) {
      const PointContext& c = (*sets[p].contexts)[i];
      prob.r[static_cast<Eigen::Index>(row)] = (*sets[p].residual_um)[static_cast<Eigen::Index>(i)];
      prob.xy.row(static_cast<Eigen::Index>(row)) = c.point.head<2>().transpose();
      prob.pos.row(static_cast<Eigen::Index>(row)) = c.point.transpose();
      prob.part_of.push_back(sets[p].part >= 0 ? sets[p].part : static_cast<int>(p));
      sigma_of_row.push_back(sets[p].sigma_um);
      t_max = std::max(t_max, c.cut_time_s);
    }
  }
  FL_ASSIGN_OR_RETURN(prob.neighbours, KnnLists(prob.pos, knn, &prob.part_of));
  // Direct measurements: the part each belongs to and its parameter's column.
  struct DirectRow {
    const Effect* effect;
    int column, part;
    double value, sigma;
  };
  std::vector<DirectRow> direct_rows;
  for (const DirectMeasurement& d : direct) {
    FL_RETURN_IF_ERROR(d.Validate());
    const Effect* e = FindEffect(d.effect);
    int column = 0;
    while (e->parameters()[column].name != d.parameter) ++column;
    int part = 0;
    if (!d.part.empty()) {
      const auto it = std::find(labels.begin(), labels.end(), d.part);
      if (it == labels.end()) {
        return Status::BadInput(Where{.field = "direct measurement part"}, "no part is labelled '" + d.part + "'",
                                "use one of the parts' labels (their run folders' names)");
      }
      part = static_cast<int>(it - labels.begin());
    }
    direct_rows.push_back({e, column, part, d.value, d.sigma});
  }
  if (!direct_rows.empty()) {
    // Every row weighted by 1/σ: the points by their part's nugget σ̂ (as when pooling), a direct
    // measurement by its own σ.
    prob.points = n;
    const int total = n + static_cast<int>(direct_rows.size());
    prob.r.conservativeResize(total);
    prob.weight = Eigen::VectorXd::Ones(total);
    prob.xy.conservativeResize(total, 2);
    prob.pos.conservativeResize(total, 3);
    prob.neighbours.resize(static_cast<std::size_t>(total));
    for (std::size_t k = 0; k < direct_rows.size(); ++k) {
      const Eigen::Index row = n + static_cast<Eigen::Index>(k);
      prob.r[row] = direct_rows[k].value;
      prob.xy.row(row).setZero();
      prob.pos.row(row).setZero();
      prob.part_of.push_back(direct_rows[k].part);
      sigma_of_row.push_back(direct_rows[k].sigma);
    }
    fixed_sigma = true;
  }
  if (fixed_sigma || parts > 1) {
    for (int p = 0; p < parts; ++p) {
      std::vector<int> rows;
      for (int i = 0; i < n; ++i) {
        if (prob.part_of[static_cast<std::size_t>(i)] == p && !(sigma_of_row[static_cast<std::size_t>(i)] > 0)) {
          rows.push_back(i);
        }
      }
      if (rows.empty()) continue;
      double sum = 0;
      for (int i : rows) {
        const double d = prob.r[i] - prob.r[prob.neighbours[static_cast<std::size_t>(i)].front()];
        sum += 0.5 * d * d;
      }
      const double sigma = std::sqrt(sum / static_cast<double>(rows.size()));
      if (!(sigma > 0)) return Status::BadInput("part " + labels[p] + ": the residual has no scatter at all");
      for (int i : rows) prob.weight[i] = 1.0 / sigma;
    }
    for (int i = 0; i < prob.n(); ++i) {
      if (sigma_of_row[static_cast<std::size_t>(i)] > 0)
        prob.weight[i] = 1.0 / sigma_of_row[static_cast<std::size_t>(i)];
    }
    prob.r = prob.r.cwiseProduct(prob.weight);
  }
  prob.applicable = [](const Effect*) { return true; };
  prob.jacobian = [sets, n, direct_rows](const Effect* e, const std::vector<double>& theta) {
    Eigen::MatrixXd j = Eigen::MatrixXd::Zero(n + static_cast<Eigen::Index>(direct_rows.size()), e->parameter_count());
    for (std::size_t k = 0; k < direct_rows.size(); ++k) {
      if (direct_rows[k].effect == e) j(n + static_cast<Eigen::Index>(k), direct_rows[k].column) = 1.0;
    }
    Eigen::Index row = 0;
    for (const PartRows& set : sets) {
      const std::vector<PointContext>& contexts = *set.contexts;
      const Eigen::MatrixXd jp = ProbeJacobian(contexts, e, theta);
      for (Eigen::Index i = 0; i < jp.rows(); ++i, ++row) {
        j.row(row) = jp.row(i);
        if (set.sensitivity == nullptr) continue;
        const PointContext& c = contexts[static_cast<std::size_t>(i)];
        if (e->kind() == EffectKind::kMeasurement) {
          // The basis is ΔR·c_a; the measured response to ΔR is radius[i].
          const double ca = std::max(1e-6, -c.approach.dot(c.normal));
          j.row(row) *= set.sensitivity->radius[i] / ca;
        } else {
          j.row(row) *= set.sensitivity->surface[i];
        }
      }
    }
    return j;
  };
  prob.time_scale_s = std::max(1.0, t_max);
  return prob;
}

}  // namespace detail

namespace {

// The stacked problem of one or more parts, diagnosed. With several, each part's rows are weighted by
// 1/σ̂ of its noise (nugget of its residual), so parts measured with different scatter count by their
// precision.
Result<Diagnosis> DiagnoseParts(const std::vector<detail::PartRows>& parts, const std::vector<std::string>& labels,
                                const Model& baseline, const DiagnoseOptions& options) {
  FL_RETURN_IF_ERROR(options.Validate());
  for (std::size_t p = 0; p < parts.size(); ++p) {
    const std::size_t m = parts[p].contexts->size();
    if (m < 20) {
      return Status::BadInput("diagnose needs at least 20 measured points per part, got " + std::to_string(m) +
                              (parts.size() > 1 ? " in part " + labels[p] : std::string()));
    }
  }
  for (const DirectMeasurement& d : options.direct) {
    if (baseline.Has(d.effect)) {
      return Status::BadInput(Where{.field = "direct measurement " + d.effect + "." + d.parameter},
                              "the baseline model already holds " + d.effect + ", so it is not diagnosed",
                              "diagnose against a baseline without it, or put the measured value into the baseline");
    }
  }
  FL_ASSIGN_OR_RETURN(const detail::Problem prob,
                      detail::BuildProbeProblem(parts, labels, options.knn, options.direct));
  FL_ASSIGN_OR_RETURN(Diagnosis out, detail::RunEngine(prob, baseline, options));
  // What the fit makes of each measured parameter (NaN: its effect is not named, or the parameter is
  // inside an alias group).
  out.direct = options.direct;
  for (const DirectMeasurement& d : options.direct) {
    const std::string part = parts.size() > 1 ? (d.part.empty() ? labels.front() : d.part) : std::string();
    double fitted = std::numeric_limits<double>::quiet_NaN();
    for (const Cause& c : out.causes) {
      if (c.effect != d.effect || (FindEffect(d.effect)->part_specific() && c.part != part)) continue;
      for (std::size_t j = 0; j < c.parameter_names.size(); ++j) {
        if (c.parameter_names[j] == d.parameter) fitted = c.parameters[j];
      }
    }
    out.direct_fitted.push_back(fitted);
  }
  return out;
}

std::vector<std::string> LabelsFor(std::size_t parts, const std::vector<std::string>& labels) {
  if (!labels.empty()) return labels;
  std::vector<std::string> out;
  for (std::size_t p = 0; p < parts; ++p) out.push_back(std::to_string(p + 1));
  return out;
}

}  // namespace

Status DirectMeasurement::Validate() const {
  const Effect* e = FindEffect(effect);
  if (e == nullptr) {
    return Status::BadInput(Where{.field = "effect"}, "unknown effect '" + effect + "'", "use one of " + EffectNames());
  }
  bool known = false;
  std::string names;
  for (const auto& p : e->parameters()) {
    known = known || p.name == parameter;
    names += (names.empty() ? "" : ", ") + p.name;
  }
  if (!known) {
    return Status::BadInput(Where{.field = "parameter"}, effect + " has no parameter '" + parameter + "'",
                            "use one of " + names);
  }
  if (!std::isfinite(value)) {
    return Status::BadInput(Where{.field = "value"}, "must be a finite number");
  }
  for (const auto& p : e->parameters()) {
    if (p.name == parameter && !p.linear) {
      return Status::BadInput(Where{.field = "parameter"}, "a nonlinear parameter cannot be measured directly");
    }
  }
  if (!(sigma > 0) || !std::isfinite(sigma)) {
    return Status::BadInput(Where{.field = "sigma"}, "must be > 0", "the measurement's standard uncertainty");
  }
  return Status::Ok();
}

nlohmann::json DirectMeasurement::ToJson() const {
  nlohmann::json j = {{"effect", effect}, {"parameter", parameter}, {"value", value}, {"sigma", sigma}, {"by", by}};
  if (!part.empty()) j["part"] = part;
  return j;
}

Result<std::vector<DirectMeasurement>> ReadDirectMeasurements(const std::string& path) {
  FL_ASSIGN_OR_RETURN(const Json j, ReadJsonFile(path));
  if (!j.is_object() || !j.contains("direct_measurements")) {
    return Status::BadInput(Where{.file = path, .field = "direct_measurements"}, "missing",
                            "give {\"direct_measurements\": [{\"effect\": \"tool_radius\", \"parameter\": "
                            "\"delta_r_um\", \"value\": 6.1, \"sigma\": 1.0, \"by\": \"tool setter\"}]}");
  }
  return DirectMeasurementsFromJson(j["direct_measurements"], path, "direct_measurements");
}

Result<std::vector<DirectMeasurement>> DirectMeasurementsFromJson(const nlohmann::json& list, const std::string& source,
                                                                  const std::string& field) {
  const std::string& path = source;
  if (!list.is_array()) {
    return Status::BadInput(Where{.file = path, .field = field}, "not an array",
                            "give [{\"effect\": \"tool_radius\", \"parameter\": \"delta_r_um\", \"value\": 6.1, "
                            "\"sigma\": 1.0, \"by\": \"tool setter\"}, ...]");
  }
  std::vector<DirectMeasurement> out;
  for (std::size_t i = 0; i < list.size(); ++i) {
    const std::string at = field + "[" + std::to_string(i) + "]";
    const Json& e = list[i];
    if (!e.is_object()) return Status::BadInput(Where{.file = path, .field = at}, "must be an object");
    DirectMeasurement d;
    for (const char* key : {"effect", "parameter"}) {
      if (!e.contains(key) || !e[key].is_string()) {
        return Status::BadInput(Where{.file = path, .field = at + "." + key}, "missing or not a string");
      }
    }
    for (const char* key : {"value", "sigma"}) {
      if (!e.contains(key) || !e[key].is_number()) {
        return Status::BadInput(Where{.file = path, .field = at + "." + key}, "missing or not a number",
                                "in the parameter's unit (the catalogue's: um, urad, um/m)");
      }
    }
    d.effect = e["effect"].get<std::string>();
    d.parameter = e["parameter"].get<std::string>();
    d.value = e["value"].get<double>();
    d.sigma = e["sigma"].get<double>();
    d.part = e.value("part", "");
    d.by = e.value("by", "");
    const Status valid = d.Validate();
    if (!valid.ok()) {
      return Status::BadInput(Where{.file = path, .field = at}, std::string(valid.message()),
                              "see docs/diagnose.md, direct measurements");
    }
    for (const auto& o : out) {
      if (o.effect == d.effect && o.parameter == d.parameter && o.part == d.part) {
        return Status::BadInput(Where{.file = path, .field = at}, "measures " + d.effect + "." + d.parameter + " twice",
                                "average repeated measurements into one value and its uncertainty");
      }
    }
    out.push_back(d);
  }
  return out;
}

Status DiagnoseOptions::Validate() const {
  if (!(alpha > 0 && alpha < 1)) return Status::BadInput(Where{.field = "alpha"}, "must be in (0, 1)");
  if (!(alias_alpha > 0 && alias_alpha < 1)) {
    return Status::BadInput(Where{.field = "alias_alpha"}, "must be in (0, 1)");
  }
  if (!(alias_bic >= 0)) return Status::BadInput(Where{.field = "alias_bic"}, "must be >= 0");
  if (!(pair_alias_share >= 0 && pair_alias_share <= 1)) {
    return Status::BadInput(Where{.field = "pair_alias_share"}, "must be in [0, 1]");
  }
  if (max_causes < 1) return Status::BadInput(Where{.field = "max_causes"}, "must be >= 1");
  if (!(min_share >= 0 && min_share < 1)) return Status::BadInput(Where{.field = "min_share"}, "must be in [0, 1)");
  if (knn < 1) return Status::BadInput(Where{.field = "knn"}, "must be >= 1");
  if (cv_blocks < 2) return Status::BadInput(Where{.field = "cv_blocks"}, "must be >= 2");
  for (const auto& d : direct) FL_RETURN_IF_ERROR(d.Validate());
  for (const auto& c : candidates) {
    if (FindEffect(c) == nullptr) {
      return Status::BadInput(Where{.field = "candidates"}, "unknown effect '" + c + "'",
                              "use one of " + EffectNames());
    }
  }
  return Status::Ok();
}

Result<Diagnosis> DiagnoseResiduals(const std::vector<PointContext>& contexts, const Eigen::VectorXd& residual_um,
                                    const Model& baseline, const DiagnoseOptions& options,
                                    const MeasurementSensitivity* sensitivity) {
  return DiagnoseParts({detail::PartRows{&contexts, &residual_um, sensitivity}}, {""}, baseline, options);
}

Result<Diagnosis> DiagnosePooledResiduals(const std::vector<ProbeResidualData>& parts, const Model& baseline,
                                          const DiagnoseOptions& options, const std::vector<std::string>& labels) {
  if (parts.empty()) return Status::BadInput("diagnose needs at least one part");
  if (!labels.empty() && labels.size() != parts.size()) {
    return Status::Internal("DiagnosePooledResiduals: one label per part");
  }
  std::vector<detail::PartRows> rows;
  for (const auto& p : parts) rows.push_back({&p.contexts, &p.residual_um, &p.sensitivity});
  return DiagnoseParts(rows, LabelsFor(parts.size(), labels), baseline, options);
}

Result<Diagnosis> DiagnosePooled(const std::vector<ProbeDataInput>& inputs, const Model& baseline,
                                 const DiagnoseOptions& options, const std::vector<std::string>& labels) {
  std::vector<ProbeResidualData> parts;
  for (const auto& in : inputs) {
    FL_ASSIGN_OR_RETURN(ProbeResidualData data, ProbeResiduals(in, baseline));
    parts.push_back(std::move(data));
  }
  return DiagnosePooledResiduals(parts, baseline, options, labels);
}

Result<ProbeResidualData> ProbeResiduals(const ProbeDataInput& in, const Model& baseline) {
  if (in.surface == nullptr || in.cutter_locations == nullptr || in.plan == nullptr || in.measured == nullptr) {
    return Status::Internal("ProbeResiduals: missing input");
  }
  std::map<std::int64_t, const metrology::ProbePoint*> by_id;
  for (const auto& p : in.plan->points) by_id[p.id] = &p;
  std::vector<MeasuredPoint> points;
  for (const auto& rec : in.measured->records) {
    const auto it = by_id.find(rec.id);
    if (it == by_id.end()) {
      return Status::BadInput(Where{.file = in.measured->source, .line = rec.line},
                              "probe id " + std::to_string(rec.id) + " is not in the probing plan",
                              "give the plan the log was measured with");
    }
    points.push_back({rec.id, it->second->point, it->second->normal, rec.approach});
  }
  ProbeResidualData out;
  FL_ASSIGN_OR_RETURN(out.contexts, AssociateWithToolpath(*in.cutter_locations, in.tool_radius_mm, points));
  auto deviations_um = [&](const metrology::ProbeLog& log) -> Result<Eigen::VectorXd> {
    FL_ASSIGN_OR_RETURN(const auto dev, metrology::ComputeDeviations(*in.surface, *in.plan, log, in.probe));
    Eigen::VectorXd d(static_cast<Eigen::Index>(dev.size()));
    for (std::size_t i = 0; i < dev.size(); ++i) d[static_cast<Eigen::Index>(i)] = 1e3 * dev[i].deviation_mm;
    return d;
  };
  FL_ASSIGN_OR_RETURN(const Eigen::VectorXd measured, deviations_um(*in.measured));
  FL_ASSIGN_OR_RETURN(const Eigen::VectorXd simulated,
                      deviations_um(PredictProbeLog(out.contexts, baseline, in.probe)));
  out.residual_um = measured - simulated;
  // Sensitivities by a 1 µm step through the same chain (the response is linear to ~1e-4 over tens of µm).
  FL_ASSIGN_OR_RETURN(const Eigen::VectorXd shifted,
                      deviations_um(PredictProbeLog(out.contexts, baseline, in.probe, 1.0, 0.0)));
  FL_ASSIGN_OR_RETURN(const Eigen::VectorXd widened,
                      deviations_um(PredictProbeLog(out.contexts, baseline, in.probe, 0.0, 1.0)));
  out.sensitivity.surface = shifted - simulated;
  out.sensitivity.radius = widened - simulated;
  return out;
}

Result<Diagnosis> Diagnose(const ProbeDataInput& input, const Model& baseline, const DiagnoseOptions& options) {
  FL_ASSIGN_OR_RETURN(const ProbeResidualData data, ProbeResiduals(input, baseline));
  return DiagnoseResiduals(data.contexts, data.residual_um, baseline, options, &data.sensitivity);
}

Result<double> PredictionRms(const ProbeDataInput& input, const Model& model) {
  FL_ASSIGN_OR_RETURN(const ProbeResidualData data, ProbeResiduals(input, model));
  return std::sqrt(data.residual_um.squaredNorm() / std::max<Eigen::Index>(1, data.residual_um.size()));
}

Result<Diagnosis> DiagnosePlanOnly(const metrology::ProbingPlan& plan, const metrology::ProbeLog& measured,
                                   const metrology::ProbeModel& probe, const Model& baseline, DiagnoseOptions options) {
  std::map<std::int64_t, const metrology::ProbePoint*> by_id;
  for (const auto& p : plan.points) by_id[p.id] = &p;
  std::vector<PointContext> contexts;
  Eigen::VectorXd r(static_cast<Eigen::Index>(measured.records.size()));
  for (std::size_t i = 0; i < measured.records.size(); ++i) {
    const auto& rec = measured.records[i];
    const auto it = by_id.find(rec.id);
    if (it == by_id.end()) {
      return Status::BadInput(Where{.file = measured.source, .line = rec.line},
                              "probe id " + std::to_string(rec.id) + " is not in the probing plan",
                              "give the plan the log was measured with");
    }
    PointContext c;
    c.id = rec.id;
    c.point = it->second->point;
    c.normal = it->second->normal;
    c.approach = rec.approach;
    const double measured_um = 1e3 * (metrology::ContactPoint(rec, probe) - c.point).dot(c.normal);
    r[static_cast<Eigen::Index>(i)] = measured_um - baseline.DeviationUm(c);
    contexts.push_back(c);
  }
  options.toolpath_known = false;
  return DiagnoseResiduals(contexts, r, baseline, options);
}

}  // namespace formloop::sim
