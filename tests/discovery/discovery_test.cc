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

#include "tests/support/discovery.h"

namespace formloop::testing {
namespace {

constexpr int kPerEffect = 20;

class SingleEffect : public ::testing::TestWithParam<std::string> {};

// Named first, parameters inside the reported 95 % interval, held-out gain ≥ 50 % of the injected
// RMS — per effect, over kPerEffect scenarios (surfaces, point counts 400–3000, SNR 3–20 drawn).
TEST_P(SingleEffect, IsNamedFirstWithItsParameterAndAHeldOutGain) {
  const std::string effect = GetParam();
  const sim::Effect* e = sim::FindEffect(effect);
  ASSERT_NE(e, nullptr);
  int named_first = 0, grouped = 0, parameters = 0, in_interval = 0, gain_ok = 0;
  const std::vector<std::string> all = InjectableEffects();
  std::uint64_t seed = 1000 + 100 * static_cast<std::uint64_t>(std::find(all.begin(), all.end(), effect) - all.begin());
  for (int k = 0; k < kPerEffect; ++k) {
    const Scenario s = DrawScenario(++seed, {effect}, false);
    const auto d = DiagnoseScenario(s);
    ASSERT_TRUE(d.ok()) << d.status().message();
    const sim::EffectInstance* truth = s.truth.Find(effect);
    if (!d->causes.empty() && d->causes.front().effect == effect) {
      ++named_first;
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
    }
    if (d->heldout_rms_before_um - d->heldout_rms_after_um >= 0.5 * s.effect_rms_um) ++gain_ok;
  }
  std::printf(
      "%-16s scenarios %d  named first %.0f%%  only in an alias group %.0f%%  parameters in 95%% interval "
      "%.0f%%  held-out gain >= 50%%: %.0f%%\n",
      effect.c_str(), kPerEffect, 100.0 * named_first / kPerEffect, 100.0 * grouped / kPerEffect,
      100.0 * in_interval / std::max(1, parameters), 100.0 * gain_ok / kPerEffect);
  // Issue 20: an effect whose look-alike the design cannot exclude (wear and thermal drift at SNR 3–5,
  // squareness and a rotation on a saddle) is reported as an alias group, not named. Named or so
  // reported in ≥ 95 %; named first in ≥ 85 % (before issue 20 the bound was named first in ≥ 95 %).
  EXPECT_GE(named_first + grouped, 0.95 * kPerEffect);
  EXPECT_GE(named_first, 0.85 * kPerEffect);
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
