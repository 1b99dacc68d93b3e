// The case library API: migrations 1 -> 2 -> 3, round trips, validation, export/import, check, refusals.

#include <algorithm>
#include <filesystem>
#include <fstream>

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
using testing::ReadBytes;
using testing::SyntheticCase;
using testing::WriteBytes;
namespace fs = std::filesystem;

TEST_F(KbLibraryTest, MigratesAVersion1LibraryWithItsCasesAndLoops) {
  const fs::path path = dir_ / "v1.db";
  {
    auto db = Database::Open(path, Database::Mode::kCreate);
    ASSERT_TRUE(db.ok());
    const std::vector<Migration> v1(SchemaMigrations().begin(), SchemaMigrations().begin() + 1);
    ASSERT_TRUE(Migrate(db->get(), v1).ok());
    ASSERT_TRUE((*db)
                    ->Execute(R"sql(
      INSERT INTO materials(id, name, taxonomy_path) VALUES (1, 'H13', 'metal/steel/tool steel/H13');
      INSERT INTO machines(id, name, controller) VALUES (1, 'dmu50', 'heidenhain');
      INSERT INTO tools(id, name, type, radius_mm) VALUES (1, 'ball6', 'ball_end', 3);
      INSERT INTO cases(id, name, created_at, surface_family, features_json, material_id, tolerance_mm, machine_id,
                        tool_id, plan_json, simulation_json)
        VALUES (1, 'blade A', '2026-01-02T03:04:05Z', 'turbine_blade', '{"batch_size":4}', 1, 0.02, 1, 1,
                '{"strategy":{"raster_angle_deg":30}}', '{"model_format":"step"}'),
               (2, 'plate', '2026-01-03T00:00:00Z', 'freeform', 'not json', NULL, 0.05, NULL, NULL, '{}', '{}');
      INSERT INTO case_loops(case_id, loop_index, form_error_mm, compensated) VALUES (1, 1, 0.012, 1), (1, 0, 0.05, 0);
    )sql")
                    .ok());
    ASSERT_EQ(*(*db)->QueryInt("PRAGMA user_version;"), 1);
  }
  const auto init = InitLibrary(path);
  ASSERT_TRUE(init.ok()) << init.status().message();
  EXPECT_EQ(init->migration.from_version, 1);
  EXPECT_EQ(init->migration.to_version, LatestSchemaVersion());
  auto lib = Library::Open(path);
  ASSERT_TRUE(lib.ok()) << lib.status().message();

  auto a = (*lib)->GetCase("v1-1");
  ASSERT_TRUE(a.ok()) << a.status().message();
  EXPECT_EQ(a->name, "blade A");
  EXPECT_EQ(a->family, "turbine_blade");
  EXPECT_EQ(a->created_at, "2026-01-02T03:04:05Z");
  EXPECT_EQ(a->part["batch_size"], 4);
  EXPECT_DOUBLE_EQ(a->part["tolerance_mm"].get<double>(), 0.02);
  EXPECT_EQ(a->part["material"], "H13");
  EXPECT_EQ(a->simulation["model_format"], "step");
  EXPECT_EQ(a->manufacturing["machine"], "dmu50");
  EXPECT_EQ(a->manufacturing["tool"], "ball6");
  EXPECT_EQ(a->manufacturing["strategy"]["raster_angle_deg"], 30);
  ASSERT_EQ(a->manufacturing["compensation"]["loops"].size(), 2u);
  EXPECT_EQ(a->manufacturing["compensation"]["loops"][0]["loop_index"], 0);
  EXPECT_FALSE(a->descriptor.has_value());
  auto b = (*lib)->GetCase("v1-2");
  ASSERT_TRUE(b.ok());
  EXPECT_FALSE(b->part.contains("material"));  // no material in v1: no key, not null
  EXPECT_FALSE(b->manufacturing.contains("machine"));

  // case_loops survived and now points at the new cases table: removing the case removes its loops.
  EXPECT_EQ(*(*lib)->db()->QueryInt("SELECT COUNT(*) FROM case_loops;"), 2);
  ASSERT_TRUE((*lib)->RemoveCase("v1-1").ok());
  EXPECT_EQ(*(*lib)->db()->QueryInt("SELECT COUNT(*) FROM case_loops;"), 0);

  // Seeded rule base and a clean check (missing descriptors are only a warning).
  auto rules = (*lib)->GetRules();
  ASSERT_TRUE(rules.ok());
  EXPECT_EQ(rules->version, 1);
  auto thresholds = ThresholdsOf(rules->rules);
  ASSERT_TRUE(thresholds.ok());
  EXPECT_DOUBLE_EQ(thresholds->low, 0.80);
  EXPECT_DOUBLE_EQ(thresholds->high, 0.95);
  EXPECT_EQ(rules->Find("facet.weights")->choice["shape"], 3);
  EXPECT_EQ(rules->Find("route.direct")->choice["dma"], "GA+SVM");
  EXPECT_EQ(rules->Find("route.simulate")->choice["dfa"], "B-spline");
  auto check = (*lib)->Check();
  ASSERT_TRUE(check.ok());
  EXPECT_TRUE(check->clean()) << check->ToJson().dump();
  EXPECT_EQ(check->cases_missing_descriptor, std::vector<std::string>{"v1-2"});
}

