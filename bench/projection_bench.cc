// Foot-point projection of 100,000 points (spec/reconstruction.md §4): formloop's FootPointProjector
// (cell-grid start + Newton on span polynomials, ProjectAll on one thread, and on all cores as
// ours_all_cores/, wall time) next to OpenCASCADE's
// GeomAPI_ProjectPointOnSurf, used three ways:
//   occt_new_per_point:  GeomAPI_ProjectPointOnSurf(P, surface) for every point, as a user would write it;
//   occt_init_once:      one object, Init(surface, bounds) once, Perform(P) per point (OpenCASCADE's
//                        documented "projection for many points"; it keeps its sample grid), with the
//                        default Extrema_ExtAlgo_Grad;
//   occt_tree:           the same with Extrema_ExtAlgo_Tree (its bounding-box tree of surface cells).
// The surfaces are the pipeline's Q: B-spline fits (61 × 61 grid, tolerance 1e-4 mm) of the franke and
// egg_box reference surfaces (OpenCASCADE raises the degree to 5 for the tolerance), and franke's fit with
// the degree held at 3 (franke_bicubic). The points are p = Q(u, v) + t n(u, v) with seeded (u, v) over
// the whole domain and t uniform in [-1, 1] mm, so every foot point is (u, v) and every deviation is t.
//
// Also measured: building the projector, the start-grid density (seed_grid), and the B-spline
// evaluators (Geom_BSplineSurface::D2, GeomAdaptor_Surface::D2 with its span cache, our
// SpanPolynomials) on Newton-like clusters of parameters.
//
// And points far from Q ("<surface>_far": 10,000 points 3 to 30 mm off Q on either side, like a probing
// program's moves checked for clearance), ours next to OpenCASCADE's init-once variants; their table
// compares the distances only (a far point's foot point need not be (u, v)).
//
// After the runs it prints, per surface, the times side by side, the speed-ups, and the agreement with
// OpenCASCADE over all points: max |d_ours - d_occt| with d_occt = (p - q_occt)·n(q_occt), how often
// OpenCASCADE found no point or a farther one, and the max |d_ours - t|.
//
//   ./build/bench/formloop_bench_projection     (all: several minutes, nearly all of it OpenCASCADE
//                                                constructing a projector for each of 3 × 100,000 points)
//   ./build/bench/formloop_bench_projection --benchmark_filter='build|ours/|occt_init_once|occt_tree'

#include <benchmark/benchmark.h>

#include <cmath>
#include <cstdio>
#include <initializer_list>
#include <map>
#include <string>
#include <vector>

#include <GeomAPI_ProjectPointOnSurf.hxx>
#include <GeomAdaptor_Surface.hxx>
#include <Standard_Failure.hxx>

#include "core/parallel.h"
#include "core/random.h"
#include "reconstruction/bspline_surface.h"
#include "reconstruction/foot_point.h"
#include "reconstruction/span_polynomials.h"

