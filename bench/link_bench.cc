// Throughput of the machine link (cnc/): points per second through the macro-variable handshake over
// real loopback TCP, with the emulator's API latency at 0 and at 1 ms ± 0.5 ms (uniform), printed
// beside its peers in the same run:
//   - the transport alone: the round-trip time of one range read of the block on the same connection
//     (median of 1000), and the bound the protocol imposes from it: a point needs 4 round trips (the
//     read that finds POINT_READY, the data reset, its read-back, the control write), so at most
//     1 / (4 · RTT) points per second on the collector's side;
//   - the machine side's bound: after its hand-over the program looks at C once per dwell, and the
//     control write lands half a round trip into the 4th call, so a point costs it
//     measure + t_dwell · ceil((t_poll/2 + 3.5 · RTT) / t_dwell) (the poll that finds POINT_READY is
//     applied half a round trip after it is sent);
//   - the journal's cost: the same collection with the journal on the disk (fdatasync per point) and on
//     a RAM disk;
//   - virtual time with the spec's timings (t_poll 10 ms, t_dwell 20 ms; acceptance check §9.14), which
//     is what a controller with those settings achieves whatever the host.
// The emulator runs in a thread of this process, the collector in the main thread; the machine-side
// program is formloop's Fanuc program run by the emulator's interpreter.
//
//   nice -n 10 ./build/bench/formloop_bench_link [points]      (default 2000, one run)

#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <thread>
#include <vector>

#include "cnc/collector.h"
#include "cnc/emulator_server.h"
#include "cnc/tcp_transport.h"
#include "cnc/virtual_link.h"
#include "core/log.h"

namespace formloop::cnc {
namespace {

struct Setting {
  const char* name;
  double latency_ms, jitter_ms;
};

struct Measured {
  double rtt_median_ms = 0, points_per_s = 0, calls_per_point = 0, seconds = 0;
  long points = 0;
};

ControllerOptions Emulator(const Setting& s, int points, double dwell_s) {
  ControllerOptions o;
  o.dialect = Dialect::kFanuc;
  o.program.probe.post.decimals = 3;
  o.program.dwell_s = dwell_s;
  o.points = points;
  o.measure_time_s = 0;
  o.latency.base_s = (s.latency_ms - s.jitter_ms) * 1e-3;
  o.latency.jitter_s = 2 * s.jitter_ms * 1e-3;
  o.seed = 11;
  return o;
}

Measured RunTcp(const Setting& s, int points, double dwell_s, double poll_s, const std::filesystem::path& journal,
                bool fsync) {
  Measured m;
  EmulatorServerOptions so;
  so.linger_s = 0.2;
  auto server = EmulatorServer::Start(Emulator(s, points, dwell_s), so);
  if (!server.ok()) {
    std::fprintf(stderr, "%s\n", server.status().ToString().c_str());
    std::exit(1);
  }
  std::atomic<bool> stop{false};
  std::thread thread([&] { (void)(*server)->Run(&stop); });
  const int port = (*server)->port();
  // The transport alone: round trips of a range read of the block while the program waits for the arm.
  {
    TcpTransport ping("127.0.0.1", port);
    if (!ping.Connect().ok()) std::exit(1);
    std::vector<double> rtt;
    for (int k = 0; k < 1000; ++k) {
      const auto t0 = std::chrono::steady_clock::now();
      if (!ping.ReadRange(900, 4).ok()) std::exit(1);
      rtt.push_back(std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count());
    }
    std::nth_element(rtt.begin(), rtt.begin() + 500, rtt.end());
    m.rtt_median_ms = rtt[500] * 1e3;
  }
  TcpTransport transport("127.0.0.1", port);
  RealClock clock;
  CollectorOptions co;
  co.block = BlockLayout{Layout::kPacked, 900};
  co.expect_points = points;
  co.poll_s = poll_s;
  co.journal = journal;
  co.fsync = fsync;
  std::filesystem::remove(journal);
  const auto report = Collect(transport, clock, co);
  stop = true;
  thread.join();
  std::filesystem::remove(journal);
  if (!report.ok() || !report->ok || report->points_total() != points) {
    std::fprintf(stderr, "collection failed: %s\n",
                 report.ok() ? report->fatal.c_str() : report.status().ToString().c_str());
    std::exit(1);
  }
  m.points = report->points_total();
  m.seconds = report->elapsed_s;
  m.points_per_s = report->points_per_s();
  m.calls_per_point = static_cast<double>(report->counters.reads + report->counters.writes) / points;
  return m;
}

// Virtual time, the spec's timings: t_poll 10 ms, t_dwell 20 ms.
double RunVirtual(const Setting& s, int points) {
  EventScheduler scheduler;
  VirtualClock clock(&scheduler);
  auto controller = Controller::Create(Emulator(s, points, 0.020), &scheduler);
  VirtualLink link(controller->get(), &scheduler);
  CollectorOptions co;
  co.block = (*controller)->block();
  co.expect_points = points;
  co.poll_s = 0.010;
  co.fsync = false;
  co.journal =
      std::filesystem::temp_directory_path() / ("formloop-bench-link-" + std::to_string(::getpid()) + ".journal");
  std::filesystem::remove(co.journal);
  const auto report = Collect(link, clock, co);
  std::filesystem::remove(co.journal);
  const auto& rec = (*controller)->record();
  if (!report.ok() || !report->ok || rec.size() < 2) std::exit(1);
  return (rec.size() - 1) / (rec.back().t_s - rec.front().t_s);
}

}  // namespace
}  // namespace formloop::cnc

