// The pipeline with a case library (issue 8): routing, the retain step, learning from a first part,
// batch runs, a killed run, and the regression goldens.

#include <chrono>
#include <csignal>
#include <filesystem>
#include <fstream>
#include <thread>

#include <sys/wait.h>
#include <unistd.h>

#include <gtest/gtest.h>

#include "app/kb_jobs.h"
#include "app/machine_profile.h"
#include "app/part.h"
#include "app/pipeline.h"
#include "app/regress.h"
#include "core/atomic_file.h"
#include "core/json_io.h"
#include "core/log.h"
#include "kb/library.h"
#include "tests/support/run_binary.h"
#include "tests/support/starter_library.h"
#include "tests/support/test_dir.h"

namespace formloop::app {
namespace {

namespace fs = std::filesystem;
const fs::path kData = fs::path(FORMLOOP_SOURCE_DIR) / "data";

class PipelineTest : public ::testing::Test {
 protected:
  void SetUp() override {
    log::SetLevel(log::Level::kWarn);
    dir_ = testing::FreshTestDir("formloop-pipeline");
    kb_ = dir_ / "kb.sqlite";
    fs::copy_file(testing::StarterLibrary(), kb_);
  }
  void TearDown() override { fs::remove_all(dir_); }

  PartSpec Part(const std::string& name) const {
    auto part = ReadPart(kData / "regress" / "parts" / (name + ".json"));
    EXPECT_TRUE(part.ok()) << part.status().ToString();
    return *part;
  }
  RunOptions Options(const std::string& out) const {
    RunOptions o;
    o.out = dir_ / out;
    o.kb = kb_.string();
    o.machine = "virtual";
    return o;
  }
  long long Cases() const {
    auto library = kb::Library::Open(kb_);
    EXPECT_TRUE(library.ok());
    auto stats = (*library)->Stats();
    return stats.ok() ? stats->cases : -1;
  }
  fs::path dir_, kb_;
};

TEST_F(PipelineTest, RetrievesRoutesAndRetainsTheCaseWithTheLearnedModel) {
  const PartSpec part = Part("reg-dome-a");
  const long long before = Cases();
  const auto summary = RunPart(part, Options("dome"));
  ASSERT_TRUE(summary.ok()) << summary.status().ToString();
  EXPECT_GT(summary->similarity, 0.0);
  EXPECT_FALSE(summary->case_uid.empty());
  for (const char* file :
       {"retrieval.json", "plan.json", "report.html", "retain.json", "status.json", "inputs/machine_profile.json",
        "loop-0/diagnosis/diagnosis.json", "loop-0/diagnosis/model.json"}) {
    EXPECT_TRUE(fs::exists(dir_ / "dome" / file)) << file;
  }
  EXPECT_EQ(ReadJsonFile(dir_ / "dome" / "status.json").value()["state"], "complete");
  EXPECT_EQ(ReadJsonFile(dir_ / "dome" / "summary.json").value()["retained"], "added reg-dome-a");
  // vm-mill-a: the worn ball, deflection and thermal growth; the diagnosis names what it finds.
  EXPECT_FALSE(summary->causes.empty());
  EXPECT_EQ(Cases(), before + 1);
  auto library = kb::Library::Open(kb_);
  ASSERT_TRUE(library.ok());
  const auto record = (*library)->GetCase("reg-dome-a");
  ASSERT_TRUE(record.ok());
  const auto& models = record->simulation["effect_models"];
  ASSERT_EQ(models.size(), 1u);
  EXPECT_EQ(models[0]["machine"], "vm-mill-a");
  EXPECT_TRUE(models[0].contains("model"));
  EXPECT_EQ(record->part["outcome"]["within_tolerance"], summary->within_tolerance);
  // A second run of the same part updates its own case instead of adding one.
  const auto again = RunPart(part, Options("dome2"));
  ASSERT_TRUE(again.ok());
  EXPECT_EQ(again->retained, "updated reg-dome-a");
  EXPECT_EQ(again->case_uid, "reg-dome-a") << "the part's own case is now the nearest";
  EXPECT_TRUE(again->precompensated) << "planned with what the first run learned";
  EXPECT_EQ(Cases(), before + 1);
  EXPECT_EQ(summary->route == "default", summary->flag_engineer);
}

// Issue 17 item 9: on the simulation route the correction's record names the plan the run cuts with (the
// tool of plan.json and of the program), never a GA candidate the run does not use; and with --kb given as an
// absolute path, neither the record nor the report names the library's folder.
TEST_F(PipelineTest, SimulationCorrectionNamesThePlanTheProgramUsesAndNoFolderOfTheLibrary) {
  ASSERT_TRUE(kb_.is_absolute());
  const auto summary = RunPart(Part("reg-blade-a"), Options("blade"));
  ASSERT_TRUE(summary.ok()) << summary.status().ToString();
  ASSERT_EQ(summary->route, "simulate") << "reg-blade-a takes the simulation-correction route (its golden)";
  const fs::path run = dir_ / "blade";
  const Json plan = ReadJsonFile(run / "plan.json").value();
  const Json correction = ReadJsonFile(run / "sim_correction.json").value();
  const Json& applied = correction["applied"];
  ASSERT_TRUE(applied.is_object()) << correction.dump(1);
  EXPECT_EQ(applied["tool_number"], plan["toolpath"]["tool_number"]);
  EXPECT_EQ(applied["tool_radius_mm"], plan["toolpath"]["tool_radius_mm"]);
  EXPECT_EQ(applied["scallop_um"], plan["toolpath"]["scallop_um"]);
  EXPECT_FALSE(correction.contains("chosen"));
  // A candidate is either the applied plan (the GA's plan was taken) or labelled as not used.
  if (!correction["candidate"].is_null() && correction["candidate"]["tool_number"] != applied["tool_number"]) {
    EXPECT_NE(applied["decision"].get<std::string>().find("not used"), std::string::npos) << applied.dump();
  }
  const std::string tool = "T" + std::to_string(plan["toolpath"]["tool_number"].get<int>()) + " M6";
  EXPECT_NE(ReadFile(run / "toolpath" / "program.ngc").value().find(tool), std::string::npos) << tool;
  // The library is named by its file name only, in the run folder's records and in the report.
  EXPECT_EQ(ReadJsonFile(run / "retrieval.json").value()["library"], "kb.sqlite");
  EXPECT_EQ(ReadJsonFile(run / "retain.json").value()["library"], "kb.sqlite");
  // The learned model's provenance names the run folder, not its path (it goes into the library and the report).
  const Json retained = ReadJsonFile(run / "retain.json").value();
  EXPECT_EQ(retained.dump().find(dir_.string()), std::string::npos) << "retain.json names the folder " << dir_;
  const std::string html = ReadFile(run / "report.html").value();
  EXPECT_EQ(html.find(dir_.string()), std::string::npos) << "the report names the folder " << dir_;
  EXPECT_NE(html.find(applied["decision"].get<std::string>()), std::string::npos);
}

// Learning pays: a second part of the same family on the same machine, planned with the model learned
// from the first (pre-compensation), against the same part planned without it.
TEST_F(PipelineTest, SecondPartPlannedWithTheLearnedModelHalvesTheFirstCycleError) {
  PartSpec first = Part("reg-dome-a");
  ASSERT_TRUE(RunPart(first, Options("first")).ok());
  PartSpec second = first;
  second.name = "reg-dome-a-second";
  second.surface_params["size_mm"] *= 1.02;
  second.surface_params["radius_ratio"] *= 0.98;
  second.seed += 17;
  RunOptions with = Options("with");
  with.retain = false;
  const auto learned = RunPart(second, with);
  ASSERT_TRUE(learned.ok()) << learned.status().ToString();
  EXPECT_EQ(learned->case_uid, "reg-dome-a") << "the first part is the nearest case";
  EXPECT_TRUE(learned->precompensated);
  RunOptions without = with;
  without.out = dir_ / "without";
  without.learn = false;
  const auto plain = RunPart(second, without);
  ASSERT_TRUE(plain.ok()) << plain.status().ToString();
  EXPECT_FALSE(plain->precompensated);
  const double e_with = learned->loops.front().form_error_um, e_without = plain->loops.front().form_error_um;
  std::cerr << "first-cycle form error: " << e_with << " um with the learned model, " << e_without
            << " um without (ratio " << e_with / e_without << ")\n";
  EXPECT_LE(e_with, 0.5 * e_without);
  // The calibration report counts the retained outcome of the first part under the route it took.
  std::string out, err;
  ASSERT_EQ(testing::RunFormloop("kb calibrate " + kb_.string() + " --rerun", &out, &err), 0) << err;
  const Json report = ParseJson(out, "kb calibrate").value();
  int parts = 0, within = 0;
  for (const auto& [name, r] : report["outcomes"]["by_route"].items()) {
    parts += r["parts"].get<int>();
    within += r["within_tolerance_after_at_most_one_loop"].get<int>();
  }
  EXPECT_EQ(parts, 1) << "only the first part was retained";
  EXPECT_EQ(within, 1);
  EXPECT_EQ(report["outcomes"]["cases_without_pipeline_outcome"], 252) << "the starter cases";
  EXPECT_EQ(report["retrieval"]["cases"], 253);
  // Leave-one-out by machining: the first part run again on the library without it, which is the
  // starter library it was first run on, so the rerun reproduces what was recorded: same route, case,
  // A and first-cycle form error (same seed, same virtual machine).
  const Json& rerun = report["rerun"];
  ASSERT_EQ(rerun["parts"], 1);
  EXPECT_EQ(rerun["failed"], 0);
  const Json& row = rerun["per_part"][0];
  EXPECT_EQ(row["uid"], "reg-dome-a");
  EXPECT_EQ(row["route"], row["recorded"]["route"]);
  EXPECT_EQ(row["case"], row["recorded"]["retrieved_case"]);
  EXPECT_NEAR(row["similarity"].get<double>(), row["recorded"]["similarity"].get<double>(), 1e-12);
  EXPECT_NEAR(row["form_error_first_um"].get<double>(), row["recorded"]["form_error_first_um"].get<double>(), 1e-9);
  const Json& route = rerun["by_route"][row["route"].get<std::string>()];
  EXPECT_EQ(route["parts"], 1);
  EXPECT_EQ(route["within_tolerance_after_at_most_one_loop"], row["loops_to_tolerance"].get<int>() <= 1 ? 1 : 0);
}

TEST_F(PipelineTest, KilledRunIsMarkedIncompleteLeavesTheLibraryAloneAndRerunCompletes) {
  const fs::path part_file = kData / "regress" / "parts" / "reg-dome-a.json";
  const fs::path out = dir_ / "killed";
  fs::path partial = out;
  partial += ".partial";
  auto library = kb::Library::Open(kb_);
  ASSERT_TRUE(library.ok());
  const std::string before = (*library)->ExportText().value();
  library->reset();
  const pid_t child = ::fork();
  ASSERT_GE(child, 0);
  if (child == 0) {
    const std::string kb = kb_.string(), o = out.string(), p = part_file.string();
    ::execl(FORMLOOP_BINARY, FORMLOOP_BINARY, "--quiet", "run", p.c_str(), "--kb", kb.c_str(), "--out", o.c_str(),
            static_cast<char*>(nullptr));
    ::_exit(127);
  }
  // Kill it once it is machining (loop-0 exists), long before the retain step.
  for (int i = 0; i < 600 && !fs::exists(partial / "loop-0"); ++i)
    std::this_thread::sleep_for(std::chrono::milliseconds(10));
  ASSERT_EQ(::kill(child, SIGKILL), 0);
  int status = 0;
  ::waitpid(child, &status, 0);
  ASSERT_TRUE(WIFSIGNALED(status)) << "the run finished before the kill";
  EXPECT_FALSE(fs::exists(out));
  const auto marker = ReadJsonFile(partial / "status.json");
  ASSERT_TRUE(marker.ok());
  EXPECT_EQ((*marker)["state"], "incomplete");
  library = kb::Library::Open(kb_);
  ASSERT_TRUE(library.ok());
  EXPECT_EQ((*library)->ExportText().value(), before) << "the case library changed";
  library->reset();
  // Rerunning the same command completes it.
  std::string stdout_text, stderr_text;
  const int code = testing::RunFormloop(
      "run " + part_file.string() + " --kb " + kb_.string() + " --out " + out.string(), &stdout_text, &stderr_text);
  EXPECT_EQ(code, 0) << stderr_text;
  EXPECT_NE(stderr_text.find("incomplete run"), std::string::npos);
  EXPECT_EQ(ReadJsonFile(out / "status.json").value()["state"], "complete");
  EXPECT_FALSE(fs::exists(partial));
  EXPECT_TRUE(kb::Library::Open(kb_).value()->GetCase("reg-dome-a").ok());
}

TEST_F(PipelineTest, BatchRunsEveryPartAndOneFailureDoesNotStopTheOthers) {
  const fs::path parts = dir_ / "parts";
  fs::create_directories(parts);
  fs::copy_file(kData / "parts" / "demo-saddle.json", parts / "a-demo.json");
  Json broken = ReadJsonFile(kData / "parts" / "demo-saddle.json").value();
  broken["name"] = "b-broken";
  broken["tolerance_mm"] = -1;
  ASSERT_TRUE(WriteJsonFile(parts / "b-broken.json", broken).ok());
  Json other = ReadJsonFile(kData / "parts" / "demo-saddle.json").value();
  other["name"] = "c-demo";
  other["seed"] = 7;
  ASSERT_TRUE(WriteJsonFile(parts / "c-demo.json", other).ok());
  std::string out, err;
  const int code = testing::RunFormloop("run " + parts.string() + " --out " + (dir_ / "batch").string(), &out, &err);
  EXPECT_EQ(code, 1) << err;
  const auto batch = ReadJsonFile(dir_ / "batch" / "batch_summary.json");
  ASSERT_TRUE(batch.ok());
  EXPECT_EQ((*batch)["count"], 3);
  EXPECT_EQ((*batch)["failed"], 1);
  EXPECT_EQ((*batch)["parts"][1]["status"], "failed");
  EXPECT_NE((*batch)["parts"][1]["error"].get<std::string>().find("tolerance_mm"), std::string::npos);
  // One run folder per part, named after the part (a-demo.json holds part "demo-saddle").
  EXPECT_TRUE(fs::exists(dir_ / "batch" / "demo-saddle" / "summary.json"));
  EXPECT_TRUE(fs::exists(dir_ / "batch" / "c-demo" / "summary.json"));
  EXPECT_NE(err.find("c-demo"), std::string::npos) << "the summary table lists every part";
}

// A real machine's probe log instead of the virtual machine: one analysis cycle, the compensated
// program for the next cut, and the outcome retained.
TEST_F(PipelineTest, MeasuredLogGivesOneCycleAndTheCompensatedProgram) {
  const PartSpec part = Part("reg-dome-a");
  ASSERT_TRUE(RunPart(part, Options("virtual")).ok());
  RunOptions measured = Options("measured");
  measured.machine.clear();
  measured.measured = {(dir_ / "virtual" / "loop-0" / "probe_log.csv").string()};
  const auto summary = RunPart(part, measured);
  ASSERT_TRUE(summary.ok()) << summary.status().ToString();
  ASSERT_EQ(summary->loops.size(), 1u);
  EXPECT_TRUE(summary->loops[0].compensated);
  EXPECT_TRUE(fs::exists(dir_ / "measured" / "loop-0" / "program_compensated.ngc"));
  EXPECT_TRUE(fs::exists(dir_ / "measured" / "inputs" / "measured" / "loop-0.csv"));
  EXPECT_FALSE(fs::exists(dir_ / "measured" / "inputs" / "machine_profile.json")) << "no virtual machine was used";
  measured.machine = "virtual";
  measured.out = dir_ / "both";
  const auto both = RunPart(part, measured);
  ASSERT_FALSE(both.ok());
  EXPECT_NE(both.status().message().find("--measured"), std::string::npos);
  // A log with an id of another plan is refused naming the user's file and its line, not the run
  // folder's copy (which is gone by then: the failed run's folder is renamed).
  std::string text = ReadFile((dir_ / "virtual" / "loop-0" / "probe_log.csv").string()).value();
  const std::size_t row = text.find("\n3,");
  ASSERT_NE(row, std::string::npos);
  text.replace(row + 1, 1, "99999");
  const fs::path other = dir_ / "other-plan.csv";
  { std::ofstream(other) << text; }
  measured.machine.clear();
  measured.measured = {other.string()};
  measured.out = dir_ / "other";
  const auto refused = RunPart(part, measured);
  ASSERT_FALSE(refused.ok());
  const std::string why = refused.status().ToString();
  EXPECT_NE(why.find(other.string() + ":5: field 'id': id 99999 is not in the probing plan"), std::string::npos) << why;
  EXPECT_EQ(why.find("probe_log.csv"), std::string::npos) << why;
}

TEST_F(PipelineTest, AParametricSurfaceWithNoSurfaceIsRefusedNamingIt) {
  Json json = ReadJsonFile(kData / "regress" / "parts" / "reg-dome-a.json").value();
  json["surface"]["params"]["radius_ratio"] = 0.5;  // the sphere is smaller than its square footprint
  const auto part = ParsePart(json, "dome.json");
  ASSERT_FALSE(part.ok());
  EXPECT_EQ(part.status().code(), StatusCode::kBadInput);
  for (const char* text : {"dome.json", "surface.sphere_cap", "no surface"}) {
    EXPECT_NE(part.status().message().find(text), std::string::npos) << part.status().message();
  }
}

// Where Q is concave below the ball radius the ball is lifted out of it and that region is left uncut:
// the run says so in its summary and its report (before, only toolpath/toolpath.json held the counts and
// the log and report were silent, while `nc path` warned).
TEST_F(PipelineTest, ARegionLeftUncutIsInTheSummaryAndTheReport) {
  const Json json = Json::parse(R"({"name": "concave", "surface": {"reference": "egg_box"}, "tolerance_mm": 0.5,
    "tool": {"number": 1, "radius_mm": 25}, "fit": {"samples_u": 20, "samples_v": 20, "check_points": 100},
    "machine": {"name": "vm-mill-a"}, "probing": {"grid": [6, 6]}, "loops": {"max": 1},
    "toolpath": {"scallop_um": 200, "chord_tolerance_um": 20, "max_point_spacing_mm": 4}})");
  const auto part = ParsePart(json, "concave.json");
  ASSERT_TRUE(part.ok()) << part.status().ToString();
  RunOptions o = Options("concave");
  o.kb.clear();
  ASSERT_TRUE(RunPart(*part, o).ok());
  const Json summary = ReadJsonFile(dir_ / "concave" / "summary.json").value();
  const Json& toolpath = summary.at("toolpath");
  const Json report = ReadJsonFile(dir_ / "concave" / "toolpath" / "toolpath.json").value();
  EXPECT_GT(toolpath.at("lifted_points").get<int>(), 0);
  EXPECT_EQ(toolpath.at("lifted_points"), report.at("lifted_points"));
  EXPECT_GT(toolpath.at("max_lift_mm").get<double>(), 0);
  ASSERT_EQ(toolpath.at("uncut_box_mm").size(), 2u);
  const std::string html = ReadFile(dir_ / "concave" / "report.html").value();
  EXPECT_NE(html.find("Region left uncut:"), std::string::npos);
  // A part with no such region says nothing of it.
  ASSERT_TRUE(RunPart(Part("reg-dome-a"), Options("dome")).ok());
  EXPECT_EQ(ReadJsonFile(dir_ / "dome" / "summary.json").value().at("toolpath").at("lifted_points"), 0);
  EXPECT_EQ(ReadFile(dir_ / "dome" / "report.html").value().find("Region left uncut"), std::string::npos);
}

TEST_F(PipelineTest, MachineProfilesAreCheckedWithTheField) {
  Json profile = ReadJsonFile(kData / "machines" / "vm-mill-a.json").value();
  EXPECT_TRUE(MachineProfile::FromJson(profile, "p.json").ok());
  Json bad = profile;
  bad["format"] = "something";
  auto r = MachineProfile::FromJson(bad, "p.json");
  ASSERT_FALSE(r.ok());
  EXPECT_NE(r.status().message().find("format"), std::string::npos);
  bad = profile;
  bad["model"]["effects"][0]["name"] = "tool_radiuss";
  r = MachineProfile::FromJson(bad, "p.json");
  ASSERT_FALSE(r.ok());
  EXPECT_NE(r.status().message().find("tool_radiuss"), std::string::npos) << r.status().message();
  bad = profile;
  bad["version"] = 2;
  EXPECT_FALSE(MachineProfile::FromJson(bad, "p.json").ok());
  EXPECT_FALSE(ReadMachineProfile("no-such-machine", kData).ok());
}

// `formloop regress` fails when a golden figure is perturbed and passes again after --update.
TEST_F(PipelineTest, RegressFailsOnAPerturbedGoldenAndPassesAfterUpdate) {
  const fs::path goldens = dir_ / "goldens";
  const std::string args =
      "regress --only reg-dome-a --goldens " + goldens.string() + " --out " + (dir_ / "r").string();
  std::string out, err;
  ASSERT_EQ(testing::RunFormloop(args + " --update", &out, &err), 0) << err;  // goldens of this subset
  ASSERT_EQ(testing::RunFormloop(args, &out, &err), 0) << err;
  // The truth line (issue 20): on this dome a z scale fits the 8 µm ball and the deflection of vm-mill-a
  // with one parameter; it is reported in an alias group with them, never named.
  const Json table = Json::parse(out);
  EXPECT_EQ(table["truth"]["named_not_in_profile"], 0) << table["parts"][0]["truth"].dump();
  EXPECT_EQ(table["truth"]["true_missed"], 0) << table["parts"][0]["truth"].dump();
  Json golden = ReadJsonFile(goldens / "reg-dome-a.json").value();
  golden["figures"]["form_error_um"][0] = golden["figures"]["form_error_um"][0].get<double>() * 1.5;
  ASSERT_TRUE(WriteJsonFile(goldens / "reg-dome-a.json", golden).ok());
  EXPECT_EQ(testing::RunFormloop(args, &out, &err), 1);
  EXPECT_NE(err.find("form_error_um: golden"), std::string::npos) << err;
  EXPECT_EQ(testing::RunFormloop(args + " --update", &out, &err), 0) << err;
  EXPECT_NE(err.find("updated form_error_um"), std::string::npos) << err;
  EXPECT_EQ(testing::RunFormloop(args, &out, &err), 0) << err;
}

TEST(RegressFigures, ComparisonUsesTheStatedTolerances) {
  const Json golden = {
      {"route", "direct"}, {"similarity", 0.97}, {"form_error_um", {20.0, 4.0}}, {"causes", {"tool_radius"}}};
  Json value = golden;
  value["similarity"] = 0.9715;          // within 0.002
  value["form_error_um"] = {21.5, 4.3};  // within 0.5 + 10 %
  EXPECT_TRUE(CompareFigures(golden, value).empty());
  value["form_error_um"] = {23.0, 4.3};  // 3 um off 20: outside 0.5 + 2
  ASSERT_EQ(CompareFigures(golden, value).size(), 1u);
  value = golden;
  value["causes"] = {"tool_radius", "thermal_drift_z"};
  ASSERT_EQ(CompareFigures(golden, value).size(), 1u);
  value = golden;
  value["form_error_um"] = {20.0};  // a loop fewer is a change
  EXPECT_EQ(CompareFigures(golden, value).size(), 1u);
  value = golden;
  value.erase("route");
  EXPECT_EQ(CompareFigures(golden, value).size(), 1u);
}

}  // namespace
}  // namespace formloop::app
