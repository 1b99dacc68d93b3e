#pragma once
// The handshake of spec/tuning-and-link.md §7 over LinuxCNC's HAL (issue 25): formloop's machine-side
// program (cnc/machine_program.h, dialect linuxcnc) runs on the controller, formloop's collector
// (cnc/collector.h) runs beside it, and the variable block lives in HAL.
//
// The block. Address k is analog port k: the program writes it with M68 E<k> Q<value>
// (motion.analog-out-k) and commits the write by toggling motion.digital-out-k (M64/M65 P<k>, its level
// read back on motion.digital-in-k with M66 P<k> L0); it reads address k with M66 E<k> L0
// (motion.analog-in-k → #5399). The configuration's link component (cnc/linuxcnc_link.py, loaded by
// formloop.hal) keeps one register per port, the last value written by either side, drives
// motion.analog-in-k with it and answers the collector on a Unix socket, so the block behaves as shared
// variables. HAL floats are doubles: the 36-bit PACKED data word travels exact. HAL carries levels, not
// events: the commit bit makes each machine write an event, so a write of the value written last (equal
// data of consecutive points, a program restarted after sending point 1 that sends POINT_READY(1) again
// after the collector acknowledged it) arrives as any other. The component holds no protocol: the
// words are the collector's to interpret, through the link's one implementation (cnc/collector.h).
//
// LinuxCncLinkTransport is the collector's MacroTransport to that socket (addresses = ports; no offset
// table: ReadOffset/WriteOffset are refused). MeasureOnLinuxCnc runs a whole measurement: the program, the
// controller (cnc/linuxcnc_run.h) in a thread, the collector in this one, and checks what arrived against
// the controller's own record of every probe trip (PROBEOPEN).

#include <filesystem>
#include <nlohmann/json.hpp>
#include <string>

#include "cnc/collector.h"
#include "cnc/linuxcnc_config.h"
#include "cnc/linuxcnc_run.h"
#include "cnc/machine_program.h"
#include "cnc/transport.h"
#include "core/status.h"
#include "metrology/probe.h"

namespace formloop::cnc {

class LinuxCncLinkTransport final : public MacroTransport {
 public:
  explicit LinuxCncLinkTransport(std::filesystem::path socket, double call_timeout_s = 1.0);
  ~LinuxCncLinkTransport() override;
  LinuxCncLinkTransport(const LinuxCncLinkTransport&) = delete;
  LinuxCncLinkTransport& operator=(const LinuxCncLinkTransport&) = delete;
  Status Connect() override;
  void Disconnect() override;
  Result<std::vector<MacroValue>> ReadRange(int start, int count) override;
  Status WriteRange(int start, const std::vector<double>& values) override;
  Result<double> ReadOffset(const OffsetAddress& offset) override;
  Status WriteOffset(const OffsetAddress& offset, double value_mm) override;
  std::string Describe() const override { return "LinuxCNC HAL link " + socket_.string(); }

 private:
  Result<std::string> Call(const std::string& request);
  std::filesystem::path socket_;
  double call_timeout_s_;
  int fd_ = -1;
  std::string inbox_;
};

struct LinuxCncMeasureOptions {
  MachineProgramOptions program;  // dialect linuxcnc, PACKED, base 0 (the configuration's link ports)
  CollectorOptions collector;     // journal: out/journal unless given; expect_points: the plan's
  LinuxCncRunOptions run;
  LinuxCncMeasureOptions();
};

struct LinuxCncMeasurement {
  LinuxCncRunReport run;
  CollectorReport collector;
  bool collector_stopped = false;  // the controller ended before the collector had the run
  int points_planned = 0;
  int points_received = 0;        // in the last session
  int distinct_ids = 0;           // of them
  int checked_against_trips = 0;  // points compared with the PROBEOPEN record
  double max_difference_um = 0;   // |received centre − recorded trip|, largest
  metrology::ProbeLog log;        // the last COMPLETE session as a probe log
  bool ok() const;                // run and collector ok, every planned point once, all agreeing with the trips
  nlohmann::json ToJson() const;
};

// Writes out/measure.ngc (the machine-side program), runs it on `config` in out/controller while the
// collector takes the points (out/journal, out/collection.csv), and writes out/probe_log.csv. `out` must
// not exist or be empty. The configuration needs its link ([FORMLOOP] LINK_PORTS ≥ 4) and the plan ids
// 1..N in order. A non-ok Result only when nothing could run; see LinuxCncMeasurement::ok().
Result<LinuxCncMeasurement> MeasureOnLinuxCnc(const LinuxCncConfig& config, const metrology::ProbingPlan& plan,
                                              const LinuxCncMeasureOptions& options, const std::filesystem::path& out);

}  // namespace formloop::cnc
