// `formloop calibrate synth-sphere` and `formloop calibrate sphere` end to end through the binary:
// stdout is the JSON report, the profile is written and reads back, bad input exits 2 with the file
// named and no profile left behind.

#include <cmath>
#include <cstdio>
#include <filesystem>
#include <numbers>
#include <string>

#include <unistd.h>

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include "metrology/probe.h"
#include "tests/support/run_binary.h"

namespace formloop::app {
namespace {

namespace fs = std::filesystem;
using testing::RunFormloop;

class CalibrateCliTest : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = fs::temp_directory_path() / ("formloop-calibrate-" + std::to_string(::getpid()) + "-" +
                                        ::testing::UnitTest::GetInstance()->current_test_info()->name());
    fs::remove_all(dir_);
    fs::create_directories(dir_);
  }
  void TearDown() override { fs::remove_all(dir_); }
  std::string Path(const std::string& name) const { return (dir_ / name).string(); }
  fs::path dir_;
};

TEST_F(CalibrateCliTest, SynthesiseCalibrateAndWriteTheProfile) {
  std::string out, err;
  ASSERT_EQ(RunFormloop("calibrate synth-sphere --out " + Path("log.csv") +
                            " --points 50 --amplitude-um 6 --phase-deg 40 --seed 3",
                        &out, &err),
            0)
      << err;
  const nlohmann::json synth = nlohmann::json::parse(out);
  EXPECT_EQ(synth["points"], 50);
  ASSERT_TRUE(fs::exists(Path("log.csv")));

  ASSERT_EQ(RunFormloop("calibrate sphere " + Path("log.csv") + " --radius 12.5 --ball 1 --out " + Path("p.json"), &out,
                        &err),
            0)
      << err;
  const nlohmann::json report = nlohmann::json::parse(out);
  EXPECT_EQ(report["points"], 50);
  // The ISO test with the nominal ball sees the lobing (about 2 × 6 µm of form error); after
  // compensation the form error is at the noise level and the size error near 0.
  EXPECT_GT(report["iso_nominal_ball"]["probing_form_error_mm"].get<double>(), 0.008);
  EXPECT_LT(report["iso_compensated"]["probing_form_error_mm"].get<double>(), 0.004);
  EXPECT_LT(std::abs(report["iso_compensated"]["size_error_mm"].get<double>()), 0.001);
  double amplitude = 0;
  for (const auto& term : report["fit"]["terms"]) {
    if (term["k"] == 3 && term["j"] == 0) amplitude = term["amplitude_mm"].get<double>();
  }
  EXPECT_NEAR(amplitude, 0.006, 0.0006);

  Result<metrology::ProbeModel> profile = metrology::ReadProbeProfile(Path("p.json"));
  ASSERT_TRUE(profile.ok()) << profile.status().ToString();
  EXPECT_EQ(profile->ball_radius_mm, 1.0);
  EXPECT_EQ(profile->lobing.max_order, 3);
  // θ = 40°/3 is a crest of 6 µm · cos(3θ − 40°); δ there ≈ 6 µm (+ the fitted j = 1 term, small).
  const double t = 40.0 / 3 * std::numbers::pi / 180;
  EXPECT_NEAR(profile->Pretravel(-Eigen::Vector3d(std::cos(t), std::sin(t), 0)), 0.006, 0.0006);
}

TEST_F(CalibrateCliTest, BadInputExitsTwoAndWritesNothing) {
  std::string out, err;
  // Non-unit approach vector on line 3.
  std::FILE* f = std::fopen(Path("bad.csv").c_str(), "w");
  std::fputs("id,x,y,z,ax,ay,az,t\n1,0,0,13.5,0,0,-1,0\n2,13.5,0,0,-0.5,0,0,1\n", f);
  std::fclose(f);
  EXPECT_EQ(RunFormloop("calibrate sphere " + Path("bad.csv") + " --radius 12.5 --ball 1 --out " + Path("p.json"), &out,
                        &err),
            2);
  EXPECT_TRUE(out.empty()) << out;
  EXPECT_NE(err.find(Path("bad.csv") + ":3:"), std::string::npos) << err;
  EXPECT_FALSE(fs::exists(Path("p.json")));

  // Too few points for the model.
  ASSERT_EQ(RunFormloop("calibrate synth-sphere --out " + Path("short.csv") + " --points 8", &out), 0);
  EXPECT_EQ(RunFormloop("calibrate sphere " + Path("short.csv") + " --radius 12.5 --ball 1 --out " + Path("p.json"),
                        &out, &err),
            2);
  EXPECT_NE(err.find("needs at least"), std::string::npos) << err;
  EXPECT_FALSE(fs::exists(Path("p.json")));

  // Missing required option and a bad option value.
  EXPECT_EQ(RunFormloop("calibrate sphere " + Path("short.csv") + " --ball 1", &out, &err), 2);
  EXPECT_EQ(RunFormloop("calibrate sphere " + Path("short.csv") + " --radius 12.5 --ball 1 --lobes 5", &out, &err), 2);
  EXPECT_NE(err.find("--lobes"), std::string::npos) << err;
}

}  // namespace
}  // namespace formloop::app
