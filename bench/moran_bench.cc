// Residual Moran's I (Cliff & Ord 1981, §8.3) at scale (issue 5, "what it must show" 2): n seeded
// random points in the unit square, k = 8 nearest-neighbour weights (row-standardised), p = 100
// regressors (the 10 × 10 tensor Legendre polynomials in u, v, the constant among them), y = smooth
// field + noise. For n = 25,000, 50,000, 100,000 it prints the wall and CPU time of
// metrology::ResidualMoranI and the process's peak RSS (getrusage) when it returns, each n in its own
// forked process so the high-water marks do not mix: memory grows linearly in n (the n × p design,
// its Q and the sparse W), and no n × n matrix is formed. The k-NN weights and, afterwards, the CGAL
// Delaunay weights of the same points are timed too. CPU time is the figure to trust when other jobs
// share the cores.
//
// Beside it, the dense reference at small n: M = I − X(XᵀX)⁻¹Xᵀ and W as n × n dense matrices and
// the traces straight from the formulas, with its time, its peak RSS and the relative difference of
// I, E[I] and Var[I] from the sparse computation.
//
//   ./build/bench/formloop_bench_moran [n ...]          (default 25000 50000 100000)
//   ./build/bench/formloop_bench_moran --dense N        (dense reference only; default run uses 1000, 2000)
//   ./build/bench/formloop_bench_moran --knn N          (k-NN weights + global Moran's I beside numpy + SciPy)
//
// --knn: k = 8 row-standardised weights and the global Moran's I with its normality and randomisation
// tests on N uniform points, wall and CPU time (best of 5) on one thread and on all cores, beside
// bench/knn_moran_peer.py (scipy.spatial.cKDTree with workers = 1 and −1, scipy.sparse CSR, numpy moments)
// through /usr/bin/python3 on the same points in the same run (skipped with a message when absent). It
// checks the neighbour lists are the same as SciPy's and I, E[I] and both variances agree.

#include <sys/resource.h>
#include <sys/wait.h>
#include <unistd.h>

#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <string>
#include <vector>

#include <Eigen/Dense>

#include "bench/bench_support.h"
#include "core/parallel.h"
#include "core/random.h"
#include "metrology/morans_i.h"
#include "metrology/spatial_weights.h"

namespace formloop {
namespace {

constexpr int kNeighbours = 8;
constexpr int kDegree = 9;  // (kDegree + 1)² = 100 regressors

double PeakRssMb() {
  rusage usage{};
  getrusage(RUSAGE_SELF, &usage);
  return static_cast<double>(usage.ru_maxrss) / 1024.0;  // KiB on Linux
}

using bench::CpuSeconds;
using bench::JsonNumber;

double Seconds(std::chrono::steady_clock::time_point since) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - since).count();
}

// Legendre polynomials P_0..P_degree at t ∈ [−1, 1].
void Legendre(double t, int degree, double* out) {
  out[0] = 1;
  if (degree > 0) out[1] = t;
  for (int m = 2; m <= degree; ++m) out[m] = ((2 * m - 1) * t * out[m - 1] - (m - 1) * out[m - 2]) / m;
}

struct Problem {
  Eigen::MatrixXd uv;
  Eigen::VectorXd y;
  Eigen::MatrixXd x;
};

Problem MakeProblem(int n, std::uint64_t seed) {
  Rng rng(seed);
  Problem pr{Eigen::MatrixXd(2, n), Eigen::VectorXd(n), Eigen::MatrixXd(n, (kDegree + 1) * (kDegree + 1))};
  double pu[kDegree + 1], pv[kDegree + 1];
  for (int i = 0; i < n; ++i) {
    const double u = rng.Uniform(), v = rng.Uniform();
    pr.uv.col(i) << u, v;
    Legendre(2 * u - 1, kDegree, pu);
    Legendre(2 * v - 1, kDegree, pv);
    for (int a = 0; a <= kDegree; ++a) {
      for (int b = 0; b <= kDegree; ++b) pr.x(i, a * (kDegree + 1) + b) = pu[a] * pv[b];
    }
    // A field the degree-9 model cannot absorb fully, plus noise.
    pr.y[i] = std::sin(9 * u) * std::cos(7 * v) + 0.3 * std::sin(40 * u * v) + rng.Normal(0, 0.1);
  }
  return pr;
}

