#pragma once
// A thin, checked wrapper over SQLite: every return code goes through one check that turns it into
// a Status naming the database file and the statement; RAII transactions roll back unless committed.

#include <filesystem>
#include <functional>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "core/status.h"

struct sqlite3;
struct sqlite3_stmt;

namespace formloop::kb {

class Statement;

class Database {
 public:
  static constexpr int kBusyTimeoutMs = 10000;
  enum class Mode { kOpenExisting, kCreate, kReadOnly };
  // kCreate makes the file (and fails if it cannot); kOpenExisting fails with NotFound when absent.
  // Foreign keys are switched on for the connection; the journal is WAL. kReadOnly opens an existing
  // file without writing anything to it (no WAL switch): used to inspect a file before adopting it.
  // An existing, non-empty file whose first 16 bytes are not the SQLite header is refused with
  // BadInput before SQLite touches it. Writers wait up to kBusyTimeoutMs for each other.
  static Result<std::unique_ptr<Database>> Open(const std::filesystem::path& path, Mode mode);
  ~Database();
  Database(const Database&) = delete;
  Database& operator=(const Database&) = delete;

  // Runs one or more statements without results.
  Status Execute(const std::string& sql);
  Result<Statement> Prepare(const std::string& sql);
  // The integer result of a one-row, one-column query (e.g. PRAGMA user_version).
  Result<long long> QueryInt(const std::string& sql);
  Result<std::string> QueryText(const std::string& sql);
  // Every table name, sorted.
  Result<std::vector<std::string>> TableNames();

  // The rowid of the last INSERT and the rows changed by the last statement on this connection.
  long long LastInsertRowId() const;
  int Changes() const;

  const std::filesystem::path& path() const { return path_; }
  sqlite3* handle() const { return db_; }
  // Converts a SQLite return code into a Status (Ok for SQLITE_OK/ROW/DONE).
  Status Check(int rc, const std::string& what) const;

 private:
  Database(std::filesystem::path path, sqlite3* db) : path_(std::move(path)), db_(db) {}
  std::filesystem::path path_;
  sqlite3* db_ = nullptr;
};

// A prepared statement; binds are 1-based like SQLite's.
class Statement {
 public:
  Statement(const Database* db, sqlite3_stmt* stmt, std::string sql);
  Statement(Statement&& other) noexcept;
  Statement& operator=(Statement&&) = delete;
  ~Statement();

  Status Bind(int index, long long value);
  Status Bind(int index, double value);
  Status Bind(int index, const std::string& text);
  Status BindNull(int index);
  // True while a row is available; false when done.
  Result<bool> Step();
  Status Reset();
  long long ColumnInt(int column) const;  // 0-based like SQLite's
  double ColumnDouble(int column) const;
  std::string ColumnText(int column) const;
  bool ColumnIsNull(int column) const;

 private:
  const Database* db_;
  sqlite3_stmt* stmt_;
  std::string sql_;
};

// BEGIN IMMEDIATE on construction; ROLLBACK in the destructor unless Commit() succeeded.
class Transaction {
 public:
  explicit Transaction(Database* db);
  ~Transaction();
  const Status& begin_status() const { return begin_status_; }
  Status Commit();

 private:
  Database* db_;
  Status begin_status_;
  bool done_ = false;
};

}  // namespace formloop::kb
