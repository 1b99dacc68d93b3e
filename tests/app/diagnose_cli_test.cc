// `formloop simulate` and `formloop diagnose` end to end through the binary: a run folder, a probe log
// simulated with a hidden effect, the diagnosis naming it, the extended model it writes, the gain on
// a second part, and bad input refused with nothing written.

#include <filesystem>
#include <fstream>

#include <gtest/gtest.h>

#include "app/part.h"
#include "app/run_folder.h"
#include "core/json_io.h"
#include "metrology/probe.h"
#include "nc-gen/toolpath.h"
#include "nc-gen/toolpath_io.h"
#include "reconstruction/analytic_surface.h"
#include "reconstruction/bspline_surface.h"
#include "simulation/model.h"
#include "tests/support/run_binary.h"

namespace formloop::app {
namespace {
namespace fs = std::filesystem;
using testing::RunFormloop;

class DiagnoseCliTest : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = fs::temp_directory_path() / ("formloop_diagnose_cli_" + std::to_string(::getpid()));
    fs::remove_all(dir_);
    fs::create_directories(dir_);
  }
  void TearDown() override { fs::remove_all(dir_); }

  // A run folder as `formloop run` leaves it (part, Q, tool path, probing plan), built directly and
  // lighter (8 µm scallop, 18 × 18 probes) so the test stays quick.
  // `planned_radius_mm` > 0: the tool path is cut with that ball instead of the part file's (as when the
  // case's plan chooses another tool).
  fs::path MakeRun(const std::string& name, const std::string& surface, double planned_radius_mm = 0) {
    const fs::path run = dir_ / name;
    fs::create_directories(run / "inputs");
    fs::create_directories(run / "surface");
    fs::create_directories(run / "toolpath");
    auto part = ReadPart(fs::path(FORMLOOP_SOURCE_DIR) / "data" / "parts" / "demo-saddle.json");
    EXPECT_TRUE(part.ok()) << part.status().message();
    part->surface_reference = surface;
    part->toolpath.scallop_um = 8;
    part->toolpath.max_point_spacing_mm = 1.0;
    EXPECT_TRUE(WriteJsonFile(run / "inputs" / "part.json", part->ToJson()).ok());
    auto analytic = recon::MakeReferenceSurface(surface);
    const recon::BSplineSurface q = recon::FitAnalytic(*analytic.value(), 30, 30, {}, 0, 1, nullptr).value();
    EXPECT_TRUE(recon::WriteStep(run / "surface" / "Q.step", q, name).ok());
    nc::ToolpathOptions planned = part->toolpath;
    if (planned_radius_mm > 0) planned.tool.radius_mm = planned_radius_mm;
    EXPECT_TRUE(nc::WriteToolpathFile(run / "toolpath" / "toolpath.csv", nc::PlanRaster(q, planned).value()).ok());
    EXPECT_TRUE(WriteJsonFile(run / "toolpath" / "probing_plan.json",
                              metrology::PlanProbingGrid(q, 18, 18, 0.05).value().ToJson())
                    .ok());
    return run;
  }

  fs::path WriteModel(const std::string& name, const std::string& json) {
    const fs::path path = dir_ / name;
    std::ofstream(path) << json;
    return path;
  }

  fs::path dir_;
};

