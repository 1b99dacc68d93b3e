#include "metrology/probe_log_analysis.h"

#include <algorithm>
#include <cmath>
#include <unordered_map>

#include "core/log.h"
#include "core/number_text.h"
#include "reconstruction/foot_point.h"

namespace formloop::metrology {
namespace {

// One probe record on its way through compensation, registration and projection.
struct Measured {
  const ProbeRecord* record = nullptr;
  Eigen::Vector3d contact = Eigen::Vector3d::Zero();  // compensated (and registered) contact point
  const ProbePoint* planned = nullptr;                // with a plan
  recon::FootPoint foot;
  std::string flag;  // empty = used
};

Status ProjectAll(const recon::FootPointProjector& projector, double max_distance_mm, std::vector<Measured>* points) {
  for (Measured& m : *points) {
    Result<recon::FootPoint> foot = m.planned != nullptr ? projector.ProjectFrom(m.contact, m.planned->u, m.planned->v)
                                                         : projector.Project(m.contact);
    if (!foot.ok()) {
      return foot.status().WithContext("probe log line " + std::to_string(m.record->line) + " (id " +
                                       std::to_string(m.record->id) + ")");
    }
    m.foot = foot.value();
    m.flag.clear();
    if (!(m.foot.distance_mm <= max_distance_mm)) {
      m.flag = "farther from Q than the search distance";
    } else if (m.foot.on_boundary) {
      m.flag = "beyond the edge of Q (foot point held at the boundary; not a normal deviation)";
    } else if (m.foot.outside_trim) {
      m.flag =
          "outside the trimmed face (foot point over a hole or past the face's edge; not a deviation from the part)";
    }
  }
  return Status::Ok();
}

std::vector<double> FiniteOrZero(const Eigen::VectorXd& values) {
  std::vector<double> out;
  out.reserve(static_cast<std::size_t>(values.size()));
  for (long i = 0; i < values.size(); ++i) out.push_back(std::isfinite(values[i]) ? values[i] : 0.0);
  return out;
}

std::vector<double> ClusterCodes(const std::vector<LisaCluster>& clusters) {
  std::vector<double> out;
  out.reserve(clusters.size());
  for (LisaCluster c : clusters) out.push_back(static_cast<double>(static_cast<int>(c)));
  return out;
}

std::vector<double> Scaled(const std::vector<double>& values, double factor) {
  std::vector<double> out;
  out.reserve(values.size());
  for (double v : values) out.push_back(v * factor);
  return out;
}

}  // namespace

Status ProbeLogAnalysisOptions::Validate() const {
  FL_RETURN_IF_ERROR(decomposition.Validate());
  if (!(max_distance_mm > 0) || !std::isfinite(max_distance_mm)) {
    return Status::BadInput(Where{.field = "max_distance_mm"}, "must be a positive distance", "use e.g. 1");
  }
  if (lisa_permutations < 0) {
    return Status::BadInput(Where{.field = "lisa_permutations"}, "must be >= 0", "use e.g. 999, or 0");
  }
  if (!(lisa_alpha > 0 && lisa_alpha < 1)) {
    return Status::BadInput(Where{.field = "lisa_alpha"}, "must lie in (0, 1)", "use e.g. 0.05");
  }
  return Status::Ok();
}

nlohmann::json FlaggedPoint::ToJson() const {
  return {{"id", id}, {"line", line},    {"distance_mm", distance_mm}, {"deviation_um", deviation_um}, {"u", u},
          {"v", v},   {"reason", reason}};
}

Result<ProbeLogAnalysis> AnalyseProbeLog(const recon::BSplineSurface& q, const ProbeLog& log, const ProbeModel& probe,
                                         const ProbingPlan* plan, const ProbeLogAnalysisOptions& options) {
  FL_RETURN_IF_ERROR(options.Validate());
  FL_RETURN_IF_ERROR(probe.Validate());
  ProbeLogAnalysis a;
  a.records = log.records.size();

  // 1. Probe compensation along each record's own approach direction.
  std::unordered_map<std::int64_t, const ProbePoint*> planned;
  if (plan != nullptr) {
    FL_ASSIGN_OR_RETURN(a.not_measured, CheckProbeLogAgainstPlan(log, *plan));
    for (const auto& p : plan->points) planned[p.id] = &p;
  }
  std::vector<Measured> measured(log.records.size());
  for (std::size_t i = 0; i < log.records.size(); ++i) {
    measured[i].record = &log.records[i];
    measured[i].contact = ContactPoint(log.records[i], probe);
    if (plan != nullptr) measured[i].planned = planned.at(log.records[i].id);
  }

  // 2. Foot points; far points are flagged. 3. Registration (when asked for) uses the points not
  // flagged, then every point is moved and projected again.
  FL_ASSIGN_OR_RETURN(const recon::FootPointProjector projector, recon::FootPointProjector::Build(q));
  FL_RETURN_IF_ERROR(ProjectAll(projector, options.max_distance_mm, &measured));
  if (std::any_of(options.registration.begin(), options.registration.end(), [](bool b) { return b; })) {
    std::vector<Eigen::Vector3d> near;
    for (const Measured& m : measured) {
      if (m.flag.empty()) near.push_back(m.contact);
    }
    RegistrationOptions ro;
    ro.dofs = options.registration;
    ro.max_distance_mm = options.max_distance_mm;
    FL_ASSIGN_OR_RETURN(const RegistrationReport report, RegisterToSurface(near, projector, ro));
    for (Measured& m : measured) m.contact = report.part_from_machine * m.contact;
    FL_RETURN_IF_ERROR(ProjectAll(projector, options.max_distance_mm, &measured));
    log::Info("analyse: registered {} points ({}), rms {:.2f} -> {:.2f} um", report.points,
              DofMaskToString(options.registration), report.rms_before_mm * 1e3, report.rms_after_mm * 1e3);
    a.registration = report;
  }
  for (const Measured& m : measured) {
    if (!m.flag.empty()) {
      a.flagged.push_back({.id = m.record->id,
                           .line = m.record->line,
                           .distance_mm = m.foot.distance_mm,
                           .deviation_um = m.foot.deviation_mm * 1e3,
                           .u = m.foot.u,
                           .v = m.foot.v,
                           .reason = m.flag});
      continue;
    }
    Deviation d;
    d.id = m.record->id;
    d.u = m.foot.u;
    d.v = m.foot.v;
    d.contact = m.contact;
    d.foot = m.foot.foot;
    d.normal = m.foot.normal;
    d.deviation_mm = m.foot.deviation_mm;
    d.on_boundary = m.foot.on_boundary;
    a.deviations.push_back(d);
    a.lines.push_back(m.record->line);
  }
  // A log most of whose points are not on Q does not measure this part (another part, a wrong work offset
  // or surface): refused, not analysed on the few that happen to be near.
  if (2 * a.flagged.size() > measured.size()) {
    const FlaggedPoint& first = a.flagged.front();
    return Status::BadInput(
        Where{.file = log.source},
        std::to_string(a.flagged.size()) + " of " + std::to_string(measured.size()) +
            " points lie farther from Q than the search distance " + FormatSignificant(options.max_distance_mm, 4) +
            " mm or past its edge (the first on line " + std::to_string(first.line) + ", " +
            FormatSignificant(first.distance_mm, 4) + " mm away)",
        "check that the log belongs to this part and that the log and Q share one frame (work offset); "
        "registration (--register) can align a part that is only shifted");
  }
  if (!a.flagged.empty()) {
    log::Warn(
        "analyse: {} of {} points flagged (beyond {} mm of Q or past its edge) and left out; see "
        "flagged_points in analysis.json",
        a.flagged.size(), measured.size(), options.max_distance_mm);
  }

  // 4. Decomposition (raw Moran, the ladder, d_s, d_f, d_u, the evaluation against the tolerance).
  Result<Decomposition> decomposed = Decompose(a.deviations, q.domain(), options.decomposition);
  if (!decomposed.ok()) {
    return decomposed.status().WithContext("analyse " + log.source + " (" + std::to_string(a.deviations.size()) +
                                           " points used, " + std::to_string(a.flagged.size()) + " flagged)");
  }
  a.decomposition = std::move(decomposed).value();

  // 5. Local Moran of the deviations and of d_u on the decomposition's k-NN weights in (u, v). d_u is a
  // least-squares residual, so its values are not exchangeable in the strict sense; the conditional-
  // randomisation p-values are the usual screening approximation (as for the raw deviations) and the
  // ladder's global residual test is the exact one. When d_u is identically zero (the model reproduces
  // every point) there is nothing to map.
  const long n = static_cast<long>(a.deviations.size());
  Eigen::VectorXd y(n), y_um(n), y_random(n);
  for (long i = 0; i < n; ++i) {
    const auto k = static_cast<std::size_t>(i);
    y[i] = a.deviations[k].deviation_mm;
    y_um[i] = a.deviations[k].deviation_mm * 1e3;
    y_random[i] = a.decomposition.random_mm[k];
  }
  FL_ASSIGN_OR_RETURN(const SpatialWeights weights, UvKnnWeights(a.deviations, options.decomposition.neighbours));
  const LocalMoranOptions lisa_options{.islands = IslandPolicy::kRefuse,
                                       .permutations = options.lisa_permutations,
                                       .seed = options.lisa_seed,
                                       .alpha = options.lisa_alpha};
  FL_ASSIGN_OR_RETURN(a.lisa, LocalMoranI(y, weights, lisa_options));
  FL_ASSIGN_OR_RETURN(const Eigen::VectorXd lag_um, SpatialLag(y_um, weights));
  a.lag_um.assign(lag_um.data(), lag_um.data() + lag_um.size());
  if ((y_random.array() - y_random.mean()).square().sum() > 0) {
    FL_ASSIGN_OR_RETURN(a.lisa_random, LocalMoranI(y_random, weights, lisa_options));
  }
  return a;
}

nlohmann::json ProbeLogAnalysis::DeviationSummaryJson() const {
  const long n = static_cast<long>(deviations.size());
  double sum = 0, sum2 = 0;
  long peak = 0;
  for (long i = 0; i < n; ++i) {
    const double y = deviations[static_cast<std::size_t>(i)].deviation_mm;
    sum += y;
    sum2 += y * y;
    if (std::abs(y) > std::abs(deviations[static_cast<std::size_t>(peak)].deviation_mm)) peak = i;
  }
  const Deviation& pd = deviations[static_cast<std::size_t>(peak)];
  return {{"n_records", records},
          {"n_used", n},
          {"n_flagged", flagged.size()},
          {"mean_um", sum / static_cast<double>(n) * 1e3},
          {"rms_um", std::sqrt(sum2 / static_cast<double>(n)) * 1e3},
          {"max_abs_um", std::abs(pd.deviation_mm) * 1e3},
          {"max_abs_at",
           {{"id", pd.id},
            {"line", lines[static_cast<std::size_t>(peak)]},
            {"deviation_um", pd.deviation_mm * 1e3},
            {"u", pd.u},
            {"v", pd.v},
            {"contact_mm", {pd.contact.x(), pd.contact.y(), pd.contact.z()}}}}};
}

nlohmann::json ProbeLogAnalysis::FlaggedJson() const {
  nlohmann::json out = nlohmann::json::array();
  for (const FlaggedPoint& f : flagged) out.push_back(f.ToJson());
  return out;
}

nlohmann::json ProbeLogAnalysis::LisaRandomJson() const {
  if (!lisa_random) {
    return {{"of", "the random part d_u"},
            {"note", "d_u is identically zero (the model reproduces every point): nothing to map"}};
  }
  nlohmann::json out = lisa_random->SummaryJson();
  out["of"] =
      "the random part d_u (the residual of the field and, when it ran, the spatial filter), same k-NN weights in "
      "(u, v), row-standardised";
  out["note"] =
      "d_u is a least-squares residual: its p-values are a screening approximation; the ladder's residual Moran "
      "z (Cliff-Ord) is the exact global test";
  nlohmann::json significant = nlohmann::json::array();
  for (std::size_t k = 0; k < deviations.size(); ++k) {
    const long i = static_cast<long>(k);
    const LisaCluster c = lisa_random->cluster[k];
    if (c == LisaCluster::kNotSignificant || c == LisaCluster::kIsland) continue;
    significant.push_back({{"id", deviations[k].id},
                           {"u", deviations[k].u},
                           {"v", deviations[k].v},
                           {"random_um", decomposition.random_mm[k] * 1e3},
                           {"I_i", lisa_random->i[i]},
                           {"z", lisa_random->z[i]},
                           {"p", lisa_random->permutations > 0 ? lisa_random->p_sim[i] : lisa_random->p_analytical[i]},
                           {"cluster", LisaClusterName(c)}});
  }
  out["significant_points"] = significant;
  return out;
}

PointSet ProbeLogAnalysis::PerPointTable() const {
  PointSet points = DeviationsToPoints(deviations);
  points.SetScalar("systematic_um", Scaled(decomposition.systematic_mm, 1e3));
  points.SetScalar("fine_scale_um", Scaled(decomposition.fine_scale_mm, 1e3));
  points.SetScalar("random_um", Scaled(decomposition.random_mm, 1e3));
  points.SetScalar("lag_um", lag_um);
  points.SetScalar("lisa_cluster", ClusterCodes(lisa.cluster));
  points.SetScalar("local_moran", FiniteOrZero(lisa.i));
  if (lisa_random) {
    points.SetScalar("local_moran_random", FiniteOrZero(lisa_random->i));
    points.SetScalar("lisa_cluster_random", ClusterCodes(lisa_random->cluster));
  } else {
    points.SetScalar("local_moran_random", std::vector<double>(deviations.size(), 0.0));
    points.SetScalar("lisa_cluster_random",
                     std::vector<double>(deviations.size(), static_cast<double>(LisaCluster::kNotSignificant)));
  }
  return points;
}

nlohmann::json ProbeLogAnalysis::PerPointColumns() {
  return {{"u", "foot-point parameter"},
          {"v", "foot-point parameter"},
          {"foot_x", "foot point on Q, mm"},
          {"foot_y", "foot point on Q, mm"},
          {"foot_z", "foot point on Q, mm"},
          {"deviation_um", "signed normal deviation, um (positive = material left)"},
          {"on_boundary", "1 when the foot point lies on the edge of Q, else 0"},
          {"systematic_um", "d_s at the point, um"},
          {"fine_scale_um",
           "d_f at the point, um: correlated structure finer than the field, taken out by the spatial filter when the "
           "field's residual is correlated (0 otherwise); never compensated"},
          {"random_um", "d_u = deviation - d_s - d_f, um"},
          {"lag_um", "spatial lag of the centred deviation, um (the Moran scatter's y-axis)"},
          {"lisa_cluster", "LISA cluster of the deviations: 0 not significant, 1 HH, 2 LH, 3 LL, 4 HL, 5 island"},
          {"local_moran", "local Moran I_i of the deviations (dimensionless)"},
          {"local_moran_random", "local Moran I_i of the random part d_u (dimensionless; 0 when d_u is all zero)"},
          {"lisa_cluster_random", "LISA cluster of d_u, same codes as lisa_cluster"}};
}

}  // namespace formloop::metrology
