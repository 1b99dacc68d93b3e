#pragma once
// The synthetic starter case library (issue 7, "Starter library"): a deterministic generator of cases from
// the small text source data/starter/families.json (format described in data/starter/README.md).
//
// Each family names a parametric free-form surface kind and uniform ranges for its parameters; a case is
// one draw: its surface z = f(x, y) is sampled on a fit_samples × fit_samples grid and fitted as a B-spline
// (recon::FitGrid), its 24 descriptors and facet concepts come from ExtractFeatures, and its three-part
// meta-model (part description, simulation knowledge with learned effect coefficients, manufacturing
// knowledge) is drawn from the family's ranges. Everything comes from one Rng stream seeded by the file's
// "seed", family by family, case by case, so the same file gives byte-identical cases.
//
// Surface kinds: the parametric kinds of the one surface-family registry (reconstruction/surface_family.h).

#include <filesystem>
#include <functional>
#include <map>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "core/random.h"
#include "core/status.h"
#include "kb/library.h"
#include "reconstruction/bspline_surface.h"
#include "retrieval/features.h"

namespace formloop::retrieval {

// The data folder: $FORMLOOP_DATA_DIR when set, else the source tree's data/ (compiled in).
std::filesystem::path DefaultDataDir();

struct StarterRange {
  double lo = 0, hi = 0;
};

struct StarterFamily {
  std::string name;   // family tag of the cases, e.g. "dome"
  std::string shape;  // shape concept
  std::string kind;   // surface kind (header table)
  std::map<std::string, StarterRange> params;
  std::vector<std::string> materials;
  StarterRange tolerance_mm, ra_um, batch, tool_radius_mm, scallop_um;
  std::string machine, strategy;
  std::map<std::string, StarterRange> effects;
};

struct StarterSpec {
  std::uint64_t seed = 0;
  int cases_per_family = 0;
  int fit_samples = 21;
  std::vector<StarterFamily> families;
  static Result<StarterSpec> FromJson(const nlohmann::json& j, const std::string& source);
  static Result<StarterSpec> Load(const std::filesystem::path& path);
  const StarterFamily* Find(const std::string& family) const;
};

// One generated part before feature extraction: the family, its surface parameters and its description.
struct StarterPart {
  std::string uid;
  std::string family;
  std::string kind;
  std::map<std::string, double> params;
  PartDescription description;
  nlohmann::json simulation = nlohmann::json::object();
  nlohmann::json manufacturing = nlohmann::json::object();
};

// Draws every part of the spec (families in file order, cases_per_family each): uid "<family>-NNN".
std::vector<StarterPart> DrawStarterParts(const StarterSpec& spec);

// The same part with every surface parameter multiplied by (1 + s_k · delta), s_k = ±1 drawn from rng;
// the description, tools and knowledge stay the base part's. uid gets `suffix`.
StarterPart PerturbStarterPart(const StarterPart& base, double delta, Rng& rng, const std::string& suffix);

// Surface + ExtractFeatures + the case record (descriptor and concepts filled).
Result<kb::CaseRecord> MakeStarterCase(const StarterPart& part, int fit_samples, const FeatureOptions& options);

// All cases of the spec.
Result<std::vector<kb::CaseRecord>> GenerateStarterCases(const StarterSpec& spec, const FeatureOptions& options);

// PartDescription as stored in a case's "part" object and read back from it (and from retrieve query files).
nlohmann::json PartDescriptionToJson(const PartDescription& part);
Result<PartDescription> PartDescriptionFromJson(const nlohmann::json& j, const std::string& source);

}  // namespace formloop::retrieval
