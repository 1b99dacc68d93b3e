#include "kb/library.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <ctime>
#include <set>
#include <sstream>

#include "core/atomic_file.h"
#include "core/json_io.h"

namespace formloop::kb {
namespace {

using nlohmann::json;

Result<json> ParseJsonColumn(const std::string& text, const std::string& what) {
  json j = json::parse(text, nullptr, /*allow_exceptions=*/false);
  if (j.is_discarded()) return Status::Internal("case library: column " + what + " is not valid JSON");
  return j;
}

}  // namespace

std::string UtcNow() {
  const auto now = std::chrono::system_clock::now();
  const std::time_t seconds = std::chrono::system_clock::to_time_t(now);
  const long long ms = std::chrono::duration_cast<std::chrono::milliseconds>(now.time_since_epoch()).count() % 1000;
  std::tm tm{};
  gmtime_r(&seconds, &tm);
  char buffer[64];
  std::snprintf(buffer, sizeof buffer, "%04d-%02d-%02dT%02d:%02d:%02d.%03lldZ", tm.tm_year + 1900, tm.tm_mon + 1,
                tm.tm_mday, tm.tm_hour, tm.tm_min, tm.tm_sec, ms);
  return buffer;
}

// ---------------------------------------------------------------------------------------------- Library

Result<std::unique_ptr<Library>> Library::Open(const std::string& library) {
  FL_ASSIGN_OR_RETURN(LibraryUrl url, LibraryUrl::Parse(library));
  std::unique_ptr<Database> db;
  if (url.is_postgres()) {
    FL_ASSIGN_OR_RETURN(db, Database::Open(url, Database::Mode::kOpenExisting));
    FL_ASSIGN_OR_RETURN(int version, CheckLibrarySchema(db.get(), /*allow_unversioned=*/false));
    if (version < LatestSchemaVersion()) {
      return Status::BadInput("case library '" + url.display + "' has schema version " + std::to_string(version) +
                              ", older than this formloop's " + std::to_string(LatestSchemaVersion()) +
                              ". Fix: run `formloop kb migrate " + url.display + "`");
    }
    return std::unique_ptr<Library>(new Library(std::move(db)));
  }
  const std::filesystem::path& path = url.path;
  FL_ASSIGN_OR_RETURN(int version, ProbeLibraryFile(path, /*allow_unversioned=*/false));
  if (version < LatestSchemaVersion()) {
    return Status::BadInput("case library '" + path.string() + "' has schema version " + std::to_string(version) +
                            ", older than this formloop's " + std::to_string(LatestSchemaVersion()) +
                            ". Fix: run `formloop kb migrate " + path.string() + "`");
  }
  FL_ASSIGN_OR_RETURN(db, Database::Open(path, Database::Mode::kOpenExisting));
  // The probe read without locks; confirm on the real connection.
  FL_ASSIGN_OR_RETURN(long long actual, db->SchemaVersion());
  if (actual != LatestSchemaVersion()) {
    return Status::BadInput("case library '" + path.string() + "' changed to schema version " + std::to_string(actual) +
                            " while being opened; this formloop uses " + std::to_string(LatestSchemaVersion()));
  }
  return std::unique_ptr<Library>(new Library(std::move(db)));
}

Status Library::AuditRow(const std::string& action, const std::string& uid, const std::string& detail) {
  FL_ASSIGN_OR_RETURN(Statement stmt,
                      db_->Prepare("INSERT INTO audit(at, action, case_uid, detail) VALUES (?1, ?2, ?3, ?4);"));
  FL_RETURN_IF_ERROR(stmt.Bind(1, UtcNow()));
  FL_RETURN_IF_ERROR(stmt.Bind(2, action));
  FL_RETURN_IF_ERROR(uid.empty() ? stmt.BindNull(3) : stmt.Bind(3, uid));
  FL_RETURN_IF_ERROR(stmt.Bind(4, detail));
  return stmt.Step().status();
}

Status Library::BumpChanges() {
  return db_->Execute(
      "UPDATE library_info SET value = CAST(CAST(value AS INTEGER) + 1 AS TEXT) WHERE key = 'case_changes';");
}

Result<long long> Library::ChangeCounter() {
  return db_->QueryInt(
      "SELECT coalesce((SELECT CAST(value AS INTEGER) FROM library_info WHERE key = 'case_changes'), 0);");
}

Status Library::WriteCase(const CaseRecord& record, bool replace, const std::string& action, bool keep_timestamps,
                          bool* replaced) {
  *replaced = false;
  FL_ASSIGN_OR_RETURN(Statement find, db_->Prepare("SELECT id, created_at FROM cases WHERE uid = ?1;"));
  FL_RETURN_IF_ERROR(find.Bind(1, record.uid));
  FL_ASSIGN_OR_RETURN(bool exists, find.Step());
  const std::string now = UtcNow();
  std::string created = keep_timestamps && !record.created_at.empty() ? record.created_at : now;
  const std::string updated = keep_timestamps && !record.updated_at.empty() ? record.updated_at : now;
  long long id = 0;
  if (exists) {
    if (!replace) {
      return Status::BadInput("case library '" + db_->name() + "': a case with uid '" + record.uid +
                              "' exists. Fix: give another uid, or --replace to overwrite it");
    }
    id = find.ColumnInt(0);
    if (!keep_timestamps || record.created_at.empty()) created = find.ColumnText(1);
    *replaced = true;
  }
  FL_RETURN_IF_ERROR(find.Reset());
  const std::string descriptor = record.descriptor ? json(*record.descriptor).dump() : "";
  if (exists) {
    FL_ASSIGN_OR_RETURN(Statement up,
                        db_->Prepare("UPDATE cases SET name = ?2, family = ?3, created_at = ?4, updated_at = ?5, "
                                     "part_json = ?6, simulation_json = ?7, manufacturing_json = ?8, "
                                     "descriptor_json = ?9 WHERE id = ?1;"));
    FL_RETURN_IF_ERROR(up.Bind(1, id));
    FL_RETURN_IF_ERROR(up.Bind(2, record.name));
    FL_RETURN_IF_ERROR(up.Bind(3, record.family));
    FL_RETURN_IF_ERROR(up.Bind(4, created));
    FL_RETURN_IF_ERROR(up.Bind(5, updated));
    FL_RETURN_IF_ERROR(up.Bind(6, record.part.dump()));
    FL_RETURN_IF_ERROR(up.Bind(7, record.simulation.dump()));
    FL_RETURN_IF_ERROR(up.Bind(8, record.manufacturing.dump()));
    FL_RETURN_IF_ERROR(descriptor.empty() ? up.BindNull(9) : up.Bind(9, descriptor));
    FL_RETURN_IF_ERROR(up.Step().status());
    FL_ASSIGN_OR_RETURN(Statement del, db_->Prepare("DELETE FROM case_concepts WHERE case_id = ?1;"));
    FL_RETURN_IF_ERROR(del.Bind(1, id));
    FL_RETURN_IF_ERROR(del.Step().status());
  } else {
    FL_ASSIGN_OR_RETURN(Statement ins,
                        db_->Prepare("INSERT INTO cases(uid, name, family, created_at, updated_at, part_json, "
                                     "simulation_json, manufacturing_json, descriptor_json) "
                                     "VALUES (?1, ?2, ?3, ?4, ?5, ?6, ?7, ?8, ?9);"));
    FL_RETURN_IF_ERROR(ins.Bind(1, record.uid));
    FL_RETURN_IF_ERROR(ins.Bind(2, record.name));
    FL_RETURN_IF_ERROR(ins.Bind(3, record.family));
    FL_RETURN_IF_ERROR(ins.Bind(4, created));
    FL_RETURN_IF_ERROR(ins.Bind(5, updated));
    FL_RETURN_IF_ERROR(ins.Bind(6, record.part.dump()));
    FL_RETURN_IF_ERROR(ins.Bind(7, record.simulation.dump()));
    FL_RETURN_IF_ERROR(ins.Bind(8, record.manufacturing.dump()));
    FL_RETURN_IF_ERROR(descriptor.empty() ? ins.BindNull(9) : ins.Bind(9, descriptor));
    FL_RETURN_IF_ERROR(ins.Step().status());
    FL_ASSIGN_OR_RETURN(id, db_->LastInsertRowId());
  }
  if (!record.concepts.empty()) {
    FL_ASSIGN_OR_RETURN(Statement con,
                        db_->Prepare("INSERT INTO case_concepts(case_id, facet, concept) VALUES (?1, ?2, ?3);"));
    for (const auto& [facet, concept_name] : record.concepts) {
      FL_RETURN_IF_ERROR(con.Reset());
      FL_RETURN_IF_ERROR(con.Bind(1, id));
      FL_RETURN_IF_ERROR(con.Bind(2, facet));
      FL_RETURN_IF_ERROR(con.Bind(3, concept_name));
      FL_RETURN_IF_ERROR(con.Step().status());
    }
  }
  FL_RETURN_IF_ERROR(BumpChanges());
  return AuditRow(exists ? action + ".replace" : action, record.uid, "family=" + record.family);
}

Status Library::AddCase(const CaseRecord& record, bool replace) {
  FL_RETURN_IF_ERROR(CaseRecord::FromJson(record.ToJson(), Where{.file = record.uid}).status());
  return db_->RunInTransaction([&]() -> Status {
    bool replaced = false;
    return WriteCase(record, replace, "add", /*keep_timestamps=*/false, &replaced);
  });
}

namespace {

Result<CaseRecord> RowToCase(const Statement& stmt) {
  // Columns: id, uid, name, family, created_at, updated_at, part, simulation, manufacturing, descriptor
  CaseRecord r;
  r.uid = stmt.ColumnText(1);
  r.name = stmt.ColumnText(2);
  r.family = stmt.ColumnText(3);
  r.created_at = stmt.ColumnText(4);
  r.updated_at = stmt.ColumnText(5);
  FL_ASSIGN_OR_RETURN(r.part, ParseJsonColumn(stmt.ColumnText(6), "part_json of " + r.uid));
  FL_ASSIGN_OR_RETURN(r.simulation, ParseJsonColumn(stmt.ColumnText(7), "simulation_json of " + r.uid));
  FL_ASSIGN_OR_RETURN(r.manufacturing, ParseJsonColumn(stmt.ColumnText(8), "manufacturing_json of " + r.uid));
  if (!stmt.ColumnIsNull(9)) {
    FL_ASSIGN_OR_RETURN(json d, ParseJsonColumn(stmt.ColumnText(9), "descriptor_json of " + r.uid));
    std::vector<double> values;
    for (const json& v : d) {
      if (!v.is_number()) return Status::Internal("case library: descriptor of " + r.uid + " holds a non-number");
      values.push_back(v.get<double>());
    }
    r.descriptor = std::move(values);
  }
  return r;
}

constexpr const char* kCaseColumns =
    "SELECT id, uid, name, family, created_at, updated_at, part_json, simulation_json, manufacturing_json, "
    "descriptor_json FROM cases ";

}  // namespace

Result<CaseRecord> Library::GetCase(const std::string& uid) {
  FL_ASSIGN_OR_RETURN(Statement stmt, db_->Prepare(std::string(kCaseColumns) + "WHERE uid = ?1;"));
  FL_RETURN_IF_ERROR(stmt.Bind(1, uid));
  FL_ASSIGN_OR_RETURN(bool row, stmt.Step());
  if (!row) {
    return Status::NotFound("case library '" + db_->name() + "' has no case with uid '" + uid +
                            "'. Fix: `formloop kb list " + db_->name() + "` shows the uids");
  }
  const long long id = stmt.ColumnInt(0);
  FL_ASSIGN_OR_RETURN(CaseRecord record, RowToCase(stmt));
  FL_ASSIGN_OR_RETURN(Statement con, db_->Prepare("SELECT facet, concept FROM case_concepts WHERE case_id = ?1;"));
  FL_RETURN_IF_ERROR(con.Bind(1, id));
  while (true) {
    FL_ASSIGN_OR_RETURN(bool more, con.Step());
    if (!more) break;
    record.concepts[con.ColumnText(0)] = con.ColumnText(1);
  }
  return record;
}

Result<std::vector<CaseRecord>> Library::ListCases(const std::string& family) {
  FL_ASSIGN_OR_RETURN(Statement stmt,
                      db_->Prepare(std::string(kCaseColumns) + "WHERE ?1 = '' OR family = ?1 ORDER BY uid;"));
  FL_RETURN_IF_ERROR(stmt.Bind(1, family));
  std::vector<CaseRecord> cases;
  std::map<long long, std::size_t> by_id;
  while (true) {
    FL_ASSIGN_OR_RETURN(bool row, stmt.Step());
    if (!row) break;
    by_id[stmt.ColumnInt(0)] = cases.size();
    FL_ASSIGN_OR_RETURN(CaseRecord record, RowToCase(stmt));
    cases.push_back(std::move(record));
  }
  FL_ASSIGN_OR_RETURN(Statement con, db_->Prepare("SELECT case_id, facet, concept FROM case_concepts;"));
  while (true) {
    FL_ASSIGN_OR_RETURN(bool more, con.Step());
    if (!more) break;
    auto it = by_id.find(con.ColumnInt(0));
    if (it != by_id.end()) cases[it->second].concepts[con.ColumnText(1)] = con.ColumnText(2);
  }
  return cases;
}

namespace {

Status InsertPartRecord(Database* db, const PartRecordRow& row) {
  FL_ASSIGN_OR_RETURN(Statement find, db->Prepare("SELECT id FROM cases WHERE uid = ?1;"));
  FL_RETURN_IF_ERROR(find.Bind(1, row.case_uid));
  FL_ASSIGN_OR_RETURN(const bool exists, find.Step());
  if (!exists) {
    return Status::NotFound("case library '" + db->name() + "' has no case with uid '" + row.case_uid +
                            "' to hold a part record");
  }
  const long long id = find.ColumnInt(0);
  FL_RETURN_IF_ERROR(find.Reset());
  FL_ASSIGN_OR_RETURN(Statement del, db->Prepare("DELETE FROM case_part_records WHERE case_id = ?1 AND machine = ?2 "
                                                 "AND tool = ?3 AND material = ?4;"));
  FL_ASSIGN_OR_RETURN(Statement ins, db->Prepare("INSERT INTO case_part_records(case_id, machine, tool, material, "
                                                 "points, record_json) VALUES (?1, ?2, ?3, ?4, ?5, ?6);"));
  for (Statement* s : {&del, &ins}) {
    FL_RETURN_IF_ERROR(s->Bind(1, id));
    FL_RETURN_IF_ERROR(s->Bind(2, row.machine));
    FL_RETURN_IF_ERROR(s->Bind(3, row.tool));
    FL_RETURN_IF_ERROR(s->Bind(4, row.material));
  }
  FL_RETURN_IF_ERROR(ins.Bind(5, row.record.value("points", 0LL)));
  FL_RETURN_IF_ERROR(ins.Bind(6, row.record.dump()));
  FL_RETURN_IF_ERROR(del.Step().status());
  return ins.Step().status();
}

}  // namespace

json PartRecordRow::ToJson() const {
  return {{"type", "part_record"}, {"case", case_uid},     {"machine", machine},
          {"tool", tool},          {"material", material}, {"record", record}};
}

Result<PartRecordRow> PartRecordRow::FromJson(const json& j, const Where& source) {
  PartRecordRow row;
  for (const char* key : {"case", "machine", "tool", "material"}) {
    if (!j.contains(key) || !j[key].is_string() || j[key].get<std::string>().empty()) {
      Where at = source;
      at.field = key;
      return Status::BadInput(at, "missing or not a non-empty string");
    }
  }
  if (!j.contains("record") || !j["record"].is_object() || !j["record"].contains("points") ||
      !j["record"]["points"].is_number_integer() || j["record"]["points"].get<long long>() < 1) {
    Where at = source;
    at.field = "record";
    return Status::BadInput(at, "missing, not an object, or without a positive \"points\"");
  }
  row.case_uid = j["case"].get<std::string>();
  row.machine = j["machine"].get<std::string>();
  row.tool = j["tool"].get<std::string>();
  row.material = j["material"].get<std::string>();
  row.record = j["record"];
  return row;
}

Status Library::SetPartRecord(const PartRecordRow& row) {
  FL_RETURN_IF_ERROR(
      PartRecordRow::FromJson(row.ToJson(), Where{.file = "part record of case " + row.case_uid}).status());
  return db_->RunInTransaction([&]() -> Status {
    FL_RETURN_IF_ERROR(InsertPartRecord(db_.get(), row));
    return AuditRow("part_record", row.case_uid,
                    row.machine + " / " + row.tool + " / " + row.material + ": " +
                        std::to_string(row.record.value("points", 0LL)) + " points");
  });
}

Result<std::vector<PartRecordRow>> Library::PartRecords(const std::string& machine, const std::string& tool,
                                                        const std::string& material) {
  FL_ASSIGN_OR_RETURN(Statement s,
                      db_->Prepare("SELECT c.uid, c.updated_at, r.record_json FROM case_part_records r JOIN cases c "
                                   "ON c.id = r.case_id WHERE r.machine = ?1 AND r.tool = ?2 AND r.material = ?3 "
                                   "ORDER BY c.updated_at DESC, c.uid;"));
  FL_RETURN_IF_ERROR(s.Bind(1, machine));
  FL_RETURN_IF_ERROR(s.Bind(2, tool));
  FL_RETURN_IF_ERROR(s.Bind(3, material));
  std::vector<PartRecordRow> out;
  while (true) {
    FL_ASSIGN_OR_RETURN(bool more, s.Step());
    if (!more) break;
    PartRecordRow row;
    row.case_uid = s.ColumnText(0);
    row.case_updated_at = s.ColumnText(1);
    row.machine = machine;
    row.tool = tool;
    row.material = material;
    row.record = json::parse(s.ColumnText(2), nullptr, /*allow_exceptions=*/false);
    if (row.record.is_discarded()) {
      return Status::Failed("case library '" + db_->name() + "': the part record of case " + row.case_uid +
                            " is not JSON. Fix: formloop kb check, then run the part again");
    }
    out.push_back(std::move(row));
  }
  return out;
}

Result<std::vector<PartRecordRow>> Library::AllPartRecords() {
  FL_ASSIGN_OR_RETURN(Statement s, db_->Prepare("SELECT c.uid, r.machine, r.tool, r.material, r.record_json FROM "
                                                "case_part_records r JOIN cases c ON c.id = r.case_id ORDER BY "
                                                "c.uid, r.machine, r.tool, r.material;"));
  std::vector<PartRecordRow> out;
  while (true) {
    FL_ASSIGN_OR_RETURN(bool row, s.Step());
    if (!row) break;
    PartRecordRow r{s.ColumnText(0),
                    s.ColumnText(1),
                    s.ColumnText(2),
                    s.ColumnText(3),
                    json::parse(s.ColumnText(4), nullptr, /*allow_exceptions=*/false),
                    ""};
    if (r.record.is_discarded()) {
      return Status::Failed("case library '" + db_->name() + "': the part record of case " + r.case_uid +
                            " is not JSON");
    }
    out.push_back(std::move(r));
  }
  return out;
}

Status Library::RemoveCase(const std::string& uid) {
  return db_->RunInTransaction([&]() -> Status {
    FL_ASSIGN_OR_RETURN(Statement del, db_->Prepare("DELETE FROM cases WHERE uid = ?1;"));
    FL_RETURN_IF_ERROR(del.Bind(1, uid));
    FL_RETURN_IF_ERROR(del.Step().status());
    if (db_->Changes() == 0) {
      return Status::NotFound("case library '" + db_->name() + "' has no case with uid '" + uid + "'");
    }
    FL_RETURN_IF_ERROR(BumpChanges());
    return AuditRow("remove", uid, "");
  });
}

Result<GhsomStatus> Library::Ghsom() {
  GhsomStatus status;
  FL_ASSIGN_OR_RETURN(status.current_changes, ChangeCounter());
  FL_ASSIGN_OR_RETURN(Statement stmt, db_->Prepare("SELECT id, created_at, case_count, change_counter FROM ghsom "
                                                   "ORDER BY id DESC LIMIT 1;"));
  FL_ASSIGN_OR_RETURN(bool row, stmt.Step());
  if (!row) return status;
  status.present = true;
  status.id = stmt.ColumnInt(0);
  status.created_at = stmt.ColumnText(1);
  status.case_count = stmt.ColumnInt(2);
  status.trained_at_changes = stmt.ColumnInt(3);
  status.stale = status.trained_at_changes != status.current_changes;
  return status;
}

Result<LibraryStats> Library::Stats() {
  LibraryStats stats;
  FL_ASSIGN_OR_RETURN(long long version, db_->SchemaVersion());
  stats.schema_version = static_cast<int>(version);
  FL_ASSIGN_OR_RETURN(stats.cases, db_->QueryInt("SELECT COUNT(*) FROM cases;"));
  FL_ASSIGN_OR_RETURN(stats.cases_with_descriptor,
                      db_->QueryInt("SELECT COUNT(*) FROM cases WHERE descriptor_json IS NOT NULL;"));
  {
    FL_ASSIGN_OR_RETURN(Statement s, db_->Prepare("SELECT family, COUNT(*) FROM cases GROUP BY family;"));
    while (true) {
      FL_ASSIGN_OR_RETURN(bool row, s.Step());
      if (!row) break;
      stats.per_family[s.ColumnText(0)] = s.ColumnInt(1);
    }
  }
  {
    FL_ASSIGN_OR_RETURN(Statement s,
                        db_->Prepare("SELECT facet, concept, COUNT(*) FROM case_concepts GROUP BY facet, concept;"));
    while (true) {
      FL_ASSIGN_OR_RETURN(bool row, s.Step());
      if (!row) break;
      stats.per_facet_concept[s.ColumnText(0)][s.ColumnText(1)] = s.ColumnInt(2);
    }
  }
  FL_ASSIGN_OR_RETURN(long long rv, db_->QueryInt("SELECT coalesce(MAX(version), 0) FROM rules WHERE active = 1;"));
  stats.rules_version = static_cast<int>(rv);
  FL_ASSIGN_OR_RETURN(stats.case_changes, ChangeCounter());
  FL_ASSIGN_OR_RETURN(stats.ghsom, Ghsom());
  return stats;
}

Result<CheckReport> Library::Check() {
  CheckReport report;
  {
    FL_ASSIGN_OR_RETURN(std::vector<std::string> lines, db_->IntegrityProblems());
    report.integrity = lines.empty() ? "ok" : "";
    for (std::size_t i = 0; i < lines.size(); ++i) report.integrity += (i > 0 ? "; " : "") + lines[i];
    if (report.integrity != "ok") report.problems.push_back("integrity_check: " + report.integrity);
  }
  FL_ASSIGN_OR_RETURN(report.foreign_key_violations, db_->ForeignKeyViolations());
  if (!report.foreign_key_violations.empty()) {
    report.problems.push_back(std::to_string(report.foreign_key_violations.size()) +
                              " foreign-key violation(s), first: " + report.foreign_key_violations.front());
  }
  FL_ASSIGN_OR_RETURN(report.orphan_concepts,
                      db_->QueryInt("SELECT COUNT(*) FROM case_concepts WHERE case_id NOT IN (SELECT id FROM cases);"));
  if (report.orphan_concepts > 0) {
    report.problems.push_back(std::to_string(report.orphan_concepts) + " concept row(s) belong to no case");
  }
  {
    FL_ASSIGN_OR_RETURN(Statement s, db_->Prepare("SELECT uid FROM cases WHERE descriptor_json IS NULL ORDER BY uid;"));
    while (true) {
      FL_ASSIGN_OR_RETURN(bool row, s.Step());
      if (!row) break;
      report.cases_missing_descriptor.push_back(s.ColumnText(0));
    }
    if (!report.cases_missing_descriptor.empty()) {
      report.warnings.push_back(std::to_string(report.cases_missing_descriptor.size()) +
                                " case(s) have no geometric descriptor; the GHSOM cannot place them");
    }
    FL_ASSIGN_OR_RETURN(long long lengths,
                        db_->QueryInt("SELECT COUNT(DISTINCT " + db_->JsonArrayLength("descriptor_json") +
                                      ") FROM cases WHERE descriptor_json IS NOT NULL;"));
    if (lengths > 1) report.problems.push_back("descriptors have " + std::to_string(lengths) + " different lengths");
  }
  {
    FL_ASSIGN_OR_RETURN(RuleSet rules, GetRules());
    report.rule_problems = RuleSetProblems(rules.rules);
    for (const std::string& p : report.rule_problems) report.problems.push_back("rule base: " + p);
    FL_ASSIGN_OR_RETURN(long long versions,
                        db_->QueryInt("SELECT COUNT(DISTINCT version) FROM rules WHERE active = 1;"));
    if (versions > 1) report.problems.push_back("rule base: more than one version is active");
  }
  FL_ASSIGN_OR_RETURN(report.ghsom, Ghsom());
  if (!report.ghsom.present) {
    report.warnings.push_back("no GHSOM trained yet (`formloop kb train`)");
  } else if (report.ghsom.stale) {
    // A stale map is maintenance, not damage: the library is consistent and retrieval still works on
    // the cases the map holds. It is reported (warnings, ghsom.stale) but does not make check unclean,
    // so a `kb add` killed between its commit and its GHSOM update leaves a clean library.
    report.warnings.push_back("GHSOM " + std::to_string(report.ghsom.id) + " is stale: trained at change " +
                              std::to_string(report.ghsom.trained_at_changes) + ", library now at change " +
                              std::to_string(report.ghsom.current_changes) + ". Fix: retrain (`formloop kb train`)");
  }
  return report;
}

// ---------------------------------------------------------------------------------------------- rules API

namespace {
// A rule from a row (version, name, condition_json, choice_json, ...).
Result<Rule> RuleFromRow(const Statement& s, bool active) {
  Rule r;
  r.version = static_cast<int>(s.ColumnInt(0));
  r.name = s.ColumnText(1);
  FL_ASSIGN_OR_RETURN(r.condition, ParseJsonColumn(s.ColumnText(2), "rules.condition_json"));
  FL_ASSIGN_OR_RETURN(r.choice, ParseJsonColumn(s.ColumnText(3), "rules.choice_json"));
  r.active = active;
  return r;
}

}  // namespace

Result<RuleSet> Library::GetRules() {
  RuleSet set;
  FL_ASSIGN_OR_RETURN(Statement s, db_->Prepare("SELECT version, name, condition_json, choice_json FROM rules "
                                                "WHERE active = 1 ORDER BY name;"));
  while (true) {
    FL_ASSIGN_OR_RETURN(bool row, s.Step());
    if (!row) break;
    FL_ASSIGN_OR_RETURN(Rule r, RuleFromRow(s, true));
    set.version = std::max(set.version, r.version);
    set.rules.push_back(std::move(r));
  }
  return set;
}

Result<int> Library::SetRules(const json& input, const std::string& source) {
  FL_ASSIGN_OR_RETURN(std::vector<Rule> rules, ParseRules(input, source));
  const auto problems = RuleSetProblems(rules);
  if (!problems.empty()) {
    std::string all;
    for (const auto& p : problems) all += (all.empty() ? "" : "; ") + p;
    return Status::BadInput(Where{.file = source}, "rule set refused: " + all, "fix the rules; nothing was changed");
  }
  int version = 0;
  const Status written = db_->RunInTransaction([&]() -> Status {
    FL_ASSIGN_OR_RETURN(long long latest, db_->QueryInt("SELECT coalesce(MAX(version), 0) FROM rules;"));
    version = static_cast<int>(latest) + 1;
    FL_RETURN_IF_ERROR(db_->Execute("UPDATE rules SET active = 0 WHERE active = 1;"));
    FL_ASSIGN_OR_RETURN(Statement ins, db_->Prepare("INSERT INTO rules(version, name, condition_json, choice_json, "
                                                    "active) VALUES (?1, ?2, ?3, ?4, 1);"));
    for (const Rule& r : rules) {
      FL_RETURN_IF_ERROR(ins.Reset());
      FL_RETURN_IF_ERROR(ins.Bind(1, static_cast<long long>(version)));
      FL_RETURN_IF_ERROR(ins.Bind(2, r.name));
      FL_RETURN_IF_ERROR(ins.Bind(3, r.condition.dump()));
      FL_RETURN_IF_ERROR(ins.Bind(4, r.choice.dump()));
      FL_RETURN_IF_ERROR(ins.Step().status());
    }
    return AuditRow("rules.set", "", "version=" + std::to_string(version) + " from " + source);
  });
  FL_RETURN_IF_ERROR(written);
  return version;
}

// ---------------------------------------------------------------------------------------------- taxonomies

Result<std::vector<TaxonomyNode>> Library::GetTaxonomy(const std::string& taxonomy) {
  FL_ASSIGN_OR_RETURN(Statement s,
                      db_->Prepare("SELECT node, parent FROM taxonomy_nodes WHERE taxonomy = ?1 ORDER BY node;"));
  FL_RETURN_IF_ERROR(s.Bind(1, taxonomy));
  std::vector<TaxonomyNode> nodes;
  while (true) {
    FL_ASSIGN_OR_RETURN(bool row, s.Step());
    if (!row) break;
    TaxonomyNode n{taxonomy, s.ColumnText(0), std::nullopt};
    if (!s.ColumnIsNull(1)) n.parent = s.ColumnText(1);
    nodes.push_back(std::move(n));
  }
  return nodes;
}

namespace {

Status InsertTaxonomyNode(Database* db, const TaxonomyNode& n) {
  FL_ASSIGN_OR_RETURN(Statement ins,
                      db->Prepare("INSERT INTO taxonomy_nodes(taxonomy, node, parent) VALUES (?1, ?2, ?3);"));
  FL_RETURN_IF_ERROR(ins.Bind(1, n.taxonomy));
  FL_RETURN_IF_ERROR(ins.Bind(2, n.node));
  FL_RETURN_IF_ERROR(n.parent ? ins.Bind(3, *n.parent) : ins.BindNull(3));
  return ins.Step().status();
}

Status DeleteTaxonomy(Database* db, const std::string& taxonomy) {
  FL_ASSIGN_OR_RETURN(Statement del, db->Prepare("DELETE FROM taxonomy_nodes WHERE taxonomy = ?1;"));
  FL_RETURN_IF_ERROR(del.Bind(1, taxonomy));
  return del.Step().status();
}

}  // namespace

Status Library::SetTaxonomy(const std::string& taxonomy, const std::vector<TaxonomyNode>& nodes) {
  return db_->RunInTransaction([&]() -> Status {
    // Nodes may come in any order; the parent references are checked at COMMIT.
    FL_RETURN_IF_ERROR(db_->DeferForeignKeys());
    FL_RETURN_IF_ERROR(DeleteTaxonomy(db_.get(), taxonomy));
    for (TaxonomyNode n : nodes) {
      n.taxonomy = taxonomy;
      FL_RETURN_IF_ERROR(InsertTaxonomyNode(db_.get(), n));
    }
    return AuditRow("taxonomy.set", "", taxonomy + ": " + std::to_string(nodes.size()) + " nodes");
  });
}

// ---------------------------------------------------------------------------------------------- GHSOM

Result<long long> Library::StoreGhsom(GhsomRecord given) {
  long long id = 0;
  const Status written = db_->RunInTransaction([&]() -> Status {
    GhsomRecord record = given;  // a rerun starts from what the caller gave
    if (record.change_counter < 0) {
      FL_ASSIGN_OR_RETURN(record.change_counter, ChangeCounter());
    }
    if (record.case_count < 0) {
      FL_ASSIGN_OR_RETURN(record.case_count, db_->QueryInt("SELECT COUNT(*) FROM cases;"));
    }
    record.created_at = UtcNow();
    FL_ASSIGN_OR_RETURN(Statement ins,
                        db_->Prepare("INSERT INTO ghsom(created_at, seed, parameters_json, quality_json, "
                                     "map_json, case_count, change_counter) VALUES (?1, ?2, ?3, ?4, ?5, ?6, ?7);"));
    FL_RETURN_IF_ERROR(ins.Bind(1, record.created_at));
    FL_RETURN_IF_ERROR(ins.Bind(2, record.seed));
    FL_RETURN_IF_ERROR(ins.Bind(3, record.parameters.dump()));
    FL_RETURN_IF_ERROR(ins.Bind(4, record.quality.dump()));
    FL_RETURN_IF_ERROR(ins.Bind(5, record.map.dump()));
    FL_RETURN_IF_ERROR(ins.Bind(6, record.case_count));
    FL_RETURN_IF_ERROR(ins.Bind(7, record.change_counter));
    FL_RETURN_IF_ERROR(ins.Step().status());
    FL_ASSIGN_OR_RETURN(id, db_->LastInsertRowId());
    // Only the newest map is ever used: older rows would pile up with every incremental `kb add` (each
    // holds the whole map), so they go in the same transaction. The audit trail keeps the history.
    FL_ASSIGN_OR_RETURN(Statement prune, db_->Prepare("DELETE FROM ghsom WHERE id <> ?1;"));
    FL_RETURN_IF_ERROR(prune.Bind(1, id));
    FL_RETURN_IF_ERROR(prune.Step().status());
    return AuditRow("ghsom.store", "",
                    "id=" + std::to_string(id) + " cases=" + std::to_string(record.case_count) +
                        " seed=" + std::to_string(record.seed));
  });
  FL_RETURN_IF_ERROR(written);
  return id;
}

Result<std::optional<GhsomRecord>> Library::LoadGhsom() {
  FL_ASSIGN_OR_RETURN(Statement s, db_->Prepare("SELECT id, created_at, seed, parameters_json, quality_json, map_json, "
                                                "case_count, change_counter FROM ghsom ORDER BY id DESC LIMIT 1;"));
  FL_ASSIGN_OR_RETURN(bool row, s.Step());
  if (!row) return std::optional<GhsomRecord>();
  GhsomRecord r;
  r.id = s.ColumnInt(0);
  r.created_at = s.ColumnText(1);
  r.seed = s.ColumnInt(2);
  FL_ASSIGN_OR_RETURN(r.parameters, ParseJsonColumn(s.ColumnText(3), "ghsom.parameters_json"));
  FL_ASSIGN_OR_RETURN(r.quality, ParseJsonColumn(s.ColumnText(4), "ghsom.quality_json"));
  FL_ASSIGN_OR_RETURN(r.map, ParseJsonColumn(s.ColumnText(5), "ghsom.map_json"));
  r.case_count = s.ColumnInt(6);
  r.change_counter = s.ColumnInt(7);
  return std::optional<GhsomRecord>(std::move(r));
}

// ---------------------------------------------------------------------------------------------- audit

Result<std::vector<AuditEntry>> Library::Audit(const std::string& uid, int limit) {
  FL_ASSIGN_OR_RETURN(Statement s, db_->Prepare("SELECT id, at, action, coalesce(case_uid, ''), detail FROM audit "
                                                "WHERE ?1 = '' OR case_uid = ?1 ORDER BY id DESC LIMIT ?2;"));
  FL_RETURN_IF_ERROR(s.Bind(1, uid));
  FL_RETURN_IF_ERROR(s.Bind(2, static_cast<long long>(limit)));
  std::vector<AuditEntry> entries;
  while (true) {
    FL_ASSIGN_OR_RETURN(bool row, s.Step());
    if (!row) break;
    entries.push_back({s.ColumnInt(0), s.ColumnText(1), s.ColumnText(2), s.ColumnText(3), s.ColumnText(4)});
  }
  return entries;
}

// ---------------------------------------------------------------------------------------------- export / import

Result<std::string> Library::ExportText() {
  // One read snapshot so the export is consistent while other processes write.
  std::string out;
  FL_RETURN_IF_ERROR(db_->RunInReadSnapshot([&]() -> Status { return ExportSnapshot(&out); }));
  return out;
}

Status Library::ExportSnapshot(std::string* text) {
  std::string& out = *text;
  FL_ASSIGN_OR_RETURN(std::vector<CaseRecord> cases, ListCases());
  const json header = {{"format", kExportFormatName},
                       {"format_version", kExportFormatVersion},
                       {"schema_version", LatestSchemaVersion()},
                       {"cases", cases.size()}};
  out += header.dump() + "\n";
  for (const CaseRecord& c : cases) out += json{{"type", "case"}, {"case", c.ToJson()}}.dump() + "\n";
  {
    FL_ASSIGN_OR_RETURN(const std::vector<PartRecordRow> records, AllPartRecords());
    for (const PartRecordRow& r : records) out += r.ToJson().dump() + "\n";
  }
  {
    FL_ASSIGN_OR_RETURN(Statement s, db_->Prepare("SELECT version, name, condition_json, choice_json, active FROM "
                                                  "rules ORDER BY version, name;"));
    while (true) {
      FL_ASSIGN_OR_RETURN(bool row, s.Step());
      if (!row) break;
      FL_ASSIGN_OR_RETURN(Rule r, RuleFromRow(s, s.ColumnInt(4) == 1));
      json line = r.ToJson();
      line["type"] = "rule";
      out += line.dump() + "\n";
    }
  }
  {
    FL_ASSIGN_OR_RETURN(Statement s,
                        db_->Prepare("SELECT taxonomy, node, parent FROM taxonomy_nodes ORDER BY taxonomy, node;"));
    while (true) {
      FL_ASSIGN_OR_RETURN(bool row, s.Step());
      if (!row) break;
      json line = {{"type", "taxonomy"}, {"taxonomy", s.ColumnText(0)}, {"node", s.ColumnText(1)}};
      line["parent"] = s.ColumnIsNull(2) ? json(nullptr) : json(s.ColumnText(2));
      out += line.dump() + "\n";
    }
  }
  return Status::Ok();
}

Status Library::ExportToFile(const std::filesystem::path& path) {
  FL_ASSIGN_OR_RETURN(std::string text, ExportText());
  return WriteFileAtomic(path, text);
}

Result<ImportReport> Library::ImportText(const std::string& text, const std::string& source,
                                         const ImportOptions& options) {
  // Parse and validate everything before the transaction starts.
  std::vector<std::pair<long, CaseRecord>> cases;
  std::vector<Rule> rules;
  std::vector<TaxonomyNode> nodes;
  std::vector<std::pair<long, PartRecordRow>> part_records;
  std::istringstream in(text);
  std::string line;
  long line_no = 0;
  bool have_header = false;
  while (std::getline(in, line)) {
    ++line_no;
    if (line.empty()) continue;
    const Where where{.file = source, .line = line_no};
    json j = json::parse(line, nullptr, /*allow_exceptions=*/false);
    if (j.is_discarded()) {
      // Say where the text stops making sense: a line cut short (a truncated copy) ends inside a value.
      std::string detail;
      try {
        const json unused = json::parse(line);
      } catch (const json::parse_error& e) {
        detail = " (at byte " + std::to_string(e.byte) + " of " + std::to_string(line.size()) + ")";
      }
      return Status::BadInput(where, "is not valid JSON" + detail,
                              "every line of a `formloop kb export` file is one JSON object; a line cut short "
                              "means the file was truncated: export the library again, nothing was imported");
    }
    if (!j.is_object()) {
      return Status::BadInput(where, "is JSON but not an object",
                              "every line of a `formloop kb export` file is one JSON object; nothing was imported");
    }
    if (!have_header) {
      if (!j.contains("format") || j["format"] != kExportFormatName) {
        return Status::BadInput(where, std::string("the first line is not a ") + kExportFormatName + " header",
                                "give a file written by `formloop kb export`");
      }
      if (!j.contains("format_version") || !j["format_version"].is_number_integer()) {
        return Status::BadInput(Where{.file = source, .line = line_no, .field = "format_version"}, "missing");
      }
      const int format_version = j["format_version"].get<int>();
      if (format_version > kExportFormatVersion) {
        return Status::BadInput(where,
                                "format version " + std::to_string(format_version) +
                                    " is newer than this formloop reads (" + std::to_string(kExportFormatVersion) + ")",
                                "upgrade formloop; nothing was imported");
      }
      const int schema_version = j.value("schema_version", 0);
      if (schema_version > LatestSchemaVersion()) {
        return Status::BadInput(where,
                                "written by a library at schema version " + std::to_string(schema_version) +
                                    ", newer than this formloop's " + std::to_string(LatestSchemaVersion()),
                                "upgrade formloop; nothing was imported");
      }
      have_header = true;
      continue;
    }
    const std::string type = j.value("type", "");
    if (type == "case") {
      if (!j.contains("case"))
        return Status::BadInput(Where{.file = source, .line = line_no, .field = "case"}, "missing");
      FL_ASSIGN_OR_RETURN(CaseRecord record, CaseRecord::FromJson(j["case"], where));
      if (options.check_case) {
        FL_RETURN_IF_ERROR(
            options.check_case(record).WithContext(source + ":" + std::to_string(line_no) + " (nothing was imported)"));
      }
      cases.emplace_back(line_no, std::move(record));
    } else if (type == "rule") {
      Rule r;
      if (!j.contains("version") || !j["version"].is_number_integer() || j["version"].get<int>() < 1 ||
          !j.contains("name") || !j["name"].is_string() || !j.contains("condition") || !j["condition"].is_object() ||
          !j.contains("choice") || !j["choice"].is_object() || !j.contains("active") || !j["active"].is_boolean()) {
        return Status::BadInput(where, "a rule line needs version (>= 1), name, condition {}, choice {}, active");
      }
      r.version = j["version"].get<int>();
      r.name = j["name"].get<std::string>();
      r.condition = j["condition"];
      r.choice = j["choice"];
      r.active = j["active"].get<bool>();
      rules.push_back(std::move(r));
    } else if (type == "taxonomy") {
      if (!j.contains("taxonomy") || !j["taxonomy"].is_string() || !j.contains("node") || !j["node"].is_string() ||
          (j.contains("parent") && !j["parent"].is_null() && !j["parent"].is_string())) {
        return Status::BadInput(where, "a taxonomy line needs taxonomy, node (strings) and parent (string or null)");
      }
      TaxonomyNode n{j["taxonomy"].get<std::string>(), j["node"].get<std::string>(), std::nullopt};
      if (j.contains("parent") && j["parent"].is_string()) n.parent = j["parent"].get<std::string>();
      nodes.push_back(std::move(n));
    } else if (type == "part_record") {
      FL_ASSIGN_OR_RETURN(PartRecordRow row, PartRecordRow::FromJson(j, where));
      part_records.emplace_back(line_no, std::move(row));
    } else {
      return Status::BadInput(Where{.file = source, .line = line_no, .field = "type"},
                              "unknown line type '" + type + "'", "expected case, part_record, rule or taxonomy");
    }
  }
  if (!have_header) return Status::BadInput(Where{.file = source}, "is empty", "give a `formloop kb export` file");
  if (!rules.empty()) {
    std::vector<Rule> active;
    for (const Rule& r : rules) {
      if (r.active) active.push_back(r);
    }
    const auto problems = RuleSetProblems(active);
    if (!problems.empty()) {
      return Status::BadInput(Where{.file = source}, "the active rules are not sane: " + problems.front(),
                              "nothing was imported");
    }
  }

  ImportReport report;
  const Status written = db_->RunInTransaction([&]() -> Status {
    report = ImportReport{};
    FL_RETURN_IF_ERROR(db_->DeferForeignKeys());
    for (const auto& [case_line, record] : cases) {
      bool replaced = false;
      FL_RETURN_IF_ERROR(WriteCase(record, options.replace, "import", /*keep_timestamps=*/true, &replaced)
                             .WithContext(source + ":" + std::to_string(case_line)));
      (replaced ? report.cases_replaced : report.cases_added) += 1;
      if (options.on_case) options.on_case(report.cases_added + report.cases_replaced);
    }
    for (const auto& [record_line, row] : part_records) {
      FL_RETURN_IF_ERROR(InsertPartRecord(db_.get(), row).WithContext(source + ":" + std::to_string(record_line)));
    }
    report.part_records = part_records.size();
    if (!rules.empty()) {
      FL_RETURN_IF_ERROR(db_->Execute("DELETE FROM rules;"));
      FL_ASSIGN_OR_RETURN(Statement ins, db_->Prepare("INSERT INTO rules(version, name, condition_json, choice_json, "
                                                      "active) VALUES (?1, ?2, ?3, ?4, ?5);"));
      for (const Rule& r : rules) {
        FL_RETURN_IF_ERROR(ins.Reset());
        FL_RETURN_IF_ERROR(ins.Bind(1, static_cast<long long>(r.version)));
        FL_RETURN_IF_ERROR(ins.Bind(2, r.name));
        FL_RETURN_IF_ERROR(ins.Bind(3, r.condition.dump()));
        FL_RETURN_IF_ERROR(ins.Bind(4, r.choice.dump()));
        FL_RETURN_IF_ERROR(ins.Bind(5, static_cast<long long>(r.active ? 1 : 0)));
        FL_RETURN_IF_ERROR(ins.Step().status().WithContext(source + ": rule " + r.name));
      }
      report.rules = rules.size();
    }
    std::set<std::string> taxonomies;
    for (const TaxonomyNode& n : nodes) taxonomies.insert(n.taxonomy);
    for (const std::string& t : taxonomies) FL_RETURN_IF_ERROR(DeleteTaxonomy(db_.get(), t));
    for (const TaxonomyNode& n : nodes) {
      FL_RETURN_IF_ERROR(InsertTaxonomyNode(db_.get(), n).WithContext(source + ": taxonomy " + n.taxonomy));
    }
    report.taxonomy_nodes = nodes.size();
    return AuditRow("import", "", source + ": " + report.ToJson().dump());
  });
  FL_RETURN_IF_ERROR(written.WithContext("import of " + source));
  return report;
}

Result<ImportReport> Library::ImportFile(const std::filesystem::path& path, const ImportOptions& options) {
  FL_ASSIGN_OR_RETURN(std::string text, ReadFile(path));
  return ImportText(text, path.string(), options);
}

}  // namespace formloop::kb
