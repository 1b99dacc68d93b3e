// The hidden-effect suite (spec/simulation.md §6). Each scenario hides catalogue effects (or none, or
// a bump outside the catalogue) in a simulated probe log; diagnose sees only the log, the plan, the
// tool path and a baseline without them. The truth is read only to grade. Rates are asserted per
// effect and the tables printed; bench/discovery_bench runs the larger sweep.

#include <algorithm>
#include <cstdio>
#include <map>
#include <string>
#include <vector>

#include <gtest/gtest.h>

#include "simulation/experiment_design.h"
#include "tests/support/multi_effect.h"

namespace formloop::testing {
namespace {

constexpr int kPerEffect = 20;

class SingleEffect : public ::testing::TestWithParam<std::string> {};

bool NamedFirst(const sim::Diagnosis& d, const std::string& effect) {
  return !d.causes.empty() && d.causes.front().effect == effect;
}

// The separating experiment the diagnosis proposes for its first alias group, applied on the virtual
// machine (the applied measurement simulated from the scenario's truth and the instrument's noise, never
// from the diagnosis; as the multi-effect suite does it) and diagnosed again. A next-part change cuts
// another part on the same machine with the same set-up (the scenario's truth). Not ok: no proposal.
Result<sim::Diagnosis> AfterTheProposedExperiment(const Scenario& s, const sim::Diagnosis& d, std::uint64_t seed,
                                                  std::string* kind) {
  sim::ExperimentOptions eo = ExperimentOptionsFor(s);
  eo.plausible = {};  // the suite diagnoses without a rule base: τ searched over the default range
  FL_ASSIGN_OR_RETURN(const std::vector<sim::ExperimentProposal> proposals,
                      sim::ProposeExperiments({InputOf(s)}, d, s.baseline, eo));
  if (proposals.empty()) return Status::NotFound("no proposal");
  const sim::ExperimentProposal& p = proposals.front();
  *kind = p.kind;
  if (!p.direct.empty()) {
    sim::DiagnoseOptions with_direct;
    with_direct.direct = Measured(s, p, seed + 9000000);
    return sim::Diagnose(InputOf(s), s.baseline, with_direct);
  }
  if (p.kind == "reprobe") return DiagnoseScenario(Reprobed(s, p, seed + 7000000));
  const Scenario next = NextPart(s, p, s.truth, sim::Model(), seed + 8000000);
  return sim::DiagnosePooled({InputOf(s), InputOf(next)}, s.baseline, sim::DiagnoseOptions());
}

// Named first, parameters inside the reported 95 % interval, held-out gain ≥ 50 % of the injected
// RMS — per effect, over kPerEffect scenarios (surfaces, point counts 400–3000, SNR 3–20 drawn). Named
// first: the diagnosis' first cause is the injected effect (a parameter of it may sit in an alias group:
// it is then not graded). Where the part as planned cannot tell the effect from a look-alike (an alias
// group, nothing false named), the experiment the diagnosis proposes is applied and named first counted
// again: the table's second column.
TEST_P(SingleEffect, IsNamedFirstWithItsParameterAndAHeldOutGain) {
  const std::string effect = GetParam();
  const sim::Effect* e = sim::FindEffect(effect);
  ASSERT_NE(e, nullptr);
  int named_first = 0, grouped = 0, parameters = 0, in_interval = 0, gain_ok = 0, after_experiment = 0;
  const std::vector<std::string> all = InjectableEffects();
  std::uint64_t seed = 1000 + 100 * static_cast<std::uint64_t>(std::find(all.begin(), all.end(), effect) - all.begin());
  for (int k = 0; k < kPerEffect; ++k) {
    const Scenario s = DrawScenario(++seed, {effect}, false);
    const auto d = DiagnoseScenario(s);
    ASSERT_TRUE(d.ok()) << d.status().message();
    const sim::EffectInstance* truth = s.truth.Find(effect);
    if (NamedFirst(*d, effect)) {
      ++named_first;
      ++after_experiment;
      const sim::Cause& c = d->causes.front();
      for (int j = 0; j < e->parameter_count(); ++j) {
        if (c.aliased[static_cast<std::size_t>(j)]) continue;  // no interval: the alias group carries it
        ++parameters;
        if (truth->values[j] >= c.lower[j] && truth->values[j] <= c.upper[j]) ++in_interval;
      }
    } else {
      parameters += e->parameter_count();
      // Not named, but honestly reported: inside an alias group ("one or more of: ...") and nothing
      // else named in its place.
      if (d->causes.empty() && d->InAliasGroup(effect)) ++grouped;
      std::printf("  miss: seed %llu %s n %d snr %.1f -> %s", static_cast<unsigned long long>(seed), s.surface.c_str(),
                  s.points, s.snr, d->causes.empty() ? "(none)" : d->causes.front().effect.c_str());
      for (const auto& g : d->alias_groups) std::printf("; %s", g.Message().c_str());
      std::printf("\n");
      if (!d->alias_groups.empty()) {
        std::string kind;
        const auto after = AfterTheProposedExperiment(s, *d, seed, &kind);
        const bool named = after.ok() && NamedFirst(*after, effect);
        if (named) ++after_experiment;
        std::printf("    after the proposed experiment (%s): %s\n", kind.empty() ? "none" : kind.c_str(),
                    !after.ok()             ? after.status().message().c_str()
                    : named                 ? "named first"
                    : after->causes.empty() ? "nothing named"
                                            : ("named first: " + after->causes.front().effect).c_str());
      }
    }
    if (d->heldout_rms_before_um - d->heldout_rms_after_um >= 0.5 * s.effect_rms_um) ++gain_ok;
  }
  std::printf(
      "%-16s scenarios %d  named first %.0f%% (after the proposed experiment %.0f%%)  only in an alias group %.0f%%  "
      "parameters in 95%% interval %.0f%%  held-out gain >= 50%%: %.0f%%\n",
      effect.c_str(), kPerEffect, 100.0 * named_first / kPerEffect, 100.0 * after_experiment / kPerEffect,
      100.0 * grouped / kPerEffect, 100.0 * in_interval / std::max(1, parameters), 100.0 * gain_ok / kPerEffect);
  // Issue 20: an effect whose look-alike the part as planned cannot exclude (wear and a linear thermal
  // drift at SNR 3–5, squareness_xy and a rotation about z on a saddle — the same columns —, a tool
  // radius and a z offset on a near-flat part) is reported as an alias group, not named: named or so
  // reported in ≥ 95 %, named first in ≥ 90 %. The experiment the diagnosis proposes (a tool setter and
  // datum, a datum plane, the next part's raster turned) then names it first in ≥ 95 %, the bound the
  // part as planned met before issue 20.
  EXPECT_GE(named_first + grouped, 0.95 * kPerEffect);
  EXPECT_GE(named_first, 0.90 * kPerEffect);
  EXPECT_GE(after_experiment, 0.95 * kPerEffect);
  // 20 draws cannot pin a 95 % coverage per effect (P(≤ 17 of 20) is 7.5 % at exactly 95 %); this is
  // the per-effect sanity bound, the ≥ 90 % requirement is asserted pooled in ParametersLie... below.
  EXPECT_GE(in_interval, 0.75 * parameters);
  EXPECT_GE(gain_ok, 0.95 * kPerEffect);
}

INSTANTIATE_TEST_SUITE_P(Catalogue, SingleEffect, ::testing::ValuesIn(InjectableEffects()),
                         [](const ::testing::TestParamInfo<std::string>& param_info) { return param_info.param; });

// The reported 95 % intervals, pooled over every effect (10 scenarios each, other seeds than above). A
// parameter inside an alias group has no interval (the group carries it, issue 20): counted apart.
TEST(DiscoveryTest, ParametersLieInTheirReported95PercentIntervals) {
  int parameters = 0, inside = 0, not_named = 0, aliased = 0;
  std::uint64_t seed = 50000;
  for (const std::string& effect : InjectableEffects()) {
    int p_e = 0, in_e = 0;
    for (int k = 0; k < 10; ++k) {
      const Scenario s = DrawScenario(++seed, {effect}, false);
      const auto d = DiagnoseScenario(s);
      ASSERT_TRUE(d.ok()) << d.status().message();
      const sim::EffectInstance* truth = s.truth.Find(effect);
      if (d->causes.empty() || d->causes.front().effect != effect) {
        p_e += static_cast<int>(truth->values.size());
        ++not_named;
        continue;
      }
      const sim::Cause& c = d->causes.front();
      for (std::size_t j = 0; j < truth->values.size(); ++j) {
        if (c.aliased[j]) {
          ++aliased;
          continue;
        }
        ++p_e;
        if (truth->values[j] >= c.lower[j] && truth->values[j] <= c.upper[j]) ++in_e;
      }
    }
    std::printf("%-16s parameters %3d inside %5.1f%%\n", effect.c_str(), p_e, 100.0 * in_e / std::max(1, p_e));
    parameters += p_e;
    inside += in_e;
  }
  std::printf(
      "pooled: %d of %d parameters inside their 95%% interval (%.1f%%); %d scenarios not named first; %d "
      "parameters of named effects inside an alias group (no interval)\n",
      inside, parameters, 100.0 * inside / parameters, not_named, aliased);
  EXPECT_GE(inside, 0.90 * parameters);
}

TEST(DiscoveryTest, NoiseOnlyNamesNoCause) {
  constexpr int kScenarios = 40;
  int quiet = 0;
  for (int k = 0; k < kScenarios; ++k) {
    const Scenario s = DrawScenario(5000 + k, {}, false);
    const auto d = DiagnoseScenario(s);
    ASSERT_TRUE(d.ok()) << d.status().message();
    if (d->causes.empty())
      ++quiet;
    else
      std::printf("  false cause: seed %d %s -> %s\n", 5000 + k, s.surface.c_str(), d->causes.front().effect.c_str());
  }
  std::printf("noise only: no cause named in %d of %d\n", quiet, kScenarios);
  EXPECT_GE(quiet, 0.95 * kScenarios);
}

TEST(DiscoveryTest, TwoInjectedEffectsAreBothNamed) {
  constexpr int kScenarios = 40;
  const auto effects = InjectableEffects();
  int both = 0;
  Rng pick(77);
  for (int k = 0; k < kScenarios; ++k) {
    const std::size_t a = pick.UniformIndex(effects.size());
    std::size_t b = pick.UniformIndex(effects.size() - 1);
    if (b >= a) ++b;
    const Scenario s = DrawScenario(6000 + k, {effects[a], effects[b]}, false);
    const auto d = DiagnoseScenario(s);
    ASSERT_TRUE(d.ok()) << d.status().message();
    std::vector<std::string> named;
    for (const auto& c : d->causes) named.push_back(c.effect);
    const bool ok =
        std::count(named.begin(), named.end(), effects[a]) && std::count(named.begin(), named.end(), effects[b]);
    if (ok)
      ++both;
    else {
      std::printf("  pair %s + %s (seed %d, %s, snr %.1f): named", effects[a].c_str(), effects[b].c_str(), 6000 + k,
                  s.surface.c_str(), s.snr);
      for (const auto& n : named) std::printf(" %s", n.c_str());
      std::printf("\n");
    }
  }
  std::printf("two effects: both named in %d of %d\n", both, kScenarios);
  EXPECT_GE(both, 0.80 * kScenarios);
}

TEST(DiscoveryTest, ABumpOutsideTheCatalogueIsReportedUnexplainedNotMislabelled) {
  constexpr int kScenarios = 30;
  int right = 0;
  for (int k = 0; k < kScenarios; ++k) {
    const Scenario s = DrawScenario(7000 + k, {}, true);
    const auto d = DiagnoseScenario(s);
    ASSERT_TRUE(d.ok()) << d.status().message();
    if (d->unexplained && d->causes.empty())
      ++right;
    else {
      std::printf("  bump seed %d %s snr %.1f: unexplained %d, named", 7000 + k, s.surface.c_str(), s.snr,
                  d->unexplained);
      for (const auto& c : d->causes) std::printf(" %s(%.2f)", c.effect.c_str(), c.variance_explained);
      std::printf("\n");
    }
  }
  std::printf("bump: unexplained and nothing named in %d of %d\n", right, kScenarios);
  EXPECT_GE(right, 0.90 * kScenarios);
}

}  // namespace
}  // namespace formloop::testing

