#pragma once
// The collector: the edge side of the handshake (spec/tuning-and-link.md §7.3–7.5, seed 000 steps
// A1–A3). It talks to a controller through a MacroTransport, keeps a Journal, and returns when the
// requested number of runs has FINISHED or on an error that needs a person.
//
// It is a reconciliation loop rather than a script: every step range-reads the block (C, data, Q, A in
// one call), decides from what it sees and from the journal, and makes at most the writes that
// decision needs. The spec's K0–K6 are cases of that one decision, so a restart (K6), a dropped or
// uncertain write, a lost connection and a controller reset all go through the same code:
//
//   C IDLE or vacant   arm when a run is wanted: data := EMPTY, then C := (1,0,1,0)          (K1, R3)
//   C (1,0,1,0)        armed, waiting for the machine's first point                           (K2)
//   C (1,0,1,p)        the machine holds the token after our acknowledgement of p: wait; the journal
//                      must end at p (else LOST_POINTS); a new Q means the run was restarted: the
//                      session is closed ABORTED and the block re-armed                       (K2, K6)
//   C (1,1,2,i)        the collector holds the token:                                          (K3)
//                      data EMPTY and i new → keep reading (R5; VISIBILITY_TIMEOUT after T_vis);
//                      i = last + 1 → decode, journal + fsync, then acknowledge;
//                      i > last + 1 → GAP (missing ids listed, session INCOMPLETE), stored, acknowledged;
//                      i = last → already stored: acknowledge only (a restart after persisting, a lost
//                      acknowledgement, or a DUPLICATE the machine sent again: first copy kept);
//                      i < last with the same Q → PROTOCOL_ERROR; a new Q → the old session ABORTED
//   C (1,1,3,N)        check N = last (= expected), journal END, C := IDLE                     (K4)
//   anything else      PROTOCOL_ERROR: stop; the block needs a manual reset                    (K6)
// Acknowledging point i: data := EMPTY; read back (C, data) and repeat the data write until it shows
// EMPTY (the machine cannot write while the collector holds the token, so this is safe); then
// C := (1,0,1,i) (or ABORT with stop_on_range after an out-of-range point). The next read is made at
// once and is C's read-back: C still (1,1,2,i) with data EMPTY means the write was lost, and it is
// made again. Writes are never repeated blindly: after any failed or uncertain call the block is read
// and the decision taken afresh.
//
// Round trips per point: the read that finds POINT_READY, the data reset, its read-back, and the
// control write: 4 (the control word's read-back is the next poll). That is the protocol's own bound
// on throughput: at most 1 / (4 · round-trip time) points per second, plus the machine's dwell.
//
// The limit of the word layout: a machine that sends the same id again faster than one round trip,
// with its data write still invisible, looks like a lost acknowledgement; the emulator's repeat fault
// needs a probing move (measure_time_s) before the repeat, as a real restart at a block does.

#include <functional>
#include <memory>
#include <nlohmann/json.hpp>
#include <string>
#include <vector>

#include "cnc/clock.h"
#include "cnc/handshake.h"
#include "cnc/journal.h"
#include "cnc/transport.h"
#include "core/status.h"

namespace formloop::cnc {

struct CollectorOptions {
  BlockLayout block;
  int expect_points = 0;       // points per run the model expects; 0 = take N from FINISHED
  int runs = 1;                // FINISHED runs to collect before returning
  double poll_s = 0.010;       // t_poll (R4)
  double poll_slow_s = 0.100;  // after slow_after_s without change
  double slow_after_s = 5.0;
  double visibility_timeout_s = 2.0;  // T_vis (R5)
  double reconnect_min_s = 0.5;       // K0 backoff 0.5 s .. 8 s
  double reconnect_max_s = 8.0;
  double idle_timeout_s = 600;  // give up when the block has not changed for this long; 0 = never
  int max_data_resets = 50;     // data := EMPTY attempts for one point before giving up
  bool stop_on_range = false;   // acknowledge an out-of-range point with ABORT
  std::filesystem::path journal;
  bool fsync = true;
  bool progress = false;  // a progress bar on stderr (core/progress.h)
  Status Validate() const;
};

// Where a test (or a fault study) may kill the collector: the hook throws, the collector object is
// dropped, and a new one starts from the journal, as after SIGKILL.
enum class CollectorStep { kAfterRead, kAfterPersist, kAfterDataReset, kAfterAck, kAfterArm, kAfterEnd };
using CollectorHook = std::function<void(CollectorStep)>;

struct CollectorCounters {
  long reads = 0, writes = 0;
  long api_errors = 0;  // calls the controller refused
  long connection_errors = 0;
  long reconnects = 0;
  long points_stored = 0;  // by this collector object
  long duplicates = 0;
  long resumed = 0;           // points found stored after a restart and acknowledged
  long lost_writes = 0;       // writes that did not land (seen on read-back) and were made again
  long visibility_waits = 0;  // reads that found POINT_READY with the data still EMPTY
  long arms = 0;
  nlohmann::json ToJson() const;
};

struct CollectorReport {
  bool ok = true;
  std::string fatal;              // "PROTOCOL_ERROR: ..." when !ok
  std::vector<Session> sessions;  // the journal's sessions when the collector stopped
  CollectorCounters counters;
  double elapsed_s = 0;
  long points_total() const;
  double points_per_s() const { return elapsed_s > 0 ? points_stored_rate_ : 0; }
  double points_stored_rate_ = 0;
  nlohmann::json ToJson() const;
};

// Runs the collector until options.runs runs have FINISHED (the journal counts runs ended before a
// restart) or an error stops it. A non-ok Status only for a journal that cannot be opened or
// written; protocol failures come back as report.ok = false with report.fatal.
Result<CollectorReport> Collect(MacroTransport& transport, Clock& clock, const CollectorOptions& options,
                                const CollectorHook& hook = {});

// The commissioning self-test (spec §7.2): with the block idle, writes 68 719 476 735 and
// 2 078 508 007 to the data address and reads both back; any difference means the controller or its
// API keeps too few digits for the PACKED layout (use SPLIT). Leaves the data address EMPTY.
struct SelfTestReport {
  bool passed = false;
  std::vector<std::pair<double, double>> written_read;  // (written, read back)
  std::string message;
};
Result<SelfTestReport> RunSelfTest(MacroTransport& transport, const BlockLayout& block);

// The points of the sessions as CSV: session,q,status,id,data0,data1,data2,vx,vy,vz,dx_mm,dy_mm,dz_mm,
// flags,t_s (written atomically).
Status WriteCollection(const std::filesystem::path& path, const std::vector<Session>& sessions);

}  // namespace formloop::cnc
