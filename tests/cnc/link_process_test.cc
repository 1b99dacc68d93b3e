// The link between real processes over loopback TCP: `formloop link emulate` as its own process (a
// free port per test, latency with jitter, fault injection) and `formloop link collect` as another,
// killed with SIGKILL at random moments at least 20 times during one collection of 10,000 points and
// restarted from its journal each time. Every point must arrive exactly once, in order, with the data
// bit for bit as the emulator's own record has it. Also the CLI's write-back against the emulator
// (limit refusal, OFFSET_CHANGED, an injected read-back mismatch rolled back) and a protocol error.

#include <gtest/gtest.h>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <map>
#include <set>
#include <sstream>
#include <thread>

#include "cnc/controller.h"
#include "core/json_io.h"
#include "core/point_io.h"
#include "core/random.h"
#include "metrology/probe.h"
#include "tests/cnc/process_support.h"
#include "tests/support/test_dir.h"

namespace formloop::cnc {
namespace {

using testing::KillAndReap;
using testing::ProcessGuard;
using testing::SpawnFormloop;
using testing::StartEmulator;
using testing::WaitFor;

std::vector<std::vector<std::string>> ReadCsv(const std::filesystem::path& path) {
  std::ifstream in(path);
  std::vector<std::vector<std::string>> rows;
  std::string line;
  while (std::getline(in, line) && line.rfind('#', 0) == 0) continue;  // formloop's marker; `line` = the header
  while (std::getline(in, line)) {
    std::vector<std::string> cells;
    std::stringstream s(line);
    std::string cell;
    while (std::getline(s, cell, ',')) cells.push_back(cell);
    if (!line.empty() && line.back() == ',') cells.push_back("");
    rows.push_back(cells);
  }
  return rows;
}

class LinkProcessTest : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = formloop::testing::FreshTestDir("formloop-link-process");
    // The journal lives in RAM when it can: the test is about kills, not the disk's fsync latency.
    shm_ = std::filesystem::exists("/dev/shm") ? std::filesystem::path("/dev/shm") / dir_.filename() : dir_;
    std::filesystem::create_directories(shm_);
  }
  void TearDown() override {
    std::filesystem::remove_all(dir_);
    std::filesystem::remove_all(shm_);
  }
  std::filesystem::path dir_, shm_;
};

