// Direct measurements beside the probe log (issue 20's separating experiment): a tool setter, a
// reference sphere, the fixture's datum faces. Each enters the fit as one more observation of a
// parameter with its σ; applied values are simulated from the machine's truth plus the instrument's
// noise (tests/support/multi_effect.h, Measured), never from the diagnosis.

#include <algorithm>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <string>
#include <vector>

#include <gtest/gtest.h>

#include "tests/support/multi_effect.h"
#include "tests/support/test_dir.h"

namespace formloop::testing {
namespace {

sim::DiagnoseOptions Options() { return StarterDiagnoseOptions(); }

sim::Model MachineOf(const std::vector<std::pair<std::string, std::vector<double>>>& effects) {
  return MachineWithNoise(effects);
}

bool Named(const sim::Diagnosis& d, const std::string& effect) {
  return std::any_of(d.causes.begin(), d.causes.end(), [&](const sim::Cause& c) { return c.effect == effect; });
}

// Probed along −n, a tool radius error and a probe radius error give one column: without more, one
// alias group. A tool-setter reading (σ 1 µm) of the real tool splits it: the tool radius is named
// with an interval holding the truth, the probe radius is not named (the machine's probe is right).
TEST(DirectMeasurementTest, AToolSetterReadingSplitsToolRadiusFromProbeRadius) {
  const sim::Model m = MachineOf({{"tool_radius", {7.0}}});
  const Scenario s = ProbePart({"saddle", 0, 24}, m, 51);
  const auto before = sim::Diagnose(InputOf(s), s.baseline, Options());
  ASSERT_TRUE(before.ok()) << before.status().message();
  std::printf("probe data alone:\n%s", before->Summary().c_str());
  ASSERT_TRUE(before->InAliasGroup("tool_radius") && before->InAliasGroup("probe_radius")) << before->Summary();
  sim::DiagnoseOptions o = Options();
  o.direct = {{"tool_radius", "delta_r_um", 6.4, 1.0, "", "tool setter"}};  // 7.0 read 0.6 µm low
  const auto after = sim::Diagnose(InputOf(s), s.baseline, o);
  ASSERT_TRUE(after.ok()) << after.status().message();
  std::printf("with the tool setter:\n%s", after->Summary().c_str());
  EXPECT_FALSE(after->InAliasGroup("tool_radius")) << after->Summary();
  EXPECT_FALSE(Named(*after, "probe_radius")) << after->Summary();
  ASSERT_TRUE(Named(*after, "tool_radius")) << after->Summary();
  for (const auto& c : after->causes) {
    if (c.effect != "tool_radius") continue;
    EXPECT_LE(c.lower[0], 7.0);
    EXPECT_GE(c.upper[0], 7.0);
    // The points fix the sum to ~0.1 µm; the reading does not pull the estimate off the data.
    EXPECT_NEAR(c.parameters[0], 7.0, 0.3);
  }
  ASSERT_EQ(after->direct_fitted.size(), 1u);
  EXPECT_NEAR(after->direct_fitted[0], 7.0, 0.3);
  // The residual and its outputs stay per point.
  EXPECT_EQ(after->residual_after_um.size(), before->residual_after_um.size());
  EXPECT_EQ(after->n, before->n);
}

// The tool is right (the setter reads 0.3 ± 1 µm) and the probe's radius is off by 6 µm: the reading
// takes the tool radius out of the question — not named, in no alias group — and leaves the 6 µm to
// what can carry it (on this saddle the probe radius or a z set-up shift). A reference-sphere
// calibration of the probe (σ 0.5 µm) then names the probe radius alone.
TEST(DirectMeasurementTest, AToolSetterReadingOfARightToolPutsTheErrorElsewhere) {
  const sim::Model m = MachineOf({{"probe_radius", {6.0}}});
  const Scenario s = ProbePart({"saddle", 0, 24}, m, 52);
  sim::DiagnoseOptions o = Options();
  o.direct = {{"tool_radius", "delta_r_um", 0.3, 1.0, "", "tool setter"}};
  const auto d = sim::Diagnose(InputOf(s), s.baseline, o);
  ASSERT_TRUE(d.ok()) << d.status().message();
  std::printf("with the tool setter:\n%s", d->Summary().c_str());
  EXPECT_FALSE(Named(*d, "tool_radius")) << d->Summary();
  EXPECT_FALSE(d->InAliasGroup("tool_radius")) << d->Summary();
  EXPECT_TRUE(Named(*d, "probe_radius") || d->InAliasGroup("probe_radius")) << d->Summary();
  o.direct.push_back({"probe_radius", "delta_r_eff_um", 5.7, 0.5, "", "reference sphere"});
  const auto both = sim::Diagnose(InputOf(s), s.baseline, o);
  ASSERT_TRUE(both.ok()) << both.status().message();
  std::printf("with the tool setter and the reference sphere:\n%s", both->Summary().c_str());
  ASSERT_TRUE(Named(*both, "probe_radius")) << both->Summary();
  EXPECT_FALSE(Named(*both, "tool_radius")) << both->Summary();
  EXPECT_FALSE(Named(*both, "setup_offset")) << both->Summary();
  EXPECT_TRUE(both->alias_groups.empty()) << both->Summary();
  for (const auto& c : both->causes) {
    if (c.effect == "probe_radius") {
      EXPECT_TRUE(c.lower[0] <= 6.0 && 6.0 <= c.upper[0]) << both->Summary();
    }
  }
}

// The issue's second case (a ball 6 µm under size + set-up z 14 µm + wear 0.4 µm/m on an egg box): the
// probe data alone cannot place the 20 µm between the radii and the z shift. The tool setter and the
// datum faces, applied, split it: tool radius and set-up offset named with intervals that hold the
// truth, nothing false named.
TEST(DirectMeasurementTest, ToolSetterAndDatumSplitRadiusFromSetupZ) {
  const sim::Model m = MachineOf({{"tool_radius", {6.0}}, {"setup_offset", {0.0, 0.0, 14.0}}, {"tool_wear", {0.4}}});
  const Scenario s = ProbePart({"egg_box", 0, 30}, m, 12);
  const auto d = sim::Diagnose(InputOf(s), s.baseline, Options());
  ASSERT_TRUE(d.ok()) << d.status().message();
  std::printf("probe data alone:\n%s", d->Summary().c_str());
  ASSERT_FALSE(d->alias_groups.empty()) << d->Summary();
  const auto proposals = sim::ProposeExperiments({InputOf(s)}, *d, s.baseline, ExperimentOptionsFor(s));
  ASSERT_TRUE(proposals.ok()) << proposals.status().message();
  for (const auto& p : *proposals) {
    std::printf("proposal [%s]: %s (cost %.0f s; correlation %.4f -> %.4f; separation %.1f%s)\n", p.kind.c_str(),
                p.change.c_str(), p.cost_s, p.correlation_before, p.correlation_after, p.separation,
                p.predicted_to_split ? "" : "; not predicted to split");
  }
  sim::DiagnoseOptions o = Options();
  Rng rng(53);
  o.direct = {{"tool_radius", "delta_r_um", rng.Normal(6.0, 1.0), 1.0, "", "tool setter"},
              {"setup_offset", "tx_um", rng.Normal(0.0, 1.0), 1.0, "", "datum faces"},
              {"setup_offset", "ty_um", rng.Normal(0.0, 1.0), 1.0, "", "datum faces"},
              {"setup_offset", "tz_um", rng.Normal(14.0, 1.0), 1.0, "", "datum faces"}};
  const auto after = sim::Diagnose(InputOf(s), s.baseline, o);
  ASSERT_TRUE(after.ok()) << after.status().message();
  std::printf("with the tool setter and the datum faces:\n%s", after->Summary().c_str());
  EXPECT_TRUE(Named(*after, "tool_radius")) << after->Summary();
  EXPECT_TRUE(Named(*after, "setup_offset")) << after->Summary();
  EXPECT_FALSE(Named(*after, "probe_radius")) << after->Summary();
  EXPECT_FALSE(Named(*after, "thermal_drift_z")) << after->Summary();
  for (const auto& c : after->causes) {
    const sim::EffectInstance* t = m.Find(c.effect);
    ASSERT_NE(t, nullptr) << c.effect << " named but not there\n" << after->Summary();
    for (std::size_t j = 0; j < t->values.size(); ++j) {
      if (c.aliased[j]) continue;
      EXPECT_TRUE(t->values[j] >= c.lower[j] && t->values[j] <= c.upper[j])
          << c.effect << "." << c.parameter_names[j] << " = " << t->values[j] << " outside [" << c.lower[j] << ", "
          << c.upper[j] << "]\n"
          << after->Summary();
    }
  }
  EXPECT_LT(after->heldout_rms_after_um, 1.5) << after->Summary();
}

// A named set-up whose z shift alone is aliased (with the radii: a constant along n on this saddle)
// keeps tx and ty as estimates. The experiment design must leave only tz out of the others: before the
// fix it kept the whole set-up there, so the member tz_um was explained by its own column — design
// correlation 0 reported for an inseparable group and no change predicted to split it (the suite's
// probe_radius + setup_offset(tz_um) + tool_radius misses). Now the group's correlation is 1, the tool
// setter with the datum faces is predicted to split it, and applied (truth + the instruments' noise)
// they do.
TEST(DirectMeasurementTest, AnAliasedSetupParameterIsSplitByTheProposedReadings) {
  const sim::Model m = MachineOf({{"tool_deflection", {96.0}}, {"setup_offset", {-14.8, 13.8, 17.5}}});
  const Scenario s = ProbePart({"saddle", 45, 28}, m, 5);
  const auto d = sim::Diagnose(InputOf(s), s.baseline, Options());
  ASSERT_TRUE(d.ok()) << d.status().message();
  std::printf("probe data alone:\n%s", d->Summary().c_str());
  const auto tz = std::find_if(d->alias_groups.begin(), d->alias_groups.end(), [](const sim::AliasGroup& g) {
    return std::find(g.members.begin(), g.members.end(), "setup_offset(tz_um)") != g.members.end();
  });
  ASSERT_NE(tz, d->alias_groups.end()) << d->Summary();
  const auto proposals = sim::ProposeExperiments({InputOf(s)}, *d, s.baseline, ExperimentOptionsFor(s));
  ASSERT_TRUE(proposals.ok()) << proposals.status().message();
  const auto p = std::find_if(proposals->begin(), proposals->end(),
                              [&](const sim::ExperimentProposal& q) { return q.members == tz->members; });
  ASSERT_NE(p, proposals->end());
  std::printf("proposal [%s]: %s (cost %.0f s; correlation %.4f -> %.4f; separation %.1f)\n", p->kind.c_str(),
              p->change.c_str(), p->cost_s, p->correlation_before, p->correlation_after, p->separation);
  EXPECT_GT(p->correlation_before, 0.99);
  ASSERT_TRUE(p->predicted_to_split);
  ASSERT_FALSE(p->direct.empty());
  EXPECT_NE(p->kind.find("datum"), std::string::npos) << p->kind;
  sim::DiagnoseOptions o = Options();
  o.direct = Measured(s, *p, 54);
  const auto after = sim::Diagnose(InputOf(s), s.baseline, o);
  ASSERT_TRUE(after.ok()) << after.status().message();
  std::printf("with the readings:\n%s", after->Summary().c_str());
  EXPECT_FALSE(after->InAliasGroup("setup_offset")) << after->Summary();
  EXPECT_FALSE(Named(*after, "tool_radius")) << after->Summary();
  EXPECT_FALSE(Named(*after, "probe_radius")) << after->Summary();
  ASSERT_TRUE(Named(*after, "setup_offset")) << after->Summary();
  for (const auto& c : after->causes) {
    if (c.effect != "setup_offset") continue;
    EXPECT_TRUE(c.lower[2] <= 17.5 && 17.5 <= c.upper[2]) << after->Summary();
  }
}

// The design counts the readings the diagnosis has already: a coarse tool-setter reading (σ 10 µm of a
// 7 µm radius error) leaves the radii (and the z set-up) grouped, and the proposal made on that diagnosis knows the
// reading is there — the group's design correlation before the change is below the probe data's alone, and the tool
// setter it proposes is said to be a second reading. (Before, the design ignored readings made: a pooled diagnosis with
// the tool setter, sphere and datum read was proposed those same readings, its correlation "before" 1.0000, the suite's
// scenario 175.)
TEST(DirectMeasurementTest, TheProposalCountsTheReadingsTheDiagnosisHasAlready) {
  const sim::Model m = MachineOf({{"tool_radius", {7.0}}});
  const Scenario s = ProbePart({"saddle", 0, 24}, m, 51);
  const auto plain = sim::Diagnose(InputOf(s), s.baseline, Options());
  ASSERT_TRUE(plain.ok()) << plain.status().message();
  sim::DiagnoseOptions o = Options();
  o.direct = {{"tool_radius", "delta_r_um", 4.0, 10.0, "", "tool presetter"}};
  const auto read = sim::Diagnose(InputOf(s), s.baseline, o);
  ASSERT_TRUE(read.ok()) << read.status().message();
  std::printf("with a coarse tool-setter reading:\n%s", read->Summary().c_str());
  ASSERT_TRUE(read->InAliasGroup("tool_radius") && read->InAliasGroup("probe_radius")) << read->Summary();
  auto radii = [](const std::vector<sim::ExperimentProposal>& ps) -> const sim::ExperimentProposal* {
    for (const auto& p : ps) {
      if (std::count(p.members.begin(), p.members.end(), "tool_radius") > 0) return &p;
    }
    return nullptr;
  };
  const auto before = sim::ProposeExperiments({InputOf(s)}, *plain, s.baseline, ExperimentOptionsFor(s));
  const auto after = sim::ProposeExperiments({InputOf(s)}, *read, s.baseline, ExperimentOptionsFor(s));
  ASSERT_TRUE(before.ok() && after.ok());
  const sim::ExperimentProposal* p0 = radii(*before);
  const sim::ExperimentProposal* p1 = radii(*after);
  ASSERT_TRUE(p0 != nullptr && p1 != nullptr);
  std::printf(
      "probe data alone: [%s] %s (correlation %.8f -> %.8f)\nwith the reading: [%s] %s (correlation %.8f -> %.8f)\n",
      p0->kind.c_str(), p0->change.c_str(), p0->correlation_before, p0->correlation_after, p1->kind.c_str(),
      p1->change.c_str(), p1->correlation_before, p1->correlation_after);
  EXPECT_LT(p1->correlation_before, p0->correlation_before);
  EXPECT_TRUE(p1->predicted_to_split);
  ASSERT_NE(p1->kind.find("tool_setter"), std::string::npos) << p1->kind;
  EXPECT_NE(p1->change.find("again (already read by the tool presetter, sigma 10;"), std::string::npos) << p1->change;
  EXPECT_EQ(p0->change.find("already read"), std::string::npos) << p0->change;
}

// The file `formloop diagnose --direct` reads: values, errors naming the entry and the field.
TEST(DirectMeasurementTest, TheFileIsReadAndBadEntriesAreNamed) {
  const std::filesystem::path dir = FreshTestDir("direct_measurements");
  const std::string good = (dir / "good.json").string();
  std::ofstream(good) << R"({"direct_measurements": [
    {"effect": "tool_radius", "parameter": "delta_r_um", "value": 6.1, "sigma": 1.0, "by": "tool setter"},
    {"effect": "setup_offset", "parameter": "tz_um", "value": 13.2, "sigma": 0.8, "part": "A"}]})";
  const auto read = sim::ReadDirectMeasurements(good);
  ASSERT_TRUE(read.ok()) << read.status().message();
  ASSERT_EQ(read->size(), 2u);
  EXPECT_EQ((*read)[0].effect, "tool_radius");
  EXPECT_DOUBLE_EQ((*read)[0].value, 6.1);
  EXPECT_EQ((*read)[0].by, "tool setter");
  EXPECT_EQ((*read)[1].part, "A");
  EXPECT_DOUBLE_EQ((*read)[1].sigma, 0.8);
  const std::vector<std::pair<std::string, std::string>> bad = {
      {R"({"direct": []})", "direct_measurements"},
      {R"({"direct_measurements": [{"effect": "tool_radiu", "parameter": "delta_r_um", "value": 1, "sigma": 1}]})",
       "unknown effect"},
      {R"({"direct_measurements": [{"effect": "tool_radius", "parameter": "r", "value": 1, "sigma": 1}]})",
       "no parameter 'r'"},
      {R"({"direct_measurements": [{"effect": "tool_radius", "parameter": "delta_r_um", "value": 1, "sigma": 0}]})",
       "sigma"},
      {R"({"direct_measurements": [{"effect": "tool_radius", "parameter": "delta_r_um", "sigma": 1}]})",
       "direct_measurements[0].value"},
      {R"({"direct_measurements": [{"effect": "thermal_drift_z", "parameter": "tau_s", "value": 600, "sigma": 60}]})",
       "nonlinear"},
      {R"({"direct_measurements": [{"effect": "tool_radius", "parameter": "delta_r_um", "value": 1, "sigma": 1},
                                   {"effect": "tool_radius", "parameter": "delta_r_um", "value": 2, "sigma": 1}]})",
       "twice"}};
  for (std::size_t k = 0; k < bad.size(); ++k) {
    const std::string path = (dir / ("bad_" + std::to_string(k) + ".json")).string();
    std::ofstream(path) << bad[k].first;
    const auto r = sim::ReadDirectMeasurements(path);
    ASSERT_FALSE(r.ok()) << bad[k].first;
    EXPECT_NE(std::string(r.status().message()).find(bad[k].second), std::string::npos) << r.status().message();
    EXPECT_NE(std::string(r.status().message()).find(path), std::string::npos) << r.status().message();
  }
  // A measured effect already in the baseline is refused, not silently ignored.
  const sim::Model m = MachineOf({{"tool_radius", {5.0}}});
  const Scenario s = ProbePart({"saddle", 0, 20}, m, 54);
  sim::Model baseline = s.baseline;
  ASSERT_TRUE(baseline.Set("tool_radius", {4.0}).ok());
  sim::DiagnoseOptions o = Options();
  o.direct = {{"tool_radius", "delta_r_um", 5.0, 1.0, "", "tool setter"}};
  const auto d = sim::Diagnose(InputOf(s), baseline, o);
  ASSERT_FALSE(d.ok());
  EXPECT_NE(std::string(d.status().message()).find("baseline"), std::string::npos) << d.status().message();
  std::filesystem::remove_all(dir);
}

}  // namespace
}  // namespace formloop::testing
