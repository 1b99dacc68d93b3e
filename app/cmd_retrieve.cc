// `formloop retrieve --library PATH --part PART.json [--top K] [--breadth B] [--max-scored N] [--data DIR]`: the most
// similar cases of a case library for a part, with A, the per-facet similarities and common nodes, and the route
// (retrieval/retrieve.h). `formloop retrieve --library PATH --calibrate` prints the leave-one-out report instead
// (same as `formloop kb calibrate PATH`).
//
// The query file (JSON object), the fields of the part description (retrieval::PartDescriptionFromJson):
//   {
//     "name": "door-handle die",          optional, carried
//     "shape_family": "sphere_cap",       node or alias of data/taxonomies/shape.txt
//     "material": "H13",                  node or alias of material.txt
//     "tolerance_mm": 0.01,               form tolerance (> 0)
//     "finish_ra_um": 0.4,                (or "ra_um")
//     "batch_size": 5,                    optional (1)
//     "machine_class": "3-axis",          "3-axis" or "5-axis"
//     "tool_radius_mm": 3,                (or "tool": {"radius_mm": 3}, app/part.h style)
//     and the surface, one of:
//     "surface": {"kind": "sphere_cap", "params": {"size_mm": 80, "radius_ratio": 1.3}}   a starter kind
//                                                    (retrieval/starter.h), fitted from 21 × 21 samples
//     "surface": {"reference": "saddle"}  or  "surface_reference": "saddle"   an analytic reference surface
//                                                    (app/part.h style), fitted from 50 × 50 samples
//     "descriptor": [24 numbers]                      the descriptor itself
//   }
// A case file (`formloop kb show` output: "part" object with these fields, "descriptor") is accepted too, and
// so is a part file of `formloop run` (app/part.h, e.g. data/parts/demo-saddle.json): it is described and
// its surface fitted as the run does.

#include <iostream>
#include <map>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "app/case_knowledge.h"
#include "app/command.h"
#include "app/part.h"
#include "app/pipeline_stages.h"
#include "app/route_calibration.h"
#include "app/surface_source.h"
#include "core/json_io.h"
#include "core/log.h"
#include "kb/library.h"
#include "reconstruction/analytic_surface.h"
#include "reconstruction/bspline_surface.h"
#include "reconstruction/surface_family.h"
#include "retrieval/retrieve.h"
#include "retrieval/starter.h"