TEST_F(LinkProcessTest, TenThousandPointsWithTwentyCollectorKillsAcrossProcesses) {
  ProcessGuard guard;
  pid_t emulator = -1;
  const std::string address = StartEmulator(dir_,
                                            {"--points",
                                             "2000",
                                             "--runs",
                                             "5",
                                             "--seed",
                                             "2026",
                                             "--latency-ms",
                                             "0.1",
                                             "--jitter-ms",
                                             "0.05",
                                             "--dwell-ms",
                                             "1",
                                             "--measure-ms",
                                             "0.5",
                                             "--visibility-ms",
                                             "1",
                                             "--reorder-rate",
                                             "0.05",
                                             "--api-error-rate",
                                             "0.01",
                                             "--drop-write-rate",
                                             "0.002",
                                             "--drop-connection-rate",
                                             "0.0005",
                                             "--half-open-rate",
                                             "0.0002",
                                             "--torn-reads",
                                             "--repeat-rate",
                                             "0.001",
                                             "--ack-timeout-s",
                                             "30",
                                             "--arm-timeout-s",
                                             "120",
                                             "--record",
                                             (dir_ / "record.csv").string(),
                                             "--linger-s",
                                             "2",
                                             "--max-run-s",
                                             "400"},
                                            &guard, &emulator);
  ASSERT_FALSE(address.empty()) << "the emulator did not start";
  const std::vector<std::string> collect = {"link",
                                            "collect",
                                            "--address",
                                            address,
                                            "--out",
                                            (dir_ / "P.csv").string(),
                                            "--journal",
                                            (shm_ / "P.journal").string(),
                                            "--expect",
                                            "2000",
                                            "--runs",
                                            "5",
                                            "--poll-ms",
                                            "0.5",
                                            "--visibility-timeout-s",
                                            "0.1",
                                            "--reconnect-min-s",
                                            "0.02",
                                            "--reconnect-max-s",
                                            "0.2",
                                            "--call-timeout-s",
                                            "0.2",
                                            "--idle-timeout-s",
                                            "60",
                                            "--quiet"};
  Rng rng(20);
  int kills = 0, active_kills = 0, exit_code = -1;
  const auto start = std::chrono::steady_clock::now();
  for (int attempt = 0; attempt < 200; ++attempt) {
    const pid_t collector = SpawnFormloop(collect, dir_ / "collect.out", dir_ / "collect.err");
    ASSERT_GT(collector, 0);
    guard.pids.push_back(collector);
    if (kills < 22) {
      // Wait until this collector stores points (its journal grows; the binary takes ~0.25 s to load),
      // then kill it at a random moment of its work.
      const auto journal = shm_ / "P.journal";
      const auto size = [&] { return std::filesystem::exists(journal) ? std::filesystem::file_size(journal) : 0; };
      const auto before = size();
      for (int k = 0; k < 1000 && size() == before; ++k) std::this_thread::sleep_for(std::chrono::milliseconds(5));
      exit_code = WaitFor(collector, rng.Uniform(0.0, 0.4));
      if (exit_code == -1) {
        const auto at_kill = size();
        KillAndReap(collector);
        ++kills;
        active_kills += at_kill > before ? 1 : 0;
        continue;
      }
      break;
    }
    exit_code = WaitFor(collector, 300);
    break;
  }
  const double seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  EXPECT_EQ(exit_code, 0);
  EXPECT_GE(kills, 20);
  EXPECT_GE(active_kills, 20);  // each killed while it was storing points
  EXPECT_EQ(WaitFor(emulator, 30), 0) << "the emulator did not finish its runs cleanly";
  // The emulator's record (run, q, id, data, deviations) against what the collector stored.
  const auto record = ReadCsv(dir_ / "record.csv");
  const auto stored = ReadCsv(dir_ / "P.csv");
  std::map<std::string, std::vector<std::pair<int, std::string>>> by_q;  // q → (id, D) first copies
  std::map<std::string, std::set<int>> seen;
  for (const auto& r : record) {
    if (seen[r[1]].insert(std::stoi(r[2])).second) by_q[r[1]].push_back({std::stoi(r[2]), r[3]});
  }
  ASSERT_EQ(by_q.size(), 5u);
  std::map<std::string, std::vector<std::pair<int, std::string>>> got;
  for (const auto& s : stored) {
    EXPECT_EQ(s[2], "COMPLETE");
    got[s[1]].push_back({std::stoi(s[3]), s[4]});
  }
  long points = 0, mismatches = 0;
  for (const auto& [q, expected] : by_q) {
    ASSERT_EQ(got[q].size(), 2000u) << "run Q=" << q;
    for (std::size_t k = 0; k < 2000; ++k) {
      EXPECT_EQ(got[q][k].first, static_cast<int>(k) + 1);
      mismatches += got[q][k] != expected[k] ? 1 : 0;
      ++points;
    }
  }
  EXPECT_EQ(points, 10000);
  EXPECT_EQ(mismatches, 0);
  std::printf(
      "10,000 points over TCP between processes: %d SIGKILLs of the collector (%d while it was storing points), %.1f s "
      "wall, %zu handovers recorded (repeats included)\n",
      kills, active_kills, seconds, record.size());
  std::ifstream summary(dir_ / "emulate.out");
  std::string line;
  while (std::getline(summary, line)) {
    if (line.find("faults_injected") != std::string::npos || line.find("\": ") != std::string::npos) {
      if (line.find("rate") == std::string::npos) std::printf("  emulator: %s\n", line.c_str());
    }
  }
}

