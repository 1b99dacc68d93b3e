// The case library: creation, schema version, foreign keys, WAL, migrations, refusals.

#include <filesystem>
#include <fstream>

#include <unistd.h>

#include <gtest/gtest.h>

#include "kb/database.h"
#include "kb/library.h"
#include "kb/library_url.h"
#include "kb/schema.h"
#include "tests/kb/kb_fixtures.h"

namespace formloop::kb {
namespace {

namespace fs = std::filesystem;
using testing::KbBackendTest;

class KbTest : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = fs::temp_directory_path() / ("formloop-kb-" + std::to_string(::getpid()) + "-" +
                                        ::testing::UnitTest::GetInstance()->current_test_info()->name());
    fs::remove_all(dir_);
    fs::create_directories(dir_);
  }
  void TearDown() override { fs::remove_all(dir_); }
  fs::path dir_;
};

TEST_F(KbTest, InitCreatesVersionedLibraryWithForeignKeysAndWal) {
  const fs::path path = dir_ / "cases.db";
  const auto report = InitLibrary(path);
  ASSERT_TRUE(report.ok()) << report.status().message();
  EXPECT_TRUE(report->created);
  EXPECT_EQ(report->migration.from_version, 0);
  EXPECT_EQ(report->migration.to_version, LatestSchemaVersion());
  EXPECT_EQ(report->journal_mode, "wal");
  EXPECT_TRUE(report->foreign_keys);
  for (const char* table : {"cases", "case_loops", "machines", "tools", "materials", "error_models", "library_info"}) {
    EXPECT_NE(std::find(report->tables.begin(), report->tables.end(), table), report->tables.end()) << table;
  }
  // A second init is a no-op that reports the same version.
  const auto again = InitLibrary(path);
  ASSERT_TRUE(again.ok());
  EXPECT_FALSE(again->created);
  EXPECT_TRUE(again->migration.applied.empty());
  // Foreign keys are enforced: a loop for a case that does not exist is refused.
  auto db = Database::Open(path, Database::Mode::kOpenExisting);
  ASSERT_TRUE(db.ok());
  const Status orphan = (*db)->Execute(
      "INSERT INTO case_loops(case_id, loop_index, form_error_mm, compensated) VALUES (999, 0, 0.01, 0);");
  EXPECT_EQ(orphan.code(), StatusCode::kBadInput);
  EXPECT_NE(orphan.message().find("FOREIGN KEY"), std::string::npos) << orphan.message();
}

TEST_F(KbTest, MigrationsRunInOrderInsideTransactions) {
  const fs::path path = dir_ / "m.db";
  auto db = Database::Open(path, Database::Mode::kCreate);
  ASSERT_TRUE(db.ok());
  std::vector<Migration> migrations = {{1, "t1", "CREATE TABLE a(x INTEGER);"}};
  auto r1 = Migrate(db->get(), migrations);
  ASSERT_TRUE(r1.ok());
  EXPECT_EQ(r1->to_version, 1);
  // A failing migration leaves the library at its previous version and without partial changes.
  migrations.push_back({2, "broken", "CREATE TABLE b(y INTEGER); INSERT INTO nowhere VALUES (1);"});
  auto r2 = Migrate(db->get(), migrations);
  EXPECT_FALSE(r2.ok());
  EXPECT_EQ(*(*db)->QueryInt("PRAGMA user_version;"), 1);
  const auto tables = (*db)->TableNames();
  EXPECT_EQ(tables.value(), std::vector<std::string>{"a"});
  // Fixed, it applies.
  migrations[1].sql = "CREATE TABLE b(y INTEGER);";
  auto r3 = Migrate(db->get(), migrations);
  ASSERT_TRUE(r3.ok());
  EXPECT_EQ(r3->from_version, 1);
  EXPECT_EQ(r3->to_version, 2);
  EXPECT_EQ(*(*db)->QueryInt("PRAGMA user_version;"), 2);
}

TEST_F(KbTest, RefusesNewerLibrariesForeignDatabasesAndNonDatabases) {
  const fs::path newer = dir_ / "newer.db";
  {
    auto db = Database::Open(newer, Database::Mode::kCreate);
    ASSERT_TRUE(db.ok());
    ASSERT_TRUE((*db)->Execute("PRAGMA user_version = 999;").ok());
  }
  const auto r = InitLibrary(newer);
  EXPECT_EQ(r.status().code(), StatusCode::kBadInput);
  EXPECT_NE(r.status().message().find("newer than this formloop"), std::string::npos);

  const fs::path foreign = dir_ / "foreign.db";
  {
    auto db = Database::Open(foreign, Database::Mode::kCreate);
    ASSERT_TRUE((*db)->Execute("CREATE TABLE somebody_elses(x);").ok());
  }
  EXPECT_NE(InitLibrary(foreign).status().message().find("no formloop schema version"), std::string::npos);

  const fs::path text = dir_ / "notes.txt";
  std::ofstream(text) << "this is not a database, just some text that is long enough to matter\n";
  const auto bad = InitLibrary(text);
  EXPECT_EQ(bad.status().code(), StatusCode::kBadInput);
  EXPECT_NE(bad.status().message().find("not a formloop case library"), std::string::npos) << bad.status().message();

  const auto missing_dir = InitLibrary(dir_ / "no-such-folder" / "cases.db");
  EXPECT_EQ(missing_dir.status().code(), StatusCode::kNotFound);
  EXPECT_EQ(Database::Open(dir_ / "absent.db", Database::Mode::kOpenExisting).status().code(), StatusCode::kNotFound);
}

