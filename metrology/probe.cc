#include "metrology/probe.h"

#include <cmath>
#include <map>
#include <optional>
#include <set>
#include <string_view>
#include <utility>

#include "core/atomic_file.h"
#include "core/json_io.h"
#include "core/number_text.h"
#include "core/point_io.h"
#include "reconstruction/trim.h"

namespace formloop::metrology {

nlohmann::json ProbingPlan::ToJson() const {
  nlohmann::json points_json = nlohmann::json::array();
  for (const ProbePoint& p : points) {
    points_json.push_back({{"id", p.id},
                           {"u", p.u},
                           {"v", p.v},
                           {"point", {p.point.x(), p.point.y(), p.point.z()}},
                           {"normal", {p.normal.x(), p.normal.y(), p.normal.z()}}});
  }
  nlohmann::json out = {{"count", points.size()}, {"points", points_json}};
  if (trimmed) {
    out["trim"] = {{"edge_margin_mm", edge_margin_mm},
                   {"left_out", left_out},
                   {"rule",
                    "points inside the trimmed face (OpenCASCADE classification) and at least edge_margin_mm "
                    "(3-D distance) from its loops"}};
  }
  return out;
}

bool ProbePositionAllowed(const recon::BSplineSurface& surface, double u, double v, const Eigen::Vector3d& p,
                          double edge_margin_mm) {
  const recon::Trim* trim = surface.trim();
  if (trim == nullptr || trim->natural()) return true;
  return trim->Inside(u, v) && trim->EdgeDistanceMm(p) >= edge_margin_mm;
}

Result<ProbingPlan> PlanProbingGrid(const recon::BSplineSurface& surface, int nu, int nv, double inset_fraction,
                                    double edge_margin_mm) {
  if (nu < 2 || nv < 2) return Status::BadInput(Where{.field = "probing.grid"}, "needs at least 2 × 2 points");
  if (!(inset_fraction >= 0 && inset_fraction < 0.5)) {
    return Status::BadInput(Where{.field = "probing.inset_fraction"}, "must be in [0, 0.5)");
  }
  if (!(edge_margin_mm >= 0) || !std::isfinite(edge_margin_mm)) {
    return Status::BadInput(Where{.field = "probing.edge_margin_mm"}, "must be a finite number >= 0");
  }
  const recon::ParamDomain dom = surface.domain();
  const double u0 = dom.u_min + inset_fraction * dom.u_span(), u1 = dom.u_max - inset_fraction * dom.u_span();
  const double v0 = dom.v_min + inset_fraction * dom.v_span(), v1 = dom.v_max - inset_fraction * dom.v_span();
  ProbingPlan plan;
  plan.trimmed = surface.trim() != nullptr && !surface.trim()->natural();
  plan.edge_margin_mm = plan.trimmed ? edge_margin_mm : 0.0;
  for (int j = 0; j < nv; ++j) {
    for (int i = 0; i < nu; ++i) {
      ProbePoint p;
      p.id = static_cast<std::int64_t>(j) * nu + i + 1;
      p.u = u0 + (u1 - u0) * i / (nu - 1);
      p.v = v0 + (v1 - v0) * j / (nv - 1);
      p.point = surface.Point(p.u, p.v);
      if (!ProbePositionAllowed(surface, p.u, p.v, p.point, edge_margin_mm)) {
        ++plan.left_out;
        continue;
      }
      p.normal = surface.Normal(p.u, p.v);
      plan.points.push_back(p);
    }
  }
  if (plan.points.empty()) {
    return Status::BadInput(Where{.field = "probing.grid"},
                            "no point of the " + std::to_string(nu) + " x " + std::to_string(nv) +
                                " grid lies inside the trimmed face at least " + FormatExact(edge_margin_mm) +
                                " mm from its edge",
                            "use a finer grid or a smaller probing.edge_margin_mm");
  }
  return plan;
}

namespace {

constexpr const char* kLogColumnsFix = "a probe log has the header row id,x,y,z,ax,ay,az,t (any order)";

}  // namespace

Result<ProbeLog> ReadProbeLog(const std::filesystem::path& path) {
  const std::string file = path.string();
  CsvLayout layout;
  FL_ASSIGN_OR_RETURN(PointSet points, ReadCsv(path, &layout));
  std::string missing;
  for (const char* column : {"ax", "ay", "az"}) {
    if (points.FindScalar(column) == nullptr) missing += std::string(missing.empty() ? "" : ", ") + column;
  }
  if (!points.has_ids()) missing = "id" + std::string(missing.empty() ? "" : ", ") + missing;
  if (!points.has_times()) missing += std::string(missing.empty() ? "" : ", ") + "t";
  if (!missing.empty()) {
    // Name the header line and what it holds, so the user can see at once which name is wrong.
    const long header_line = layout.header_line;
    const std::string& header_text = layout.header_text;
    const bool several = missing.find(',') != std::string::npos;
    return Status::BadInput(
        Where{.file = file, .line = header_line, .field = missing},
        std::string(several ? "columns are" : "column is") + " missing from the header row on line " +
            std::to_string(header_line) + ": " + missing + " (the header reads \"" + header_text + "\")",
        "add the missing column" + std::string(several ? "s" : "") + " (" + missing + ") to the header on line " +
            std::to_string(header_line) + " and a value for every row; " + kLogColumnsFix);
  }
  const auto& ax = *points.FindScalar("ax");
  const auto& ay = *points.FindScalar("ay");
  const auto& az = *points.FindScalar("az");
  const std::vector<long>& lines = layout.row_lines;

  ProbeLog log;
  log.source = file;
  log.records.reserve(points.size());
  std::map<std::int64_t, long> seen;  // id -> line
  for (std::size_t i = 0; i < points.size(); ++i) {
    ProbeRecord r;
    r.id = points.ids[i];
    r.centre = points.points[i];
    r.approach = Eigen::Vector3d(ax[i], ay[i], az[i]);
    r.t_s = points.times_s[i];
    r.line = lines[i];
    const Where where{.file = file, .line = r.line, .field = "ax,ay,az"};
    const double norm = r.approach.norm();
    if (!(norm > 1e-9)) {
      return Status::BadInput(where, "approach direction of id " + std::to_string(r.id) + " is zero",
                              "write the unit approach direction (from the probe towards the surface, usually "
                              "the negated planned normal) for every point");
    }
    if (std::abs(norm - 1.0) > kApproachUnitTolerance) {
      return Status::BadInput(where,
                              "approach direction of id " + std::to_string(r.id) + " has length " +
                                  FormatFixed(norm, 9) + "; a unit vector is needed (|length − 1| ≤ " +
                                  FormatExact(kApproachUnitTolerance) + ")",
                              "check that ax,ay,az hold the approach direction and write it normalised (a/|a|) "
                              "with at least 6 decimals");
    }
    r.approach /= norm;
    const auto [it, inserted] = seen.emplace(r.id, r.line);
    if (!inserted) {
      return Status::BadInput(
          Where{.file = file, .line = r.line, .field = "id"},
          "id " + std::to_string(r.id) + " appears again (first on line " + std::to_string(it->second) + ")",
          "give every probe point its own id; remove a repeated measurement or renumber it");
    }
    log.records.push_back(r);
  }
  return log;
}

Result<std::vector<std::int64_t>> CheckProbeLogAgainstPlan(const ProbeLog& log, const ProbingPlan& plan) {
  std::set<std::int64_t> planned;
  for (const ProbePoint& p : plan.points) planned.insert(p.id);
  std::set<std::int64_t> measured;
  for (const ProbeRecord& r : log.records) {
    if (planned.count(r.id) == 0) {
      return Status::BadInput(Where{.file = log.source, .line = r.line, .field = "id"},
                              "id " + std::to_string(r.id) + " is not in the probing plan (" +
                                  std::to_string(plan.points.size()) + " planned points)",
                              "use the log measured with this plan, or the plan the log was measured with");
    }
    measured.insert(r.id);
  }
  std::vector<std::int64_t> missing;
  for (const ProbePoint& p : plan.points) {
    if (measured.count(p.id) == 0) missing.push_back(p.id);
  }
  return missing;
}

Status WriteProbeLog(const std::filesystem::path& path, const ProbeLog& log) {
  // Column order as in spec/metrology.md §1; 1 nm resolution.
  std::string text = "# formloop probe log: ball centre (mm), unit approach direction, time (s)\n";
  text += "id,x,y,z,ax,ay,az,t\n";
  for (const ProbeRecord& r : log.records) {
    if (!r.centre.allFinite() || !r.approach.allFinite() || !std::isfinite(r.t_s)) {
      return Status::Internal("probe record " + std::to_string(r.id) + " is not finite; " + path.string() +
                              " was not written");
    }
    text += std::to_string(r.id);
    for (int a = 0; a < 3; ++a) text += "," + FormatFixed(r.centre[a], 6);
    for (int a = 0; a < 3; ++a) text += "," + FormatFixed(r.approach[a], 9);
    text += "," + FormatFixed(r.t_s, 3) + "\n";
  }
  return WriteFileAtomic(path, text);
}

ProbingAngles AnglesOfApproach(const Eigen::Vector3d& approach) {
  const Eigen::Vector3d d = -approach;
  ProbingAngles angles;
  const double horizontal = std::hypot(d.x(), d.y());
  angles.elevation_rad = std::atan2(d.z(), horizontal);
  angles.at_pole = horizontal < 1e-9;
  angles.azimuth_rad = angles.at_pole ? 0.0 : std::atan2(d.y(), d.x());
  return angles;
}

PretravelLobing PretravelLobing::Zero(int max_order, int elevation_degree) {
  PretravelLobing lobing;
  lobing.max_order = max_order;
  lobing.elevation_degree = elevation_degree;
  lobing.cos_mm = Eigen::MatrixXd::Zero(max_order + 1, elevation_degree + 1);
  lobing.sin_mm = Eigen::MatrixXd::Zero(max_order + 1, elevation_degree + 1);
  return lobing;
}

double PretravelLobing::Evaluate(const Eigen::Vector3d& approach) const {
  if (IsZero()) return 0.0;
  const ProbingAngles angles = AnglesOfApproach(approach);
  const double s = std::sin(angles.elevation_rad);
  double sum = 0;
  for (int k = 0; k <= max_order; ++k) {
    if (k > 0 && angles.at_pole) break;
    const double c = std::cos(k * angles.azimuth_rad), sn = std::sin(k * angles.azimuth_rad);
    double power = 1;
    for (int j = 0; j <= elevation_degree; ++j) {
      sum += power * (cos_mm(k, j) * c + sin_mm(k, j) * sn);
      power *= s;
    }
  }
  return sum;
}

double PretravelLobing::BoundMm() const { return cos_mm.cwiseAbs().sum() + sin_mm.cwiseAbs().sum(); }

bool PretravelLobing::IsZero() const { return cos_mm.isZero(0.0) && sin_mm.isZero(0.0); }

Status PretravelLobing::Validate(const std::string& field_prefix) const {
  if (max_order < 0 || max_order > kMaxOrder) {
    return Status::BadInput(Where{.field = field_prefix + ".max_order"},
                            "must be in 0.." + std::to_string(kMaxOrder) + ", got " + std::to_string(max_order));
  }
  if (elevation_degree < 0 || elevation_degree > kMaxElevationDegree) {
    return Status::BadInput(
        Where{.field = field_prefix + ".elevation_degree"},
        "must be in 0.." + std::to_string(kMaxElevationDegree) + ", got " + std::to_string(elevation_degree));
  }
  for (const auto* m : {&cos_mm, &sin_mm}) {
    if (m->rows() != max_order + 1 || m->cols() != elevation_degree + 1) {
      return Status::Internal(field_prefix + ": coefficient matrix is " + std::to_string(m->rows()) + " × " +
                              std::to_string(m->cols()) + ", expected (max_order + 1) × (elevation_degree + 1)");
    }
    if (!m->allFinite()) {
      return Status::BadInput(Where{.field = field_prefix + ".terms"}, "coefficients must be finite");
    }
  }
  if (!sin_mm.row(0).isZero(0.0)) {
    return Status::BadInput(Where{.field = field_prefix + ".terms"}, "k = 0 terms have no sine part",
                            "set sin_mm to 0 for k = 0");
  }
  return Status::Ok();
}

Status ProbeModel::Validate() const {
  if (!(ball_radius_mm > 0)) return Status::BadInput(Where{.field = "probe.ball_radius_mm"}, "must be > 0");
  if (!(std::abs(pretravel_mm) < ball_radius_mm)) {
    return Status::BadInput(Where{.field = "probe.pretravel_mm"}, "must be smaller than the ball radius");
  }
  FL_RETURN_IF_ERROR(lobing.Validate());
  if (!(std::abs(pretravel_mm) + lobing.BoundMm() < ball_radius_mm)) {
    return Status::BadInput(Where{.field = "probe.lobing"},
                            "the pretravel can reach the ball radius in some direction (|pretravel| + Σ|coefficients| "
                            "= " +
                                FormatFixed(std::abs(pretravel_mm) + lobing.BoundMm(), 6) + " mm)",
                            "check the units: lobing coefficients are in mm");
  }
  return Status::Ok();
}

Eigen::Vector3d ContactPoint(const ProbeRecord& record, const ProbeModel& model) {
  return record.centre + model.EffectiveRadius(record.approach) * record.approach;
}

namespace {
constexpr const char* kProfileFormat = "formloop probe profile";
constexpr int kProfileVersion = 1;
}  // namespace

nlohmann::json ProbeProfileToJson(const ProbeModel& model) {
  nlohmann::json terms = nlohmann::json::array();
  for (int k = 0; k <= model.lobing.max_order; ++k) {
    for (int j = 0; j <= model.lobing.elevation_degree; ++j) {
      const double c = model.lobing.cos_mm(k, j), s = model.lobing.sin_mm(k, j);
      if (c == 0 && s == 0) continue;
      terms.push_back({{"k", k}, {"j", j}, {"cos_mm", c}, {"sin_mm", s}});
    }
  }
  return {{"format", kProfileFormat},
          {"version", kProfileVersion},
          {"ball_radius_mm", model.ball_radius_mm},
          {"pretravel_mm", model.pretravel_mm},
          {"lobing",
           {{"max_order", model.lobing.max_order},
            {"elevation_degree", model.lobing.elevation_degree},
            {"angles",
             "theta = atan2(-ay, -ax), sin(phi) = -az; delta = pretravel_mm + sum_kj "
             "sin(phi)^j (cos_mm cos(k theta) + sin_mm sin(k theta))"},
            {"terms", terms}}}};
}

Result<ProbeModel> ProbeProfileFromJson(const nlohmann::json& json, const std::string& source) {
  JsonFields f(json, source);
  FL_RETURN_IF_ERROR(f.CheckKnown({"format", "version", "ball_radius_mm", "pretravel_mm", "lobing", "calibration"}));
  std::string format;
  FL_RETURN_IF_ERROR(f.String("format", &format));
  if (format != kProfileFormat) {
    return Status::BadInput(Where{.file = source, .field = "format"},
                            "is '" + format + "', not '" + kProfileFormat + "'",
                            "pass a probe profile written by `formloop calibrate sphere`");
  }
  long long version = 0;
  FL_RETURN_IF_ERROR(f.Integer("version", &version));
  if (version != kProfileVersion) {
    return Status::BadInput(Where{.file = source, .field = "version"},
                            "version " + std::to_string(version) + " is not supported (this formloop reads " +
                                std::to_string(kProfileVersion) + ")",
                            "recalibrate with this formloop");
  }
  ProbeModel model;
  FL_RETURN_IF_ERROR(f.Number("ball_radius_mm", &model.ball_radius_mm, {.min = 0, .exclusive_min = true}));
  FL_RETURN_IF_ERROR(f.Number("pretravel_mm", &model.pretravel_mm));
  std::optional<JsonFields> lobing_fields;
  FL_RETURN_IF_ERROR(f.Object("lobing", &lobing_fields));
  if (lobing_fields) {
    const JsonFields& l = *lobing_fields;
    FL_RETURN_IF_ERROR(l.CheckKnown({"max_order", "elevation_degree", "angles", "terms"}));
    long long order = 0, degree = 0;
    FL_RETURN_IF_ERROR(l.Integer("max_order", &order, 0, PretravelLobing::kMaxOrder));
    FL_RETURN_IF_ERROR(l.Integer("elevation_degree", &degree, 0, PretravelLobing::kMaxElevationDegree));
    model.lobing = PretravelLobing::Zero(static_cast<int>(order), static_cast<int>(degree));
    if (l.Has("terms")) {
      const nlohmann::json& terms = l.json().at("terms");
      if (!terms.is_array()) {
        return Status::BadInput(Where{.file = source, .field = l.Path("terms")}, "must be an array",
                                "write [{\"k\": 3, \"j\": 0, \"cos_mm\": ..., \"sin_mm\": ...}, ...]");
      }
      std::set<std::pair<long long, long long>> seen;
      for (std::size_t t = 0; t < terms.size(); ++t) {
        const std::string prefix = l.Path("terms") + "[" + std::to_string(t) + "].";
        JsonFields term(terms[t], source, prefix);
        FL_RETURN_IF_ERROR(term.CheckKnown({"k", "j", "cos_mm", "sin_mm", "cos_se_mm", "sin_se_mm"}));
        long long k = 0, j = 0;
        FL_RETURN_IF_ERROR(term.Integer("k", &k, 0, order));
        FL_RETURN_IF_ERROR(term.Integer("j", &j, 0, degree));
        if (!seen.emplace(k, j).second) {
          return Status::BadInput(Where{.file = source, .field = prefix + "k"},
                                  "term k = " + std::to_string(k) + ", j = " + std::to_string(j) + " appears twice",
                                  "give each (k, j) once");
        }
        double c = 0, s = 0;
        FL_RETURN_IF_ERROR(term.Number("cos_mm", &c));
        FL_RETURN_IF_ERROR(term.OptionalNumber("sin_mm", &s));
        if (k == 0 && s != 0) {
          return Status::BadInput(Where{.file = source, .field = prefix + "sin_mm"}, "k = 0 terms have no sine part",
                                  "remove sin_mm or set it to 0");
        }
        model.lobing.cos_mm(k, j) = c;
        model.lobing.sin_mm(k, j) = s;
      }
    }
  }
  Status valid = model.Validate();
  if (!valid.ok()) return valid.WithContext(source);
  return model;
}

Status WriteProbeProfile(const std::filesystem::path& path, const ProbeModel& model,
                         const nlohmann::json& calibration) {
  FL_RETURN_IF_ERROR(model.Validate());
  nlohmann::json json = ProbeProfileToJson(model);
  if (!calibration.is_null()) json["calibration"] = calibration;
  return WriteJsonFile(path, json);
}

Result<ProbeModel> ReadProbeProfile(const std::filesystem::path& path) {
  FL_ASSIGN_OR_RETURN(const nlohmann::json json, ReadJsonFile(path));
  return ProbeProfileFromJson(json, path.string());
}

}  // namespace formloop::metrology