// Write-back through the CLI against the emulator: a value beyond its limit is never sent; an offset
// that moved since the measurement aborts before writing; an injected read-back mismatch is detected,
// reported and everything written is rolled back; a clean plan is written and verified.
TEST_F(LinkProcessTest, WriteBackRefusesRollsBackAndWrites) {
  ProcessGuard guard;
  pid_t emulator = -1;
  const std::string address = StartEmulator(
      dir_,
      {"--points", "1", "--start-delay-s", "1e6", "--offset", "T3.radius_wear=0.085", "--offset",
       "T5.length_wear=-0.02", "--offset", "G54.X=-120.5", "--offset-mismatch", "G54.X=0.004", "--max-run-s", "60"},
      &guard, &emulator);
  ASSERT_FALSE(address.empty());
  const auto plan = [&](const std::string& name, const std::string& status, bool confirmed, const std::string& writes) {
    const auto path = dir_ / (name + ".json");
    std::ofstream(path) << R"({"format": "formloop.offset_write_plan", "version": 1, "session": "test", "status": ")"
                        << status << R"(", "blocked_reasons": [], "confirmed": )" << (confirmed ? "true" : "false")
                        << R"(, "not_reachable_acknowledged": [], "extra_field_from_tuning": 1, "writes": [)" << writes
                        << "]}";
    return path.string();
  };
  const std::string t3_ok =
      R"({"offset": "T3_radius_wear", "kind": "TOOL_RADIUS_WEAR", "tool": 3, "previous_mm": 0.085, "delta_mm": 0.010,
          "new_mm": 0.095, "resolution_mm": 0.001, "baseline_mm": 0.0, "limit_mm": 0.1, "step_limit_mm": null})";
  const std::string t3_over =
      R"({"offset": "T3_radius_wear", "kind": "TOOL_RADIUS_WEAR", "tool": 3, "previous_mm": 0.085, "delta_mm": 0.020,
          "new_mm": 0.105, "resolution_mm": 0.001, "baseline_mm": 0.0, "limit_mm": 0.1})";
  const std::string t5_ok =
      R"({"offset": "T5_length_wear", "kind": "TOOL_LENGTH_WEAR", "tool": 5, "previous_mm": -0.02, "delta_mm": -0.005,
          "new_mm": -0.025, "resolution_mm": 0.001, "baseline_mm": 0.0, "limit_mm": 0.1})";
  const std::string g54 =
      R"({"offset": "G54_X", "kind": "WORK_OFFSET", "wcs": "G54", "axis": "X", "previous_mm": -120.5, "delta_mm": 0.003,
          "new_mm": -120.497, "resolution_mm": 0.001, "baseline_mm": -120.5, "limit_mm": 0.05})";
  const auto run = [&](const std::string& plan_path, bool confirm, nlohmann::json* out) {
    std::vector<std::string> args = {"link", "write", "--address", address, "--plan", plan_path, "--quiet"};
    if (confirm) args.push_back("--confirm");
    std::filesystem::remove(dir_ / "write.out");
    const pid_t p = SpawnFormloop(args, dir_ / "write.out", dir_ / "write.err");
    guard.pids.push_back(p);
    const int code = WaitFor(p, 60);
    auto text = ReadFile(dir_ / "write.out");
    *out = text.ok() && !text->empty() ? nlohmann::json::parse(*text) : nlohmann::json();
    return code;
  };
  const auto offset = [&](nlohmann::json& report, const std::string& name) -> nlohmann::json& {
    for (auto& o : report["offsets"]) {
      if (o["address"] == name) return o;
    }
    static nlohmann::json none;
    return none;
  };
  nlohmann::json r;
  // 0.085 + 0.020 = 0.105 > 0.1: refused, nothing sent (spec §9.10); also without --confirm.
  EXPECT_EQ(run(plan("over", "SAFE", true, t3_over), true, &r), 1);
  EXPECT_EQ(r["outcome"], "REFUSED");
  EXPECT_FALSE(offset(r, "T3.radius_wear").contains("read_before_mm"));  // not even read: nothing was sent
  EXPECT_EQ(run(plan("unconfirmed", "SAFE", true, t3_ok), false, &r), 1);
  EXPECT_EQ(r["outcome"], "REFUSED");
  EXPECT_EQ(run(plan("recheck", "RECHECK", true, t3_ok), true, &r), 1);
  EXPECT_EQ(r["outcome"], "REFUSED");
  // The offset moved since the plan was made: OFFSET_CHANGED, nothing written.
  const std::string t3_stale =
      std::string(t3_ok).replace(t3_ok.find("0.085"), 5, "0.080").replace(t3_ok.find("0.095"), 5, "0.090");
  EXPECT_EQ(run(plan("stale", "SAFE", true, t3_stale), true, &r), 1);
  EXPECT_EQ(r["outcome"], "OFFSET_CHANGED");
  EXPECT_FALSE(offset(r, "T3.radius_wear")["written"].get<bool>());
  // G54.X stores what is written + 4 µm (injected): detected on read-back, everything rolled back.
  EXPECT_EQ(run(plan("mismatch", "SAFE", true, t3_ok + "," + t5_ok + "," + g54), true, &r), 1);
  EXPECT_EQ(r["outcome"], "WRITE_VERIFY_FAILED");
  auto& g = offset(r, "G54.X");
  EXPECT_NEAR(g["read_back_mm"].get<double>(), -120.493, 1e-9);
  for (const char* name : {"T3.radius_wear", "T5.length_wear", "G54.X"}) {
    EXPECT_TRUE(offset(r, name)["written"].get<bool>()) << name;
    EXPECT_TRUE(offset(r, name)["rolled_back"].get<bool>()) << name;
  }
  EXPECT_NEAR(offset(r, "T3.radius_wear")["rolled_back_read_mm"].get<double>(), 0.085, 1e-12);
  EXPECT_NEAR(offset(r, "T5.length_wear")["rolled_back_read_mm"].get<double>(), -0.02, 1e-12);
  // A clean plan is written and verified.
  EXPECT_EQ(run(plan("clean", "SAFE", true, t3_ok + "," + t5_ok), true, &r), 0);
  EXPECT_EQ(r["outcome"], "WRITTEN");
  EXPECT_NEAR(offset(r, "T3.radius_wear")["read_back_mm"].get<double>(), 0.095, 1e-12);
  EXPECT_NEAR(offset(r, "T5.length_wear")["read_back_mm"].get<double>(), -0.025, 1e-12);
  // The alarm request and the self-test through the CLI against the same controller.
  for (const char* code : {"5", "0"}) {
    const pid_t p = SpawnFormloop({"link", "alarm", "--address", address, "--code", code, "--quiet"},
                                  dir_ / "alarm.out", dir_ / "alarm.err");
    guard.pids.push_back(p);
    EXPECT_EQ(WaitFor(p, 30), 0);
  }
  const pid_t self = SpawnFormloop({"link", "selftest", "--address", address, "--quiet"}, dir_ / "selftest.out",
                                   dir_ / "selftest.err");
  guard.pids.push_back(self);
  EXPECT_EQ(WaitFor(self, 30), 0);
  EXPECT_TRUE(nlohmann::json::parse(*ReadFile(dir_ / "selftest.out"))["passed"].get<bool>());
  ::kill(emulator, SIGTERM);
  EXPECT_NE(WaitFor(emulator, 10), -1);
  const auto summary = nlohmann::json::parse(*ReadFile(dir_ / "emulate.out"));
  EXPECT_TRUE(summary["stopped_by_signal"].get<bool>());
  EXPECT_NEAR(summary["offsets_mm"]["T3.radius_wear"].get<double>(), 0.095, 1e-12);
}

