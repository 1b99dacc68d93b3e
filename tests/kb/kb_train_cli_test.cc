// `formloop kb init --starter` → `kb train` → `formloop retrieve` → `kb add` (incremental GHSOM insertion) →
// `kb check` / `kb calibrate`, through the binary. Skipped when the binary has not been built.

#include <csignal>
#include <cstdio>
#include <filesystem>
#include <string>

#include <fcntl.h>
#include <sys/wait.h>
#include <unistd.h>

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include "tests/kb/kb_fixtures.h"
#include "tests/support/run_binary.h"

namespace formloop::kb {
namespace {

using testing::KbLibraryTest;
using testing::WriteBytes;
namespace fs = std::filesystem;

class KbTrainCliTest : public KbLibraryTest {
 protected:
  void SetUp() override {
    if (!fs::exists(FORMLOOP_BINARY)) GTEST_SKIP() << "formloop binary not built: " << FORMLOOP_BINARY;
    KbLibraryTest::SetUp();
  }
  std::string P(const std::string& name) const { return (dir_ / name).string(); }
  int Run(const std::string& args) { return formloop::testing::RunFormloop("--quiet " + args, &out_, &err_); }
  nlohmann::json Out() const { return nlohmann::json::parse(out_); }
  std::string out_, err_;
};

TEST_F(KbTrainCliTest, StarterTrainRetrieveAddCheck) {
  const std::string db = P("starter.db");
  ASSERT_EQ(Run("kb init " + db + " --starter"), 0) << err_;
  const auto init = Out();
  EXPECT_GE(init["starter"]["cases"].get<int>(), 200);
  EXPECT_GE(init["starter"]["families"].get<int>(), 8);
  EXPECT_GT(init["starter"]["ghsom"]["ghsom_id"].get<int>(), 0);
  // A second --starter on a filled library is refused.
  EXPECT_EQ(Run("kb init " + db + " --starter"), 2) << err_;

  ASSERT_EQ(Run("kb train " + db + " --tau1 0.3 --seed 7"), 0) << err_;
  const auto train = Out();
  EXPECT_EQ(train["cases"].get<int>(), init["starter"]["cases"].get<int>());
  ASSERT_TRUE(train["quality"]["maps"].is_array());
  EXPECT_TRUE(train["quality"]["maps"][0].contains("qe"));
  EXPECT_TRUE(train["quality"]["maps"][0].contains("te"));
  EXPECT_TRUE(train["quality"]["maps"][0].contains("mqe"));
  ASSERT_EQ(Run("kb check " + db), 0) << err_ << out_;
  EXPECT_FALSE(Out()["ghsom"]["stale"].get<bool>());

  // A query of the dome family, given by its surface parameters.
  WriteBytes(dir_ / "query.json",
             nlohmann::json{{"name", "dome query"},
                            {"shape_family", "sphere_cap"},
                            {"material", "H13"},
                            {"tolerance_mm", 0.01},
                            {"finish_ra_um", 0.3},
                            {"machine_class", "3-axis"},
                            {"tool_radius_mm", 4},
                            {"surface", {{"kind", "sphere_cap"}, {"params", {{"size_mm", 90}, {"radius_ratio", 1.4}}}}}}
                 .dump(2));
  ASSERT_EQ(Run("retrieve --library " + db + " --part " + P("query.json") + " --top 3"), 0) << err_;
  const auto r = Out();
  ASSERT_TRUE(r["route"]["name"].is_string());
  const std::string route = r["route"]["name"];
  EXPECT_TRUE(route == "direct" || route == "simulate" || route == "default") << route;
  ASSERT_EQ(r["ranked"].size(), 3u);
  EXPECT_EQ(r["ranked"][0]["family"], "dome");
  EXPECT_TRUE(r["ranked"][0]["facets"].is_array());

  // An existing case as the query (kb show output) finds itself with A = 1 → direct.
  ASSERT_EQ(Run("kb show " + db + " pocket-003"), 0) << err_;
  WriteBytes(dir_ / "case.json", out_);
  ASSERT_EQ(Run("retrieve --library " + db + " --part " + P("case.json") + " --top 1"), 0) << err_;
  EXPECT_EQ(Out()["ranked"][0]["uid"], "pocket-003");
  EXPECT_GE(Out()["route"]["similarity"].get<double>(), 0.99);
  EXPECT_EQ(Out()["route"]["name"], "direct");

  // kb add of a new case while the GHSOM is current: inserted, still current.
  auto c = nlohmann::json::parse(testing::ReadBytes(dir_ / "case.json"));
  c["uid"] = "pocket-new";
  c.erase("created_at");
  c.erase("updated_at");
  WriteBytes(dir_ / "new.json", c.dump());
  ASSERT_EQ(Run("kb add " + db + " " + P("new.json")), 0) << err_;
  EXPECT_TRUE(Out()["ghsom"]["inserted"].get<bool>()) << out_;
  ASSERT_EQ(Run("kb check " + db), 0) << err_ << out_;
  ASSERT_EQ(Run("retrieve --library " + db + " --part " + P("new.json") + " --top 2"), 0) << err_;
  EXPECT_EQ(Out()["library"]["cases_not_in_ghsom"], 0);

  // A removal makes the GHSOM stale: check reports it (a warning, ghsom.stale) until kb train.
  ASSERT_EQ(Run("kb remove " + db + " pocket-new"), 0) << err_;
  EXPECT_EQ(Run("kb check " + db), 0);
  EXPECT_TRUE(Out()["ghsom"]["stale"].get<bool>());
  ASSERT_EQ(Run("kb train " + db), 0) << err_;
  EXPECT_EQ(Run("kb check " + db), 0) << out_;

  ASSERT_EQ(Run("kb calibrate " + db), 0) << err_;
  const auto cal = Out();
  EXPECT_EQ(cal["retrieval"]["cases"].get<int>(), init["starter"]["cases"].get<int>());
  EXPECT_TRUE(cal["retrieval"]["routes"].contains("direct"));
  EXPECT_TRUE(cal["retrieval"]["confusion"].is_object());
  EXPECT_EQ(cal["outcomes"]["cases_without_pipeline_outcome"].get<int>(), init["starter"]["cases"].get<int>());
  EXPECT_FALSE(cal.contains("rerun")) << "only with --rerun";
  // A big library is sampled: at most --max-cases left out, evenly spaced, each with its own training.
  ASSERT_EQ(Run("kb calibrate " + db + " --max-cases 7"), 0) << err_;
  const auto sampled = Out();
  EXPECT_EQ(sampled["retrieval"]["cases"].get<int>(), 7);
  EXPECT_EQ(sampled["retrieval"]["library_cases"].get<int>(), init["starter"]["cases"].get<int>());
  ASSERT_EQ(sampled["retrieval"]["per_case"].size(), 7u);
  EXPECT_EQ(sampled["retrieval"]["per_case"][0]["uid"], cal["retrieval"]["per_case"][0]["uid"]);
}

TEST_F(KbTrainCliTest, RetrieveRefusesUntrainedLibrary) {
  const std::string db = P("empty.db");
  ASSERT_EQ(Run("kb init " + db), 0) << err_;
  WriteBytes(dir_ / "q.json", R"({"shape_family":"saddle","material":"H13","tolerance_mm":0.02,"finish_ra_um":1,
    "machine_class":"5-axis","tool_radius_mm":3,"surface":{"reference":"saddle"}})");
  EXPECT_EQ(Run("retrieve --library " + db + " --part " + P("q.json")), 1);
  EXPECT_NE(err_.find("kb train"), std::string::npos) << err_;
  EXPECT_EQ(Run("kb train " + db), 2);  // no cases
}

// `kb train` SIGKILLed at increasing moments of its run (from the first milliseconds to after it has
// finished): every time the library opens, `kb check` is clean, no case is lost and a GHSOM loads.
TEST_F(KbTrainCliTest, TrainKilledAtAnyMomentLeavesACleanLibrary) {
  const std::string db = P("killed.db");
  ASSERT_EQ(Run("kb init " + db + " --starter"), 0) << err_;
  const int cases = Out()["starter"]["cases"].get<int>();
  int killed_while_running = 0;
  for (int delay_ms : {5, 20, 50, 100, 200, 400, 800}) {
    const pid_t child = ::fork();
    ASSERT_GE(child, 0);
    if (child == 0) {
      const int null = ::open("/dev/null", O_WRONLY);
      ::dup2(null, 1);
      ::dup2(null, 2);
      ::execl(FORMLOOP_BINARY, FORMLOOP_BINARY, "kb", "train", db.c_str(), "--seed",
              std::to_string(1000 + delay_ms).c_str(), static_cast<char*>(nullptr));
      ::_exit(127);
    }
    ::usleep(static_cast<useconds_t>(delay_ms) * 1000);
    int status = 0;
    if (::waitpid(child, &status, WNOHANG) == 0) {
      ASSERT_EQ(::kill(child, SIGKILL), 0);
      ++killed_while_running;
    }
    ::waitpid(child, &status, 0);
    ASSERT_EQ(Run("kb check " + db), 0) << "after " << delay_ms << " ms: " << out_;
    EXPECT_TRUE(Out()["clean"].get<bool>());
    EXPECT_TRUE(Out()["ghsom"]["present"].get<bool>()) << out_;
    ASSERT_EQ(Run("kb stats " + db), 0) << err_;
    EXPECT_EQ(Out()["cases"].get<int>(), cases) << out_;
  }
  std::printf("kb train killed while running in %d of 7 tries\n", killed_while_running);
  EXPECT_GE(killed_while_running, 1);
}

}  // namespace
}  // namespace formloop::kb