TEST_P(KbBackendTest, AddGetListRemoveRoundTrip) {
  auto lib = NewLibrary("cases.db");
  ASSERT_NE(lib, nullptr);
  for (int i = 0; i < 9; ++i) ASSERT_TRUE(lib->AddCase(SyntheticCase(i)).ok());
  const CaseRecord original = SyntheticCase(4);
  auto got = lib->GetCase(original.uid);
  ASSERT_TRUE(got.ok()) << got.status().message();
  EXPECT_EQ(got->name, original.name);
  EXPECT_EQ(got->family, original.family);
  EXPECT_EQ(got->part, original.part);
  EXPECT_EQ(got->simulation, original.simulation);
  EXPECT_EQ(got->manufacturing, original.manufacturing);
  ASSERT_TRUE(got->descriptor.has_value());
  EXPECT_EQ(*got->descriptor, *original.descriptor);  // bit-exact through the JSON text column
  EXPECT_EQ(got->concepts, original.concepts);
  EXPECT_FALSE(got->created_at.empty());

  auto all = lib->ListCases();
  ASSERT_TRUE(all.ok());
  ASSERT_EQ(all->size(), 9u);
  EXPECT_TRUE(
      std::is_sorted(all->begin(), all->end(), [](const CaseRecord& x, const CaseRecord& y) { return x.uid < y.uid; }));
  auto blades = lib->ListCases("turbine_blade");
  ASSERT_TRUE(blades.ok());
  EXPECT_EQ(blades->size(), 3u);
  for (const auto& c : *blades) EXPECT_EQ(c.family, "turbine_blade");

  auto stats = lib->Stats();
  ASSERT_TRUE(stats.ok());
  EXPECT_EQ(stats->cases, 9);
  EXPECT_EQ(stats->per_family.at("freeform"), 3);
  EXPECT_EQ(stats->per_facet_concept.at("material").at("H13"), 3);
  EXPECT_EQ(stats->case_changes, 9);

  ASSERT_TRUE(lib->RemoveCase(original.uid).ok());
  EXPECT_EQ(lib->GetCase(original.uid).status().code(), StatusCode::kNotFound);
  EXPECT_EQ(lib->RemoveCase(original.uid).code(), StatusCode::kNotFound);
  EXPECT_EQ(*lib->db()->QueryInt("SELECT COUNT(*) FROM case_concepts;"), 8 * 3);

  auto audit = lib->Audit(original.uid);
  ASSERT_TRUE(audit.ok());
  ASSERT_EQ(audit->size(), 2u);
  EXPECT_EQ((*audit)[0].action, "remove");
  EXPECT_EQ((*audit)[1].action, "add");
}