// `link collect --plan --probe-log` turns the last complete run into a probe log for `formloop analyse`:
// each centre is the point's reference (surface point + R·normal) plus the deviation the emulated probe
// measured, to within the 0.1 µm quantisation.
TEST_F(LinkProcessTest, CollectWritesAProbeLogOfTheRun) {
  ProcessGuard guard;
  const auto plan = dir_ / "plan.json";
  const metrology::ProbingPlan probing = SyntheticPlan(40);
  ASSERT_TRUE(WriteJsonFile(plan, probing.ToJson()).ok());
  pid_t emulator = -1;
  const std::string address = StartEmulator(dir_,
                                            {"--points", "40", "--dwell-ms", "2", "--measure-ms", "1", "--record",
                                             (dir_ / "record.csv").string(), "--linger-s", "0.5"},
                                            &guard, &emulator);
  ASSERT_FALSE(address.empty());
  const pid_t collector = SpawnFormloop(
      {"link", "collect", "--address", address, "--out", (dir_ / "P.csv").string(), "--expect", "40", "--poll-ms", "1",
       "--plan", plan.string(), "--probe-log", (dir_ / "probe_log.csv").string(), "--quiet"},
      dir_ / "collect.out", dir_ / "collect.err");
  guard.pids.push_back(collector);
  ASSERT_EQ(WaitFor(collector, 60), 0) << *ReadFile(dir_ / "collect.err");
  EXPECT_EQ(WaitFor(emulator, 30), 0);
  const auto log = metrology::ReadProbeLog(dir_ / "probe_log.csv");
  ASSERT_TRUE(log.ok()) << log.status().ToString();
  ASSERT_EQ(log->records.size(), 40u);
  const auto record = ReadCsv(dir_ / "record.csv");
  for (std::size_t k = 0; k < 40; ++k) {
    const auto& r = log->records[k];
    const auto& p = probing.points[k];
    EXPECT_EQ(r.id, p.id);
    for (int a = 0; a < 3; ++a) {
      const double truth = std::stod(record[k][6 + a]);
      EXPECT_NEAR(r.centre[a], p.point[a] + p.normal[a] + truth, 1e-4) << "point " << p.id << " axis " << a;
    }
    EXPECT_NEAR((r.approach + p.normal).norm(), 0, 1e-9);
  }
}

