#pragma once
// The emulated controller (spec/tuning-and-link.md §8): macro-variable memory with consecutive-range
// reads and writes, an offset table, the machine side running formloop's own machine-side program
// (cnc/machine_program.h) through the dialect's interpreter, configurable latency, visibility delays
// and fault injection, and the controller's own record of every point the program handed over.
//
// Everything runs on an EventScheduler (cnc/clock.h): in-process under virtual time (VirtualLink, the
// deterministic tests), or in the `formloop link emulate` process from a real clock (EmulatorServer).
// Every random draw comes from one seeded Rng in a fixed order per call, so a virtual run is
// reproducible bit for bit.
//
// Memory model. Addresses hold a double or nothing (vacant). A write through the API is visible at
// once. A write by the machine program to the block becomes visible to the API after a visibility
// delay drawn in [0, visibility_max_s] (its scratch variables carry no delay of their own); the writes
// of the program become visible in the order it made them (FIFO) unless the reorder fault moves one
// handover's control word ahead of its data. The program itself
// reads its own writes (as an NC does). Precision modes round every stored value to 8 significant
// digits, or pass API values through a 32-bit mantissa with a decimal exponent (FOCAS's ODBM).
//
// Faults (all optional, seeded):
//   API        error codes (nothing applied), dropped writes (reported OK, not applied), connection
//              drops and half-open connections (the call may or may not have been applied), latency
//              = base + jitter (uniform or log-normal) with rare spikes, torn range reads (one address
//              at a time across the call, the machine running in between: a writer inside the
//              critical section during a read)
//   machine    visibility delay, C visible before D, a repeated point id (the program restarted at the
//              point's block after its acknowledgement), a skipped point id (block skip), a controller
//              reset mid-measurement (volatile variables cleared, program restarted after a delay),
//              a third party writing into the block while the collector holds the token, a data word
//              that is not a whole number, deviations ≥ 0.1 mm (the program writes OVERFLOW), vacant or
//              stale values at start
//   offsets    writes refused for named offsets, a first write that stores another value than written

#include <array>
#include <cstdint>
#include <deque>
#include <functional>
#include <map>
#include <memory>
#include <set>
#include <string>
#include <unordered_map>
#include <vector>

#include "cnc/api.h"
#include "cnc/clock.h"
#include "cnc/handshake.h"
#include "cnc/machine_program.h"
#include "cnc/macro_interpreter.h"
#include "cnc/transport.h"
#include "core/random.h"
#include "core/status.h"
#include "metrology/probe.h"

namespace formloop::cnc {

struct LatencyModel {
  enum class Distribution { kUniform, kLogNormal };
  Distribution distribution = Distribution::kUniform;
  double base_s = 0;      // fixed part
  double jitter_s = 0;    // uniform: U(0, jitter); log-normal: median jitter, σ(ln) = 0.5
  double spike_rate = 0;  // probability of a spike per call
  double spike_s = 0;     // added on a spike
  double Draw(Rng& rng) const;
  Status Validate() const;
};

enum class Precision { kDouble, kDigits8 };

struct PointAt {
  int run = 1;    // 1-based program start
  int point = 1;  // point id
};

struct ControllerFaults {
  double api_error_rate = 0;
  double dropped_write_rate = 0;
  double connection_drop_rate = 0;
  double half_open_rate = 0;
  bool torn_range_reads = false;
  bool api_mantissa32 = false;
  double visibility_max_s = 0;
  double reorder_rate = 0;      // per handover
  double repeat_rate = 0;       // per handover
  double skip_rate = 0;         // per handover
  std::vector<PointAt> resets;  // reset just before the program starts probing this point
  struct ThirdParty {
    PointAt at;
    int offset = 0;  // block address offset (0 = C)
    double value = 0;
  };
  std::vector<ThirdParty> third_party;  // written right after the machine hands this point over
  std::vector<PointAt> corrupt_data;    // the data word of this point is written + 0.5
  struct Deviation {
    PointAt at;
    int axis = 0;
    double value_mm = 0;
  };
  std::vector<Deviation> deviations;  // replaces the generated deviation (e.g. 0.15 mm: OVERFLOW)
  std::set<std::string> offset_reject;
  std::map<std::string, double> offset_mismatch;  // the first write stores written + this
  Status Validate() const;
};

struct OffsetEntry {
  double value_mm = 0;
  double min_mm = -1, max_mm = 1;
  double resolution_mm = 0.001;
};

struct ControllerOptions {
  Dialect dialect = Dialect::kFanuc;
  MachineProgramOptions program;  // how the machine-side program is written (dialect is overridden)
  int points = 100;               // per run, 1..2000
  int runs = 1;                   // complete runs of the measuring program
  std::uint64_t seed = 1;
  Precision precision = Precision::kDouble;
  LatencyModel latency;                              // per API call
  double measure_time_s = 0.05;                      // one probing move
  double run_gap_s = 0.2;                            // between one run's end and the next start
  double restart_delay_s = 0.5;                      // reset → cycle start
  double start_delay_s = 0;                          // before the first run
  std::vector<std::pair<int, int>> volatile_ranges;  // cleared by a reset (Fanuc #100-#199 by default)
  std::map<int, double> initial_values;              // block (and other) addresses set at power-on
  std::map<std::string, OffsetEntry> offsets;        // added to / replacing the default table
  ControllerFaults faults;
  Status Validate() const;
};

// What the program handed over, as the controller saw it (its own record).
struct HandoverRecord {
  int run = 0;   // program start (1-based)
  double q = 0;  // Q as the program holds it
  int id = 0;
  std::array<double, 3> data{};      // D (packed: data[0]) or v_x, v_y, v_z (split), as written
  std::array<double, 3> truth_mm{};  // the deviation the probe measured (reference → trigger point)
  double t_s = 0;
  bool corrupted = false;
};

class Controller final : public MachineEnvironment {
 public:
  // Builds the plan (SyntheticPlan), writes and reads back the machine-side program, and schedules
  // the first run on `scheduler`.
  static Result<std::unique_ptr<Controller>> Create(const ControllerOptions& options, EventScheduler* scheduler);

