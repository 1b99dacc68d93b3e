#include "kb/schema.h"

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
    return Status::BadInput("case library '" + db->path().string() + "' has schema version " +
                            std::to_string(version) + ", newer than this formloop understands (" +
                            std::to_string(latest) + "). Fix: use a newer formloop; the library was not changed");
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
    FL_RETURN_IF_ERROR(db->Execute("PRAGMA user_version = " + std::to_string(v) + ";"));
    FL_RETURN_IF_ERROR(transaction.Commit());
    report.applied.push_back(m.description);
  }
  report.to_version = latest;
  return report;
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