TEST_P(KbBackendTest, DuplicateUidRefusedUnlessReplace) {
  auto lib = NewLibrary("cases.db");
  ASSERT_NE(lib, nullptr);
  CaseRecord c = SyntheticCase(1);
  ASSERT_TRUE(lib->AddCase(c).ok());
  const std::string created = lib->GetCase(c.uid)->created_at;
  c.name = "renamed";
  const Status dup = lib->AddCase(c);
  EXPECT_EQ(dup.code(), StatusCode::kBadInput);
  EXPECT_NE(dup.message().find("'case-00001' exists"), std::string::npos) << dup.message();
  EXPECT_EQ(lib->GetCase(c.uid)->name, "synthetic part 1");
  c.concepts = {{"shape", "other"}};
  ASSERT_TRUE(lib->AddCase(c, /*replace=*/true).ok());
  auto got = lib->GetCase(c.uid);
  EXPECT_EQ(got->name, "renamed");
  EXPECT_EQ(got->created_at, created);
  EXPECT_EQ(got->concepts.size(), 1u);
  EXPECT_EQ(*lib->db()->QueryInt("SELECT COUNT(*) FROM cases;"), 1);
}

TEST_P(KbBackendTest, BadCaseFieldsAreNamed) {
  const nlohmann::json good = SyntheticCase(0).ToJson();
  struct Mutation {
    std::string field;
    std::function<void(nlohmann::json&)> apply;
  };
  const std::vector<Mutation> mutations = {
      {"uid", [](nlohmann::json& j) { j.erase("uid"); }},
      {"uid", [](nlohmann::json& j) { j["uid"] = "has space"; }},
      {"name", [](nlohmann::json& j) { j["name"] = ""; }},
      {"family", [](nlohmann::json& j) { j["family"] = 3; }},
      {"part", [](nlohmann::json& j) { j["part"] = nlohmann::json::array(); }},
      {"simulation", [](nlohmann::json& j) { j.erase("simulation"); }},
      {"part.tolerance_mm", [](nlohmann::json& j) { j["part"]["tolerance_mm"] = -0.1; }},
      {"part.batch_size", [](nlohmann::json& j) { j["part"]["batch_size"] = 2.5; }},
      {"simulation.effect_models[0].effects[1].standard_error",
       [](nlohmann::json& j) { j["simulation"]["effect_models"][0]["effects"][1]["standard_error"] = -1; }},
      {"manufacturing.tools[0].radius_mm", [](nlohmann::json& j) { j["manufacturing"]["tools"][0]["radius_mm"] = 0; }},
      {"descriptor[3]", [](nlohmann::json& j) { j["descriptor"][3] = "x"; }},
      {"concepts.material", [](nlohmann::json& j) { j["concepts"]["material"] = ""; }},
      {"colour", [](nlohmann::json& j) { j["colour"] = "red"; }},
  };
  for (const auto& m : mutations) {
    nlohmann::json j = good;
    m.apply(j);
    const auto r = CaseRecord::FromJson(j, Where{.file = "case.json"});
    ASSERT_FALSE(r.ok()) << m.field;
    EXPECT_EQ(r.status().code(), StatusCode::kBadInput);
    EXPECT_NE(r.status().message().find("field '" + m.field + "'"), std::string::npos)
        << m.field << ": " << r.status().message();
    EXPECT_NE(r.status().message().find("case.json"), std::string::npos) << r.status().message();
  }
  // A case file on disk: syntax errors name the file.
  WriteBytes(dir_ / "broken.json", "{\"uid\": ");
  const auto broken = ReadCaseFile(dir_ / "broken.json");
  EXPECT_EQ(broken.status().code(), StatusCode::kBadInput);
  EXPECT_NE(broken.status().message().find("broken.json"), std::string::npos);
}

TEST_P(KbBackendTest, ExampleCaseFileIsValid) {
  const auto example = ReadCaseFile(fs::path(FORMLOOP_SOURCE_DIR) / "data/kb/example_case.json");
  ASSERT_TRUE(example.ok()) << example.status().message();
  EXPECT_EQ(example->uid, "example-blade-001");
  EXPECT_EQ(example->descriptor->size(), 24u);  // retrieval::kDescriptorCount: the library's descriptors
  auto lib = NewLibrary("cases.db");
  ASSERT_NE(lib, nullptr);
  ASSERT_TRUE(lib->AddCase(*example).ok());
  EXPECT_EQ(lib->GetCase(example->uid)->manufacturing, example->manufacturing);
}

