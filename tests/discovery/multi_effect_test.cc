// Several causes at once (issue 20): the cases the issue measured on the old diagnosis, pooling of
// parts, the separating experiment, and the learned model with its alias groups. Probe logs come from
// the virtual machine (tests/support/multi_effect.h); the truth is read only to grade.

#include <algorithm>
#include <cstdio>
#include <string>
#include <vector>

#include <gtest/gtest.h>

#include "tests/support/multi_effect.h"

namespace formloop::testing {
namespace {

sim::DiagnoseOptions Options() { return StarterDiagnoseOptions(); }

sim::Model MachineOf(const std::vector<std::pair<std::string, std::vector<double>>>& effects) {
  return MachineWithNoise(effects);
}

// Every true effect named or inside an alias group, nothing named that is not there, every named
// parameter's interval holding its true value.
void ExpectHonest(const sim::Diagnosis& d, const sim::Model& truth) {
  for (const auto& e : truth.effects) {
    if (e.effect->kind() == sim::EffectKind::kNoise) continue;
    bool named = false;
    for (const auto& c : d.causes) named = named || c.effect == e.effect->name();
    EXPECT_TRUE(named || d.InAliasGroup(e.effect->name())) << e.effect->name() << " lost\n" << d.Summary();
  }
  for (const auto& c : d.causes) {
    const sim::EffectInstance* t = truth.Find(c.effect);
    EXPECT_NE(t, nullptr) << c.effect << " named but not there\n" << d.Summary();
    if (t == nullptr) continue;
    for (std::size_t j = 0; j < t->values.size(); ++j) {
      if (c.aliased[j]) continue;
      EXPECT_TRUE(t->values[j] >= c.lower[j] && t->values[j] <= c.upper[j])
          << c.effect << "." << c.parameter_names[j] << " = " << t->values[j] << " outside [" << c.lower[j] << ", "
          << c.upper[j] << "]\n"
          << d.Summary();
    }
  }
}

// The first case: thermal drift 12 µm + set-up offset (10, −6, 0) µm + tool wear 2 µm/m on an
// egg box, 30 × 30 probes. The old diagnosis added a false x-rotation of 118 µrad and gave thermal 21 µm.
TEST(MultiEffectTest, ThermalOffsetAndWearOnAnEggBoxNameNothingFalse) {
  const sim::Model m =
      MachineOf({{"thermal_drift_z", {12.0, 900.0}}, {"setup_offset", {10.0, -6.0, 0.0}}, {"tool_wear", {2.0}}});
  for (double angle : {0.0, 45.0, 90.0}) {
    const Scenario s = ProbePart({"egg_box", angle, 30}, m, 11);
    const auto d = sim::Diagnose(InputOf(s), s.baseline, Options());
    ASSERT_TRUE(d.ok()) << d.status().message();
    std::printf("raster %g deg:\n%s", angle, d->Summary().c_str());
    ExpectHonest(*d, m);
    EXPECT_LT(d->heldout_rms_after_um, 1.5 * 0.98 + 0.5) << "held-out RMS near the noise";
  }
}

// The second case: a ball 6 µm under size + set-up z 14 µm + wear 0.4 µm/m. The old diagnosis
// named thermal drift with A = 168 µm and τ = 34,700 s beside a z offset of 20 µm. On an egg box
// (n_z ≈ 1 almost everywhere) the z offset's column lies close to the radius's: the offset, significant
// beside the radius but too weak to be selected with its three parameters, is listed in the radius's
// alias group rather than lost.
TEST(MultiEffectTest, RadiusOffsetAndWearNameNoAbsurdThermalDrift) {
  const sim::Model m = MachineOf({{"tool_radius", {6.0}}, {"setup_offset", {0.0, 0.0, 14.0}}, {"tool_wear", {0.4}}});
  for (double angle : {0.0, 45.0, 90.0}) {
    const Scenario s = ProbePart({"egg_box", angle, 30}, m, 12);
    const auto d = sim::Diagnose(InputOf(s), s.baseline, Options());
    ASSERT_TRUE(d.ok()) << d.status().message();
    std::printf("raster %g deg:\n%s", angle, d->Summary().c_str());
    for (const auto& c : d->causes) EXPECT_NE(c.effect, "thermal_drift_z") << d->Summary();
    ExpectHonest(*d, m);
    // The z offset is named, or listed in the group of the radius that carries its column.
    bool offset_said = false;
    for (const auto& c : d->causes) offset_said = offset_said || c.effect == "setup_offset";
    for (const auto& g : d->alias_groups) {
      const auto holds = [&](const char* e) { return std::count(g.members.begin(), g.members.end(), e) > 0; };
      offset_said = offset_said || (holds("setup_offset") && holds("tool_radius"));
    }
    EXPECT_TRUE(offset_said) << d->Summary();
    // Whatever carries the 20 µm, compensation gets it: the held-out residual is noise.
    EXPECT_LT(d->heldout_rms_after_um, 1.5) << d->Summary();
  }
}

// An implausible best fit is said, not named: a tool that grows by 3 µm per metre of cut (wear is a
// loss: the rule base's range is 0–50 µm/m) is reported with the value it would need, not named.
TEST(MultiEffectTest, AValueOutsideItsPlausibleRangeIsNotNamed) {
  const sim::Model m = MachineOf({{"tool_wear", {-3.0}}});  // a tool that grows as it cuts
  const Scenario s = ProbePart({"saddle", 0, 25}, m, 13);
  const auto d = sim::Diagnose(InputOf(s), s.baseline, Options());
  ASSERT_TRUE(d.ok()) << d.status().message();
  std::printf("%s", d->Summary().c_str());
  for (const auto& c : d->causes) EXPECT_NE(c.effect, "tool_wear") << d->Summary();
  bool said = false;
  for (const auto& b : d->implausible) said = said || b.effect == "tool_wear";
  EXPECT_TRUE(said) << d->ToJson()["implausible"].dump();
}

// Probed along −n, a tool radius error and a probe radius error give identical columns: one alias group
// (on this franke part with a z scale and the deflection too). The proposal for it — the cheapest change
// that separates it; here the tool setter and the reference sphere (a tilted re-probe cannot split the
// deflection and the z scale) — applied on the machine (its readings drawn from the truth plus the
// instruments' noise) splits the tool radius from the probe radius as predicted, and the diagnosis after
// it names the 8 µm radius within its interval and nothing false.
TEST(MultiEffectTest, TheProposedExperimentSplitsToolRadiusFromProbeRadius) {
  const sim::Model m = MachineOf({{"tool_radius", {8.0}}, {"setup_offset", {5.0, -4.0, 0.0}}});
  const Scenario s = ProbePart({"franke", 0, 24}, m, 21);
  const auto d = sim::Diagnose(InputOf(s), s.baseline, Options());
  ASSERT_TRUE(d.ok()) << d.status().message();
  std::printf("%s", d->Summary().c_str());
  ASSERT_TRUE(d->InAliasGroup("tool_radius")) << d->Summary();
  ASSERT_TRUE(d->InAliasGroup("probe_radius")) << d->Summary();
  const auto proposals = sim::ProposeExperiments({InputOf(s)}, *d, s.baseline, ExperimentOptionsFor(s));
  ASSERT_TRUE(proposals.ok()) << proposals.status().message();
  ASSERT_EQ(proposals->size(), d->alias_groups.size());
  const sim::ExperimentProposal* p = nullptr;
  for (const auto& q : *proposals) {
    if (std::count(q.members.begin(), q.members.end(), "probe_radius") > 0) p = &q;
  }
  ASSERT_NE(p, nullptr);
  std::printf("proposal: %s (cost %.0f s; correlation %.4f -> %.4f predicted; separation %.1f)\n", p->change.c_str(),
              p->cost_s, p->correlation_before, p->correlation_after, p->separation);
  EXPECT_TRUE(p->predicted_to_split);
  EXPECT_GT(p->correlation_before, 0.999);
  EXPECT_LT(p->correlation_after, p->correlation_before);
  // Applied: a re-probe probes the part again; readings are diagnosed with the same log.
  Scenario again = s;
  sim::DiagnoseOptions o = Options();
  if (!p->direct.empty()) {
    o.direct = Measured(s, *p, 22);
  } else {
    ASSERT_EQ(p->kind, "reprobe");
    again = Reprobed(s, *p, 22);
  }
  const auto d2 = sim::Diagnose(InputOf(again), s.baseline, o);
  ASSERT_TRUE(d2.ok()) << d2.status().message();
  std::printf("after the experiment:\n%s", d2->Summary().c_str());
  const auto measured = sim::GroupCorrelation({InputOf(again)}, *d2, s.baseline, p->members, o.direct);
  ASSERT_TRUE(measured.ok()) << measured.status().message();
  std::printf("measured correlation %.4f\n", *measured);
  EXPECT_NEAR(*measured, p->correlation_after, 0.05);
  EXPECT_FALSE(d2->InAliasGroup("tool_radius") && d2->InAliasGroup("probe_radius")) << d2->Summary();
  ExpectHonest(*d2, m);
}

// Thermal drift and wear look alike on a flat part cut at one feed; a second part of the same machine
// (another shape and raster, its own set-up) pooled with it separates them, each part's offset its own.
TEST(MultiEffectTest, PoolingTwoPartsSplitsWhatOnePartCannot) {
  const sim::Model machine = MachineOf({{"thermal_drift_z", {14.0, 700.0}}, {"tool_wear", {3.0}}});
  sim::Model a = machine, b = machine;
  ASSERT_TRUE(a.Set("setup_offset", {8.0, -5.0, 3.0}).ok());
  ASSERT_TRUE(b.Set("setup_offset", {-6.0, 2.0, 9.0}).ok());
  const Scenario part_a = ProbePart({"egg_box", 0, 24}, a, 31);
  const Scenario part_b = ProbePart({"sphere_cap", 90, 24}, b, 32);
  const auto one = sim::Diagnose(InputOf(part_a), part_a.baseline, Options());
  ASSERT_TRUE(one.ok());
  std::printf("part A alone:\n%s", one->Summary().c_str());
  const auto both = sim::DiagnosePooled({InputOf(part_a), InputOf(part_b)}, part_a.baseline, Options(), {"A", "B"});
  ASSERT_TRUE(both.ok()) << both.status().message();
  std::printf("A and B pooled:\n%s", both->Summary().c_str());
  std::vector<std::string> named;
  for (const auto& c : both->causes) named.push_back(c.Label());
  for (const char* label : {"thermal_drift_z", "tool_wear", "setup_offset@A", "setup_offset@B"}) {
    EXPECT_TRUE(std::count(named.begin(), named.end(), label) == 1) << label << "\n" << both->Summary();
  }
  for (const auto& c : both->causes) {
    const sim::Model& truth = c.part == "B" ? b : a;
    const sim::EffectInstance* t = truth.Find(c.effect);
    ASSERT_NE(t, nullptr) << c.Label();
    for (std::size_t j = 0; j < t->values.size(); ++j) {
      if (c.aliased[j]) continue;  // inside an alias group: no value is claimed
      EXPECT_TRUE(t->values[j] >= c.lower[j] && t->values[j] <= c.upper[j])
          << c.Label() << "." << c.parameter_names[j] << " = " << t->values[j] << " outside [" << c.lower[j] << ", "
          << c.upper[j] << "]";
    }
  }
}

// A part turned on the table is a part-specific rotation; on a sphere cap that rotation moves the surface
// like a shift, and turning it about the line through the sphere's centre moves nothing. Pooled with a
// saddle of the same machine (a probe radius 15 µm small), the diagnosis names each part's rotation, groups the sphere
// cap's three angles as what the data cannot tell apart, and names no set-up offset (none is there). Before a term was
// judged on what the data determine of it, that undetermined combination (tens of thousands of µrad) threw every part's
// rotation out as implausible and set-up offsets were named on both parts.
TEST(MultiEffectTest, APooledSphereCapsRotationIsGroupedNotReplacedByOffsets) {
  const sim::Model machine = MachineOf({{"probe_radius", {-15.0}}});
  sim::Model a = machine, b = machine;
  ASSERT_TRUE(a.Set("setup_rotation", {-300.0, -90.0, 110.0}).ok());
  ASSERT_TRUE(b.Set("setup_rotation", {200.0, 285.0, -225.0}).ok());
  const Scenario part_a = ProbePart({"saddle", 0, 24}, a, 51);
  const Scenario part_b = ProbePart({"sphere_cap", 90, 24}, b, 52);
  const auto both = sim::DiagnosePooled({InputOf(part_a), InputOf(part_b)}, part_a.baseline, Options(), {"A", "B"});
  ASSERT_TRUE(both.ok()) << both.status().message();
  std::printf("saddle A and sphere cap B pooled:\n%s", both->Summary().c_str());
  std::vector<std::string> named;
  for (const auto& c : both->causes) named.push_back(c.Label());
  for (const char* label : {"setup_rotation@A", "setup_rotation@B"}) {
    EXPECT_EQ(std::count(named.begin(), named.end(), label), 1) << label << "\n" << both->Summary();
  }
  // Probed along the normal, the probe radius is one with the tool radius (the group the experiment splits).
  EXPECT_TRUE(std::count(named.begin(), named.end(), "probe_radius") == 1 || both->InAliasGroup("probe_radius"))
      << both->Summary();
  for (const auto& c : both->causes) {
    const sim::Model& truth = c.part == "B" ? b : a;
    const sim::EffectInstance* t = truth.Find(c.effect);
    ASSERT_NE(t, nullptr) << c.Label() << " named but not there\n" << both->Summary();
    for (std::size_t j = 0; j < t->values.size(); ++j) {
      if (c.aliased[j]) continue;
      EXPECT_TRUE(t->values[j] >= c.lower[j] && t->values[j] <= c.upper[j])
          << c.Label() << "." << c.parameter_names[j] << " = " << t->values[j] << " outside [" << c.lower[j] << ", "
          << c.upper[j] << "]";
    }
  }
  // The sphere cap's angles: at least two in one group, and none of them printed as an estimate.
  bool grouped = false;
  for (const auto& g : both->alias_groups) {
    int angles = 0;
    for (const auto& m : g.members) angles += m.rfind("setup_rotation(", 0) == 0 && m.find("@B") != std::string::npos;
    grouped = grouped || angles >= 2;
  }
  EXPECT_TRUE(grouped) << both->Summary();
  // ... and the finding says which turn changes nothing: the one about the line from the part origin to
  // the sphere's centre (50, 40, -80) mm, which moves every point of the cap along the sphere.
  const Eigen::Vector3d axis = Eigen::Vector3d(50, 40, -80).normalized();
  int said = 0;
  for (const auto& g : both->alias_groups) {
    for (const auto& u : g.undetermined) {
      Eigen::Vector3d w = Eigen::Vector3d::Zero();
      for (std::size_t j = 0; j < u.parameters.size(); ++j) {
        for (int axis_index = 0; axis_index < 3; ++axis_index) {
          const std::string name = std::string("setup_rotation(w") + "xyz"[axis_index] + "_urad)@B";
          if (u.parameters[j] == name) w[axis_index] = u.coefficients[j];
        }
      }
      if (w.norm() < 0.9) continue;
      ++said;
      EXPECT_GT(std::abs(w.normalized().dot(axis)), 0.99) << u.Text() << "\n" << both->Summary();
      EXPECT_NE(g.Message().find("changes nothing these points see"), std::string::npos) << g.Message();
    }
  }
  EXPECT_EQ(said, 1) << both->Summary();
  for (const auto& c : both->causes) {
    if (c.Label() != "setup_rotation@B") continue;
    for (std::size_t j = 0; j < c.aliased.size(); ++j) EXPECT_TRUE(c.aliased[j]) << c.parameter_names[j];
  }
}

// The learned model keeps an alias group as its combined prediction: it predicts the part it came from
// as well as the named effects would, it writes and reads back, and it names no member as a cause.
TEST(MultiEffectTest, TheLearnedModelHoldsAnAliasGroupAsItsCombinedPrediction) {
  const sim::Model m = MachineOf({{"tool_radius", {7.0}}, {"tool_wear", {1.5}}});
  const Scenario s = ProbePart({"saddle", 0, 24}, m, 41);
  const auto d = sim::Diagnose(InputOf(s), s.baseline, Options());
  ASSERT_TRUE(d.ok());
  ASSERT_FALSE(d->alias_groups.empty()) << d->Summary();
  const sim::Model& learned = d->extended;
  ASSERT_FALSE(learned.alias_groups.empty());
  int in_group = 0;
  for (const auto& e : learned.effects) {
    if (!e.alias_group.empty()) {
      ++in_group;
      EXPECT_FALSE(learned.Names(e.effect->name()));
    }
  }
  EXPECT_GE(in_group, 1);
  const auto back = sim::Model::FromJson(learned.ToJson(), "round trip");
  ASSERT_TRUE(back.ok()) << back.status().message();
  EXPECT_EQ(back->ToJson(), learned.ToJson());
  // Its prediction of the part: the residual against it is noise.
  const auto rms = sim::PredictionRms(InputOf(s), learned);
  ASSERT_TRUE(rms.ok());
  EXPECT_LT(*rms, 1.3) << "prediction RMS with the learned model";
}

}  // namespace
}  // namespace formloop::testing
