// `formloop run` pools the case library's earlier parts of the same machine/tool/material (issue 20,
// "Pooling parts"; RunOptions::pool_cases, simulation/part_record.h): the first part's run stores its part
// record beside its case; the second part, another shape, is diagnosed together with it. The machine has
// a ball 6 µm under its programmed radius and clamps every part 10 µm high. On the shallow dome alone the
// z offset (∝ n_z) cannot be told from a constant offset along n (tool radius, probe radius, deflection,
// z scale): one alias group. The egg box alone confuses its z offset with a thermal drift. Pooled, each
// part's set-up is named (right within its interval); what is left grouped is the tool radius with the
// probe radius, which no part probed along −n can split. Another machine/tool/material is not pooled, a
// case without a part record (a library from before schema v3) is not pooled and the run says so, and a
// damaged record stops the run with an error naming the case.

#include <array>
#include <cstdio>
#include <filesystem>
#include <map>
#include <set>
#include <string>

#include <gtest/gtest.h>

#include "app/case_knowledge.h"
#include "app/part.h"
#include "app/pipeline.h"
#include "core/atomic_file.h"
#include "core/json_io.h"
#include "core/log.h"
#include "kb/library.h"
#include "tests/support/starter_library.h"
#include "tests/support/test_dir.h"

namespace formloop::app {
namespace {

namespace fs = std::filesystem;
const fs::path kParts = fs::path(FORMLOOP_SOURCE_DIR) / "data" / "regress" / "parts";

bool Grouped(const Json& diagnosis, const std::string& a, const std::string& b) {
  for (const auto& g : diagnosis["alias_groups"]) {
    const std::string members = g["members"].dump();
    if (members.find(a) != std::string::npos && members.find(b) != std::string::npos) return true;
  }
  return false;
}

bool InAGroup(const Json& diagnosis, const std::string& effect) {
  for (const auto& g : diagnosis["alias_groups"]) {
    for (const auto& m : g["members"]) {
      if (m.get<std::string>().rfind(effect, 0) == 0) return true;
    }
  }
  return false;
}

bool Named(const Json& diagnosis, const std::string& effect) {
  for (const auto& c : diagnosis["causes"]) {
    if (c["effect"] == effect) return true;
  }
  return false;
}

std::string FileText(const fs::path& path) {
  const auto text = ReadFile(path);
  EXPECT_TRUE(text.ok()) << path;
  return text.ok() ? *text : std::string();
}

class PipelinePoolingRunTest : public ::testing::Test {
 protected:
  void SetUp() override {
    log::SetLevel(log::Level::kWarn);
    dir_ = testing::FreshTestDir("formloop-pooling-run");
    kb_ = dir_ / "kb.sqlite";
    fs::copy_file(testing::StarterLibrary(), kb_);
  }
  void TearDown() override { fs::remove_all(dir_); }

