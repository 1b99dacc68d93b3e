// Scattered-point fit (FitScattered) against OpenCASCADE's grid approximator
// (GeomAPI_PointsToBSplineSurface through FitGrid) on the same surface, noise and control-net size.
//
// Data: Franke's surface (100 × 100 mm, heights 0-24 mm), 1 µm Gaussian noise along the normal.
// - OCCT: a 316 × 316 grid (99,856 samples), cubic (degree 3..3), C2, tolerance 5 µm (5σ: it
//   stops refining once the noise is all that is left). It runs first; its pole counts are read.
// - Ours: 100,000 seeded uniform scattered points, cubic, the same total u × v pole counts,
//   parameter correction (at most 3 rounds; see the counter "rounds"); λ by GCV (the default) and,
//   to show what bias GCV's λ adds, a tiny fixed λ = 1e-9. 100,000 points leave no corner hole
//   wider than a fraction of a span, so FitScattered takes the dense layout (scattered_fit.cc,
//   DataKnots): uniform knots over the data for a first fit, then knots redistributed to the
//   shape (RedistributedKnots) and a refit; the table prints that choice.
// Counters: fit residual RMS in µm (orthogonal distance of the fitted points to Q, for both; OCCT's
// own parametric figure as parametric_rms_um), error against the true surface at 10,000 random
// points (distance to the foot point on Q), poles.
// A table with all rows is printed at the end, with the RMS of the noise drawn for each data set.
//
// What "orth rms" measures: the residual against the noisy data it fitted, so it is the drawn
// noise (0.9971 µm on the grid, 1.0034 µm on the scatter) plus the model error in quadrature.
// Measured (Release, 2 shared cores; times vary with the load): OCCT 4-9 s, 1.094 µm (truth RMS
// 0.457 µm, max 5.4 µm). Ours with uniform knots (before 2026-11): 0.7 s, 1.153 µm (truth 0.571
// µm, max 6.6 µm), the same with λ = 1e-9 to 1e-3 µm, so not λ: OCCT's 24 × 24 net has uniform knots
// exactly over the grid's [0, 100]² (its knots were printed), ours over the PCA box, ~2 % wider
// (franke's principal plane is tilted ~10° from its xy domain) plus a rim of 2 spacings: spans ~4 %
// wider, and a cubic's error goes as h⁴. A search for the plane whose projection best fills its
// bounding rectangle found xy (1.121 µm; 1.108 µm with a 10× narrower rim), still above OCCT's,
// and it made the noise-free corner of franke in the reference test worse (0.5 -> 2.9 µm), so it
// was not kept. Redistributing the knots (NEWNOT: spans equidistribute the approximation error
// estimated from the first fit's third-derivative jumps) gives 1.055 µm, truth RMS 0.346 µm, max
// 2.6 µm, in 1.2-2.5 s (one more fit), at the same net size: lower than OCCT's on every figure.
//
// Run: formloop_bench_scattered_fit [--benchmark_repetitions=N]

#include <benchmark/benchmark.h>

#include <cmath>
#include <cstdio>
#include <string>
#include <vector>

#include "core/random.h"
#include "reconstruction/scattered_fit.h"