TEST_F(DiagnoseCliTest, SimulateThenDiagnoseNamesTheHiddenEffectAndMeasuresTheGainOnASecondPart) {
  const fs::path run1 = MakeRun("part1", "saddle");
  const fs::path run2 = MakeRun("part2", "franke");
  const fs::path machine = WriteModel("machine.json", R"({"format": "formloop-model", "version": 1, "effects": [
      {"name": "tool_wear", "parameters": {"k_w_um_per_m": 2}},
      {"name": "noise", "parameters": {"surface_sigma_um": 0.5, "probe_sigma_um": 0.5}}]})");
  const fs::path baseline = WriteModel("baseline.json", R"({"format": "formloop-model", "version": 1, "effects": [
      {"name": "noise", "parameters": {"surface_sigma_um": 0.5, "probe_sigma_um": 0.5}}]})");
  std::string out, err;
  // Each part its own truth file: an output that exists is refused (core/output_file.h).
  for (const auto& [run, log] : {std::pair{run1, dir_ / "log1.csv"}, std::pair{run2, dir_ / "log2.csv"}}) {
    ASSERT_EQ(RunFormloop("simulate --run " + run.string() + " --model " + machine.string() + " --out " + log.string() +
                              " --truth " + log.string() + ".truth.json --seed 7",
                          &out, &err),
              0)
        << err;
    ASSERT_TRUE(fs::exists(log));
  }
  const fs::path out_dir = dir_ / "diagnosis";
  ASSERT_EQ(RunFormloop("diagnose --measured " + (dir_ / "log1.csv").string() + " --run " + run1.string() +
                            " --baseline " + baseline.string() + " --out " + out_dir.string() + " --validate " +
                            (dir_ / "log2.csv").string() + " --validate-run " + run2.string(),
                        &out, &err),
            0)
      << err;
  const auto json = ParseJson(out, "stdout");
  ASSERT_TRUE(json.ok()) << out;
  ASSERT_FALSE((*json)["causes"].empty()) << out;
  EXPECT_EQ((*json)["causes"][0]["effect"], "tool_wear");
  const double k = (*json)["causes"][0]["parameters"]["k_w_um_per_m"].get<double>();
  const double se = (*json)["causes"][0]["std_errors"]["k_w_um_per_m"].get<double>();
  EXPECT_LE(std::abs(k - 2), 3 * se) << k << " +- " << se;
  for (const char* key : {"rms_before_um", "rms_after_um", "heldout_rms_before_um", "heldout_rms_after_um"}) {
    EXPECT_TRUE((*json)["gain"][key].is_number()) << key;
  }
  // After: the noise (0.5 µm roughness + 0.5 µm probe ≈ 0.71 µm); before: the wear on top of it.
  EXPECT_LT((*json)["gain"]["heldout_rms_after_um"].get<double>(), 0.8);
  EXPECT_LT((*json)["gain"]["heldout_rms_after_um"].get<double>(),
            0.5 * (*json)["gain"]["heldout_rms_before_um"].get<double>());
  const auto& second = (*json)["gain"]["second_part"];
  EXPECT_LT(second["rms_after_um"].get<double>(), 0.5 * second["rms_before_um"].get<double>()) << second.dump();
  EXPECT_TRUE((*json)["unexplained"].is_null());
  EXPECT_NE(err.find("cause: tool_wear"), std::string::npos) << err;
  for (const char* file : {"diagnosis.json", "model.json", "residuals.csv", "inputs/measured.csv",
                           "inputs/baseline.json", "inputs/arguments.json"}) {
    EXPECT_TRUE(fs::exists(out_dir / file)) << file;
  }
  // The extended model is a model formloop reads back, with the cause in it.
  const auto model = sim::ReadModel(out_dir / "model.json");
  ASSERT_TRUE(model.ok()) << model.status().message();
  EXPECT_TRUE(model->Has("tool_wear"));
  // The learned model goes into a case of the library, keyed by machine/tool/material, with provenance.
  const std::string db = (dir_ / "cases.db").string();
  ASSERT_EQ(RunFormloop("kb init " + db, &out, &err), 0) << err;
  ASSERT_EQ(
      RunFormloop("kb add " + db + " " + (fs::path(FORMLOOP_SOURCE_DIR) / "data" / "kb" / "example_case.json").string(),
                  &out, &err),
      0)
      << err;
  ASSERT_EQ(RunFormloop("diagnose --measured " + (dir_ / "log1.csv").string() + " --run " + run1.string() +
                            " --baseline " + baseline.string() + " --out " + (dir_ / "stored").string() +
                            " --library " + db + " --case example-blade-001 --machine virtual-3axis",
                        &out, &err),
            0)
      << err;
  ASSERT_EQ(RunFormloop("kb show " + db + " example-blade-001", &out, &err), 0) << err;
  const auto shown = ParseJson(out, "kb show");
  ASSERT_TRUE(shown.ok()) << out;
  bool found = false;
  for (const auto& m : (*shown)["simulation"]["effect_models"]) {
    if (m.value("machine", "") != "virtual-3axis") continue;
    found = true;
    EXPECT_EQ(m["tool"], "ball r3");
    EXPECT_NE(m["model"].dump().find("tool_wear"), std::string::npos) << m.dump();
    EXPECT_EQ(m["provenance"]["measured"], (dir_ / "log1.csv").string());
  }
  EXPECT_TRUE(found) << out;
  // Same inputs, same seed: the same log.
  ASSERT_EQ(RunFormloop("simulate --run " + run1.string() + " --model " + machine.string() + " --out " +
                            (dir_ / "again.csv").string() + " --seed 7",
                        &out, &err),
            0);
  std::ifstream a(dir_ / "log1.csv"), b(dir_ / "again.csv");
  EXPECT_EQ(std::string(std::istreambuf_iterator<char>(a), {}), std::string(std::istreambuf_iterator<char>(b), {}));
}

