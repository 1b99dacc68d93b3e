#include "cnc/linuxcnc_link.h"

#include <poll.h>
#include <sys/socket.h>
#include <sys/un.h>
#include <unistd.h>

#include <atomic>
#include <charconv>
#include <chrono>
#include <cmath>
#include <cstring>
#include <limits>
#include <set>
#include <sstream>
#include <thread>

#include "cnc/linuxcnc_probing.h"
#include "core/atomic_file.h"
#include "core/log.h"
#include "core/number_text.h"
#include "core/point_io.h"

namespace formloop::cnc {
namespace {

namespace fs = std::filesystem;
using nlohmann::json;

// Both files print six decimals; the received centre is rounded to the 0.1 µm of the data word.
constexpr double kAgreeUm = 0.05 + 1e-3;

// The collector's clock: real time, except that sleeping after the controller has ended stops the
// collector (nothing would ever answer it again).
struct ControllerEnded {};
class StoppableClock final : public Clock {
 public:
  explicit StoppableClock(const std::atomic<bool>& ended) : ended_(ended) {}
  double NowS() override { return real_.NowS(); }
  void SleepS(double seconds) override {
    if (ended_) throw ControllerEnded{};
    real_.SleepS(seconds);
  }

 private:
  RealClock real_;
  const std::atomic<bool>& ended_;
};

// A short private folder for the link's socket (a socket path has at most 107 bytes).
class SocketFolder {
 public:
  ~SocketFolder() {
    std::error_code ec;
    if (!path_.empty()) fs::remove_all(path_, ec);
  }
  Status Make() {
    char pattern[] = "/tmp/formloop-link-XXXXXX";
    if (::mkdtemp(pattern) == nullptr) return Status::IoError(std::string("mkdtemp: ") + std::strerror(errno));
    path_ = pattern;
    return Status::Ok();
  }
  fs::path socket() const { return path_ / "link.sock"; }

