// The PostgreSQL back end of kb/database.h, through libpqxx 6.4.
//
// One connection per Database; statements run on a pqxx::nontransaction so that BEGIN / COMMIT are
// ours (kb/database.h: RunInTransaction). Parameters are sent as text with their types left to the
// server, which infers them from the statement, so the same `?N` SQL serves both back ends.

#include <algorithm>
#include <charconv>
#include <cstdlib>
#include <optional>

#include <pqxx/pqxx>

#include "kb/database.h"

namespace formloop::kb {
namespace {

// Advisory locks are per database; this key ("formloop" in ASCII) is the library's writer lock.
constexpr long long kWriterLockKey = 0x666f726d6c6f6f70LL;

// libpq's messages end in a newline and may span lines ("...refused\n\tIs the server running..."): one line.
std::string Trimmed(const std::string& text) {
  std::string out;
  for (char c : text) {
    if (c == '\n' || c == '\t') {
      if (!out.empty() && out.back() != ' ') out += ' ';
    } else {
      out += c;
    }
  }
  while (!out.empty() && out.back() == ' ') out.pop_back();
  return out;
}

// `?N` -> `$N`, outside quoted strings and identifiers.
std::string ToPostgresParameters(const std::string& sql) {
  std::string out;
  out.reserve(sql.size());
  char quote = 0;
  for (std::size_t i = 0; i < sql.size(); ++i) {
    const char c = sql[i];
    if (quote != 0) {
      if (c == quote) quote = 0;
    } else if (c == '\'' || c == '"') {
      quote = c;
    } else if (c == '?' && i + 1 < sql.size() && sql[i + 1] >= '0' && sql[i + 1] <= '9') {
      out += '$';
      continue;
    }
    out += c;
  }
  return out;
}

class PostgresDatabase;

class PostgresStatement : public StatementImpl {
 public:
  PostgresStatement(PostgresDatabase* db, std::string sql) : db_(db), sql_(std::move(sql)) {}
  Status Bind(int index, long long value) override { return Set(index, std::to_string(value)); }
  Status Bind(int index, double value) override {
    char buffer[64];
    const auto [end, ec] = std::to_chars(buffer, buffer + sizeof buffer, value);
    return Set(index, std::string(buffer, end));
  }
  Status Bind(int index, const std::string& text) override { return Set(index, text); }
  Status BindNull(int index) override { return Set(index, std::nullopt); }
  Result<bool> Step() override;
  Status Reset() override {
    executed_ = false;
    return Status::Ok();
  }
  long long ColumnInt(int column) const override {
    const pqxx::field f = result_[static_cast<pqxx::row::size_type>(row_)][column];
    long long value = 0;
    if (!f.is_null()) std::from_chars(f.c_str(), f.c_str() + f.size(), value);
    return value;
  }
  double ColumnDouble(int column) const override {
    const pqxx::field f = result_[static_cast<pqxx::row::size_type>(row_)][column];
    double value = 0;
    if (!f.is_null()) std::from_chars(f.c_str(), f.c_str() + f.size(), value);
    return value;
  }
  std::string ColumnText(int column) const override {
    const pqxx::field f = result_[static_cast<pqxx::row::size_type>(row_)][column];
    return f.is_null() ? std::string() : std::string(f.c_str(), f.size());
  }
  bool ColumnIsNull(int column) const override {
    return result_[static_cast<pqxx::row::size_type>(row_)][column].is_null();
  }

 private:
  Status Set(int index, std::optional<std::string> value) {
    if (index < 1 || index > 99) return Status::Internal("parameter index " + std::to_string(index) + " out of range");
    if (params_.size() < static_cast<std::size_t>(index)) params_.resize(static_cast<std::size_t>(index));
    params_[static_cast<std::size_t>(index - 1)] = std::move(value);
    return Status::Ok();
  }
  PostgresDatabase* db_;
  std::string sql_;
  std::vector<std::optional<std::string>> params_;
  pqxx::result result_;
  long row_ = 0;
  bool executed_ = false;
};

class PostgresDatabase : public Database {
 public:
  PostgresDatabase(const LibraryUrl& url, std::unique_ptr<pqxx::connection> conn)
      : Database(url.display), conn_(std::move(conn)), work_(std::make_unique<pqxx::nontransaction>(*conn_)) {}
  ~PostgresDatabase() override {
    if (in_tx_ || locked_) Rollback();
    work_.reset();
  }
  Backend backend() const override { return Backend::kPostgres; }