int main(int argc, char** argv) {
  using namespace formloop::cnc;
  formloop::log::SetLevel(formloop::log::Level::kWarn);
  const int points = argc > 1 ? std::atoi(argv[1]) : 2000;
  const double dwell_s = 0.001, poll_s = 0.0002;
  const std::filesystem::path ram =
      std::filesystem::exists("/dev/shm") ? "/dev/shm" : std::filesystem::temp_directory_path();
  const std::filesystem::path disk = std::filesystem::current_path();
  const auto journal = [&](const std::filesystem::path& dir) {
    return dir / ("formloop-bench-link-" + std::to_string(::getpid()) + ".journal");
  };
  std::printf(
      "machine link throughput, %d points, Fanuc program in the emulator (measure 0, t_dwell %.0f ms), collector "
      "t_poll %.1f ms, loopback TCP\n\n",
      points, dwell_s * 1e3, poll_s * 1e3);
  std::printf("%-22s %10s %12s %12s %14s %14s %14s %16s\n", "API latency", "RTT ms", "pts/s RAM", "pts/s disk",
              "calls/point", "bound 4 RTT", "bound machine", "virtual 10/20ms");
  for (const Setting& s : {Setting{"0", 0, 0}, Setting{"1 ms +/- 0.5 ms", 1.0, 0.5}}) {
    const Measured ram_run = RunTcp(s, points, dwell_s, poll_s, journal(ram), true);
    const Measured disk_run = RunTcp(s, points, dwell_s, poll_s, journal(disk), true);
    const double rtt_s = ram_run.rtt_median_ms * 1e-3;
    const double bound_rtt = 1.0 / (4 * rtt_s);
    const double to_hand_back = poll_s / 2 + 3.5 * rtt_s;  // POINT_READY visible → the control write applied
    const double bound_machine = 1.0 / (dwell_s * std::ceil(to_hand_back / dwell_s - 1e-9));
    const double virt = RunVirtual(s, std::min(points, 500));
    std::printf("%-22s %10.3f %12.1f %12.1f %14.2f %14.1f %14.1f %16.1f\n", s.name, ram_run.rtt_median_ms,
                ram_run.points_per_s, disk_run.points_per_s, ram_run.calls_per_point, bound_rtt, bound_machine, virt);
  }
  std::printf(
      "\nbound 4 RTT: 1 / (4 round trips per point x median RTT) = the protocol's own limit on the collector side;\n"
      "bound machine: 1 / (t_dwell x ceil((t_poll/2 + 3.5 RTT) / t_dwell)): the program looks at C once per dwell;\n"
      "virtual 10/20 ms: points/s in virtual time with the spec's t_poll = 10 ms, t_dwell = 20 ms (check 14).\n");
  return 0;
}
