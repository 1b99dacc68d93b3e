#pragma once
// Test support for the link: an emulated controller and a collector in one process under virtual time
// (cnc/virtual_link.h), collector kills that drop the collector object and start a new one from the
// journal (as after SIGKILL), and the comparison of what the collector stored with the controller's
// own record.

#include <gtest/gtest.h>

#include <filesystem>
#include <functional>
#include <map>
#include <memory>
#include <set>
#include <string>
#include <vector>

#include "cnc/collector.h"
#include "cnc/controller.h"
#include "cnc/virtual_link.h"
#include "core/random.h"

namespace formloop::cnc::testing {

// Thrown by a kill hook; caught by CollectWithKills.
struct Killed {};

struct VirtualBench {
  EventScheduler scheduler;
  VirtualClock clock{&scheduler};
  std::unique_ptr<Controller> controller;
  std::unique_ptr<VirtualLink> link;

  explicit VirtualBench(ControllerOptions options, VirtualLinkOptions link_options = {}) {
    if (options.dialect == Dialect::kFanuc) options.program.probe.post.decimals = 3;
    options.program.dialect = options.dialect;
    auto c = Controller::Create(options, &scheduler);
    if (!c.ok()) {
      ADD_FAILURE() << c.status().ToString();
      return;
    }
    controller = std::move(*c);
    link = std::make_unique<VirtualLink>(controller.get(), &scheduler, link_options);
  }

  CollectorOptions Collector(const std::filesystem::path& journal, int runs, int expect) const {
    CollectorOptions o;
    o.block = controller->block();
    o.runs = runs;
    o.expect_points = expect;
    o.journal = journal;
    o.fsync = false;
    o.reconnect_min_s = 0.05;
    o.reconnect_max_s = 0.4;
    o.idle_timeout_s = 120;
    return o;
  }

  // Runs collectors until one returns; `kill(step)` decides whether to kill at a step. Each kill
  // drops the collector and starts a new one after restart_s of virtual time.
  Result<CollectorReport> CollectWithKills(const CollectorOptions& options,
                                           const std::function<bool(CollectorStep)>& kill, double restart_s,
                                           int* kills) {
    for (int attempt = 0; attempt < 100000; ++attempt) {
      try {
        return Collect(*link, clock, options, [&](CollectorStep step) {
          if (kill && kill(step)) throw Killed{};
        });
      } catch (const Killed&) {
        ++*kills;
        link->Disconnect();
        clock.SleepS(restart_s);
      }
    }
    return Status::Internal("too many kills");
  }

  // Lets the machine program finish what it does after the collector returned (its M5 wait).
  void Drain(double seconds = 30) { scheduler.RunUntil(scheduler.now_s() + seconds); }
};

// Checks the collector's sessions against the controller's record: per run, the ids the machine
// handed over are stored once each, in order, with bit-exact data; returns the number of points
// compared. `skipped` receives, per run, the ids the machine never sent (gaps).
inline long ExpectMatchesRecord(const Controller& controller, const std::vector<Session>& sessions) {
  // The record's first copy of each (run, id): the collector keeps the first copy of a duplicate.
  std::map<int, std::vector<const HandoverRecord*>> by_run;
  std::map<int, std::set<int>> seen;
  std::map<int, double> q_of_run;
  for (const auto& r : controller.record()) {
    q_of_run[r.run] = r.q;
    if (seen[r.run].insert(r.id).second) by_run[r.run].push_back(&r);
  }
  long compared = 0;
  for (const auto& [run, records] : by_run) {
    const Session* session = nullptr;
    for (const auto& s : sessions) {
      if (s.q == q_of_run[run]) session = &s;
    }
    if (session == nullptr) {
      ADD_FAILURE() << "no session for run " << run << " (Q=" << q_of_run[run] << ")";
      continue;
    }
    EXPECT_EQ(session->points.size(), records.size()) << "run " << run;
    const std::size_t n = std::min(session->points.size(), records.size());
    for (std::size_t k = 0; k < n; ++k) {
      const auto& p = session->points[k];
      const auto& r = *records[k];
      EXPECT_EQ(p.id, r.id) << "run " << run << " position " << k;
      const int count = controller.block().data_count();
      for (int a = 0; a < count; ++a)
        EXPECT_EQ(p.data[a], r.data[a]) << "run " << run << " id " << r.id << " word " << a;
      if (!r.corrupted) {
        for (int a = 0; a < 3; ++a) {
          if (p.decoded.flags[a] == AxisFlag::kOk) {
            EXPECT_EQ(p.decoded.v[a], QuantiseDeviation(r.truth_mm[a])) << "run " << run << " id " << r.id;
          }
        }
      }
      ++compared;
    }
    // Strictly increasing ids: in order, no duplicates.
    for (std::size_t k = 1; k < session->points.size(); ++k)
      EXPECT_LT(session->points[k - 1].id, session->points[k].id);
  }
  return compared;
}

}  // namespace formloop::cnc::testing