  // One API call: applied after half the latency (a torn read address by address across it),
  // `done` called after the whole latency with the response and what happens to the connection.
  void Submit(const ApiRequest& request, std::function<void(const ApiResponse&, Disposition)> done);

  // True once `runs` runs ended (M30) or the program stopped in an alarm that is not restarted.
  bool done() const { return done_; }
  int runs_completed() const { return runs_completed_; }
  int runs_started() const { return runs_started_; }
  const std::vector<HandoverRecord>& record() const { return record_; }
  struct AlarmRecord {
    int run = 0;
    int number = 0;
    std::string text;
    std::string where;
    double t_s = 0;
  };
  const std::vector<AlarmRecord>& alarms() const { return alarms_; }
  const std::vector<std::string>& messages() const { return messages_; }
  // How often each fault was actually injected ("api_error", "dropped_write", "reorder", ...).
  const std::map<std::string, long>& fault_counts() const { return fault_counts_; }
  const metrology::ProbingPlan& plan() const { return plan_; }
  const MachineProgram& program() const { return program_; }
  const BlockLayout& block() const { return block_; }
  // The API's view (tests): visible value, vacant as nullopt.
  MacroValue Peek(int address) const;
  Result<double> PeekOffset(const std::string& name) const;
  // Writes the record as CSV (run,q,id,data0,data1,data2,dx_mm,dy_mm,dz_mm,t_s,corrupted).
  Status WriteRecord(const std::filesystem::path& path) const;
  // The deviation the probe measures at a point of a run (fault overrides included), mm.
  std::array<double, 3> Truth(int run, int id) const;

 private:
  Controller(const ControllerOptions& options, EventScheduler* scheduler);
  Status Setup();

 public:
  // MachineEnvironment (the machine program's side; not for API callers).
  MacroValue ReadVariable(int number) override;
  void WriteVariable(int number, MacroValue value) override;
  double PortIn(int port) override { return ReadVariable(port).value_or(0.0); }
  void PortOut(int port, double value) override { WriteVariable(port, value); }
  ProbeOutcome Probe(const std::array<double, 3>& from, const std::array<double, 3>& to, double feed) override;
  void Message(const std::string& text) override;
  MarkAction OnPointMark(int id) override;

 private:
  std::vector<std::array<double, 3>> GenerateTruth(int run) const;
  double Store(double value) const;  // precision mode
  double ApiPath(double value) const;
  void Commit(int address, double value);
  void StartRun();
  void Step();
  void Reset();
  bool Draw(double rate);

  ControllerOptions options_;
  EventScheduler* scheduler_;
  Rng rng_;
  metrology::ProbingPlan plan_;
  MachineProgram program_;
  MacroCode code_;
  std::unique_ptr<MacroInterpreter> interpreter_;
  BlockLayout block_;
  std::unordered_map<int, double> memory_;  // visible values; absent = vacant
  struct Pending {
    std::uint64_t seq;
    int address;
    double value;
  };
  std::deque<Pending> pending_;  // machine writes not visible yet, in write order
  std::uint64_t pending_seq_ = 0;
  double last_visible_t_ = 0;
  std::map<std::string, OffsetEntry> offsets_;
  std::set<std::string> mismatch_used_;
  std::map<std::int64_t, int> probe_index_;                // key of a probe end point → plan index
  std::vector<std::vector<std::array<double, 3>>> truth_;  // per run (lazily), per point
  std::vector<HandoverRecord> record_;
  std::vector<AlarmRecord> alarms_;
  std::vector<std::string> messages_;
  std::map<std::string, long> fault_counts_;
  int runs_started_ = 0, runs_completed_ = 0;
  int current_point_ = 0;
  int pending_repeat_ = 0, pending_skip_ = 0;
  std::array<double, 3> last_data_{};
  std::array<double, 3> last_truth_{};
  bool last_corrupted_ = false;
  std::uint64_t generation_ = 0;  // bumps on reset so stale scheduled steps do nothing
  bool running_ = false;
  bool done_ = false;
};

// The plan the emulator measures: `count` points (ids 1..count) on a gently curved surface
// z = 0.5·sin(x/13)·cos(y/17) over a grid with 2 mm spacing, normals from the surface.
metrology::ProbingPlan SyntheticPlan(int count);

}  // namespace formloop::cnc
