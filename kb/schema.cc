#include "kb/schema.h"

#include <algorithm>

namespace formloop::kb {

const std::vector<Migration>& SchemaMigrations() {
  static const std::vector<Migration> kMigrations = {
      {1, "initial case library: machines, tools, materials, cases, loops, learned error models", R"sql(
CREATE TABLE library_info (
  key   TEXT PRIMARY KEY,
  value TEXT NOT NULL
);
CREATE TABLE machines (
  id          INTEGER PRIMARY KEY,
  name        TEXT NOT NULL UNIQUE,
  controller  TEXT NOT NULL CHECK (controller IN ('linuxcnc', 'fanuc', 'heidenhain', 'sinumerik')),
  limits_json TEXT NOT NULL DEFAULT '{}'          -- travel and feed limits, mm and mm/min
);
CREATE TABLE tools (
  id          INTEGER PRIMARY KEY,
  name        TEXT NOT NULL UNIQUE,
  type        TEXT NOT NULL CHECK (type IN ('ball_end', 'flat_end', 'bull_nose')),
  radius_mm   REAL NOT NULL CHECK (radius_mm > 0),
  flutes      INTEGER CHECK (flutes > 0),
  stickout_mm REAL CHECK (stickout_mm > 0)
);
CREATE TABLE materials (
  id            INTEGER PRIMARY KEY,
  name          TEXT NOT NULL UNIQUE,
  taxonomy_path TEXT NOT NULL                     -- e.g. 'metal/steel/tool steel/H13'
);
CREATE TABLE cases (
  id              INTEGER PRIMARY KEY,
  name            TEXT NOT NULL UNIQUE,
  created_at      TEXT NOT NULL,
  surface_family  TEXT NOT NULL,
  features_json   TEXT NOT NULL,                  -- part feature description (meta-model part 1)
  material_id     INTEGER REFERENCES materials(id) ON DELETE RESTRICT,
  tolerance_mm    REAL NOT NULL CHECK (tolerance_mm > 0),
  machine_id      INTEGER REFERENCES machines(id) ON DELETE RESTRICT,
  tool_id         INTEGER REFERENCES tools(id) ON DELETE RESTRICT,
  plan_json       TEXT NOT NULL DEFAULT '{}',     -- manufacturing knowledge (meta-model part 3)
  simulation_json TEXT NOT NULL DEFAULT '{}'      -- simulation knowledge (meta-model part 2)
);
CREATE TABLE case_loops (
  case_id                INTEGER NOT NULL REFERENCES cases(id) ON DELETE CASCADE,
  loop_index             INTEGER NOT NULL CHECK (loop_index >= 0),
  form_error_mm          REAL NOT NULL,
  systematic_peak_mm     REAL,
  random_sigma_mm        REAL,
  compensated            INTEGER NOT NULL CHECK (compensated IN (0, 1)),
  PRIMARY KEY (case_id, loop_index)
);
CREATE TABLE error_models (
  id          INTEGER PRIMARY KEY,
  machine_id  INTEGER REFERENCES machines(id) ON DELETE CASCADE,
  tool_id     INTEGER REFERENCES tools(id) ON DELETE CASCADE,
  material_id INTEGER REFERENCES materials(id) ON DELETE CASCADE,
  model_json  TEXT NOT NULL,                      -- effects, parameters, standard errors
  provenance  TEXT NOT NULL                       -- which case and data it was learned from
);
CREATE INDEX cases_by_family ON cases(surface_family);
INSERT INTO library_info(key, value) VALUES ('format', 'formloop case library');
)sql"},
      {2,
       "case library v2: three-part cases with uid and descriptor, concepts, taxonomies, versioned rules, GHSOM, "
       "audit",
       R"sql(
-- v1 cases are rebuilt into the three-part meta-model (spec/case-library.md §1). ALTER TABLE RENAME
-- re-points case_loops' foreign key at cases_v1; case_loops is then rebuilt to point at the new table.
ALTER TABLE cases RENAME TO cases_v1;
CREATE TABLE cases (
  id                  INTEGER PRIMARY KEY,
  uid                 TEXT NOT NULL UNIQUE CHECK (length(uid) > 0),
  name                TEXT NOT NULL CHECK (length(name) > 0),
  family              TEXT NOT NULL CHECK (length(family) > 0),
  created_at          TEXT NOT NULL,                 -- ISO 8601 UTC
  updated_at          TEXT NOT NULL,
  part_json           TEXT NOT NULL CHECK (json_valid(part_json) AND json_type(part_json) = 'object'),
  simulation_json     TEXT NOT NULL CHECK (json_valid(simulation_json) AND json_type(simulation_json) = 'object'),
  manufacturing_json  TEXT NOT NULL
                      CHECK (json_valid(manufacturing_json) AND json_type(manufacturing_json) = 'object'),
  descriptor_json     TEXT CHECK (descriptor_json IS NULL OR
                                  (json_valid(descriptor_json) AND json_type(descriptor_json) = 'array'))
);
INSERT INTO cases(id, uid, name, family, created_at, updated_at, part_json, simulation_json, manufacturing_json,
                  descriptor_json)
SELECT c.id,
       'v1-' || c.id,
       c.name,
       c.surface_family,
       c.created_at,
       c.created_at,
       -- json_patch drops keys whose value is NULL (no material, machine or tool recorded).
       json_patch(CASE WHEN json_valid(c.features_json) AND json_type(c.features_json) = 'object'
                       THEN c.features_json ELSE '{}' END,
                  json_object('tolerance_mm', c.tolerance_mm,
                              'material', (SELECT m.name FROM materials m WHERE m.id = c.material_id))),
       CASE WHEN json_valid(c.simulation_json) AND json_type(c.simulation_json) = 'object'
            THEN c.simulation_json ELSE '{}' END,
       json_patch(CASE WHEN json_valid(c.plan_json) AND json_type(c.plan_json) = 'object'
                       THEN c.plan_json ELSE '{}' END,
                  json_object('machine', (SELECT m.name FROM machines m WHERE m.id = c.machine_id),
                              'tool', (SELECT t.name FROM tools t WHERE t.id = c.tool_id),
                              'compensation', json_object('loops', json(
                  (SELECT json_group_array(json_object('loop_index', l.loop_index,
                                                       'form_error_mm', l.form_error_mm,
                                                       'systematic_peak_mm', l.systematic_peak_mm,
                                                       'random_sigma_mm', l.random_sigma_mm,
                                                       'compensated', l.compensated))
                   FROM (SELECT * FROM case_loops WHERE case_id = c.id ORDER BY loop_index) l))))),
       NULL
FROM cases_v1 c;
CREATE TABLE case_loops_v2 (
  case_id                INTEGER NOT NULL REFERENCES cases(id) ON DELETE CASCADE,
  loop_index             INTEGER NOT NULL CHECK (loop_index >= 0),
  form_error_mm          REAL NOT NULL,
  systematic_peak_mm     REAL,
  random_sigma_mm        REAL,
  compensated            INTEGER NOT NULL CHECK (compensated IN (0, 1)),
  PRIMARY KEY (case_id, loop_index)
);
INSERT INTO case_loops_v2 SELECT * FROM case_loops;
DROP TABLE case_loops;
ALTER TABLE case_loops_v2 RENAME TO case_loops;
DROP TABLE cases_v1;
CREATE INDEX cases_by_family ON cases(family, uid);

CREATE TABLE case_concepts (
  case_id  INTEGER NOT NULL REFERENCES cases(id) ON DELETE CASCADE,
  facet    TEXT NOT NULL CHECK (length(facet) > 0),
  concept  TEXT NOT NULL CHECK (length(concept) > 0),
  PRIMARY KEY (case_id, facet)
);
CREATE INDEX case_concepts_by_facet ON case_concepts(facet, concept);

-- Facet taxonomies (spec §3): one row per node; parent NULL for a root.
CREATE TABLE taxonomy_nodes (
  taxonomy  TEXT NOT NULL CHECK (length(taxonomy) > 0),
  node      TEXT NOT NULL CHECK (length(node) > 0),
  parent    TEXT,
  PRIMARY KEY (taxonomy, node),
  FOREIGN KEY (taxonomy, parent) REFERENCES taxonomy_nodes(taxonomy, node) ON DELETE CASCADE
);

-- The rule base (spec §5): each `kb rules --set` writes a new version; only the newest is active.
CREATE TABLE rules (
  id              INTEGER PRIMARY KEY,
  version         INTEGER NOT NULL CHECK (version > 0),
  name            TEXT NOT NULL CHECK (length(name) > 0),
  condition_json  TEXT NOT NULL CHECK (json_valid(condition_json) AND json_type(condition_json) = 'object'),
  choice_json     TEXT NOT NULL CHECK (json_valid(choice_json) AND json_type(choice_json) = 'object'),
  active          INTEGER NOT NULL CHECK (active IN (0, 1)),
  UNIQUE (version, name)
);
CREATE INDEX rules_active ON rules(active, name);

-- Trained GHSOM trees (spec §2); the newest row is the current map.
CREATE TABLE ghsom (
  id               INTEGER PRIMARY KEY,
  created_at       TEXT NOT NULL,
  seed             INTEGER NOT NULL,
  parameters_json  TEXT NOT NULL CHECK (json_valid(parameters_json)),
  quality_json     TEXT NOT NULL CHECK (json_valid(quality_json)),
  map_json         TEXT NOT NULL CHECK (json_valid(map_json)),
  case_count       INTEGER NOT NULL CHECK (case_count >= 0),
  change_counter   INTEGER NOT NULL CHECK (change_counter >= 0)
);

-- Every change to the library, in the change's own transaction.
CREATE TABLE audit (
  id        INTEGER PRIMARY KEY,
  at        TEXT NOT NULL,
  action    TEXT NOT NULL,
  case_uid  TEXT,
  detail    TEXT NOT NULL DEFAULT ''
);
CREATE INDEX audit_by_case ON audit(case_uid);

-- Counts every change to the set of cases; a GHSOM trained at an older count is stale.
INSERT INTO library_info(key, value) VALUES ('case_changes', '0');

-- Default rule base, version 1. Thresholds 0.95 / 0.80 are the seed's (spec §4); the facet weights are
-- defaults to be calibrated (shape dominates because the geometric facet is what the GHSOM classifies).
INSERT INTO rules(version, name, condition_json, choice_json, active) VALUES
  (1, 'route.direct', '{"similarity":{"gt":0.95}}',
   '{"route":"direct_nc","dma":"GA+SVM","dfa":"adaptive","ad":{"sampling":"equidistant","step_list":true}}', 1),
  (1, 'route.simulate', '{"similarity":{"ge":0.8,"le":0.95}}',
   '{"route":"simulation_correction","dma":"GA","dfa":"B-spline","ad":{"sampling":"equidistant"}}', 1),
  (1, 'route.default', '{"similarity":{"lt":0.8}}',
   '{"route":"default_plan","flag_engineer":true}', 1),
  (1, 'facet.weights', '{}',
   '{"shape":3,"material":1,"tolerance":1,"finish":0.5,"machine_tool":1}', 1);

-- Starter material taxonomy (spec §3 examples).
INSERT INTO taxonomy_nodes(taxonomy, node, parent) VALUES
  ('material', 'metal', NULL),
  ('material', 'steel', 'metal'),
  ('material', 'tool steel', 'steel'),
  ('material', 'H13', 'tool steel'),
  ('material', 'titanium', 'metal'),
  ('material', 'Ti-6Al-4V', 'titanium'),
  ('material', 'aluminium', 'metal'),
  ('material', 'Al 6061', 'aluminium');
)sql"},
  };
  return kMigrations;
}

int LatestSchemaVersion() { return SchemaMigrations().back().version; }

Result<MigrationReport> Migrate(Database* db, const std::vector<Migration>& migrations) {
  for (std::size_t i = 0; i < migrations.size(); ++i) {
    if (migrations[i].version != static_cast<int>(i) + 1) {
      return Status::Internal("migration list is not numbered 1..N at position " + std::to_string(i));
    }
  }
  MigrationReport report;
  FL_ASSIGN_OR_RETURN(long long version, db->QueryInt("PRAGMA user_version;"));
  report.from_version = static_cast<int>(version);
  const int latest = static_cast<int>(migrations.size());
  if (version > latest) {
    return Status::BadInput("case library '" + db->path().string() + "' has schema version " + std::to_string(version) +
                            ", newer than this formloop understands (" + std::to_string(latest) +
                            "). Fix: upgrade formloop; the library was not changed");
  }
  if (version < 0) {
    return Status::BadInput("case library '" + db->path().string() + "' has a negative schema version");
  }
  if (version == 0) {
    // A version-0 file must be empty: refuse to adopt someone else's database.
    FL_ASSIGN_OR_RETURN(auto tables, db->TableNames());
    if (!tables.empty()) {
      return Status::BadInput("'" + db->path().string() + "' holds tables (" + tables.front() +
                              ", ...) but no formloop schema version. Fix: give a new file name for the case library");
    }
  }
  for (int v = static_cast<int>(version) + 1; v <= latest; ++v) {
    const Migration& m = migrations[static_cast<std::size_t>(v - 1)];
    Transaction transaction(db);
    FL_RETURN_IF_ERROR(transaction.begin_status());
    FL_RETURN_IF_ERROR(db->Execute(m.sql).WithContext("migration " + std::to_string(v)));
    // A migration that rebuilds tables must leave every foreign key satisfied.
    FL_ASSIGN_OR_RETURN(Statement fk_check, db->Prepare("PRAGMA foreign_key_check;"));
    FL_ASSIGN_OR_RETURN(bool violation, fk_check.Step());
    if (violation) {
      return Status::Internal("migration " + std::to_string(v) + " left a foreign-key violation in table '" +
                              fk_check.ColumnText(0) + "'; the library was not changed");
    }
    FL_RETURN_IF_ERROR(db->Execute("PRAGMA user_version = " + std::to_string(v) + ";"));
    FL_RETURN_IF_ERROR(transaction.Commit());
    report.applied.push_back(m.description);
  }
  report.to_version = latest;
  return report;
}

Result<int> ProbeLibraryFile(const std::filesystem::path& path, bool allow_unversioned) {
  std::error_code ec;
  if (!std::filesystem::exists(path, ec)) {
    if (allow_unversioned) return 0;
    return Status::NotFound("case library '" + path.string() +
                            "' does not exist. Fix: create it with `formloop kb init " + path.string() + "`");
  }
  if (std::filesystem::is_directory(path, ec)) {
    return Status::BadInput("case library path '" + path.string() + "' is a folder; give a file name such as cases.db");
  }
  if (std::filesystem::file_size(path, ec) == 0) {
    if (allow_unversioned) return 0;
    return Status::BadInput("'" + path.string() +
                            "' is an empty file, not a formloop case library. Fix: run "
                            "`formloop kb init " +
                            path.string() + "` or check the path");
  }
  FL_ASSIGN_OR_RETURN(std::unique_ptr<Database> db, Database::Open(path, Database::Mode::kReadOnly));
  FL_ASSIGN_OR_RETURN(long long version, db->QueryInt("PRAGMA user_version;"));
  const int latest = LatestSchemaVersion();
  if (version > latest) {
    return Status::BadInput("case library '" + path.string() + "' has schema version " + std::to_string(version) +
                            ", newer than this formloop understands (" + std::to_string(latest) +
                            "). Fix: upgrade formloop; the library was not changed");
  }
  FL_ASSIGN_OR_RETURN(auto tables, db->TableNames());
  if (version <= 0) {
    if (tables.empty() && allow_unversioned) return 0;
    if (tables.empty()) {
      return Status::BadInput("'" + path.string() +
                              "' is an empty SQLite database, not a formloop case library. "
                              "Fix: run `formloop kb init " +
                              path.string() + "`");
    }
    return Status::BadInput("'" + path.string() + "' holds tables (" + tables.front() +
                            ", ...) but no formloop schema version: not a formloop case library (a foreign SQLite "
                            "database); the file was not changed. Fix: give a new file name for the case library");
  }
  if (std::find(tables.begin(), tables.end(), "library_info") == tables.end()) {
    return Status::BadInput("'" + path.string() + "' is an SQLite database without formloop's tables (user_version " +
                            std::to_string(version) +
                            " but no library_info): not a formloop case library; the file "
                            "was not changed");
  }
  FL_ASSIGN_OR_RETURN(std::string format,
                      db->QueryText("SELECT coalesce((SELECT value FROM library_info WHERE key = 'format'), '');"));
  if (format != "formloop case library") {
    return Status::BadInput("'" + path.string() +
                            "' is an SQLite database whose library_info does not name a "
                            "formloop case library (format '" +
                            format + "'); the file was not changed");
  }
  return static_cast<int>(version);
}

nlohmann::json InitReport::ToJson() const {
  return {{"path", path},
          {"created", created},
          {"schema_version_before", migration.from_version},
          {"schema_version", migration.to_version},
          {"migrations_applied", migration.applied},
          {"tables", tables},
          {"journal_mode", journal_mode},
          {"foreign_keys", foreign_keys}};
}

Result<InitReport> InitLibrary(const std::filesystem::path& path) {
  InitReport report;
  report.path = path.string();
  std::error_code ec;
  report.created = !std::filesystem::exists(path, ec);
  if (path.has_parent_path() && !std::filesystem::exists(path.parent_path(), ec)) {
    return Status::NotFound("folder '" + path.parent_path().string() + "' for the case library does not exist. " +
                            "Fix: create it first");
  }
  // Refuse foreign, corrupt and newer files before opening them read-write (which switches on WAL).
  FL_RETURN_IF_ERROR(ProbeLibraryFile(path, /*allow_unversioned=*/true).status());
  auto opened = Database::Open(path, Database::Mode::kCreate);
  if (!opened.ok()) {
    if (report.created) std::filesystem::remove(path, ec);
    return opened.status();
  }
  std::unique_ptr<Database> db = std::move(opened).value();
  auto migrated = Migrate(db.get(), SchemaMigrations());
  if (!migrated.ok()) {
    if (report.created) {
      db.reset();
      for (const char* suffix : {"", "-wal", "-shm"}) std::filesystem::remove(path.string() + suffix, ec);
    }
    return migrated.status();
  }
  report.migration = migrated.value();
  FL_ASSIGN_OR_RETURN(report.tables, db->TableNames());
  FL_ASSIGN_OR_RETURN(report.journal_mode, db->QueryText("PRAGMA journal_mode;"));
  FL_ASSIGN_OR_RETURN(long long fk, db->QueryInt("PRAGMA foreign_keys;"));
  report.foreign_keys = fk == 1;
  return report;
}

}  // namespace formloop::kb
