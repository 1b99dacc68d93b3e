// The LinuxCNC machine's files without running LinuxCNC: the configuration folder (cnc/linuxcnc_config.h),
// the probe log read back from the program's LOG and PROBEOPEN files (cnc/linuxcnc_probe_log.h), and the
// run's refusals before anything starts (cnc/linuxcnc_run.h). tests/linuxcnc runs the controller.

#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <string>

#include "cnc/linuxcnc_config.h"
#include "cnc/linuxcnc_probe_log.h"
#include "cnc/linuxcnc_run.h"
#include "core/atomic_file.h"
#include "tests/support/test_dir.h"

namespace formloop::cnc {
namespace {

namespace fs = std::filesystem;

class LinuxCncFilesTest : public ::testing::Test {
 protected:
  void SetUp() override { dir_ = testing::FreshTestDir("formloop-linuxcnc-files"); }
  void TearDown() override { fs::remove_all(dir_); }
  fs::path Write(const std::string& name, const std::string& text) {
    std::ofstream(dir_ / name) << text;
    return dir_ / name;
  }
  fs::path dir_;
};

TEST_F(LinuxCncFilesTest, ConfigurationHasEveryFileAndReadsBack) {
  LinuxCncMachineOptions o;
  o.surface.surface = "plane";
  o.surface.pose.shift_um = Eigen::Vector3d(1, 2, 3);
  o.travel_max_mm.z() = 60;
  const auto report = WriteLinuxCncConfig(dir_ / "cfg", o);
  ASSERT_TRUE(report.ok()) << report.status().message();
  for (const char* f :
       {"formloop.ini", "formloop.hal", "formloop_display.py", "formloop_link.py", "tool.tbl", "probe_surface.json"}) {
    EXPECT_TRUE(fs::exists(dir_ / "cfg" / f)) << f;
  }
  EXPECT_NE(fs::status(dir_ / "cfg" / "formloop_display.py").permissions() & fs::perms::owner_exec, fs::perms::none);
  const auto config = ReadLinuxCncConfig(dir_ / "cfg");
  ASSERT_TRUE(config.ok()) << config.status().message();
  EXPECT_EQ(config->Get("DISPLAY", "DISPLAY"), "./formloop_display.py");
  EXPECT_EQ(config->Get("TRAJ", "LINEAR_UNITS"), "mm");
  EXPECT_EQ(config->Get("JOINT_2", "HOME_OFFSET"), "60") << "Z is declared at the top of its travel";
  EXPECT_EQ(config->Get("JOINT_0", "HOME_SEARCH_VEL"), "0") << "homing without switches";
  EXPECT_EQ(config->Get("FORMLOOP", "PROBE_SURFACE"), "plane");
  EXPECT_EQ(config->Get("FORMLOOP", "PROBE_SHIFT_UM"), "1 2 3");
  EXPECT_EQ(config->files.size(), 6u);
  EXPECT_EQ(config->Get("FORMLOOP", "LINK_PORTS"), "4");
  EXPECT_EQ(config->Get("FORMLOOP", "SERVO_CLOCK_INPUT"), "15");
  const std::string hal = ReadFile(dir_ / "cfg" / "formloop.hal").value();
  for (const char* must : {"net probe-tripped probe-live.out => motion.probe-input", "spindle.0.on",
                           "net servo-seconds servo-clock.out => motion.analog-in-15", "joint.2.pos-cmd",
                           "loadrt sum2 names=psurf-s0,psurf-s1", "loadusr -Wn formloop-link ./formloop_link.py 4\n",
                           "net link-block-3 formloop-link.block-3 => motion.analog-in-03",
                           "net link-commit-2 motion.digital-out-02 => formloop-link.commit-2 motion.digital-in-02",
                           "num_aio=16 num_dio=16"}) {
    EXPECT_NE(hal.find(must), std::string::npos) << must;
  }
  // Written again over its own files: fine.
  EXPECT_TRUE(WriteLinuxCncConfig(dir_ / "cfg", o).ok());
}

TEST_F(LinuxCncFilesTest, AFileFormloopDidNotWriteIsNeverReplaced) {
  fs::create_directories(dir_ / "cfg");
  const fs::path mine = Write("cfg/formloop.hal", "# my own HAL file\n");
  LinuxCncMachineOptions o;
  const auto report = WriteLinuxCncConfig(dir_ / "cfg", o);
  ASSERT_FALSE(report.ok());
  EXPECT_NE(report.status().message().find("formloop.hal"), std::string::npos) << report.status().message();
  EXPECT_EQ(ReadFile(mine).value(), "# my own HAL file\n");
  EXPECT_FALSE(fs::exists(dir_ / "cfg" / "formloop.ini")) << "nothing written when one file is refused";
}

TEST_F(LinuxCncFilesTest, AnIniFormloopDidNotWriteIsNotRun) {
  const fs::path ini = Write("other.ini", "[EMC]\nVERSION = 1.1\n[DISPLAY]\nDISPLAY = axis\n");
  const auto config = ReadLinuxCncConfig(ini);
  ASSERT_FALSE(config.ok());
  EXPECT_EQ(config.status().code(), StatusCode::kBadInput);
  EXPECT_NE(config.status().message().find("[FORMLOOP] FORMAT"), std::string::npos) << config.status().message();
}

TEST_F(LinuxCncFilesTest, NoProbeSurfaceLeavesTheProbeInputLow) {
  LinuxCncMachineOptions o;
  o.probe = false;
  ASSERT_TRUE(WriteLinuxCncConfig(dir_ / "cfg", o).ok());
  const std::string hal = ReadFile(dir_ / "cfg" / "formloop.hal").value();
  EXPECT_EQ(hal.find("=> motion.probe-input"), std::string::npos);
  EXPECT_FALSE(fs::exists(dir_ / "cfg" / "probe_surface.json"));
  o.probe = true;
  o.surface.surface = "franke";
  const auto refused = WriteLinuxCncConfig(dir_ / "cfg2", o);
  ASSERT_FALSE(refused.ok());
  EXPECT_NE(refused.status().message().find("not a plane or a quadric"), std::string::npos);
  EXPECT_FALSE(fs::exists(dir_ / "cfg2"));
}

constexpr const char* kLog =
    "formloop probe log 1: point id x y z tripped ax ay az t_s\n"
    "point 7 10.000000 10.000000 6.506083 1.000000 0.099751 -0.049876 -0.993763 3.610000\n"
    "point 8 20.000000 10.000000 7.506083 1.000000 0.000000000 0.000000000 -1.000000000 4.862000\n";
constexpr const char* kTrips =
    "10.000000 10.000000 6.500000 0.000000 0.000000 0.000000 0.000000 0.000000 0.000000\n"
    "10.000000 10.000000 6.506083 0.000000 0.000000 0.000000 0.000000 0.000000 0.000000\n"
    "20.000000 10.000000 7.500000 0.000000 0.000000 0.000000 0.000000 0.000000 0.000000\n"
    "20.000000 10.000000 7.506083 0.000000 0.000000 0.000000 0.000000 0.000000 0.000000\n";

TEST_F(LinuxCncFilesTest, ProbeLogReadsIdsCentresApproachesAndTimes) {
  const auto log = ReadLinuxCncProbeLog(Write("points.txt", kLog), Write("trips.txt", kTrips), 2);
  ASSERT_TRUE(log.ok()) << log.status().message();
  ASSERT_EQ(log->records.size(), 2u);
  EXPECT_EQ(log->records[0].id, 7);
  EXPECT_EQ(log->records[0].centre, Eigen::Vector3d(10, 10, 6.506083));
  EXPECT_NEAR(log->records[0].approach.norm(), 1.0, 1e-15);
  EXPECT_NEAR(log->records[0].approach.z(), -0.993763, 2e-6);  // rescaled to unit length
  EXPECT_EQ(log->records[1].t_s, 4.862);
  EXPECT_EQ(log->records[1].line, 3);
}

TEST_F(LinuxCncFilesTest, ProbeLogProblemsNameTheFileAndLine) {
  struct Case {
    std::string log, trips, needle;
    int touches;
  };
  const std::string header = "formloop probe log 1: point id x y z tripped ax ay az t_s\n";
  const std::vector<Case> cases = {
      {"some other file\n", kTrips, "does not start with", 2},
      {header + "point 7 10 10 6.5 0.000000 0 0 -1 1.0\n", "", "the probe did not trip", 1},
      {header + "point 7 10 10 6.5 1 0 0 -1 1.0\npoint 7 10 10 6.5 1 0 0 -1 2.0\n", "", "logged twice", 1},
      {header + "point 7 10 10 6.5 1 0 0.5 -1 1.0\n", "", "not a unit vector", 1},
      {header + "point 7 10 10 abc 1 0 0 -1 1.0\n", "", "'abc' is not a number", 1},
      {kLog, kTrips, "holds 4 probe trips", 1},
      {kLog, std::string(kTrips).replace(std::string(kTrips).find("6.506083"), 8, "6.506183"), "disagrees with point 7",
       2},
  };
  for (const Case& c : cases) {
    const fs::path trips = c.trips.empty() ? fs::path() : Write("trips.txt", c.trips);
    const auto log = ReadLinuxCncProbeLog(Write("points.txt", c.log), trips, c.touches);
    ASSERT_FALSE(log.ok()) << c.needle;
    EXPECT_EQ(log.status().code(), StatusCode::kBadInput) << c.needle;
    EXPECT_NE(log.status().message().find(c.needle), std::string::npos) << log.status().message();
    EXPECT_NE(log.status().message().find(".txt"), std::string::npos) << log.status().message();
  }
}

TEST_F(LinuxCncFilesTest, RunRefusesAnExistingSessionFolderBeforeStartingAnything) {
  LinuxCncMachineOptions o;
  ASSERT_TRUE(WriteLinuxCncConfig(dir_ / "cfg", o).ok());
  const auto config = ReadLinuxCncConfig(dir_ / "cfg");
  ASSERT_TRUE(config.ok());
  const fs::path program = Write("p.ngc", "G21\nM2\n");
  fs::create_directories(dir_ / "session");
  const fs::path keep = Write("session/notes.txt", "mine\n");
  const auto run = RunOnLinuxCnc(*config, program, dir_ / "session", {});
  ASSERT_FALSE(run.ok());
  EXPECT_NE(run.status().message().find("not empty"), std::string::npos) << run.status().message();
  EXPECT_EQ(ReadFile(keep).value(), "mine\n");
  LinuxCncRunOptions bad;
  bad.timeout_s = 0;
  EXPECT_NE(RunOnLinuxCnc(*config, program, dir_ / "s2", bad).status().message().find("--timeout-s"),
            std::string::npos);
}

}  // namespace
}  // namespace formloop::cnc