TEST_P(KbBackendTest, ExportImportExportIsByteIdentical) {
  auto a = NewLibrary("a.db");
  ASSERT_NE(a, nullptr);
  for (int i = 0; i < 40; ++i) ASSERT_TRUE(a->AddCase(SyntheticCase(i, 11)).ok());
  CaseRecord bare = SyntheticCase(99, 11);
  bare.descriptor.reset();
  bare.concepts.clear();
  ASSERT_TRUE(a->AddCase(bare).ok());
  auto rules = a->GetRules();
  nlohmann::json new_rules = rules->ToJson();
  for (auto& r : new_rules["rules"]) {
    if (r["name"] == "facet.weights") r["choice"]["finish"] = 0.75;
  }
  ASSERT_EQ(*a->SetRules(new_rules, "rules.json"), 2);
  ASSERT_TRUE(a->SetTaxonomy("finish", {{"", "finish", std::nullopt},
                                        {"", "fine", std::string("finish")},
                                        {"", "mirror", std::string("fine")}})
                  .ok());
  const fs::path first = dir_ / "a.jsonl";
  ASSERT_TRUE(a->ExportToFile(first).ok());

  auto b = NewLibrary("b.db");
  ASSERT_NE(b, nullptr);
  auto report = b->ImportFile(first);
  ASSERT_TRUE(report.ok()) << report.status().message();
  EXPECT_EQ(report->cases_added, 41u);
  EXPECT_EQ(report->rules, 8u);
  const fs::path second = dir_ / "b.jsonl";
  ASSERT_TRUE(b->ExportToFile(second).ok());
  const std::string text = ReadBytes(first);
  EXPECT_EQ(text, ReadBytes(second));
  EXPECT_EQ(std::count(text.begin(), text.end(), '\n'), 1 + 41 + 8 + 8 + 3);
  EXPECT_EQ(b->GetRules()->version, 2);
  EXPECT_EQ(b->GetRules()->Find("facet.weights")->choice["finish"], 0.75);
  EXPECT_FALSE(b->GetCase(bare.uid)->descriptor.has_value());

  // Importing again refuses the duplicates and changes nothing; --replace replaces them.
  const auto again = b->ImportFile(first);
  EXPECT_EQ(again.status().code(), StatusCode::kBadInput);
  EXPECT_NE(again.status().message().find("a.jsonl:2"), std::string::npos) << again.status().message();
  EXPECT_EQ(*b->db()->QueryInt("SELECT COUNT(*) FROM cases;"), 41);
  ImportOptions replace;
  replace.replace = true;
  const auto replaced = b->ImportFile(first, replace);
  ASSERT_TRUE(replaced.ok());
  EXPECT_EQ(replaced->cases_replaced, 41u);
  ASSERT_TRUE(b->ExportToFile(second).ok());
  EXPECT_EQ(text, ReadBytes(second));
}

TEST_P(KbBackendTest, ImportRefusesNewerFormatsAndBadLines) {
  auto lib = NewLibrary("cases.db");
  ASSERT_NE(lib, nullptr);
  const std::string one_case = nlohmann::json{{"type", "case"}, {"case", SyntheticCase(1).ToJson()}}.dump() + "\n";
  const auto newer_format =
      lib->ImportText(R"({"format":"formloop-case-library","format_version":2,"schema_version":2})"
                      "\n" +
                          one_case,
                      "x.jsonl");
  EXPECT_EQ(newer_format.status().code(), StatusCode::kBadInput);
  EXPECT_NE(newer_format.status().message().find("format version 2 is newer"), std::string::npos);
  EXPECT_NE(newer_format.status().message().find("upgrade formloop"), std::string::npos);
  const auto newer_schema =
      lib->ImportText(R"({"format":"formloop-case-library","format_version":1,"schema_version":7})"
                      "\n" +
                          one_case,
                      "x.jsonl");
  EXPECT_NE(newer_schema.status().message().find("schema version 7"), std::string::npos);
  const auto not_ours = lib->ImportText("{\"hello\":1}\n", "x.jsonl");
  EXPECT_NE(not_ours.status().message().find("header"), std::string::npos);
  // A bad case on line 3 refuses the whole file: the good case on line 2 is not imported either.
  nlohmann::json bad = SyntheticCase(2).ToJson();
  bad["part"]["tolerance_mm"] = "tight";
  const auto bad_line = lib->ImportText(R"({"format":"formloop-case-library","format_version":1,"schema_version":2})"
                                        "\n" +
                                            one_case + nlohmann::json{{"type", "case"}, {"case", bad}}.dump() + "\n",
                                        "x.jsonl");
  EXPECT_NE(bad_line.status().message().find("x.jsonl:3: field 'part.tolerance_mm'"), std::string::npos)
      << bad_line.status().message();
  EXPECT_EQ(*lib->db()->QueryInt("SELECT COUNT(*) FROM cases;"), 0);
}