namespace formloop::recon {
namespace {

using Eigen::Vector3d;

constexpr std::size_t kPoints = 100'000;
constexpr double kOffsetMm = 1;  // points within ±1 mm of Q along its normal (issue 26's recipe)
constexpr std::size_t kFarPoints = 10'000;
constexpr double kFarMinMm = 3, kFarMaxMm = 30;  // the far points' distance along the normal, either side
// "_bicubic": the same fit with the degree held at 3 (OpenCASCADE raises it to 5 for the tolerance otherwise).
const char* const kSurfaces[] = {"franke", "egg_box", "franke_bicubic"};

struct Case {
  BSplineSurface q;
  std::vector<Vector3d> points;
  std::vector<double> offsets_mm;  // t: the exact deviation of each point
};

const Case& GetCase(const std::string& name) {
  static std::map<std::string, Case> cases;
  auto it = cases.find(name);
  if (it != cases.end()) return it->second;
  Case c;
  const auto ends_with = [](const std::string& text, const std::string& tail) {
    return text.size() > tail.size() && text.substr(text.size() - tail.size()) == tail;
  };
  const bool far = ends_with(name, "_far");
  const std::string base = far ? name.substr(0, name.size() - 4) : name;
  const std::string suffix = "_bicubic";
  const bool bicubic = ends_with(base, suffix);
  auto surface = MakeReferenceSurface(bicubic ? base.substr(0, base.size() - suffix.size()) : base);
  if (!surface.ok()) std::abort();
  GridFitOptions options;
  if (bicubic) options.degree_min = options.degree_max = 3;
  auto q = FitAnalytic(**surface, 61, 61, options, 0, 1, nullptr);
  if (!q.ok()) std::abort();
  c.q = *q;
  const ParamDomain d = c.q.domain();
  Rng rng(20240612);
  for (std::size_t k = 0; k < (far ? kFarPoints : kPoints); ++k) {
    const double u = rng.Uniform(d.u_min, d.u_max), v = rng.Uniform(d.v_min, d.v_max);
    double t = rng.Uniform(-kOffsetMm, kOffsetMm);
    if (far) t = (t < 0 ? -1 : 1) * rng.Uniform(kFarMinMm, kFarMaxMm);
    c.points.push_back(c.q.Point(u, v) + t * c.q.Normal(u, v));
    c.offsets_mm.push_back(t);
  }
  return cases.emplace(name, std::move(c)).first->second;
}

// Answers of the last run of each method, kept for the comparison table.
struct Answers {
  std::vector<double> deviation_mm, distance_mm;  // NaN where the method found no point
};
std::map<std::string, Answers>& AllAnswers() {
  static std::map<std::string, Answers> answers;
  return answers;
}

FootPointProjector BuildOrDie(const BSplineSurface& q, int seed_grid) {
  auto projector = FootPointProjector::Build(q, ProjectorOptions{.seed_grid = seed_grid});
  if (!projector.ok()) {
    std::fprintf(stderr, "%s\n", projector.status().ToString().c_str());
    std::abort();
  }
  return *projector;
}

void BM_Build(benchmark::State& state, const std::string& name) {
  const Case& c = GetCase(name);
  for (auto _ : state) benchmark::DoNotOptimize(BuildOrDie(c.q, 0));
  const FootPointProjector projector = BuildOrDie(c.q, 0);
  state.counters["samples"] = static_cast<double>(projector.seed_grid_u()) * projector.seed_grid_v();
  state.counters["degree"] = c.q.u_degree();
  state.counters["poles"] = static_cast<double>(c.q.u_poles()) * c.q.v_poles();
  state.counters["delta_mm"] = projector.seed_cover_mm();
}

// threads: 1 (the single-threaded figure) or 0 (all cores, --threads' default; timed by the wall clock,
// since the benchmark's CPU column counts the calling thread only).
// seed_grid: the start grid (0 = automatic; the far table's dense column takes 512 × 512, the start grid of a
// CAD face of many spans, whose cells are then a small fraction of the points' distance).
void BM_Ours(benchmark::State& state, const std::string& name, int threads, int seed_grid = 0) {
  const Case& c = GetCase(name);
  const FootPointProjector projector = BuildOrDie(c.q, seed_grid);
  std::vector<FootPoint> feet;
  SetThreadCount(threads);
  state.counters["threads"] = ThreadCount();
  for (auto _ : state) {
    auto result = projector.ProjectAll(c.points);
    if (!result.ok()) {
      state.SkipWithError(result.status().ToString().c_str());
      return;
    }
    feet = std::move(result).value();
  }
  SetThreadCount(1);  // the rest of the bench (ours_seed_grid) runs on one thread
  if (threads != 1) {
    state.SetItemsProcessed(static_cast<std::int64_t>(state.iterations() * c.points.size()));
    return;
  }
  Answers& answers = AllAnswers()[(seed_grid == 0 ? "ours/" : "ours_dense/") + name];
  answers = {};
  for (const FootPoint& f : feet) {
    answers.deviation_mm.push_back(f.deviation_mm);
    answers.distance_mm.push_back(f.distance_mm);
  }
  state.SetItemsProcessed(static_cast<std::int64_t>(state.iterations() * c.points.size()));
}

// Build + ProjectAll with a given start grid (0 = automatic).
void BM_OursSeedGrid(benchmark::State& state, const std::string& name) {
  const Case& c = GetCase(name);
  int samples = 0;
  for (auto _ : state) {
    const FootPointProjector projector = BuildOrDie(c.q, static_cast<int>(state.range(0)));
    samples = projector.seed_grid_u() * projector.seed_grid_v();
    benchmark::DoNotOptimize(projector.ProjectAll(c.points));
  }
  state.counters["samples"] = samples;
  state.SetItemsProcessed(static_cast<std::int64_t>(state.iterations() * c.points.size()));
}

// What OpenCASCADE returned for one point: recorded inside the timed loop (cheap), turned into a
// deviation afterwards.
struct OcctRaw {
  bool found = false;
  double u = 0, v = 0, distance_mm = 0;
};

OcctRaw ReadOcct(const GeomAPI_ProjectPointOnSurf& projection) {
  OcctRaw raw;
  if (!projection.IsDone() || projection.NbPoints() == 0) return raw;
  raw.found = true;
  projection.LowerDistanceParameters(raw.u, raw.v);
  raw.distance_mm = projection.LowerDistance();
  return raw;
}

// Signed deviation of p from OpenCASCADE's nearest point, along our normal there.
Answers ToAnswers(const std::vector<OcctRaw>& raw, const Case& c) {
  Answers answers;
  for (std::size_t k = 0; k < raw.size(); ++k) {
    const OcctRaw& r = raw[k];
    answers.deviation_mm.push_back(r.found ? (c.points[k] - c.q.Point(r.u, r.v)).dot(c.q.Normal(r.u, r.v))
                                           : std::nan(""));
    answers.distance_mm.push_back(r.found ? r.distance_mm : std::nan(""));
  }
  return answers;
}

void BM_OcctNewPerPoint(benchmark::State& state, const std::string& name) {
  const Case& c = GetCase(name);
  std::vector<OcctRaw> raw;
  raw.reserve(c.points.size());
  for (auto _ : state) {
    raw.clear();
    for (const Vector3d& p : c.points) {
      try {
        const GeomAPI_ProjectPointOnSurf projection(gp_Pnt(p.x(), p.y(), p.z()), c.q.geom());
        raw.push_back(ReadOcct(projection));
      } catch (const Standard_Failure&) {
        raw.emplace_back();
      }
    }
  }
  AllAnswers()["occt_new_per_point/" + name] = ToAnswers(raw, c);
  state.SetItemsProcessed(static_cast<std::int64_t>(state.iterations() * c.points.size()));
}

// One projector, Init once, Perform per point, with OpenCASCADE's default gradient search (Grad) or its
// tree of surface cells (Tree: Extrema_GenExtPS's bounding-box tree, the faster for many points).
void BM_OcctInitOnce(benchmark::State& state, const std::string& name, Extrema_ExtAlgo algo) {
  const Case& c = GetCase(name);
  const ParamDomain d = c.q.domain();
  std::vector<OcctRaw> raw;
  raw.reserve(c.points.size());
  for (auto _ : state) {
    raw.clear();
    GeomAPI_ProjectPointOnSurf projection;
    projection.Init(c.q.geom(), d.u_min, d.u_max, d.v_min, d.v_max, algo);
    for (const Vector3d& p : c.points) {
      try {
        projection.Perform(gp_Pnt(p.x(), p.y(), p.z()));
        raw.push_back(ReadOcct(projection));
      } catch (const Standard_Failure&) {
        raw.emplace_back();
      }
    }
  }
  AllAnswers()[std::string(algo == Extrema_ExtAlgo_Tree ? "occt_tree/" : "occt_init_once/") + name] = ToAnswers(raw, c);
  state.SetItemsProcessed(static_cast<std::int64_t>(state.iterations() * c.points.size()));
}

// Newton-like evaluation pattern: clusters of 5 evaluations within 0.05 mm of a random (u, v).
std::vector<std::pair<double, double>> EvalParameters(const BSplineSurface& q) {
  const ParamDomain d = q.domain();
  Rng rng(5);
  std::vector<std::pair<double, double>> uv;
  for (int k = 0; k < 20'000; ++k) {
    const double u = rng.Uniform(d.u_min + 0.1, d.u_max - 0.1), v = rng.Uniform(d.v_min + 0.1, d.v_max - 0.1);
    for (int i = 0; i < 5; ++i) uv.emplace_back(u + rng.Uniform(-0.05, 0.05), v + rng.Uniform(-0.05, 0.05));
  }
  return uv;
}

void BM_EvalGeomD2(benchmark::State& state, const std::string& name) {
  const Case& c = GetCase(name);
  const auto uv = EvalParameters(c.q);
  gp_Pnt p;
  gp_Vec su, sv, suu, svv, suv;
  for (auto _ : state) {
    for (const auto& [u, v] : uv) {
      c.q.geom()->D2(u, v, p, su, sv, suu, svv, suv);
      benchmark::DoNotOptimize(p);
    }
  }
  state.SetItemsProcessed(static_cast<std::int64_t>(state.iterations() * uv.size()));
}

void BM_EvalAdaptorD2(benchmark::State& state, const std::string& name) {
  const Case& c = GetCase(name);
  const auto uv = EvalParameters(c.q);
  gp_Pnt p;
  gp_Vec su, sv, suu, svv, suv;
  for (auto _ : state) {
    GeomAdaptor_Surface adaptor(c.q.geom());
    for (const auto& [u, v] : uv) {
      adaptor.D2(u, v, p, su, sv, suu, svv, suv);
      benchmark::DoNotOptimize(p);
    }
  }
  state.SetItemsProcessed(static_cast<std::int64_t>(state.iterations() * uv.size()));
}

void BM_EvalSpanPolynomials(benchmark::State& state, const std::string& name) {
  const Case& c = GetCase(name);
  const auto uv = EvalParameters(c.q);
  const Result<SpanPolynomials> polynomials = SpanPolynomials::Of(c.q);
  if (!polynomials.ok()) {
    state.SkipWithError(polynomials.status().ToString().c_str());
    return;
  }
  for (auto _ : state) {
    SpanPolynomials::Evaluator eval(*polynomials);
    for (const auto& [u, v] : uv) benchmark::DoNotOptimize(eval.D2(u, v));
  }
  state.SetItemsProcessed(static_cast<std::int64_t>(state.iterations() * uv.size()));
}

// Collects each benchmark's CPU time per iteration (ms) for the table. CPU time, because the machine
// may be shared: wall time then includes other processes' turns.
class TableReporter : public benchmark::ConsoleReporter {
 public:
  void ReportRuns(const std::vector<Run>& runs) override {
    for (const Run& run : runs) {
      if (run.error_occurred) continue;
      std::string name = run.benchmark_name();
      name = name.substr(0, name.find("/iterations:"));
      times_ms_[name] = run.GetAdjustedCPUTime() * benchmark::GetTimeUnitMultiplier(benchmark::kMillisecond) /
                        benchmark::GetTimeUnitMultiplier(run.time_unit);
    }
    ConsoleReporter::ReportRuns(runs);
  }
  double TimeMs(const std::string& name) const {
    auto it = times_ms_.find(name);
    return it == times_ms_.end() ? std::nan("") : it->second;
  }

