// The demo part end to end (issue 8): wall time and peak resident memory per pipeline stage, beside the
// whole run's wall time. Peak memory per stage: the kernel's high-water mark (VmHWM) is reset before
// each stage by writing 5 to /proc/self/clear_refs (Linux ≥ 4.0), so each row is that stage's own peak.
//
//   formloop_bench_pipeline [PART.json] [--repeat N]     (default: data/parts/demo-saddle.json, N = 3)
//
// Each repetition starts from a fresh starter case library (built first, timed as "kb init --starter").

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <map>
#include <string>
#include <vector>

#include <unistd.h>

#include "app/kb_jobs.h"
#include "app/part.h"
#include "app/pipeline.h"
#include "core/log.h"
#include "retrieval/starter.h"

namespace {
namespace fs = std::filesystem;

double PeakRssMiB() {
  std::ifstream status("/proc/self/status");
  std::string line;
  while (std::getline(status, line)) {
    if (line.rfind("VmHWM:", 0) == 0) return std::stod(line.substr(6)) / 1024.0;
  }
  return -1;
}

void ResetPeak() {
  std::ofstream clear("/proc/self/clear_refs");
  clear << "5";
}

double Seconds(std::chrono::steady_clock::time_point since) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - since).count();
}

}  // namespace

int main(int argc, char** argv) {
  using namespace formloop;
  fs::path part_file = retrieval::DefaultDataDir() / "parts" / "demo-saddle.json";
  int repeat = 3;
  for (int i = 1; i < argc; ++i) {
    const std::string a = argv[i];
    if (a == "--repeat" && i + 1 < argc) {
      repeat = std::max(1, std::atoi(argv[++i]));
    } else {
      part_file = a;
    }
  }
  log::SetLevel(log::Level::kWarn);
  const auto part = app::ReadPart(part_file);
  if (!part.ok()) {
    std::fprintf(stderr, "%s\n", part.status().ToString().c_str());
    return 2;
  }
  const fs::path dir = fs::temp_directory_path() / ("formloop-bench-pipeline-" + std::to_string(::getpid()));
  std::vector<std::string> order;
  std::map<std::string, std::vector<double>> seconds, peak;
  std::vector<double> totals, kb_init;
  for (int r = 0; r < repeat; ++r) {
    fs::remove_all(dir);
    fs::create_directories(dir);
    ResetPeak();
    auto start = std::chrono::steady_clock::now();
    if (auto made = app::CreateStarterLibrary((dir / "kb.sqlite").string(), retrieval::DefaultDataDir()); !made.ok()) {
      std::fprintf(stderr, "%s\n", made.status().ToString().c_str());
      return 1;
    }
    kb_init.push_back(Seconds(start));
    seconds["kb init --starter"].push_back(kb_init.back());
    peak["kb init --starter"].push_back(PeakRssMiB());
    app::RunOptions options;
    options.out = dir / "run";
    options.kb = (dir / "kb.sqlite").string();
    options.on_stage = [&](std::string_view stage, double s) {
      const std::string name(stage);
      if (r == 0 && std::find(order.begin(), order.end(), name) == order.end()) order.push_back(name);
      seconds[name].push_back(s);
      peak[name].push_back(PeakRssMiB());
      ResetPeak();
    };
    ResetPeak();
    start = std::chrono::steady_clock::now();
    const auto summary = app::RunPart(*part, options);
    totals.push_back(Seconds(start));
    if (!summary.ok()) {
      std::fprintf(stderr, "%s\n", summary.status().ToString().c_str());
      return 1;
    }
  }
  fs::remove_all(dir);
  auto median = [](std::vector<double> v) {
    std::sort(v.begin(), v.end());
    return v[v.size() / 2];
  };
  auto max = [](const std::vector<double>& v) { return *std::max_element(v.begin(), v.end()); };
  std::printf("pipeline benchmark: %s, %d repetition(s), %ld cores\n", part_file.filename().c_str(), repeat,
              ::sysconf(_SC_NPROCESSORS_ONLN));
  std::printf("%-28s %12s %16s\n", "stage", "median s", "peak RSS MiB");
  std::printf("%-28s %12.3f %16.1f\n", "kb init --starter (setup)", median(seconds["kb init --starter"]),
              max(peak["kb init --starter"]));
  double sum = 0;
  for (const std::string& stage : order) {
    std::printf("%-28s %12.3f %16.1f\n", stage.c_str(), median(seconds[stage]), max(peak[stage]));
    sum += median(seconds[stage]);
  }
  double whole_peak = 0;
  for (const auto& [stage, values] : peak) whole_peak = std::max(whole_peak, max(values));
  std::printf("%-28s %12.3f %16.1f\n", "formloop run (whole)", median(totals), whole_peak);
  std::printf("sum of stage medians %.3f s (the rest: run folder set-up, log, rename)\n", sum);
  return 0;
}
