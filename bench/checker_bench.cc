// Cost of the independent scallop/gouge checker (tests/support/swept_ball.h) on a realistic tool path:
// PlanRaster on a B-spline fit of franke (61 × 61 grid, 100 × 100 mm), 6 mm ball (r = 3), 5 µm scallop,
// 1 µm chord tolerance, point spacing set for about 80,000 CL points.
//
//   BM_BuildCapsuleHash        swept capsules of the whole path into the 1 mm xy hash
//   BM_HeightHash              machined height at N random (x, y) in the part (hash lookup + capsules)
//   BM_CheckSampleHash         a full checker sample: Q(u, v), n(u, v), machined height, normal distance
//   BM_HeightBruteForce        reference method: every capsule for every sample, on a small subset
//
// After the Google Benchmark table, a summary: samples/s of both methods (with the largest difference
// between them on the subset, which must be 0) and the time for a full-surface check with samples
// step-over/10 apart in u and in v (the spacing the tests use across the passes).
//
//   ./build/bench/formloop_bench_checker [--benchmark_filter=...]

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <memory>
#include <random>
#include <vector>

#include <benchmark/benchmark.h>

#include "nc-gen/toolpath.h"
#include "reconstruction/analytic_surface.h"
#include "reconstruction/bspline_surface.h"
#include "tests/support/swept_ball.h"

namespace formloop {
namespace {

constexpr long kTargetCl = 80'000;

struct Fixture {
  recon::BSplineSurface q;
  nc::Toolpath path;
  std::unique_ptr<testing::MachinedSurface> machined;
  std::vector<Eigen::Vector2d> uv;  // random parameters, 2 mm inside the domain
  std::vector<Eigen::Vector2d> xy;  // Q(u, v).xy of those
};

Fixture MakeFixture() {
  auto franke = recon::MakeReferenceSurface("franke");
  recon::FitReport report;
  auto q = recon::FitAnalytic(**franke, 61, 61, recon::GridFitOptions{}, 0, 1, &report);
  if (!q.ok()) {
    std::fprintf(stderr, "%s\n", q.status().ToString().c_str());
    std::exit(1);
  }
  nc::ToolpathOptions options;
  options.tool.radius_mm = 3;
  options.scallop_um = 5;
  options.chord_tolerance_um = 1;
  options.max_point_spacing_mm = 0.5;
  auto path = nc::PlanRaster(*q, options);
  // The spacing cap sets the count where the chord tolerance does not: correct it on the measured counts.
  for (int round = 0; round < 3 && path.ok(); ++round) {
    const double ratio = static_cast<double>(path->points.size()) / kTargetCl;
    if (std::abs(ratio - 1) < 0.03) break;
    options.max_point_spacing_mm *= ratio;
    path = nc::PlanRaster(*q, options);
  }
  if (!path.ok()) {
    std::fprintf(stderr, "%s\n", path.status().ToString().c_str());
    std::exit(1);
  }
  Fixture f{q.value(), path.value(), nullptr, {}, {}};
  f.machined = std::make_unique<testing::MachinedSurface>(f.path, f.path.options.tool.radius_mm);
  const recon::ParamDomain dom = f.q.domain();
  std::mt19937_64 rng(42);
  std::uniform_real_distribution<double> ru(dom.u_min + 2, dom.u_max - 2), rv(dom.v_min + 2, dom.v_max - 2);
  for (int i = 0; i < (1 << 16); ++i) {
    f.uv.emplace_back(ru(rng), rv(rng));
    f.xy.push_back(f.q.Point(f.uv.back().x(), f.uv.back().y()).head<2>());
  }
  return f;
}

const Fixture& Get() {
  static const Fixture f = MakeFixture();
  return f;
}

void BM_BuildCapsuleHash(benchmark::State& state) {
  const Fixture& f = Get();
  for (auto _ : state) {
    testing::MachinedSurface m(f.path, f.path.options.tool.radius_mm);
    benchmark::DoNotOptimize(m.cell_count());
  }
  state.counters["CL"] = static_cast<double>(f.path.points.size());
  state.counters["cells"] = static_cast<double>(f.machined->cell_count());
}
BENCHMARK(BM_BuildCapsuleHash)->Unit(benchmark::kMillisecond);

void BM_HeightHash(benchmark::State& state) {
  const Fixture& f = Get();
  const std::size_t n = static_cast<std::size_t>(state.range(0));
  for (auto _ : state) {
    double sum = 0;
    for (std::size_t i = 0; i < n; ++i) sum += f.machined->Height(f.xy[i].x(), f.xy[i].y());
    benchmark::DoNotOptimize(sum);
  }
  state.SetItemsProcessed(state.iterations() * state.range(0));
}
BENCHMARK(BM_HeightHash)->Arg(1 << 16)->Unit(benchmark::kMillisecond);

void BM_CheckSampleHash(benchmark::State& state) {
  const Fixture& f = Get();
  const std::size_t n = static_cast<std::size_t>(state.range(0));
  for (auto _ : state) {
    testing::CheckResult r;
    for (std::size_t i = 0; i < n; ++i) testing::CheckSample(f.q, *f.machined, f.uv[i].x(), f.uv[i].y(), &r);
    benchmark::DoNotOptimize(r.max_scallop_um);
  }
  state.SetItemsProcessed(state.iterations() * state.range(0));
}
BENCHMARK(BM_CheckSampleHash)->Arg(1 << 16)->Unit(benchmark::kMillisecond);

void BM_HeightBruteForce(benchmark::State& state) {
  const Fixture& f = Get();
  const std::size_t n = static_cast<std::size_t>(state.range(0));
  for (auto _ : state) {
    double sum = 0;
    for (std::size_t i = 0; i < n; ++i) sum += f.machined->BruteForceHeight(f.xy[i].x(), f.xy[i].y());
    benchmark::DoNotOptimize(sum);
  }
  state.SetItemsProcessed(state.iterations() * state.range(0));
}
BENCHMARK(BM_HeightBruteForce)->Arg(64)->Unit(benchmark::kMillisecond);

double Seconds(std::chrono::steady_clock::time_point since) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - since).count();
}

