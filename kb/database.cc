#include "kb/database.h"

#include <chrono>
#include <random>
#include <thread>

namespace formloop::kb {

Result<std::unique_ptr<Database>> Database::Open(const LibraryUrl& url, Mode mode) {
  if (url.is_postgres()) return OpenPostgres(url, mode);
  return OpenSqlite(url.path, mode);
}

Result<std::unique_ptr<Database>> Database::Open(const std::filesystem::path& path, Mode mode) {
  return OpenSqlite(path, mode);
}

Result<long long> Database::QueryInt(const std::string& sql) {
  FL_ASSIGN_OR_RETURN(Statement stmt, Prepare(sql));
  FL_ASSIGN_OR_RETURN(bool row, stmt.Step());
  if (!row) return Status::Internal(Named() + ": `" + sql + "` returned no row");
  return stmt.ColumnInt(0);
}

Result<std::string> Database::QueryText(const std::string& sql) {
  FL_ASSIGN_OR_RETURN(Statement stmt, Prepare(sql));
  FL_ASSIGN_OR_RETURN(bool row, stmt.Step());
  if (!row) return Status::Internal(Named() + ": `" + sql + "` returned no row");
  return stmt.ColumnText(0);
}

Status Database::RunInTransaction(const std::function<Status()>& body) {
  if (depth_ > 0) return body();
  // Jittered back-off between attempts so that writers which collided do not collide again.
  std::minstd_rand jitter(static_cast<unsigned>(std::chrono::steady_clock::now().time_since_epoch().count()));
  Status last;
  for (int attempt = 1; attempt <= kMaxAttempts; ++attempt) {
    Status status = BeginWrite();
    if (status.ok()) {
      struct Depth {
        int* depth;
        bool open = true;
        Database* db;
        ~Depth() {
          --*depth;
          if (open) db->Rollback();  // an exception from the body
        }
      } guard{&depth_, true, this};
      ++depth_;
      status = body();
      if (status.ok()) status = Commit();
      if (status.ok()) {
        guard.open = false;
        return status;
      }
      guard.open = false;
      Rollback();
    }
    if (!TakeRetryableFailure()) return status;
    last = status;
    std::this_thread::sleep_for(std::chrono::milliseconds(2 * attempt + static_cast<int>(jitter() % 8)));
  }
  return last.WithContext("gave up after " + std::to_string(kMaxAttempts) +
                          " attempts on serialization failures (other writers kept conflicting); rerun");
}

Status Database::RunInReadSnapshot(const std::function<Status()>& body) {
  if (depth_ > 0) return body();
  FL_RETURN_IF_ERROR(BeginRead());
  ++depth_;
  struct End {
    int* depth;
    Database* db;
    ~End() {
      --*depth;
      db->Rollback();  // nothing was written; ends the snapshot
    }
  } end{&depth_, this};
  return body();
}

}  // namespace formloop::kb
