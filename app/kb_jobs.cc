#include "app/kb_jobs.h"

#include "core/json_io.h"
#include "core/log.h"
#include "kb/library.h"
#include "kb/schema.h"
#include "retrieval/retrieve.h"
#include "retrieval/starter.h"

namespace formloop::app {

Result<nlohmann::json> FillStarterLibrary(const std::string& path, const std::filesystem::path& data_dir,
                                          const retrieval::GhsomOptions& ghsom) {
  FL_ASSIGN_OR_RETURN(auto library, kb::Library::Open(path));
  FL_ASSIGN_OR_RETURN(kb::LibraryStats stats, library->Stats());
  if (stats.cases > 0) {
    return Status::BadInput("case library '" + path + "' already holds " + std::to_string(stats.cases) +
                            " case(s); --starter fills only an empty library");
  }
  FL_ASSIGN_OR_RETURN(retrieval::StarterSpec spec,
                      retrieval::StarterSpec::Load(data_dir / "starter" / "families.json"));
  FL_ASSIGN_OR_RETURN(retrieval::FacetTaxonomies tax, retrieval::FacetTaxonomies::Load(data_dir / "taxonomies"));
  retrieval::FeatureOptions options;
  options.taxonomies = std::make_shared<const retrieval::FacetTaxonomies>(std::move(tax));
  log::Info("starter library: generating {} families x {} cases", spec.families.size(), spec.cases_per_family);
  FL_ASSIGN_OR_RETURN(auto cases, retrieval::GenerateStarterCases(spec, options));
  // One transaction for all cases: the export format (kb/library.h), header line then one case per line.
  std::string text =
      nlohmann::json{{"format", kb::kExportFormatName}, {"format_version", kb::kExportFormatVersion}}.dump();
  text += "\n";
  for (const auto& c : cases) text += nlohmann::json{{"type", "case"}, {"case", c.ToJson()}}.dump() + "\n";
  FL_ASSIGN_OR_RETURN(kb::ImportReport imported, library->ImportText(text, "<starter cases>"));
  FL_ASSIGN_OR_RETURN(Json rules, ReadJsonFile(data_dir / "starter" / "rules.json"));
  FL_ASSIGN_OR_RETURN(int rules_version, library->SetRules(rules, (data_dir / "starter" / "rules.json").string()));
  FL_ASSIGN_OR_RETURN(nlohmann::json trained, retrieval::TrainLibraryGhsom(*library, ghsom));
  return nlohmann::json{{"cases", imported.cases_added},
                        {"families", spec.families.size()},
                        {"rules_version", rules_version},
                        {"ghsom", trained}};
}

Result<nlohmann::json> CreateStarterLibrary(const std::string& path, const std::filesystem::path& data_dir) {
  FL_ASSIGN_OR_RETURN(kb::InitReport report, kb::InitLibrary(path));
  (void)report;
  return FillStarterLibrary(path, data_dir, retrieval::LibraryGhsomDefaults());
}

}  // namespace formloop::app