namespace formloop::testing {
namespace {

// A model learned on part 1 (one surface) predicts part 2 (another surface, same machine and tool):
// held-out RMS on part 2 falls by ≥ 50 % against the baseline.
TEST(DiscoveryTest, AModelLearnedOnOnePartPredictsAnother) {
  sim::Model machine;
  ASSERT_TRUE(machine.Set("tool_wear", {0.8}).ok());                // µm/m
  ASSERT_TRUE(machine.Set("thermal_drift_z", {6.0, 120.0}).ok());   // µm, s (saturates within the cut)
  ASSERT_TRUE(machine.Set("setup_offset", {4.0, -3.0, 2.0}).ok());  // µm
  Rng rng1(4242), rng2(4343);
  const Scenario part1 = MakeScenario(rng1, "saddle", 1500, 0, {}, false, &machine);
  const Scenario part2 = MakeScenario(rng2, "egg_box", 1200, 0, {}, false, &machine);
  const auto d = DiagnoseScenario(part1);
  ASSERT_TRUE(d.ok()) << d.status().message();
  std::printf("%s", d->Summary().c_str());
  // On a saddle a rotation about x or y through the part origin moves the surface like a shift: the
  // set-up may be reported as an alias group of offset and rotation; the others are named.
  for (const char* effect : {"tool_wear", "thermal_drift_z", "setup_offset"}) {
    EXPECT_TRUE(d->extended.Names(effect) || d->InAliasGroup(effect))
        << effect << " neither named nor aliased on part 1";
  }
  const auto before = sim::PredictionRms(InputOf(part2), part2.baseline);
  const auto after = sim::PredictionRms(InputOf(part2), d->extended);
  ASSERT_TRUE(before.ok() && after.ok());
  std::printf("part 2 (egg_box): prediction rms %.3f um with the baseline, %.3f um with the model learned on part 1\n",
              *before, *after);
  EXPECT_LE(*after, 0.5 * *before);
}

// A set-up offset on a sphere cap: a rotation about the part origin moves the cap like a shift
// perpendicular to the line from the origin to the sphere's centre, so each of tx, ty, tz loses its
// significance beside setup_rotation — but the shift along that line no rotation makes. The offset is
// named (the data need it), none of its components printed, and they sit in a group with the rotation;
// the rotation is not named.
TEST(DiscoveryTest, AnOffsetOnASphereCapIsNamedWithItsComponentsGroupedWithARotation) {
  sim::Model machine;
  ASSERT_TRUE(machine.Set("setup_offset", {9.5, -20.9, 20.9}).ok());  // µm: 19.8 along the centre line
  Rng rng(2218);
  const Scenario s = MakeScenario(rng, "sphere_cap", 1200, 0, {}, false, &machine);
  const auto d = DiagnoseScenario(s);
  ASSERT_TRUE(d.ok()) << d.status().message();
  std::printf("%s", d->Summary().c_str());
  ASSERT_FALSE(d->causes.empty());
  EXPECT_EQ(d->causes.front().effect, "setup_offset");
  for (const auto& c : d->causes) EXPECT_NE(c.effect, "setup_rotation");
  int aliased = 0;
  for (bool a : d->causes.front().aliased) aliased += a;
  EXPECT_GE(aliased, 2);  // at least the two components across the centre line
  bool grouped_with_rotation = false;
  for (const auto& g : d->alias_groups) {
    const bool rotation = std::count(g.members.begin(), g.members.end(), "setup_rotation") == 1;
    const bool component = std::any_of(g.members.begin(), g.members.end(),
                                       [](const std::string& m) { return m.rfind("setup_offset(", 0) == 0; });
    grouped_with_rotation = grouped_with_rotation || (rotation && component);
  }
  EXPECT_TRUE(grouped_with_rotation);
  // Not also listed as a look-alike the data separate.
  for (const auto& c : d->confounded) EXPECT_NE(c.other, "setup_rotation") << c.named;
  EXPECT_LT(d->heldout_rms_after_um, 0.2 * d->heldout_rms_before_um);
}

// A rotation of a sphere about an axis through the origin is a translation of it: the two form one alias
// group, neither is named, and the group carries the prediction.
TEST(DiscoveryTest, RotatingASphereCapIsReportedAsAnAliasGroupWithAnOffset) {
  sim::Model machine;
  ASSERT_TRUE(machine.Set("setup_rotation", {120.0, -80.0, 0.0}).ok());
  Rng rng(99);
  const Scenario s = MakeScenario(rng, "sphere_cap", 1500, 0, {}, false, &machine);
  const auto d = DiagnoseScenario(s);
  ASSERT_TRUE(d.ok()) << d.status().message();
  std::printf("%s", d->Summary().c_str());
  for (const auto& c : d->causes) EXPECT_TRUE(c.effect != "setup_rotation" && c.effect != "setup_offset") << c.effect;
  ASSERT_FALSE(d->alias_groups.empty());
  const auto& members = d->alias_groups.front().members;
  EXPECT_TRUE(std::count(members.begin(), members.end(), "setup_rotation") == 1 &&
              std::count(members.begin(), members.end(), "setup_offset") == 1)
      << d->alias_groups.front().Message();
  EXPECT_GT(d->alias_groups.front().max_correlation, 0.99);
  EXPECT_LT(d->heldout_rms_after_um, 0.5 * d->heldout_rms_before_um);
  EXPECT_FALSE(d->extended.alias_groups.empty());
}

}  // namespace
}  // namespace formloop::testing