int RunSparse(int n) {
  const Problem pr = MakeProblem(n, 2026);
  const double inputs_mb = PeakRssMb();
  auto t0 = std::chrono::steady_clock::now();
  auto w = metrology::KnnWeights(pr.uv, kNeighbours, metrology::WeightStyle::kRowStandardised);
  const double knn_s = Seconds(t0);
  if (!w.ok()) {
    std::fprintf(stderr, "%s\n", w.status().ToString().c_str());
    return 1;
  }
  t0 = std::chrono::steady_clock::now();
  const double cpu0 = CpuSeconds();
  auto r = metrology::ResidualMoranI(pr.y, pr.x, w.value());
  const double moran_s = Seconds(t0);
  const double moran_cpu_s = CpuSeconds() - cpu0;
  const double moran_peak_mb = PeakRssMb();  // before the Delaunay weights below
  if (!r.ok()) {
    std::fprintf(stderr, "%s\n", r.status().ToString().c_str());
    return 1;
  }
  t0 = std::chrono::steady_clock::now();
  auto delaunay = metrology::DelaunayWeights(pr.uv, metrology::WeightStyle::kRowStandardised);
  const double delaunay_s = Seconds(t0);
  if (!delaunay.ok()) {
    std::fprintf(stderr, "%s\n", delaunay.status().ToString().c_str());
    return 1;
  }
  std::printf(
      "%8d %4d %6.2f s %7.2f s %8.3f s %8.3f s %9.0f MB %9.0f MB %8.4f %10.3e %8.1f   (one dense n×n: %.0f GB)\n", n,
      r->p, knn_s, delaunay_s, moran_s, moran_cpu_s, inputs_mb, moran_peak_mb, r->i, r->expected, r->z,
      8.0 * n * static_cast<double>(n) / 1e9);
  return 0;
}

// The Cliff–Ord formulas with dense n × n matrices (the reference the sparse traces must equal).
int RunDense(int n) {
  const Problem pr = MakeProblem(n, 2026);
  auto w = metrology::KnnWeights(pr.uv, kNeighbours, metrology::WeightStyle::kRowStandardised);
  if (!w.ok()) return 1;
  auto t0 = std::chrono::steady_clock::now();
  auto sparse = metrology::ResidualMoranI(pr.y, pr.x, w.value());
  const double sparse_s = Seconds(t0);
  if (!sparse.ok()) return 1;
  const double sparse_mb = PeakRssMb();
  t0 = std::chrono::steady_clock::now();
  const Eigen::MatrixXd wd = Eigen::MatrixXd(w->w);
  const Eigen::HouseholderQR<Eigen::MatrixXd> qr(pr.x);
  const Eigen::MatrixXd q = qr.householderQ() * Eigen::MatrixXd::Identity(n, pr.x.cols());
  const Eigen::MatrixXd m = Eigen::MatrixXd::Identity(n, n) - q * q.transpose();
  const Eigen::VectorXd e = m * pr.y;
  const Eigen::MatrixXd mw = m * wd;
  const Eigen::MatrixXd mwt = m * wd.transpose();
  const double p = static_cast<double>(pr.x.cols()), nn = n, s0 = wd.sum(), tr_mw = mw.trace();
  const double tr_mwmwt = (mw * mwt).trace();
  const double tr_mwmw = (mw * mw).trace();
  const double scale = nn / s0;
  const double i = scale * e.dot(wd * e) / e.dot(e);
  const double expected = scale * tr_mw / (nn - p);
  const double variance =
      scale * scale * (tr_mwmwt + tr_mwmw + tr_mw * tr_mw) / ((nn - p) * (nn - p + 2)) - expected * expected;
  const double dense_s = Seconds(t0);
  auto rel = [](double a, double b) { return std::abs(a - b) / std::abs(b); };
  std::printf("%8d  sparse %7.3f s %6.0f MB | dense %7.2f s %6.0f MB | rel. diff I %.1e  E[I] %.1e  Var[I] %.1e\n", n,
              sparse_s, sparse_mb, dense_s, PeakRssMb(), rel(sparse->i, i), rel(sparse->expected, expected),
              rel(sparse->variance, variance));
  return 0;
}