  // Turns a libpqxx exception into a Status naming the library, the statement and the fix.
  Status Fail(const std::exception& e, const std::string& what) {
    const std::string head = Named() + ": " + what + " failed: " + Trimmed(e.what());
    const std::string reach =
        ". Fix: check that the PostgreSQL server is running and reachable, then rerun; an interrupted change was "
        "rolled back by the server";
    if (dynamic_cast<const pqxx::broken_connection*>(&e) != nullptr) {
      broken_ = true;
      return Status::IoError(head + reach);
    }
    if (const auto* sql = dynamic_cast<const pqxx::sql_error*>(&e)) {
      const std::string state = sql->sqlstate();
      if (state == "40001" || state == "40P01") {
        retryable_ = true;
        return Status::IoError(head + " (SQLSTATE " + state + ")");
      }
      if (state.rfind("23", 0) == 0) return Status::BadInput(head);
      if (state.rfind("08", 0) == 0 || state.rfind("57P", 0) == 0) {
        broken_ = true;
        return Status::IoError(head + " (SQLSTATE " + state + ")" + reach);
      }
      if (state == "25006") return Status::IoError(head + " (the session is read-only)");
      return Status::Internal(head + " (SQLSTATE " + state + ")");
    }
    return Status::Internal(head);
  }

  // Runs one statement with text parameters (nullopt = NULL).
  Result<pqxx::result> Run(const std::string& sql, const std::vector<std::optional<std::string>>& params) {
    if (broken_) return Status::IoError(Named() + ": the connection to the server was lost earlier. Fix: rerun");
    try {
      pqxx::result r;
      if (params.empty()) {
        r = work_->exec(sql);
      } else {
        std::vector<const char*> values;
        values.reserve(params.size());
        for (const auto& p : params) values.push_back(p ? p->c_str() : nullptr);
        r = work_->exec_params(sql, pqxx::prepare::make_dynamic_params(values));
      }
      changes_ = r.affected_rows();
      return r;
    } catch (const std::exception& e) {
      if (in_tx_) tx_failed_ = true;  // the server aborted the transaction: it can only roll back
      return Fail(e, "running `" + sql.substr(0, 80) + "`");
    }
  }

  Status Execute(const std::string& sql) override { return Run(sql, {}).status(); }
  Result<Statement> Prepare(const std::string& sql) override {
    return Statement(std::make_unique<PostgresStatement>(this, ToPostgresParameters(sql)));
  }
  Result<std::vector<std::string>> TableNames() override {
    return Column(
        "SELECT table_name::text FROM information_schema.tables WHERE table_schema = current_schema() AND "
        "table_type = 'BASE TABLE' AND table_name <> 'formloop_schema_version' ORDER BY 1;");
  }
  Result<long long> LastInsertRowId() override { return QueryInt("SELECT lastval();"); }
  long long Changes() const override { return changes_; }
  Result<long long> SchemaVersion() override {
    FL_ASSIGN_OR_RETURN(long long has_table,
                        QueryInt("SELECT count(*) FROM information_schema.tables WHERE table_schema = "
                                 "current_schema() AND table_name = 'formloop_schema_version';"));
    if (has_table == 0) return 0LL;
    return QueryInt("SELECT coalesce(max(version), 0) FROM formloop_schema_version;");
  }
  Status SetSchemaVersion(int version) override {
    return Execute(
        "CREATE TABLE IF NOT EXISTS formloop_schema_version (version INTEGER NOT NULL); "
        "DELETE FROM formloop_schema_version; INSERT INTO formloop_schema_version(version) VALUES (" +
        std::to_string(version) + ");");
  }
  Result<std::vector<std::string>> IntegrityProblems() override {
    // The server enforces every constraint on every write; what can be wrong is a constraint or index
    // someone left unvalidated or invalid (e.g. NOT VALID, a failed CREATE INDEX CONCURRENTLY).
    return Column(
        "SELECT c.conrelid::regclass::text || ': constraint ' || c.conname || ' is not validated' FROM pg_constraint c "
        "JOIN pg_namespace n ON n.oid = c.connamespace WHERE n.nspname = current_schema() AND NOT c.convalidated "
        "UNION ALL "
        "SELECT i.indexrelid::regclass::text || ': index is invalid' FROM pg_index i JOIN pg_class t ON t.oid = "
        "i.indrelid JOIN pg_namespace n ON n.oid = t.relnamespace WHERE n.nspname = current_schema() AND NOT "
        "i.indisvalid ORDER BY 1;");
  }
  Result<std::vector<std::string>> ForeignKeyViolations() override {
    // The server enforces the keys; this re-checks them the way SQLite's foreign_key_check reports.
    FL_ASSIGN_OR_RETURN(std::vector<std::string> tables, TableNames());
    auto has = [&](const char* t) { return std::find(tables.begin(), tables.end(), t) != tables.end(); };
    std::vector<std::string> out;
    struct Key {
      const char* child;
      const char* parent;
      const char* sql;
    };
    static const Key kKeys[] = {
        {"case_concepts", "cases",
         "SELECT 'case_concepts rowid ' || x.case_id || ' -> cases' FROM case_concepts x WHERE NOT EXISTS "
         "(SELECT 1 FROM cases c WHERE c.id = x.case_id) ORDER BY 1;"},
        {"case_loops", "cases",
         "SELECT 'case_loops rowid ' || x.case_id || ' -> cases' FROM case_loops x WHERE NOT EXISTS "
         "(SELECT 1 FROM cases c WHERE c.id = x.case_id) ORDER BY 1;"},
        {"taxonomy_nodes", "taxonomy_nodes",
         "SELECT 'taxonomy_nodes ' || x.taxonomy || '/' || x.node || ' -> taxonomy_nodes' FROM taxonomy_nodes x "
         "WHERE x.parent IS NOT NULL AND NOT EXISTS (SELECT 1 FROM taxonomy_nodes p WHERE p.taxonomy = x.taxonomy "
         "AND p.node = x.parent) ORDER BY 1;"},
    };
    for (const Key& k : kKeys) {
      if (!has(k.child) || !has(k.parent)) continue;
      FL_ASSIGN_OR_RETURN(std::vector<std::string> rows, Column(k.sql));
      out.insert(out.end(), rows.begin(), rows.end());
    }
    return out;
  }
  std::string JsonArrayLength(const std::string& column) const override {
    return "jsonb_array_length(" + column + "::jsonb)";
  }
  Status DeferForeignKeys() override { return Execute("SET CONSTRAINTS ALL DEFERRED;"); }

