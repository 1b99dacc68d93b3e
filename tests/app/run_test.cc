// The end-to-end run: every stage writes its report, the loop reaches tolerance, runs repeat
// byte for byte, bad parts are refused before anything is written, and the binary behaves.

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <sstream>
#include <string>
#include <vector>

#include <unistd.h>

#include <gtest/gtest.h>

#include "app/part.h"
#include "app/pipeline.h"
#include "core/atomic_file.h"
#include "core/json_io.h"
#include "core/log.h"
#include "core/version.h"
#include "tests/support/run_binary.h"
#include "tests/support/test_dir.h"

namespace formloop::app {
namespace {

namespace fs = std::filesystem;
const fs::path kDemo = fs::path(FORMLOOP_SOURCE_DIR) / "data" / "parts" / "demo-saddle.json";

class RunTest : public ::testing::Test {
 protected:
  void SetUp() override {
    log::SetLevel(log::Level::kWarn);
    dir_ = testing::FreshTestDir("formloop-run");
  }
  void TearDown() override { fs::remove_all(dir_); }
  fs::path dir_;
};

TEST_F(RunTest, DemoRunsEveryStageAndCompensatesIntoTolerance) {
  const auto part = ReadPart(kDemo);
  ASSERT_TRUE(part.ok()) << part.status().message();
  RunOptions options;
  options.out = dir_ / "demo";
  const auto summary = RunPart(*part, options);
  ASSERT_TRUE(summary.ok()) << summary.status().message();
  for (const char* file :
       {"summary.json", "formloop.log", "inputs/part.json", "surface/Q.step", "surface/surface.json",
        "surface/samples.csv", "toolpath/program.ngc", "toolpath/probe.ngc", "toolpath/probing_plan.json",
        "toolpath/toolpath.json", "loop-0/probe_log.csv", "loop-0/machine.json", "loop-0/deviations.csv",
        "loop-0/deviations.ply", "loop-0/analysis.json", "loop-0/program_compensated.ngc",
        "loop-0/compensation_side.bin", "loop-0/compensation.json", "loop-1/analysis.json"}) {
    EXPECT_TRUE(fs::exists(options.out / file)) << file;
  }
  EXPECT_FALSE(fs::exists(dir_ / "demo.partial"));
  // One version string (CMake's project version): the summary and the programs name it.
  const auto written = ReadJsonFile(options.out / "summary.json");
  ASSERT_TRUE(written.ok());
  EXPECT_EQ((*written)["formloop_version"], Version());
  std::ifstream program(options.out / "toolpath" / "program.ngc");
  const std::string program_text((std::istreambuf_iterator<char>(program)), std::istreambuf_iterator<char>());
  EXPECT_NE(program_text.find(std::string("formloop ") + Version() + " part "), std::string::npos);
  // The injected error is systematic and out of tolerance; one mirror compensation brings it in.
  ASSERT_EQ(summary->loops.size(), 2u);
  const LoopSummary& first = summary->loops[0];
  const LoopSummary& second = summary->loops[1];
  EXPECT_GT(first.raw_moran_z, 2.326);
  EXPECT_GT(first.form_error_um, 10.0);
  EXPECT_TRUE(first.compensated);
  EXPECT_TRUE(second.within_tolerance);
  EXPECT_LT(second.form_error_um, 0.4 * first.form_error_um);
  EXPECT_LT(second.raw_moran_z, 2.326) << "what is left after compensation should be random";
  // The decision is the decomposition's §8 evaluation, recorded with the chosen model and its
  // residual z, in the summary and in each loop's analysis.json.
  EXPECT_NE(first.chosen_model, "constant");
  EXPECT_TRUE(first.systematic_significant);
  EXPECT_TRUE(first.compensation_advised);
  EXPECT_FALSE(first.within_tolerance);
  EXPECT_NE(first.decision.find("compensate by -d_s"), std::string::npos) << first.decision;
  EXPECT_EQ(first.residual_independent, first.residual_moran_z <= 2.326);
  EXPECT_FALSE(second.compensation_advised);
  EXPECT_EQ(second.decision, "within tolerance: done");
  for (int loop = 0; loop < 2; ++loop) {
    const auto analysis = ReadJsonFile(options.out / ("loop-" + std::to_string(loop)) / "analysis.json");
    ASSERT_TRUE(analysis.ok());
    const LoopSummary& l = summary->loops[static_cast<std::size_t>(loop)];
    EXPECT_EQ((*analysis)["chosen_model"], l.chosen_model);
    EXPECT_EQ((*analysis)["evaluation"]["compensate"], l.compensation_advised);
    EXPECT_EQ((*analysis)["evaluation"]["form_error_um"], l.form_error_um);
    EXPECT_EQ((*analysis)["compensate"], l.compensated);
    EXPECT_EQ((*analysis)["decision"], l.decision);
    const auto& steps = (*analysis)["models_tried"];
    EXPECT_EQ(steps[(*analysis)["chosen_step"].get<std::size_t>()]["residual_moran_z"], l.residual_moran_z);
  }
  const auto summary_json = ReadJsonFile(options.out / "summary.json");
  ASSERT_TRUE(summary_json.ok());
  for (const char* key :
       {"chosen_model", "residual_moran_z", "residual_independent", "compensation_advised", "decision"}) {
    EXPECT_TRUE((*summary_json)["loops"][0].contains(key)) << key;
  }
  // Residual σ stays at the injected noise level: roughness 1 µm, probe 0.5 µm, and the scallop
  // (0..3 µm between passes) → about 1.4 µm.
  EXPECT_NEAR(second.random_sigma_um, std::hypot(1.0, 0.5, 3.0 / std::sqrt(12.0) * 1.0), 0.4);
  // The resolved inputs reproduce the part.
  const auto resolved = ReadPart(options.out / "inputs" / "part.json");
  ASSERT_TRUE(resolved.ok()) << resolved.status().message();
  EXPECT_EQ(resolved->ToJson(), part->ToJson());
  // The compensated program moves the tool, the side file's offsets check out from the programs.
  const auto comp = ReadJsonFile(options.out / "loop-0" / "compensation.json");
  ASSERT_TRUE(comp.ok());
  EXPECT_GT((*comp)["max_offset_um"].get<double>(), 5.0);
  EXPECT_LT((*comp)["side_file_check_max_disagreement_um"].get<double>(), 0.2);
}

std::string Slurp(const fs::path& p) { return ReadFile(p).value(); }

TEST_F(RunTest, SameInputsGiveByteIdenticalOutputs) {
  const auto part = ReadPart(kDemo);
  ASSERT_TRUE(part.ok());
  for (const char* name : {"a", "b"}) {
    RunOptions options;
    options.out = dir_ / name;
    ASSERT_TRUE(RunPart(*part, options).ok());
  }
  int compared = 0;
  for (const auto& entry : fs::recursive_directory_iterator(dir_ / "a")) {
    if (!entry.is_regular_file() || entry.path().filename() == "formloop.log") continue;  // the log has timestamps
    const fs::path rel = fs::relative(entry.path(), dir_ / "a");
    ASSERT_TRUE(fs::exists(dir_ / "b" / rel)) << rel;
    EXPECT_EQ(Slurp(entry.path()), Slurp(dir_ / "b" / rel)) << rel;
    ++compared;
  }
  EXPECT_GE(compared, 18);
}

// `formloop run` and `formloop analyse` call the one analysis of a probe log: on the run's own loop-0
// log, with the part's analysis settings, they give the same per-point table (same columns; the same
// values apart from the LISA clusters, whose permutations are seeded differently, within 1e-5 of the
// 6-decimal text: analyse reads Q back from surface/Q.step, the run keeps the fitted surface in memory)
// and the same decision; and `formloop report` draws the analyse folder like a run's loop 0.
TEST_F(RunTest, RunAndAnalyseGiveTheSamePerPointTable) {
  const auto part = ReadPart(kDemo);
  ASSERT_TRUE(part.ok());
  RunOptions options;
  options.out = dir_ / "run";
  ASSERT_TRUE(RunPart(*part, options).ok());
  const fs::path run = options.out;
  const fs::path out = dir_ / "analyse";
  std::string stdout_text, stderr_text;
  const std::string args = "analyse --surface " + (run / "surface" / "Q.step").string() + " --probe-log " +
                           (run / "loop-0" / "probe_log.csv").string() + " --plan " +
                           (run / "toolpath" / "probing_plan.json").string() +
                           " --ball-radius 1 --knn 8 --max-control-net 8 --coverage-factor 2 --tolerance-um 10"
                           " --lisa-permutations 199 --out " +
                           out.string();
  ASSERT_EQ(testing::RunFormloop(args, &stdout_text, &stderr_text), 0) << stderr_text;
  const std::string run_csv = Slurp(run / "loop-0" / "deviations.csv");
  const std::string analyse_csv = Slurp(out / "deviations.csv");
  auto lines = [](const std::string& text) {
    std::vector<std::vector<std::string>> rows;
    std::istringstream in(text);
    for (std::string line; std::getline(in, line);) {
      if (!line.empty() && line[0] == '#') continue;  // formloop's marker line
      std::vector<std::string> cells;
      std::istringstream cs(line);
      for (std::string cell; std::getline(cs, cell, ',');) cells.push_back(cell);
      rows.push_back(cells);
    }
    return rows;
  };
  const auto a = lines(run_csv), b = lines(analyse_csv);
  ASSERT_EQ(a.size(), 401u);
  ASSERT_EQ(b.size(), a.size());
  ASSERT_EQ(a.front(), b.front());  // the same columns in the same order
  const std::vector<std::string>& header = a.front();
  int compared = 0;
  for (std::size_t c = 0; c < header.size(); ++c) {
    if (header[c] == "lisa_cluster" || header[c] == "lisa_cluster_random") continue;
    for (std::size_t r = 1; r < a.size(); ++r) {
      const double x = std::stod(a[r][c]), y = std::stod(b[r][c]);
      ASSERT_LE(std::abs(x - y), 1e-5 * std::max(1.0, std::abs(x))) << header[c] << " row " << r;
    }
    ++compared;
  }
  EXPECT_EQ(compared, 20);  // x, y, z, nx, ny, nz, id and 13 scalars
  const auto run_analysis = ReadJsonFile(run / "loop-0" / "analysis.json");
  const auto analyse_analysis = ReadJsonFile(out / "analysis.json");
  ASSERT_TRUE(run_analysis.ok() && analyse_analysis.ok());
  const auto& e1 = (*run_analysis)["evaluation"];
  const auto& e2 = (*analyse_analysis)["evaluation"];
  EXPECT_EQ(e1["decision"], e2["decision"]);
  EXPECT_EQ(e1["compensate"], e2["compensate"]);
  EXPECT_NEAR(e1["form_error_um"].get<double>(), e2["form_error_um"].get<double>(), 1e-5);
  EXPECT_EQ((*run_analysis)["chosen_model"], (*analyse_analysis)["chosen_model"]);

  ASSERT_EQ(testing::RunFormloop("report " + out.string(), &stdout_text, &stderr_text), 0) << stderr_text;
  const std::string html = Slurp(out / "report.html");
  EXPECT_NE(html.find("Analysis report: analysis of"), std::string::npos);
  for (const char* section : {"id=\"loops\"", "id=\"deviations\"", "id=\"spatial\""}) {
    EXPECT_NE(html.find(section), std::string::npos) << section;
  }
  EXPECT_EQ(html.find("id=\"retrieval\""), std::string::npos);  // run-only sections are left out
  EXPECT_EQ(html.find("not available"), std::string::npos);     // every picture of loop 0 is drawn
}

// machine.effects: the effect catalogue's model JSON, and the old fields (deprecated) read as the same
// model; the resolved part writes the model.
TEST_F(RunTest, MachineEffectsAreTheCatalogueModelAndTheOldFieldsStillRead) {
  auto json = ReadJsonFile(kDemo);
  ASSERT_TRUE(json.ok());
  const auto as_model = ParsePart(*json, "demo.json");
  ASSERT_TRUE(as_model.ok()) << as_model.status().ToString();
  ASSERT_TRUE(as_model->effects.has_value());
  Json old = *json;
  old["machine"]["effects"] = {{"tool_radius_error_um", 18}, {"deflection_um", 20},     {"thermal_amplitude_um", 6},
                               {"thermal_tau_s", 900},       {"surface_noise_um", 1.0}, {"probe_noise_um", 0.5}};
  const auto as_fields = ParsePart(old, "old.json");
  ASSERT_TRUE(as_fields.ok()) << as_fields.status().ToString();
  ASSERT_TRUE(as_fields->effects.has_value());
  EXPECT_EQ(as_fields->effects->ToJson(), as_model->effects->ToJson());
  EXPECT_EQ(as_fields->ToJson()["machine"]["effects"]["format"], "formloop-model");
  old["machine"]["effects"]["deflection_um"] = "twenty";
  EXPECT_FALSE(ParsePart(old, "old.json").ok());
  Json typo = *json;
  typo["machine"]["effects"]["effects"][0]["name"] = "tool_radiuss";
  const auto bad = ParsePart(typo, "typo.json");
  ASSERT_FALSE(bad.ok());
  EXPECT_NE(bad.status().message().find("unknown effect 'tool_radiuss'"), std::string::npos) << bad.status().message();
}

TEST_F(RunTest, BadPartsAreRefusedWithTheFieldAndNothingIsWritten) {
  auto json = ReadJsonFile(kDemo).value();
  struct Case {
    std::function<void(Json&)> edit;
    std::string expect;
  };
  const std::vector<Case> cases = {
      {[](Json& j) { j.erase("tolerance_mm"); }, "field 'tolerance_mm': required field is missing"},
      {[](Json& j) { j["tool"]["radius_mm"] = -3; }, "field 'tool.radius_mm'"},
      {[](Json& j) { j["surface"]["reference"] = "teapot"; }, "field 'surface.reference'"},
      {[](Json& j) { j["toolpath"]["scallop"] = 3; }, "field 'toolpath.scallop': unknown field"},
      {[](Json& j) { j["probing"]["grid"] = {20}; }, "field 'probing.grid'"},
      {[](Json& j) { j["machine"]["travel_min_mm"] = "far"; }, "field 'machine.travel_min_mm'"},
  };
  for (const Case& c : cases) {
    Json edited = json;
    c.edit(edited);
    const auto part = ParsePart(edited, "bad.json");
    ASSERT_FALSE(part.ok()) << c.expect;
    EXPECT_EQ(part.status().code(), StatusCode::kBadInput);
    EXPECT_EQ(part.status().message().rfind("bad.json", 0), 0u) << part.status().message();
    EXPECT_NE(part.status().message().find(c.expect), std::string::npos) << part.status().message();
  }
  EXPECT_TRUE(fs::is_empty(dir_));
}

TEST_F(RunTest, SafetyLimitStopsTheRunAndLeavesNoRunFolder) {
  auto json = ReadJsonFile(kDemo).value();
  json["machine"]["travel_max_mm"] = {30, 300, 150};  // the saddle spans X -50..50
  const auto part = ParsePart(json, "tight.json");
  ASSERT_TRUE(part.ok());
  RunOptions options;
  options.out = dir_ / "tight";
  const auto summary = RunPart(*part, options);
  ASSERT_FALSE(summary.ok());
  EXPECT_EQ(summary.status().code(), StatusCode::kSafetyLimit);
  EXPECT_NE(summary.status().message().find("outside the travel"), std::string::npos) << summary.status().message();
  EXPECT_FALSE(fs::exists(options.out));
  EXPECT_FALSE(fs::exists(dir_ / "tight" / "toolpath" / "program.ngc"));
  EXPECT_TRUE(fs::exists(dir_ / "tight.failed" / "formloop.log"));
  EXPECT_FALSE(fs::exists(dir_ / "tight.failed" / "toolpath" / "program.ngc")) << "no program beyond the limits";
}

// A folder of the user's at --out is refused, and the message says --force would not replace it either
// (it used to suggest --force, which was then refused too).
TEST_F(RunTest, ExistingRunFolderNeedsForce) {
  fs::create_directories(dir_ / "taken");
  const auto part = ReadPart(kDemo);
  RunOptions options;
  options.out = dir_ / "taken";
  const auto r = RunPart(*part, options);
  EXPECT_EQ(r.status().code(), StatusCode::kBadInput);
  EXPECT_NE(r.status().message().find("formloop did not make it"), std::string::npos) << r.status().message();
  EXPECT_NE(r.status().message().find("even with --force"), std::string::npos) << r.status().message();
  options.force = true;
  EXPECT_EQ(RunPart(*part, options).status().code(), StatusCode::kBadInput);
  EXPECT_TRUE(fs::is_directory(dir_ / "taken"));
}

int RunBinary(const std::string& args, std::string* out) { return testing::RunFormloop(args, out); }

TEST_F(RunTest, BinaryHelpExitCodesAndCleanStdout) {
  std::string out;
  EXPECT_EQ(RunBinary("--help", &out), 0);
  for (const char* sub : {"run", "regress", "surfaces", "kb"}) EXPECT_NE(out.find(sub), std::string::npos) << sub;
  EXPECT_EQ(RunBinary("--version", &out), 0);
  EXPECT_EQ(out, std::string("formloop ") + Version() + "\n");
  EXPECT_EQ(RunBinary("run --help", &out), 0);
  EXPECT_NE(out.find("--out"), std::string::npos);
  EXPECT_EQ(RunBinary("run " + (dir_ / "missing.json").string(), &out), 2);
  EXPECT_EQ(RunBinary("no-such-command", &out), 2);
  EXPECT_EQ(RunBinary("surfaces sample teapot --out " + (dir_ / "x.csv").string(), &out), 2);
  // stdout carries only JSON.
  ASSERT_EQ(RunBinary("surfaces list", &out), 0);
  const auto listed = ParseJson(out, "stdout");
  ASSERT_TRUE(listed.ok()) << out;
  EXPECT_EQ(listed->size(), 9u);
  ASSERT_EQ(RunBinary("kb init " + (dir_ / "cases.db").string(), &out), 0);
  const auto kb = ParseJson(out, "stdout");
  ASSERT_TRUE(kb.ok()) << out;
  EXPECT_EQ((*kb)["journal_mode"], "wal");
  ASSERT_EQ(RunBinary("surfaces export franke --out " + (dir_ / "franke.step").string(), &out), 0);
  EXPECT_TRUE(out.empty()) << "STEP banners must not reach stdout: " << out;
  EXPECT_TRUE(fs::exists(dir_ / "franke.step"));
}

}  // namespace
}  // namespace formloop::app
