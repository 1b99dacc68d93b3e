// The offset solve's bounded least squares (tuning/trust_region_lsq.h) beside SciPy's lsq_linear on the same
// problems in the same run (issue 21 "what it must show" 6).
//
// Problems: the §4.2 penalty form of seeded random offset scenarios with K like real parts
// (tests/support/tuning_scenarios.h): n dimensions × k offsets → A is (2n + k) × (n + k). Default sizes
// 200 × 60 (A 460 × 260) and 2000 × 600 (A 4600 × 2600).
//
// For each: our solver (median wall and CPU time over repeats, with where the time goes: setup, unconstrained
// start, iterations, polish), the KKT certificate and, up to N = 400, our test-side BVLS (Stark–Parker); then
// the problem is written to a temporary JSON file and bench/scipy_lsq_peer.py runs SciPy's trf (dense A,
// lsq_solver='exact', tol=1e-12), bvls (dense) and trf with lsmr (sparse A) through /usr/bin/python3, each in
// its own process with a CPU-time limit (--peer-timeout, default 1800 s). Costs are compared as |f − f_ours|/max(1,
// f_ours). When /usr/bin/python3 or SciPy is missing the peer is skipped with a message.
//
//   ./build/bench/formloop_bench_tuning [--sizes 200x60,2000x600] [--repeats R] [--peer-timeout S] [--no-peer]
//                                       [--peer-parts]   (also times SciPy trf's pieces: lstsq, QR, one iteration)

#include <sys/resource.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <string>
#include <vector>

#include <Eigen/Dense>
#include <nlohmann/json.hpp>

#include "bench/bench_support.h"
#include "core/atomic_file.h"
#include "tests/support/bounded_lsq_check.h"
#include "tests/support/tuning_scenarios.h"
#include "tuning/offset_solve.h"
#include "tuning/trust_region_lsq.h"

