#pragma once
// The case library (spec/case-library.md §1, §2 storage, §4–§5 rule base): typed access to cases,
// their facet concepts, the facet taxonomies, the versioned rule base, stored GHSOM trees and the audit
// trail, over the schema of kb/schema.h (version 3) on SQLite or PostgreSQL (kb/database.h).
//
// Every write runs in one transaction (Database::RunInTransaction: SQLite BEGIN IMMEDIATE, PostgreSQL
// SERIALIZABLE behind the library's writer lock) together with its audit row, so a crash or a lost
// server leaves either the whole change or none of it. Writers wait for each other instead of failing.
//
// The case file (`formloop kb add PATH CASE.json`), one JSON object:
//   {
//     "uid": "blade-017",                 required; 1-128 of [A-Za-z0-9._:-]; the library's key
//     "name": "turbine blade, batch 3",   required, non-empty
//     "family": "freeform",               required, non-empty: the surface-shape family tag
//     "part": {...},                      required object: part feature description. Checked when present:
//                                           tolerance_mm > 0, finish_ra_um > 0, batch_size integer >= 1,
//                                           material string
//     "simulation": {...},                required object: simulation knowledge. Checked when present:
//                                           effect_models: array of {"effects": [{"name": string,
//                                           "estimate": number, "standard_error": number >= 0}, ...], ...}
//     "manufacturing": {...},             required object: manufacturing knowledge. Checked when present:
//                                           tools: array of objects (radius_mm > 0), strategy / reconstruction /
//                                           compensation: objects, compensation.loops: array of objects
//     "descriptor": [0.1, 2.5, ...],      optional: the geometric descriptor vector (finite numbers)
//     "concepts": {"shape": "...", "material": "H13", ...}   optional: facet -> concept
//   }
// Unknown top-level keys are refused (they are usually typos). "created_at"/"updated_at" (ISO 8601 UTC) are
// written by the library; they are read back from export files so an import keeps them.

#include <cstddef>
#include <filesystem>
#include <functional>
#include <map>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "core/status.h"
#include "kb/database.h"
#include "kb/schema.h"

namespace formloop::kb {

// The export/import text format: JSON Lines, a header line then one line per case, rule and taxonomy node.
inline constexpr const char* kExportFormatName = "formloop-case-library";
inline constexpr int kExportFormatVersion = 1;

// The facets of spec §3 with a default weight in the seeded rule base. Other lowercase facet names are
// accepted in case files (the facet family is open), they simply carry no default weight.
const std::vector<std::string>& KnownFacets();

struct CaseRecord {
  std::string uid;
  std::string name;
  std::string family;
  nlohmann::json part = nlohmann::json::object();           // meta-model part 1
  nlohmann::json simulation = nlohmann::json::object();     // meta-model part 2
  nlohmann::json manufacturing = nlohmann::json::object();  // meta-model part 3
  std::optional<std::vector<double>> descriptor;            // geometric descriptor, #D values
  std::map<std::string, std::string> concepts;              // facet -> concept
  std::string created_at;                                   // ISO 8601 UTC; set by the library
  std::string updated_at;

