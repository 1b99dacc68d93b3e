#pragma once
// The case library's schema and its migrations (spec/case-library.md §1).
//
// The schema version is SQLite's `PRAGMA user_version`. Each migration moves the library from
// version - 1 to version inside one transaction, so a library is always at exactly one version.
// A library newer than this formloop is refused (never downgraded). Adding a table or column is a
// new Migration appended to SchemaMigrations(); released migrations are never edited.

#include <filesystem>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "core/status.h"
#include "kb/database.h"

namespace formloop::kb {

struct Migration {
  int version;              // the user_version after this migration, 1, 2, ...
  std::string description;  // one line, shown by `kb init`
  std::string sql;          // statements run inside the migration's transaction
};

// formloop's migrations, in order.
const std::vector<Migration>& SchemaMigrations();
int LatestSchemaVersion();

struct MigrationReport {
  int from_version = 0;
  int to_version = 0;
  std::vector<std::string> applied;  // descriptions of the migrations run
};

// Applies every migration above the library's version. `migrations` must be numbered 1..N in order.
Result<MigrationReport> Migrate(Database* db, const std::vector<Migration>& migrations);

// Inspects an existing file read-only, before formloop writes to it, and refuses (BadInput, naming the
// file; the file is left unchanged) anything that is not a formloop case library this formloop can use:
// a non-SQLite file, an SQLite file with tables but no formloop schema, a library whose user_version is
// newer than LatestSchemaVersion(). `allow_unversioned` accepts an empty, version-0 SQLite file (kb init).
// Returns the schema version found (0 for an absent or empty file when allowed).
Result<int> ProbeLibraryFile(const std::filesystem::path& path, bool allow_unversioned);

struct InitReport {
  std::string path;
  bool created = false;  // the file did not exist before
  MigrationReport migration;
  std::vector<std::string> tables;
  std::string journal_mode;
  bool foreign_keys = false;
  nlohmann::json ToJson() const;
};

// `formloop kb init PATH`: creates the library, or brings an existing one up to date.
Result<InitReport> InitLibrary(const std::filesystem::path& path);

}  // namespace formloop::kb
