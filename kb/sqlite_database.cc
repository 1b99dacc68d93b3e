// The SQLite back end of kb/database.h: one file, WAL journal, foreign keys on, BEGIN IMMEDIATE writers.

#include <sqlite3.h>

#include <cstdio>
#include <cstring>
#include <fstream>

#include "kb/database.h"

namespace formloop::kb {
namespace {

class SqliteDatabase;

class SqliteStatement : public StatementImpl {
 public:
  SqliteStatement(const SqliteDatabase* db, sqlite3_stmt* stmt, std::string sql)
      : db_(db), stmt_(stmt), sql_(std::move(sql)) {}
  ~SqliteStatement() override { sqlite3_finalize(stmt_); }
  Status Bind(int index, long long value) override;
  Status Bind(int index, double value) override;
  Status Bind(int index, const std::string& text) override;
  Status BindNull(int index) override;
  Result<bool> Step() override;
  Status Reset() override;
  long long ColumnInt(int column) const override { return sqlite3_column_int64(stmt_, column); }
  double ColumnDouble(int column) const override { return sqlite3_column_double(stmt_, column); }
  std::string ColumnText(int column) const override {
    const unsigned char* text = sqlite3_column_text(stmt_, column);
    return text != nullptr ? reinterpret_cast<const char*>(text) : "";
  }
  bool ColumnIsNull(int column) const override { return sqlite3_column_type(stmt_, column) == SQLITE_NULL; }

 private:
  const SqliteDatabase* db_;
  sqlite3_stmt* stmt_;
  std::string sql_;
};

class SqliteDatabase : public Database {
 public:
  SqliteDatabase(const std::filesystem::path& path, sqlite3* db) : Database(path.string()), db_(db) {}
  ~SqliteDatabase() override {
    if (db_ != nullptr) sqlite3_close_v2(db_);
  }
  Backend backend() const override { return Backend::kSqlite; }

  // Converts a SQLite return code into a Status (Ok for SQLITE_OK/ROW/DONE).
  Status Check(int rc, const std::string& what) const {
    if (rc == SQLITE_OK || rc == SQLITE_ROW || rc == SQLITE_DONE) return Status::Ok();
    std::string message = Named() + ": " + what + " failed: " + sqlite3_errstr(rc);
    if (db_ != nullptr) {
      const char* detail = sqlite3_errmsg(db_);
      if (detail != nullptr && std::string(detail) != sqlite3_errstr(rc)) message += " (" + std::string(detail) + ")";
    }
    const int primary = rc & 0xff;
    if (primary == SQLITE_NOTADB || primary == SQLITE_CORRUPT) {
      return Status::BadInput(message + ". Fix: the file is not a formloop case library; check the path");
    }
    if (primary == SQLITE_CONSTRAINT) return Status::BadInput(message);
    if (primary == SQLITE_CANTOPEN || primary == SQLITE_READONLY || primary == SQLITE_IOERR || primary == SQLITE_FULL ||
        primary == SQLITE_BUSY || primary == SQLITE_LOCKED) {
      return Status::IoError(message);
    }
    return Status::Internal(message);
  }

  Status Execute(const std::string& sql) override {
    char* error = nullptr;
    const int rc = sqlite3_exec(db_, sql.c_str(), nullptr, nullptr, &error);
    sqlite3_free(error);
    if (rc == SQLITE_OK) return Status::Ok();
    return Check(rc, "executing `" + sql.substr(0, 80) + "`");
  }

  Result<Statement> Prepare(const std::string& sql) override {
    sqlite3_stmt* stmt = nullptr;
    const int rc = sqlite3_prepare_v2(db_, sql.c_str(), -1, &stmt, nullptr);
    if (rc != SQLITE_OK) {
      sqlite3_finalize(stmt);
      return Check(rc, "preparing `" + sql.substr(0, 80) + "`");
    }
    return Statement(std::make_unique<SqliteStatement>(this, stmt, sql));
  }

  Result<std::vector<std::string>> TableNames() override {
    return Column("SELECT name FROM sqlite_schema WHERE type = 'table' AND name NOT LIKE 'sqlite_%' ORDER BY name;");
  }
  Result<long long> LastInsertRowId() override { return sqlite3_last_insert_rowid(db_); }
  long long Changes() const override { return sqlite3_changes(db_); }
  Result<long long> SchemaVersion() override { return QueryInt("PRAGMA user_version;"); }
  Status SetSchemaVersion(int version) override {
    return Execute("PRAGMA user_version = " + std::to_string(version) + ";");
  }
  Result<std::vector<std::string>> IntegrityProblems() override {
    FL_ASSIGN_OR_RETURN(std::vector<std::string> lines, Column("PRAGMA integrity_check;"));
    if (lines.size() == 1 && lines.front() == "ok") lines.clear();
    return lines;
  }
  Result<std::vector<std::string>> ForeignKeyViolations() override {
    FL_ASSIGN_OR_RETURN(Statement s, Prepare("PRAGMA foreign_key_check;"));
    std::vector<std::string> out;
    while (true) {
      FL_ASSIGN_OR_RETURN(bool row, s.Step());
      if (!row) break;
      out.push_back(s.ColumnText(0) + " rowid " + s.ColumnText(1) + " -> " + s.ColumnText(2));
    }
    return out;
  }
  std::string JsonArrayLength(const std::string& column) const override { return "json_array_length(" + column + ")"; }
  Status DeferForeignKeys() override { return Execute("PRAGMA defer_foreign_keys = ON;"); }

 protected:
  Status BeginWrite() override { return Execute("BEGIN IMMEDIATE;"); }
  Status BeginRead() override { return Execute("BEGIN;"); }
  Status Commit() override { return Execute("COMMIT;"); }
  void Rollback() override {
    if (!sqlite3_get_autocommit(db_)) (void)Execute("ROLLBACK;");
  }