  // The case-file JSON above (timestamps included when set). Keys are sorted, so dump() is deterministic.
  nlohmann::json ToJson() const;
  // Validates and converts; errors name `source` (a file, possibly with a line) and the bad field.
  static Result<CaseRecord> FromJson(const nlohmann::json& json, const Where& source);
};

// Reads and validates one case file.
Result<CaseRecord> ReadCaseFile(const std::filesystem::path& path);

// A case's part record for one machine/tool/material (schema v3, table case_part_records): what a later
// pooled diagnosis of the same machine/tool/material needs of the part (the JSON of
// simulation/part_record.h; the library checks only that it is an object with a positive "points").
// In the export file, one line {"type": "part_record", "case": uid, "machine", "tool", "material",
// "record"} per row, after the cases.
struct PartRecordRow {
  std::string case_uid;
  std::string machine, tool, material;
  nlohmann::json record = nlohmann::json::object();
  std::string case_updated_at;  // read back: the case's updated_at (newest first)
  // The export line (without the case's timestamp).
  nlohmann::json ToJson() const;
  // An export line; errors name `source`.
  static Result<PartRecordRow> FromJson(const nlohmann::json& json, const Where& source);
};

struct RouteThresholds {
  double low = 0.80;   // below: no adequate case (default plan)
  double high = 0.95;  // above: the case's plan drives NC directly
};

struct Rule {
  int version = 0;
  std::string name;
  nlohmann::json condition = nlohmann::json::object();
  nlohmann::json choice = nlohmann::json::object();
  bool active = false;
  nlohmann::json ToJson() const;
};

// The active rule base.
struct RuleSet {
  int version = 0;
  std::vector<Rule> rules;  // sorted by name
  nlohmann::json ToJson() const;
  const Rule* Find(const std::string& name) const;
};

// Sanity of a rule set: route.direct / route.simulate / route.default present and consistent, thresholds
// 0 < low < high <= 1, facet.weights non-negative numbers with a positive sum. Returns every problem found.
std::vector<std::string> RuleSetProblems(const std::vector<Rule>& rules);
// A rule base as JSON ({"rules": [...]} or the bare array; each {"name", "condition", "choice"}, names
// unique), read with the errors naming `source` and the rule's index. Does not check RuleSetProblems.
Result<std::vector<Rule>> ParseRules(const nlohmann::json& input, const std::string& source);
// The route thresholds of a sane rule set (BadInput listing the problems otherwise).
Result<RouteThresholds> ThresholdsOf(const std::vector<Rule>& rules);

struct TaxonomyNode {
  std::string taxonomy;
  std::string node;
  std::optional<std::string> parent;  // nullopt for a root
};

// A trained GHSOM tree as stored (the structure of map/parameters/quality belongs to retrieval/).
struct GhsomRecord {
  long long id = 0;        // set by StoreGhsom
  std::string created_at;  // set by StoreGhsom
  long long seed = 0;
  nlohmann::json parameters = nlohmann::json::object();  // tau1, tau2, epochs, scaling ...
  nlohmann::json quality = nlohmann::json::object();     // MQE, QE, TE per map ...
  nlohmann::json map = nlohmann::json::object();         // the tree
  long long case_count = -1;                             // cases trained on; -1: the library's count at StoreGhsom
  long long change_counter = -1;  // ChangeCounter() read with the training snapshot; -1: current value
};

struct GhsomStatus {
  bool present = false;
  long long id = 0;
  std::string created_at;
  long long case_count = 0;
  long long trained_at_changes = 0;
  long long current_changes = 0;
  bool stale = false;  // cases were added, replaced or removed since training
  nlohmann::json ToJson() const;
};

struct LibraryStats {
  int schema_version = 0;
  long long cases = 0;
  long long cases_with_descriptor = 0;
  std::map<std::string, long long> per_family;
  std::map<std::string, std::map<std::string, long long>> per_facet_concept;
  int rules_version = 0;
  long long case_changes = 0;
  GhsomStatus ghsom;
  nlohmann::json ToJson() const;
};

struct CheckReport {
  std::string integrity = "ok";                       // PRAGMA integrity_check
  std::vector<std::string> foreign_key_violations;    // "table rowid N -> parent"
  long long orphan_concepts = 0;                      // case_concepts rows without a case
  std::vector<std::string> cases_missing_descriptor;  // uids (a warning: retrieval cannot place them)
  std::vector<std::string> rule_problems;
  GhsomStatus ghsom;
  std::vector<std::string> problems;  // what makes the library not clean
  std::vector<std::string> warnings;  // worth knowing, not failures
  bool clean() const { return problems.empty(); }
  nlohmann::json ToJson() const;
};

struct ImportOptions {
  bool replace = false;  // replace cases whose uid exists instead of refusing the import
  // Called inside the transaction after each case is written (tests use it to interrupt an import).
  std::function<void(std::size_t cases_written)> on_case;
  // Called for every case of the file before anything is written; an error refuses the whole import
  // (`formloop kb import` checks the concepts and descriptor against the taxonomies this way).
  std::function<Status(const CaseRecord&)> check_case;
};

struct ImportReport {
  std::size_t cases_added = 0;
  std::size_t cases_replaced = 0;
  std::size_t rules = 0;
  std::size_t taxonomy_nodes = 0;
  std::size_t part_records = 0;  // in the JSON only when the file had some
  nlohmann::json ToJson() const;
};

struct AuditEntry {
  long long id = 0;
  std::string at;
  std::string action;
  std::string case_uid;
  std::string detail;
};

// An open case library at the current schema version.
class Library {
 public:
  // Refuses (BadInput, file untouched) a file that is not SQLite, an SQLite file without formloop's tables,
  // a library newer than this formloop and one older (run `formloop kb migrate`). NotFound when absent.
  // `library` is a name as in kb/library_url.h (a path, sqlite:PATH or postgresql://...). PostgreSQL:
  // refuses a database without formloop's schema the same way (nothing is written to it).
  static Result<std::unique_ptr<Library>> Open(const std::string& library);

