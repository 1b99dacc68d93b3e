#include "tuning/measurement_model.h"

#include <cmath>
#include <set>
#include <string>

#include "core/json_io.h"

namespace formloop::tuning {
namespace {

using metrology::DimensionMethod;
using metrology::DimensionType;

Status Bad(const std::string& source, const std::string& field, const std::string& what, const std::string& fix) {
  return Status::BadInput(Where{.file = source, .field = field}, what, fix);
}

Status ParseAxis(const std::string& source, const std::string& field, const std::string& text, int* axis) {
  if (text == "X")
    *axis = 0;
  else if (text == "Y")
    *axis = 1;
  else if (text == "Z")
    *axis = 2;
  else
    return Bad(source, field, "value '" + text + "' is not an axis", "write \"X\", \"Y\" or \"Z\"");
  return Status::Ok();
}

// [x, y, z] in mm through core's array reader (messages name the field and the entry).
Status Vector3(const JsonFields& f, const std::string& key, Eigen::Vector3d* out) {
  std::vector<double> v;
  FL_RETURN_IF_ERROR(f.NumberArray(key, &v, 3));
  *out = Eigen::Vector3d(v[0], v[1], v[2]);
  return Status::Ok();
}

Status ParsePoint(const Json& j, const std::string& source, double default_u, ModelPoint* p) {
  if (!j.is_object())
    return Bad(source, "points[]", "expected an object", "write {\"id\": 1, \"reference_mm\": [...]}");
  long long id = 0;
  JsonFields f(j, source, "points[].");
  FL_RETURN_IF_ERROR(f.Integer("id", &id, 1, 2000));
  p->id = static_cast<int>(id);
  const std::string prefix = "points[id " + std::to_string(id) + "].";
  JsonFields g(j, source, prefix);
  FL_RETURN_IF_ERROR(g.CheckKnown({"id", "process", "reference_mm", "approach", "axes", "u_mm"}));
  FL_RETURN_IF_ERROR(g.OptionalString("process", &p->process));
  if (!g.Has("reference_mm")) {
    return Bad(source, prefix + "reference_mm", "required field is missing",
               "give the nominal surface point [x, y, z] in the process WCS");
  }
  FL_RETURN_IF_ERROR(Vector3(g, "reference_mm", &p->reference_mm));
  if (g.Has("approach")) {
    FL_RETURN_IF_ERROR(Vector3(g, "approach", &p->approach));
    if (!(p->approach.norm() > 0)) {
      return Bad(source, prefix + "approach", "is the zero vector", "give the probing direction or leave it out");
    }
    p->approach.normalize();
  }
  std::string axes = "XYZ";
  FL_RETURN_IF_ERROR(g.OptionalString("axes", &axes));
  p->measured = {false, false, false};
  for (char c : axes) {
    if (c == 'X')
      p->measured[0] = true;
    else if (c == 'Y')
      p->measured[1] = true;
    else if (c == 'Z')
      p->measured[2] = true;
    else
      return Bad(source, prefix + "axes", "value '" + axes + "' has a letter that is not X, Y or Z",
                 "e.g. \"X\" or \"XYZ\"");
  }
  if (axes.empty()) return Bad(source, prefix + "axes", "is empty", "list at least one measured axis");
  p->u_mm = default_u;
  FL_RETURN_IF_ERROR(g.OptionalNumber("u_mm", &p->u_mm, {.min = 0}));
  return Status::Ok();
}

Status ParseOffset(const Json& j, const std::string& source, ModelOffset* o) {
  if (!j.is_object()) return Bad(source, "offsets[]", "expected an object", "write {\"id\": ..., \"kind\": ...}");
  JsonFields f0(j, source, "offsets[].");
  FL_RETURN_IF_ERROR(f0.String("id", &o->id));
  if (o->id.empty()) return Bad(source, "offsets[].id", "is empty", "give each offset an id");
  const std::string prefix = "offsets[" + o->id + "].";
  JsonFields f(j, source, prefix);
  FL_RETURN_IF_ERROR(f.CheckKnown({"id", "kind", "tool", "wcs", "axis", "address", "resolution_mm", "delta_min_mm",
                                   "delta_max_mm", "limit_mm", "baseline_mm", "step_limit_mm", "weight"}));
  std::string kind;
  FL_RETURN_IF_ERROR(f.String("kind", &kind));
  if (kind == "TOOL_RADIUS_WEAR")
    o->kind = OffsetKind::kToolRadiusWear;
  else if (kind == "TOOL_LENGTH_WEAR")
    o->kind = OffsetKind::kToolLengthWear;
  else if (kind == "WORK_OFFSET")
    o->kind = OffsetKind::kWorkOffset;
  else
    return Bad(source, prefix + "kind", "value '" + kind + "' is unknown",
               "write TOOL_RADIUS_WEAR, TOOL_LENGTH_WEAR or WORK_OFFSET");
  if (o->kind == OffsetKind::kWorkOffset) {
    FL_RETURN_IF_ERROR(f.String("wcs", &o->wcs));
    // The work offsets `formloop link write` addresses (cnc/transport.h): G54..G59.
    if (o->wcs.size() != 3 || o->wcs[0] != 'G' || o->wcs[1] != '5' || o->wcs[2] < '4' || o->wcs[2] > '9') {
      return Bad(source, prefix + "wcs", "value '" + o->wcs + "' is not a work coordinate system the link can write",
                 "write G54, G55, G56, G57, G58 or G59");
    }
    FL_RETURN_IF_ERROR(f.String("axis", &o->axis));
    int axis = 0;
    FL_RETURN_IF_ERROR(ParseAxis(source, prefix + "axis", o->axis, &axis));
    if (f.Has("tool")) return Bad(source, prefix + "tool", "a work offset has no tool", "remove \"tool\"");
  } else {
    long long tool = 0;
    FL_RETURN_IF_ERROR(f.Integer("tool", &tool, 1, 9999));
    o->tool = static_cast<int>(tool);
    if (f.Has("wcs") || f.Has("axis")) {
      return Bad(source, prefix + "wcs", "a tool offset has no wcs/axis", "remove \"wcs\" and \"axis\"");
    }
  }
  FL_RETURN_IF_ERROR(f.OptionalString("address", &o->address));
  FL_RETURN_IF_ERROR(f.OptionalNumber("resolution_mm", &o->resolution_mm, {.min = 0, .exclusive_min = true}));
  FL_RETURN_IF_ERROR(f.OptionalNumber("delta_min_mm", &o->delta_min_mm, {.max = 0}));
  FL_RETURN_IF_ERROR(f.OptionalNumber("delta_max_mm", &o->delta_max_mm, {.min = 0}));
  FL_RETURN_IF_ERROR(f.OptionalNumber("limit_mm", &o->limit_mm, {.min = 0, .exclusive_min = true}));
  FL_RETURN_IF_ERROR(f.OptionalNumber("baseline_mm", &o->baseline_mm));
  if (f.Has("step_limit_mm")) {
    double step = 0;
    FL_RETURN_IF_ERROR(f.Number("step_limit_mm", &step, {.min = 0, .exclusive_min = true}));
    o->step_limit_mm = step;
  }
  FL_RETURN_IF_ERROR(f.OptionalNumber("weight", &o->weight, {.min = 0, .exclusive_min = true}));
  return Status::Ok();
}

Status ParseDimension(const Json& j, const MeasurementModel& model, ModelDimension* d) {
  const std::string& source = model.source;
  if (!j.is_object()) return Bad(source, "dimensions[]", "expected an object", "write {\"id\": ..., \"type\": ...}");
  JsonFields f0(j, source, "dimensions[].");
  FL_RETURN_IF_ERROR(f0.String("id", &d->id));
  if (d->id.empty()) return Bad(source, "dimensions[].id", "is empty", "give each dimension an id");
  const std::string prefix = "dimensions[" + d->id + "].";
  JsonFields f(j, source, prefix);
  FL_RETURN_IF_ERROR(f.CheckKnown({"id",
                                   "name",
                                   "process",
                                   "type",
                                   "method",
                                   "axis",
                                   "nominal_mm",
                                   "tol_upper_mm",
                                   "tol_lower_mm",
                                   "tolerance_mm",
                                   "nominal_deg",
                                   "tol_upper_deg",
                                   "tol_lower_deg",
                                   "nominal_position_mm",
                                   "feature_axis",
                                   "weight",
                                   "mode",
                                   "target",
                                   "points",
                                   "k_row"}));
  d->definition.id = d->id;
  FL_RETURN_IF_ERROR(f.OptionalString("name", &d->name));
  FL_RETURN_IF_ERROR(f.OptionalString("process", &d->process));
  std::string type, method = "DEFAULT", axis = "Z", mode = "COMPENSATE", target = "NOMINAL";
  FL_RETURN_IF_ERROR(f.String("type", &type));
  if (!metrology::ParseDimensionType(type, &d->definition.type)) {
    return Bad(source, prefix + "type", "value '" + type + "' is unknown",
               "write LENGTH, DIAMETER, RADIUS, POSITION, TRUE_POSITION, FLATNESS, ROUNDNESS, PARALLELISM, "
               "PERPENDICULARITY, COAXIALITY, SYMMETRY or ANGLE");
  }
  const DimensionType t = d->definition.type;
  FL_RETURN_IF_ERROR(f.OptionalString("method", &method));
  if (!metrology::ParseDimensionMethod(method, &d->definition.method)) {
    return Bad(source, prefix + "method", "value '" + method + "' is unknown", "leave it out for the type's default");
  }
  if (d->definition.method != DimensionMethod::kDefault) {
    bool allowed = false;
    std::string list;
    for (auto m : metrology::MethodsOf(t)) {
      allowed = allowed || m == d->definition.method;
      list += (list.empty() ? "" : ", ") + std::string(metrology::DimensionMethodName(m));
    }
    if (!allowed) {
      return Bad(source, prefix + "method", "method " + method + " does not apply to " + type, "use one of: " + list);
    }
  }
  FL_RETURN_IF_ERROR(f.OptionalString("axis", &axis));
  FL_RETURN_IF_ERROR(ParseAxis(source, prefix + "axis", axis, &d->definition.axis));
  if (f.Has("feature_axis")) {
    if (t != DimensionType::kPosition) {
      return Bad(source, prefix + "feature_axis", "only POSITION (method CIRCLE) takes a feature axis", "remove it");
    }
    std::string feature_axis;
    FL_RETURN_IF_ERROR(f.String("feature_axis", &feature_axis));
    FL_RETURN_IF_ERROR(ParseAxis(source, prefix + "feature_axis", feature_axis, &d->definition.feature_axis));
  }
  const bool zone = metrology::IsZoneType(t);
  d->angle = t == DimensionType::kAngle;
  d->tolerance.zone = zone;
  if (zone) {
    for (const char* k :
         {"nominal_mm", "tol_upper_mm", "tol_lower_mm", "nominal_deg", "tol_upper_deg", "tol_lower_deg"}) {
      if (f.Has(k)) {
        return Bad(source, prefix + k, type + " is a zone: its nominal is 0 and its band [0, t]",
                   "give only \"tolerance_mm\": t");
      }
    }
    FL_RETURN_IF_ERROR(f.Number("tolerance_mm", &d->tolerance.upper, {.min = 0, .exclusive_min = true}));
    d->tolerance.nominal = 0;
    d->tolerance.lower = 0;
  } else {
    if (f.Has("tolerance_mm")) {
      return Bad(source, prefix + "tolerance_mm", "only zone types take a single tolerance",
                 "give tol_upper and tol_lower as signed deviations");
    }
    const std::string unit = d->angle ? "_deg" : "_mm";
    for (const char* k :
         {"nominal_mm", "tol_upper_mm", "tol_lower_mm", "nominal_deg", "tol_upper_deg", "tol_lower_deg"}) {
      const std::string key = k;
      if (f.Has(key) && !key.ends_with(unit)) {
        return Bad(source, prefix + key, "this type's values are in " + std::string(d->angle ? "degrees" : "mm"),
                   "use the " + unit + " keys");
      }
    }
    FL_RETURN_IF_ERROR(f.Number("nominal" + unit, &d->tolerance.nominal));
    FL_RETURN_IF_ERROR(f.Number("tol_upper" + unit, &d->tolerance.upper));
    FL_RETURN_IF_ERROR(f.Number("tol_lower" + unit, &d->tolerance.lower));
    if (!(d->tolerance.lower < d->tolerance.upper)) {
      return Bad(source, prefix + "tol_lower" + unit,
                 "lower deviation " + Json(d->tolerance.lower).dump() + " is not below upper " +
                     Json(d->tolerance.upper).dump(),
                 "give signed deviations with tol_lower < tol_upper, e.g. +0.09 / -0.05");
    }
  }
  if (t == DimensionType::kTruePosition) {
    if (!f.Has("nominal_position_mm")) {
      return Bad(source, prefix + "nominal_position_mm", "missing",
                 "give the nominal position [u, v] along the two axes normal to \"axis\"");
    }
    std::vector<double> uv;
    FL_RETURN_IF_ERROR(f.NumberArray("nominal_position_mm", &uv, 2));
    d->definition.nominal_position = {uv[0], uv[1]};
  } else if (f.Has("nominal_position_mm")) {
    return Bad(source, prefix + "nominal_position_mm", "only TRUE_POSITION takes a nominal position", "remove it");
  }
  FL_RETURN_IF_ERROR(f.OptionalNumber("weight", &d->weight, {.min = 0, .exclusive_min = true}));
  FL_RETURN_IF_ERROR(f.OptionalString("mode", &mode));
  if (mode == "COMPENSATE")
    d->mode = DimensionMode::kCompensate;
  else if (mode == "TOLERANCE_ONLY" || mode == "CHECK_ONLY")
    d->mode = DimensionMode::kToleranceOnly;
  else if (mode == "IGNORE")
    d->mode = DimensionMode::kIgnore;
  else
    return Bad(source, prefix + "mode", "value '" + mode + "' is unknown",
               "write COMPENSATE, TOLERANCE_ONLY or IGNORE");
  FL_RETURN_IF_ERROR(f.OptionalString("target", &target));
  if (target == "NOMINAL")
    d->target = DimensionTarget::kNominal;
  else if (target == "BAND_CENTRE")
    d->target = DimensionTarget::kBandCentre;
  else
    return Bad(source, prefix + "target", "value '" + target + "' is unknown", "write NOMINAL or BAND_CENTRE");

  // Points and roles.
  if (!f.Has("points") || !j["points"].is_array() || j["points"].empty()) {
    return Bad(source, prefix + "points", "missing or empty",
               "list the probe points as [{\"id\": 1, \"role\": \"WALL_A\"}, ...]");
  }
  std::set<std::string> roles;
  for (const auto& pj : j["points"]) {
    JsonFields pf(pj, source, prefix + "points[].");
    FL_RETURN_IF_ERROR(pf.CheckKnown({"id", "role"}));
    long long id = 0;
    PointRef ref;
    FL_RETURN_IF_ERROR(pf.Integer("id", &id, 1, 2000));
    FL_RETURN_IF_ERROR(pf.String("role", &ref.role));
    ref.id = static_cast<int>(id);
    if (!model.FindPoint(ref.id)) {
      return Bad(source, prefix + "points", "point " + std::to_string(id) + " is not in the model's points",
                 "add it to \"points\" with its reference coordinates or fix the id");
    }
    if (!metrology::RoleAccepted(t, d->definition.method, ref.role)) {
      std::string list;
      for (const auto& r : metrology::RequiredRoles(t, d->definition.method)) list += (list.empty() ? "" : ", ") + r;
      return Bad(source, prefix + "points",
                 "role '" + ref.role + "' does not belong to a " + type + " (" +
                     metrology::DimensionMethodName(metrology::ResolvedMethod(t, d->definition.method)) + ")",
                 "use the roles " + list + (t == DimensionType::kCoaxiality ? " (and DATUM_2, FEATURE_2, ...)" : ""));
    }
    roles.insert(ref.role);
    d->points.push_back(ref);
  }
  for (const auto& r : metrology::RequiredRoles(t, d->definition.method)) {
    if (!roles.count(r)) {
      return Bad(source, prefix + "points", "no point has the role " + r, "give the points of " + r);
    }
  }
  // K row.
  if (f.Has("k_row")) {
    if (!j["k_row"].is_object())
      return Bad(source, prefix + "k_row", "expected an object", "write {\"offset id\": K, ...}");
    const JsonFields kf(j["k_row"], source, prefix + "k_row.");
    for (const auto& item : j["k_row"].items()) {
      const std::string& key = item.key();
      if (model.OffsetIndex(key) < 0) {
        return Bad(source, prefix + "k_row." + key, "offset '" + key + "' is not in the model's offsets",
                   "add the offset or fix its id");
      }
      double k = 0;
      FL_RETURN_IF_ERROR(kf.Number(key, &k));
      if (k != 0) d->k_row[key] = k;
    }
  }
  if (zone && d->mode == DimensionMode::kCompensate) {
    return Bad(source, prefix + "mode", type + " is a zone and not linear in the offsets, so it cannot drive them",
               "set \"mode\": \"TOLERANCE_ONLY\"; to correct a location error model its signed parts as POSITION "
               "dimensions (spec §1.2)");
  }
  if (zone && !d->k_row.empty()) {
    return Bad(source, prefix + "k_row", "a zone's K row is 0", "remove \"k_row\"");
  }
  if (d->angle && d->mode == DimensionMode::kCompensate) {
    return Bad(source, prefix + "mode", "an ANGLE cannot drive length offsets", "set \"mode\": \"TOLERANCE_ONLY\"");
  }
  if (d->mode == DimensionMode::kCompensate && d->k_row.empty()) {
    return Bad(source, prefix + "k_row", "the dimension is COMPENSATE but no offset moves it",
               "give its K coefficients (e.g. {\"T3_radius_wear\": 2}) or set \"mode\": \"TOLERANCE_ONLY\"");
  }
  return Status::Ok();
}

}  // namespace

const char* DimensionModeName(DimensionMode mode) {
  switch (mode) {
    case DimensionMode::kCompensate:
      return "COMPENSATE";
    case DimensionMode::kToleranceOnly:
      return "TOLERANCE_ONLY";
    case DimensionMode::kIgnore:
      return "IGNORE";
  }
  return "?";
}

const char* OffsetKindName(OffsetKind kind) {
  switch (kind) {
    case OffsetKind::kToolRadiusWear:
      return "TOOL_RADIUS_WEAR";
    case OffsetKind::kToolLengthWear:
      return "TOOL_LENGTH_WEAR";
    case OffsetKind::kWorkOffset:
      return "WORK_OFFSET";
  }
  return "?";
}

const ModelPoint* MeasurementModel::FindPoint(int id) const {
  for (const auto& p : points) {
    if (p.id == id) return &p;
  }
  return nullptr;
}

int MeasurementModel::OffsetIndex(const std::string& id) const {
  for (std::size_t j = 0; j < offsets.size(); ++j) {
    if (offsets[j].id == id) return static_cast<int>(j);
  }
  return -1;
}

Result<MeasurementModel> ParseMeasurementModel(const Json& json, const std::string& source) {
  MeasurementModel model;
  model.source = source;
  JsonFields f(json, source);
  FL_RETURN_IF_ERROR(
      f.CheckKnown({"format", "version", "project", "part", "machine", "processes", "point_uncertainty_mm",
                    "max_point_deviation_mm", "points", "offsets", "dimensions", "block", "solver", "average"}));
  std::string format;
  FL_RETURN_IF_ERROR(f.String("format", &format));
  if (format != "formloop.measurement_model") {
    return Bad(source, "format", "value '" + format + "' is not a measurement model",
               "write \"format\": \"formloop.measurement_model\"");
  }
  long long version = 0;
  FL_RETURN_IF_ERROR(f.Integer("version", &version, 1, 1));
  FL_RETURN_IF_ERROR(f.OptionalString("project", &model.project));
  std::optional<JsonFields> part, machine, block, solver, average;
  FL_RETURN_IF_ERROR(f.Object("part", &part));
  if (part) {
    FL_RETURN_IF_ERROR(part->CheckKnown({"code", "drawing_revision"}));
    FL_RETURN_IF_ERROR(part->OptionalString("code", &model.part_code));
    FL_RETURN_IF_ERROR(part->OptionalString("drawing_revision", &model.drawing_revision));
  }
  FL_RETURN_IF_ERROR(f.Object("machine", &machine));
  if (machine) {
    FL_RETURN_IF_ERROR(machine->CheckKnown({"serial"}));
    FL_RETURN_IF_ERROR(machine->OptionalString("serial", &model.machine_serial));
  }
  std::set<std::string> processes;
  if (f.Has("processes")) {
    if (!json["processes"].is_array())
      return Bad(source, "processes", "expected an array", "write [{\"id\": \"OP10\"}, ...]");
    for (const auto& pj : json["processes"]) {
      JsonFields pf(pj, source, "processes[].");
      FL_RETURN_IF_ERROR(pf.CheckKnown({"id", "nc_program", "measuring_program", "tools", "wcs"}));
      std::string id;
      FL_RETURN_IF_ERROR(pf.String("id", &id));
      if (!processes.insert(id).second) {
        return Bad(source, "processes[" + id + "]", "id is given twice", "give each process a unique id");
      }
    }
  }
  double default_u = 0.0005;
  FL_RETURN_IF_ERROR(f.OptionalNumber("point_uncertainty_mm", &default_u, {.min = 0}));
  FL_RETURN_IF_ERROR(
      f.OptionalNumber("max_point_deviation_mm", &model.max_point_deviation_mm, {.min = 0, .exclusive_min = true}));

  if (!f.Has("points") || !json["points"].is_array() || json["points"].empty()) {
    return Bad(source, "points", "missing or empty", "list the probe points with their reference coordinates");
  }
  for (const auto& pj : json["points"]) {
    ModelPoint p;
    FL_RETURN_IF_ERROR(ParsePoint(pj, source, default_u, &p));
    if (model.FindPoint(p.id)) {
      return Bad(source, "points[id " + std::to_string(p.id) + "]", "id is given twice", "give each point a unique id");
    }
    if (!p.process.empty() && !processes.empty() && !processes.count(p.process)) {
      return Bad(source, "points[id " + std::to_string(p.id) + "].process",
                 "process '" + p.process + "' is not in \"processes\"", "add the process or fix the name");
    }
    model.points.push_back(p);
  }
  if (!f.Has("offsets") || !json["offsets"].is_array()) {
    return Bad(source, "offsets", "missing", "list the offsets (an empty list [] when nothing is compensated)");
  }
  for (const auto& oj : json["offsets"]) {
    ModelOffset o;
    FL_RETURN_IF_ERROR(ParseOffset(oj, source, &o));
    if (model.OffsetIndex(o.id) >= 0) {
      return Bad(source, "offsets[" + o.id + "]", "id is given twice", "give each offset a unique id");
    }
    model.offsets.push_back(o);
  }
  if (!f.Has("dimensions") || !json["dimensions"].is_array() || json["dimensions"].empty()) {
    return Bad(source, "dimensions", "missing or empty", "list the drawing's dimensions");
  }
  std::set<std::string> dim_ids;
  for (const auto& dj : json["dimensions"]) {
    ModelDimension d;
    FL_RETURN_IF_ERROR(ParseDimension(dj, model, &d));
    if (!dim_ids.insert(d.id).second) {
      return Bad(source, "dimensions[" + d.id + "]", "id is given twice", "give each dimension a unique id");
    }
    if (!d.process.empty() && !processes.empty() && !processes.count(d.process)) {
      return Bad(source, "dimensions[" + d.id + "].process", "process '" + d.process + "' is not in \"processes\"",
                 "add the process or fix the name");
    }
    model.dimensions.push_back(d);
  }

  FL_RETURN_IF_ERROR(f.Object("block", &block));
  if (block) {
    FL_RETURN_IF_ERROR(block->CheckKnown({"mode", "max_age_min"}));
    std::string mode = "NEAREST";
    FL_RETURN_IF_ERROR(block->OptionalString("mode", &mode));
    if (!metrology::ParseBlockMode(mode, &model.block_mode)) {
      return Bad(source, "block.mode", "value '" + mode + "' is unknown", "write NEAREST, LINEAR or SCALE");
    }
    double minutes = 30;
    FL_RETURN_IF_ERROR(block->OptionalNumber("max_age_min", &minutes, {.min = 0, .exclusive_min = true}));
    model.block_max_age_s = minutes * 60;
  }
  FL_RETURN_IF_ERROR(f.Object("solver", &solver));
  if (solver) {
    FL_RETURN_IF_ERROR(solver->CheckKnown({"rho", "band_shrink"}));
    FL_RETURN_IF_ERROR(solver->OptionalNumber("rho", &model.solver.rho, {.min = 0, .exclusive_min = true}));
    FL_RETURN_IF_ERROR(
        solver->OptionalNumber("band_shrink", &model.solver.band_shrink, {.min = 0, .max = 1, .exclusive_min = true}));
  }
  FL_RETURN_IF_ERROR(f.Object("average", &average));
  if (average) {
    FL_RETURN_IF_ERROR(average->CheckKnown({"skip_band_mm", "max_mm"}));
    FL_RETURN_IF_ERROR(average->OptionalNumber("skip_band_mm", &model.average.skip_band_mm, {.min = 0}));
    FL_RETURN_IF_ERROR(average->OptionalNumber("max_mm", &model.average.max_mm, {.min = 0, .exclusive_min = true}));
  }
  return model;
}

Result<MeasurementModel> ReadMeasurementModel(const std::filesystem::path& path) {
  FL_ASSIGN_OR_RETURN(const Json json, ReadJsonFile(path));
  return ParseMeasurementModel(json, path.string());
}

}  // namespace formloop::tuning