TEST_P(KbBackendTest, TransactionRollsBackUnlessCommitted) {
  const std::string name = LibraryName("t.db");
  ASSERT_TRUE(InitLibrary(name).ok());
  auto db = Database::Open(*LibraryUrl::Parse(name), Database::Mode::kOpenExisting);
  ASSERT_TRUE(db.ok()) << db.status().message();
  Database* d = db->get();
  const Status failed = d->RunInTransaction([&]() -> Status {
    EXPECT_TRUE(d->Execute("INSERT INTO materials(name, taxonomy_path) VALUES ('H13', 'metal/steel/H13');").ok());
    return Status::IoError("the body failed");
  });
  EXPECT_EQ(failed.message(), "the body failed");
  EXPECT_EQ(*d->QueryInt("SELECT COUNT(*) FROM materials;"), 0);
  EXPECT_THROW(d->RunInTransaction([&]() -> Status {
    EXPECT_TRUE(d->Execute("INSERT INTO materials(name, taxonomy_path) VALUES ('H13', 'metal/steel/H13');").ok());
    throw std::runtime_error("interrupted");
  }),
               std::runtime_error);
  EXPECT_EQ(*d->QueryInt("SELECT COUNT(*) FROM materials;"), 0);
  EXPECT_FALSE(d->in_transaction());
  // A failed statement inside the body: nothing of the body is written (PostgreSQL aborts the whole
  // transaction; a COMMIT would answer ROLLBACK and must not be reported as written).
  const Status duplicate = d->RunInTransaction([&]() -> Status {
    EXPECT_TRUE(d->Execute("INSERT INTO materials(name, taxonomy_path) VALUES ('Al', 'metal/Al');").ok());
    (void)d->Execute("INSERT INTO materials(name, taxonomy_path) VALUES ('Al', 'metal/Al');");
    return Status::Ok();
  });
  if (postgres()) {
    EXPECT_FALSE(duplicate.ok());
  }
  EXPECT_EQ(*d->QueryInt("SELECT COUNT(*) FROM materials WHERE name = 'Al';"), postgres() ? 0 : 1);
  ASSERT_TRUE(d->RunInTransaction([&]() -> Status {
                 FL_ASSIGN_OR_RETURN(Statement stmt,
                                     d->Prepare("INSERT INTO materials(name, taxonomy_path) VALUES (?1, ?2);"));
                 FL_RETURN_IF_ERROR(stmt.Bind(1, std::string("Ti-6Al-4V")));
                 FL_RETURN_IF_ERROR(stmt.Bind(2, std::string("metal/titanium/Ti-6Al-4V")));
                 return stmt.Step().status();
               }).ok());
  EXPECT_EQ(*d->QueryText("SELECT name FROM materials WHERE name <> 'Al';"), "Ti-6Al-4V");
}

TEST(KbLibraryUrl, NamesAreParsedAndPasswordsNeverShown) {
  EXPECT_FALSE(LibraryUrl::Parse("cases.db")->is_postgres());
  EXPECT_EQ(LibraryUrl::Parse("sqlite:lib/cases.db")->path, fs::path("lib/cases.db"));
  const auto pg = LibraryUrl::Parse("postgresql://plant:s3cret@db.local:5433/kb?sslmode=require&password=x");
  ASSERT_TRUE(pg.ok());
  EXPECT_TRUE(pg->is_postgres());
  EXPECT_EQ(pg->display, "postgresql://plant@db.local:5433/kb?sslmode=require");
  EXPECT_EQ(LibraryUrl::Parse("mysql://x/y").status().code(), StatusCode::kBadInput);
  EXPECT_EQ(LibraryUrl::Parse("").status().code(), StatusCode::kBadInput);
  EXPECT_EQ(LibraryUrl::Parse("sqlite:").status().code(), StatusCode::kBadInput);
  // A server that is not there: the error names the library (without the password) and the fix.
  const auto down = Library::Open("postgresql://plant:s3cret@127.0.0.1:1/kb?connect_timeout=5");
  ASSERT_FALSE(down.ok());
  EXPECT_NE(down.status().message().find("'postgresql://plant@127.0.0.1:1/kb?connect_timeout=5'"), std::string::npos)
      << down.status().message();
  EXPECT_EQ(down.status().message().find("s3cret"), std::string::npos);
  EXPECT_NE(down.status().message().find("Fix:"), std::string::npos);
}

}  // namespace
}  // namespace formloop::kb
