#include "app/part.h"

#include "core/json_io.h"
#include "core/log.h"
#include "core/number_text.h"
#include "core/work_estimate.h"
#include "nc-gen/raster_estimate.h"
#include "reconstruction/analytic_surface.h"
#include "reconstruction/surface_family.h"
#include "retrieval/starter.h"
#include "retrieval/taxonomy.h"

namespace formloop::app {
namespace {

constexpr double kMaxTravelMm = 100000;  // 100 m: no 3-axis machine travels further

// An optional [x, y, z] in mm within the travel any machine has (+-100 m).
Status ReadVec3(const JsonFields& f, const std::string& key, Eigen::Vector3d* out) {
  if (!f.Has(key)) return Status::Ok();
  std::vector<double> v;
  FL_RETURN_IF_ERROR(f.NumberArray(key, &v, 3, {.min = -kMaxTravelMm, .max = kMaxTravelMm}));
  *out = Eigen::Vector3d(v[0], v[1], v[2]);
  return Status::Ok();
}

Status ReadInt(const JsonFields& f, const std::string& key, int* out, int min, int max) {
  long long value = *out;
  FL_RETURN_IF_ERROR(f.OptionalInteger(key, &value, min, max));
  *out = static_cast<int>(value);
  return Status::Ok();
}

constexpr NumberRange kNonNegative{.min = 0};
// Upper bounds of the fields that steer the machine or the probe: far beyond any real 3-axis job, well
// short of the values a wrong unit or a typo gives (core/work_estimate.h bounds the job's size).
constexpr NumberRange kLength{.min = 0, .max = 1000, .exclusive_min = true};     // mm: clearances, spacing
constexpr NumberRange kBallRadius{.min = 0, .max = 50, .exclusive_min = true};   // mm: tools and styli
constexpr NumberRange kMicrons{.min = 0, .max = 1000, .exclusive_min = true};    // um: scallop, chord
constexpr NumberRange kFeed{.min = 0, .max = 200000, .exclusive_min = true};     // mm/min
constexpr NumberRange kSpindle{.min = 0, .max = 200000, .exclusive_min = true};  // rpm
constexpr NumberRange kEffectMicrons{.min = -1000, .max = 1000};                 // um of a simulated effect

// The material must be a concept (or alias) of data/taxonomies/material.txt, spelled as there: the case
// library and retrieval know no other (a "h13 " stored in a case breaks every later retrieval).
Status CheckMaterial(const std::string& material, const std::string& source) {
  if (material == "unspecified") return Status::Ok();
  const std::filesystem::path file = retrieval::DefaultDataDir() / "taxonomies" / "material.txt";
  FL_ASSIGN_OR_RETURN(const retrieval::Taxonomy taxonomy, retrieval::Taxonomy::Load(file));
  if (taxonomy.Find(material)) return Status::Ok();
  const std::optional<std::string> near = taxonomy.Suggest(material);
  return Status::BadInput(Where{.file = source, .field = "material"},
                          "'" + material + "' is not a material of data/taxonomies/material.txt" +
                              (near ? " (did you mean '" + *near + "'?)" : std::string()),
                          "write a name or alias exactly as listed there, e.g. H13, 1.2344, 6061, or leave it out");
}

// "profile": a probe profile file from `formloop calibrate sphere` (relative to the part file) or the
// profile itself inline; it replaces ball_radius_mm and pretravel_mm, which may then not be given too.
Status ReadProbeProfileField(const JsonFields& f, const std::string& source, metrology::ProbeModel* model,
                             bool* given) {
  if (!f.Has("profile")) return Status::Ok();
  const std::string field = f.Path("profile");
  if (f.Has("ball_radius_mm") || f.Has("pretravel_mm")) {
    return Status::BadInput(Where{.file = source, .field = field},
                            "a probe profile is given together with ball_radius_mm or pretravel_mm",
                            "give the profile alone: it holds the ball radius and the pretravel");
  }
  Result<metrology::ProbeModel> read = Status::Internal("unset");
  if (f.json().at("profile").is_object()) {
    std::optional<JsonFields> inline_profile;
    FL_RETURN_IF_ERROR(f.Object("profile", &inline_profile));
    read = metrology::ProbeProfileFromJson(inline_profile->json(), source + " field '" + field + "'");
  } else {
    std::string name;
    if (!f.String("profile", &name).ok() || name.empty()) {
      return Status::BadInput(Where{.file = source, .field = field}, "must be a file name or a probe profile object",
                              "write e.g. \"profile\": \"probe.json\" (from `formloop calibrate sphere --out "
                              "probe.json`)");
    }
    const std::filesystem::path given_path(name);
    read = metrology::ReadProbeProfile(
        given_path.is_absolute() ? given_path : std::filesystem::path(source).parent_path() / given_path);
  }
  if (!read.ok()) {
    return Status::BadInput(FormatWhere(Where{.file = source, .field = field}) + read.status().message());
  }
  *model = *read;
  *given = true;
  return Status::Ok();
}

// separating_experiment: "library", a file of `formloop diagnose` (diagnosis.json: each proposal's
// "next_part"; or {"proposals": [...]}), relative to the part file, or {"proposals": [...]} inline.
Status ReadSeparatingExperiment(const nlohmann::json& json, const std::string& source, PartSpec* part) {
  if (!json.contains("separating_experiment")) return Status::Ok();
  const nlohmann::json& value = json.at("separating_experiment");
  const std::string fix =
      "write \"separating_experiment\": \"library\", the diagnosis.json of `formloop diagnose` (relative to the "
      "part file), or {\"proposals\": [...]}";
  nlohmann::json holder;
  std::string from = source, prefix = "separating_experiment.";
  if (value.is_string()) {
    const std::string text = value.get<std::string>();
    if (text == "library") {
      part->separating_experiment = "library";
      return Status::Ok();
    }
    if (text.empty()) return Status::BadInput(Where{.file = source, .field = "separating_experiment"}, "is empty", fix);
    const std::filesystem::path file = std::filesystem::path(source).parent_path() / text;
    FL_ASSIGN_OR_RETURN(holder, ReadJsonFile(file));
    from = file.string();
    prefix.clear();
  } else if (value.is_object()) {
    holder = value;
  } else {
    return Status::BadInput(Where{.file = source, .field = "separating_experiment"},
                            "must be \"library\", a file name or an object", fix);
  }
  if (!holder.is_object() || !holder.contains("proposals") || !holder["proposals"].is_array()) {
    return Status::BadInput(Where{.file = from, .field = prefix + "proposals"}, "missing or not an array", fix);
  }
  const nlohmann::json& list = holder["proposals"];
  for (std::size_t i = 0; i < list.size(); ++i) {
    const std::string at = prefix + "proposals[" + std::to_string(i) + "]";
    // A proposal of `formloop diagnose` carries its change for the next part as "next_part".
    const bool wrapped = list[i].is_object() && list[i].contains("next_part");
    FL_ASSIGN_OR_RETURN(sim::PlannedProposal p,
                        sim::PlannedProposal::FromJson(wrapped ? list[i]["next_part"] : list[i], from,
                                                       at + (wrapped ? ".next_part." : ".")));
    part->proposals.push_back(std::move(p));
  }
  if (part->proposals.empty()) {
    return Status::BadInput(Where{.file = from, .field = prefix + "proposals"},
                            "holds no proposal (the diagnosis found no alias group to separate)",
                            "leave separating_experiment out of the part file");
  }
  part->separating_experiment = "given";
  return Status::Ok();
}

// direct_measurements: a file of `formloop diagnose --direct` relative to the part file, or the list
// inline. The readings are of this part: a "part" label (which a pooled `formloop diagnose` needs) is
// refused.
Status ReadDirect(const nlohmann::json& json, const std::string& source, PartSpec* part) {
  if (!json.contains("direct_measurements")) return Status::Ok();
  const nlohmann::json& value = json.at("direct_measurements");
  std::string from = source;
  if (value.is_string()) {
    const std::string text = value.get<std::string>();
    if (text.empty()) {
      return Status::BadInput(Where{.file = source, .field = "direct_measurements"}, "is empty",
                              "name the readings file (relative to the part file) or leave the field out");
    }
    const std::filesystem::path file = std::filesystem::path(source).parent_path() / text;
    FL_ASSIGN_OR_RETURN(part->direct, sim::ReadDirectMeasurements(file.string()));
    from = file.string();
  } else {
    FL_ASSIGN_OR_RETURN(part->direct, sim::DirectMeasurementsFromJson(value, source, "direct_measurements"));
  }
  for (std::size_t i = 0; i < part->direct.size(); ++i) {
    if (!part->direct[i].part.empty()) {
      return Status::BadInput(Where{.file = from, .field = "direct_measurements[" + std::to_string(i) + "].part"},
                              "a part file's readings are of this part",
                              "leave \"part\" out (it names a part of a pooled `formloop diagnose`)");
    }
  }
  return Status::Ok();
}

}  // namespace

Result<PartSpec> ParsePart(const nlohmann::json& json, const std::string& source) {
  PartSpec part;
  JsonFields top(json, source);
  FL_RETURN_IF_ERROR(top.CheckKnown({"name", "surface", "material", "tolerance_mm", "seed", "fit", "tool", "tools",
                                     "toolpath", "machine", "probing", "analysis", "loops", "comment", "shape_family",
                                     "finish_ra_um", "batch_size", "separating_experiment",
                                     "direct_measurements"}));
  FL_RETURN_IF_ERROR(top.OptionalString("shape_family", &part.shape_family));
  FL_RETURN_IF_ERROR(
      top.OptionalNumber("finish_ra_um", &part.finish_ra_um, {.min = 0, .max = 100, .exclusive_min = true}));
  FL_RETURN_IF_ERROR(ReadInt(top, "batch_size", &part.batch_size, 1, 1000000));
  FL_RETURN_IF_ERROR(top.String("name", &part.name));
  if (part.name.empty() || part.name.find_first_of("/\\()") != std::string::npos) {
    return Status::BadInput(Where{.file = source, .field = "name"}, "must be non-empty without / \\ ( )",
                            "use letters, digits, '-' and '_'");
  }
  FL_RETURN_IF_ERROR(top.OptionalString("material", &part.material));
  FL_RETURN_IF_ERROR(top.Number("tolerance_mm", &part.tolerance_mm, {.min = 0, .max = 10, .exclusive_min = true}));
  long long seed = static_cast<long long>(part.seed);
  FL_RETURN_IF_ERROR(top.OptionalInteger("seed", &seed, 0));
  part.seed = static_cast<unsigned long long>(seed);

  std::optional<JsonFields> surface;
  FL_RETURN_IF_ERROR(top.Object("surface", &surface));
  if (!surface) {
    return Status::BadInput(Where{.file = source, .field = "surface"}, "required field is missing",
                            "add \"surface\": {\"reference\": \"saddle\"} (see `formloop surfaces list`)");
  }
  if (!IsSurfaceFile(surface->json())) {
    FL_RETURN_IF_ERROR(surface->CheckKnown({"reference", "kind", "params", "samples"}));
  }
  if (IsSurfaceFile(surface->json())) {
    FL_ASSIGN_OR_RETURN(part.surface_file, ParseSurfaceFile(*surface, source));
  } else if (surface->Has("kind")) {
    FL_RETURN_IF_ERROR(surface->String("kind", &part.surface_kind));
    FL_RETURN_IF_ERROR(ReadInt(*surface, "samples", &part.surface_samples, 8, 400));
    std::optional<JsonFields> params;
    FL_RETURN_IF_ERROR(surface->Object("params", &params));
    if (params) {
      for (const auto& [key, value] : params->json().items()) {
        FL_RETURN_IF_ERROR(params->Number(key, &part.surface_params[key]));
      }
    }
    // Sampled here, so parameters that give no surface are refused before a run writes anything.
    if (auto grid = recon::ParametricGrid(part.surface_kind, part.surface_params, part.surface_samples); !grid.ok()) {
      return Status::BadInput(Where{.file = source, .field = "surface"}, grid.status().message());
    }
  } else {
    FL_RETURN_IF_ERROR(surface->String("reference", &part.surface_reference));
    if (auto made = recon::MakeReferenceSurface(part.surface_reference); !made.ok()) {
      return Status::BadInput(Where{.file = source, .field = "surface.reference"}, made.status().message());
    }
  }

  std::optional<JsonFields> f;
  FL_RETURN_IF_ERROR(top.Object("fit", &f));
  if (f) {
    FL_RETURN_IF_ERROR(f->CheckKnown({"samples_u", "samples_v", "tolerance_mm", "check_points"}));
    FL_RETURN_IF_ERROR(ReadInt(*f, "samples_u", &part.fit_samples_u, 4, 2000));
    FL_RETURN_IF_ERROR(ReadInt(*f, "samples_v", &part.fit_samples_v, 4, 2000));
    FL_RETURN_IF_ERROR(
        f->OptionalNumber("tolerance_mm", &part.fit.tolerance_mm, {.min = 0, .max = 1, .exclusive_min = true}));
    FL_RETURN_IF_ERROR(ReadInt(*f, "check_points", &part.fit_check_points, 0, 1000000));
  }

  FL_RETURN_IF_ERROR(top.Object("tool", &f));
  if (f) {
    FL_RETURN_IF_ERROR(f->CheckKnown({"number", "radius_mm", "flutes"}));
    FL_RETURN_IF_ERROR(ReadInt(*f, "number", &part.toolpath.tool.number, 1, 9999));
    FL_RETURN_IF_ERROR(f->OptionalNumber("radius_mm", &part.toolpath.tool.radius_mm, kBallRadius));
    FL_RETURN_IF_ERROR(ReadInt(*f, "flutes", &part.flutes, 1, 16));
  }
  if (json.contains("tools")) {
    const Json& tools = json["tools"];
    if (!tools.is_array() || tools.empty()) {
      return Status::BadInput(Where{.file = source, .field = "tools"}, "must be a non-empty array",
                              "write e.g. [{\"number\": 2, \"radius_mm\": 1.5}]");
    }
    for (std::size_t k = 0; k < tools.size(); ++k) {
      const std::string field = "tools[" + std::to_string(k) + "]";
      if (!tools[k].is_object()) return Status::BadInput(Where{.file = source, .field = field}, "must be an object");
      JsonFields t(tools[k], source, field + ".");
      FL_RETURN_IF_ERROR(t.CheckKnown({"number", "radius_mm"}));
      nc::BallEndTool tool;
      FL_RETURN_IF_ERROR(ReadInt(t, "number", &tool.number, 1, 9999));
      FL_RETURN_IF_ERROR(t.Number("radius_mm", &tool.radius_mm, kBallRadius));
      part.tools.push_back(tool);
    }
  }
  FL_RETURN_IF_ERROR(top.Object("toolpath", &f));
  if (f) {
    auto& t = part.toolpath;
    FL_RETURN_IF_ERROR(
        f->CheckKnown({"scallop_um", "chord_tolerance_um", "max_point_spacing_mm", "raster_angle_deg", "zigzag",
                       "lead_mm", "feed_mm_per_min", "plunge_feed_mm_per_min", "spindle_rpm", "clearance_mm"}));
    FL_RETURN_IF_ERROR(f->OptionalNumber("raster_angle_deg", &t.raster_angle_deg, {.min = -360, .max = 360}));
    FL_RETURN_IF_ERROR(f->OptionalNumber("lead_mm", &t.lead_mm, {.min = 0, .max = 100}));
    FL_RETURN_IF_ERROR(f->OptionalNumber("scallop_um", &t.scallop_um, kMicrons));
    FL_RETURN_IF_ERROR(f->OptionalNumber("chord_tolerance_um", &t.chord_tolerance_um, kMicrons));
    FL_RETURN_IF_ERROR(f->OptionalNumber("max_point_spacing_mm", &t.max_point_spacing_mm,
                                         {.min = 0, .max = 100, .exclusive_min = true}));
    FL_RETURN_IF_ERROR(f->OptionalBool("zigzag", &t.zigzag));
    FL_RETURN_IF_ERROR(f->OptionalNumber("feed_mm_per_min", &t.feed_mm_per_min, kFeed));
    FL_RETURN_IF_ERROR(f->OptionalNumber("plunge_feed_mm_per_min", &t.plunge_feed_mm_per_min, kFeed));
    FL_RETURN_IF_ERROR(f->OptionalNumber("spindle_rpm", &t.spindle_rpm, kSpindle));
    FL_RETURN_IF_ERROR(f->OptionalNumber("clearance_mm", &t.clearance_mm, kLength));
  }
  FL_RETURN_IF_ERROR(top.Object("machine", &f));
  if (f) {
    FL_RETURN_IF_ERROR(f->OptionalString("name", &part.machine_name));
    FL_RETURN_IF_ERROR(f->OptionalString("class", &part.machine_class));
    FL_RETURN_IF_ERROR(f->CheckKnown({"name", "class", "dialect", "travel_min_mm", "travel_max_mm",
                                      "max_feed_mm_per_min", "max_spindle_rpm", "effects", "probe"}));
    FL_RETURN_IF_ERROR(ReadVec3(*f, "travel_min_mm", &part.limits.travel_min_mm));
    FL_RETURN_IF_ERROR(ReadVec3(*f, "travel_max_mm", &part.limits.travel_max_mm));
    FL_RETURN_IF_ERROR(f->OptionalString("dialect", &part.dialect));
    if (nc::FindPost(part.dialect) == nullptr) {
      std::string names;
      for (const std::string& name : nc::PostNames()) names += (names.empty() ? "" : ", ") + name;
      return Status::BadInput(Where{.file = source, .field = "machine.dialect"},
                              "unknown controller dialect '" + part.dialect + "'", "use one of " + names);
    }
    FL_RETURN_IF_ERROR(f->OptionalNumber("max_feed_mm_per_min", &part.limits.max_feed_mm_per_min, kFeed));
    FL_RETURN_IF_ERROR(f->OptionalNumber("max_spindle_rpm", &part.limits.max_spindle_rpm, kSpindle));
    std::optional<JsonFields> e;
    FL_RETURN_IF_ERROR(f->Object("effects", &e));
    if (e && (e->Has("format") || e->Has("effects"))) {
      // The effect catalogue's model JSON (simulation/model.h).
      auto model = sim::Model::FromJson(e->json(), source);
      if (!model.ok()) return model.status().WithContext("machine.effects");
      part.effects = std::move(model).value();
    } else if (e) {
      // The fields of the first part format, still read (deprecated).
      sim::MachineEffects x;
      FL_RETURN_IF_ERROR(e->CheckKnown({"tool_radius_error_um", "deflection_um", "thermal_amplitude_um",
                                        "thermal_tau_s", "surface_noise_um", "probe_noise_um"}));
      FL_RETURN_IF_ERROR(e->OptionalNumber("tool_radius_error_um", &x.tool_radius_error_um, kEffectMicrons));
      FL_RETURN_IF_ERROR(e->OptionalNumber("deflection_um", &x.deflection_um, kEffectMicrons));
      FL_RETURN_IF_ERROR(e->OptionalNumber("thermal_amplitude_um", &x.thermal_amplitude_um, kEffectMicrons));
      FL_RETURN_IF_ERROR(
          e->OptionalNumber("thermal_tau_s", &x.thermal_tau_s, {.min = 0, .max = 1e6, .exclusive_min = true}));
      FL_RETURN_IF_ERROR(e->OptionalNumber("surface_noise_um", &x.surface_noise_um, {.min = 0, .max = 100}));
      FL_RETURN_IF_ERROR(e->OptionalNumber("probe_noise_um", &x.probe_noise_um, {.min = 0, .max = 100}));
      FL_RETURN_IF_ERROR(x.Validate().WithContext(source + ": machine.effects"));
      part.effects = x.ToModel();
      log::Warn(
          "{}: machine.effects with the fields tool_radius_error_um, deflection_um, ... is deprecated and will "
          "not be read in a later version; give the effects as the catalogue's model JSON (simulation/model.h), "
          "here: {}",
          source, part.effects->ToJson().dump());
    }
    std::optional<JsonFields> p;
    FL_RETURN_IF_ERROR(f->Object("probe", &p));
    if (p) {
      FL_RETURN_IF_ERROR(p->CheckKnown({"ball_radius_mm", "pretravel_mm", "profile"}));
      FL_RETURN_IF_ERROR(ReadProbeProfileField(*p, source, &part.true_probe, &part.true_probe_profile_given));
      FL_RETURN_IF_ERROR(p->OptionalNumber("ball_radius_mm", &part.true_probe.ball_radius_mm, kBallRadius));
      FL_RETURN_IF_ERROR(p->OptionalNumber("pretravel_mm", &part.true_probe.pretravel_mm, {.min = -1, .max = 1}));
    }
  }
  FL_RETURN_IF_ERROR(top.Object("probing", &f));
  bool true_probe_given = json.contains("machine") && json["machine"].contains("probe");
  if (f) {
    FL_RETURN_IF_ERROR(
        f->CheckKnown({"grid", "inset_fraction", "edge_margin_mm", "ball_radius_mm", "pretravel_mm", "profile",
                       "clearance_mm", "search_mm", "feed_mm_per_min", "tool", "fanuc_result_base", "sinumerik_r_base",
                       "sinumerik_r_last", "min_gap_mm", "shank_radius_mm"}));
    FL_RETURN_IF_ERROR(ReadProbeProfileField(*f, source, &part.probe, &part.probe_profile_given));
    FL_RETURN_IF_ERROR(f->OptionalNumber("edge_margin_mm", &part.probe_edge_margin_mm, kNonNegative));
    FL_RETURN_IF_ERROR(ReadInt(*f, "tool", &part.probe_program.probe_tool, 1, 9999));
    // Where the controller keeps the results (nc-gen/probe_program.h); a plan that does not fit is split.
    FL_RETURN_IF_ERROR(ReadInt(*f, "fanuc_result_base", &part.probe_program.fanuc_result_base, 100, 997));
    FL_RETURN_IF_ERROR(ReadInt(*f, "sinumerik_r_base", &part.probe_program.sinumerik_r_base, 0, 32765));
    FL_RETURN_IF_ERROR(ReadInt(*f, "sinumerik_r_last", &part.probe_program.sinumerik_r_last, 2, 32767));
    if (part.probe_program.sinumerik_r_last < part.probe_program.sinumerik_r_base + 2) {
      return Status::BadInput(Where{.file = source, .field = "probing.sinumerik_r_last"},
                              "leaves no room for one point's X, Y, Z after probing.sinumerik_r_base",
                              "give the control's last R parameter (MD28050 - 1, 99 by default)");
    }
    if (f->Has("grid")) {
      std::vector<long long> g;
      FL_RETURN_IF_ERROR(f->IntegerArray("grid", &g, 5, 1000));
      if (g.size() != 2) {
        return Status::BadInput(Where{.file = source, .field = "probing.grid"}, "expected [nu, nv]",
                                "write two integers from 5 to 1000, e.g. [20, 20]");
      }
      part.probe_nu = static_cast<int>(g[0]);
      part.probe_nv = static_cast<int>(g[1]);
    }
    FL_RETURN_IF_ERROR(f->OptionalNumber("inset_fraction", &part.probe_inset_fraction, {.min = 0, .max = 0.45}));
    FL_RETURN_IF_ERROR(f->OptionalNumber("ball_radius_mm", &part.probe.ball_radius_mm, kBallRadius));
    FL_RETURN_IF_ERROR(f->OptionalNumber("pretravel_mm", &part.probe.pretravel_mm, {.min = -1, .max = 1}));
    FL_RETURN_IF_ERROR(f->OptionalNumber("clearance_mm", &part.probe_program.clearance_mm,
                                         {.min = 0, .max = 100, .exclusive_min = true}));
    FL_RETURN_IF_ERROR(
        f->OptionalNumber("search_mm", &part.probe_program.search_mm, {.min = 0, .max = 50, .exclusive_min = true}));
    FL_RETURN_IF_ERROR(f->OptionalNumber("feed_mm_per_min", &part.probe_program.probe_feed_mm_per_min, kFeed));
    // The probe's gap from the part on the moves that do not probe, and its shank (nc-gen/probe_program.h).
    FL_RETURN_IF_ERROR(
        f->OptionalNumber("min_gap_mm", &part.probe_program.min_gap_mm, {.min = 0, .max = 50, .exclusive_min = true}));
    FL_RETURN_IF_ERROR(
        f->OptionalNumber("shank_radius_mm", &part.probe_program.shank_radius_mm, {.min = 0, .max = 50}));
  }
  if (!true_probe_given) part.true_probe = part.probe;
  part.probe_program.ball_radius_mm = part.probe.ball_radius_mm;
  FL_RETURN_IF_ERROR(top.Object("analysis", &f));
  if (f) {
    FL_RETURN_IF_ERROR(f->CheckKnown({"neighbours", "max_control_net", "coverage_factor"}));
    FL_RETURN_IF_ERROR(ReadInt(*f, "neighbours", &part.analysis.neighbours, 1, 64));
    FL_RETURN_IF_ERROR(ReadInt(*f, "max_control_net", &part.analysis.max_control_net, 3, 20));
    FL_RETURN_IF_ERROR(f->OptionalNumber("coverage_factor", &part.analysis.coverage_factor,
                                         {.min = 0, .max = 10, .exclusive_min = true}));
  }
  FL_RETURN_IF_ERROR(top.Object("loops", &f));
  if (f) {
    FL_RETURN_IF_ERROR(f->CheckKnown({"max", "max_offset_um"}));
    FL_RETURN_IF_ERROR(ReadInt(*f, "max", &part.max_loops, 1, 20));
    FL_RETURN_IF_ERROR(f->OptionalNumber("max_offset_um", &part.compensation.max_offset_um,
                                         {.min = 0, .max = 5000, .exclusive_min = true}));
  }
  // The magazine always holds the part's own tool.
  bool has_own_tool = false;
  for (const auto& t : part.tools) has_own_tool |= t.radius_mm == part.toolpath.tool.radius_mm;
  if (!has_own_tool) part.tools.insert(part.tools.begin(), part.toolpath.tool);
  // What the machine cannot do is refused here, naming both fields, before any program exists.
  const struct {
    const char* field;
    double value;
    const char* limit_field;
    double limit;
  } kMachineBounds[] = {
      {"toolpath.feed_mm_per_min", part.toolpath.feed_mm_per_min, "machine.max_feed_mm_per_min",
       part.limits.max_feed_mm_per_min},
      {"toolpath.plunge_feed_mm_per_min", part.toolpath.plunge_feed_mm_per_min, "machine.max_feed_mm_per_min",
       part.limits.max_feed_mm_per_min},
      {"probing.feed_mm_per_min", part.probe_program.probe_feed_mm_per_min, "machine.max_feed_mm_per_min",
       part.limits.max_feed_mm_per_min},
      {"toolpath.spindle_rpm", part.toolpath.spindle_rpm, "machine.max_spindle_rpm", part.limits.max_spindle_rpm},
  };
  for (const auto& b : kMachineBounds) {
    if (b.value > b.limit) {
      return Status::BadInput(Where{.file = source, .field = b.field},
                              FormatSignificant(b.value, 6) + " is above the machine's " + b.limit_field + " " +
                                  FormatSignificant(b.limit, 6),
                              "lower it, or correct the machine's limit");
    }
  }
  FL_RETURN_IF_ERROR(CheckMaterial(part.material, source));
  // Cross-field validation, reported against the part file.
  auto in_file = [&](Status s) { return s.ok() ? s : Status(s.code(), source + ": " + s.message()); };
  FL_RETURN_IF_ERROR(in_file(part.toolpath.Validate()));
  FL_RETURN_IF_ERROR(in_file(part.limits.Validate()));
  FL_RETURN_IF_ERROR(in_file(part.probe.Validate()));
  FL_RETURN_IF_ERROR(in_file(part.true_probe.Validate()));
  FL_RETURN_IF_ERROR(in_file(part.analysis.Validate()));
  FL_RETURN_IF_ERROR(in_file(part.fit.Validate()));
  FL_RETURN_IF_ERROR(ReadSeparatingExperiment(json, source, &part));
  FL_RETURN_IF_ERROR(ReadDirect(json, source, &part));
  return part;
}

Status CheckPartWork(const PartSpec& part, const nc::ToolpathOptions& plan, const std::string& source,
                     const recon::BSplineSurface* q) {
  // A CAD or scan part's Q exists only once its file is read: its work is checked with the chosen plan, on Q.
  if (q == nullptr && part.surface_file) return Status::Ok();
  nc::RasterEstimate raster;
  if (q != nullptr) {
    raster = nc::EstimateRaster(*q, plan);
  } else if (part.surface_kind.empty()) {
    FL_ASSIGN_OR_RETURN(const std::unique_ptr<recon::AnalyticSurface> surface,
                        recon::MakeReferenceSurface(part.surface_reference));
    raster = nc::EstimateRaster([&surface](double u, double v) { return surface->Derivatives(u, v); },
                                surface->domain(), plan);
  } else {
    FL_ASSIGN_OR_RETURN(const recon::BSplineSurface fitted,
                        recon::FitParametric(part.surface_kind, part.surface_params, part.surface_samples));
    raster = nc::EstimateRaster(fitted, plan);
  }
  const double probe_points = static_cast<double>(part.probe_nu) * part.probe_nv;
  const double probing_s = nc::ProbingSeconds(probe_points, part.probe_program.clearance_mm,
                                              part.probe_program.search_mm, part.probe_program.probe_feed_mm_per_min);
  WorkEstimate work;
  work.what = "part '" + part.name + "' (" + FormatSignificant(raster.passes, 3) + " passes of a ball r " +
              FormatSignificant(plan.tool.radius_mm, 4) + " mm at a scallop of " +
              FormatSignificant(plan.scallop_um, 4) + " um, " + FormatSignificant(probe_points, 7) +
              " probe points, up to " + std::to_string(part.max_loops) + " cycles)";
  work.points = raster.cl_points + probe_points;
  work.memory_bytes = 60e6 + nc::kRunBytesPerClPoint * raster.cl_points + 2e3 * probe_points;
  work.machining_s = part.max_loops * (raster.cutting_s + probing_s);
  work.output_bytes = part.max_loops * nc::kRunOutputBytesPerClPoint * raster.cl_points;
  const std::string field = probing_s > raster.cutting_s ? "probing.grid" : std::string("toolpath.") + raster.driver();
  return CheckWork(work, source, field);
}

Result<PartSpec> ReadPart(const std::filesystem::path& path) {
  FL_ASSIGN_OR_RETURN(Json json, ReadJsonFile(path));
  return ParsePart(json, path.string());
}

nlohmann::json PartSpec::ToJson() const {
  const auto& t = toolpath;
  nlohmann::json surface = {{"reference", surface_reference}};
  if (!surface_kind.empty())
    surface = {{"kind", surface_kind}, {"params", surface_params}, {"samples", surface_samples}};
  // A file is named by its copy beside the resolved part in the run folder (inputs/).
  if (surface_file) surface = surface_file->ToJson(surface_file->CopyName());
  nlohmann::json magazine = nlohmann::json::array();
  for (const auto& tool : tools) magazine.push_back({{"number", tool.number}, {"radius_mm", tool.radius_mm}});
  nlohmann::json out = {
      {"name", name},
      {"surface", surface},
      {"shape_family", ShapeConcept()},
      {"finish_ra_um", finish_ra_um},
      {"batch_size", batch_size},
      {"tools", magazine},
      {"material", material},
      {"tolerance_mm", tolerance_mm},
      {"seed", seed},
      {"fit",
       {{"samples_u", fit_samples_u},
        {"samples_v", fit_samples_v},
        {"tolerance_mm", fit.tolerance_mm},
        {"check_points", fit_check_points}}},
      {"tool", {{"number", t.tool.number}, {"radius_mm", t.tool.radius_mm}, {"flutes", flutes}}},
      {"toolpath",
       {{"scallop_um", t.scallop_um},
        {"chord_tolerance_um", t.chord_tolerance_um},
        {"max_point_spacing_mm", t.max_point_spacing_mm},
        {"raster_angle_deg", t.raster_angle_deg},
        {"zigzag", t.zigzag},
        {"lead_mm", t.lead_mm},
        {"feed_mm_per_min", t.feed_mm_per_min},
        {"plunge_feed_mm_per_min", t.plunge_feed_mm_per_min},
        {"spindle_rpm", t.spindle_rpm},
        {"clearance_mm", t.clearance_mm}}},
      {"machine",
       {{"name", machine_name},
        {"class", machine_class},
        {"dialect", dialect},
        {"travel_min_mm", {limits.travel_min_mm.x(), limits.travel_min_mm.y(), limits.travel_min_mm.z()}},
        {"travel_max_mm", {limits.travel_max_mm.x(), limits.travel_max_mm.y(), limits.travel_max_mm.z()}},
        {"max_feed_mm_per_min", limits.max_feed_mm_per_min},
        {"max_spindle_rpm", limits.max_spindle_rpm},
        {"probe", {{"ball_radius_mm", true_probe.ball_radius_mm}, {"pretravel_mm", true_probe.pretravel_mm}}}}},
      {"probing",
       {{"grid", {probe_nu, probe_nv}},
        {"inset_fraction", probe_inset_fraction},
        {"ball_radius_mm", probe.ball_radius_mm},
        {"pretravel_mm", probe.pretravel_mm},
        {"clearance_mm", probe_program.clearance_mm},
        {"search_mm", probe_program.search_mm},
        {"feed_mm_per_min", probe_program.probe_feed_mm_per_min},
        {"tool", probe_program.probe_tool},
        {"fanuc_result_base", probe_program.fanuc_result_base},
        {"sinumerik_r_base", probe_program.sinumerik_r_base},
        {"sinumerik_r_last", probe_program.sinumerik_r_last}}},
      {"analysis",
       {{"neighbours", analysis.neighbours},
        {"max_control_net", analysis.max_control_net},
        {"coverage_factor", analysis.coverage_factor}}},
      {"loops", {{"max", max_loops}, {"max_offset_um", compensation.max_offset_um}}}};
  // Only effects the part gave: without them `--machine virtual` takes the machine's profile, and a
  // resolved part read again must do the same.
  out["probing"]["edge_margin_mm"] = probe_edge_margin_mm;
  // The probe's gap and shank only when not the defaults (resolved parts of earlier runs stay as they were).
  if (probe_program.min_gap_mm != nc::ProbeProgramOptions{}.min_gap_mm) {
    out["probing"]["min_gap_mm"] = probe_program.min_gap_mm;
  }
  if (probe_program.shank_radius_mm > 0) out["probing"]["shank_radius_mm"] = probe_program.shank_radius_mm;
  if (probe_profile_given) {
    out["probing"].erase("ball_radius_mm");
    out["probing"].erase("pretravel_mm");
    out["probing"]["profile"] = metrology::ProbeProfileToJson(probe);
  }
  if (true_probe_profile_given) out["machine"]["probe"] = {{"profile", metrology::ProbeProfileToJson(true_probe)}};
  if (effects) out["machine"]["effects"] = effects->ToJson();
  if (separating_experiment == "library") out["separating_experiment"] = "library";
  if (separating_experiment == "given") {
    nlohmann::json list = nlohmann::json::array();
    for (const auto& p : proposals) list.push_back(p.ToJson());
    out["separating_experiment"] = {{"proposals", list}};
  }
  if (!direct.empty()) {  // inline: the resolved part holds the readings themselves
    nlohmann::json list = nlohmann::json::array();
    for (const auto& d : direct) list.push_back(d.ToJson());
    out["direct_measurements"] = list;
  }
  return out;
}

std::string PartSpec::SurfaceName() const {
  if (surface_file) return surface_file->Describe();
  if (surface_kind.empty()) return surface_reference;
  std::string text = surface_kind + "(";
  bool first = true;
  for (const auto& [k, v] : surface_params) {
    text += (first ? "" : ", ") + k + "=" + FormatExact(v);
    first = false;
  }
  return text + ")";
}

std::string PartSpec::ShapeConcept() const {
  if (!shape_family.empty()) return shape_family;
  if (surface_file) return "free-form";  // a CAD face or a scan: the taxonomy's node above every free-form family
  if (surface_kind.empty()) return surface_reference;  // the shape taxonomy's leaves carry these names
  static const std::map<std::string, std::string> kShapeOfKind = {
      {"paraboloid", "tilted_paraboloid"}, {"gaussian_pocket", "bowl"}, {"twisted_ruled", "blade"}};
  const auto it = kShapeOfKind.find(surface_kind);
  return it == kShapeOfKind.end() ? surface_kind : it->second;
}

}  // namespace formloop::app
