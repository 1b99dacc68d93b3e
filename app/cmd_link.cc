// `formloop link`: the machine link (cnc/, spec/tuning-and-link.md §5, §7–8).
//
//   formloop link emulate --port N [--ready-file F] [--dialect fanuc] [--points 2000] [--runs 1]
//                         [--latency-ms 1 --jitter-ms 0.5] [faults ...] [--record R.csv]
//     an emulated controller as a separate process: macro memory, offset table, the machine side
//     running formloop's own measuring program, latency and fault injection; prints a JSON summary.
//   formloop link collect --address HOST:PORT --out P.csv [--expect N] [--runs R] [--journal J]
//     collects the points of R runs; restartable at any moment (the journal), progress on stderr,
//     a JSON summary with retries and points per second on stdout; exit 1 when a session is not
//     COMPLETE (lost points, aborted run), its points still written with their status.
//   formloop link write --address HOST:PORT --plan offsets.json --confirm
//     writes the confirmed offset write plan, reads every value back, rolls back on a mismatch.
//   formloop link program --plan probing_plan.json --dialect D --out DIR
//     writes the machine side of the handshake (Fanuc macro B, LinuxCNC O-codes, Sinumerik R).
//   formloop link check --dialect D FILE...
//     reads a machine-side program with formloop's reader of that dialect (every line checked).
//   formloop link selftest --address HOST:PORT
//     the commissioning self-test of the PACKED layout (§7.2).
//   formloop link alarm --address HOST:PORT --code N
//     writes the alarm request A (the measuring program raises DIMENSION NG at its next start while
//     A > 0); --code 0 clears it once the operator has acknowledged (§7.5).

#include <unistd.h>

#include <fmt/format.h>
#include <atomic>
#include <csignal>
#include <iostream>
#include <memory>
#include <nlohmann/json.hpp>
#include <sstream>
#include <string>
#include <vector>

#include "app/command.h"
#include "app/run_folder.h"
#include "cnc/collector.h"
#include "cnc/emulator_server.h"
#include "cnc/machine_program.h"
#include "cnc/tcp_transport.h"
#include "cnc/write_back.h"
#include "core/atomic_file.h"
#include "core/json_io.h"
#include "core/log.h"
#include "core/output_file.h"
#include "core/point_io.h"