  // Refuses a uid that exists (BadInput) unless `replace`; a replaced case keeps its created_at.
  Status AddCase(const CaseRecord& record, bool replace = false);
  Result<CaseRecord> GetCase(const std::string& uid);
  // Sorted by uid; all families when `family` is empty.
  Result<std::vector<CaseRecord>> ListCases(const std::string& family = "");
  Status RemoveCase(const std::string& uid);

  // Stores (or replaces) the part record of case row.case_uid for row's machine/tool/material, in one
  // transaction with its audit row (joining an enclosing RunInTransaction). NotFound when the case is absent.
  Status SetPartRecord(const PartRecordRow& row);
  // The part records of a machine/tool/material, the newest case first (its updated_at, then uid).
  Result<std::vector<PartRecordRow>> PartRecords(const std::string& machine, const std::string& tool,
                                                 const std::string& material);
  // Every part record, by case uid, machine, tool, material (export; `kb check`).
  Result<std::vector<PartRecordRow>> AllPartRecords();

  Result<LibraryStats> Stats();
  Result<CheckReport> Check();

  // JSON Lines (kExportFormatName), deterministic: cases by uid, rules by (version, name), taxonomy nodes
  // by (taxonomy, node); every object with sorted keys.
  Result<std::string> ExportText();
  Status ExportToFile(const std::filesystem::path& path);  // atomic (temp file + rename)
  // One transaction: all or nothing. Rules in the file replace the rule base (all versions); taxonomy
  // nodes replace the taxonomies the file names. `source` names the input in errors.
  Result<ImportReport> ImportText(const std::string& text, const std::string& source,
                                  const ImportOptions& options = {});
  Result<ImportReport> ImportFile(const std::filesystem::path& path, const ImportOptions& options = {});

  Result<RuleSet> GetRules();
  // Writes `rules` as a new version (the previous becomes inactive). Accepts {"rules": [...]} or [...], each
  // {"name", "condition", "choice"}. Refuses a set that fails RuleSetProblems. Returns the new version.
  Result<int> SetRules(const nlohmann::json& rules, const std::string& source);

  Result<std::vector<TaxonomyNode>> GetTaxonomy(const std::string& taxonomy);
  // Replaces one taxonomy's nodes.
  Status SetTaxonomy(const std::string& taxonomy, const std::vector<TaxonomyNode>& nodes);

  // Counts every add / replace / remove / import of cases.
  Result<long long> ChangeCounter();
  Result<long long> StoreGhsom(GhsomRecord record);  // returns the new id
  // The newest GHSOM, or nullopt when none was trained.
  Result<std::optional<GhsomRecord>> LoadGhsom();
  Result<GhsomStatus> Ghsom();

  // Newest first; all cases when `uid` is empty.
  Result<std::vector<AuditEntry>> Audit(const std::string& uid = "", int limit = 100);

  // Runs `body` as one transaction (kb/database.h: RunInTransaction): the library's writes inside it
  // join it, so e.g. a `kb add` and the GHSOM update it triggers commit together, and a PostgreSQL
  // serialization failure reruns the whole body. `body` must be safe to rerun.
  Status RunInTransaction(const std::function<Status()>& body) { return db_->RunInTransaction(body); }

  Database* db() { return db_.get(); }
  // The SQLite path, or the URL without password: for messages.
  std::filesystem::path path() const { return db_->path(); }

 private:
  explicit Library(std::unique_ptr<Database> db) : db_(std::move(db)) {}
  Status WriteCase(const CaseRecord& record, bool replace, const std::string& action, bool keep_timestamps,
                   bool* replaced);
  Status AuditRow(const std::string& action, const std::string& uid, const std::string& detail);
  Status BumpChanges();
  Status ExportSnapshot(std::string* text);
  std::unique_ptr<Database> db_;
};

// ISO 8601 UTC with milliseconds, e.g. 2026-11-22T00:03:59.123Z.
std::string UtcNow();

}  // namespace formloop::kb