 protected:
  Status BeginWrite() override {
    // Writers queue on the library's advisory lock (taken before the snapshot, so a writer sees every
    // earlier commit), then run SERIALIZABLE as the guard against anything that bypasses the lock.
    FL_RETURN_IF_ERROR(Execute("SELECT pg_advisory_lock(" + std::to_string(kWriterLockKey) + ");"));
    locked_ = true;
    FL_RETURN_IF_ERROR(Execute("BEGIN ISOLATION LEVEL SERIALIZABLE;"));
    in_tx_ = true;
    tx_failed_ = false;
    return Status::Ok();
  }
  Status BeginRead() override {
    FL_RETURN_IF_ERROR(Execute("BEGIN ISOLATION LEVEL REPEATABLE READ READ ONLY;"));
    in_tx_ = true;
    tx_failed_ = false;
    return Status::Ok();
  }
  Status Commit() override {
    if (tx_failed_) {
      // COMMIT of an aborted transaction answers ROLLBACK without an error; never report it as written.
      Rollback();
      return Status::Internal(Named() + ": a statement of the transaction failed earlier; nothing was written");
    }
    const Status status = Execute("COMMIT;");
    in_tx_ = false;  // COMMIT ends the transaction even when it fails
    Unlock();
    return status;
  }
  void Rollback() override {
    if (in_tx_ && !broken_) (void)Execute("ROLLBACK;");
    in_tx_ = false;
    tx_failed_ = false;
    Unlock();
  }
  bool TakeRetryableFailure() override {
    const bool r = retryable_;
    retryable_ = false;
    return r;
  }

 private:
  void Unlock() {
    if (locked_ && !broken_) (void)Execute("SELECT pg_advisory_unlock(" + std::to_string(kWriterLockKey) + ");");
    locked_ = false;  // a lost session released it
  }
  Result<std::vector<std::string>> Column(const std::string& sql) {
    FL_ASSIGN_OR_RETURN(pqxx::result r, Run(sql, {}));
    std::vector<std::string> out;
    for (const auto& row : r) out.push_back(row[0].is_null() ? "" : row[0].c_str());
    return out;
  }

  std::unique_ptr<pqxx::connection> conn_;
  std::unique_ptr<pqxx::nontransaction> work_;
  long long changes_ = 0;
  bool retryable_ = false;
  bool broken_ = false;
  bool in_tx_ = false;
  bool tx_failed_ = false;
  bool locked_ = false;
};

Result<bool> PostgresStatement::Step() {
  if (!executed_) {
    FL_ASSIGN_OR_RETURN(result_, db_->Run(sql_, params_));
    executed_ = true;
    row_ = 0;
  } else {
    ++row_;
  }
  return row_ < static_cast<long>(result_.size());
}

}  // namespace

Result<std::unique_ptr<Database>> OpenPostgres(const LibraryUrl& url, Database::Mode mode) {
  std::unique_ptr<pqxx::connection> conn;
  try {
    conn = std::make_unique<pqxx::connection>(url.conninfo);
  } catch (const std::exception& e) {
    const std::string what = Trimmed(e.what());
    const std::string head = "case library '" + url.display + "': cannot connect: " + what;
    if (what.find("does not exist") != std::string::npos && what.find("database") != std::string::npos) {
      return Status::NotFound(head + ". Fix: create the database (createdb), then `formloop kb init " + url.display +
                              "`");
    }
    if (what.find("password") != std::string::npos || what.find("authentication") != std::string::npos) {
      return Status::IoError(head + ". Fix: check the user and give the password through PGPASSWORD or ~/.pgpass");
    }
    return Status::IoError(head +
                           ". Fix: check that the PostgreSQL server is running and that the URL's host, port "
                           "and database are right");
  }
  auto db = std::make_unique<PostgresDatabase>(url, std::move(conn));
  // Notices (e.g. "relation already exists, skipping") would go to stderr; warnings still do.
  FL_RETURN_IF_ERROR(db->Execute("SET client_min_messages = warning;"));
  if (mode == Database::Mode::kReadOnly) FL_RETURN_IF_ERROR(db->Execute("SET default_transaction_read_only = on;"));
  return std::unique_ptr<Database>(std::move(db));
}

}  // namespace formloop::kb