  // A regression part's surface on machine "vm-warm": the ball 6 µm undersize, every part clamped 10 µm
  // high; a 3 mm ball in H13 on every part, one cycle, 16 × 16 probes.
  Json PartJson(const std::string& from, const std::string& name, double feed_mm_per_min) const {
    Json j = ReadJsonFile(kParts / (from + ".json")).value();
    j["name"] = name;
    j["machine"] = {{"name", "vm-warm"},
                    {"effects",
                     {{"format", "formloop-model"},
                      {"version", 1},
                      {"effects",
                       {{{"name", "tool_radius"}, {"parameters", {{"delta_r_um", 6.0}}}},
                        {{"name", "setup_offset"}, {"parameters", {{"tx_um", 0.0}, {"ty_um", 0.0}, {"tz_um", 10.0}}}},
                        {{"name", "noise"}, {"parameters", {{"surface_sigma_um", 0.8}, {"probe_sigma_um", 0.5}}}}}}}}};
    j["material"] = "H13";
    j["tool"] = {{"number", 4}, {"radius_mm", 3.0}, {"flutes", 2}};
    j["tools"] = Json::array({{{"number", 4}, {"radius_mm", 3.0}}});
    j["toolpath"]["feed_mm_per_min"] = feed_mm_per_min;
    j["probing"] = {{"grid", {16, 16}}};
    j["loops"] = {{"max", 1}};
    return j;
  }
  Result<RunSummary> Run(const Json& part_json, const std::string& out, const fs::path& kb, int pool_cases,
                         bool retain) const {
    const fs::path file = dir_ / (out + ".json");
    EXPECT_TRUE(WriteJsonFile(file, part_json).ok());
    FL_ASSIGN_OR_RETURN(const PartSpec part, ReadPart(file));
    RunOptions o;
    o.out = dir_ / out;
    o.kb = kb.string();
    o.machine = "virtual";
    o.part_source = file.string();
    o.learn = false;  // each part cut as planned (no pre-compensation)
    o.pool_cases = pool_cases;
    o.retain = retain;
    o.report = false;
    return RunPart(part, o);
  }
  Json Diagnosis(const std::string& out) const {
    return ReadJsonFile(dir_ / out / "loop-0" / "diagnosis" / "diagnosis.json").value();
  }
  fs::path dir_, kb_;
};

TEST_F(PipelinePoolingRunTest, TheSecondPartPoolsTheFirstAndSplitsWhatNeitherCanAlone) {
  const auto first = Run(PartJson("reg-dome-a", "warm-dome", 1500), "first", kb_, 2, true);
  ASSERT_TRUE(first.ok()) << first.status().ToString();
  const Json d1 = Diagnosis("first");
  std::printf("first part: causes %s\ngroups %s\n", d1["causes"].dump().c_str(), d1["alias_groups"].dump().c_str());
  ASSERT_TRUE(d1.contains("pooled"));
  EXPECT_TRUE(d1["pooled"]["cases"].empty()) << "nothing to pool with yet";
  ASSERT_TRUE(Grouped(d1, "setup_offset", "tool_radius")) << "a shallow dome: z offset and tool radius alias";
  EXPECT_FALSE(Named(d1, "setup_offset"));
  {
    // The library holds the part record beside the case, keyed like the learned model.
    auto library = kb::Library::Open(kb_.string());
    ASSERT_TRUE(library.ok());
    const auto rows = (*library)->PartRecords("vm-warm", "ball r3", "H13");
    ASSERT_TRUE(rows.ok()) << rows.status().ToString();
    ASSERT_EQ(rows->size(), 1u);
    EXPECT_EQ((*rows)[0].case_uid, "warm-dome");
    EXPECT_EQ((*rows)[0].record["points"], 256);
  }
  const Json retain = ReadJsonFile(dir_ / "first" / "retain.json").value();
  EXPECT_EQ(retain["part_record"]["points"], 256);
  {
    // Only the same machine, tool and material pool: another machine, tool or material finds nothing.
    auto library = kb::Library::Open(kb_.string());
    ASSERT_TRUE(library.ok());
    for (const auto& [machine, tool, material] : std::vector<std::array<std::string, 3>>{
             {"vm-cold", "ball r3", "H13"}, {"vm-warm", "ball r2", "H13"}, {"vm-warm", "ball r3", "D2"}}) {
      const auto found = FindPooledCases(**library, machine, tool, material, "another-part", 2);
      ASSERT_TRUE(found.ok()) << found.status().ToString();
      EXPECT_TRUE(found->uids.empty()) << machine << " / " << tool << " / " << material;
      EXPECT_TRUE(found->report["not_pooled"].empty()) << found->report.dump();
    }
    // The part's own case is never pooled with itself.
    EXPECT_TRUE(FindPooledCases(**library, "vm-warm", "ball r3", "H13", "warm-dome", 2)->uids.empty());
  }

  // A library whose case has no part record (as one from before schema v3): not pooled, and said so.
  const fs::path old_kb = dir_ / "old.sqlite";
  fs::copy_file(kb_, old_kb);
  {
    auto library = kb::Library::Open(old_kb.string());
    ASSERT_TRUE(library.ok());
    ASSERT_TRUE((*library)->db()->Execute("DELETE FROM case_part_records;").ok());
  }
  const Json second_part = PartJson("reg-eggbox-a", "warm-eggbox", 1500);
  const auto alone = Run(second_part, "alone", old_kb, 2, false);
  ASSERT_TRUE(alone.ok()) << alone.status().ToString();
  const Json d_alone = Diagnosis("alone");
  std::printf("second part alone: causes %s\ngroups %s\n", d_alone["causes"].dump().c_str(),
              d_alone["alias_groups"].dump().c_str());
  EXPECT_TRUE(d_alone["pooled"]["cases"].empty());
  ASSERT_EQ(d_alone["pooled"]["not_pooled"].size(), 1u) << d_alone["pooled"].dump();
  EXPECT_EQ(d_alone["pooled"]["not_pooled"][0]["case"], "warm-dome");
  EXPECT_NE(d_alone["pooled"]["not_pooled"][0]["why"].get<std::string>().find("no part record"), std::string::npos);
  EXPECT_FALSE(Named(d_alone, "setup_offset")) << "the second part alone cannot name its set-up either";
  EXPECT_TRUE(InAGroup(d_alone, "setup_offset")) << d_alone["alias_groups"].dump();

  // Another material on the same machine and tool, with the first part in the library: not pooled.
  Json other_material = second_part;
  other_material["material"] = "D2";
  const auto other = Run(other_material, "other", kb_, 2, false);
  ASSERT_TRUE(other.ok()) << other.status().ToString();
  EXPECT_TRUE(other->pooled_cases.empty());
  const Json d_other = Diagnosis("other");
  EXPECT_TRUE(d_other["pooled"]["cases"].empty()) << d_other["pooled"].dump();
  EXPECT_FALSE(d_other.contains("parts")) << "diagnosed alone";

  // A library whose record of the first part is damaged: the run refuses, naming the library, the case
  // and the field, and leaves no run folder but the failed one.
  const fs::path bad_kb = dir_ / "bad.sqlite";
  fs::copy_file(kb_, bad_kb);
  {
    auto library = kb::Library::Open(bad_kb.string());
    ASSERT_TRUE(library.ok());
    ASSERT_TRUE((*library)
                    ->db()
                    ->Execute("UPDATE case_part_records SET record_json = json_remove(record_json, '$.d_radius');")
                    .ok());
  }
  {
    // `kb check` finds it first (PartRecordProblems); the good library has none.
    auto library = kb::Library::Open(bad_kb.string());
    ASSERT_TRUE(library.ok());
    const auto problems = PartRecordProblems(**library);
    ASSERT_TRUE(problems.ok()) << problems.status().ToString();
    ASSERT_EQ(problems->size(), 1u);
    EXPECT_NE((*problems)[0].find("case warm-dome (vm-warm / ball r3 / H13)"), std::string::npos) << (*problems)[0];
    EXPECT_NE((*problems)[0].find("d_radius"), std::string::npos) << (*problems)[0];
    auto good = kb::Library::Open(kb_.string());
    ASSERT_TRUE(good.ok());
    EXPECT_TRUE(PartRecordProblems(**good)->empty());
  }
  const auto bad = Run(second_part, "bad", bad_kb, 2, false);
  ASSERT_FALSE(bad.ok());
  const std::string message = bad.status().ToString();
  EXPECT_NE(message.find("bad.sqlite"), std::string::npos) << message;
  EXPECT_NE(message.find("case warm-dome"), std::string::npos) << message;
  EXPECT_NE(message.find("d_radius"), std::string::npos) << message;
  EXPECT_NE(message.find("--pool-cases 0"), std::string::npos) << message;
  EXPECT_FALSE(fs::exists(dir_ / "bad"));
  // With --pool-cases 0 the same library runs the part alone.
  const auto bad_alone = Run(second_part, "bad-alone", bad_kb, 0, false);
  ASSERT_TRUE(bad_alone.ok()) << bad_alone.status().ToString();
  EXPECT_FALSE(Diagnosis("bad-alone").contains("pooled"));

  // Pooled with the first part (its record from the library; the first run folder is gone).
  fs::remove_all(dir_ / "first");
  const fs::path before_second = dir_ / "before-second.sqlite";
  fs::copy_file(kb_, before_second);
  // It asks for the separating experiment (the library holds none yet: its plan is unchanged), so the run
  // proposes one for the next part.
  Json asking = second_part;
  asking["separating_experiment"] = "library";
  const auto second = Run(asking, "second", kb_, 2, true);
  ASSERT_TRUE(second.ok()) << second.status().ToString();
  EXPECT_EQ(second->pooled_cases, std::vector<std::string>{"warm-dome"});
  // The run folder's inputs name the record it pooled.
  const Json pooled_inputs = ReadJsonFile(dir_ / "second" / "inputs" / "pooled_cases.json").value();
  ASSERT_EQ(pooled_inputs["cases"].size(), 1u) << pooled_inputs.dump();
  EXPECT_EQ(pooled_inputs["cases"][0]["case"], "warm-dome");
  EXPECT_EQ(pooled_inputs["cases"][0]["points"], 256);
  EXPECT_EQ(pooled_inputs["cases"][0]["record_sha256"].get<std::string>().size(), 64u);
  EXPECT_EQ(pooled_inputs["key"]["machine"], "vm-warm");
  const Json d2 = Diagnosis("second");
  std::printf("second part pooled: causes %s\ngroups %s\n", d2["causes"].dump().c_str(),
              d2["alias_groups"].dump().c_str());
  EXPECT_EQ(d2["pooled"]["cases"], Json::array({"warm-dome"}));
  EXPECT_EQ(d2["parts"], Json::array({"warm-eggbox", "warm-dome"}));
  // Each part's set-up named, right within its interval; nothing named the machine lacks; the tool radius
  // (true) left only in a group with the probe radius, which parts probed along −n cannot split.
  std::set<std::string> set_up_parts;
  for (const auto& c : d2["causes"]) {
    ASSERT_EQ(c["effect"], "setup_offset") << c.dump() << " named falsely";
    set_up_parts.insert(c["part"].get<std::string>());
    for (const auto& [parameter, truth] :
         std::map<std::string, double>{{"tx_um", 0.0}, {"ty_um", 0.0}, {"tz_um", 10.0}}) {
      const Json& interval = c["interval_95"][parameter];
      EXPECT_LE(interval[0].get<double>(), truth) << parameter << " " << c.dump();
      EXPECT_GE(interval[1].get<double>(), truth) << parameter << " " << c.dump();
    }
    EXPECT_NEAR(c["parameters"]["tz_um"].get<double>(), 10.0, 2.0) << c.dump();
  }
  EXPECT_EQ(set_up_parts, (std::set<std::string>{"warm-eggbox", "warm-dome"})) << d2["causes"].dump();
  EXPECT_TRUE(InAGroup(d2, "tool_radius")) << d2["alias_groups"].dump();
  EXPECT_FALSE(InAGroup(d2, "setup_offset")) << d2["alias_groups"].dump();
  EXPECT_FALSE(InAGroup(d2, "thermal_drift_z")) << d2["alias_groups"].dump();
  // The separating experiment for the next part is designed on the pooled diagnosis: one proposal per
  // group the two parts leave, the same members (the egg box alone would group its z offset with a
  // thermal drift, a group pooling has split), and the radii are predicted to be split by it.
  const Json proposals = ReadJsonFile(dir_ / "second" / "loop-0" / "diagnosis" / "proposals.json").value();
  std::printf("second part's proposals: %s\n", proposals.dump().substr(0, 2000).c_str());
  ASSERT_EQ(proposals["proposals"].size(), d2["alias_groups"].size()) << proposals.dump();
  for (std::size_t g = 0; g < d2["alias_groups"].size(); ++g) {
    EXPECT_EQ(proposals["proposals"][g]["alias_group"], d2["alias_groups"][g]["members"]);
    EXPECT_TRUE(proposals["proposals"][g]["predicted_to_split"].get<bool>()) << proposals["proposals"][g].dump();
  }

  // Reproducible: the same part, library (as it was before the second run) and options give the same
  // diagnosis and record the same pooled inputs, byte for byte.
  fs::remove(kb_);
  fs::copy_file(before_second, kb_);
  const auto again = Run(asking, "again", kb_, 2, true);
  ASSERT_TRUE(again.ok()) << again.status().ToString();
  EXPECT_EQ(FileText(dir_ / "second" / "loop-0" / "diagnosis" / "diagnosis.json"),
            FileText(dir_ / "again" / "loop-0" / "diagnosis" / "diagnosis.json"));
  EXPECT_EQ(FileText(dir_ / "second" / "inputs" / "pooled_cases.json"),
            FileText(dir_ / "again" / "inputs" / "pooled_cases.json"));
  EXPECT_EQ(FileText(dir_ / "second" / "loop-0" / "diagnosis" / "proposals.json"),
            FileText(dir_ / "again" / "loop-0" / "diagnosis" / "proposals.json"));
}

}  // namespace
}  // namespace formloop::app
