// Which case's separating experiments `formloop run` applies with separating_experiment: "library"
// (app/case_knowledge.h, StoredSeparatingExperiments): the retrieved case's when it holds some for the
// machine/tool/material, else the most recently updated case's — its diagnosis saw the most of the
// machine — not the first by uid. A case of another key is never taken.

#include <string>

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include "app/case_knowledge.h"
#include "kb/library.h"
#include "kb/schema.h"
#include "simulation/proposal_plan.h"
#include "tests/support/test_dir.h"

namespace formloop::app {
namespace {

using Json = nlohmann::json;

// A case whose learned model for `machine` / ball r3 / H13 holds one raster-turn proposal of `turn_deg`.
Json CaseLine(const std::string& uid, const std::string& machine, double turn_deg, const std::string& updated_at) {
  sim::PlannedProposal p;
  p.members = {"thermal_drift_z", "tool_wear"};
  p.kind = "raster_turn";
  p.raster_turn_deg = turn_deg;
  Json c = {{"uid", uid},
            {"name", uid},
            {"family", "freeform"},
            {"part", {{"material", "H13"}}},
            {"simulation",
             {{"effect_models",
               Json::array({{{"machine", machine},
                             {"tool", "ball r3"},
                             {"material", "H13"},
                             {"separating_experiments", Json::array({p.ToJson()})}}})}}},
            {"manufacturing", Json::object()},
            {"created_at", "2026-11-01T00:00:00.000Z"},
            {"updated_at", updated_at}};
  return {{"type", "case"}, {"case", c}};
}

class StoredExperimentsTest : public ::testing::Test {
 protected:
  void SetUp() override {
    const std::string path = (testing::FreshTestDir("stored_experiments") / "library.db").string();
    ASSERT_TRUE(kb::InitLibrary(path).ok());
    auto opened = kb::Library::Open(path);
    ASSERT_TRUE(opened.ok()) << opened.status().ToString();
    library_ = std::move(*opened);
    // "a-old" sorts first by uid and was updated first; "b-new" later; "c-other" is the newest, of
    // another machine.
    std::string text = Json{{"format", kb::kExportFormatName},
                            {"format_version", kb::kExportFormatVersion},
                            {"schema_version", kb::LatestSchemaVersion()}}
                           .dump() +
                       "\n";
    text += CaseLine("a-old", "vm-1", 10, "2026-11-02T08:00:00.000Z").dump() + "\n";
    text += CaseLine("b-new", "vm-1", 20, "2026-11-20T08:00:00.000Z").dump() + "\n";
    text += CaseLine("c-other", "vm-2", 30, "2026-11-25T08:00:00.000Z").dump() + "\n";
    const auto imported = library_->ImportText(text, "cases.jsonl");
    ASSERT_TRUE(imported.ok()) << imported.status().ToString();
    ASSERT_EQ(imported->cases_added, 3u);
  }
  // The proposals taken for vm-1 / ball r3 / H13 with `preferred` retrieved: from which case, and the
  // raster turn of its one proposal.
  void ExpectTaken(const std::string& preferred, const std::string& uid, double turn_deg) {
    std::string from;
    const auto got = StoredSeparatingExperiments(*library_, "vm-1", "ball r3", "H13", preferred, &from);
    ASSERT_TRUE(got.ok()) << got.status().ToString();
    ASSERT_EQ(got->size(), 1u);
    EXPECT_EQ(from, uid) << "retrieved " << preferred;
    EXPECT_DOUBLE_EQ(got->front().raster_turn_deg, turn_deg) << "retrieved " << preferred;
  }
  std::unique_ptr<kb::Library> library_;
};

TEST_F(StoredExperimentsTest, TheNewestCaseOfTheKeyWhenTheRetrievedOneHoldsNone) {
  ExpectTaken("not-in-library", "b-new", 20);
}

TEST_F(StoredExperimentsTest, TheRetrievedCaseFirst) {
  ExpectTaken("a-old", "a-old", 10);
  // The retrieved case of another machine holds none for vm-1: the newest of vm-1's.
  ExpectTaken("c-other", "b-new", 20);
}

TEST_F(StoredExperimentsTest, NoneForAnotherKey) {
  std::string from = "unchanged";
  const auto got = StoredSeparatingExperiments(*library_, "vm-1", "ball r3", "Ti-6Al-4V", "", &from);
  ASSERT_TRUE(got.ok()) << got.status().ToString();
  EXPECT_TRUE(got->empty());
  EXPECT_EQ(from, "unchanged");
}

}  // namespace
}  // namespace formloop::app
