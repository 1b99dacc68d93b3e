// Model discovery, measured (spec/simulation.md §5–§6, issue 20):
//   1. `diagnose` on 3,000 probe points against the full catalogue: wall and CPU time (goal < 5 s); and
//      pooled over 3 parts of one machine (3 × 1,000 and 3 × 3,000 points), with and without the
//      proposal of the separating experiment, beside the single-part figure.
//   2. The hidden-effect sweep at a larger scale than the CI suite (tests/discovery): per effect the
//      rate of naming it first, of its parameters inside their 95 % intervals and of a held-out gain
//      ≥ 50 % of its RMS; noise-only, two-effect and outside-the-catalogue (bump) scenarios.
//   Diagnose's candidate fits, exchange steps and profile intervals run on the cores --threads allows
//   (core/parallel.h, the same bytes on any count): the pooled figures are printed on one thread and on
//   all cores, side by side; the sweep runs its scenarios on all cores (each scenario on its own seed,
//   so the rates are the same as one at a time).
// Usage: formloop_bench_discovery [scenarios_per_effect (default 50; 0: the timings alone)]

#include <array>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <ctime>
#include <map>
#include <string>
#include <vector>

#include "core/parallel.h"
#include "tests/support/multi_effect.h"

using namespace formloop;
using namespace formloop::testing;

namespace {
// Counts per scenario (four outcomes), filled on all cores, each scenario in its own slot.
using Tally = std::array<int, 4>;
Tally Sum(const std::vector<Tally>& tallies) {
  Tally sum{0, 0, 0, 0};
  for (const Tally& t : tallies) {
    for (std::size_t k = 0; k < sum.size(); ++k) sum[k] += t[k];
  }
  return sum;
}
double CpuSeconds() { return static_cast<double>(std::clock()) / CLOCKS_PER_SEC; }
double WallSeconds() {
  return std::chrono::duration<double>(std::chrono::steady_clock::now().time_since_epoch()).count();
}
}  // namespace

