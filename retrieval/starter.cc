#include "retrieval/starter.h"

#include <charconv>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <functional>
#include <limits>
#include <numbers>
#include <sstream>

#include "core/json_io.h"
#include "core/number_text.h"
#include "reconstruction/surface_family.h"

namespace formloop::retrieval {
namespace {

using nlohmann::json;

#ifndef FORMLOOP_STARTER_DATA_DIR
#define FORMLOOP_STARTER_DATA_DIR "data"
#endif

// [lo, hi] with lo <= hi.
Result<StarterRange> ReadRange(const JsonFields& f, const std::string& key) {
  std::vector<double> v;
  FL_RETURN_IF_ERROR(f.NumberArray(key, &v, 2));
  if (!(v[0] <= v[1])) {
    return Status::BadInput(Where{.file = f.source(), .field = f.Path(key)}, "expected [lo, hi] with lo <= hi");
  }
  return StarterRange{v[0], v[1]};
}

// Every member of the object `key` as a range, by name.
Status ReadRanges(const JsonFields& f, const std::string& key, std::map<std::string, StarterRange>* out) {
  std::optional<JsonFields> ranges;
  FL_RETURN_IF_ERROR(f.RequiredObject(key, &ranges));
  for (const auto& [name, value] : ranges->json().items()) {
    FL_ASSIGN_OR_RETURN((*out)[name], ReadRange(*ranges, name));
  }
  return Status::Ok();
}

double Draw(Rng& rng, const StarterRange& r) { return r.lo + (r.hi - r.lo) * rng.Uniform(); }

// Rough material properties for the simulation knowledge (E GPa, hardness HV, specific cutting force N/mm²).
json MaterialProperties(const std::string& material) {
  struct Props {
    const char* name;
    double e_gpa, hv, kc;
  };
  static const Props kTable[] = {{"H13", 210, 520, 2600},       {"H11", 210, 500, 2550},
                                 {"P20", 205, 300, 2100},       {"P20+Ni", 205, 340, 2200},
                                 {"1.2738", 205, 340, 2200},    {"D2", 210, 600, 2900},
                                 {"420", 200, 480, 2400},       {"C45", 205, 200, 1800},
                                 {"S355", 205, 170, 1700},      {"6061", 69, 107, 700},
                                 {"7075", 72, 175, 800},        {"5083", 71, 95, 650},
                                 {"Ti-6Al-4V", 114, 340, 1600}, {"Inconel 718", 200, 400, 3100},
                                 {"POM", 3, 20, 150},           {"epoxy tooling board", 2, 10, 80}};
  for (const Props& p : kTable) {
    if (material == p.name) {
      return {{"youngs_modulus_gpa", p.e_gpa}, {"hardness_hv", p.hv}, {"specific_cutting_force_n_per_mm2", p.kc}};
    }
  }
  return {{"youngs_modulus_gpa", nullptr}, {"hardness_hv", nullptr}, {"specific_cutting_force_n_per_mm2", nullptr}};
}

// %.*g without the locale, so the generated library is the same whatever LC_NUMERIC says.
std::string Round(double x, int digits) { return FormatSignificant(x, digits); }
double R6(double x) {
  const std::string text = Round(x, 6);
  double value = 0;
  std::from_chars(text.data(), text.data() + text.size(), value);
  return value;
}

}  // namespace

std::filesystem::path DefaultDataDir() {
  if (const char* env = std::getenv("FORMLOOP_DATA_DIR"); env != nullptr && *env != '\0') return env;
  return FORMLOOP_STARTER_DATA_DIR;
}

Result<StarterSpec> StarterSpec::FromJson(const json& j, const std::string& source) {
  const Where where{.file = source};
  if (!j.is_object() || j.value("format", "") != "formloop-starter-families") {
    return Status::BadInput(where, "not a starter families file (\"format\": \"formloop-starter-families\")");
  }
  const JsonFields top(j, source);
  StarterSpec spec;
  long long cases = 0, fit_samples = spec.fit_samples;
  FL_RETURN_IF_ERROR(top.Unsigned("seed", &spec.seed));
  FL_RETURN_IF_ERROR(top.Integer("cases_per_family", &cases, 1, 100000));
  FL_RETURN_IF_ERROR(top.OptionalInteger("fit_samples", &fit_samples, 4, recon::kMaxInterpolationSamples));
  spec.cases_per_family = static_cast<int>(cases);
  spec.fit_samples = static_cast<int>(fit_samples);
  std::vector<JsonFields> families;
  FL_RETURN_IF_ERROR(top.ObjectArray("families", &families));
  for (const JsonFields& f : families) {
    StarterFamily fam;
    FL_RETURN_IF_ERROR(f.String("name", &fam.name));
    FL_RETURN_IF_ERROR(f.String("shape", &fam.shape));
    FL_RETURN_IF_ERROR(f.String("kind", &fam.kind));
    FL_RETURN_IF_ERROR(ReadRanges(f, "params", &fam.params));
    FL_RETURN_IF_ERROR(f.StringArray("materials", &fam.materials));
    FL_ASSIGN_OR_RETURN(fam.tolerance_mm, ReadRange(f, "tolerance_mm"));
    FL_ASSIGN_OR_RETURN(fam.ra_um, ReadRange(f, "ra_um"));
    FL_ASSIGN_OR_RETURN(fam.batch, ReadRange(f, "batch"));
    FL_ASSIGN_OR_RETURN(fam.tool_radius_mm, ReadRange(f, "tool_radius_mm"));
    FL_ASSIGN_OR_RETURN(fam.scallop_um, ReadRange(f, "scallop_um"));
    FL_RETURN_IF_ERROR(f.String("machine", &fam.machine));
    FL_RETURN_IF_ERROR(f.String("strategy", &fam.strategy));
    FL_RETURN_IF_ERROR(ReadRanges(f, "effects", &fam.effects));
    if (fam.materials.empty())
      return Status::BadInput(Where{.file = source, .field = f.Path("materials")}, "no materials");
    spec.families.push_back(std::move(fam));
  }
  if (spec.families.empty()) return Status::BadInput(Where{.file = source, .field = "families"}, "no families");
  return spec;
}

Result<StarterSpec> StarterSpec::Load(const std::filesystem::path& path) {
  std::ifstream in(path);
  if (!in) return Status::NotFound("cannot open starter families file '" + path.string() + "'");
  std::stringstream ss;
  ss << in.rdbuf();
  json j = json::parse(ss.str(), nullptr, /*allow_exceptions=*/false);
  if (j.is_discarded()) return Status::BadInput(Where{.file = path.string()}, "not valid JSON");
  return FromJson(j, path.string());
}

const StarterFamily* StarterSpec::Find(const std::string& family) const {
  for (const auto& f : families) {
    if (f.name == family) return &f;
  }
  return nullptr;
}

std::vector<StarterPart> DrawStarterParts(const StarterSpec& spec) {
  Rng rng(spec.seed);
  std::vector<StarterPart> parts;
  for (const StarterFamily& fam : spec.families) {
    for (int k = 0; k < spec.cases_per_family; ++k) {
      StarterPart part;
      char uid[160];
      std::snprintf(uid, sizeof uid, "%s-%03d", fam.name.c_str(), k);
      part.uid = uid;
      part.family = fam.name;
      part.kind = fam.kind;
      for (const auto& [name, range] : fam.params) part.params[name] = R6(Draw(rng, range));
      PartDescription& d = part.description;
      d.family_tag = fam.name;
      d.shape_family = fam.shape;
      d.material = fam.materials[rng.UniformIndex(fam.materials.size())];
      d.form_tolerance_mm = R6(Draw(rng, fam.tolerance_mm));
      d.ra_um = R6(Draw(rng, fam.ra_um));
      d.batch_size = static_cast<int>(std::lround(Draw(rng, fam.batch)));
      d.machine_class = fam.machine;
      d.tool_radius_mm = R6(Draw(rng, fam.tool_radius_mm));
      d.strategy = fam.strategy;
      d.raster_angle_deg = R6(std::floor(Draw(rng, {0, 180}) / 15) * 15);
      const double scallop = R6(Draw(rng, fam.scallop_um));
      json effects = json::array();
      for (const auto& [name, range] : fam.effects) {
        const double est = R6(Draw(rng, range));
        effects.push_back(
            {{"name", name}, {"estimate", est}, {"standard_error", R6(0.05 * est + 0.1 * rng.Uniform())}});
      }
      part.simulation = {{"model_format", "bspline-grid-fit"},
                         {"material", d.material},
                         {"material_properties", MaterialProperties(d.material)},
                         {"size_mm", {{"x", nullptr}, {"y", nullptr}}},
                         {"effect_models", json::array({{{"machine", d.machine_class},
                                                         {"tool", "ball r" + Round(d.tool_radius_mm, 4)},
                                                         {"material", d.material},
                                                         {"effects", effects},
                                                         {"confidence", 0.95}}})}};
      const double before = R6(d.form_tolerance_mm * 1e3 * (2.0 + 3.0 * rng.Uniform()));
      const int loops = 1 + static_cast<int>(rng.UniformIndex(3));
      json loop_rows = json::array();
      double err = before;
      for (int l = 0; l < loops; ++l) {
        const double after = R6(err * (0.25 + 0.2 * rng.Uniform()));
        loop_rows.push_back({{"loop", l + 1}, {"form_error_before_um", err}, {"form_error_after_um", after}});
        err = after;
      }
      const int flutes = 2 + static_cast<int>(rng.UniformIndex(3));
      part.manufacturing = {
          {"machine", d.machine_class + " machining centre"},
          {"tools", json::array({{{"type", "ball-end"},
                                  {"radius_mm", d.tool_radius_mm},
                                  {"flutes", flutes},
                                  {"stick_out_mm", R6(4 * d.tool_radius_mm + 10)}}})},
          {"strategy",
           {{"pattern", d.strategy},
            {"raster_angle_deg", d.raster_angle_deg},
            {"scallop_um", scallop},
            {"direction", "climb"}}},
          {"feeds",
           {{"feed_mm_per_min", R6(800 + 1200 * rng.Uniform())}, {"spindle_rpm", R6(8000 + 16000 * rng.Uniform())}}},
          {"compensation", {{"method", "mirror-systematic"}, {"loops", loop_rows}}},
          {"probing", {{"grid", {20, 20}}, {"inset_fraction", 0.05}}},
          {"reconstruction", {{"algorithm", "B-spline"}, {"degree", 3}, {"control_net", {8, 8}}, {"smoothing", 1e-4}}}};
      parts.push_back(std::move(part));
    }
  }
  return parts;
}

StarterPart PerturbStarterPart(const StarterPart& base, double delta, Rng& rng, const std::string& suffix) {
  StarterPart p = base;
  p.uid = base.uid + suffix;
  for (auto& [name, value] : p.params) value *= 1.0 + (rng.Uniform() < 0.5 ? -delta : delta);
  return p;
}

nlohmann::json PartDescriptionToJson(const PartDescription& d) {
  return {{"family_tag", d.family_tag},       {"shape_family", d.shape_family},
          {"material", d.material},           {"tolerance_mm", d.form_tolerance_mm},
          {"finish_ra_um", d.ra_um},          {"batch_size", d.batch_size},
          {"machine_class", d.machine_class}, {"tool_radius_mm", d.tool_radius_mm},
          {"strategy", d.strategy},           {"raster_angle_deg", d.raster_angle_deg}};
}

Result<PartDescription> PartDescriptionFromJson(const nlohmann::json& j, const std::string& source) {
  PartDescription d;
  if (!j.is_object()) return Status::BadInput(Where{.file = source}, "the part description must be a JSON object");
  const JsonFields f(j, source);
  FL_RETURN_IF_ERROR(f.OptionalString("name", &d.family_tag));
  FL_RETURN_IF_ERROR(f.OptionalString("family_tag", &d.family_tag));
  FL_RETURN_IF_ERROR(f.String("shape_family", &d.shape_family));
  FL_RETURN_IF_ERROR(f.String("material", &d.material));
  FL_RETURN_IF_ERROR(f.Number("tolerance_mm", &d.form_tolerance_mm));
  FL_RETURN_IF_ERROR(f.Has("finish_ra_um") ? f.Number("finish_ra_um", &d.ra_um) : f.Number("ra_um", &d.ra_um));
  long long batch = d.batch_size;
  FL_RETURN_IF_ERROR(f.OptionalInteger("batch_size", &batch, 1));
  d.batch_size = static_cast<int>(batch);
  FL_RETURN_IF_ERROR(f.String("machine_class", &d.machine_class));
  if (f.Has("tool_radius_mm")) {
    FL_RETURN_IF_ERROR(f.Number("tool_radius_mm", &d.tool_radius_mm));
  } else {
    std::optional<JsonFields> tool;
    FL_RETURN_IF_ERROR(f.Object("tool", &tool));
    if (tool) FL_RETURN_IF_ERROR(tool->OptionalNumber("radius_mm", &d.tool_radius_mm));
  }
  FL_RETURN_IF_ERROR(f.OptionalString("strategy", &d.strategy));
  FL_RETURN_IF_ERROR(f.OptionalNumber("raster_angle_deg", &d.raster_angle_deg));
  return d;
}

Result<kb::CaseRecord> MakeStarterCase(const StarterPart& part, int fit_samples, const FeatureOptions& options) {
  FL_ASSIGN_OR_RETURN(recon::BSplineSurface surface, recon::FitParametric(part.kind, part.params, fit_samples));
  FL_ASSIGN_OR_RETURN(PartFeatures features, ExtractFeatures(part.description, surface, options));
  kb::CaseRecord r;
  r.uid = part.uid;
  r.name = part.family + " " + part.uid.substr(part.uid.rfind('-') + 1) + " (starter)";
  r.family = part.family;
  r.part = PartDescriptionToJson(part.description);
  r.part["surface"] = {{"kind", part.kind}, {"params", part.params}};
  r.part["size_mm"] = features.size_mm;
  r.simulation = part.simulation;
  r.manufacturing = part.manufacturing;
  r.descriptor =
      std::vector<double>(features.descriptors.data(), features.descriptors.data() + features.descriptors.size());
  r.concepts = features.Concepts();
  return r;
}

Result<std::vector<kb::CaseRecord>> GenerateStarterCases(const StarterSpec& spec, const FeatureOptions& options) {
  std::vector<kb::CaseRecord> cases;
  for (const StarterPart& part : DrawStarterParts(spec)) {
    FL_ASSIGN_OR_RETURN(kb::CaseRecord r, MakeStarterCase(part, spec.fit_samples, options));
    cases.push_back(std::move(r));
  }
  return cases;
}

}  // namespace formloop::retrieval