 private:
  fs::path path_;
};

Result<std::vector<Eigen::Vector3d>> Trips(const fs::path& file) {
  FL_ASSIGN_OR_RETURN(const std::string text, ReadFile(file));
  std::vector<Eigen::Vector3d> trips;
  std::istringstream in(text);
  for (std::string line; std::getline(in, line);) {
    std::istringstream words(line);
    Eigen::Vector3d p;
    if (words >> p.x() >> p.y() >> p.z()) trips.push_back(p);
  }
  return trips;
}

}  // namespace

// ---- LinuxCncLinkTransport ----

LinuxCncLinkTransport::LinuxCncLinkTransport(fs::path socket, double call_timeout_s)
    : socket_(std::move(socket)), call_timeout_s_(call_timeout_s) {}

LinuxCncLinkTransport::~LinuxCncLinkTransport() { Disconnect(); }

Status LinuxCncLinkTransport::Connect() {
  Disconnect();
  sockaddr_un address{};
  address.sun_family = AF_UNIX;
  const std::string path = socket_.string();
  if (path.size() >= sizeof(address.sun_path)) return Status::BadInput("socket path too long: " + path);
  std::memcpy(address.sun_path, path.c_str(), path.size() + 1);
  fd_ = ::socket(AF_UNIX, SOCK_STREAM | SOCK_CLOEXEC, 0);
  if (fd_ < 0) return Status::IoError(std::string("socket: ") + std::strerror(errno));
  if (::connect(fd_, reinterpret_cast<const sockaddr*>(&address), sizeof(address)) != 0) {
    const std::string why = std::strerror(errno);
    Disconnect();
    return Status::IoError("cannot connect to " + path + ": " + why);
  }
  return Status::Ok();
}

void LinuxCncLinkTransport::Disconnect() {
  if (fd_ >= 0) ::close(fd_);
  fd_ = -1;
  inbox_.clear();
}

Result<std::string> LinuxCncLinkTransport::Call(const std::string& request) {
  if (fd_ < 0) return Status::IoError("not connected");
  const std::string line = request + "\n";
  if (::send(fd_, line.data(), line.size(), MSG_NOSIGNAL) != static_cast<ssize_t>(line.size())) {
    Disconnect();
    return Status::IoError(std::string("send: ") + std::strerror(errno));
  }
  const auto deadline = std::chrono::steady_clock::now() + std::chrono::duration<double>(call_timeout_s_);
  for (;;) {
    const auto end = inbox_.find('\n');
    if (end != std::string::npos) {
      std::string answer = inbox_.substr(0, end);
      inbox_.erase(0, end + 1);
      if (answer.rfind("OK", 0) == 0) return answer.size() > 2 ? answer.substr(3) : std::string();
      return Status::Failed("the link component refused '" + request + "': " + answer);
    }
    const double left = std::chrono::duration<double>(deadline - std::chrono::steady_clock::now()).count();
    pollfd p{fd_, POLLIN, 0};
    if (left <= 0 || ::poll(&p, 1, static_cast<int>(std::ceil(left * 1000))) <= 0) {
      Disconnect();
      return Status::IoError("the link component did not answer within " + FormatExact(call_timeout_s_) + " s");
    }
    char buffer[4096];
    const ssize_t n = ::recv(fd_, buffer, sizeof(buffer), 0);
    if (n <= 0) {
      Disconnect();
      return Status::IoError("the link component closed the connection");
    }
    inbox_.append(buffer, static_cast<std::size_t>(n));
  }
}

Result<std::vector<MacroValue>> LinuxCncLinkTransport::ReadRange(int start, int count) {
  FL_ASSIGN_OR_RETURN(const std::string answer, Call("R " + std::to_string(start) + " " + std::to_string(count)));
  std::vector<MacroValue> values;
  std::istringstream words(answer);
  for (std::string w; words >> w;) {
    double v = 0;
    const auto r = std::from_chars(w.data(), w.data() + w.size(), v);
    if (r.ec != std::errc() || r.ptr != w.data() + w.size()) {
      return Status::IoError("the link component answered '" + w + "', not a number");
    }
    values.emplace_back(v);
  }
  if (static_cast<int>(values.size()) != count) return Status::IoError("the link component answered the wrong count");
  return values;
}

Status LinuxCncLinkTransport::WriteRange(int start, const std::vector<double>& values) {
  std::string request = "W " + std::to_string(start);
  for (double v : values) request += " " + FormatExact(v);
  return Call(request).status();
}

Result<double> LinuxCncLinkTransport::ReadOffset(const OffsetAddress& offset) {
  return Status::Failed("the LinuxCNC HAL link has no offset table (" + offset.ToString() + ")");
}

Status LinuxCncLinkTransport::WriteOffset(const OffsetAddress& offset, double) {
  return Status::Failed("the LinuxCNC HAL link has no offset table (" + offset.ToString() + ")");
}

// ---- MeasureOnLinuxCnc ----

LinuxCncMeasureOptions::LinuxCncMeasureOptions() {
  program.dialect = Dialect::kLinuxCnc;
  program.layout = Layout::kPacked;
  program.base = 0;
  program.log_trips = true;
  // One touch at F300 from 1 mm: the points travel through the block, the controller's trip record
  // checks them (the trigger error, 5 µm at most, is not what this measures).
  program.probe.clearance_mm = 1.0;
  program.probe.search_mm = 1.0;
  program.probe.probe_feed_mm_per_min = 300;
  program.probe.safe_z_mm = std::numeric_limits<double>::quiet_NaN();
  program.probe.results_file = "probe_results.txt";
  collector.poll_s = 0.010;
  collector.reconnect_min_s = 0.2;  // the link's socket appears about 1 s after the start
  collector.reconnect_max_s = 1.0;
  collector.idle_timeout_s = 120;
}

bool LinuxCncMeasurement::ok() const {
  return run.ok && collector.ok && !collector_stopped && points_received == points_planned &&
         distinct_ids == points_planned && checked_against_trips == points_planned && max_difference_um <= kAgreeUm;
}

json LinuxCncMeasurement::ToJson() const {
  return {{"ok", ok()},
          {"points_planned", points_planned},
          {"points_received", points_received},
          {"distinct_ids", distinct_ids},
          {"checked_against_trips", checked_against_trips},
          {"max_difference_um", max_difference_um},
          {"collector_stopped_by_controller_end", collector_stopped},
          {"collector", collector.ToJson()},
          {"run", run.ToJson()}};
}

Result<LinuxCncMeasurement> MeasureOnLinuxCnc(const LinuxCncConfig& config, const metrology::ProbingPlan& plan,
                                              const LinuxCncMeasureOptions& options, const fs::path& out) {
  std::error_code ec;
  if (fs::exists(out, ec) && !fs::is_empty(out, ec)) {
    return Status::BadInput(Where{.file = out.string()}, "exists and is not empty", "give a new output folder");
  }
  if (std::atoi(config.Get("FORMLOOP", "LINK_PORTS").c_str()) < kLinuxCncLinkPorts) {
    return Status::BadInput(Where{.file = config.ini.string(), .field = "[FORMLOOP] LINK_PORTS"},
                            "the configuration has no handshake link", "write it again without --no-link");
  }
  MachineProgramOptions program = options.program;
  if (program.dialect != Dialect::kLinuxCnc || program.ResolvedBase() != 0 || program.layout != Layout::kPacked) {
    return Status::BadInput(Where{.field = "program"}, "the configuration's link is PACKED at LinuxCNC ports 0..3");
  }
  FL_ASSIGN_OR_RETURN(program.probe.post.limits, LimitsOf(config));
  if (!ParseDouble(config.Get("FORMLOOP", "PROBE_BALL_RADIUS_MM"), &program.probe.ball_radius_mm) ||
      !(program.probe.ball_radius_mm > 0)) {
    return Status::BadInput(Where{.file = config.ini.string(), .field = "[FORMLOOP] PROBE_BALL_RADIUS_MM"},
                            "the configuration has no probe surface");
  }
  if (program.probe.post.title.empty()) program.probe.post.title = "formloop handshake on LinuxCNC";
  if (std::isnan(program.probe.safe_z_mm)) {
    double top = -std::numeric_limits<double>::infinity();
    for (const auto& p : plan.points) top = std::max(top, ProbePathOf(p, program.probe).clearance[2]);
    program.probe.safe_z_mm = std::ceil(top + 5.0);
  }
  FL_ASSIGN_OR_RETURN(const MachineProgram written, WriteMachineProgram(plan, program));
  FL_RETURN_IF_ERROR(MakeDirectories(out));
  const fs::path program_path = out / MainProgramFileName(Dialect::kLinuxCnc);
  FL_RETURN_IF_ERROR(WriteFileAtomic(program_path, written.files.front().text));

  SocketFolder sockets;
  FL_RETURN_IF_ERROR(sockets.Make());
  LinuxCncRunOptions run_options = options.run;
  run_options.link_socket = sockets.socket();
  CollectorOptions collector = options.collector;
  collector.block = program.Block();
  if (collector.expect_points == 0) collector.expect_points = static_cast<int>(plan.points.size());
  if (collector.journal.empty()) collector.journal = out / "journal";

  // The controller in a thread, the collector here.
  std::atomic<bool> ended{false};
  Result<LinuxCncRunReport> run = Status::Internal("the controller did not run");
  std::thread controller([&] {
    run = RunOnLinuxCnc(config, program_path, out / "controller", run_options);
    ended = true;
  });
  LinuxCncMeasurement m;
  m.points_planned = static_cast<int>(plan.points.size());
  {
    LinuxCncLinkTransport transport(sockets.socket());
    StoppableClock clock(ended);
    try {
      auto collected = Collect(transport, clock, collector);
      if (!collected.ok()) {
        controller.join();
        return collected.status();
      }
      m.collector = std::move(collected).value();
    } catch (const ControllerEnded&) {
      m.collector_stopped = true;
      m.collector.ok = false;
      m.collector.fatal = "the controller ended before the run was collected";
      FL_ASSIGN_OR_RETURN(const Journal journal, Journal::Open(collector.journal, false));
      m.collector.sessions = journal.sessions();
    }
  }
  controller.join();
  if (!run.ok()) return run.status();
  m.run = std::move(run).value();

  FL_RETURN_IF_ERROR(WriteCollection(out / "collection.csv", m.collector.sessions));
  const Session* last = m.collector.sessions.empty() ? nullptr : &m.collector.sessions.back();
  if (last != nullptr) {
    std::set<int> ids;
    for (const auto& p : last->points) ids.insert(p.id);
    m.points_received = static_cast<int>(last->points.size());
    m.distinct_ids = static_cast<int>(ids.size());
    std::vector<int> skipped;
    FL_ASSIGN_OR_RETURN(m.log, ProbeLogOfSession(*last, plan, {}, program.probe.ball_radius_mm, &skipped));
    m.log.source = (out / "probe_log.csv").string();
    // The controller's own record: one trip per point, in order.
    auto trips = Trips(out / "controller" / program.probe.results_file);
    if (trips.ok()) {
      for (const auto& r : m.log.records) {
        if (r.id < 1 || r.id > static_cast<std::int64_t>(trips->size())) continue;
        const Eigen::Vector3d d = r.centre - (*trips)[static_cast<std::size_t>(r.id - 1)];
        m.max_difference_um = std::max(m.max_difference_um, 1e3 * d.cwiseAbs().maxCoeff());
        ++m.checked_against_trips;
      }
    }
    if (last->status == SessionStatus::kComplete) {
      FL_RETURN_IF_ERROR(metrology::WriteProbeLog(out / "probe_log.csv", m.log));
    }
  }
  log::Info(
      "linuxcnc link: {} of {} points received ({} distinct), {} checked against the controller's trips "
      "(largest difference {:.3f} um); collector {}",
      m.points_received, m.points_planned, m.distinct_ids, m.checked_against_trips, m.max_difference_um,
      m.collector.ok ? "ok" : m.collector.fatal);
  return m;
}

}  // namespace formloop::cnc