namespace formloop::app {
namespace {

using namespace formloop::cnc;

Status Print(const nlohmann::json& json, const std::string& command) {
  std::cout << json.dump(2) << "\n";
  std::cout.flush();
  return std::cout ? Status::Ok() : Status::IoError(command + ": writing to stdout failed");
}

// "A:B[:C...]" into numbers; `what` names the option in messages.
Status SplitNumbers(const std::string& text, std::size_t count, const std::string& option, const std::string& form,
                    std::vector<std::string>* parts) {
  parts->clear();
  std::stringstream in(text);
  std::string item;
  while (std::getline(in, item, ':')) parts->push_back(item);
  if (parts->size() != count) return Status::BadInput(Where{.field = option}, "'" + text + "' is not " + form);
  return Status::Ok();
}

Status ToInt(const std::string& s, const std::string& option, int* out) {
  double v = 0;
  if (!ParseDouble(s, &v) || v != static_cast<int>(v)) {
    return Status::BadInput(Where{.field = option}, "'" + s + "' is not a whole number");
  }
  *out = static_cast<int>(v);
  return Status::Ok();
}

Status ToNumber(const std::string& s, const std::string& option, double* out) {
  if (!ParseDouble(s, out)) return Status::BadInput(Where{.field = option}, "'" + s + "' is not a number");
  return Status::Ok();
}

Result<PointAt> ParsePointAt(const std::string& text, const std::string& option) {
  std::vector<std::string> p;
  FL_RETURN_IF_ERROR(SplitNumbers(text, 2, option, "RUN:POINT", &p));
  PointAt at;
  FL_RETURN_IF_ERROR(ToInt(p[0], option, &at.run));
  FL_RETURN_IF_ERROR(ToInt(p[1], option, &at.point));
  return at;
}

// NAME=VALUE
Status ParseAssignment(const std::string& text, const std::string& option, std::string* name, double* value) {
  const auto eq = text.find('=');
  if (eq == std::string::npos) return Status::BadInput(Where{.field = option}, "'" + text + "' is not NAME=VALUE");
  *name = text.substr(0, eq);
  return ToNumber(text.substr(eq + 1), option, value);
}

// ---- emulate -------------------------------------------------------------------------------------

struct EmulateArgs {
  std::string host = "127.0.0.1";
  int port = 0;
  std::string ready_file, record;
  bool force = false;
  std::string dialect = "fanuc", layout = "packed", precision = "double", latency_dist = "uniform";
  int points = 100, runs = 1, base = -1;
  std::uint64_t seed = 1;
  double latency_ms = 0, jitter_ms = 0, spike_rate = 0, spike_ms = 0;
  double visibility_ms = 0, reorder_rate = 0, api_error_rate = 0, dropped_write_rate = 0;
  double connection_drop_rate = 0, half_open_rate = 0, repeat_rate = 0, skip_rate = 0;
  bool torn_reads = false, mantissa32 = false;
  double measure_ms = 50, dwell_ms = 20, run_gap_s = 0.2, restart_delay_s = 0.5, start_delay_s = 0;
  double arm_timeout_s = 60, ack_timeout_s = 10;
  double linger_s = 1, max_run_s = 0;
  std::vector<std::string> resets, corrupt, deviations, third_party, offsets, mismatch, reject, initial;
};

std::atomic<bool> g_stop{false};
extern "C" void OnStopSignal(int) { g_stop = true; }

Result<ControllerOptions> EmulatorOptions(const EmulateArgs& a) {
  ControllerOptions o;
  FL_ASSIGN_OR_RETURN(o.dialect, ParseDialect(a.dialect));
  o.program.dialect = o.dialect;
  FL_ASSIGN_OR_RETURN(o.program.layout, cnc::ParseLayout(a.layout));
  o.program.base = a.base;
  o.program.dwell_s = a.dwell_ms * 1e-3;
  o.program.arm_timeout_s = a.arm_timeout_s;
  o.program.ack_timeout_s = a.ack_timeout_s;
  o.program.probe.post.decimals = o.dialect == Dialect::kFanuc ? 3 : 4;
  o.points = a.points;
  o.runs = a.runs;
  o.seed = a.seed;
  if (a.precision == "digits8") {
    o.precision = Precision::kDigits8;
  } else if (a.precision != "double") {
    return Status::BadInput(Where{.field = "--precision"}, "'" + a.precision + "'", "use double or digits8");
  }
  if (a.jitter_ms > a.latency_ms) {
    return Status::BadInput(Where{.field = "--jitter-ms"},
                            "must not exceed --latency-ms (uniform in latency ± jitter)");
  }
  if (a.latency_dist == "uniform") {
    o.latency.base_s = (a.latency_ms - a.jitter_ms) * 1e-3;
    o.latency.jitter_s = 2 * a.jitter_ms * 1e-3;
  } else if (a.latency_dist == "lognormal") {
    o.latency.distribution = LatencyModel::Distribution::kLogNormal;
    o.latency.base_s = 0;
    o.latency.jitter_s = a.latency_ms * 1e-3;
  } else {
    return Status::BadInput(Where{.field = "--latency-dist"}, "'" + a.latency_dist + "'", "use uniform or lognormal");
  }
  o.latency.spike_rate = a.spike_rate;
  o.latency.spike_s = a.spike_ms * 1e-3;
  o.measure_time_s = a.measure_ms * 1e-3;
  o.run_gap_s = a.run_gap_s;
  o.restart_delay_s = a.restart_delay_s;
  o.start_delay_s = a.start_delay_s;
  ControllerFaults& f = o.faults;
  f.visibility_max_s = a.visibility_ms * 1e-3;
  f.reorder_rate = a.reorder_rate;
  f.api_error_rate = a.api_error_rate;
  f.dropped_write_rate = a.dropped_write_rate;
  f.connection_drop_rate = a.connection_drop_rate;
  f.half_open_rate = a.half_open_rate;
  f.repeat_rate = a.repeat_rate;
  f.skip_rate = a.skip_rate;
  f.torn_range_reads = a.torn_reads;
  f.api_mantissa32 = a.mantissa32;
  for (const auto& r : a.resets) {
    FL_ASSIGN_OR_RETURN(const PointAt at, ParsePointAt(r, "--reset-at"));
    f.resets.push_back(at);
  }
  for (const auto& r : a.corrupt) {
    FL_ASSIGN_OR_RETURN(const PointAt at, ParsePointAt(r, "--corrupt-at"));
    f.corrupt_data.push_back(at);
  }
  for (const auto& d : a.deviations) {
    std::vector<std::string> p;
    FL_RETURN_IF_ERROR(SplitNumbers(d, 4, "--deviation", "RUN:POINT:AXIS:MM (axis X, Y or Z)", &p));
    ControllerFaults::Deviation dev;
    FL_RETURN_IF_ERROR(ToInt(p[0], "--deviation", &dev.at.run));
    FL_RETURN_IF_ERROR(ToInt(p[1], "--deviation", &dev.at.point));
    if (p[2].size() != 1 || p[2][0] < 'X' || p[2][0] > 'Z')
      return Status::BadInput(Where{.field = "--deviation"}, "axis must be X, Y or Z");
    dev.axis = p[2][0] - 'X';
    FL_RETURN_IF_ERROR(ToNumber(p[3], "--deviation", &dev.value_mm));
    f.deviations.push_back(dev);
  }
  for (const auto& t : a.third_party) {
    std::vector<std::string> p;
    FL_RETURN_IF_ERROR(SplitNumbers(t, 4, "--third-party", "RUN:POINT:OFFSET:VALUE", &p));
    ControllerFaults::ThirdParty tp;
    FL_RETURN_IF_ERROR(ToInt(p[0], "--third-party", &tp.at.run));
    FL_RETURN_IF_ERROR(ToInt(p[1], "--third-party", &tp.at.point));
    FL_RETURN_IF_ERROR(ToInt(p[2], "--third-party", &tp.offset));
    FL_RETURN_IF_ERROR(ToNumber(p[3], "--third-party", &tp.value));
    f.third_party.push_back(tp);
  }
  for (const auto& s : a.offsets) {
    std::string name;
    double value = 0;
    FL_RETURN_IF_ERROR(ParseAssignment(s, "--offset", &name, &value));
    FL_RETURN_IF_ERROR(ParseOffsetAddress(name).status());
    OffsetEntry entry;
    entry.value_mm = value;
    if (name[0] == 'G') entry = OffsetEntry{value, -1000, 1000, 0.001};
    o.offsets[name] = entry;
  }
  for (const auto& s : a.mismatch) {
    std::string name;
    double value = 0;
    FL_RETURN_IF_ERROR(ParseAssignment(s, "--offset-mismatch", &name, &value));
    f.offset_mismatch[name] = value;
  }
  for (const auto& s : a.reject) f.offset_reject.insert(s);
  for (const auto& s : a.initial) {
    std::string name;
    double value = 0;
    FL_RETURN_IF_ERROR(ParseAssignment(s, "--initial", &name, &value));
    int address = 0;
    FL_RETURN_IF_ERROR(ToInt(name, "--initial", &address));
    o.initial_values[address] = value;
  }
  FL_RETURN_IF_ERROR(o.Validate());
  return o;
}

Status Emulate(const EmulateArgs& a) {
  FL_ASSIGN_OR_RETURN(const ControllerOptions options, EmulatorOptions(a));
  FL_RETURN_IF_ERROR(CheckOutputFiles({{"--ready-file", a.ready_file}, {"--record", a.record}}, {}, a.force));
  EmulatorServerOptions so;
  so.host = a.host;
  so.port = a.port;
  so.linger_s = a.linger_s;
  so.max_run_s = a.max_run_s;
  FL_ASSIGN_OR_RETURN(auto server, EmulatorServer::Start(options, so));
  const std::string address = a.host + ":" + std::to_string(server->port());
  if (!a.ready_file.empty()) {
    FL_RETURN_IF_ERROR(WriteJsonFile(
        a.ready_file,
        {{"address", address}, {"port", server->port()}, {"pid", ::getpid()}, {"generator", kGeneratorName}}));
  }
  log::Info("link emulate: {} controller on {}, {} runs of {} points, block {}{} ({})", a.dialect, address, a.runs,
            a.points, a.dialect == "sinumerik" ? "R" : (a.dialect == "linuxcnc" ? "E" : "#"),
            server->controller().block().base, a.layout);
  g_stop = false;
  std::signal(SIGTERM, OnStopSignal);
  std::signal(SIGINT, OnStopSignal);
  FL_RETURN_IF_ERROR(server->Run(&g_stop));
  const Controller& c = server->controller();
  if (!a.record.empty()) FL_RETURN_IF_ERROR(c.WriteRecord(a.record));
  nlohmann::json alarms = nlohmann::json::array();
  for (const auto& al : c.alarms())
    alarms.push_back({{"run", al.run}, {"number", al.number}, {"text", al.text}, {"where", al.where}});
  nlohmann::json faults = nlohmann::json::object();
  for (const auto& [name, count] : c.fault_counts()) faults[name] = count;
  nlohmann::json offsets = nlohmann::json::object();
  for (const auto& s : a.offsets) {
    const std::string name = s.substr(0, s.find('='));
    offsets[name] = *c.PeekOffset(name);
  }
  FL_RETURN_IF_ERROR(Print({{"address", address},
                            {"runs_started", c.runs_started()},
                            {"runs_completed", c.runs_completed()},
                            {"handovers", c.record().size()},
                            {"requests", server->requests()},
                            {"alarms", alarms},
                            {"messages", c.messages()},
                            {"faults_injected", faults},
                            {"offsets_mm", offsets},
                            {"stopped_by_signal", g_stop.load()}},
                           "link emulate"));
  if (c.runs_completed() < options.runs || !c.alarms().empty()) {
    return Status::Failed("link emulate: " + std::to_string(c.runs_completed()) + " of " +
                          std::to_string(options.runs) + " runs completed" +
                          (c.alarms().empty() ? ""
                                              : ", the program stopped in alarm " +
                                                    std::to_string(c.alarms()[0].number) + " " + c.alarms()[0].text));
  }
  return Status::Ok();
}

// ---- collect / selftest --------------------------------------------------------------------------

struct BlockArgs {
  std::string dialect = "fanuc", layout = "packed";
  int base = -1;
  Result<BlockLayout> Block() const {
    MachineProgramOptions p;
    FL_ASSIGN_OR_RETURN(p.dialect, ParseDialect(dialect));
    FL_ASSIGN_OR_RETURN(p.layout, cnc::ParseLayout(layout));
    p.base = base;
    return p.Block();
  }
  void Add(CLI::App* app) {
    app->add_option("--dialect", dialect,
                    "controller dialect: where the block lives by default (fanuc #900, linuxcnc E0, sinumerik R90)")
        ->capture_default_str();
    app->add_option("--layout", layout, "block layout: packed (C, D, Q, A) or split (C, v_x, v_y, v_z, Q, A)")
        ->capture_default_str();
    app->add_option("--base", base, "first address of the block (-1: the dialect's default)")->capture_default_str();
  }
};

struct CollectArgs {
  std::string address, out, journal, plan, probe_log;
  bool force = false;
  BlockArgs block;
  int expect = 0, runs = 1;
  double poll_ms = 10, visibility_timeout_s = 2, idle_timeout_s = 600, reconnect_min_s = 0.5, reconnect_max_s = 8;
  double call_timeout_s = 1, ball_radius_mm = 1.0;
  bool stop_on_range = false, no_fsync = false;
};

Status WriteProbeLogOf(const CollectArgs& a, const std::vector<Session>& sessions) {
  FL_ASSIGN_OR_RETURN(const PlanWithApproaches plan, ReadPlanFile(a.plan));
  const Session* last = nullptr;
  for (const auto& s : sessions) {
    if (s.status == SessionStatus::kComplete) last = &s;
  }
  if (last == nullptr) return Status::Failed("link collect: no COMPLETE session, no probe log written");
  std::vector<int> skipped;
  auto log = ProbeLogOfSession(*last, plan.plan, plan.approaches, a.ball_radius_mm, &skipped);
  if (!log.ok()) return Status::BadInput(Where{.file = a.plan}, log.status().message());
  if (!skipped.empty()) log::Warn("link collect: {} out-of-range points left out of the probe log", skipped.size());
  return metrology::WriteProbeLog(a.probe_log, *log);
}

Status CollectCommand(const CollectArgs& a) {
  std::string host;
  int port = 0;
  FL_RETURN_IF_ERROR(ParseAddress(a.address, &host, &port));
  if (!a.probe_log.empty() && a.plan.empty()) return Status::BadInput(Where{.field = "--probe-log"}, "needs --plan");
  CollectorOptions o;
  FL_ASSIGN_OR_RETURN(o.block, a.block.Block());
  o.expect_points = a.expect;
  o.runs = a.runs;
  o.poll_s = a.poll_ms * 1e-3;
  o.poll_slow_s = std::max(o.poll_s, 0.1);
  o.visibility_timeout_s = a.visibility_timeout_s;
  o.idle_timeout_s = a.idle_timeout_s;
  o.reconnect_min_s = a.reconnect_min_s;
  o.reconnect_max_s = a.reconnect_max_s;
  o.stop_on_range = a.stop_on_range;
  o.journal = a.journal.empty() ? a.out + ".journal" : a.journal;
  o.fsync = !a.no_fsync;
  o.progress = true;
  // No output onto an input or onto another output (core/output_folder.h).
  FL_RETURN_IF_ERROR(CheckOutputsNotInputs({{"--out", a.out}, {"--journal", o.journal}, {"--probe-log", a.probe_log}},
                                           {{"--plan", a.plan}}));
  // The journal is resumed on purpose (cnc/journal.h refuses a file that is not one); the others are outputs.
  FL_RETURN_IF_ERROR(CheckOutputFiles({{"--out", a.out}, {"--probe-log", a.probe_log}}, {}, a.force));
  TcpTransport transport(host, port, TcpTransportOptions{2.0, a.call_timeout_s});
  RealClock clock;
  FL_ASSIGN_OR_RETURN(const CollectorReport report, Collect(transport, clock, o));
  FL_RETURN_IF_ERROR(WriteCollection(a.out, report.sessions));
  if (!a.probe_log.empty()) FL_RETURN_IF_ERROR(WriteProbeLogOf(a, report.sessions));
  nlohmann::json json = report.ToJson();
  json["out"] = a.out;
  json["journal"] = o.journal.string();
  const auto& c = report.counters;
  log::Info(
      "link collect: {} points in {:.2f} s ({:.1f} points/s by this process); retries: {} reads and {} writes in all, "
      "{} refused "
      "calls, {} lost connections, {} reconnects, {} lost writes made again",
      report.points_total(), report.elapsed_s, report.points_per_s(), c.reads, c.writes, c.api_errors,
      c.connection_errors, c.reconnects, c.lost_writes);
  FL_RETURN_IF_ERROR(Print(json, "link collect"));
  if (!report.ok) return Status::Failed("link collect: " + report.fatal);
  // A session that lost points or was aborted is the job's own failure (exit 1): its points are in OUT
  // with the session's status, but nothing downstream may take it for a whole measurement (spec §7.5).
  std::string unfinished;
  for (const auto& s : report.sessions) {
    if (s.status == SessionStatus::kComplete) continue;
    unfinished += fmt::format("{}run Q={} {}", unfinished.empty() ? "" : "; ", s.q, SessionStatusName(s.status));
    for (const auto& e : s.errors) unfinished += " (" + e + ")";
  }
  if (!unfinished.empty()) return Status::Failed("link collect: not every session is COMPLETE: " + unfinished);
  return Status::Ok();
}

struct SelfTestArgs {
  std::string address;
  BlockArgs block;
};

Status SelfTestCommand(const SelfTestArgs& a) {
  std::string host;
  int port = 0;
  FL_RETURN_IF_ERROR(ParseAddress(a.address, &host, &port));
  FL_ASSIGN_OR_RETURN(const BlockLayout block, a.block.Block());
  TcpTransport transport(host, port);
  FL_ASSIGN_OR_RETURN(const SelfTestReport r, RunSelfTest(transport, block));
  nlohmann::json pairs = nlohmann::json::array();
  for (const auto& [w, b] : r.written_read) pairs.push_back({{"written", w}, {"read", b}});
  FL_RETURN_IF_ERROR(Print({{"passed", r.passed}, {"values", pairs}, {"message", r.message}}, "link selftest"));
  return r.passed ? Status::Ok() : Status::Failed("link selftest: " + r.message);
}

struct AlarmArgs {
  std::string address;
  BlockArgs block;
  int code = 0;
};

// A has a single writer, the collector side, and lies outside the critical section (R3): written and
// read back, whatever the token does.
Status AlarmCommand(const AlarmArgs& a) {
  std::string host;
  int port = 0;
  FL_RETURN_IF_ERROR(ParseAddress(a.address, &host, &port));
  if (a.code < 0 || a.code > 9999) return Status::BadInput(Where{.field = "--code"}, "must be 0 (clear) .. 9999");
  FL_ASSIGN_OR_RETURN(const BlockLayout block, a.block.Block());
  TcpTransport transport(host, port);
  FL_RETURN_IF_ERROR(transport.Connect());
  FL_RETURN_IF_ERROR(transport.Write(block.alarm(), a.code));
  FL_ASSIGN_OR_RETURN(const auto back, transport.ReadRange(block.alarm(), 1));
  const bool ok = back.size() == 1 && back[0] && *back[0] == a.code;
  FL_RETURN_IF_ERROR(
      Print({{"address", block.alarm()}, {"alarm_request", a.code}, {"read_back_ok", ok}}, "link alarm"));
  return ok ? Status::Ok() : Status::Failed("link alarm: the alarm request did not read back as written");
}

// ---- write ---------------------------------------------------------------------------------------

struct WriteArgs {
  std::string address, plan;
  bool confirm = false;
  double call_timeout_s = 2;
};

Status WriteCommand(const WriteArgs& a) {
  std::string host;
  int port = 0;
  FL_RETURN_IF_ERROR(ParseAddress(a.address, &host, &port));
  FL_ASSIGN_OR_RETURN(const WritePlan plan, ReadWritePlan(a.plan));
  TcpTransport transport(host, port, TcpTransportOptions{2.0, a.call_timeout_s});
  FL_ASSIGN_OR_RETURN(const WriteBackReport report, WriteBack(transport, plan, a.confirm));
  nlohmann::json json = report.ToJson();
  json["plan"] = a.plan;
  json["session"] = plan.session;
  FL_RETURN_IF_ERROR(Print(json, "link write"));
  if (report.outcome == "REFUSED") {
    return Status::SafetyLimit("link write: refused, nothing was sent: " + report.reasons.front());
  }
  if (!report.ok()) return Status::Failed("link write: " + report.outcome + ": " + report.reasons.front());
  return Status::Ok();
}

// ---- program / check -----------------------------------------------------------------------------

struct ProgramArgs {
  std::string plan, out, dialect = "fanuc", layout = "packed", title;
  int base = -1, decimals = -1;
  double dwell_ms = 20, ball_radius_mm = 1, clearance_mm = 3, search_mm = 2, feed = 200, safe_z_mm = 50;
  double arm_timeout_s = 60, ack_timeout_s = 10;
  bool force = false;
};

Status ProgramCommand(const ProgramArgs& a) {
  FL_RETURN_IF_ERROR(CheckOutputsNotInputs({}, {{"--plan", a.plan}}, {{"--out", a.out}}));
  FL_ASSIGN_OR_RETURN(const PlanWithApproaches plan, ReadPlanFile(a.plan));
  MachineProgramOptions o;
  FL_ASSIGN_OR_RETURN(o.dialect, ParseDialect(a.dialect));
  FL_ASSIGN_OR_RETURN(o.layout, cnc::ParseLayout(a.layout));
  o.base = a.base;
  o.dwell_s = a.dwell_ms * 1e-3;
  o.arm_timeout_s = a.arm_timeout_s;
  o.ack_timeout_s = a.ack_timeout_s;
  o.probe.ball_radius_mm = a.ball_radius_mm;
  o.probe.clearance_mm = a.clearance_mm;
  o.probe.search_mm = a.search_mm;
  o.probe.probe_feed_mm_per_min = a.feed;
  o.probe.safe_z_mm = a.safe_z_mm;
  o.probe.post.title = a.title;
  o.probe.post.decimals = a.decimals >= 0 ? a.decimals : (o.dialect == Dialect::kFanuc ? 3 : 4);
  FL_ASSIGN_OR_RETURN(const MachineProgram program, WriteMachineProgram(plan.plan, o));
  FL_RETURN_IF_ERROR(ReadMacroProgram(o.dialect, program.files)
                         .status()
                         .WithContext("link program: the written program does not read back"));
  // The folder may hold the shop's own programs: a file of the same name is replaced only with --force and
  // only when formloop wrote it (core/output_file.h), checked for every file before any is written.
  for (const auto& f : program.files) {
    FL_RETURN_IF_ERROR(CheckReplaceable(std::filesystem::path(a.out) / f.name, a.force, "--out"));
  }
  FL_RETURN_IF_ERROR(MakeDirectories(a.out));
  nlohmann::json files = nlohmann::json::array();
  for (const auto& f : program.files) {
    const auto path = std::filesystem::path(a.out) / f.name;
    FL_RETURN_IF_ERROR(WriteFileAtomic(path, f.text));
    files.push_back(path.string());
  }
  return Print({{"dialect", a.dialect},
                {"points", program.points},
                {"block_base", program.block.base},
                {"layout", a.layout},
                {"files", files}},
               "link program");
}

struct CheckArgs {
  std::string dialect = "fanuc";
  std::vector<std::string> files;
  int r_last = 99, ports = 4;
};

Status CheckCommand(const CheckArgs& a) {
  FL_ASSIGN_OR_RETURN(const Dialect d, ParseDialect(a.dialect));
  std::vector<MacroFile> files;
  for (const auto& f : a.files) {
    FL_ASSIGN_OR_RETURN(std::string text, ReadFile(f));
    files.push_back({std::filesystem::path(f).filename().string(), std::move(text)});
  }
  MacroLimits limits;
  limits.sinumerik_r_last = a.r_last;
  limits.linuxcnc_ports = a.ports;
  FL_ASSIGN_OR_RETURN(const MacroCode code, ReadMacroProgram(d, files, limits));
  return Print(
      {{"ok", true}, {"dialect", a.dialect}, {"instructions", code.instrs.size()}, {"points", code.marks.size()}},
      "link check");
}

}  // namespace

void AddLinkCommand(CLI::App& root, CommandAction* action) {
  CLI::App* link = root.add_subcommand(
      "link",
      "The machine link: macro-variable handshake, emulated controller, collection, confirmed offset write-back.");
  link->require_subcommand(1);

  auto e = std::make_shared<EmulateArgs>();
  CLI::App* emulate = link->add_subcommand(
      "emulate",
      "Run an emulated controller (macro memory, offsets, the measuring program, latency, faults) on a TCP port.");
  emulate->add_option("--port", e->port, "TCP port; 0 = a free one (written to --ready-file)")->required();
  emulate->add_option("--host", e->host, "address to listen on")->capture_default_str();
  emulate->add_option("--ready-file", e->ready_file, "JSON file written once the port is open: {address, port, pid}");
  emulate->add_option("--record", e->record, "CSV of every point the program handed over (the emulator's own record)");
  AddForceFlag(emulate, &e->force);
  emulate->add_option("--dialect", e->dialect, "machine-side program: fanuc, linuxcnc or sinumerik")
      ->capture_default_str();
  emulate->add_option("--layout", e->layout, "block layout: packed or split")->capture_default_str();
  emulate->add_option("--base", e->base, "block base address (-1: the dialect's default)")->capture_default_str();
  emulate->add_option("--points", e->points, "points per run, 1..2000")->capture_default_str();
  emulate->add_option("--runs", e->runs, "runs of the measuring program")->capture_default_str();
  emulate->add_option("--seed", e->seed, "seed of the deviations and of every fault draw")->capture_default_str();
  emulate->add_option("--latency-ms", e->latency_ms, "API call latency, ms (uniform: its mean; lognormal: its median)")
      ->capture_default_str();
  emulate->add_option("--jitter-ms", e->jitter_ms, "uniform latency in latency ± jitter, ms")->capture_default_str();
  emulate->add_option("--latency-dist", e->latency_dist, "uniform or lognormal")->capture_default_str();
  emulate->add_option("--spike-rate", e->spike_rate, "probability of a latency spike per call")->capture_default_str();
  emulate->add_option("--spike-ms", e->spike_ms, "size of a spike, ms")->capture_default_str();
  emulate->add_option("--measure-ms", e->measure_ms, "time of one probing move, ms")->capture_default_str();
  emulate->add_option("--dwell-ms", e->dwell_ms, "the program's dwell per look at C (t_dwell), ms")
      ->capture_default_str();
  emulate->add_option("--arm-timeout-s", e->arm_timeout_s, "T_arm of the program")->capture_default_str();
  emulate->add_option("--ack-timeout-s", e->ack_timeout_s, "T_ack of the program")->capture_default_str();
  emulate->add_option("--run-gap-s", e->run_gap_s, "pause between runs")->capture_default_str();
  emulate->add_option("--restart-delay-s", e->restart_delay_s, "reset to cycle start")->capture_default_str();
  emulate->add_option("--start-delay-s", e->start_delay_s, "before the first run starts")->capture_default_str();
  emulate->add_option("--visibility-ms", e->visibility_ms, "machine writes become visible after U(0, this), ms")
      ->capture_default_str();
  emulate->add_option("--reorder-rate", e->reorder_rate, "per point: C visible before D")->capture_default_str();
  emulate->add_option("--api-error-rate", e->api_error_rate, "per call: an error code, nothing applied")
      ->capture_default_str();
  emulate->add_option("--drop-write-rate", e->dropped_write_rate, "per write: reported OK, not applied")
      ->capture_default_str();
  emulate->add_option("--drop-connection-rate", e->connection_drop_rate, "per call: the connection is closed")
      ->capture_default_str();
  emulate->add_option("--half-open-rate", e->half_open_rate, "per call: the connection stops answering")
      ->capture_default_str();
  emulate->add_flag("--torn-reads", e->torn_reads,
                    "range reads one address at a time with the machine running in between");
  emulate->add_option("--repeat-rate", e->repeat_rate, "per point: the program sends the point again")
      ->capture_default_str();
  emulate->add_option("--skip-rate", e->skip_rate, "per point: the program skips the next point")
      ->capture_default_str();
  emulate->add_option("--reset-at", e->resets, "RUN:POINT: controller reset before probing that point");
  emulate->add_option("--corrupt-at", e->corrupt, "RUN:POINT: that point's data word is written + 0.5");
  emulate->add_option("--deviation", e->deviations, "RUN:POINT:AXIS:MM: the probe measures this deviation there");
  emulate->add_option("--third-party", e->third_party,
                      "RUN:POINT:OFFSET:VALUE: written into the block after that point's hand-over");
  emulate->add_option("--precision", e->precision, "double or digits8 (8 significant digits kept)")
      ->capture_default_str();
  emulate->add_flag("--mantissa32", e->mantissa32, "API values pass a 32-bit mantissa + decimal exponent");
  emulate->add_option("--offset", e->offsets, "NAME=VALUE: initial offset (T3.radius_wear=0.085, G54.X=-120)");
  emulate->add_option("--offset-mismatch", e->mismatch,
                      "NAME=DELTA: the first write to that offset stores the written value + DELTA");
  emulate->add_option("--offset-reject", e->reject, "NAME: writes to that offset are refused");
  emulate->add_option("--initial", e->initial, "ADDRESS=VALUE: memory at power-on (stale values)");
  emulate->add_option("--linger-s", e->linger_s, "keep answering this long after the last run")->capture_default_str();
  emulate->add_option("--max-run-s", e->max_run_s, "stop after this long (0: no limit)")->capture_default_str();
  emulate->callback([action, e] { *action = [e] { return Emulate(*e); }; });

  auto c = std::make_shared<CollectArgs>();
  CLI::App* collect = link->add_subcommand(
      "collect",
      "Collect the points of the measuring program through the handshake; restartable from its journal at any moment.");
  collect->add_option("--address", c->address, "controller HOST:PORT")->required();
  collect->add_option("--out", c->out, "CSV of the collected points (written when the collection ends)")->required();
  collect->add_option("--journal", c->journal, "journal (default: OUT.journal); keep it to resume after a crash");
  collect->add_option("--expect", c->expect, "points per run the model expects (0: as the program says)")
      ->capture_default_str();
  collect->add_option("--runs", c->runs, "finished runs to collect")->capture_default_str();
  c->block.Add(collect);
  collect->add_option("--poll-ms", c->poll_ms, "t_poll: interval of the range reads, ms")->capture_default_str();
  collect->add_option("--visibility-timeout-s", c->visibility_timeout_s, "T_vis")->capture_default_str();
  collect->add_option("--idle-timeout-s", c->idle_timeout_s, "give up after this long without a change (0: never)")
      ->capture_default_str();
  collect->add_option("--reconnect-min-s", c->reconnect_min_s, "first reconnect backoff")->capture_default_str();
  collect->add_option("--reconnect-max-s", c->reconnect_max_s, "largest reconnect backoff")->capture_default_str();
  collect->add_option("--call-timeout-s", c->call_timeout_s, "a call without an answer by then fails")
      ->capture_default_str();
  collect->add_flag("--stop-on-range", c->stop_on_range, "answer an out-of-range point with ABORT");
  collect->add_flag("--no-fsync", c->no_fsync, "do not flush the journal to disk per point (measurements only)");
  collect->add_option("--plan", c->plan, "probing plan (JSON or CSV) of the measuring program, for --probe-log");
  collect->add_option("--probe-log", c->probe_log, "probe log (id,x,y,z,ax,ay,az,t) of the last COMPLETE run");
  AddForceFlag(collect, &c->force);
  collect->add_option("--ball-radius-mm", c->ball_radius_mm, "stylus ball radius the program was written for")
      ->capture_default_str();
  collect->callback([action, c] { *action = [c] { return CollectCommand(*c); }; });

  auto w = std::make_shared<WriteArgs>();
  CLI::App* write = link->add_subcommand(
      "write", "Write a confirmed offset write plan (formloop tune), read every value back, roll back on a mismatch.");
  write->add_option("--address", w->address, "controller HOST:PORT")->required();
  write->add_option("--plan", w->plan, "offset write plan (formloop.offset_write_plan JSON)")->required();
  write->add_flag("--confirm", w->confirm, "the operator confirms this write (without it nothing is sent)");
  write->add_option("--call-timeout-s", w->call_timeout_s, "a call without an answer by then fails")
      ->capture_default_str();
  write->callback([action, w] { *action = [w] { return WriteCommand(*w); }; });

  auto p = std::make_shared<ProgramArgs>();
  CLI::App* program = link->add_subcommand(
      "program",
      "Write the machine side of the handshake for a probing plan: Fanuc macro B, LinuxCNC O-codes or Sinumerik R.");
  program->add_option("--plan", p->plan, "probing plan (JSON or CSV), ids 1..N, N <= 2000")->required();
  program->add_option("--out", p->out, "folder for the program file(s)")->required();
  AddForceFlag(program, &p->force);
  program->add_option("--dialect", p->dialect, "fanuc, linuxcnc or sinumerik")->capture_default_str();
  program->add_option("--layout", p->layout, "packed or split")->capture_default_str();
  program->add_option("--base", p->base, "block base address (-1: the dialect's default)")->capture_default_str();
  program->add_option("--dwell-ms", p->dwell_ms, "t_dwell, ms")->capture_default_str();
  program->add_option("--arm-timeout-s", p->arm_timeout_s, "T_arm")->capture_default_str();
  program->add_option("--ack-timeout-s", p->ack_timeout_s, "T_ack")->capture_default_str();
  program->add_option("--ball-radius-mm", p->ball_radius_mm, "stylus ball radius")->capture_default_str();
  program->add_option("--clearance-mm", p->clearance_mm, "start of the probing move outside the surface")
      ->capture_default_str();
  program->add_option("--search-mm", p->search_mm, "end of the probing move inside the surface")->capture_default_str();
  program->add_option("--feed", p->feed, "probing feed, mm/min")->capture_default_str();
  program->add_option("--safe-z-mm", p->safe_z_mm, "rapids between points")->capture_default_str();
  program->add_option("--decimals", p->decimals, "coordinate decimals (-1: 3 for Fanuc IS-B, else 4)")
      ->capture_default_str();
  program->add_option("--title", p->title, "a comment line in the program");
  program->callback([action, p] { *action = [p] { return ProgramCommand(*p); }; });

  auto k = std::make_shared<CheckArgs>();
  CLI::App* check = link->add_subcommand(
      "check", "Read a machine-side program with formloop's reader of its dialect; every line is checked.");
  check->add_option("--dialect", k->dialect, "fanuc, linuxcnc or sinumerik")->capture_default_str();
  check->add_option("files", k->files, "program file(s); Sinumerik: the MPF first, then its SPF files")->required();
  check->add_option("--r-last", k->r_last, "Sinumerik: highest R parameter (MD28050 - 1)")->capture_default_str();
  check->add_option("--ports", k->ports, "LinuxCNC: motion.num_aio")->capture_default_str();
  check->callback([action, k] { *action = [k] { return CheckCommand(*k); }; });

  auto al = std::make_shared<AlarmArgs>();
  CLI::App* alarm = link->add_subcommand(
      "alarm", "Write the alarm request A (0 clears it): the measuring program alarms at its next start while A > 0.");
  alarm->add_option("--address", al->address, "controller HOST:PORT")->required();
  alarm->add_option("--code", al->code, "alarm code, 1..9999; 0 clears")->required();
  al->block.Add(alarm);
  alarm->callback([action, al] { *action = [al] { return AlarmCommand(*al); }; });

  auto s = std::make_shared<SelfTestArgs>();
  CLI::App* selftest =
      link->add_subcommand("selftest", "Commissioning self-test: can the data word carry 36 bits exactly?");
  selftest->add_option("--address", s->address, "controller HOST:PORT")->required();
  s->block.Add(selftest);
  selftest->callback([action, s] { *action = [s] { return SelfTestCommand(*s); }; });
}

}  // namespace formloop::app
