// The case library: creation, schema version, foreign keys, WAL, migrations, refusals.

#include <filesystem>
#include <fstream>

#include <unistd.h>

#include <gtest/gtest.h>

#include "kb/database.h"
#include "kb/schema.h"

namespace formloop::kb {
namespace {

namespace fs = std::filesystem;

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

TEST_F(KbTest, TransactionRollsBackUnlessCommitted) {
  const fs::path path = dir_ / "t.db";
  ASSERT_TRUE(InitLibrary(path).ok());
  auto db = Database::Open(path, Database::Mode::kOpenExisting);
  ASSERT_TRUE(db.ok());
  {
    Transaction t(db->get());
    ASSERT_TRUE(t.begin_status().ok());
    ASSERT_TRUE((*db)->Execute("INSERT INTO materials(name, taxonomy_path) VALUES ('H13', 'metal/steel/H13');").ok());
  }  // no commit
  EXPECT_EQ(*(*db)->QueryInt("SELECT COUNT(*) FROM materials;"), 0);
  {
    Transaction t(db->get());
    auto stmt = (*db)->Prepare("INSERT INTO materials(name, taxonomy_path) VALUES (?1, ?2);");
    ASSERT_TRUE(stmt.ok());
    ASSERT_TRUE(stmt->Bind(1, std::string("Ti-6Al-4V")).ok());
    ASSERT_TRUE(stmt->Bind(2, std::string("metal/titanium/Ti-6Al-4V")).ok());
    ASSERT_TRUE(stmt->Step().ok());
    ASSERT_TRUE(t.Commit().ok());
  }
  EXPECT_EQ(*(*db)->QueryText("SELECT name FROM materials;"), "Ti-6Al-4V");
}

}  // namespace
}  // namespace formloop::kb