// Without the run folder (no Q, no tool path) a plan, a log and the probe profile still diagnose the
// effects that do not need the tool path; the others are listed as not screened.
TEST_F(DiagnoseCliTest, APlanAndALogAloneScreenTheEffectsThatNeedNoToolPath) {
  const fs::path run = MakeRun("part", "franke");
  const fs::path machine = WriteModel("machine.json", R"({"format": "formloop-model", "version": 1, "effects": [
      {"name": "setup_offset", "parameters": {"tx_um": 6, "ty_um": -4, "tz_um": 3}},
      {"name": "noise", "parameters": {"surface_sigma_um": 0.5, "probe_sigma_um": 0.5}}]})");
  std::string out, err;
  ASSERT_EQ(RunFormloop("simulate --run " + run.string() + " --model " + machine.string() + " --out " +
                            (dir_ / "log.csv").string(),
                        &out, &err),
            0)
      << err;
  const auto part = ReadPart(run / "inputs" / "part.json");
  ASSERT_TRUE(part.ok());
  ASSERT_TRUE(metrology::WriteProbeProfile(dir_ / "probe.json", part->probe).ok());
  ASSERT_EQ(RunFormloop("diagnose --measured " + (dir_ / "log.csv").string() + " --plan " +
                            (run / "toolpath" / "probing_plan.json").string() + " --probe-profile " +
                            (dir_ / "probe.json").string() + " --out " + (dir_ / "d").string(),
                        &out, &err),
            0)
      << err;
  const auto json = ParseJson(out, "stdout");
  ASSERT_TRUE(json.ok()) << out;
  ASSERT_FALSE((*json)["causes"].empty()) << out;
  EXPECT_EQ((*json)["causes"][0]["effect"], "setup_offset");
  const auto& skipped = (*json)["not_screened"]["effects"];
  for (const char* effect : {"tool_wear", "tool_deflection", "thermal_drift_z", "backlash_x", "backlash_y"}) {
    EXPECT_NE(std::find(skipped.begin(), skipped.end(), effect), skipped.end()) << effect;
  }
  // Without the profile it is refused, naming the option.
  EXPECT_EQ(RunFormloop("diagnose --measured " + (dir_ / "log.csv").string() + " --plan " +
                            (run / "toolpath" / "probing_plan.json").string() + " --out " + (dir_ / "e").string(),
                        &out, &err),
            2);
  EXPECT_NE(err.find("--probe-profile"), std::string::npos) << err;
}

// The planner may cut with another tool than the part file names (the retrieved case's plan): a run
// folder read back for simulate/diagnose carries the tool of the tool path. Reading the part file's
// radius instead made reg-dome-a's residuals 2,017 µm instead of 18 µm and its causes nonsense.
TEST_F(DiagnoseCliTest, ARunFolderReadBackCarriesTheToolThatCutThePart) {
  const fs::path run = MakeRun("other_tool", "saddle", 5.0);
  const auto part = ReadPart(run / "inputs" / "part.json");
  ASSERT_TRUE(part.ok()) << part.status().message();
  ASSERT_NE(part->toolpath.tool.radius_mm, 5.0);
  const auto folder = ReadRunFolder(run);
  ASSERT_TRUE(folder.ok()) << folder.status().message();
  EXPECT_EQ(folder->toolpath.options.tool.radius_mm, 5.0);
  EXPECT_EQ(folder->part.toolpath.tool.radius_mm, 5.0);
}

TEST_F(DiagnoseCliTest, BadInputIsRefusedWithTheFieldNamedAndNothingWritten) {
  const fs::path run = MakeRun("part", "saddle");
  std::string out, err;
  const fs::path typo = WriteModel("typo.json", R"({"format": "formloop-model", "version": 1, "effects": [
      {"name": "tool_wera", "parameters": {}}]})");
  EXPECT_EQ(RunFormloop("simulate --run " + run.string() + " --model " + typo.string() + " --out " +
                            (dir_ / "log.csv").string(),
                        &out, &err),
            2);
  EXPECT_NE(err.find("effects[0].name"), std::string::npos) << err;
  EXPECT_NE(err.find("tool_wera"), std::string::npos) << err;
  EXPECT_FALSE(fs::exists(dir_ / "log.csv"));
  EXPECT_NE(RunFormloop("simulate --run " + (dir_ / "nowhere").string() + " --model " + typo.string() + " --out " +
                            (dir_ / "log.csv").string(),
                        &out, &err),
            0);
  EXPECT_NE(err.find("nowhere"), std::string::npos) << err;
  // A log whose ids are not in the plan: the line is named, no output folder appears.
  std::ofstream(dir_ / "foreign.csv") << "id,x,y,z,ax,ay,az,t\n9999,0,0,0,0,0,-1,1\n";
  EXPECT_EQ(RunFormloop("diagnose --measured " + (dir_ / "foreign.csv").string() + " --run " + run.string() +
                            " --out " + (dir_ / "d").string(),
                        &out, &err),
            2);
  EXPECT_NE(err.find("9999"), std::string::npos) << err;
  EXPECT_FALSE(fs::exists(dir_ / "d"));
  EXPECT_FALSE(fs::exists(dir_ / "d.partial"));
}

}  // namespace
}  // namespace formloop::app