struct Timed {
  double wall_s = 1e300, cpu_s = 1e300;
  void Keep(double wall, double cpu) {
    wall_s = std::min(wall_s, wall);
    cpu_s = std::min(cpu_s, cpu);
  }
};

int RunKnn(int n) {
  Rng rng(2026);
  Eigen::MatrixXd uv(2, n);
  Eigen::VectorXd y(n);
  for (int i = 0; i < n; ++i) {
    const double u = rng.Uniform(), v = rng.Uniform();
    uv.col(i) << u, v;
    y[i] = std::sin(9 * u) * std::cos(7 * v) + rng.Normal(0, 0.5);
  }
  std::printf("k-NN weights (k = %d, W style) + global Moran's I, %d uniform points; best of 5\n", kNeighbours, n);
  std::printf("%-40s %10s %10s %10s %10s %10s\n", "", "weights", "(CPU)", "Moran I", "(CPU)", "total");
  metrology::SpatialWeights w;
  metrology::MoranResult r;
  for (int threads : {1, 0}) {
    SetThreadCount(threads);
    Timed tw, ti;
    for (int rep = 0; rep < 5; ++rep) {
      auto t0 = std::chrono::steady_clock::now();
      double c0 = CpuSeconds();
      auto weights = metrology::KnnWeights(uv, kNeighbours, metrology::WeightStyle::kRowStandardised);
      tw.Keep(Seconds(t0), CpuSeconds() - c0);
      t0 = std::chrono::steady_clock::now();
      c0 = CpuSeconds();
      auto moran = metrology::MoranI(y, *weights);
      ti.Keep(Seconds(t0), CpuSeconds() - c0);
      if (!weights.ok() || !moran.ok()) return 1;
      w = *std::move(weights);
      r = *moran;
    }
    const std::string label =
        "formloop (" + std::to_string(ThreadCount()) + " thread" + (ThreadCount() > 1 ? "s)" : ")");
    std::printf("%-40s %8.3f s %8.3f s %8.3f s %8.3f s %8.3f s\n", label.c_str(), tw.wall_s, tw.cpu_s, ti.wall_s,
                ti.cpu_s, tw.wall_s + ti.wall_s);
  }
  SetThreadCount(0);
  if (std::system("/usr/bin/python3 -c 'import scipy.spatial' >/dev/null 2>&1") != 0) {
    std::printf("peer skipped: /usr/bin/python3 with SciPy (Debian's python3-scipy) is not available\n");
    return 0;
  }
  char dir_template[] = "/tmp/formloop_knn_bench_XXXXXX";
  if (!mkdtemp(dir_template)) return 1;
  const std::string points = std::string(dir_template) + "/points.bin";
  {
    std::ofstream out(points, std::ios::binary);
    for (int i = 0; i < n; ++i) {
      const double row[3] = {uv(0, i), uv(1, i), y[i]};
      out.write(reinterpret_cast<const char*>(row), sizeof row);
    }
  }
  int failures = 0;
  for (int workers : {1, -1}) {
    const std::string command = "/usr/bin/python3 " + std::string(FORMLOOP_SOURCE_DIR) + "/bench/knn_moran_peer.py " +
                                points + " " + std::to_string(n) + " " + std::to_string(kNeighbours) + " 5 " +
                                std::to_string(workers);
    std::string line;
    if (!bench::RunPeer(command, &line)) {
      std::printf("peer failed: %s\n", command.c_str());
      ++failures;
      continue;
    }
    const double pw = JsonNumber(line, "weights_s"), pi = JsonNumber(line, "moran_s");
    const std::string label = std::string("numpy + SciPy cKDTree (workers ") + (workers == 1 ? "1)" : "-1)");
    std::printf("%-40s %8.3f s %8.3f s %8.3f s %8.3f s %8.3f s\n", label.c_str(), pw, JsonNumber(line, "weights_cpu_s"),
                pi, JsonNumber(line, "moran_cpu_s"), pw + pi);
    if (workers != 1) continue;
    // The neighbour lists and the statistics, compared.
    std::ifstream rows(points + ".rows", std::ios::binary);
    std::vector<std::int32_t> theirs(static_cast<std::size_t>(n) * kNeighbours);
    rows.read(reinterpret_cast<char*>(theirs.data()), static_cast<std::streamsize>(theirs.size() * 4));
    long differing = 0;
    for (int i = 0; i < n; ++i) {
      const int* ours = w.w.innerIndexPtr() + w.w.outerIndexPtr()[i];
      for (int m = 0; m < kNeighbours; ++m) {
        if (ours[m] != theirs[static_cast<std::size_t>(i) * kNeighbours + static_cast<std::size_t>(m)]) {
          ++differing;
          break;
        }
      }
    }
    auto rel = [](double a, double b) { return std::abs(a - b) / std::max(std::abs(b), 1e-300); };
    std::printf(
        "  same data: rows whose neighbours differ from SciPy's %ld of %d; rel. diff I %.1e, E[I] %.1e, "
        "Var_N %.1e, Var_R %.1e\n",
        differing, n, rel(r.i, JsonNumber(line, "i")), rel(r.expected, JsonNumber(line, "expected")),
        rel(r.variance_normality, JsonNumber(line, "variance_normality")),
        rel(r.variance_randomisation, JsonNumber(line, "variance_randomisation")));
    if (differing > 0) ++failures;
  }
  std::filesystem::remove_all(dir_template);
  return failures == 0 ? 0 : 1;
}

