// GHSOM training and descent cost (spec/case-library.md §2): training on 10,000 synthetic clustered cases × 24
// features (goal ≤ 30 s), then the latency of ConceptPath and Descend over 100,000 queries. Then (issue 7 item 5)
// full retrieval (descent, candidates, A over all facets, ranking, route) over a library_cases-case library built in
// memory from the starter cases (each a starter case with its descriptor jittered by 2 % per entry), median and p99
// latency (goal median ≤ 1 ms), and `kb add` throughput into a temporary SQLite library, without and with the
// incremental GHSOM insertion. Prints tables; run the Release build:
//   formloop_bench_retrieval [cases] [queries] [tau1] [tau2] [library_cases] [adds] [library_tau2]
// (defaults 10000 100000, GhsomOptions, 100000 2000 0.02; the big library uses LibraryGhsomDefaults with tau2 =
// library_tau2).

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <vector>

#include <unistd.h>
#include <filesystem>

#include "core/json_io.h"
#include "core/random.h"
#include "kb/library.h"
#include "kb/schema.h"
#include "retrieval/ghsom.h"
#include "retrieval/retrieve.h"
#include "retrieval/starter.h"

namespace {

using formloop::Rng;
using namespace formloop::retrieval;

// Clustered cases: 8 top clusters (centres N(0, 6²)), 4 sub-clusters each (offsets N(0, 2²)), points N(0, 0.5²)
// around the sub-centres, per component. The centres come from centre_seed, the points from sample_seed, so queries
// can be fresh cases of the same library.
Eigen::MatrixXd MakeCases(int n, int dim, std::uint64_t centre_seed, std::uint64_t sample_seed) {
  Rng rng(centre_seed);
  constexpr int kTop = 8, kSub = 4;
  std::vector<Eigen::VectorXd> centres;
  for (int t = 0; t < kTop; ++t) {
    Eigen::VectorXd top(dim);
    for (int k = 0; k < dim; ++k) top(k) = rng.Normal(0, 6);
    for (int s = 0; s < kSub; ++s) {
      Eigen::VectorXd c = top;
      for (int k = 0; k < dim; ++k) c(k) += rng.Normal(0, 2);
      centres.push_back(c);
    }
  }
  rng = Rng(sample_seed);
  Eigen::MatrixXd x(n, dim);
  for (int i = 0; i < n; ++i) {
    const auto& c = centres[rng.UniformIndex(centres.size())];
    for (int k = 0; k < dim; ++k) x(i, k) = c(k) + rng.Normal(0, 0.5);
  }
  return x;
}

double Percentile(std::vector<double> v, double p) {
  std::sort(v.begin(), v.end());
  const auto i = static_cast<std::size_t>(
      std::min<double>(static_cast<double>(v.size() - 1), p * static_cast<double>(v.size() - 1) + 0.5));
  return v[i];
}

using Clock = std::chrono::steady_clock;
double Seconds(Clock::time_point a, Clock::time_point b) { return std::chrono::duration<double>(b - a).count(); }

int Fail(const formloop::Status& s) {
  std::fprintf(stderr, "%s\n", s.ToString().c_str());
  return 1;
}

int LibraryBench(int library_cases, int adds, double big_tau2) {
  namespace kb = formloop::kb;
  const std::filesystem::path data = DefaultDataDir();
  auto spec = StarterSpec::Load(data / "starter" / "families.json");
  if (!spec.ok()) return Fail(spec.status());
  auto tax = FacetTaxonomies::Load(data / "taxonomies");
  if (!tax.ok()) return Fail(tax.status());
  FeatureOptions fo;
  fo.taxonomies = std::make_shared<const FacetTaxonomies>(*tax);
  std::printf("Library benchmarks (building the starter cases ...)\n");
  auto t0 = Clock::now();
  auto starter = GenerateStarterCases(*spec, fo);
  if (!starter.ok()) return Fail(starter.status());
  auto t1 = Clock::now();
  const auto& base = *starter;
  std::printf("Starter library: %zu cases generated (surface fit + features) in %.2f s (%.1f ms/case)\n", base.size(),
              Seconds(t0, t1), 1e3 * Seconds(t0, t1) / static_cast<double>(base.size()));
  auto rules_json = formloop::ReadJsonFile(data / "starter" / "rules.json");
  if (!rules_json.ok()) return Fail(rules_json.status());
  auto rules = RulesFromJson(*rules_json, "rules.json");
  if (!rules.ok()) return Fail(rules.status());

  // The big library: lean records (descriptor and concepts only), jittered copies of the starter cases.
  Rng rng(99);
  std::vector<kb::CaseRecord> big;
  big.reserve(static_cast<size_t>(library_cases));
  for (int i = 0; i < library_cases; ++i) {
    const kb::CaseRecord& b = base[static_cast<size_t>(i) % base.size()];
    kb::CaseRecord r;
    char uid[32];
    std::snprintf(uid, sizeof uid, "b%07d", i);
    r.uid = uid;
    r.name = uid;
    r.family = b.family;
    r.concepts = b.concepts;
    std::vector<double> d = *b.descriptor;
    for (double& v : d) v *= 1.0 + 0.02 * rng.Normal();
    r.descriptor = std::move(d);
    big.push_back(std::move(r));
  }
  // The starter defaults (a flat map, calibrated for ~250 cases) give leaves of thousands of cases at 100,000;
  // a big library is trained deeper (tau2 = big_tau2) so that a leaf and its neighbours hold few cases.
  GhsomOptions big_options = LibraryGhsomDefaults();
  big_options.tau2 = big_tau2;
  t0 = Clock::now();
  auto model = RetrievalModel::Train(big, big_options, *rules, *tax);
  t1 = Clock::now();
  if (!model.ok()) return Fail(model.status());
  std::vector<double> leaf_sizes;
  for (const auto& leaf : model->ghsom().Leaves()) {
    const auto n = model->ghsom().InputIds(leaf).size();
    if (n > 0) leaf_sizes.push_back(static_cast<double>(n));
  }
  std::printf(
      "Retrieval library: %d cases, GHSOM tau1 %.2f tau2 %.3f trained + indexed in %.1f s: %zu maps, "
      "%zu non-empty leaves, leaf size median %.0f, p99 %.0f\n",
      library_cases, big_options.tau1, big_options.tau2, Seconds(t0, t1), model->ghsom().maps().size(),
      leaf_sizes.size(), Percentile(leaf_sizes, 0.5), Percentile(leaf_sizes, 0.99));
  struct Setting {
    int breadth, max_scored;
  };
  for (const Setting& setting : {Setting{0, 0}, Setting{1, 0}, Setting{0, 200}, Setting{1, 200}}) {
    const int breadth = setting.breadth;
    const int n_queries = setting.max_scored > 0 ? 2000 : 200;  // unbounded: thousands of candidates a query
    std::vector<double> ms;
    std::vector<double> cands;
    int direct = 0;
    Rng qrng(7);
    for (int q = 0; q < n_queries; ++q) {
      const kb::CaseRecord& b = base[qrng.UniformIndex(base.size())];
      Eigen::VectorXd d = Eigen::Map<const Eigen::VectorXd>(b.descriptor->data(), kDescriptorCount);
      for (int k = 0; k < kDescriptorCount; ++k) d(k) *= 1.0 + 0.03 * qrng.Normal();
      RetrieveOptions ro;
      ro.breadth = breadth;
      ro.max_scored = setting.max_scored;
      const auto a = Clock::now();
      auto r = model->Retrieve(d, b.concepts, ro);
      const auto z = Clock::now();
      if (!r.ok()) return Fail(r.status());
      ms.push_back(1e3 * Seconds(a, z));
      cands.push_back(r->candidates);
      direct += r->route == "direct" ? 1 : 0;
    }
    std::printf(
        "  retrieve breadth %d, max_scored %d, %d queries: median %.3f ms, p99 %.3f ms (goal median <= 1 ms); "
        "scored median %.0f, p99 %.0f; routed direct %d\n",
        breadth, setting.max_scored, n_queries, Percentile(ms, 0.5), Percentile(ms, 0.99), Percentile(cands, 0.5),
        Percentile(cands, 0.99), direct);
  }

  // kb add throughput into a temporary library.
  const auto dir = std::filesystem::temp_directory_path() / ("formloop-bench-kb-" + std::to_string(::getpid()));
  std::filesystem::remove_all(dir);
  std::filesystem::create_directories(dir);
  for (int with_ghsom = 0; with_ghsom < 2; ++with_ghsom) {
    const auto path = dir / (with_ghsom ? "g.db" : "a.db");
    if (auto init = kb::InitLibrary(path); !init.ok()) return Fail(init.status());
    auto lib = kb::Library::Open(path);
    if (!lib.ok()) return Fail(lib.status());
    int n = adds;
    if (with_ghsom) {
      // The starter cases, trained; then each add is inserted into the stored GHSOM.
      for (const auto& c : base) {
        if (auto s = (*lib)->AddCase(c); !s.ok()) return Fail(s);
      }
      if (auto tr = TrainLibraryGhsom(**lib, LibraryGhsomDefaults()); !tr.ok()) return Fail(tr.status());
      n = std::min(adds, 200);
    }
    t0 = Clock::now();
    int inserted = 0;
    for (int i = 0; i < n; ++i) {
      kb::CaseRecord r = base[static_cast<size_t>(i) % base.size()];
      r.uid = "add-" + std::to_string(i);
      auto before = (*lib)->ChangeCounter();
      if (!before.ok()) return Fail(before.status());
      if (auto s = (*lib)->AddCase(r); !s.ok()) return Fail(s);
      if (with_ghsom) {
        auto ins = InsertCaseIntoGhsom(**lib, r, *before);
        if (!ins.ok()) return Fail(ins.status());
        inserted += (*ins)["inserted"].get<bool>() ? 1 : 0;
      }
    }
    t1 = Clock::now();
    std::printf("kb add %s: %d cases in %.2f s = %.0f cases/s%s\n",
                with_ghsom ? "with GHSOM insertion (store the grown map per add)" : "(one transaction per case)", n,
                Seconds(t0, t1), n / Seconds(t0, t1),
                with_ghsom ? (", inserted " + std::to_string(inserted)).c_str() : "");
  }
  std::filesystem::remove_all(dir);
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  std::setvbuf(stdout, nullptr, _IOLBF, 0);
  const int cases = argc > 1 ? std::atoi(argv[1]) : 10000;
  const int queries = argc > 2 ? std::atoi(argv[2]) : 100000;
  constexpr int kDim = 24;
  const Eigen::MatrixXd raw = MakeCases(cases, kDim, 20240601, 1);
  auto standardiser = Standardiser::Fit(raw);
  if (!standardiser.ok()) {
    std::fprintf(stderr, "%s\n", standardiser.status().ToString().c_str());
    return 1;
  }
  const Eigen::MatrixXd z = *standardiser->ApplyRows(raw);

  GhsomOptions options;  // defaults, unless given on the command line
  if (argc > 3) options.tau1 = std::atof(argv[3]);
  if (argc > 4) options.tau2 = std::atof(argv[4]);
  GhsomReport report;
  auto trained = TrainGhsom(z, options, &report);
  if (!trained.ok()) {
    std::fprintf(stderr, "%s\n", trained.status().ToString().c_str());
    return 1;
  }
  const Ghsom& g = *trained;
  double top_qe = g.maps().front().qe, top_te = g.maps().front().te, mean_te = 0;
  for (const auto& m : g.maps()) mean_te += m.te;
  mean_te /= static_cast<double>(g.maps().size());
  int capped = 0;
  for (const auto& row : report.maps) capped += row.unit_cap_reached ? 1 : 0;

  std::printf(
      "GHSOM training: %d cases x %d features, tau1 %.2f, tau2 %.3f, "
      "epochs %d\n",
      cases, kDim, options.tau1, options.tau2, options.epochs);
  std::printf("  %-28s %10.3f s (goal <= 30 s)\n", "wall time", report.wall_time_s);
  std::printf("  %-28s %10.3f s\n", "cpu time", report.cpu_time_s);
  std::printf("  %-28s %10zu\n", "maps", g.maps().size());
  std::printf("  %-28s %10d\n", "units", report.unit_count);
  std::printf("  %-28s %10d\n", "maps stopped by unit cap", capped);
  std::printf("  %-28s %10d\n", "leaves", report.leaf_count);
  std::printf("  %-28s %10d\n", "depth", report.max_depth);
  std::printf("  %-28s %3d x %-6d\n", "layer-1 map", g.maps().front().rows, g.maps().front().cols);
  std::printf("  %-28s %10.4f\n", "layer-1 QE", top_qe);
  std::printf("  %-28s %10.4f\n", "layer-1 TE", top_te);
  std::printf("  %-28s %10.4f\n", "mean TE over maps", mean_te);
  std::printf("  %-28s %10.4f\n", "leaf QE", report.leaf_qe);
  std::printf("  %-28s %10.4f\n", "mqe0", g.mqe0());

  // Queries: fresh cases from the same generator (another seed), standardised like the cases.
  const Eigen::MatrixXd q = *standardiser->ApplyRows(MakeCases(queries, kDim, 20240601, 777));
  std::vector<double> path_ns(static_cast<std::size_t>(queries)), descend_ns(static_cast<std::size_t>(queries));
  std::size_t concepts = 0;
  for (int i = 0; i < queries; ++i) {
    const Eigen::VectorXd x = q.row(i).transpose();
    auto t0 = std::chrono::steady_clock::now();
    const auto path = g.ConceptPath(x);
    auto t1 = std::chrono::steady_clock::now();
    const auto refs = g.Descend(x);
    auto t2 = std::chrono::steady_clock::now();
    concepts += path.size() + (refs.size() + 1 == path.size() ? 0 : 1000000);  // a mismatch shows up
    path_ns[static_cast<std::size_t>(i)] = std::chrono::duration<double, std::nano>(t1 - t0).count();
    descend_ns[static_cast<std::size_t>(i)] = std::chrono::duration<double, std::nano>(t2 - t1).count();
  }
  std::printf(
      "Query latency over %d queries (mean path length %.2f concepts "
      "incl. root)\n",
      queries, static_cast<double>(concepts) / queries);
  std::printf("  %-28s %10s %10s\n", "", "median us", "p99 us");
  std::printf("  %-28s %10.3f %10.3f\n", "ConceptPath", Percentile(path_ns, 0.5) / 1e3,
              Percentile(path_ns, 0.99) / 1e3);
  std::printf("  %-28s %10.3f %10.3f\n", "Descend", Percentile(descend_ns, 0.5) / 1e3,
              Percentile(descend_ns, 0.99) / 1e3);
  const int library_cases = argc > 5 ? std::atoi(argv[5]) : 100000;
  const int adds = argc > 6 ? std::atoi(argv[6]) : 2000;
  const double big_tau2 = argc > 7 ? std::atof(argv[7]) : 0.02;
  return LibraryBench(library_cases, adds, big_tau2);
}