namespace formloop::app {
namespace {

// The separating experiment applied through the CLI: a tool radius error alone is an alias group with
// the probe radius on probe data; the diagnosis proposes what separates them; a tool-setter reading
// given with --direct splits it and names the tool radius, the reading echoed with its fitted value.
TEST_F(DiagnoseCliTest, ADirectMeasurementGivenWithDirectSplitsAnAliasGroup) {
  const fs::path run = MakeRun("part", "saddle");
  const fs::path machine = WriteModel("machine.json", R"({"format": "formloop-model", "version": 1, "effects": [
      {"name": "tool_radius", "parameters": {"delta_r_um": 6}},
      {"name": "noise", "parameters": {"surface_sigma_um": 0.5, "probe_sigma_um": 0.5}}]})");
  std::string out, err;
  const fs::path log = dir_ / "log.csv";
  ASSERT_EQ(RunFormloop("simulate --run " + run.string() + " --model " + machine.string() + " --out " + log.string() +
                            " --seed 3",
                        &out, &err),
            0)
      << err;
  ASSERT_EQ(RunFormloop("diagnose --measured " + log.string() + " --run " + run.string() + " --out " +
                            (dir_ / "alone").string(),
                        &out, &err),
            0)
      << err;
  const auto alone = ParseJson(out, "stdout");
  ASSERT_TRUE(alone.ok()) << out;
  ASSERT_FALSE((*alone)["alias_groups"].empty()) << out;
  EXPECT_FALSE((*alone)["proposals"].empty()) << out;
  EXPECT_FALSE(alone->contains("direct_measurements"));
  const fs::path direct = WriteModel("direct.json", R"({"direct_measurements": [
      {"effect": "tool_radius", "parameter": "delta_r_um", "value": 6.4, "sigma": 1.0, "by": "tool setter"}]})");
  const fs::path out_dir = dir_ / "with_setter";
  ASSERT_EQ(RunFormloop("diagnose --measured " + log.string() + " --run " + run.string() + " --direct " +
                            direct.string() + " --out " + out_dir.string(),
                        &out, &err),
            0)
      << err;
  const auto json = ParseJson(out, "stdout");
  ASSERT_TRUE(json.ok()) << out;
  EXPECT_TRUE((*json)["alias_groups"].empty()) << out;
  ASSERT_EQ((*json)["causes"].size(), 1u) << out;
  EXPECT_EQ((*json)["causes"][0]["effect"], "tool_radius");
  const auto& interval = (*json)["causes"][0]["interval_95"]["delta_r_um"];
  EXPECT_LE(interval[0].get<double>(), 6.0) << out;
  EXPECT_GE(interval[1].get<double>(), 6.0) << out;
  EXPECT_NEAR((*json)["direct_measurements"][0]["fitted"].get<double>(), 6.0, 0.3) << out;
  EXPECT_EQ((*json)["direct_measurements"][0]["by"], "tool setter");
  EXPECT_NE(err.find("measured directly (tool setter)"), std::string::npos) << err;
  EXPECT_TRUE(fs::exists(out_dir / "inputs" / "direct.json"));
  // A bad file: refused with the file and field named, nothing written.
  const fs::path bad = WriteModel("bad_direct.json", R"({"direct_measurements": [
      {"effect": "tool_radius", "parameter": "delta_r_um", "value": 6.4, "sigma": -1}]})");
  EXPECT_NE(RunFormloop("diagnose --measured " + log.string() + " --run " + run.string() + " --direct " + bad.string() +
                            " --out " + (dir_ / "refused").string(),
                        &out, &err),
            0);
  EXPECT_NE(err.find("bad_direct.json"), std::string::npos) << err;
  EXPECT_NE(err.find("sigma"), std::string::npos) << err;
  EXPECT_FALSE(fs::exists(dir_ / "refused"));
}

}  // namespace
}  // namespace formloop::app
