// The thin-plate deviation field of `nc compensate` at the size of a finished part (issue 26): 2,916
// samples (a 54 × 54 probe grid, seeded smooth field + 1 µm noise) evaluated at 1,050,000 cutter
// locations (1,000 raster passes of 1,050 points over the unit square). Wall and CPU time of the fit,
// of building the tabulated field (nc-gen/deviation_field.h) and of evaluating it at every location (one
// thread, then fixed chunks on all cores), beside the direct sum, and the largest difference between
// the two. The direct sum is timed on every 50th location (21,000) and scaled to all of them, unless
// --full. The peer is SciPy's RBFInterpolator (thin_plate_spline, degree 1, no smoothing) through
// bench/rbf_peer.py and /usr/bin/python3, fitted to the same samples and evaluated at the same subset (or
// all with --full), its values compared with formloop's direct sum; skipped with a message when absent.
//
//   ./build/bench/formloop_bench_compensate_field [--full]

#include <sys/resource.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <string>
#include <vector>

#include "bench/bench_support.h"
#include "core/parallel.h"
#include "core/random.h"
#include "nc-gen/deviation_field.h"

namespace formloop {
namespace {

using bench::CpuSeconds;
using bench::JsonNumber;

struct Clock {
  std::chrono::steady_clock::time_point wall = std::chrono::steady_clock::now();
  double cpu = CpuSeconds();
  double Wall() const { return std::chrono::duration<double>(std::chrono::steady_clock::now() - wall).count(); }
  double Cpu() const { return CpuSeconds() - cpu; }
};

void Row(const char* what, double wall_s, double cpu_s, const std::string& note = "") {
  std::printf("%-52s %9.3f s %9.3f s  %s\n", what, wall_s, cpu_s, note.c_str());
}

}  // namespace
}  // namespace formloop