TEST_P(KbBackendTest, RulesAreVersionedAndChecked) {
  auto lib = NewLibrary("cases.db");
  ASSERT_NE(lib, nullptr);
  nlohmann::json rules = lib->GetRules()->ToJson();
  nlohmann::json swapped = rules;
  for (auto& r : swapped["rules"]) {
    if (r["name"] == "route.direct") r["condition"]["similarity"]["gt"] = 0.7;
    if (r["name"] == "route.simulate") r["condition"]["similarity"] = {{"ge", 0.8}, {"le", 0.7}};
  }
  const auto refused = lib->SetRules(swapped, "rules.json");
  EXPECT_EQ(refused.status().code(), StatusCode::kBadInput);
  EXPECT_NE(refused.status().message().find("0 < low < high <= 1"), std::string::npos) << refused.status().message();
  EXPECT_EQ(lib->GetRules()->version, 1);
  for (auto& r : rules["rules"]) {
    if (r["name"] == "route.direct") r["condition"]["similarity"]["gt"] = 0.97;
    if (r["name"] == "route.simulate") r["condition"]["similarity"]["le"] = 0.97;
  }
  ASSERT_EQ(*lib->SetRules(rules, "rules.json"), 2);
  EXPECT_DOUBLE_EQ(ThresholdsOf(lib->GetRules()->rules)->high, 0.97);
  EXPECT_EQ(*lib->db()->QueryInt("SELECT COUNT(*) FROM rules WHERE active = 0;"), 4);
  EXPECT_TRUE(lib->Check()->clean());
  // A rule base broken behind the API's back is reported by check.
  ASSERT_TRUE(lib->db()
                  ->Execute("UPDATE rules SET condition_json = '{\"similarity\":{\"ge\":1.2,\"le\":0.97}}' "
                            "WHERE active = 1 AND name = 'route.simulate';")
                  .ok());
  auto check = lib->Check();
  EXPECT_FALSE(check->clean());
  EXPECT_FALSE(check->rule_problems.empty());
}

TEST_P(KbBackendTest, CheckFindsOrphansAndStaleGhsom) {
  auto lib = NewLibrary("cases.db");
  ASSERT_NE(lib, nullptr);
  for (int i = 0; i < 5; ++i) ASSERT_TRUE(lib->AddCase(SyntheticCase(i)).ok());
  EXPECT_TRUE(lib->Check()->clean());

  GhsomRecord g;
  g.seed = 42;
  g.parameters = {{"tau1", 0.6}, {"tau2", 0.05}};
  g.quality = {{"mqe0", 1.5}};
  g.map = {{"units", nlohmann::json::array({{{"weight", {0.1, 0.2}}}})}};
  auto id = lib->StoreGhsom(g);
  ASSERT_TRUE(id.ok()) << id.status().message();
  auto loaded = lib->LoadGhsom();
  ASSERT_TRUE(loaded.ok() && loaded->has_value());
  EXPECT_EQ((*loaded)->map, g.map);
  EXPECT_EQ((*loaded)->case_count, 5);
  EXPECT_EQ((*loaded)->seed, 42);
  auto fresh = lib->Check();
  EXPECT_TRUE(fresh->clean()) << fresh->ToJson().dump();
  EXPECT_FALSE(fresh->ghsom.stale);

  ASSERT_TRUE(lib->AddCase(SyntheticCase(5)).ok());
  auto stale = lib->Check();
  EXPECT_TRUE(stale->clean());  // stale is a warning, not damage
  EXPECT_FALSE(stale->warnings.empty());
  EXPECT_TRUE(stale->ghsom.stale);
  EXPECT_EQ(stale->ghsom.trained_at_changes, 5);
  EXPECT_EQ(stale->ghsom.current_changes, 6);
  ASSERT_TRUE(lib->StoreGhsom(g).ok());
  EXPECT_TRUE(lib->Check()->clean());
  // Storing a map replaces the previous one (only the newest is used; rows do not pile up).
  EXPECT_EQ(*lib->db()->QueryInt("SELECT COUNT(*) FROM ghsom;"), 1);

  // An orphan concept row, written with foreign keys off by another program (PostgreSQL: a superuser
  // session that skips the foreign-key triggers).
  const std::string orphan_row = "INSERT INTO case_concepts(case_id, facet, concept) VALUES (9999, 'shape', 'ghost');";
  ASSERT_TRUE(lib->db()
                  ->Execute(postgres() ? "SET session_replication_role = replica; " + orphan_row +
                                             " SET session_replication_role = origin;"
                                       : "PRAGMA foreign_keys = OFF; " + orphan_row + " PRAGMA foreign_keys = ON;")
                  .ok());
  auto orphan = lib->Check();
  EXPECT_FALSE(orphan->clean());
  EXPECT_EQ(orphan->orphan_concepts, 1);
  ASSERT_EQ(orphan->foreign_key_violations.size(), 1u);
  EXPECT_NE(orphan->foreign_key_violations[0].find("case_concepts"), std::string::npos);
}

