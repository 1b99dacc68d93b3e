// `formloop tune` → `formloop link write` end to end (the write plan of /work/wt/WRITE_PLAN.md between tuning/
// and cnc/): the plan tune writes is read by link write's own parser (cnc::ReadWritePlan) field for field, for
// every status tune can give; a confirmed SAFE plan is written by `formloop link write` to an emulated
// controller (`formloop link emulate`, a separate process) and read back; the same plan applied a second time
// is refused (OFFSET_CHANGED); an unconfirmed plan and a plan whose offset would pass its limit are refused
// with nothing sent.

#include <filesystem>
#include <map>
#include <string>
#include <vector>

#include <gtest/gtest.h>

#include "cnc/write_back.h"
#include "core/atomic_file.h"
#include "core/json_io.h"
#include "tests/cnc/process_support.h"
#include "tests/support/run_binary.h"
#include "tests/support/test_dir.h"

namespace formloop::app {
namespace {

namespace fs = std::filesystem;
using cnc::testing::ProcessGuard;
using cnc::testing::SpawnFormloop;
using cnc::testing::StartEmulator;
using cnc::testing::WaitFor;

const std::string kData = std::string(FORMLOOP_SOURCE_DIR) + "/data/tuning/bracket/";

class TuneLinkTest : public ::testing::Test {
 protected:
  void SetUp() override { dir_ = formloop::testing::FreshTestDir("formloop-tune-link"); }
  void TearDown() override { fs::remove_all(dir_); }

  // Runs `formloop tune` on the bracket; returns the exit code.
  int Tune(const std::string& out, const std::string& extra, const std::string& offsets = kData + "offsets.json") {
    std::string stdout_text, stderr_text;
    const std::string args = "tune --model " + kData + "model.json --points " + kData + "points.csv --block " + kData +
                             "block.csv" + (offsets.empty() ? "" : " --offsets " + offsets) + " --out " +
                             (dir_ / out).string() + " " + extra;
    return formloop::testing::RunFormloop(args, &stdout_text, &stderr_text);
  }

