// `nc distribute` on programs of 100,000 to 2,000,000 blocks (issue 23): wall time, CPU time and peak resident
// memory of reading, correcting and writing, each size in a process of its own (fork), so the peak
// memory of one size says what that size needs; beside it formloop's reader alone and LinuxCNC's own
// interpreter `rs274 -g` (when installed) reading the distributed program.
//
// The program is a finishing raster written here: passes of 1 mm straight moves with a 90° arc (r = 2 mm)
// every 10 blocks, a comment or feed block every 50, a key point (M59 P<n>) every 1,000 blocks and a
// region (M57 ... M58, closed by a 1 mm lift) every 20 key points; the deviations vary from key point to key point by a
// few µm, so every block is corrected and arcs stay arcs (their drift is far below the resolution).
//
//   ./build/bench/formloop_bench_nc_distribute [blocks ...]      (default 100000 1000000 2000000)

#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <string>
#include <vector>

#include <sys/resource.h>
#include <sys/wait.h>
#include <unistd.h>

#include "nc-gen/gcode_reader.h"
#include "nc-gen/path_deviation.h"

namespace formloop {
namespace {

namespace fs = std::filesystem;

double PeakRssMb() {
  rusage usage{};
  getrusage(RUSAGE_SELF, &usage);
  return static_cast<double>(usage.ru_maxrss) / 1024.0;  // KiB on Linux
}

// CPU seconds (user + system) used by this process (`who` RUSAGE_SELF) or by the children it waited for
// (RUSAGE_CHILDREN): on a shared machine the wall time also counts the time other processes held the
// cores, the CPU time does not.
double CpuSeconds(int who = RUSAGE_SELF) {
  rusage usage{};
  getrusage(who, &usage);
  return static_cast<double>(usage.ru_utime.tv_sec + usage.ru_stime.tv_sec) +
         1e-6 * static_cast<double>(usage.ru_utime.tv_usec + usage.ru_stime.tv_usec);
}

double Seconds(std::chrono::steady_clock::time_point since) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - since).count();
}

struct Generated {
  long blocks = 0, keys = 0;
};

// Writes the program (streamed: the generator holds one line at a time) and the table.
Generated WriteProgram(const fs::path& program, const fs::path& table, long target) {
  std::ofstream out(program, std::ios::binary);
  out << "%\n(formloop distribution benchmark)\nG21 G90 G17 G94\nG0 X0 Y0 Z5\nG0 X0 Y0 Z0\nF1200\n";
  Generated g;
  double x = 0, y = 0;
  int dir = 1;
  long key = 0, in_region = 0;
  bool open = false;
  char line[128];
  while (g.blocks < target) {
    if (!open) {
      out << "M57\n";
      open = true;
    }
    for (int k = 0; k < 1000 && g.blocks < target; ++k, ++g.blocks) {
      if (k % 50 == 49) {
        out << "(pass " << g.blocks << ")\n";
      } else if (k % 10 == 9) {  // quarter arc turning the raster, r = 2
        const double cx = x, cy = y + 2;
        x += dir * 2;
        y += 2;
        std::snprintf(line, sizeof(line), "%s X%.4f Y%.4f I%.4f J%.4f\n", dir > 0 ? "G3" : "G2", x, y,
                      cx - (x - dir * 2), cy - (y - 2));
        out << line;
        if (std::abs(x) > 200) dir = -dir;
      } else {
        x += dir * 1.0;
        std::snprintf(line, sizeof(line), "G1 X%.4f Y%.4f\n", x, y);
        out << line;
      }
      if (y > 400) y = 0;
    }
    ++key;
    out << "M59 P" << key << "\n";
    if (++in_region == 20) {
      out << "G1 Z1.\nM58\nG0 Z5\nG0 X" << x << " Y" << y << "\nG0 Z0\n";  // a lift: the path back to 0
      open = false;
      in_region = 0;
    }
  }
  if (open) out << "G1 Z1.\nM58\n";
  out << "G0 Z5\nM30\n%\n";
  g.keys = key;
  std::ofstream t(table);
  t << "index,dx,dy,dz\n";
  for (long k = 1; k <= key; ++k) {
    t << k << "," << 0.002 * std::sin(0.7 * k) << "," << 0.002 * std::cos(0.3 * k) << "," << 0.001 * std::sin(0.1 * k)
      << "\n";
  }
  return g;
}

struct Measured {
  double seconds = 0, cpu_seconds = 0, peak_mb = 0;
  long lines_out = 0;
  int status = 0;
};