TEST_F(KbLibraryTest, RefusedFilesAreNamedAndLeftUnchanged) {
  // Garbage bytes, a text file, a PNG, a foreign SQLite database, a library newer than this formloop.
  std::string garbage(4096, '\0');
  for (std::size_t i = 0; i < garbage.size(); ++i) garbage[i] = static_cast<char>((i * 7919 + 13) & 0xff);
  WriteBytes(dir_ / "garbage.db", garbage);
  WriteBytes(dir_ / "notes.txt", "cases:\n  - blade\n  - plate\n");
  // 24 bytes: the PNG signature, the IHDR chunk's length and type, width and height 16 (the literal holds exactly
  // these: reading 24 bytes of a shorter literal overran it; ASan found it).
  WriteBytes(dir_ / "image.png",
             std::string("\x89PNG\r\n\x1a\n\0\0\0\rIHDR\0\0\0\x10\0\0\0\x10", 24) + std::string(200, 'x'));
  {
    auto db = Database::Open(dir_ / "foreign.db", Database::Mode::kCreate);
    ASSERT_TRUE(db.ok());
    ASSERT_TRUE((*db)->Execute("PRAGMA journal_mode = DELETE; CREATE TABLE invoices(id INTEGER, total REAL);").ok());
  }
  {
    auto db = Database::Open(dir_ / "foreign_versioned.db", Database::Mode::kCreate);
    ASSERT_TRUE((*db)->Execute("PRAGMA journal_mode = DELETE; CREATE TABLE t(x); PRAGMA user_version = 2;").ok());
  }
  ASSERT_TRUE(InitLibrary(dir_ / "newer.db").ok());
  {
    auto db = Database::Open(dir_ / "newer.db", Database::Mode::kOpenExisting);
    ASSERT_TRUE((*db)->Execute("PRAGMA user_version = 9;").ok());
  }
  struct Case {
    std::string file;
    std::string expected;
  };
  const std::vector<Case> cases = {{"garbage.db", "not a formloop case library"},
                                   {"notes.txt", "not a formloop case library"},
                                   {"image.png", "not a formloop case library"},
                                   {"foreign.db", "not a formloop case library"},
                                   {"foreign_versioned.db", "without formloop's tables"},
                                   {"newer.db", "schema version 9, newer than this formloop understands (3)"}};
  for (const auto& c : cases) {
    const fs::path path = dir_ / c.file;
    const std::string before = ReadBytes(path);
    const auto opened = Library::Open(path);
    ASSERT_FALSE(opened.ok()) << c.file;
    EXPECT_EQ(opened.status().code(), StatusCode::kBadInput) << c.file;
    EXPECT_NE(opened.status().message().find(c.expected), std::string::npos) << opened.status().message();
    EXPECT_NE(opened.status().message().find(path.string()), std::string::npos) << opened.status().message();
    const auto init = InitLibrary(path);
    EXPECT_FALSE(init.ok()) << c.file;
    EXPECT_EQ(ReadBytes(path), before) << c.file << " was modified";
    EXPECT_FALSE(fs::exists(path.string() + "-wal")) << c.file;
  }
  const auto newer = Library::Open(dir_ / "newer.db");
  EXPECT_NE(newer.status().message().find("upgrade formloop"), std::string::npos);
  // An old library is refused by Open with the migrate command, and left unchanged.
  {
    auto db = Database::Open(dir_ / "old.db", Database::Mode::kCreate);
    const std::vector<Migration> v1(SchemaMigrations().begin(), SchemaMigrations().begin() + 1);
    ASSERT_TRUE(Migrate(db->get(), v1).ok());
  }
  const std::string old_before = ReadBytes(dir_ / "old.db");
  const auto old = Library::Open(dir_ / "old.db");
  EXPECT_NE(old.status().message().find("kb migrate"), std::string::npos) << old.status().message();
  EXPECT_EQ(ReadBytes(dir_ / "old.db"), old_before);
  EXPECT_EQ(Library::Open(dir_ / "absent.db").status().code(), StatusCode::kNotFound);
}