namespace formloop {
namespace {

using bench::CpuSeconds;

double Median(std::vector<double> v) {
  std::sort(v.begin(), v.end());
  return v[v.size() / 2];
}

struct PeerResult {
  std::string method;
  bool ok = false;
  double seconds = 0, cpu_s = 0, cost = 0;
  nlohmann::json raw;
  int status = 0, nit = 0;
  std::string note;
};

// Runs one SciPy method on the problem file in its own process.
PeerResult RunPeer(const std::filesystem::path& problem, const std::string& method, int timeout_s) {
  PeerResult r;
  r.method = method;
  const std::string script = std::string(FORMLOOP_SOURCE_DIR) + "/bench/scipy_lsq_peer.py";
  // A CPU-time limit (the cores are shared; wall time under load says little), with a wall-clock guard 4x larger.
  const std::string command = "timeout " + std::to_string(4 * timeout_s) + " sh -c 'ulimit -t " +
                              std::to_string(timeout_s) + "; exec /usr/bin/python3 " + script + " " + problem.string() +
                              " " + method + "' 2>&1";
  FILE* pipe = ::popen(command.c_str(), "r");
  if (pipe == nullptr) {
    r.note = "could not start /usr/bin/python3";
    return r;
  }
  std::string out;
  char buffer[4096];
  std::size_t n;
  while ((n = std::fread(buffer, 1, sizeof buffer, pipe)) > 0) out.append(buffer, n);
  const int status = ::pclose(pipe);
  const int code = WIFEXITED(status) ? WEXITSTATUS(status) : -1;
  if (code == 124 || code == 137 || code == 152 || code == -1) {
    r.note = "did not finish within " + std::to_string(timeout_s) + " s of CPU time (stopped)";
    return r;
  }
  try {
    const auto j = nlohmann::json::parse(out.substr(out.rfind('{')));
    r.raw = j;
    if (j.contains("seconds")) {
      r.seconds = j["seconds"];
      r.cpu_s = j["cpu_s"];
      r.cost = j["cost"];
      r.status = j["status"];
      r.nit = j["nit"];
    }
    r.ok = true;
  } catch (const std::exception&) {
    r.note = "no result (" + std::string(code == 127 ? "/usr/bin/python3 missing" : "SciPy failed") +
             "): " + out.substr(0, std::min<std::size_t>(out.size(), 200));
  }
  return r;
}

bool PeerAvailable(std::string* why) {
  if (std::system("/usr/bin/python3 -c 'import scipy.optimize' >/dev/null 2>&1") != 0) {
    *why = "/usr/bin/python3 with SciPy (Debian's python3-scipy) is not available";
    return false;
  }
  return true;
}

void Bench(int n, int k, int repeats, int peer_timeout_s, bool peer, bool peer_parts) {
  // Some dimensions beyond reach and some tight offset bounds, so the bounds are active (the bounded path).
  const auto scenario = testing::MakeTuningScenario(20211102 + n, n, k, {.t_spread = 1.1, .tight_offset_share = 0.2});
  auto form = tuning::BuildPenaltyForm(scenario.problem);
  if (!form.ok()) {
    std::printf("%s\n", form.status().ToString().c_str());
    return;
  }
  const int m = form->a.rows(), cols = form->a.cols();
  std::printf("\n== %d dimensions x %d offsets: A %d x %d, %ld non-zeros (%.2f %% dense)\n", n, k, m, cols,
              static_cast<long>(form->a.nonZeros()), 100.0 * form->a.nonZeros() / (double(m) * cols));
  std::vector<double> wall, cpu;
  tuning::BoundedLsqReport ours;
  for (int r = 0; r < repeats; ++r) {
    const double c0 = CpuSeconds();
    const auto t0 = std::chrono::steady_clock::now();
    auto rep = tuning::SolveBoundedLsq(form->a, form->b, form->lb, form->ub);
    wall.push_back(std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count());
    cpu.push_back(CpuSeconds() - c0);
    if (!rep.ok()) {
      std::printf("ours failed: %s\n", rep.status().ToString().c_str());
      return;
    }
    ours = *rep;
  }
  const double ours_wall = Median(wall), ours_cpu = Median(cpu);
  const auto& t = ours.timing;
  int active = 0;
  for (int a : ours.active) active += a != 0;
  std::printf(
      "ours (trust-region reflective, Schur over %d coupled columns): median %.3f ms wall, %.3f ms CPU over %d runs; "
      "cost %.12g, %s, %d iterations, %d factorisations, %d separable columns, %d active bounds, polished %s\n",
      cols - ours.separable_columns, 1e3 * ours_wall, 1e3 * ours_cpu, repeats, ours.cost,
      tuning::BoundedLsqStatusName(ours.status), ours.iterations, t.factorizations, ours.separable_columns, active,
      ours.polished ? "yes" : "no");
  const double total = t.setup_s + t.start_s + t.iterations_s + t.polish_s;
  std::printf(
      "  where the time goes (last run): setup %.1f %%, unconstrained start %.1f %%, iterations %.1f %% "
      "(%.3f ms each), polish %.1f %%\n",
      100 * t.setup_s / total, 100 * t.start_s / total, 100 * t.iterations_s / total,
      1e3 * t.iterations_s / std::max(1, ours.iterations), 100 * t.polish_s / total);
  const Eigen::MatrixXd dense(form->a);
  const auto kkt = testing::KktCertificate(dense, form->b, form->lb, form->ub, ours.x);
  std::printf("  KKT certificate: %s (worst violation %.2e, eps_g %.2e)\n", kkt.ok ? "passed" : "FAILED",
              kkt.worst_violation, kkt.eps_g);
  auto rel = [&](double f) { return std::abs(f - ours.cost) / std::max(1.0, ours.cost); };
  // Ratios of CPU times: the cores are shared, and wall time under load says more about the neighbours.
  std::printf("  %-34s %10s %10s %14s %22s %14s\n", "peer", "wall s", "CPU s", "CPU peer/ours", "cost",
              "|df|/max(1,f)");
  if (cols <= 400) {
    const double c0 = CpuSeconds();
    const auto t0 = std::chrono::steady_clock::now();
    const auto bvls = testing::Bvls(dense, form->b, form->lb, form->ub);
    const double s = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    const double c = CpuSeconds() - c0;
    std::printf("  %-34s %10.4f %10.4f %13.1fx %22.12g %14.2e\n", "our test-side BVLS (Stark-Parker)", s, c,
                c / ours_cpu, bvls.cost, rel(bvls.cost));
  }
  if (!peer) return;
  std::string why;
  if (!PeerAvailable(&why)) {
    std::printf("  SciPy peer skipped: %s\n", why.c_str());
    return;
  }
  nlohmann::json problem = {{"shape", {m, cols}},
                            {"b", std::vector<double>(form->b.data(), form->b.data() + m)},
                            {"lb", std::vector<double>(form->lb.data(), form->lb.data() + cols)},
                            {"ub", std::vector<double>(form->ub.data(), form->ub.data() + cols)}};
  nlohmann::json triplets = nlohmann::json::array();
  for (int j = 0; j < form->a.outerSize(); ++j) {
    for (Eigen::SparseMatrix<double>::InnerIterator it(form->a, j); it; ++it) {
      triplets.push_back({it.row(), j, it.value()});
    }
  }
  problem["a_triplets"] = triplets;
  const auto file = std::filesystem::temp_directory_path() /
                    ("formloop-tuning-bench-" + std::to_string(::getpid()) + "-" + std::to_string(n) + ".json");
  if (!WriteFileAtomic(file, problem.dump()).ok()) {
    std::printf("  SciPy peer skipped: cannot write %s\n", file.string().c_str());
    return;
  }
  for (const char* method : {"trf", "bvls", "trf-lsmr"}) {
    const PeerResult r = RunPeer(file, method, peer_timeout_s);
    const std::string label =
        std::string("scipy lsq_linear ") + method + (std::string(method) == "trf-lsmr" ? " (sparse A)" : " (dense A)");
    if (r.ok) {
      std::printf("  %-34s %10.3f %10.3f %13.1fx %22.12g %14.2e   status %d, %d iterations\n", label.c_str(), r.seconds,
                  r.cpu_s, r.cpu_s / ours_cpu, r.cost, rel(r.cost), r.status, r.nit);
    } else {
      std::printf("  %-34s %s\n", label.c_str(), r.note.c_str());
    }
  }
  if (peer_parts) {
    const PeerResult r = RunPeer(file, "parts", peer_timeout_s);
    if (r.ok) {
      std::printf(
          "  where SciPy trf's time goes: numpy lstsq (unconstrained start) %.3f s, pivoted QR of A %.3f s, one "
          "regularised solve through the QR (each iteration) %.3f s\n",
          r.raw["lstsq_s"].get<double>(), r.raw["qr_s"].get<double>(), r.raw["iteration_solve_s"].get<double>());
    } else {
      std::printf("  SciPy parts: %s\n", r.note.c_str());
    }
  }
  std::filesystem::remove(file);
}

}  // namespace
}  // namespace formloop