// Runs `work` in a child process and returns its time and peak memory.
template <typename F>
Measured InChild(F work) {
  int fds[2];
  if (pipe(fds) != 0) return {.status = -1};
  const pid_t pid = fork();
  if (pid == 0) {
    close(fds[0]);
    const double cpu0 = CpuSeconds();
    Measured m = work();
    m.cpu_seconds = CpuSeconds() - cpu0;
    m.peak_mb = PeakRssMb();
    if (write(fds[1], &m, sizeof(m)) != sizeof(m)) _exit(1);
    _exit(0);
  }
  close(fds[1]);
  Measured m{.status = -1};
  if (read(fds[0], &m, sizeof(m)) != sizeof(m)) m.status = -1;
  close(fds[0]);
  int status = 0;
  waitpid(pid, &status, 0);
  return m;
}

int Run(const std::vector<long>& sizes) {
  const fs::path dir = fs::temp_directory_path() / ("formloop-bench-distribute-" + std::to_string(getpid()));
  fs::create_directories(dir);
  const bool have_rs274 = std::system("command -v rs274 >/dev/null 2>&1") == 0;
  std::printf("nc distribute benchmark (one process per row; peak RSS = that process's high-water mark)\n");
  std::printf("%-10s %-44s %10s %10s %10s %12s\n", "blocks", "stage", "wall s", "cpu s", "peak MB", "lines out");
  for (long n : sizes) {
    const fs::path program = dir / ("p" + std::to_string(n) + ".ngc"), table = dir / "d.csv";
    const fs::path out = dir / ("o" + std::to_string(n) + ".ngc");
    const Generated g = WriteProgram(program, table, n);
    const Measured read = InChild([&] {
      const auto t0 = std::chrono::steady_clock::now();
      nc::ReaderOptions options;
      options.caller_m_codes = {57, 58, 59};
      nc::GcodeReader reader(options, program.string());
      auto lines = nc::LineSource::Open(program);
      nc::Block block;
      std::string_view line, eol;
      Measured m;
      while (lines->Next(&line, &eol)) {
        if (!reader.Read(line, &block).ok()) return Measured{.status = 1};
      }
      m.seconds = Seconds(t0);
      m.lines_out = static_cast<long>(reader.report().lines);
      return m;
    });
    const Measured distribute = InChild([&] {
      const auto t0 = std::chrono::steady_clock::now();
      Measured m;
      auto t = nc::ReadDeviationTable(table);
      nc::DistributeOptions options;
      options.decimals_mm = 4;
      const auto report = nc::DistributeProgram(program, out, *t, options);
      if (!report.ok()) {
        std::fprintf(stderr, "%s\n", report.status().ToString().c_str());
        return Measured{.status = 1};
      }
      m.seconds = Seconds(t0);
      m.lines_out = static_cast<long>(report->lines_out);
      return m;
    });
    std::printf("%-10ld %-44s %10.2f %10.2f %10.1f %12ld\n", g.blocks, "formloop reader (read only)", read.seconds,
                read.cpu_seconds, read.peak_mb, read.lines_out);
    std::printf("%-10ld %-44s %10.2f %10.2f %10.1f %12ld\n", g.blocks, "formloop nc distribute (read+correct+write)",
                distribute.seconds, distribute.cpu_seconds, distribute.peak_mb, distribute.lines_out);
    if (have_rs274) {
      const double cpu0 = CpuSeconds(RUSAGE_CHILDREN);
      const auto t0 = std::chrono::steady_clock::now();
      const std::string command = "rs274 -g " + out.string() + " /dev/null </dev/null >/dev/null 2>&1";
      const int rc = std::system(command.c_str());
      const double wall = Seconds(t0);
      std::printf("%-10ld %-44s %10.2f %10.2f %10s %12s  (exit %d)\n", g.blocks,
                  "LinuxCNC rs274 -g (the distributed program)", wall, CpuSeconds(RUSAGE_CHILDREN) - cpu0, "-", "-",
                  WEXITSTATUS(rc));
    }
    std::fflush(stdout);
    fs::remove(program);
    fs::remove(out);
  }
  fs::remove_all(dir);
  return 0;
}

}  // namespace
}  // namespace formloop

int main(int argc, char** argv) {
  std::vector<long> sizes;
  for (int i = 1; i < argc; ++i) sizes.push_back(std::atol(argv[i]));
  if (sizes.empty()) sizes = {100000, 1000000, 2000000};
  return formloop::Run(sizes);
}
