// `formloop run` with a separating experiment (issue 20; part file "separating_experiment", docs/formats.md):
// the first part of a machine whose tool radius and probe radius are both off cannot tell them apart and
// proposes a tilted re-probe, which the case library keeps with its learned model; the next part (another
// shape, same machine/tool/material) asking for the library's experiment is probed with the tilted points,
// its probing program and log carry them, and its own diagnosis no longer holds the radii in one group;
// `formloop simulate --run` of that run probes its tilted points along their approaches.

#include <algorithm>
#include <cctype>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <map>
#include <string>

#include <gtest/gtest.h>

#include "app/model_jobs.h"
#include "app/part.h"
#include "app/pipeline.h"
#include "app/run_folder.h"
#include "core/atomic_file.h"
#include "core/json_io.h"
#include "core/log.h"
#include "kb/library.h"
#include "metrology/probe.h"
#include "tests/support/starter_library.h"
#include "tests/support/test_dir.h"

namespace formloop::app {
namespace {

namespace fs = std::filesystem;
const fs::path kParts = fs::path(FORMLOOP_SOURCE_DIR) / "data" / "regress" / "parts";

class SeparatingExperimentTest : public ::testing::Test {
 protected:
  void SetUp() override {
    log::SetLevel(log::Level::kWarn);
    dir_ = testing::FreshTestDir("formloop-separating");
    kb_ = dir_ / "kb.sqlite";
    fs::copy_file(testing::StarterLibrary(), kb_);
  }
  void TearDown() override { fs::remove_all(dir_); }