int main(int argc, char** argv) {
  std::setvbuf(stdout, nullptr, _IOLBF, 0);  // lines appear as they are printed (the SciPy peer takes minutes)
  std::vector<std::pair<int, int>> sizes = {{200, 60}, {2000, 600}};
  int repeats = 0, timeout_s = 1800;
  bool peer = true, peer_parts = false;
  for (int i = 1; i < argc; ++i) {
    const std::string arg = argv[i];
    if (arg == "--sizes" && i + 1 < argc) {
      sizes.clear();
      std::string list = argv[++i];
      std::size_t pos = 0;
      while (pos < list.size()) {
        const std::size_t comma = list.find(',', pos);
        const std::string item = list.substr(pos, comma == std::string::npos ? std::string::npos : comma - pos);
        const std::size_t x = item.find('x');
        sizes.push_back({std::stoi(item.substr(0, x)), std::stoi(item.substr(x + 1))});
        pos = comma == std::string::npos ? list.size() : comma + 1;
      }
    } else if (arg == "--repeats" && i + 1 < argc) {
      repeats = std::stoi(argv[++i]);
    } else if (arg == "--peer-timeout" && i + 1 < argc) {
      timeout_s = std::stoi(argv[++i]);
    } else if (arg == "--no-peer") {
      peer = false;
    } else if (arg == "--peer-parts") {
      peer_parts = true;
    } else {
      std::fprintf(stderr,
                   "usage: %s [--sizes 200x60,2000x600] [--repeats R] [--peer-timeout S] [--no-peer] [--peer-parts]\n",
                   argv[0]);
      return 2;
    }
  }
  std::printf(
      "bounded least squares of the offset solve (spec/tuning-and-link.md §4.2-4.4); Eigen %d.%d.%d, %ld cores\n",
      EIGEN_WORLD_VERSION, EIGEN_MAJOR_VERSION, EIGEN_MINOR_VERSION, sysconf(_SC_NPROCESSORS_ONLN));
  for (const auto& [n, k] : sizes) {
    formloop::Bench(n, k, repeats > 0 ? repeats : (n * k <= 20000 ? 21 : 3), timeout_s, peer, peer_parts);
  }
  return 0;
}
