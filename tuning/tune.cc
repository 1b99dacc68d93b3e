#include "tuning/tune.h"

#include <algorithm>
#include <cmath>
#include <regex>
#include <set>
#include <sstream>

#include "core/atomic_file.h"
#include "core/json_io.h"
#include "core/log.h"
#include "core/point_io.h"

namespace formloop::tuning {
namespace {

namespace fs = std::filesystem;
constexpr const char* kReportFormat = "formloop.tune_report";
constexpr const char* kPartialMarker = ".formloop-tune-partial";

struct MeasuredPoint {
  Eigen::Vector3d position;
  std::optional<double> time_s;
};

Result<std::map<int, MeasuredPoint>> ReadMeasuredPoints(const fs::path& path) {
  FL_ASSIGN_OR_RETURN(const PointSet set, ReadCsv(path));
  if (!set.has_ids()) {
    return Status::BadInput(Where{.file = path.string(), .field = "id"}, "the points file has no id column",
                            "write the header id,x,y,z[,t] with the model's probe point ids");
  }
  std::map<int, MeasuredPoint> out;
  for (std::size_t i = 0; i < set.size(); ++i) {
    const auto id = set.ids[i];
    if (id < 1 || id > 2000) {
      return Status::BadInput(Where{.file = path.string(), .field = "id"},
                              "point id " + std::to_string(id) + " is outside 1..2000",
                              "use the model's probe point ids");
    }
    MeasuredPoint p{set.points[i], std::nullopt};
    if (set.has_times()) p.time_s = set.times_s[i];
    if (!out.emplace(static_cast<int>(id), p).second) {
      return Status::BadInput(Where{.file = path.string(), .field = "id"},
                              "point id " + std::to_string(id) + " appears twice",
                              "keep one measurement per point (the collector de-duplicates by id)");
    }
  }
  return out;
}

std::string Join(const std::vector<std::string>& v, const std::string& sep = ", ") {
  std::string out;
  for (const auto& s : v) out += (out.empty() ? "" : sep) + s;
  return out;
}

Json OptionalNumber(const std::optional<double>& v) { return v ? Json(*v) : Json(nullptr); }

// A length for a message: binary noise below a picometre dropped ("0.025", not "0.025000000000000355").
std::string MmText(double mm) { return Json(std::round(mm * 1e9) / 1e9).dump(); }

// One pass: block, dimensions, offset problem, strategy, rounding, limits.
Result<TuneAttempt> Attempt(const MeasurementModel& model, const std::map<int, MeasuredPoint>& measured,
                            const fs::path& block_path, const std::map<std::string, double>& previous,
                            const TuneOptions& options, std::vector<Json>* audit) {
  TuneAttempt at;
  std::vector<double> times;
  for (const auto& [id, p] : measured) {
    if (p.time_s) times.push_back(*p.time_s);
  }
  if (!block_path.empty()) {
    FL_ASSIGN_OR_RETURN(const metrology::StandardBlock block, metrology::ReadStandardBlockCsv(block_path));
    FL_ASSIGN_OR_RETURN(at.corrector, metrology::BlockCorrector::Build(block, model.block_mode));
    at.block_file = block_path.string();
    at.block_age = metrology::CheckBlockAge(block, times, model.block_max_age_s);
    Json line = {{"step", "block"},
                 {"file", at.block_file},
                 {"correction", at.corrector->ToJson()},
                 {"age_checked", at.block_age.checked},
                 {"max_gap_s", at.block_age.max_gap_s},
                 {"max_age_s", model.block_max_age_s},
                 {"stale", at.block_age.stale}};
    if (!at.block_age.checked) line["note"] = "the block or the points carry no times: the block's age was not checked";
    audit->push_back(line);
    if (!at.block_age.checked)
      log::Warn("standard block: no times in the block or the points file, its age is not checked");
  } else {
    audit->push_back({{"step", "block"}, {"file", nullptr}, {"note", "no standard-block correction"}});
  }

  // Dimensions.
  for (const ModelDimension& d : model.dimensions) {
    DimensionResult r;
    r.dimension = &d;
    for (const auto& ref : d.points) r.point_ids.push_back(ref.id);
    if (d.mode == DimensionMode::kIgnore) {
      r.state = "IGNORED";
      at.dimensions.push_back(r);
      continue;
    }
    std::vector<metrology::RolePoints> roles;
    std::vector<std::string> missing, invalid;
    for (const PointRef& ref : d.points) {
      const ModelPoint& mp = *model.FindPoint(ref.id);
      auto it = measured.find(ref.id);
      if (it == measured.end()) {
        missing.push_back(std::to_string(ref.id));
        continue;
      }
      metrology::ProbedPoint p;
      p.id = ref.id;
      p.approach = mp.approach;
      p.measured = mp.measured;
      p.u_mm = mp.u_mm;
      p.position = mp.reference_mm;
      for (int a = 0; a < 3; ++a) {
        if (!mp.measured[a]) continue;
        const double off = it->second.position(a) - mp.reference_mm(a);
        if (std::abs(off) > model.max_point_deviation_mm) {
          invalid.push_back("point " + std::to_string(ref.id) + ", axis " + "XYZ"[a] + ": " + MmText(off) +
                            " mm from its reference (limit " + MmText(model.max_point_deviation_mm) + " mm)");
        }
        p.position(a) = it->second.position(a);
      }
      if (at.corrector) {
        bool extrapolated = false;
        p.position = at.corrector->Correct(p.position, p.measured, &extrapolated);
        r.extrapolated = r.extrapolated || extrapolated;
      }
      auto role = std::find_if(roles.begin(), roles.end(), [&](const auto& x) { return x.role == ref.role; });
      if (role == roles.end()) {
        roles.push_back({ref.role, {}});
        role = roles.end() - 1;
      }
      role->points.push_back(p);
    }
    if (!missing.empty()) {
      r.state = "NOT_MEASURED";
      r.problem = "point(s) " + Join(missing) + " missing from the points file";
    } else if (!invalid.empty()) {
      r.state = "INVALID";
      r.problem = "invalid measurement: " + Join(invalid, "; ");
    } else {
      auto e = metrology::EvaluateDimension(d.definition, roles);
      if (!e.ok()) {
        r.state = "INVALID";
        r.problem = e.status().message();
      } else {
        r.state = "MEASURED";
        r.evaluation = *e;
        r.judgement = metrology::Judge(d.tolerance, e->value, e->expanded_u);
      }
    }
    Json line = {{"step", "dimension"},
                 {"id", d.id},
                 {"type", metrology::DimensionTypeName(d.definition.type)},
                 {"mode", DimensionModeName(d.mode)},
                 {"points", r.point_ids},
                 {"state", r.state}};
    if (r.state == "MEASURED") {
      line["value"] = r.evaluation.value;
      line["u"] = r.evaluation.u;
      line["nominal"] = d.tolerance.nominal;
      line["tol_lower"] = d.tolerance.lower;
      line["tol_upper"] = d.tolerance.upper;
      line["deviation"] = r.judgement.deviation;
      line["ok"] = r.judgement.ok;
      line["excess"] = r.judgement.excess;
      if (r.extrapolated) line["block_extrapolated"] = true;
    } else {
      line["problem"] = r.problem;
    }
    audit->push_back(line);
    at.dimensions.push_back(r);
  }

  // The offset problem: COMPENSATE dimensions that were measured.
  OffsetProblem& p = at.problem;
  const int k = static_cast<int>(model.offsets.size());
  for (const auto& o : model.offsets) p.offset_ids.push_back(o.id);
  std::vector<Eigen::Triplet<double>> triplets;
  std::vector<double> e, lo, hi, target, weight;
  for (std::size_t i = 0; i < at.dimensions.size(); ++i) {
    const DimensionResult& r = at.dimensions[i];
    const ModelDimension& d = *r.dimension;
    if (d.mode != DimensionMode::kCompensate || r.state != "MEASURED") continue;
    const int row = static_cast<int>(p.dimension_ids.size());
    p.dimension_ids.push_back(d.id);
    at.problem_rows.push_back(static_cast<int>(i));
    for (const auto& [id, kij] : d.k_row) triplets.emplace_back(row, model.OffsetIndex(id), kij);
    e.push_back(r.judgement.deviation);
    lo.push_back(d.tolerance.lower);
    hi.push_back(d.tolerance.upper);
    target.push_back(d.target == DimensionTarget::kBandCentre ? 0.5 * (d.tolerance.lower + d.tolerance.upper) : 0.0);
    weight.push_back(d.weight);
  }
  const int n = static_cast<int>(p.dimension_ids.size());
  p.k.resize(n, k);
  p.k.setFromTriplets(triplets.begin(), triplets.end());
  auto vec = [](const std::vector<double>& v) {
    return Eigen::VectorXd(Eigen::Map<const Eigen::VectorXd>(v.data(), v.size()));
  };
  p.deviation_mm = vec(e);
  p.tol_lower_mm = vec(lo);
  p.tol_upper_mm = vec(hi);
  p.target_mm = vec(target);
  p.weight = vec(weight);
  p.delta_min_mm.resize(k);
  p.delta_max_mm.resize(k);
  p.offset_weight.resize(k);
  p.resolution_mm.resize(k);
  for (int j = 0; j < k; ++j) {
    p.delta_min_mm(j) = model.offsets[j].delta_min_mm;
    p.delta_max_mm(j) = model.offsets[j].delta_max_mm;
    p.offset_weight(j) = model.offsets[j].weight;
    p.resolution_mm(j) = model.offsets[j].resolution_mm;
  }

  Eigen::VectorXd delta = Eigen::VectorXd::Zero(k);
  if (n > 0 && options.strategy == Strategy::kWls) {
    FL_ASSIGN_OR_RETURN(at.wls, SolveOffsets(p, model.solver));
    at.rounded = at.wls->rounded;
    for (int row = 0; row < n; ++row) {
      DimensionResult& r = at.dimensions[at.problem_rows[row]];
      r.not_reachable = at.wls->not_reachable[row];
      r.r_eq_mm = at.wls->r_eq_mm(row);
    }
    Json line = {{"step", "solve"},
                 {"strategy", "wls"},
                 {"rho", model.solver.rho},
                 {"band_shrink", model.solver.band_shrink},
                 {"dimensions", p.dimension_ids},
                 {"offsets", p.offset_ids},
                 {"deviation_mm", std::vector<double>(p.deviation_mm.data(), p.deviation_mm.data() + n)},
                 {"result", at.wls->ToJson()}};
    audit->push_back(line);
  } else if (n > 0) {
    FL_ASSIGN_OR_RETURN(at.average, AverageWearCompensation(p, model.average));
    FL_ASSIGN_OR_RETURN(at.rounded, RoundOffsets(p, at.average->delta_mm, model.solver));
    audit->push_back({{"step", "solve"},
                      {"strategy", "average"},
                      {"skip_band_mm", model.average.skip_band_mm},
                      {"max_mm", model.average.max_mm},
                      {"result", at.average->ToJson(p)}});
  } else {
    at.rounded.delta_mm = delta;
    at.rounded.delta_rounded_mm = delta;
    at.rounded.rule.assign(k, "no COMPENSATE dimension was measured: no change");
    audit->push_back({{"step", "solve"}, {"note", "no COMPENSATE dimension was measured: nothing to solve"}});
  }
  for (int j = 0; j < k; ++j) {
    audit->push_back({{"step", "rounding"},
                      {"offset", model.offsets[j].id},
                      {"delta_mm", at.rounded.delta_mm(j)},
                      {"resolution_mm", model.offsets[j].resolution_mm},
                      {"delta_min_mm", model.offsets[j].delta_min_mm},
                      {"delta_max_mm", model.offsets[j].delta_max_mm},
                      {"rounded_mm", at.rounded.delta_rounded_mm(j)},
                      {"rule", at.rounded.rule[j]}});
  }
  // Predictions after the rounded change, for every judged dimension with a K row.
  for (DimensionResult& r : at.dimensions) {
    if (r.state != "MEASURED") continue;
    const ModelDimension& d = *r.dimension;
    double change = 0;
    for (const auto& [id, kij] : d.k_row) change += kij * at.rounded.delta_rounded_mm(model.OffsetIndex(id));
    const double after = r.evaluation.value + change;
    r.predicted_value_after = after;
    r.predicted_ok_after = metrology::Judge(d.tolerance, after).ok;
  }
  at.changes = CheckOffsetLimits(model, at.rounded.delta_mm, at.rounded.delta_rounded_mm, at.rounded.rule, previous);
  for (const auto& c : at.changes) {
    Json line = {{"step", "limits"},
                 {"offset", c.offset->id},
                 {"previous_mm", OptionalNumber(c.previous_mm)},
                 {"delta_mm", c.delta_mm},
                 {"baseline_mm", c.offset->baseline_mm},
                 {"limit_mm", c.offset->limit_mm},
                 {"step_limit_mm", OptionalNumber(c.offset->step_limit_mm)},
                 {"checked", c.checked},
                 {"within_limits", c.within_limits}};
    if (c.checked) line["new_mm"] = c.new_mm;
    if (!c.violation.empty()) line["violation"] = c.violation;
    audit->push_back(line);
  }
  return at;
}

// Reasons other than the limits that block the write, and the dimensions that will stay NG.
std::vector<std::string> BlockReasons(const MeasurementModel& model, const TuneAttempt& at, const TuneOptions& options,
                                      bool have_previous, std::vector<std::string>* stay_ng) {
  std::vector<std::string> reasons;
  if (!have_previous) {
    reasons.push_back(
        "current offsets unknown: pass --offsets CURRENT.json with the values read from the controller "
        "at acquisition start");
  }
  if (at.block_age.stale) {
    reasons.push_back("BLOCK_STALE: the standard block was probed " + Json(at.block_age.max_gap_s).dump() +
                      " s away from the part points (limit " + Json(model.block_max_age_s).dump() +
                      " s); probe the block in this session");
  }
  if (at.wls && at.wls->solver.status == BoundedLsqStatus::kMaxIter) {
    reasons.push_back("MAX_ITER: the offset solve did not converge");
  }
  for (const auto& r : at.dimensions) {
    if (r.dimension->mode == DimensionMode::kCompensate && (r.state == "NOT_MEASURED" || r.state == "INVALID")) {
      reasons.push_back("dimension " + r.dimension->id + " " + r.state + ": " + r.problem);
    }
  }
  for (const auto& r : at.dimensions) {
    if (r.dimension->mode != DimensionMode::kCompensate || r.state != "MEASURED") continue;
    if (r.not_reachable || (r.predicted_ok_after && !*r.predicted_ok_after)) stay_ng->push_back(r.dimension->id);
  }
  // A TOLERANCE_ONLY dimension never drives the offsets, but its K row says what the change does to it: one
  // that is OK now and NG after the change is harmed by the write and needs the same acknowledgement.
  std::vector<std::string> made_ng;
  for (const auto& r : at.dimensions) {
    if (r.dimension->mode != DimensionMode::kToleranceOnly || r.state != "MEASURED" || r.dimension->k_row.empty())
      continue;
    if (r.judgement.ok && r.predicted_ok_after && !*r.predicted_ok_after) made_ng.push_back(r.dimension->id);
  }
  const auto unacknowledged = [&](const std::vector<std::string>& ids) {
    std::vector<std::string> out;
    for (const auto& id : ids) {
      if (std::find(options.acknowledge_ng.begin(), options.acknowledge_ng.end(), id) == options.acknowledge_ng.end())
        out.push_back(id);
    }
    return out;
  };
  if (const auto ids = unacknowledged(*stay_ng); !ids.empty()) {
    reasons.push_back("dimension(s) " + Join(ids) +
                      " will stay NG after the change (NOT_REACHABLE within the offset bounds or NG after rounding): "
                      "writing needs --acknowledge-ng " +
                      Join(ids, ","));
  }
  if (const auto ids = unacknowledged(made_ng); !ids.empty()) {
    reasons.push_back("TOLERANCE_ONLY dimension(s) " + Join(ids) +
                      " are OK now and NG after the change (predicted through their K rows): writing needs "
                      "--acknowledge-ng " +
                      Join(ids, ","));
  }
  stay_ng->insert(stay_ng->end(), made_ng.begin(), made_ng.end());
  if (at.average && at.average->alarm && !options.accept_alarm) {
    std::vector<std::string> cells;
    for (const auto& c : at.average->cells) {
      if (c.alarm) cells.push_back(model.offsets[c.offset].id + " " + MmText(c.value_mm) + " mm");
    }
    reasons.push_back("ALARM: " + Join(cells) + " beyond the allowed maximum " + MmText(model.average.max_mm) +
                      " mm; send only after the operator confirms (--accept-alarm)");
  }
  return reasons;
}

Json DimensionRecord(const DimensionResult& r, const TuneReport& report, const MeasurementModel& model,
                     const TuneOptions& options, const std::string& block_mode) {
  const ModelDimension& d = *r.dimension;
  const bool measured = r.state == "MEASURED";
  Json j = {
      {"id", d.id},
      {"name", d.name},
      {"type", metrology::DimensionTypeName(d.definition.type)},
      {"method", metrology::DimensionMethodName(metrology::ResolvedMethod(d.definition.type, d.definition.method))},
      {"unit", d.angle ? "deg" : "mm"},
      {"mode", DimensionModeName(d.mode)},
      {"state", r.state},
      {"measured_at", options.measured_at.empty() ? Json(nullptr) : Json(options.measured_at)},
      {"part_code", model.part_code},
      {"machine_serial", model.machine_serial},
      {"session", report.plan.session},
      {"nominal", d.tolerance.nominal},
      {"tol_upper", d.tolerance.upper},
      {"tol_lower", d.tolerance.lower},
      {"points", r.point_ids.size()},
      {"block_mode", block_mode}};
  if (measured) {
    j["actual"] = r.evaluation.value;
    j["deviation"] = r.judgement.deviation;
    j["ok"] = r.judgement.ok;
    j["judgement"] = r.judgement.ok ? "OK" : "NG";
    j["excess"] = r.judgement.excess;
    j["u"] = r.evaluation.u;
    j["expanded_u"] = r.evaluation.expanded_u;
    j["ambiguous"] = r.judgement.ambiguous;
    j["predicted_after"] = OptionalNumber(r.predicted_value_after);
    j["predicted_ok_after"] = r.predicted_ok_after ? Json(*r.predicted_ok_after) : Json(nullptr);
    if (d.mode == DimensionMode::kCompensate) {
      j["not_reachable"] = r.not_reachable;
      j["r_eq"] = r.r_eq_mm;
    }
    if (r.extrapolated) j["block_extrapolated"] = true;
  } else if (!r.problem.empty()) {
    j["problem"] = r.problem;
    j["judgement"] = "NG";
  }
  return j;
}

std::string Fixed(double v) { return FormatFixed(v, 6); }

std::string ReportCsv(const TuneAttempt& at) {
  std::ostringstream out;
  out << "id,type,mode,state,nominal,tol_lower,tol_upper,actual,deviation,judgement,excess,u,points,predicted_after,"
         "predicted_after_judgement\n";
  for (const auto& r : at.dimensions) {
    const ModelDimension& d = *r.dimension;
    out << d.id << ',' << metrology::DimensionTypeName(d.definition.type) << ',' << DimensionModeName(d.mode) << ','
        << r.state << ',' << Fixed(d.tolerance.nominal) << ',' << Fixed(d.tolerance.lower) << ','
        << Fixed(d.tolerance.upper) << ',';
    if (r.state == "MEASURED") {
      out << Fixed(r.evaluation.value) << ',' << Fixed(r.judgement.deviation) << ',' << (r.judgement.ok ? "OK" : "NG")
          << ',' << Fixed(r.judgement.excess) << ',' << Fixed(r.evaluation.u) << ',' << r.point_ids.size() << ','
          << (r.predicted_value_after ? Fixed(*r.predicted_value_after) : "") << ','
          << (r.predicted_ok_after ? (*r.predicted_ok_after ? "OK" : "NG") : "") << '\n';
    } else {
      out << ",," << (r.state == "IGNORED" ? "" : "NG") << ",,," << r.point_ids.size() << ",,\n";
    }
  }
  return out.str();
}

std::string SummaryText(const TuneReport& report, const MeasurementModel& model, const TuneOptions& options) {
  const TuneAttempt& at = report.final_attempt();
  std::ostringstream s;
  s << "formloop tune: part " << (model.part_code.empty() ? "?" : model.part_code) << ", session '"
    << report.plan.session << "', strategy " << StrategyName(options.strategy) << "\n";
  int judged = 0;
  for (const auto& r : at.dimensions) judged += r.state != "IGNORED";
  s << judged << " dimension(s) judged, " << report.ng_count << " NG"
    << (report.ng_count > 0 ? " (hold the machine before the next part)" : "") << "\n";
  for (const auto& r : at.dimensions) {
    if (r.state == "IGNORED") continue;
    s << "  " << r.dimension->id << " " << metrology::DimensionTypeName(r.dimension->definition.type) << ": ";
    if (r.state == "MEASURED") {
      s << Fixed(r.evaluation.value) << " (dev " << Fixed(r.judgement.deviation) << ") "
        << (r.judgement.ok ? "OK" : "NG");
      if (r.predicted_value_after) {
        s << " -> predicted " << Fixed(*r.predicted_value_after) << " " << (*r.predicted_ok_after ? "OK" : "NG");
      }
    } else {
      s << r.state << ": " << r.problem;
    }
    s << "\n";
  }
  s << "offset changes:\n";
  bool any = false;
  for (const auto& c : at.changes) {
    if (c.delta_mm == 0) continue;
    any = true;
    s << "  " << c.offset->id << ": " << Fixed(c.delta_mm) << " mm";
    if (c.previous_mm) s << " (" << Fixed(*c.previous_mm) << " -> " << Fixed(c.new_mm) << ")";
    if (!c.within_limits) s << "  BEYOND LIMIT: " << c.violation;
    s << "\n";
  }
  if (!any) s << "  none\n";
  s << "write plan: " << PlanStatusName(report.plan.status)
    << (report.plan.confirmed
            ? ", confirmed"
            : (report.plan.status == PlanStatus::kSafe ? ", waiting for confirmation (--confirm)" : ""))
    << "\n";
  for (const auto& reason : report.plan.blocked_reasons) s << "  - " << reason << "\n";
  return s.str();
}

Status PrepareOutput(const TuneOptions& options, fs::path* partial) {
  std::error_code ec;
  const fs::path out = fs::weakly_canonical(options.out, ec);
  for (const fs::path& input :
       {options.model, options.points, options.block, options.recheck_block, options.current_offsets}) {
    if (input.empty()) continue;
    const fs::path in = fs::weakly_canonical(input, ec);
    const auto rel = in.lexically_relative(out);
    if (!rel.empty() && *rel.begin() != "..") {
      return Status::BadInput(
          Where{.field = "--out"},
          "input '" + input.string() + "' lies inside the output folder '" + options.out.string() + "'",
          "choose an output folder that holds none of the inputs");
    }
  }
  const fs::path cwd = fs::weakly_canonical(fs::current_path(ec), ec);
  if (const auto rel = cwd.lexically_relative(out); !rel.empty() && *rel.begin() != "..") {
    return Status::BadInput(Where{.field = "--out"},
                            "the output folder '" + options.out.string() + "' contains the current directory",
                            "choose an output folder outside the current directory's path");
  }
  if (fs::exists(options.out, ec)) {
    if (!options.force) {
      return Status::BadInput(Where{.field = "--out"}, "output folder '" + options.out.string() + "' already exists",
                              "choose another folder or pass --force to replace an earlier tune output");
    }
    auto previous = ReadJsonFile(options.out / "report.json");
    if (!previous.ok() || !previous->is_object() || previous->value("format", "") != kReportFormat) {
      return Status::BadInput(Where{.field = "--out"},
                              "'" + options.out.string() +
                                  "' does not hold a formloop tune output (no report.json of format " + kReportFormat +
                                  "); formloop replaces only what it wrote",
                              "choose another folder");
    }
  }
  *partial = options.out;
  *partial += ".partial";
  if (fs::exists(*partial, ec)) {
    if (!fs::exists(*partial / kPartialMarker, ec)) {
      return Status::BadInput(Where{.field = "--out"},
                              "'" + partial->string() + "' exists and was not made by formloop tune",
                              "move it away or choose another output folder");
    }
    fs::remove_all(*partial, ec);
  }
  if (options.out.has_parent_path()) FL_RETURN_IF_ERROR(MakeDirectories(options.out.parent_path()));
  FL_RETURN_IF_ERROR(MakeDirectories(*partial));
  return WriteFileAtomic(*partial / kPartialMarker, "formloop tune output in progress\n");
}

}  // namespace

const char* StrategyName(Strategy strategy) { return strategy == Strategy::kWls ? "wls" : "average"; }

bool ParseStrategy(const std::string& text, Strategy* strategy) {
  if (text == "wls")
    *strategy = Strategy::kWls;
  else if (text == "average")
    *strategy = Strategy::kAverage;
  else
    return false;
  return true;
}

Status TuneOptions::Validate() const {
  if (model.empty())
    return Status::BadInput(Where{.field = "--model"}, "no measurement model given", "pass --model M.json");
  if (points.empty())
    return Status::BadInput(Where{.field = "--points"}, "no probe points given", "pass --points P.csv");
  if (out.empty()) return Status::BadInput(Where{.field = "--out"}, "no output folder given", "pass --out DIR");
  if (!measured_at.empty()) {
    static const std::regex kIso8601(R"(\d{4}-\d{2}-\d{2}T\d{2}:\d{2}(:\d{2}(\.\d+)?)?(Z|[+-]\d{2}:?\d{2}))");
    if (!std::regex_match(measured_at, kIso8601)) {
      return Status::BadInput(Where{.field = "--measured-at"},
                              "value '" + measured_at + "' is not ISO 8601 with a time zone",
                              "write e.g. 2026-11-26T12:00:00+01:00 or 2026-11-26T11:00:00Z");
    }
  }
  if (!recheck_block.empty() && recheck_block == block) {
    return Status::BadInput(Where{.field = "--recheck-block"}, "is the same file as --block",
                            "probe the standard block again and pass the new file");
  }
  return Status::Ok();
}

Json TuneReport::SummaryJson() const {
  const TuneAttempt& at = final_attempt();
  Json writes = Json::array();
  for (const auto& c : at.changes) {
    if (c.delta_mm != 0)
      writes.push_back({{"offset", c.offset->id}, {"delta_mm", c.delta_mm}, {"within_limits", c.within_limits}});
  }
  return {{"status", PlanStatusName(plan.status)},
          {"confirmed", plan.confirmed},
          {"ng", ng_count},
          {"rechecked", recheck.has_value()},
          {"changes", writes},
          {"blocked_reasons", plan.blocked_reasons}};
}

Result<TuneReport> RunTune(const TuneOptions& options) {
  FL_RETURN_IF_ERROR(options.Validate());
  FL_ASSIGN_OR_RETURN(MeasurementModel read_model, ReadMeasurementModel(options.model));
  auto shared_model = std::make_shared<const MeasurementModel>(std::move(read_model));
  const MeasurementModel& model = *shared_model;
  FL_ASSIGN_OR_RETURN(const auto measured, ReadMeasuredPoints(options.points));
  std::map<std::string, double> previous;
  const bool have_previous = !options.current_offsets.empty();
  if (have_previous) {
    FL_ASSIGN_OR_RETURN(previous, ReadCurrentOffsets(options.current_offsets, model));
  }
  for (const auto& id : options.acknowledge_ng) {
    if (std::none_of(model.dimensions.begin(), model.dimensions.end(), [&](const auto& d) { return d.id == id; })) {
      return Status::BadInput(Where{.field = "--acknowledge-ng"}, "dimension '" + id + "' is not in the model",
                              "name the dimensions by their ids");
    }
  }
  fs::path partial;
  FL_RETURN_IF_ERROR(PrepareOutput(options, &partial));

  TuneReport report;
  report.model = shared_model;
  report.plan.strategy = StrategyName(options.strategy);
  report.plan.session = options.session.empty() ? (model.part_code.empty() ? std::string("part") : model.part_code) +
                                                      " " + options.points.filename().string()
                                                : options.session;
  std::set<int> used;
  for (const auto& d : model.dimensions) {
    for (const auto& p : d.points) used.insert(p.id);
  }
  std::vector<std::string> unused;
  for (const auto& [id, p] : measured) {
    if (!used.count(id)) unused.push_back(std::to_string(id));
  }
  report.audit.push_back({{"step", "inputs"},
                          {"model", options.model.string()},
                          {"points", options.points.string()},
                          {"points_read", measured.size()},
                          {"points_not_in_any_dimension", unused},
                          {"current_offsets", have_previous ? Json(options.current_offsets.string()) : Json(nullptr)},
                          {"strategy", StrategyName(options.strategy)},
                          {"session", report.plan.session},
                          {"acknowledge_ng", options.acknowledge_ng},
                          {"accept_alarm", options.accept_alarm},
                          {"confirm", options.confirm}});
  if (!unused.empty()) log::Warn("points file: {} point(s) belong to no dimension: {}", unused.size(), Join(unused));

  auto attempt = Attempt(model, measured, options.block, previous, options, &report.audit);
  if (!attempt.ok()) {
    std::error_code ec;
    fs::remove_all(partial, ec);
    return attempt.status();
  }
  report.first = std::move(attempt).value();

  // The ladder.
  bool beyond = have_previous && !AllWithinLimits(report.first.changes);
  if (beyond && !options.recheck_block.empty()) {
    report.audit.push_back({{"step", "ladder"},
                            {"decision", "RECHECK"},
                            {"reason", "an offset is beyond its limit; recomputing with the re-probed block"},
                            {"recheck_block", options.recheck_block.string()}});
    auto second = Attempt(model, measured, options.recheck_block, previous, options, &report.audit);
    if (!second.ok()) {
      std::error_code ec;
      fs::remove_all(partial, ec);
      return second.status();
    }
    report.recheck = std::move(second).value();
    beyond = !AllWithinLimits(report.recheck->changes);
  } else if (!options.recheck_block.empty()) {
    report.audit.push_back(
        {{"step", "ladder"}, {"note", "--recheck-block not used: every offset is within its limits"}});
  }
  const TuneAttempt& at = report.final_attempt();
  std::vector<std::string> stay_ng;
  std::vector<std::string> others = BlockReasons(model, at, options, have_previous, &stay_ng);
  WritePlan& plan = report.plan;
  plan.changes = at.changes;
  if (beyond) {
    for (const auto& c : at.changes) {
      if (!c.within_limits) plan.blocked_reasons.push_back(c.violation);
    }
    if (report.recheck) {
      plan.status = PlanStatus::kIntervene;
      plan.blocked_reasons.push_back(
          "INTERVENE: still beyond the limit after the standard-block re-check; hold the machine (alarm/feed hold) and "
          "act by hand. Limits are changed only through an audited configuration change, not here");
    } else {
      plan.status = PlanStatus::kRecheck;
      plan.blocked_reasons.push_back(
          "RECHECK: probe the standard block again and rerun with --recheck-block NEW_BLOCK.csv; nothing is written");
    }
  } else if (!others.empty()) {
    plan.status = PlanStatus::kBlocked;
  } else {
    plan.status = PlanStatus::kSafe;
  }
  for (const auto& r : others) plan.blocked_reasons.push_back(r);
  for (const auto& id : stay_ng) {
    if (std::find(options.acknowledge_ng.begin(), options.acknowledge_ng.end(), id) != options.acknowledge_ng.end()) {
      plan.not_reachable_acknowledged.push_back(id);
    }
  }
  plan.confirmed = options.confirm && plan.status == PlanStatus::kSafe;
  if (options.accept_alarm && at.average && at.average->alarm) {
    report.audit.push_back({{"step", "alarm"},
                            {"accepted_by_operator", true},
                            {"note", "values beyond the allowed maximum sent on the operator's confirmation"}});
  }
  report.audit.push_back({{"step", "status"},
                          {"status", PlanStatusName(plan.status)},
                          {"blocked_reasons", plan.blocked_reasons},
                          {"will_stay_ng", stay_ng},
                          {"acknowledged", plan.not_reachable_acknowledged}});
  report.audit.push_back({{"step", "confirmation"},
                          {"requested", options.confirm},
                          {"confirmed", plan.confirmed},
                          {"note", plan.confirmed ? "operator confirmed the whole set (--confirm)"
                                                  : (options.confirm ? "not confirmed: the plan is not SAFE"
                                                                     : "waiting for the operator's confirmation")}});
  for (const auto& r : at.dimensions)
    report.ng_count += r.state != "IGNORED" && !(r.state == "MEASURED" && r.judgement.ok);

  // Outputs.
  const std::string block_mode = at.corrector ? metrology::BlockModeName(at.corrector->mode()) : "NONE";
  Json dims = Json::array();
  for (const auto& r : at.dimensions) dims.push_back(DimensionRecord(r, report, model, options, block_mode));
  Json offsets = Json::array();
  for (const auto& c : at.changes) {
    offsets.push_back({{"offset", c.offset->id},
                       {"kind", OffsetKindName(c.offset->kind)},
                       {"delta_continuous_mm", c.delta_continuous_mm},
                       {"delta_mm", c.delta_mm},
                       {"rule", c.rule},
                       {"previous_mm", OptionalNumber(c.previous_mm)},
                       {"new_mm", c.previous_mm ? Json(c.new_mm) : Json(nullptr)},
                       {"within_limits", c.within_limits}});
  }
  Json report_json = {{"format", kReportFormat},
                      {"version", 1},
                      {"session", plan.session},
                      {"part_code", model.part_code},
                      {"drawing_revision", model.drawing_revision},
                      {"machine_serial", model.machine_serial},
                      {"measured_at", options.measured_at.empty() ? Json(nullptr) : Json(options.measured_at)},
                      {"strategy", StrategyName(options.strategy)},
                      {"block", at.corrector ? at.corrector->ToJson() : Json(nullptr)},
                      {"block_file", at.block_file.empty() ? Json(nullptr) : Json(at.block_file)},
                      {"rechecked", report.recheck.has_value()},
                      {"ng", report.ng_count},
                      {"hold_before_next_part", report.ng_count > 0},
                      {"dimensions", dims},
                      {"offsets", offsets},
                      {"status", PlanStatusName(plan.status)}};
  if (at.wls) report_json["solve"] = at.wls->ToJson();
  if (at.average) report_json["average"] = at.average->ToJson(at.problem);
  std::string audit_text;
  for (const auto& line : report.audit) audit_text += line.dump() + "\n";
  Status status = WriteJsonFile(partial / "report.json", report_json);
  if (status.ok()) status = WriteFileAtomic(partial / "report.csv", ReportCsv(at));
  if (status.ok()) status = WriteJsonFile(partial / "offsets.json", plan.ToJson());
  if (status.ok()) status = WriteFileAtomic(partial / "audit.jsonl", audit_text);
  if (status.ok()) status = WriteFileAtomic(partial / "summary.txt", SummaryText(report, model, options));
  std::error_code ec;
  if (status.ok()) fs::remove(partial / kPartialMarker, ec);
  if (!status.ok()) {
    fs::remove_all(partial, ec);
    return status;
  }
  fs::remove_all(options.out, ec);
  fs::rename(partial, options.out, ec);
  if (ec)
    return Status::IoError("cannot rename '" + partial.string() + "' to '" + options.out.string() +
                           "': " + ec.message());
  log::Info("tune: {} dimension(s) NG; write plan {}{}", report.ng_count, PlanStatusName(plan.status),
            plan.confirmed ? " (confirmed)" : "");
  return report;
}

}  // namespace formloop::tuning