void Summary() {
  const Fixture& f = Get();
  using Clock = std::chrono::steady_clock;
  auto t0 = Clock::now();
  const testing::MachinedSurface m(f.path, f.path.options.tool.radius_mm);
  const double build_s = Seconds(t0);

  t0 = Clock::now();
  testing::CheckResult r;
  for (const auto& uv : f.uv) testing::CheckSample(f.q, m, uv.x(), uv.y(), &r);
  const double hash_rate = static_cast<double>(f.uv.size()) / Seconds(t0);

  constexpr std::size_t kBrute = 256;
  double worst = 0;
  t0 = Clock::now();
  std::vector<double> brute(kBrute);
  for (std::size_t i = 0; i < kBrute; ++i) brute[i] = m.BruteForceHeight(f.xy[i].x(), f.xy[i].y());
  const double brute_rate = kBrute / Seconds(t0);
  for (std::size_t i = 0; i < kBrute; ++i)
    worst = std::max(worst, std::abs(brute[i] - m.Height(f.xy[i].x(), f.xy[i].y())));

  const recon::ParamDomain dom = f.q.domain();
  const double spacing = f.path.min_step_over_mm / 10;
  const double full = std::floor(dom.u_span() / spacing + 1) * std::floor(dom.v_span() / spacing + 1);
  std::printf(
      "\nchecker summary: franke fit 61x61, r = %.1f mm, scallop %.0f um: %zu CL, %d passes, step-over "
      "%.4f..%.4f mm, %zu capsules in %zu hash cells\n",
      f.path.options.tool.radius_mm, f.path.options.scallop_um, f.path.points.size(), f.path.passes,
      f.path.min_step_over_mm, f.path.max_step_over_mm, m.capsule_count(), m.cell_count());
  std::printf("  build capsule hash                 %10.3f s\n", build_s);
  std::printf(
      "  hash: full sample (Q, n, height)   %10.3g samples/s  (%zu samples: max scallop %.2f um, max gouge "
      "%.2f um, %d uncovered)\n",
      hash_rate, f.uv.size(), r.max_scallop_um, r.max_gouge_um, r.uncovered);
  std::printf("  reference: brute force height      %10.3g samples/s  (%zu samples; max |hash - brute| %.3g mm)\n",
              brute_rate, kBrute, worst);
  std::printf("  full-surface check at step-over/10 = %.4f mm in u and v: %.3g samples\n", spacing, full);
  std::printf("    hash:        %10.1f s  (build + samples / rate)\n", build_s + full / hash_rate);
  std::printf("    brute force: %10.3g s  (estimated from the subset rate; %.0fx the hash)\n", full / brute_rate,
              (full / brute_rate) / (build_s + full / hash_rate));
}

}  // namespace
}  // namespace formloop

int main(int argc, char** argv) {
  benchmark::Initialize(&argc, argv);
  if (benchmark::ReportUnrecognizedArguments(argc, argv)) return 1;
  benchmark::RunSpecifiedBenchmarks();
  benchmark::Shutdown();
  formloop::Summary();
  return 0;
}