  fs::path dir_;
};

// Every write tune puts in its plan comes out of link write's parser with the same values and the controller
// address its kind, tool, wcs and axis give.
void ExpectSameWrites(const Json& tuned, const cnc::WritePlan& read) {
  ASSERT_EQ(tuned["writes"].size(), read.writes.size());
  const std::map<std::string, std::string> address = {
      {"T3_radius_wear", "T3.radius_wear"}, {"T5_length_wear", "T5.length_wear"}, {"G54_X", "G54.X"}};
  for (std::size_t k = 0; k < read.writes.size(); ++k) {
    const Json& w = tuned["writes"][k];
    const cnc::PlannedWrite& r = read.writes[k];
    SCOPED_TRACE(r.offset);
    EXPECT_EQ(r.offset, w["offset"].get<std::string>());
    EXPECT_EQ(r.address.ToString(), address.at(r.offset));
    EXPECT_EQ(r.previous_mm, w["previous_mm"].get<double>());
    EXPECT_EQ(r.delta_mm, w["delta_mm"].get<double>());
    EXPECT_EQ(r.new_mm, w["new_mm"].get<double>());
    EXPECT_EQ(r.resolution_mm, w["resolution_mm"].get<double>());
    EXPECT_EQ(r.baseline_mm, w["baseline_mm"].get<double>());
    EXPECT_EQ(r.limit_mm, w["limit_mm"].get<double>());
    EXPECT_FALSE(r.step_limit_mm.has_value());  // the bracket gives none; tune writes null
    EXPECT_NEAR(r.previous_mm + r.delta_mm, r.new_mm, 1e-12);
  }
}

TEST_F(TuneLinkTest, EveryPlanTuneWritesIsAcceptedByLinkWritesParser) {
  // SAFE and confirmed (wls), SAFE waiting for --confirm, the average strategy, BLOCKED without the current offsets.
  ASSERT_EQ(Tune("confirmed", "--confirm"), 0);
  ASSERT_EQ(Tune("unconfirmed", ""), 0);
  const int average = Tune("average", "--strategy average --confirm");
  ASSERT_TRUE(average == 0 || average == 1);
  ASSERT_EQ(Tune("blocked", "--confirm", ""), 1);
  for (const char* name : {"confirmed", "unconfirmed", "average", "blocked"}) {
    SCOPED_TRACE(name);
    const fs::path path = dir_ / name / "offsets.json";
    const auto tuned = ReadJsonFile(path);
    ASSERT_TRUE(tuned.ok()) << tuned.status().ToString();
    const auto read = cnc::ReadWritePlan(path);
    ASSERT_TRUE(read.ok()) << read.status().ToString();
    EXPECT_EQ(read->status, (*tuned)["status"].get<std::string>());
    EXPECT_EQ(read->confirmed, (*tuned)["confirmed"].get<bool>());
    EXPECT_EQ(read->session, (*tuned)["session"].get<std::string>());
    EXPECT_EQ(read->blocked_reasons.size(), (*tuned)["blocked_reasons"].size());
    ExpectSameWrites(*tuned, *read);
  }
  EXPECT_EQ(cnc::ReadWritePlan(dir_ / "confirmed/offsets.json")->writes.size(), 3u);
  EXPECT_TRUE(cnc::ReadWritePlan(dir_ / "confirmed/offsets.json")->confirmed);
  EXPECT_FALSE(cnc::ReadWritePlan(dir_ / "unconfirmed/offsets.json")->confirmed);
  EXPECT_EQ(cnc::ReadWritePlan(dir_ / "blocked/offsets.json")->status, "BLOCKED");
  EXPECT_TRUE(cnc::ReadWritePlan(dir_ / "blocked/offsets.json")->writes.empty());
}

TEST_F(TuneLinkTest, ConfirmedPlanIsWrittenToTheControllerAndReadBack) {
  ASSERT_EQ(Tune("confirmed", "--confirm"), 0);
  ASSERT_EQ(Tune("unconfirmed", ""), 0);
  // Current offsets near T3's limit (0.1 mm from baseline 0): its change (−0.004 mm) would pass it, so tune stops at
  // RECHECK with no writes.
  Json near = *ReadJsonFile(kData + "offsets.json");
  near["values_mm"]["T3_radius_wear"] = -0.099;
  ASSERT_TRUE(WriteJsonFile(dir_ / "near_limit.json", near).ok());
  ASSERT_EQ(Tune("recheck", "--confirm", (dir_ / "near_limit.json").string()), 1);
  const Json recheck = *ReadJsonFile(dir_ / "recheck/offsets.json");
  ASSERT_EQ(recheck["status"], "RECHECK");
  ASSERT_TRUE(recheck["writes"].empty());

  // The controller holds the offsets tune was given as current (data/tuning/bracket/offsets.json).
  ProcessGuard guard;
  pid_t emulator = -1;
  const std::string address =
      StartEmulator(dir_,
                    {"--points", "1", "--start-delay-s", "1e6", "--offset", "T3.radius_wear=0.012", "--offset",
                     "T5.length_wear=-0.004", "--offset", "G54.X=-250.003", "--max-run-s", "120"},
                    &guard, &emulator);
  ASSERT_FALSE(address.empty()) << "the emulator did not start";
  const auto write = [&](const fs::path& plan, Json* report) {
    fs::remove(dir_ / "write.out");
    const pid_t p =
        SpawnFormloop({"link", "write", "--address", address, "--plan", plan.string(), "--confirm", "--quiet"},
                      dir_ / "write.out", dir_ / "write.err");
    guard.pids.push_back(p);
    const int code = WaitFor(p, 60);
    const auto text = ReadFile(dir_ / "write.out");
    *report = text.ok() && !text->empty() ? Json::parse(*text) : Json();
    return code;
  };
  const auto item = [](const Json& report, const std::string& offset_address) {
    for (const auto& o : report["offsets"]) {
      if (o["address"] == offset_address) return o;
    }
    return Json();
  };
  Json r;
  // Not confirmed in tune, or not SAFE: refused by the writer, nothing read or sent.
  EXPECT_EQ(write(dir_ / "unconfirmed/offsets.json", &r), 1);
  EXPECT_EQ(r["outcome"], "REFUSED");
  EXPECT_NE(r["reasons"].dump().find("confirmed: false"), std::string::npos) << r.dump();
  EXPECT_FALSE(item(r, "T3.radius_wear").contains("read_before_mm"));
  EXPECT_EQ(write(dir_ / "recheck/offsets.json", &r), 1);
  EXPECT_EQ(r["outcome"], "REFUSED");
  EXPECT_NE(r["reasons"].dump().find("RECHECK"), std::string::npos) << r.dump();

  // The confirmed SAFE plan: every offset written and read back as planned.
  const Json plan = *ReadJsonFile(dir_ / "confirmed/offsets.json");
  ASSERT_EQ(write(dir_ / "confirmed/offsets.json", &r), 0) << r.dump();
  EXPECT_EQ(r["outcome"], "WRITTEN");
  std::map<std::string, double> planned;
  for (const auto& w : plan["writes"]) {
    const std::string a = w["kind"] == "WORK_OFFSET"
                              ? w["wcs"].get<std::string>() + "." + w["axis"].get<std::string>()
                              : "T" + std::to_string(w["tool"].get<int>()) +
                                    (w["kind"] == "TOOL_RADIUS_WEAR" ? ".radius_wear" : ".length_wear");
    planned[a] = w["new_mm"].get<double>();
    const Json o = item(r, a);
    ASSERT_FALSE(o.is_null()) << a;
    EXPECT_TRUE(o["written"].get<bool>()) << a;
    EXPECT_NEAR(o["read_back_mm"].get<double>(), w["new_mm"].get<double>(), 1e-12) << a;
  }
  ASSERT_EQ(planned.size(), 3u);

  // The same plan again: the controller no longer holds its previous values, so nothing is written twice.
  EXPECT_EQ(write(dir_ / "confirmed/offsets.json", &r), 1);
  EXPECT_EQ(r["outcome"], "OFFSET_CHANGED");

  ::kill(emulator, SIGTERM);
  EXPECT_NE(WaitFor(emulator, 10), -1);
  const auto summary = Json::parse(*ReadFile(dir_ / "emulate.out"));
  for (const auto& [a, value] : planned) EXPECT_NEAR(summary["offsets_mm"][a].get<double>(), value, 1e-12) << a;
}

}  // namespace
}  // namespace formloop::app
