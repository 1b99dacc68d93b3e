// Part records (schema v3, kb::Library::SetPartRecord / PartRecords): what a later pooled diagnosis needs
// of a case's part, stored beside the case per machine/tool/material, newest case first, carried by export
// and import, removed with the case; a v2 library migrates with its cases and no records.

#include <algorithm>
#include <filesystem>
#include <string>

#include <gtest/gtest.h>

#include "kb/database.h"
#include "kb/library.h"
#include "kb/schema.h"
#include "tests/kb/kb_fixtures.h"

namespace formloop::kb {
namespace {

using testing::Backend;
using testing::KbBackendTest;
using testing::KbLibraryTest;
using testing::SyntheticCase;
namespace fs = std::filesystem;

nlohmann::json Record(int points, double first) {
  return {{"format", "formloop-part-record"}, {"points", points}, {"residual_um", {first, 2.0}}};
}

PartRecordRow Row(const std::string& uid, const std::string& machine, const nlohmann::json& record) {
  PartRecordRow row;
  row.case_uid = uid;
  row.machine = machine;
  row.tool = "ball r3";
  row.material = "H13";
  row.record = record;
  return row;
}

class PartRecordTest : public KbBackendTest {};

TEST_P(PartRecordTest, StoredBesideTheCaseNewestFirstExportedImportedAndRemovedWithIt) {
  auto lib = NewLibrary("records");
  ASSERT_NE(lib, nullptr);
  // Two cases with known timestamps (an import keeps them): b is the newer.
  CaseRecord a = SyntheticCase(1), b = SyntheticCase(2);
  a.uid = "a-old";
  a.created_at = a.updated_at = "2026-01-01T00:00:00.000Z";
  b.uid = "b-new";
  b.created_at = b.updated_at = "2026-02-01T00:00:00.000Z";
  std::string text = R"({"format":"formloop-case-library","format_version":1,"schema_version":3})"
                     "\n";
  for (const CaseRecord* c : {&a, &b}) text += nlohmann::json{{"type", "case"}, {"case", c->ToJson()}}.dump() + "\n";
  text += Row("a-old", "vm-1", Record(2, 1.5)).ToJson().dump() + "\n";
  const auto imported = lib->ImportText(text, "records.jsonl");
  ASSERT_TRUE(imported.ok()) << imported.status().message();
  EXPECT_EQ(imported->part_records, 1u);
  ASSERT_TRUE(lib->SetPartRecord(Row("b-new", "vm-1", Record(2, 7.0))).ok());
  ASSERT_TRUE(lib->SetPartRecord(Row("b-new", "vm-2", Record(2, 9.0))).ok());
  // Replacing a record of the same key keeps one row.
  ASSERT_TRUE(lib->SetPartRecord(Row("b-new", "vm-1", Record(2, 8.0))).ok());
  const auto rows = lib->PartRecords("vm-1", "ball r3", "H13");
  ASSERT_TRUE(rows.ok()) << rows.status().message();
  ASSERT_EQ(rows->size(), 2u);
  EXPECT_EQ((*rows)[0].case_uid, "b-new");
  EXPECT_EQ((*rows)[0].record["residual_um"][0], 8.0);
  EXPECT_EQ((*rows)[1].case_uid, "a-old");
  EXPECT_EQ((*rows)[1].record, Record(2, 1.5));
  EXPECT_TRUE(lib->PartRecords("vm-1", "ball r3", "D2")->empty());
  // A record for a case that does not exist, or without a positive point count, is refused.
  EXPECT_EQ(lib->SetPartRecord(Row("nobody", "vm-1", Record(2, 0))).code(), StatusCode::kNotFound);
  EXPECT_FALSE(lib->SetPartRecord(Row("a-old", "vm-1", Record(0, 0))).ok());

  // Export carries the records; an import into a new library gives them back, byte for byte.
  const auto exported = lib->ExportText();
  ASSERT_TRUE(exported.ok()) << exported.status().message();
  std::size_t lines = 0;
  for (std::size_t at = exported->find("\"type\":\"part_record\""); at != std::string::npos;
       at = exported->find("\"type\":\"part_record\"", at + 1)) {
    ++lines;
  }
  EXPECT_EQ(lines, 3u);
  auto copy = NewLibrary("copy");
  ASSERT_NE(copy, nullptr);
  ASSERT_TRUE(copy->ImportText(*exported, "export").ok());
  EXPECT_EQ(copy->ExportText().value(), *exported);
  EXPECT_EQ(copy->PartRecords("vm-2", "ball r3", "H13")->size(), 1u);

  // Removing a case removes its records.
  ASSERT_TRUE(lib->RemoveCase("b-new").ok());
  const auto left = lib->PartRecords("vm-1", "ball r3", "H13");
  ASSERT_EQ(left->size(), 1u);
  EXPECT_EQ((*left)[0].case_uid, "a-old");
  EXPECT_TRUE(lib->PartRecords("vm-2", "ball r3", "H13")->empty());

  // A part_record line naming a case the file and the library lack is refused, naming the line.
  const std::string orphan = R"({"format":"formloop-case-library","format_version":1,"schema_version":3})"
                             "\n" +
                             Row("ghost", "vm-1", Record(2, 0)).ToJson().dump() + "\n";
  const auto refused = lib->ImportText(orphan, "orphan.jsonl");
  ASSERT_FALSE(refused.ok());
  EXPECT_NE(refused.status().message().find("orphan.jsonl:2"), std::string::npos) << refused.status().message();
  EXPECT_NE(refused.status().message().find("ghost"), std::string::npos) << refused.status().message();
}

INSTANTIATE_TEST_SUITE_P(Backends, PartRecordTest, ::testing::Values(Backend::kSqlite, Backend::kPostgres),
                         testing::BackendName);

TEST_F(KbLibraryTest, AVersion2LibraryMigratesToVersion3WithItsCasesAndNoPartRecords) {
  // A v2 library with two cases: v3 only adds case_part_records, so a current library without it, at
  // user_version 2, is what formloop before v3 wrote.
  const fs::path path = dir_ / "v2.db";
  {
    auto lib = NewLibrary("v2.db");
    ASSERT_NE(lib, nullptr);
    ASSERT_TRUE(lib->AddCase(SyntheticCase(3)).ok());
    ASSERT_TRUE(lib->AddCase(SyntheticCase(4)).ok());
  }
  {
    auto db = Database::Open(path, Database::Mode::kOpenExisting);
    ASSERT_TRUE(db.ok());
    ASSERT_TRUE((*db)->Execute("DROP TABLE case_part_records; PRAGMA user_version = 2;").ok());
  }
  // A migration that fails half-way (an object already holds the index's name) changes nothing: the
  // library stays at v2 without the new table.
  const fs::path blocked = dir_ / "blocked.db";
  fs::copy_file(path, blocked);
  {
    auto db = Database::Open(blocked, Database::Mode::kOpenExisting);
    ASSERT_TRUE(db.ok());
    ASSERT_TRUE((*db)->Execute("CREATE TABLE case_part_records_by_key(x INTEGER);").ok());
  }
  EXPECT_FALSE(InitLibrary(blocked.string()).ok());
  {
    auto db = Database::Open(blocked, Database::Mode::kOpenExisting);
    ASSERT_TRUE(db.ok());
    EXPECT_EQ(*(*db)->QueryInt("PRAGMA user_version;"), 2);
    EXPECT_EQ(*(*db)->QueryInt("SELECT count(*) FROM sqlite_master WHERE name = 'case_part_records';"), 0);
  }

  // A v2 library is refused until migrated; migrated, it keeps its cases and has no part records.
  EXPECT_FALSE(Library::Open(path.string()).ok());
  const auto init = InitLibrary(path.string());
  ASSERT_TRUE(init.ok()) << init.status().message();
  EXPECT_EQ(init->migration.from_version, 2);
  EXPECT_EQ(init->migration.to_version, 3);
  EXPECT_NE(std::find(init->tables.begin(), init->tables.end(), "case_part_records"), init->tables.end());
  auto lib = Library::Open(path.string());
  ASSERT_TRUE(lib.ok()) << lib.status().message();
  const auto cases = (*lib)->ListCases();
  ASSERT_TRUE(cases.ok());
  EXPECT_EQ(cases->size(), 2u);
  EXPECT_TRUE((*lib)->AllPartRecords()->empty());
  // and takes records from now on.
  ASSERT_TRUE((*lib)->SetPartRecord(Row((*cases)[0].uid, "vm-1", Record(2, 1.0))).ok());
  EXPECT_EQ((*lib)->PartRecords("vm-1", "ball r3", "H13")->size(), 1u);
}

}  // namespace
}  // namespace formloop::kb