  // A regression part's surface on machine "vm-radii" with a 3 mm ball in H13: the ball 10 µm over size,
  // the probe's effective radius 8 µm over its calibration; one cycle, 16 × 16 probes.
  Json PartJson(const std::string& from, const std::string& name, const Json& experiment) const {
    Json j = ReadJsonFile(kParts / (from + ".json")).value();
    j["name"] = name;
    j["machine"] = {{"name", "vm-radii"},
                    {"effects",
                     {{"format", "formloop-model"},
                      {"version", 1},
                      {"effects",
                       {{{"name", "tool_radius"}, {"parameters", {{"delta_r_um", 10.0}}}},
                        {{"name", "probe_radius"}, {"parameters", {{"delta_r_eff_um", 8.0}}}},
                        {{"name", "noise"}, {"parameters", {{"surface_sigma_um", 0.8}, {"probe_sigma_um", 0.5}}}}}}}}};
    // The same tool and material on every part (the learned model's key with the machine).
    j["material"] = "H13";
    j["tool"] = {{"number", 4}, {"radius_mm", 3.0}, {"flutes", 2}};
    j["tools"] = Json::array({{{"number", 4}, {"radius_mm", 3.0}}});
    j["probing"] = {{"grid", {16, 16}}};
    j["loops"] = {{"max", 1}};
    if (!experiment.is_null()) j["separating_experiment"] = experiment;
    return j;
  }
  Result<RunSummary> Run(const Json& part_json, const std::string& out, bool learn = false) const {
    const fs::path file = dir_ / (out + ".json");
    EXPECT_TRUE(WriteJsonFile(file, part_json).ok());
    FL_ASSIGN_OR_RETURN(const PartSpec part, ReadPart(file));
    RunOptions o;
    o.out = dir_ / out;
    o.kb = kb_.string();
    o.machine = "virtual";
    o.part_source = file.string();
    o.learn = learn;  // false: each part diagnosed against the nominal model, what its own data say
    if (learn) o.pool_cases = 0;
    return RunPart(part, o);
  }
  fs::path dir_, kb_;
};

TEST_F(SeparatingExperimentTest, TheNextPartIsProbedWithTheLibrarysTiltedReprobe) {
  const auto first = Run(PartJson("reg-dome-a", "radii-dome", "library"), "first");
  ASSERT_TRUE(first.ok()) << first.status().ToString();
  const fs::path run1 = dir_ / "first";
  const Json applied1 = ReadJsonFile(run1 / "toolpath" / "separating_experiment.json").value();
  EXPECT_EQ(applied1["points_added"], 0);
  EXPECT_NE(applied1["source"].get<std::string>().find("none in the case library"), std::string::npos);
  const Json d1 = ReadJsonFile(run1 / "loop-0" / "diagnosis" / "diagnosis.json").value();
  bool grouped = false;
  for (const auto& g : d1["alias_groups"]) {
    const std::string members = g["members"].dump();
    grouped = grouped ||
              (members.find("tool_radius") != std::string::npos && members.find("probe_radius") != std::string::npos);
  }
  ASSERT_TRUE(grouped) << "probed along -n the two radii are one alias group: " << d1["alias_groups"].dump();
  const Json proposals = ReadJsonFile(run1 / "loop-0" / "diagnosis" / "proposals.json").value();
  ASSERT_FALSE(proposals["proposals"].empty());
  // The library keeps the proposal with the learned model of vm-radii.
  {
    auto library = kb::Library::Open(kb_.string());
    ASSERT_TRUE(library.ok());
    const auto record = (*library)->GetCase("radii-dome");
    ASSERT_TRUE(record.ok()) << record.status().ToString();
    const Json& models = record->simulation["effect_models"];
    ASSERT_EQ(models.size(), 1u);
    EXPECT_EQ(models[0]["machine"], "vm-radii");
    ASSERT_TRUE(models[0].contains("separating_experiments"));
    EXPECT_EQ(models[0]["separating_experiments"].size(), proposals["proposals"].size());
  }

  const auto second = Run(PartJson("reg-eggbox-a", "radii-eggbox", "library"), "second");
  ASSERT_TRUE(second.ok()) << second.status().ToString();
  const fs::path run2 = dir_ / "second";
  const Json applied2 = ReadJsonFile(run2 / "toolpath" / "separating_experiment.json").value();
  EXPECT_EQ(applied2["source"], "case library, case radii-dome");
  const int added = applied2["points_added"].get<int>();
  ASSERT_GT(added, 0) << applied2.dump();
  // The plan, its approaches, the probing program and the log all hold the tilted points.
  const Json plan = ReadJsonFile(run2 / "toolpath" / "probing_plan.json").value();
  EXPECT_EQ(plan["points"].size(), static_cast<std::size_t>(16 * 16 + added));
  EXPECT_TRUE(fs::exists(run2 / "toolpath" / "probing_plan.csv"));
  std::ifstream program(run2 / "toolpath" / "probe.ngc");
  const std::string text((std::istreambuf_iterator<char>(program)), std::istreambuf_iterator<char>());
  const std::string last_id = std::to_string(16 * 16 + added);
  EXPECT_NE(text.find("(point " + last_id + ")"), std::string::npos);
  std::ifstream log_file(run2 / "loop-0" / "probe_log.csv");
  int records = 0;  // data lines (a digit first; the header and comments are not)
  for (std::string line; std::getline(log_file, line);) records += !line.empty() && std::isdigit(line[0]) ? 1 : 0;
  EXPECT_EQ(records, 16 * 16 + added);
  // The second part's own diagnosis (its tilted points included) no longer holds the radii in one alias
  // group, names nothing that is not there, and every named value's interval holds the truth. (With 16
  // tilted points of 272 the probe radius's own share, 8 µm × (1 − cos 30°) at those points, is near the
  // noise: it may stay unnamed, and the tool radius's interval then spans it — the extreme-bounds
  // interval of simulation/diagnose.h.)
  const Json d2 = ReadJsonFile(run2 / "loop-0" / "diagnosis" / "diagnosis.json").value();
  std::printf("second part: causes %s\nalias groups %s\n", d2["causes"].dump().c_str(),
              d2["alias_groups"].dump().c_str());
  for (const auto& g : d2["alias_groups"]) {
    const std::string members = g["members"].dump();
    EXPECT_FALSE(members.find("tool_radius") != std::string::npos && members.find("probe_radius") != std::string::npos)
        << members;
  }
  ASSERT_FALSE(d2["causes"].empty());
  const std::map<std::string, std::pair<std::string, double>> truth = {{"tool_radius", {"delta_r_um", 10.0}},
                                                                       {"probe_radius", {"delta_r_eff_um", 8.0}}};
  for (const auto& c : d2["causes"]) {
    const std::string effect = c["effect"].get<std::string>();
    const auto t = truth.find(effect);
    ASSERT_NE(t, truth.end()) << effect << " named falsely";
    const Json& interval = c["interval_95"][t->second.first];
    EXPECT_LE(interval[0].get<double>(), t->second.second) << effect;
    EXPECT_GE(interval[1].get<double>(), t->second.second) << effect;
  }

  // `formloop simulate --run` probes the run's tilted points along the approaches the run planned
  // (toolpath/probing_plan.csv), as if the plan CSV were given with --probe-plan: the same log, byte for byte.
  ASSERT_TRUE(WriteJsonFile(dir_ / "model.json",
                            {{"format", "formloop-model"},
                             {"version", 1},
                             {"effects", {{{"name", "probe_radius"}, {"parameters", {{"delta_r_eff_um", 8.0}}}}}}})
                  .ok());
  SimulateArgs sim{.run = run2.string(), .model = (dir_ / "model.json").string(), .out = (dir_ / "sim.csv").string()};
  ASSERT_TRUE(RunSimulate(sim).ok());
  SimulateArgs given = sim;
  given.probe_plan = (run2 / "toolpath" / "probing_plan.csv").string();
  given.out = (dir_ / "sim_given.csv").string();
  ASSERT_TRUE(RunSimulate(given).ok());
  const auto simulated = metrology::ReadProbeLog(dir_ / "sim.csv");
  const auto approaches = ReadPlanFile(run2 / "toolpath" / "probing_plan.csv");
  ASSERT_TRUE(simulated.ok() && approaches.ok());
  ASSERT_EQ(simulated->records.size(), approaches->approaches.size());
  int tilted = 0;
  for (std::size_t i = 0; i < simulated->records.size(); ++i) {
    const auto& r = simulated->records[i];
    EXPECT_LT((r.approach - approaches->approaches[i]).norm(), 1e-6) << "point " << r.id;
    tilted += r.approach.dot(-approaches->plan.points[i].normal) < 0.99 ? 1 : 0;
  }
  EXPECT_EQ(tilted, added);
  std::ifstream a(dir_ / "sim.csv"), b(dir_ / "sim_given.csv");
  const std::string text_a((std::istreambuf_iterator<char>(a)), std::istreambuf_iterator<char>());
  const std::string text_b((std::istreambuf_iterator<char>(b)), std::istreambuf_iterator<char>());
  EXPECT_EQ(text_a, text_b);

  // `formloop diagnose --run` of that run reads the same folder, its approaches checked against the plan,
  // and diagnoses every point of the simulated log; the probe radius is among its findings.
  DiagnoseArgs da{.measured = (dir_ / "sim.csv").string(), .run = run2.string(), .out = (dir_ / "diag").string()};
  da.propose = false;
  const auto diagnosed = RunDiagnose(da);
  ASSERT_TRUE(diagnosed.ok()) << diagnosed.status().ToString();
  EXPECT_EQ((*diagnosed)["n"].get<std::size_t>(), simulated->records.size());
  EXPECT_NE(((*diagnosed)["causes"].dump() + (*diagnosed)["alias_groups"].dump()).find("probe_radius"),
            std::string::npos)
      << diagnosed->dump();
  // A run folder whose approach file is not of the JSON plan's points is refused naming the file and row.
  const fs::path copied = dir_ / "copied";
  fs::copy(run2, copied, fs::copy_options::recursive);
  // The first two data rows (after the header) swapped: the first row holds the plan's second point.
  std::ifstream csv_in(copied / "toolpath" / "probing_plan.csv");
  std::vector<std::string> lines;
  for (std::string line; std::getline(csv_in, line);) lines.push_back(line);
  csv_in.close();
  // The header is the first line that is no '#' comment (formloop's marker line comes first).
  std::size_t header = 0;
  while (header < lines.size() && !lines[header].empty() && lines[header][0] == '#') ++header;
  ASSERT_GE(lines.size(), header + 3);
  std::swap(lines[header + 1], lines[header + 2]);
  std::string csv;
  for (const auto& line : lines) csv += line + "\n";
  ASSERT_TRUE(WriteFileAtomic(copied / "toolpath" / "probing_plan.csv", csv).ok());
  const auto mismatched = ReadRunFolder(copied);
  ASSERT_FALSE(mismatched.ok());
  EXPECT_NE(mismatched.status().ToString().find("probing_plan.csv"), std::string::npos)
      << mismatched.status().ToString();
  EXPECT_NE(mismatched.status().ToString().find("is not the point of toolpath/probing_plan.json"), std::string::npos)
      << mismatched.status().ToString();
}

// The readings the proposal asks for, taken and given to `formloop run` with the part
// ("direct_measurements", the format of `formloop diagnose --direct`): the tool setter and the reference
// sphere tell the two radii apart on the very part whose probe log alone groups them (the test above);
// both are named, each interval holding the truth (10 and 8 µm), and the run folder's resolved part holds
// the readings. Bad readings are refused naming the file and the field.
TEST_F(SeparatingExperimentTest, ThePartsReadingsTellTheRadiiApart) {
  const Json readings = {{"direct_measurements",
                          {{{"effect", "tool_radius"},
                            {"parameter", "delta_r_um"},
                            {"value", 10.6},
                            {"sigma", 1.0},
                            {"by", "tool setter"}},
                           {{"effect", "probe_radius"},
                            {"parameter", "delta_r_eff_um"},
                            {"value", 7.7},
                            {"sigma", 0.5},
                            {"by", "reference sphere"}}}}};
  ASSERT_TRUE(WriteJsonFile(dir_ / "readings.json", readings).ok());
  Json part = PartJson("reg-dome-a", "radii-read", nullptr);
  part["direct_measurements"] = "readings.json";
  const auto run = Run(part, "read");
  ASSERT_TRUE(run.ok()) << run.status().ToString();
  const Json d = ReadJsonFile(dir_ / "read" / "loop-0" / "diagnosis" / "diagnosis.json").value();
  ASSERT_TRUE(d.contains("direct_measurements")) << d.dump();
  EXPECT_EQ(d["direct_measurements"].size(), 2u);
  EXPECT_FALSE(d.contains("direct_not_used"));
  std::printf("with the readings: causes %s\nalias groups %s\n", d["causes"].dump().c_str(),
              d["alias_groups"].dump().c_str());
  for (const auto& g : d["alias_groups"]) {
    const std::string members = g["members"].dump();
    EXPECT_FALSE(members.find("tool_radius") != std::string::npos && members.find("probe_radius") != std::string::npos)
        << "the readings split the radii: " << d["alias_groups"].dump();
  }
  const std::map<std::string, std::pair<std::string, double>> truth = {{"tool_radius", {"delta_r_um", 10.0}},
                                                                       {"probe_radius", {"delta_r_eff_um", 8.0}}};
  for (const auto& [effect, parameter] : truth) {
    bool named = false;
    for (const auto& c : d["causes"]) {
      if (c["effect"] != effect) continue;
      named = true;
      const Json& interval = c["interval_95"][parameter.first];
      EXPECT_LE(interval[0].get<double>(), parameter.second) << c.dump();
      EXPECT_GE(interval[1].get<double>(), parameter.second) << c.dump();
    }
    EXPECT_TRUE(named) << effect << " not named: " << d["causes"].dump();
  }
  // The run folder's part is itself a part file holding the readings inline.
  const Json resolved = ReadJsonFile(dir_ / "read" / "inputs" / "part.json").value();
  ASSERT_TRUE(resolved.contains("direct_measurements"));
  const auto again = ParsePart(resolved, "resolved");
  ASSERT_TRUE(again.ok()) << again.status().ToString();
  ASSERT_EQ(again->direct.size(), 2u);
  EXPECT_EQ(again->direct[1].by, "reference sphere");

  // The same part again, planned with the learned model of this one (retrieved), not pooled: the model holds
  // the radii the readings named, which that part's diagnosis does not estimate again, so each reading of
  // an effect the model holds is said not to be used (with why) and the run goes on.
  Json next = PartJson("reg-dome-a", "radii-next", nullptr);  // retrieves radii-read: the same description
  next["direct_measurements"] = readings["direct_measurements"];
  const auto learned_run = Run(next, "next", true);
  ASSERT_TRUE(learned_run.ok()) << learned_run.status().ToString();
  const Json dn = ReadJsonFile(dir_ / "next" / "loop-0" / "diagnosis" / "diagnosis.json").value();
  std::printf("learned baseline: %s\nnot used: %s\n", dn["baseline"].dump().c_str(),
              dn.value("direct_not_used", Json()).dump().c_str());
  const Json& baseline = dn["baseline_model"]["effects"];
  std::size_t held = 0;
  for (const auto& e : baseline) held += e["name"] == "tool_radius" || e["name"] == "probe_radius";
  ASSERT_GT(held, 0u) << dn["baseline_model"].dump();
  ASSERT_TRUE(dn.contains("direct_not_used"));
  EXPECT_EQ(dn["direct_not_used"].size(), held);
  EXPECT_EQ(dn.value("direct_measurements", Json::array()).size(), 2 - held);
  for (const auto& n : dn["direct_not_used"]) {
    EXPECT_NE(n["why"].get<std::string>().find("learned model of case radii-read"), std::string::npos) << n.dump();
  }

  auto refused = [&](const Json& value, const std::string& file, const std::string& expected) {
    Json bad = PartJson("reg-dome-a", "bad", nullptr);
    bad["direct_measurements"] = value;
    ASSERT_TRUE(WriteJsonFile(dir_ / "bad.json", bad).ok());
    const auto r = ReadPart(dir_ / "bad.json");
    ASSERT_FALSE(r.ok()) << value.dump();
    const std::string message(r.status().message());
    EXPECT_NE(message.find(file), std::string::npos) << message;
    EXPECT_NE(message.find(expected), std::string::npos) << message;
  };
  refused("missing.json", "missing.json", "missing.json");
  refused(7, "bad.json", "direct_measurements");
  refused(Json::array({{{"effect", "tool_radius"}, {"parameter", "delta_r_um"}, {"sigma", 1}}}), "bad.json",
          "direct_measurements[0].value");
  refused(
      Json::array({{{"effect", "setup_offset"}, {"parameter", "tz_um"}, {"value", 3}, {"sigma", 1}, {"part", "B"}}}),
      "bad.json", "direct_measurements[0].part");
  Json wrong_sigma = readings;
  wrong_sigma["direct_measurements"][1]["sigma"] = 0;
  ASSERT_TRUE(WriteJsonFile(dir_ / "bad_readings.json", wrong_sigma).ok());
  refused("bad_readings.json", "bad_readings.json", "direct_measurements[1]");
}

TEST_F(SeparatingExperimentTest, APartWithoutTheOptionWritesNothingNewAndBadValuesAreRefused) {
  const auto plain = Run(PartJson("reg-dome-a", "radii-plain", nullptr), "plain");
  ASSERT_TRUE(plain.ok()) << plain.status().ToString();
  EXPECT_FALSE(fs::exists(dir_ / "plain" / "toolpath" / "separating_experiment.json"));
  EXPECT_FALSE(fs::exists(dir_ / "plain" / "toolpath" / "probing_plan.csv"));
  EXPECT_FALSE(fs::exists(dir_ / "plain" / "loop-0" / "diagnosis" / "proposals.json"));
  EXPECT_FALSE(ReadJsonFile(dir_ / "plain" / "inputs" / "part.json").value().contains("separating_experiment"));

  auto refused = [&](const Json& experiment, const std::string& expected) {
    const fs::path file = dir_ / "bad.json";
    ASSERT_TRUE(WriteJsonFile(file, PartJson("reg-dome-a", "bad", experiment)).ok());
    const auto part = ReadPart(file);
    ASSERT_FALSE(part.ok()) << experiment.dump();
    EXPECT_NE(part.status().message().find(expected), std::string::npos) << part.status().message();
  };
  refused(42, "separating_experiment");
  refused("missing.json", "missing.json");
  refused(Json{{"proposals", Json::array()}}, "holds no proposal");
  refused(Json{{"proposals",
                {{{"alias_group", {"a", "b"}},
                  {"kind", "reprobe"},
                  {"points", {{{"s", 1.5}, {"t", 0.5}, {"tilt_deg", 30}, {"azimuth_deg", 0}}}}}}}},
          "separating_experiment.proposals[0].points[0].s");
  // An inline proposal survives the resolved part (inputs/part.json is itself a valid part file).
  const Json inline_turn = {
      {"proposals",
       {{{"alias_group", {"a", "b"}}, {"kind", "raster_turn"}, {"raster_turn_deg", 90}, {"feed_scale", 1}}}}};
  const fs::path file = dir_ / "turn.json";
  ASSERT_TRUE(WriteJsonFile(file, PartJson("reg-dome-a", "turn", inline_turn)).ok());
  const auto part = ReadPart(file);
  ASSERT_TRUE(part.ok()) << part.status().ToString();
  ASSERT_EQ(part->proposals.size(), 1u);
  const auto again = ParsePart(part->ToJson(), "resolved");
  ASSERT_TRUE(again.ok()) << again.status().ToString();
  EXPECT_EQ(again->proposals.size(), 1u);
  EXPECT_EQ(again->proposals[0].raster_turn_deg, 90.0);

  // The probe's least gap and shank (the clearance check of the probing program): a resolved part keeps
  // them only when the part set them (earlier runs' resolved parts stay as they were) and reads them back.
  EXPECT_FALSE(ReadJsonFile(dir_ / "plain" / "inputs" / "part.json").value()["probing"].contains("min_gap_mm"));
  Json gapped = PartJson("reg-dome-a", "gapped", nullptr);
  gapped["probing"]["min_gap_mm"] = 2.5;
  gapped["probing"]["shank_radius_mm"] = 0.75;
  ASSERT_TRUE(WriteJsonFile(dir_ / "gapped.json", gapped).ok());
  const auto with_gap = ReadPart(dir_ / "gapped.json");
  ASSERT_TRUE(with_gap.ok()) << with_gap.status().ToString();
  const auto gap_again = ParsePart(with_gap->ToJson(), "resolved");
  ASSERT_TRUE(gap_again.ok()) << gap_again.status().ToString();
  EXPECT_EQ(gap_again->probe_program.min_gap_mm, 2.5);
  EXPECT_EQ(gap_again->probe_program.shank_radius_mm, 0.75);
  for (const auto& [field, value] : std::vector<std::pair<std::string, double>>{
           {"min_gap_mm", 0}, {"min_gap_mm", 60}, {"shank_radius_mm", -1}, {"shank_radius_mm", 51}}) {
    Json bad = gapped;
    bad["probing"][field] = value;
    ASSERT_TRUE(WriteJsonFile(dir_ / "bad_gap.json", bad).ok());
    const auto refused_part = ReadPart(dir_ / "bad_gap.json");
    ASSERT_FALSE(refused_part.ok()) << field << " = " << value;
    EXPECT_NE(refused_part.status().message().find("probing." + field), std::string::npos)
        << refused_part.status().message();
  }
}

}  // namespace
}  // namespace formloop::app
