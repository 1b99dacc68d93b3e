#include "kb/database.h"

#include <sqlite3.h>

#include <cstdio>
#include <cstring>
#include <fstream>

namespace formloop::kb {

Status Database::Check(int rc, const std::string& what) const {
  if (rc == SQLITE_OK || rc == SQLITE_ROW || rc == SQLITE_DONE) return Status::Ok();
  std::string message = "case library '" + path_.string() + "': " + what + " failed: " + sqlite3_errstr(rc);
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

Result<std::unique_ptr<Database>> Database::Open(const std::filesystem::path& path, Mode mode) {
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
  std::unique_ptr<Database> db(new Database(path, raw));
  if (rc != SQLITE_OK) return db->Check(rc, "opening");
  sqlite3_extended_result_codes(raw, 1);
  sqlite3_busy_timeout(raw, kBusyTimeoutMs);
  FL_RETURN_IF_ERROR(db->Execute("PRAGMA foreign_keys = ON;"));
  if (mode == Mode::kReadOnly) {
    // A file that is not a database fails here, on the first read.
    FL_RETURN_IF_ERROR(db->QueryInt("PRAGMA user_version;").status());
    return db;
  }
  // A file that is not a database fails here, on the first read.
  FL_ASSIGN_OR_RETURN(std::string journal, db->QueryText("PRAGMA journal_mode = WAL;"));
  if (journal != "wal") {
    return Status::IoError("case library '" + path.string() + "': cannot switch to WAL journal (got '" + journal +
                           "'); is the file on a file system without shared memory?");
  }
  return db;
}

long long Database::LastInsertRowId() const { return sqlite3_last_insert_rowid(db_); }
int Database::Changes() const { return sqlite3_changes(db_); }

Database::~Database() {
  if (db_ != nullptr) sqlite3_close_v2(db_);
}

Status Database::Execute(const std::string& sql) {
  char* error = nullptr;
  const int rc = sqlite3_exec(db_, sql.c_str(), nullptr, nullptr, &error);
  std::string detail = error != nullptr ? error : "";
  sqlite3_free(error);
  if (rc == SQLITE_OK) return Status::Ok();
  Status status = Check(rc, "executing `" + sql.substr(0, 80) + "`");
  return status;
}

Result<Statement> Database::Prepare(const std::string& sql) {
  sqlite3_stmt* stmt = nullptr;
  const int rc = sqlite3_prepare_v2(db_, sql.c_str(), -1, &stmt, nullptr);
  if (rc != SQLITE_OK) {
    sqlite3_finalize(stmt);
    return Check(rc, "preparing `" + sql.substr(0, 80) + "`");
  }
  return Statement(this, stmt, sql);
}

Result<long long> Database::QueryInt(const std::string& sql) {
  FL_ASSIGN_OR_RETURN(Statement stmt, Prepare(sql));
  FL_ASSIGN_OR_RETURN(bool row, stmt.Step());
  if (!row) return Status::Internal("case library '" + path_.string() + "': `" + sql + "` returned no row");
  return stmt.ColumnInt(0);
}

Result<std::string> Database::QueryText(const std::string& sql) {
  FL_ASSIGN_OR_RETURN(Statement stmt, Prepare(sql));
  FL_ASSIGN_OR_RETURN(bool row, stmt.Step());
  if (!row) return Status::Internal("case library '" + path_.string() + "': `" + sql + "` returned no row");
  return stmt.ColumnText(0);
}

Result<std::vector<std::string>> Database::TableNames() {
  FL_ASSIGN_OR_RETURN(Statement stmt,
                      Prepare("SELECT name FROM sqlite_schema WHERE type = 'table' AND name NOT LIKE 'sqlite_%' "
                              "ORDER BY name;"));
  std::vector<std::string> names;
  while (true) {
    FL_ASSIGN_OR_RETURN(bool row, stmt.Step());
    if (!row) break;
    names.push_back(stmt.ColumnText(0));
  }
  return names;
}

Statement::Statement(const Database* db, sqlite3_stmt* stmt, std::string sql)
    : db_(db), stmt_(stmt), sql_(std::move(sql)) {}
Statement::Statement(Statement&& other) noexcept : db_(other.db_), stmt_(other.stmt_), sql_(std::move(other.sql_)) {
  other.stmt_ = nullptr;
}
Statement::~Statement() {
  if (stmt_ != nullptr) sqlite3_finalize(stmt_);
}

Status Statement::Bind(int index, long long value) {
  return db_->Check(sqlite3_bind_int64(stmt_, index, value), "binding parameter " + std::to_string(index));
}
Status Statement::Bind(int index, double value) {
  return db_->Check(sqlite3_bind_double(stmt_, index, value), "binding parameter " + std::to_string(index));
}
Status Statement::Bind(int index, const std::string& text) {
  return db_->Check(sqlite3_bind_text(stmt_, index, text.c_str(), static_cast<int>(text.size()), SQLITE_TRANSIENT),
                    "binding parameter " + std::to_string(index));
}
Status Statement::BindNull(int index) {
  return db_->Check(sqlite3_bind_null(stmt_, index), "binding parameter " + std::to_string(index));
}
Result<bool> Statement::Step() {
  const int rc = sqlite3_step(stmt_);
  if (rc == SQLITE_ROW) return true;
  if (rc == SQLITE_DONE) return false;
  return db_->Check(rc, "running `" + sql_.substr(0, 80) + "`");
}
Status Statement::Reset() { return db_->Check(sqlite3_reset(stmt_), "resetting a statement"); }
long long Statement::ColumnInt(int column) const { return sqlite3_column_int64(stmt_, column); }
double Statement::ColumnDouble(int column) const { return sqlite3_column_double(stmt_, column); }
std::string Statement::ColumnText(int column) const {
  const unsigned char* text = sqlite3_column_text(stmt_, column);
  return text != nullptr ? reinterpret_cast<const char*>(text) : "";
}
bool Statement::ColumnIsNull(int column) const { return sqlite3_column_type(stmt_, column) == SQLITE_NULL; }

Transaction::Transaction(Database* db) : db_(db) { begin_status_ = db_->Execute("BEGIN IMMEDIATE;"); }
Transaction::~Transaction() {
  if (!done_ && begin_status_.ok()) (void)db_->Execute("ROLLBACK;");
}
Status Transaction::Commit() {
  FL_RETURN_IF_ERROR(begin_status_);
  FL_RETURN_IF_ERROR(db_->Execute("COMMIT;"));
  done_ = true;
  return Status::Ok();
}

}  // namespace formloop::kb
