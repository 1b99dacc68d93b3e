#pragma once
// The case library's storage interface: one Database type with two back ends, SQLite (the embedded
// default, kb/sqlite_database.cc) and PostgreSQL through libpqxx (kb/postgres_database.cc). Every
// back-end error becomes a Status naming the library (its path, or its URL without the password) and
// the statement; transactions roll back unless committed.
//
// The SQL the library runs is written once: `?N` parameters (the PostgreSQL back end rewrites them to
// `$N`), standard functions only. What differs between the engines goes through the virtual calls
// below: the schema version (SQLite's PRAGMA user_version, PostgreSQL's formloop_schema_version
// table), integrity and foreign-key checks, deferred foreign keys, the last inserted id.
//
// Concurrency: RunInTransaction() is the one way to write. SQLite runs it in BEGIN IMMEDIATE (one
// writer at a time, others wait up to kBusyTimeoutMs). PostgreSQL takes a session advisory lock per
// library (writers queue instead of conflicting; this covers the GHSOM read-modify-write of a `kb add`
// or a `formloop run` retain step, which runs inside one outer transaction) and then BEGIN ISOLATION
// LEVEL SERIALIZABLE; a serialization failure or deadlock (SQLSTATE 40001 / 40P01) rolls back and
// reruns the whole body, up to kMaxAttempts times.

#include <filesystem>
#include <functional>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "core/status.h"
#include "kb/library_url.h"

namespace formloop::kb {

class Statement;

// One back end's prepared statement; binds are 1-based, columns 0-based.
class StatementImpl {
 public:
  virtual ~StatementImpl() = default;
  virtual Status Bind(int index, long long value) = 0;
  virtual Status Bind(int index, double value) = 0;
  virtual Status Bind(int index, const std::string& text) = 0;
  virtual Status BindNull(int index) = 0;
  virtual Result<bool> Step() = 0;
  virtual Status Reset() = 0;
  virtual long long ColumnInt(int column) const = 0;
  virtual double ColumnDouble(int column) const = 0;
  virtual std::string ColumnText(int column) const = 0;
  virtual bool ColumnIsNull(int column) const = 0;
};

class Database {
 public:
  static constexpr int kBusyTimeoutMs = 10000;
  static constexpr int kMaxAttempts = 8;  // of one transaction on serialization failures
  enum class Backend { kSqlite, kPostgres };
  enum class Mode { kOpenExisting, kCreate, kReadOnly };

  // SQLite: kCreate makes the file (and fails if it cannot); kOpenExisting fails with NotFound when
  // absent. Foreign keys are switched on for the connection; the journal is WAL. kReadOnly opens an
  // existing file without writing anything to it (no WAL switch): used to inspect a file before adopting
  // it. An existing, non-empty file whose first 16 bytes are not the SQLite header is refused with
  // BadInput before SQLite touches it.
  // PostgreSQL: connects to an existing database (formloop never creates databases or roles); kReadOnly
  // makes the session read-only.
  static Result<std::unique_ptr<Database>> Open(const LibraryUrl& url, Mode mode);
  // An SQLite file.
  static Result<std::unique_ptr<Database>> Open(const std::filesystem::path& path, Mode mode);
  virtual ~Database() = default;
  Database(const Database&) = delete;
  Database& operator=(const Database&) = delete;

  virtual Backend backend() const = 0;
  // Runs one or more statements without results.
  virtual Status Execute(const std::string& sql) = 0;
  virtual Result<Statement> Prepare(const std::string& sql) = 0;
  // The integer result of a one-row, one-column query.
  Result<long long> QueryInt(const std::string& sql);
  Result<std::string> QueryText(const std::string& sql);
  // Every table of the library, sorted (PostgreSQL's schema-version table left out).
  virtual Result<std::vector<std::string>> TableNames() = 0;

  // The id of the last INSERT and the rows changed by the last statement on this connection.
  virtual Result<long long> LastInsertRowId() = 0;
  virtual long long Changes() const = 0;

  // 0 for an empty database.
  virtual Result<long long> SchemaVersion() = 0;
  // Inside a migration's transaction.
  virtual Status SetSchemaVersion(int version) = 0;
  // Empty when the storage is sound (SQLite: PRAGMA integrity_check; PostgreSQL: every constraint of
  // the library validated).
  virtual Result<std::vector<std::string>> IntegrityProblems() = 0;
  // "table rowid N -> parent" for each row whose parent is missing.
  virtual Result<std::vector<std::string>> ForeignKeyViolations() = 0;
  // The SQL expression for the length of the JSON array in text column `column`.
  virtual std::string JsonArrayLength(const std::string& column) const = 0;
  // Inside a transaction: foreign keys checked at COMMIT instead of per statement.
  virtual Status DeferForeignKeys() = 0;

  // Runs `body` in one write transaction (see the file comment); nested calls join the outer one.
  Status RunInTransaction(const std::function<Status()>& body);
  // Runs `body` in one read-only snapshot.
  Status RunInReadSnapshot(const std::function<Status()>& body);
  bool in_transaction() const { return depth_ > 0; }

  // The library's name in messages: the SQLite path, or the URL without its password.
  const std::string& name() const { return name_; }
  std::filesystem::path path() const { return name_; }

 protected:
  explicit Database(std::string name) : name_(std::move(name)) {}
  virtual Status BeginWrite() = 0;
  virtual Status BeginRead() = 0;
  virtual Status Commit() = 0;
  virtual void Rollback() = 0;
  // True when the last failure was a serialization failure or deadlock that a rerun may clear.
  virtual bool TakeRetryableFailure() { return false; }
  // A message prefix naming the library.
  std::string Named() const { return "case library '" + name_ + "'"; }

 private:
  std::string name_;
  int depth_ = 0;
};

// A prepared statement of either back end.
class Statement {
 public:
  explicit Statement(std::unique_ptr<StatementImpl> impl) : impl_(std::move(impl)) {}
  Status Bind(int index, long long value) { return impl_->Bind(index, value); }
  Status Bind(int index, double value) { return impl_->Bind(index, value); }
  Status Bind(int index, const std::string& text) { return impl_->Bind(index, text); }
  Status BindNull(int index) { return impl_->BindNull(index); }
  // True while a row is available; false when done.
  Result<bool> Step() { return impl_->Step(); }
  Status Reset() { return impl_->Reset(); }
  long long ColumnInt(int column) const { return impl_->ColumnInt(column); }
  double ColumnDouble(int column) const { return impl_->ColumnDouble(column); }
  std::string ColumnText(int column) const { return impl_->ColumnText(column); }
  bool ColumnIsNull(int column) const { return impl_->ColumnIsNull(column); }

 private:
  std::unique_ptr<StatementImpl> impl_;
};

// The SQLite back end's file-level open, for the schema probe and tests that build old or foreign files.
Result<std::unique_ptr<Database>> OpenSqlite(const std::filesystem::path& path, Database::Mode mode);
// The PostgreSQL back end.
Result<std::unique_ptr<Database>> OpenPostgres(const LibraryUrl& url, Database::Mode mode);

}  // namespace formloop::kb