// A library moved SQLite -> PostgreSQL -> SQLite by export/import: each export byte-identical to the first.
TEST_F(KbLibraryTest, ExportIsByteIdenticalAcrossBackEnds) {
  ASSERT_TRUE(testing::PostgresServer::Get().error().empty()) << testing::PostgresServer::Get().error();
  auto a = NewLibrary("a.db");
  ASSERT_NE(a, nullptr);
  for (int i = 0; i < 30; ++i) ASSERT_TRUE(a->AddCase(SyntheticCase(i, 5)).ok());
  CaseRecord odd = SyntheticCase(31, 5);
  odd.name = "quotes ' \" and unicode \u00e9\u2202, tabs\t";  // text that needs escaping survives
  odd.part["tolerance_mm"] = 0.1 + 0.2;                       // a double that needs all 17 digits
  odd.descriptor = std::vector<double>{1e-300, -0.0, 123456789.123456789, 5e-324};
  ASSERT_TRUE(a->AddCase(odd).ok());
  nlohmann::json rules = a->GetRules()->ToJson();
  for (auto& r : rules["rules"]) {
    if (r["name"] == "facet.weights") r["choice"]["finish"] = 0.25;
  }
  ASSERT_TRUE(a->SetRules(rules, "rules.json").ok());
  ASSERT_TRUE(a->SetTaxonomy("finish", {{"", "finish", std::nullopt},
                                        {"", "Zfine", std::string("finish")},
                                        {"", "afine", std::string("finish")}})
                  .ok());
  const fs::path first = dir_ / "a.jsonl";
  ASSERT_TRUE(a->ExportToFile(first).ok());

  const std::string url = testing::PostgresServer::Get().NewLibraryUrl("cross");
  ASSERT_TRUE(InitLibrary(url).ok());
  auto b = Library::Open(url);
  ASSERT_TRUE(b.ok()) << b.status().message();
  ASSERT_TRUE((*b)->ImportFile(first).ok());
  const fs::path second = dir_ / "b.jsonl";
  ASSERT_TRUE((*b)->ExportToFile(second).ok());
  EXPECT_EQ(ReadBytes(first), ReadBytes(second));

  auto c = NewLibrary("c.db");
  ASSERT_NE(c, nullptr);
  ASSERT_TRUE(c->ImportFile(second).ok());
  const fs::path third = dir_ / "c.jsonl";
  ASSERT_TRUE(c->ExportToFile(third).ok());
  EXPECT_EQ(ReadBytes(first), ReadBytes(third));
  auto back = c->GetCase(odd.uid);
  ASSERT_TRUE(back.ok());
  EXPECT_EQ(back->name, odd.name);
  EXPECT_EQ(*back->descriptor, *odd.descriptor);
}

// The one instantiation of the back-end suite in this binary (its tests are in several files).
INSTANTIATE_TEST_SUITE_P(Backends, KbBackendTest, ::testing::Values(Backend::kSqlite, Backend::kPostgres),
                         testing::BackendName);

}  // namespace
}  // namespace formloop::kb
