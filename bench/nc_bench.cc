// Planning and posting about 1,000,000 cutter locations (issue 4, benchmark): wall time and the
// process's peak resident memory after each stage, for the raster planner on a B-spline fit of franke
// (100 × 100 mm), the canonical move list, each of the four dialect posts and reading each program
// back. The reference method is LinuxCNC's own interpreter, `rs274`, reading the same LinuxCNC
// program (when installed): it shows what a controller-grade parser spends on the same text.
//
// Peak RSS is the process's high-water mark (getrusage), so each row shows the most memory used up to
// that stage, including the calibration plans that set the point spacing before the timed plan.
//
//   ./build/bench/formloop_bench_nc [target_cl_points]      (default 1,000,000)

#include <sys/resource.h>
#include <sys/wait.h>

#include <unistd.h>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <string>

#include "nc-gen/moves.h"
#include "nc-gen/post.h"
#include "nc-gen/toolpath.h"
#include "reconstruction/analytic_surface.h"
#include "reconstruction/bspline_surface.h"

namespace formloop {
namespace {

double PeakRssMb() {
  rusage usage{};
  getrusage(RUSAGE_SELF, &usage);
  return static_cast<double>(usage.ru_maxrss) / 1024.0;  // ru_maxrss is in KiB on Linux
}

class Stopwatch {
 public:
  double Seconds() const { return std::chrono::duration<double>(std::chrono::steady_clock::now() - start_).count(); }

 private:
  std::chrono::steady_clock::time_point start_ = std::chrono::steady_clock::now();
};

void Row(const std::string& stage, double seconds, const std::string& size) {
  std::printf("%-44s %9.2f s %12s %10.0f MB\n", stage.c_str(), seconds, size.c_str(), PeakRssMb());
}

int Run(long target) {
  auto franke = recon::MakeReferenceSurface("franke");
  if (!franke.ok()) return 1;
  recon::FitReport report;
  auto q = recon::FitAnalytic(**franke, 61, 61, recon::GridFitOptions{}, 0, 1, &report);
  if (!q.ok()) {
    std::fprintf(stderr, "%s\n", q.status().ToString().c_str());
    return 1;
  }
  // Point spacing along a pass and the scallop target set the count: first a coarse plan to measure
  // CL points per mm², then the spacing that gives about `target` points.
  nc::ToolpathOptions options;
  options.tool.radius_mm = 3;
  options.scallop_um = 5;
  options.chord_tolerance_um = 1;
  options.max_point_spacing_mm = 0.5;
  auto probe = nc::PlanRaster(*q, options);
  if (!probe.ok()) {
    std::fprintf(stderr, "%s\n", probe.status().ToString().c_str());
    return 1;
  }
  options.max_point_spacing_mm = std::max(1e-3, 0.5 * static_cast<double>(probe->points.size()) / target);
  // Where the chord tolerance, not the spacing cap, sets the spacing the count grows slower than
  // 1/spacing: correct twice more on the measured counts.
  for (int round = 0; round < 2; ++round) {
    auto trial = nc::PlanRaster(*q, options);
    if (!trial.ok()) return 1;
    const double ratio = static_cast<double>(trial->points.size()) / static_cast<double>(target);
    if (std::abs(ratio - 1) < 0.02) break;
    options.max_point_spacing_mm *= ratio;
  }

  std::printf("%-44s %11s %12s %13s\n", "stage", "wall", "size", "peak RSS");
  Row("start (franke fit)", 0, "");
  Stopwatch plan_clock;
  auto path = nc::PlanRaster(*q, options);
  if (!path.ok()) {
    std::fprintf(stderr, "%s\n", path.status().ToString().c_str());
    return 1;
  }
  Row("PlanRaster", plan_clock.Seconds(), std::to_string(path->points.size()) + " CL");
  Stopwatch list_clock;
  auto moves = nc::BuildMoveList(*path);
  if (!moves.ok()) return 1;
  Row("BuildMoveList", list_clock.Seconds(), std::to_string(moves->moves.size()) + " moves");

  nc::PostOptions post;
  post.title = "formloop bench";
  post.limits.max_feed_mm_per_min = 20000;
  const std::filesystem::path dir =
      std::filesystem::temp_directory_path() / ("formloop_bench_nc_" + std::to_string(getpid()));
  std::filesystem::create_directories(dir);
  std::filesystem::path linuxcnc_file;
  for (const std::string& dialect : nc::PostNames()) {
    Stopwatch post_clock;
    auto text = nc::Post(*moves, dialect, post);
    if (!text.ok()) {
      std::fprintf(stderr, "%s: %s\n", dialect.c_str(), text.status().ToString().c_str());
      return 1;
    }
    Row("Post " + dialect, post_clock.Seconds(), std::to_string(text->size() / (1024 * 1024)) + " MiB");
    Stopwatch read_clock;
    auto back = nc::ReadProgram(*text, dialect, dialect);
    if (!back.ok()) {
      std::fprintf(stderr, "%s: %s\n", dialect.c_str(), back.status().ToString().c_str());
      return 1;
    }
    Row("ReadProgram " + dialect, read_clock.Seconds(), std::to_string(back->size()) + " moves");
    if (dialect == "linuxcnc") {
      linuxcnc_file = dir / "bench.ngc";
      std::ofstream(linuxcnc_file) << *text;
    }
  }
  // Reference: LinuxCNC's interpreter on the same program (canonical commands to /dev/null).
  if (!linuxcnc_file.empty() && std::system("command -v rs274 >/dev/null 2>&1") == 0) {
    Stopwatch rs274_clock;
    const std::string command = "rs274 -g " + linuxcnc_file.string() + " >/dev/null 2>&1";
    const int status = std::system(command.c_str());
    std::printf("%-44s %9.2f s %12s %13s\n", "reference: LinuxCNC rs274 -g (same program)", rs274_clock.Seconds(),
                WIFEXITED(status) && WEXITSTATUS(status) == 0 ? "ok" : "failed", "(own process)");
  } else {
    std::printf("reference: rs274 not installed (apt-get install linuxcnc-uspace)\n");
  }
  std::filesystem::remove_all(dir);
  return 0;
}

}  // namespace
}  // namespace formloop

int main(int argc, char** argv) {
  const long target = argc > 1 ? std::atol(argv[1]) : 1'000'000;
  if (target < 1000) {
    std::fprintf(stderr, "usage: formloop_bench_nc [target_cl_points >= 1000]\n");
    return 2;
  }
  return formloop::Run(target);
}