namespace formloop::app {
namespace {

struct RetrieveArgs {
  std::string library;
  std::string part;
  std::string data;
  int top = 5;
  int breadth = 1;
  int max_scored = 0;
  bool calibrate = false;
};

// A run's part file (app/part.h): described and fitted as `formloop run` does it.
Result<retrieval::PartFeatures> PartFileFeatures(const PartSpec& part, const retrieval::FeatureOptions& options) {
  if (part.surface_file) {  // CAD faces or a scan (app/surface_source.h)
    FL_ASSIGN_OR_RETURN(const SurfaceFromFile from_file, BuildSurfaceFromFile(*part.surface_file, part.tolerance_mm));
    return retrieval::ExtractFeatures(DescriptionOf(part, part.toolpath), from_file.q, options);
  }
  FL_ASSIGN_OR_RETURN(const recon::FamilySurface built,
                      recon::BuildFamilySurface(stages::FamilySurfaceOptionsOf(part, part.seed, /*check_points=*/0)));
  return retrieval::ExtractFeatures(DescriptionOf(part, part.toolpath), built.q, options);
}

Result<retrieval::PartFeatures> QueryFeatures(const nlohmann::json& file, const std::string& source,
                                              const retrieval::FeatureOptions& options) {
  // A part file of `formloop run` is accepted wherever a part is asked for; a file in the query format
  // below names shape_family (or holds a case's "part" or a descriptor).
  const bool query_format =
      file.is_object() && (file.contains("shape_family") || file.contains("part") || file.contains("descriptor"));
  if (!query_format) {
    FL_ASSIGN_OR_RETURN(const PartSpec spec, ParsePart(file, source));
    return PartFileFeatures(spec, options);
  }
  const nlohmann::json& part = file.contains("part") && file["part"].is_object() ? file["part"] : file;
  FL_ASSIGN_OR_RETURN(retrieval::PartDescription desc, retrieval::PartDescriptionFromJson(part, source));
  const JsonFields top(file, source);
  if (top.Has("descriptor")) {
    FL_ASSIGN_OR_RETURN(retrieval::PartFeatures f, retrieval::ClassifyPart(desc, *options.taxonomies));
    std::vector<double> values;
    FL_RETURN_IF_ERROR(top.NumberArray("descriptor", &values, static_cast<std::size_t>(retrieval::kDescriptorCount)));
    f.descriptors = Eigen::Map<const Eigen::VectorXd>(values.data(), retrieval::kDescriptorCount);
    return f;
  }
  const JsonFields fields(part, source, &part == &file ? "" : "part.");
  std::optional<JsonFields> surface;
  FL_RETURN_IF_ERROR(fields.Object("surface", &surface));
  recon::BSplineSurface q;
  if (surface && surface->Has("kind")) {
    std::string kind;
    long long samples = 21;
    FL_RETURN_IF_ERROR(surface->String("kind", &kind));
    FL_RETURN_IF_ERROR(surface->OptionalInteger("samples", &samples, 4, 400));
    std::map<std::string, double> params;
    std::optional<JsonFields> params_json;
    FL_RETURN_IF_ERROR(surface->Object("params", &params_json));
    if (params_json) {
      for (const auto& [k, v] : params_json->json().items()) FL_RETURN_IF_ERROR(params_json->Number(k, &params[k]));
    }
    FL_ASSIGN_OR_RETURN(q, recon::FitParametric(kind, params, static_cast<int>(samples)));
  } else {
    std::string reference;
    if (surface) FL_RETURN_IF_ERROR(surface->OptionalString("reference", &reference));
    if (reference.empty()) FL_RETURN_IF_ERROR(fields.OptionalString("surface_reference", &reference));
    if (reference.empty()) {
      return Status::BadInput(Where{.file = source, .field = "surface"}, "no surface",
                              "give surface.kind + surface.params, surface.reference, or descriptor");
    }
    FL_ASSIGN_OR_RETURN(std::unique_ptr<recon::AnalyticSurface> analytic, recon::MakeReferenceSurface(reference));
    recon::FitReport report;
    FL_ASSIGN_OR_RETURN(q, recon::FitAnalytic(*analytic, 50, 50, recon::GridFitOptions{}, 0, 1, &report));
  }
  return retrieval::ExtractFeatures(desc, q, options);
}

}  // namespace

void AddRetrieveCommand(CLI::App& root, CommandAction* action) {
  auto args = std::make_shared<RetrieveArgs>();
  CLI::App* cmd = root.add_subcommand(
      "retrieve",
      "Retrieve the most similar cases of a case library for a part: A, per-facet similarities and common nodes, and "
      "the route (direct / simulate / default) from the rule-base thresholds. JSON on stdout.");
  cmd->add_option("--library", args->library, "case library file (trained: formloop kb train)")->required();
  cmd->add_option("--part", args->part, "query part JSON (format in app/cmd_retrieve.cc)");
  cmd->add_option("--top", args->top, "number of ranked cases printed")->capture_default_str();
  cmd->add_option("--breadth", args->breadth, "candidates: 0 leaf, 1 + grid neighbours, 2 + the leaf's map, ...")
      ->capture_default_str();
  cmd->add_option("--max-scored", args->max_scored,
                  "score only the N candidates nearest in the GHSOM input space (0: all; for big libraries)")
      ->capture_default_str();
  cmd->add_option("--data", args->data, "data folder with taxonomies/ (default: the source tree's data/)");
  cmd->add_flag("--calibrate", args->calibrate, "print the leave-one-out calibration report instead");
  cmd->callback([args, action] {
    *action = [args]() -> Status {
      const std::filesystem::path data =
          args->data.empty() ? retrieval::DefaultDataDir() : std::filesystem::path(args->data);
      if (args->top < 1) return Status::BadInput(Where{.field = "--top"}, "must be at least 1", "use e.g. 5");
      if (args->breadth < 0) return Status::BadInput(Where{.field = "--breadth"}, "must be >= 0", "use 0, 1 or 2");
      if (args->max_scored < 0) {
        return Status::BadInput(Where{.field = "--max-scored"}, "must be >= 0", "use 0 (all) or a count");
      }
      FL_ASSIGN_OR_RETURN(retrieval::FacetTaxonomies tax, retrieval::FacetTaxonomies::Load(data / "taxonomies"));
      retrieval::FeatureOptions options;
      options.taxonomies = std::make_shared<const retrieval::FacetTaxonomies>(std::move(tax));
      FL_ASSIGN_OR_RETURN(auto library, kb::Library::Open(args->library));
      FL_ASSIGN_OR_RETURN(kb::GhsomStatus status, library->Ghsom());
      if (status.stale) log::Warn("the GHSOM of {} is stale; run `formloop kb train {}`", args->library, args->library);
      FL_ASSIGN_OR_RETURN(retrieval::RetrievalModel model,
                          retrieval::RetrievalModel::Load(*library, *options.taxonomies));
      retrieval::RetrieveOptions ro;
      ro.breadth = args->breadth;
      ro.top = args->top;
      ro.max_scored = args->max_scored;
      if (args->calibrate) {
        CalibrationOptions co;
        co.breadth = args->breadth;
        co.data_dir = data;
        FL_ASSIGN_OR_RETURN(nlohmann::json report, CalibrationReport(args->library, co));
        std::cout << report.dump(2) << std::endl;
        return Status::Ok();
      }
      if (args->part.empty()) return Status::BadInput("retrieve: give --part PART.json (or --calibrate)");
      FL_ASSIGN_OR_RETURN(Json file, ReadJsonFile(args->part));
      FL_ASSIGN_OR_RETURN(retrieval::PartFeatures features, QueryFeatures(file, args->part, options));
      FL_ASSIGN_OR_RETURN(retrieval::RetrievalResult result, model.Retrieve(features, ro));
      nlohmann::json out = result.ToJson();
      out["query"]["part"] = args->part;
      out["query"]["concepts"] = features.Concepts();
      out["library"] = {{"path", args->library},
                        {"ghsom_id", status.id},
                        {"stale", status.stale},
                        {"cases_not_in_ghsom", model.untrained().size()}};
      log::Info("retrieve: best A = {:.4f} -> route {}", result.best_similarity, result.route);
      std::cout << out.dump(2) << std::endl;
      return Status::Ok();
    };
  });
}

}  // namespace formloop::app