int main(int argc, char** argv) {
  using namespace formloop;
  const bool full = argc > 1 && std::string(argv[1]) == "--full";
  constexpr int kGrid = 54, kPasses = 1000, kAlong = 1050, kStride = 50;
  Rng rng(26);
  std::vector<nc::DeviationSample> samples;
  for (int a = 0; a < kGrid; ++a) {
    for (int b = 0; b < kGrid; ++b) {
      const double u = 0.02 + 0.96 * a / (kGrid - 1), v = 0.02 + 0.96 * b / (kGrid - 1);
      const double ds = 15 * std::sin(8.2 * u) * std::cos(5.7 * v) + 20 * (u - 0.5) * (v - 0.5) + rng.Normal(0, 1);
      samples.push_back({.u = u, .v = v, .ds_um = ds});
    }
  }
  std::vector<double> qu, qv;
  for (int p = 0; p < kPasses; ++p) {
    for (int m = 0; m < kAlong; ++m) {
      qu.push_back(static_cast<double>(m) / (kAlong - 1));
      qv.push_back(static_cast<double>(p) / (kPasses - 1));
    }
  }
  const long n = static_cast<long>(qu.size());
  std::vector<long> subset;
  for (long i = 0; i < n; i += full ? 1 : kStride) subset.push_back(i);
  const double scale = static_cast<double>(n) / static_cast<double>(subset.size());
  std::printf("thin-plate field of %zu samples at %ld cutter locations (%d threads available)\n", samples.size(), n,
              ThreadCount());
  std::printf("%-52s %11s %11s\n", "", "wall", "CPU");

  Clock clock;
  auto field = nc::DeviationField::Fit(samples, {});
  if (!field.ok()) return 1;
  Row("formloop fit (Cholesky on the null space)", clock.Wall(), clock.Cpu());
  clock = Clock();
  auto table = field->Tabulate();
  if (!table.ok()) {
    std::printf("tabulation failed: %s\n", table.status().ToString().c_str());
    return 1;
  }
  Row("formloop tabulate", clock.Wall(), clock.Cpu(),
      std::to_string(table->cells_per_side()) + "² cells, measured error " +
          std::to_string(table->measured_error_um()) + " um");
  std::vector<double> tabulated(static_cast<std::size_t>(n));
  for (int threads : {1, 0}) {
    SetThreadCount(threads);
    clock = Clock();
    ParallelFor(n, 8192, [&](long begin, long end) {
      for (long i = begin; i < end; ++i) tabulated[static_cast<std::size_t>(i)] = table->EvaluateUm(qu[i], qv[i]);
    });
    Row(threads == 1 ? "formloop tabulated evaluation, 1 thread" : "formloop tabulated evaluation, all cores",
        clock.Wall(), clock.Cpu());
  }
  SetThreadCount(0);
  std::vector<double> direct(subset.size());
  SetThreadCount(1);
  clock = Clock();
  for (std::size_t s = 0; s < subset.size(); ++s) direct[s] = field->EvaluateUm(qu[subset[s]], qv[subset[s]]);
  const double direct_wall = clock.Wall() * scale, direct_cpu = clock.Cpu() * scale;
  SetThreadCount(0);
  Row("formloop direct sum (1 thread), all locations", direct_wall, direct_cpu,
      full ? "" : "timed on " + std::to_string(subset.size()) + " locations, scaled");
  double worst = 0;
  for (std::size_t s = 0; s < subset.size(); ++s) {
    worst = std::max(worst, std::abs(tabulated[static_cast<std::size_t>(subset[s])] - direct[s]));
  }
  std::printf("  max |tabulated - direct| over %zu locations: %.2e um (tolerance %.0e um)\n", subset.size(), worst,
              nc::kTabulatedToleranceUm);

  if (std::system("/usr/bin/python3 -c 'import scipy.interpolate' >/dev/null 2>&1") != 0) {
    std::printf("peer skipped: /usr/bin/python3 with SciPy (Debian's python3-scipy) is not available\n");
    return worst <= nc::kTabulatedToleranceUm ? 0 : 1;
  }
  char dir_template[] = "/tmp/formloop_field_bench_XXXXXX";
  if (!mkdtemp(dir_template)) return 1;
  const std::string dir = dir_template, samples_file = dir + "/samples.bin", queries_file = dir + "/queries.bin";
  {
    std::ofstream out(samples_file, std::ios::binary);
    for (const auto& s : samples) {
      const double row[3] = {s.u, s.v, s.ds_um};
      out.write(reinterpret_cast<const char*>(row), sizeof row);
    }
    std::ofstream q(queries_file, std::ios::binary);
    for (long i : subset) {
      const double row[2] = {qu[static_cast<std::size_t>(i)], qv[static_cast<std::size_t>(i)]};
      q.write(reinterpret_cast<const char*>(row), sizeof row);
    }
  }
  const std::string command = "/usr/bin/python3 " + std::string(FORMLOOP_SOURCE_DIR) + "/bench/rbf_peer.py " +
                              samples_file + " " + std::to_string(samples.size()) + " " + queries_file + " " +
                              std::to_string(subset.size());
  std::string line;
  int failures = worst <= nc::kTabulatedToleranceUm ? 0 : 1;
  if (!bench::RunPeer(command, &line)) {
    std::printf("peer failed: %s\n", command.c_str());
    ++failures;
  } else {
    Row("SciPy RBFInterpolator fit", JsonNumber(line, "fit_s"), JsonNumber(line, "fit_cpu_s"));
    Row("SciPy RBFInterpolator evaluation, all locations", JsonNumber(line, "evaluate_s") * scale,
        JsonNumber(line, "evaluate_cpu_s") * scale,
        full ? "" : "timed on " + std::to_string(subset.size()) + " locations, scaled");
    std::ifstream in(queries_file + ".values", std::ios::binary);
    std::vector<double> theirs(subset.size());
    in.read(reinterpret_cast<char*>(theirs.data()), static_cast<std::streamsize>(theirs.size() * sizeof(double)));
    double peer_diff = 0;
    for (std::size_t s = 0; s < subset.size(); ++s) peer_diff = std::max(peer_diff, std::abs(theirs[s] - direct[s]));
    std::printf("  max |SciPy - formloop direct| over %zu locations: %.2e um\n", subset.size(), peer_diff);
  }
  std::filesystem::remove_all(dir);
  return failures;
}