// Runs f(n) in a child process so each row's peak RSS is its own.
int InChild(int (*f)(int), int n) {
  std::fflush(stdout);
  const pid_t pid = fork();
  if (pid == 0) {
    const int code = f(n);
    std::fflush(stdout);
    std::_Exit(code);
  }
  int status = 0;
  waitpid(pid, &status, 0);
  return WIFEXITED(status) ? WEXITSTATUS(status) : 1;
}

}  // namespace
}  // namespace formloop

int main(int argc, char** argv) {
  using namespace formloop;
  std::vector<int> sizes, dense_sizes, knn_sizes;
  for (int a = 1; a < argc; ++a) {
    const std::string arg = argv[a];
    if (arg == "--dense" && a + 1 < argc) {
      dense_sizes.push_back(std::atoi(argv[++a]));
    } else if (arg == "--knn" && a + 1 < argc) {
      knn_sizes.push_back(std::atoi(argv[++a]));
    } else {
      sizes.push_back(std::atoi(arg.c_str()));
    }
  }
  int failures = 0;
  for (int n : knn_sizes) failures += InChild(RunKnn, n) != 0;
  if (!knn_sizes.empty() && sizes.empty() && dense_sizes.empty()) return failures == 0 ? 0 : 1;
  if (sizes.empty() && dense_sizes.empty()) {
    sizes = {25000, 50000, 100000};
    dense_sizes = {1000, 2000};
  }
  if (!sizes.empty()) {
    std::printf("Residual Moran, k = %d (W style), p = %d, points uniform in the unit square, Eigen single-threaded\n",
                kNeighbours, (kDegree + 1) * (kDegree + 1));
    std::printf("%8s %4s %8s %9s %10s %10s %12s %12s %8s %10s %8s\n", "n", "p", "kNN", "Delaunay", "residual", "(CPU)",
                "RSS inputs", "peak RSS", "I", "E[I]", "z");
    for (int n : sizes) failures += InChild(RunSparse, n) != 0;
  }
  if (!dense_sizes.empty()) {
    std::printf("\nDense reference (n × n M and W, traces by dense products) beside the sparse computation\n");
    for (int n : dense_sizes) failures += InChild(RunDense, n) != 0;
  }
  return failures == 0 ? 0 : 1;
}