// `link program` writes the machine side for a plan file and `link check` reads it back; a broken line
// is an error naming the file and the line (exit 2).
TEST_F(LinkProcessTest, ProgramAndCheckCommands) {
  ProcessGuard guard;
  const auto plan = dir_ / "plan.json";
  ASSERT_TRUE(WriteJsonFile(plan, SyntheticPlan(12).ToJson()).ok());
  const auto run = [&](const std::vector<std::string>& args) {
    const pid_t p = SpawnFormloop(args, dir_ / "cmd.out", dir_ / "cmd.err");
    guard.pids.push_back(p);
    return WaitFor(p, 60);
  };
  for (const std::string dialect : {"fanuc", "linuxcnc", "sinumerik"}) {
    const auto out = dir_ / dialect;
    ASSERT_EQ(run({"link", "program", "--plan", plan.string(), "--dialect", dialect, "--out", out.string(), "--quiet"}),
              0)
        << dialect;
    std::vector<std::string> check = {"link", "check", "--dialect", dialect};
    for (const char* name : {"measure.nc", "measure.ngc", "FL_MEASURE.MPF", "FL_SEND.SPF"}) {
      if (std::filesystem::exists(out / name)) check.push_back((out / name).string());
    }
    EXPECT_EQ(run(check), 0) << dialect;
  }
  auto text = *ReadFile(dir_ / "fanuc" / "measure.nc");
  const auto at = text.find("#902=#165+1");
  const long line = 1 + std::count(text.begin(), text.begin() + static_cast<long>(at), '\n');
  text.replace(at, 11, "#902=#165+");
  ASSERT_TRUE(WriteFileAtomic(dir_ / "broken.nc", text).ok());
  std::filesystem::remove(dir_ / "cmd.err");
  EXPECT_EQ(run({"link", "check", "--dialect", "fanuc", (dir_ / "broken.nc").string()}), 2);
  const auto err = *ReadFile(dir_ / "cmd.err");
  EXPECT_NE(err.find("broken.nc:" + std::to_string(line) + ":"), std::string::npos) << err;
}

// The program skips points: the collector keeps what it received, names the missing ids (GAP) and
// exits 1, so a lost point can never pass for a whole measurement.
TEST_F(LinkProcessTest, SkippedPointsMakeTheCollectionFail) {
  ProcessGuard guard;
  pid_t emulator = -1;
  const std::string address = StartEmulator(dir_,
                                            {"--points", "30", "--dwell-ms", "2", "--measure-ms", "1", "--skip-rate",
                                             "0.2", "--seed", "7", "--ack-timeout-s", "5", "--linger-s", "0.5"},
                                            &guard, &emulator);
  ASSERT_FALSE(address.empty());
  const pid_t collector = SpawnFormloop({"link", "collect", "--address", address, "--out", (dir_ / "P.csv").string(),
                                         "--poll-ms", "1", "--idle-timeout-s", "20"},
                                        dir_ / "collect.out", dir_ / "collect.err");
  guard.pids.push_back(collector);
  EXPECT_EQ(WaitFor(collector, 60), 1);
  WaitFor(emulator, 30);
  const auto err = *ReadFile(dir_ / "collect.err");
  EXPECT_NE(err.find("not every session is COMPLETE"), std::string::npos) << err;
  EXPECT_NE(err.find("GAP"), std::string::npos) << err;
  EXPECT_TRUE(std::filesystem::exists(dir_ / "P.csv"));
}

// A third party writes an illegal control word mid-run: the collector exits 1 naming PROTOCOL_ERROR and
// the program stops in an alarm; both processes end on their own.
TEST_F(LinkProcessTest, ProtocolErrorStopsBothSides) {
  ProcessGuard guard;
  pid_t emulator = -1;
  const std::string address = StartEmulator(dir_,
                                            {"--points", "20", "--dwell-ms", "2", "--measure-ms", "1", "--third-party",
                                             "1:5:0:12345", "--ack-timeout-s", "1", "--linger-s", "0.5"},
                                            &guard, &emulator);
  ASSERT_FALSE(address.empty());
  const pid_t collector =
      SpawnFormloop({"link", "collect", "--address", address, "--out", (dir_ / "P.csv").string(), "--poll-ms", "1"},
                    dir_ / "collect.out", dir_ / "collect.err");
  guard.pids.push_back(collector);
  EXPECT_EQ(WaitFor(collector, 30), 1);
  EXPECT_EQ(WaitFor(emulator, 30), 1);
  const auto out = nlohmann::json::parse(*ReadFile(dir_ / "collect.out"));
  EXPECT_EQ(out["fatal"].get<std::string>().rfind("PROTOCOL_ERROR", 0), 0u);
  const auto emu = nlohmann::json::parse(*ReadFile(dir_ / "emulate.out"));
  ASSERT_EQ(emu["alarms"].size(), 1u);
}

}  // namespace
}  // namespace formloop::cnc