namespace formloop::recon {
namespace {

constexpr double kNoiseMm = 1e-3;
constexpr int kGridSide = 316;
constexpr int kScatteredPoints = 100000;
constexpr int kCheckPoints = 10000;

const AnalyticSurface& Surface() {
  static const std::unique_ptr<AnalyticSurface> surface = std::move(MakeReferenceSurface("franke")).value();
  return *surface;
}

// RMS of the noise actually drawn for each data set (µm): the floor of its residual RMS.
double grid_noise_rms_um = 0, scatter_noise_rms_um = 0;

const GridSamples& NoisyGrid() {
  static const GridSamples grid = [] {
    GridSamples g = SampleGrid(Surface(), kGridSide, kGridSide);
    Rng rng(7);
    double sum2 = 0;
    for (int j = 0; j < kGridSide; ++j) {
      for (int i = 0; i < kGridSide; ++i) {
        const double u = g.domain.u_min + g.domain.u_span() * i / (kGridSide - 1);
        const double v = g.domain.v_min + g.domain.v_span() * j / (kGridSide - 1);
        const double e = rng.Normal(0, kNoiseMm);
        sum2 += e * e;
        g.points[static_cast<std::size_t>(j * kGridSide + i)] += e * Surface().Normal(u, v);
      }
    }
    grid_noise_rms_um = std::sqrt(sum2 / (kGridSide * kGridSide)) * 1e3;
    return g;
  }();
  return grid;
}

const std::vector<Eigen::Vector3d>& NoisyScatter() {
  static const std::vector<Eigen::Vector3d> points = [] {
    const ParamDomain dom = Surface().domain();
    Rng rng(11);
    std::vector<Eigen::Vector3d> p;
    p.reserve(kScatteredPoints);
    double sum2 = 0;
    for (int i = 0; i < kScatteredPoints; ++i) {
      const double u = rng.Uniform(dom.u_min, dom.u_max), v = rng.Uniform(dom.v_min, dom.v_max);
      const double e = rng.Normal(0, kNoiseMm);
      sum2 += e * e;
      p.push_back(Surface().Point(u, v) + e * Surface().Normal(u, v));
    }
    scatter_noise_rms_um = std::sqrt(sum2 / kScatteredPoints) * 1e3;
    return p;
  }();
  return points;
}

// RMS and max distance from the true S(u, v) to Q at seeded random (u, v); start(p, u, v) gives
// the foot-point search's start on Q.
template <typename Start>
std::pair<double, double> TruthError(const BSplineSurface& q, Start start) {
  const ParamDomain dom = Surface().domain();
  Rng rng(13);
  double sum2 = 0, max = 0;
  int n = 0;
  for (int k = 0; k < kCheckPoints; ++k) {
    const double u = rng.Uniform(dom.u_min, dom.u_max), v = rng.Uniform(dom.v_min, dom.v_max);
    const Eigen::Vector3d p = Surface().Point(u, v);
    const Eigen::Vector2d s = start(p, u, v);
    const auto foot = ProjectFrom(q, p, s.x(), s.y());
    if (!foot.ok()) continue;
    const double e = (p - foot->foot).norm();
    sum2 += e * e;
    max = std::max(max, e);
    ++n;
  }
  return {std::sqrt(sum2 / std::max(n, 1)), max};
}

struct Row {
  std::string name;
  double seconds = 0;
  int u_poles = 0, v_poles = 0;
  double rms_um = 0, check_rms_um = 0, check_max_um = 0;
  std::string edge_spans;  // FitScattered only: "uniform" or "margin" (scattered_fit.cc, DataKnots)
  double gap_spans = 0, lambda = 0;
  bool knots_redistributed = false;
  bool done = false;
};
Row occt_row{"OCCT grid 316 x 316 (GeomAPI_PointsToBSplineSurface)"};
Row ours_row{"FitScattered 100,000 points, same net, GCV"};
Row ours_fixed_row{"FitScattered 100,000 points, same net, lambda 1e-9"};

void BM_OcctGrid316(benchmark::State& state) {
  const GridSamples& grid = NoisyGrid();
  GridFitOptions options;
  options.degree_min = options.degree_max = 3;
  options.tolerance_mm = 5 * kNoiseMm;
  Result<BSplineSurface> q = Status::Internal("not run");
  FitReport report;
  for (auto _ : state) {
    q = FitGrid(grid, options, &report);
    if (!q.ok()) {
      state.SkipWithError(q.status().ToString().c_str());
      return;
    }
    benchmark::DoNotOptimize(q->geom());
  }
  const auto [check_rms, check_max] =
      TruthError(*q, [](const Eigen::Vector3d&, double u, double v) { return Eigen::Vector2d(u, v); });
  // FitGrid reports the parametric residual at the nodes; measure the orthogonal one, as ours.
  double sum2 = 0;
  for (int j = 0; j < kGridSide; ++j) {
    for (int i = 0; i < kGridSide; ++i) {
      const Eigen::Vector3d& p = grid.points[static_cast<std::size_t>(j * kGridSide + i)];
      const auto foot = ProjectFrom(*q, p, grid.domain.u_min + grid.domain.u_span() * i / (kGridSide - 1),
                                    grid.domain.v_min + grid.domain.v_span() * j / (kGridSide - 1));
      if (foot.ok()) sum2 += (p - foot->foot).squaredNorm();
    }
  }
  occt_row.u_poles = q->u_poles();
  occt_row.v_poles = q->v_poles();
  occt_row.rms_um = std::sqrt(sum2 / (kGridSide * kGridSide)) * 1e3;
  state.counters["parametric_rms_um"] = report.rms_mm * 1e3;
  occt_row.check_rms_um = check_rms * 1e3;
  occt_row.check_max_um = check_max * 1e3;
  occt_row.done = true;
  state.counters["rms_um"] = occt_row.rms_um;
  state.counters["check_rms_um"] = occt_row.check_rms_um;
  state.counters["check_max_um"] = occt_row.check_max_um;
  state.counters["poles"] = q->u_poles() * q->v_poles();
}

// The same total net as OCCT's; λ by GCV (the default), or a tiny fixed λ (next to plain least
// squares: shows what bias GCV's λ adds to the residual).
void RunFitScattered(benchmark::State& state, bool fixed_lambda, Row* row) {
  if (!occt_row.done) {
    state.SkipWithError("run BM_OcctGrid316 first: it gives the control-net size");
    return;
  }
  const std::vector<Eigen::Vector3d>& points = NoisyScatter();
  ScatteredFitOptions options;
  options.degree = 3;
  options.u_poles = occt_row.u_poles;
  options.v_poles = occt_row.v_poles;
  if (fixed_lambda) {
    options.smoothing = ScatteredFitOptions::Smoothing::kFixed;
    options.lambda = 1e-9;
  }
  options.max_correction_iterations = 3;
  Result<BSplineSurface> q = Status::Internal("not run");
  FitReport report;
  for (auto _ : state) {
    q = FitScattered(points, options, &report);
    if (!q.ok()) {
      state.SkipWithError(q.status().ToString().c_str());
      return;
    }
    benchmark::DoNotOptimize(q->geom());
  }
  const nlohmann::json& frame = report.details.at("frame");
  auto vec = [&](const char* key) {
    const nlohmann::json& a = frame.at(key);
    return Eigen::Vector3d(a[0].get<double>(), a[1].get<double>(), a[2].get<double>());
  };
  const Eigen::Vector3d origin = vec("origin_mm"), u_axis = vec("u_axis"), v_axis = vec("v_axis");
  const auto [check_rms, check_max] = TruthError(*q, [&](const Eigen::Vector3d& p, double, double) {
    return Eigen::Vector2d((p - origin).dot(u_axis), (p - origin).dot(v_axis));
  });
  row->u_poles = q->u_poles();
  row->v_poles = q->v_poles();
  row->rms_um = report.rms_mm * 1e3;
  row->check_rms_um = check_rms * 1e3;
  row->check_max_um = check_max * 1e3;
  row->edge_spans = report.details.at("edge_spans").get<std::string>();
  row->gap_spans = report.details.at("initial_gap_spans").get<double>();
  row->lambda = report.details.at("lambda").get<double>();
  row->knots_redistributed = report.details.at("knots_redistributed").get<bool>();
  row->done = true;
  state.counters["rms_um"] = row->rms_um;
  state.counters["check_rms_um"] = row->check_rms_um;
  state.counters["check_max_um"] = row->check_max_um;
  state.counters["poles"] = q->u_poles() * q->v_poles();
  state.counters["lambda"] = report.details.at("lambda").get<double>();
  state.counters["rounds"] = report.details.at("correction_iterations").get<int>();
}

void BM_FitScattered100k(benchmark::State& state) { RunFitScattered(state, false, &ours_row); }
void BM_FitScattered100kFixedLambda(benchmark::State& state) { RunFitScattered(state, true, &ours_fixed_row); }

// Iterations(1): one fit is a few seconds; use --benchmark_repetitions for spread.
BENCHMARK(BM_OcctGrid316)->Unit(benchmark::kMillisecond)->Iterations(1);
BENCHMARK(BM_FitScattered100k)->Unit(benchmark::kMillisecond)->Iterations(1);
BENCHMARK(BM_FitScattered100kFixedLambda)->Unit(benchmark::kMillisecond)->Iterations(1);

// Keeps the wall time of the last run of each benchmark for the table.
class TableReporter : public benchmark::ConsoleReporter {
 public:
  void ReportRuns(const std::vector<Run>& runs) override {
    for (const Run& run : runs) {
      const double seconds = run.GetAdjustedRealTime() * 1e-3;  // ms → s
      if (run.benchmark_name().find("BM_OcctGrid316") != std::string::npos) occt_row.seconds = seconds;
      if (run.benchmark_name().find("BM_FitScattered100k/") != std::string::npos) ours_row.seconds = seconds;
      if (run.benchmark_name().find("BM_FitScattered100kFixedLambda") != std::string::npos) {
        ours_fixed_row.seconds = seconds;
      }
    }
    ConsoleReporter::ReportRuns(runs);
  }
};

void PrintTable() {
  std::printf("\nFranke, 1 um noise, cubic, same control net; error vs truth at %d random points\n", kCheckPoints);
  std::printf("%-56s %8s %11s %13s %15s %15s\n", "method", "time s", "poles", "orth rms um", "truth rms um",
              "truth max um");
  for (const Row* row : {&occt_row, &ours_row, &ours_fixed_row}) {
    if (!row->done) continue;
    std::printf("%-56s %8.2f %5d x %-5d %13.3f %15.3f %15.3f\n", row->name.c_str(), row->seconds, row->u_poles,
                row->v_poles, row->rms_um, row->check_rms_um, row->check_max_um);
  }
  std::printf("noise drawn: grid %.4f um rms, scatter %.4f um rms\n", grid_noise_rms_um, scatter_noise_rms_um);
  for (const Row* row : {&ours_row, &ours_fixed_row}) {
    if (!row->done) continue;
    std::printf("%-56s edge spans: %s (largest initial gap %.3f spans), knots %s, lambda %.2e\n", row->name.c_str(),
                row->edge_spans.c_str(), row->gap_spans, row->knots_redistributed ? "redistributed" : "as laid",
                row->lambda);
  }
}

}  // namespace
}  // namespace formloop::recon

int main(int argc, char** argv) {
  benchmark::Initialize(&argc, argv);
  if (benchmark::ReportUnrecognizedArguments(argc, argv)) return 1;
  formloop::recon::TableReporter reporter;
  benchmark::RunSpecifiedBenchmarks(&reporter);
  benchmark::Shutdown();
  formloop::recon::PrintTable();
  return 0;
}