 private:
  std::map<std::string, double> times_ms_;
};

// Agreement of our answers with each OpenCASCADE variant that ran (summed): where OpenCASCADE found a
// point at least as close as ours (to 1e-7 mm), the largest difference of the deviations; elsewhere who
// is closer, or that OpenCASCADE found nothing.
struct Agreement {
  double max_diff = 0;
  long fail = 0, occt_far = 0, ours_far = 0;
};
Agreement Compare(const Answers& a, const std::string& name, std::initializer_list<const char*> methods) {
  Agreement g;
  for (const char* method : methods) {
    auto it = AllAnswers().find(method + name);
    if (it == AllAnswers().end()) continue;
    const Answers& o = it->second;
    for (std::size_t k = 0; k < o.deviation_mm.size(); ++k) {
      if (std::isnan(o.deviation_mm[k])) {
        ++g.fail;
      } else if (o.distance_mm[k] > a.distance_mm[k] + 1e-7) {
        ++g.occt_far;
      } else if (a.distance_mm[k] > o.distance_mm[k] + 1e-7) {
        ++g.ours_far;
      } else {
        g.max_diff = std::max(g.max_diff, std::abs(a.deviation_mm[k] - o.deviation_mm[k]));
      }
    }
  }
  return g;
}

void PrintTable(const TableReporter& reporter) {
  std::printf("\nFoot points of %zu points within %g mm of Q, single thread, CPU ms (us/point = ms / 100)\n", kPoints,
              kOffsetMm);
  std::printf("%-9s %9s %12s %12s %12s %8s %8s %8s | %12s %12s %9s %9s %9s\n", "surface", "ours_ms", "occt_new_ms",
              "occt_grad_ms", "occt_tree_ms", "x_new", "x_grad", "x_tree", "max|d-docc|", "max|d-t|", "occt_fail",
              "occt_far", "ours_far");
  for (const char* name : kSurfaces) {
    const double ours = reporter.TimeMs("ours/" + std::string(name));
    const double occt_new = reporter.TimeMs("occt_new_per_point/" + std::string(name));
    const double occt_init = reporter.TimeMs("occt_init_once/" + std::string(name));
    const double occt_tree = reporter.TimeMs("occt_tree/" + std::string(name));
    const auto& all = AllAnswers();
    auto ours_it = all.find("ours/" + std::string(name));
    if (ours_it == all.end()) continue;
    const Answers& a = ours_it->second;
    const Case& c = GetCase(name);
    double max_truth = 0;
    for (std::size_t k = 0; k < a.deviation_mm.size(); ++k) {
      max_truth = std::max(max_truth, std::abs(a.deviation_mm[k] - c.offsets_mm[k]));
    }
    const Agreement g = Compare(a, name, {"occt_new_per_point/", "occt_init_once/", "occt_tree/"});
    std::printf("%-9s %9.1f %12.1f %12.1f %12.1f %8.1f %8.1f %8.1f | %12.2e %12.2e %9ld %9ld %9ld\n", name, ours,
                occt_new, occt_init, occt_tree, occt_new / ours, occt_init / ours, occt_tree / ours, g.max_diff,
                max_truth, g.fail, g.occt_far, g.ours_far);
  }
  std::printf(
      "x_new, x_grad, x_tree: OpenCASCADE time / ours. occt_fail: no point found; occt_far / ours_far: that side's\n"
      "point is farther by more than 1e-7 mm (summed over the OpenCASCADE variants that ran).\n");
}

// The far points: time and distances only (ours against each OpenCASCADE variant that ran).
void PrintFarTable(const TableReporter& reporter) {
  std::printf("\nFoot points of %zu points %g to %g mm off Q, single thread, CPU ms\n", kFarPoints, kFarMinMm,
              kFarMaxMm);
  std::printf("%-9s %9s %15s %12s %12s %8s %8s | %9s %9s %9s %9s\n", "surface", "ours_ms", "ours_dense_ms",
              "occt_grad_ms", "occt_tree_ms", "x_grad", "x_tree", "occt_fail", "occt_far", "ours_far", "dense_far");
  for (const char* surface : kSurfaces) {
    const std::string name = std::string(surface) + "_far";
    const double ours = reporter.TimeMs("ours/" + name);
    const double dense = reporter.TimeMs("ours_dense/" + name);
    const double occt_init = reporter.TimeMs("occt_init_once/" + name);
    const double occt_tree = reporter.TimeMs("occt_tree/" + name);
    const auto& all = AllAnswers();
    auto ours_it = all.find("ours/" + name);
    if (ours_it == all.end()) continue;
    const Answers& a = ours_it->second;
    long dense_far = 0;
    if (auto it = all.find("ours_dense/" + name); it != all.end()) {
      for (std::size_t k = 0; k < a.distance_mm.size(); ++k) {
        dense_far += it->second.distance_mm[k] > a.distance_mm[k] + 1e-7;
      }
    }
    const Agreement g = Compare(a, name, {"occt_init_once/", "occt_tree/"});
    std::printf("%-9s %9.1f %15.1f %12.1f %12.1f %8.1f %8.1f | %9ld %9ld %9ld %9ld\n", surface, ours, dense, occt_init,
                occt_tree, occt_init / ours, occt_tree / ours, g.fail, g.occt_far, g.ours_far, dense_far);
  }
  std::printf(
      "ours_dense: a 512 x 512 start grid (cells a small fraction of the distance); dense_far: its point farther\n"
      "than the automatic grid's by more than 1e-7 mm.\n");
}

// OpenCASCADE's init-once projector with its gradient search and with its tree, once each (minutes).
void RegisterOcctInitOnce(const std::string& name) {
  for (const auto& [label, algo] :
       {std::pair{"occt_init_once/", Extrema_ExtAlgo_Grad}, {"occt_tree/", Extrema_ExtAlgo_Tree}}) {
    benchmark::RegisterBenchmark((label + name).c_str(), BM_OcctInitOnce, name, algo)
        ->Iterations(1)
        ->Unit(benchmark::kMillisecond);
  }
}

void Register() {
  for (const char* name_text : kSurfaces) {
    const std::string name = name_text;
    benchmark::RegisterBenchmark(("build/" + name).c_str(), BM_Build, name)->Unit(benchmark::kMillisecond);
    benchmark::RegisterBenchmark(("ours/" + name).c_str(), BM_Ours, name, 1, 0)->Unit(benchmark::kMillisecond);
    benchmark::RegisterBenchmark(("ours_all_cores/" + name).c_str(), BM_Ours, name, 0, 0)
        ->Unit(benchmark::kMillisecond)
        ->UseRealTime();
    auto* seed_grid = benchmark::RegisterBenchmark(("ours_seed_grid/" + name).c_str(), BM_OursSeedGrid, name);
    for (int n : {0, 16, 24, 32, 48, 64, 96, 128, 256, 512}) seed_grid->Arg(n);
    seed_grid->Unit(benchmark::kMillisecond);
    benchmark::RegisterBenchmark(("occt_new_per_point/" + name).c_str(), BM_OcctNewPerPoint, name)
        ->Iterations(1)
        ->Unit(benchmark::kMillisecond);
    RegisterOcctInitOnce(name);
    benchmark::RegisterBenchmark(("EvalGeomD2/" + name).c_str(), BM_EvalGeomD2, name)->Unit(benchmark::kMicrosecond);
    benchmark::RegisterBenchmark(("EvalAdaptorD2/" + name).c_str(), BM_EvalAdaptorD2, name)
        ->Unit(benchmark::kMicrosecond);
    benchmark::RegisterBenchmark(("EvalSpanPolynomials/" + name).c_str(), BM_EvalSpanPolynomials, name)
        ->Unit(benchmark::kMicrosecond);
  }
  for (const char* name_text : kSurfaces) {
    const std::string name = std::string(name_text) + "_far";
    benchmark::RegisterBenchmark(("ours/" + name).c_str(), BM_Ours, name, 1, 0)->Unit(benchmark::kMillisecond);
    benchmark::RegisterBenchmark(("ours_dense/" + name).c_str(), BM_Ours, name, 1, 512)->Unit(benchmark::kMillisecond);
    RegisterOcctInitOnce(name);
  }
}

}  // namespace
}  // namespace formloop::recon

int main(int argc, char** argv) {
  benchmark::Initialize(&argc, argv);
  if (benchmark::ReportUnrecognizedArguments(argc, argv)) return 1;
  formloop::recon::Register();
  formloop::SetThreadCount(1);  // single-threaded figures unless a benchmark says otherwise
  formloop::recon::TableReporter reporter;
  benchmark::RunSpecifiedBenchmarks(&reporter);
  formloop::recon::PrintTable(reporter);
  formloop::recon::PrintFarTable(reporter);
  benchmark::Shutdown();
  return 0;
}