 private:
  Result<std::vector<std::string>> Column(const std::string& sql) {
    FL_ASSIGN_OR_RETURN(Statement s, Prepare(sql));
    std::vector<std::string> out;
    while (true) {
      FL_ASSIGN_OR_RETURN(bool row, s.Step());
      if (!row) break;
      out.push_back(s.ColumnText(0));
    }
    return out;
  }
  sqlite3* db_ = nullptr;
};

Status SqliteStatement::Bind(int index, long long value) {
  return db_->Check(sqlite3_bind_int64(stmt_, index, value), "binding parameter " + std::to_string(index));
}
Status SqliteStatement::Bind(int index, double value) {
  return db_->Check(sqlite3_bind_double(stmt_, index, value), "binding parameter " + std::to_string(index));
}
Status SqliteStatement::Bind(int index, const std::string& text) {
  return db_->Check(sqlite3_bind_text(stmt_, index, text.c_str(), static_cast<int>(text.size()), SQLITE_TRANSIENT),
                    "binding parameter " + std::to_string(index));
}
Status SqliteStatement::BindNull(int index) {
  return db_->Check(sqlite3_bind_null(stmt_, index), "binding parameter " + std::to_string(index));
}
Result<bool> SqliteStatement::Step() {
  const int rc = sqlite3_step(stmt_);
  if (rc == SQLITE_ROW) return true;
  if (rc == SQLITE_DONE) return false;
  return db_->Check(rc, "running `" + sql_.substr(0, 80) + "`");
}
Status SqliteStatement::Reset() { return db_->Check(sqlite3_reset(stmt_), "resetting a statement"); }

}  // namespace

Result<std::unique_ptr<Database>> OpenSqlite(const std::filesystem::path& path, Database::Mode mode) {
  using Mode = Database::Mode;
  std::error_code ec;
  if (mode == Mode::kOpenExisting && !std::filesystem::exists(path, ec)) {
    return Status::NotFound("case library '" + path.string() +
                            "' does not exist. Fix: create it with `formloop kb init " + path.string() + "`");
  }
  if (std::filesystem::is_directory(path, ec)) {
    return Status::BadInput("case library path '" + path.string() + "' is a folder; give a file name such as cases.db");
  }
  if (mode == Mode::kReadOnly && !std::filesystem::exists(path, ec)) {
    return Status::NotFound("case library '" + path.string() + "' does not exist");
  }
  bool wal_without_log = false;
  if (std::filesystem::exists(path, ec) && std::filesystem::file_size(path, ec) > 0) {
    // Check the header ourselves: SQLite must never be handed (and never write to) a foreign file.
    std::ifstream in(path, std::ios::binary);
    char header[20] = {};
    in.read(header, sizeof header);
    // Bytes 18 and 19 are 2 in a WAL-mode database. Without a -wal file nobody has it open and the main
    // file holds everything.
    wal_without_log = in && header[18] == 2 && header[19] == 2 && !std::filesystem::exists(path.string() + "-wal", ec);
    static const char kMagic[16] = {'S', 'Q', 'L', 'i', 't', 'e', ' ', 'f', 'o', 'r', 'm', 'a', 't', ' ', '3', '\0'};
    if (!in || std::memcmp(header, kMagic, sizeof kMagic) != 0) {
      return Status::BadInput("'" + path.string() +
                              "' is not a formloop case library (not an SQLite database); the file was not changed. "
                              "Fix: check the path");
    }
  }
  const int flags = mode == Mode::kReadOnly ? SQLITE_OPEN_READONLY
                                            : SQLITE_OPEN_READWRITE | (mode == Mode::kCreate ? SQLITE_OPEN_CREATE : 0);
  sqlite3* raw = nullptr;
  std::string name = path.string();
  int open_flags = flags;
  if (mode == Mode::kReadOnly && wal_without_log) {
    // A read-only connection to a WAL database would create (and leave behind) -wal and -shm files;
    // nobody has this one open, so read the main file as immutable instead.
    std::string uri = "file:";
    for (char c : name) {
      if (c == '%' || c == '?' || c == '#') {
        char escaped[4];
        std::snprintf(escaped, sizeof escaped, "%%%02X", static_cast<unsigned char>(c));
        uri += escaped;
      } else {
        uri += c;
      }
    }
    name = uri + "?immutable=1";
    open_flags |= SQLITE_OPEN_URI;
  }
  const int rc = sqlite3_open_v2(name.c_str(), &raw, open_flags, nullptr);
  auto db = std::make_unique<SqliteDatabase>(path, raw);
  if (rc != SQLITE_OK) return db->Check(rc, "opening");
  sqlite3_extended_result_codes(raw, 1);
  sqlite3_busy_timeout(raw, Database::kBusyTimeoutMs);
  FL_RETURN_IF_ERROR(db->Execute("PRAGMA foreign_keys = ON;"));
  if (mode == Mode::kReadOnly) {
    // A file that is not a database fails here, on the first read.
    FL_RETURN_IF_ERROR(db->SchemaVersion().status());
    return std::unique_ptr<Database>(std::move(db));
  }
  // A file that is not a database fails here, on the first read.
  FL_ASSIGN_OR_RETURN(std::string journal, db->QueryText("PRAGMA journal_mode = WAL;"));
  if (journal != "wal") {
    return Status::IoError("case library '" + path.string() + "': cannot switch to WAL journal (got '" + journal +
                           "'); is the file on a file system without shared memory?");
  }
  return std::unique_ptr<Database>(std::move(db));
}

}  // namespace formloop::kb