int main(int argc, char** argv) {
  const int per_effect = argc > 1 ? std::atoi(argv[1]) : 50;
  // 1. Timing at 3,000 points.
  {
    sim::Model machine;
    (void)machine.Set("thermal_drift_z", {6.0, 200.0});
    Rng rng(3000);
    const Scenario s = MakeScenario(rng, "franke", 3000, 0, {}, false, &machine);
    std::vector<double> wall, cpu;
    for (int rep = 0; rep < 5; ++rep) {
      const double w0 = WallSeconds(), c0 = CpuSeconds();
      const auto d = DiagnoseScenario(s);
      wall.push_back(WallSeconds() - w0);
      cpu.push_back(CpuSeconds() - c0);
      if (!d.ok()) {
        std::printf("diagnose failed: %s\n", d.status().message().c_str());
        return 1;
      }
      if (rep == 0) std::printf("%s", d->Summary().c_str());
    }
    std::sort(wall.begin(), wall.end());
    std::sort(cpu.begin(), cpu.end());
    std::printf(
        "diagnose, 3000 points, %zu candidate effects: median wall %.3f s, CPU %.3f s (min %.3f / max %.3f s wall)\n\n",
        InjectableEffects().size(), wall[2], cpu[2], wall.front(), wall.back());
  }
  // 1b. Pooling: three parts of one machine (thermal drift, wear and a tool radius error shared; each
  // part its own set-up offset), different surfaces and raster angles.
  {
    sim::Model machine;
    (void)machine.Set("thermal_drift_z", {12.0, 900.0});
    (void)machine.Set("tool_wear", {2.0});
    (void)machine.Set("tool_radius", {5.0});
    (void)machine.Set("noise", {0.8, 0.6});
    const std::vector<std::vector<double>> setups = {{10, -6, 0}, {-4, 8, 5}, {3, 3, -7}};
    for (int grid : {18, 32, 55}) {
      std::vector<Scenario> parts;
      const std::vector<PartLayout> layouts = {{"franke", 0, grid}, {"saddle", 45, grid}, {"egg_box", 90, grid}};
      for (std::size_t p = 0; p < layouts.size(); ++p) {
        sim::Model truth = machine;
        (void)truth.Set("setup_offset", setups[p]);
        parts.push_back(ProbePart(layouts[p], truth, 100 + p));
      }
      std::vector<sim::ProbeDataInput> inputs;
      for (const auto& part : parts) inputs.push_back(InputOf(part));
      sim::DiagnoseOptions o;
      o.plausible = StarterPlausibleRanges();
      for (int threads : {1, 0}) {
        SetThreadCount(threads);
        std::vector<double> wall, cpu, wall_proposal;
        for (int rep = 0; rep < 3; ++rep) {
          const double w0 = WallSeconds();
          const auto single = sim::Diagnose(inputs[0], parts[0].baseline, o);
          const double w1 = WallSeconds(), c1 = CpuSeconds();
          const auto d = sim::DiagnosePooled(inputs, parts[0].baseline, o);
          const double w2 = WallSeconds(), c2 = CpuSeconds();
          if (!single.ok() || !d.ok()) {
            std::printf("diagnose failed\n");
            return 1;
          }
          auto proposals = sim::ProposeExperiments(inputs, *d, parts[0].baseline, ExperimentOptionsFor(parts[0]));
          const double w3 = WallSeconds();
          wall.push_back(w2 - w1);
          cpu.push_back(c2 - c1);
          wall_proposal.push_back(w3 - w2);
          if (rep == 0 && threads == 1) {
            std::printf("one part of %d points: %.3f s wall\n%s", parts[0].points, w1 - w0, d->Summary().c_str());
          }
        }
        std::sort(wall.begin(), wall.end());
        std::sort(cpu.begin(), cpu.end());
        std::sort(wall_proposal.begin(), wall_proposal.end());
        std::printf(
            "diagnose pooled, 3 parts x %d points (%d in all), %d thread(s): median wall %.3f s, CPU %.3f s (min "
            "%.3f / max %.3f s wall); the separating-experiment proposal on top: median %.3f s\n",
            parts[0].points, 3 * parts[0].points, ThreadCount(), wall[1], cpu[1], wall.front(), wall.back(),
            wall_proposal[1]);
      }
      std::printf("\n");
    }
    SetThreadCount(0);
  }
  // 2. The sweep (an argument of 0: the timings alone).
  if (per_effect <= 0) return 0;
  std::printf("%-16s %9s %12s %14s %12s\n", "effect", "scenarios", "named first", "params in 95%", "gain >= 50%");
  int total_named = 0, total = 0, total_in = 0, total_params = 0;
  std::uint64_t seed = 200000;
  // Per scenario: {named, parameters inside, parameters, gain}.
  for (const std::string& effect : InjectableEffects()) {
    std::vector<Tally> tallies(static_cast<std::size_t>(std::max(0, per_effect)), Tally{0, 0, 0, 0});
    const std::uint64_t first_seed = seed + 1;
    seed += static_cast<std::uint64_t>(std::max(0, per_effect));
    ParallelFor(per_effect, 1, [&](long begin, long end) {
      for (long k = begin; k < end; ++k) {
        const Scenario s = DrawScenario(first_seed + static_cast<std::uint64_t>(k), {effect}, false);
        const auto d = DiagnoseScenario(s);
        if (!d.ok()) continue;
        Tally& t = tallies[static_cast<std::size_t>(k)];
        const sim::EffectInstance* truth = s.truth.Find(effect);
        t[2] = static_cast<int>(truth->values.size());
        if (!d->causes.empty() && d->causes.front().effect == effect) {
          t[0] = 1;
          for (std::size_t j = 0; j < truth->values.size(); ++j) {
            if (std::abs(d->causes.front().parameters[j] - truth->values[j]) <= 1.96 * d->causes.front().std_errors[j])
              ++t[1];
          }
        }
        if (d->heldout_rms_before_um - d->heldout_rms_after_um >= 0.5 * s.effect_rms_um) t[3] = 1;
      }
    });
    const auto [named, in, params, gain] = Sum(tallies);
    std::printf("%-16s %9d %11.1f%% %13.1f%% %11.1f%%\n", effect.c_str(), per_effect, 100.0 * named / per_effect,
                100.0 * in / std::max(1, params), 100.0 * gain / per_effect);
    total_named += named;
    total += per_effect;
    total_in += in;
    total_params += params;
  }
  std::printf("%-16s %9d %11.1f%% %13.1f%%\n\n", "all", total, 100.0 * total_named / total,
              100.0 * total_in / total_params);
  const int others = 4 * per_effect;
  const auto effects = InjectableEffects();
  // The effect pairs drawn first, in order (one generator), then the scenarios on all cores; per
  // scenario k: {noise quiet, both named, bump set aside, broad bump set aside}.
  Rng pick(77);
  std::vector<std::pair<std::size_t, std::size_t>> pairs;
  for (int k = 0; k < others; ++k) {
    const std::size_t a = pick.UniformIndex(effects.size());
    std::size_t b = pick.UniformIndex(effects.size() - 1);
    if (b >= a) ++b;
    pairs.emplace_back(a, b);
  }
  std::vector<Tally> outcomes(static_cast<std::size_t>(std::max(0, others)), Tally{0, 0, 0, 0});
  ParallelFor(others, 1, [&](long begin, long end) {
    for (long k = begin; k < end; ++k) {
      Tally& t = outcomes[static_cast<std::size_t>(k)];
      const auto noise = DiagnoseScenario(DrawScenario(300000 + k, {}, false));
      t[0] = noise.ok() && noise->causes.empty();
      const auto [a, b] = pairs[static_cast<std::size_t>(k)];
      const auto pair = DiagnoseScenario(DrawScenario(400000 + k, {effects[a], effects[b]}, false));
      if (pair.ok()) {
        int found = 0;
        for (const auto& c : pair->causes) found += (c.effect == effects[a] || c.effect == effects[b]);
        t[1] = found == 2;
      }
      const auto bump = DiagnoseScenario(DrawScenario(500000 + k, {}, true, 0.06));
      t[2] = bump.ok() && bump->unexplained && bump->causes.empty();
      const auto broad = DiagnoseScenario(DrawScenario(600000 + k, {}, true, 0.12));
      t[3] = broad.ok() && broad->unexplained && broad->causes.empty();
    }
  });
  const auto [quiet, both, bump_ok, broad_ok] = Sum(outcomes);
  std::printf("noise only: no cause named              %5.1f%% of %d\n", 100.0 * quiet / others, others);
  std::printf("two effects: both named                 %5.1f%% of %d\n", 100.0 * both / others, others);
  std::printf("local bump (sigma 6%% of part): unexplained, nothing named  %5.1f%% of %d\n", 100.0 * bump_ok / others,
              others);
  std::printf("broad bump (sigma 12%% of part): unexplained, nothing named %5.1f%% of %d\n", 100.0 * broad_ok / others,
              others);
  return 0;
}
