#pragma once
// Time for the link: a Clock the collector sleeps on, and the event scheduler that drives the emulated
// controller (spec/tuning-and-link.md §8 "Time").
//
// Under a VirtualClock every sleep, dwell and latency advances a virtual time and runs the events due
// until then, in (time, insertion) order, on the caller's thread. The collector's blocking calls and
// the machine program's dwells therefore interleave deterministically, and an hour of virtual
// measuring runs in milliseconds. The emulator process drives the same scheduler from a real
// monotonic clock (cnc/emulator_server.h).

#include <cstdint>
#include <functional>
#include <queue>
#include <vector>

namespace formloop::cnc {

class EventScheduler {
 public:
  using Action = std::function<void()>;
  double now_s() const { return now_s_; }
  // Runs `action` at time t_s (never before now; an earlier time runs at now, after what is queued).
  void At(double t_s, Action action);
  void After(double delay_s, Action action) { At(now_s_ + delay_s, std::move(action)); }
  // Time of the earliest pending event; +inf when none.
  double NextTime() const;
  bool empty() const { return queue_.empty(); }
  // Runs every event due at or before t_s, then sets now to t_s (never moves backwards).
  void RunUntil(double t_s);
  // Runs the earliest event (now moves to its time); false when none is pending.
  bool RunNext();

 private:
  struct Event {
    double t_s;
    std::uint64_t seq;
    Action action;
  };
  struct Later {
    bool operator()(const Event& a, const Event& b) const { return a.t_s != b.t_s ? a.t_s > b.t_s : a.seq > b.seq; }
  };
  std::priority_queue<Event, std::vector<Event>, Later> queue_;
  double now_s_ = 0;
  std::uint64_t seq_ = 0;
};

class Clock {
 public:
  virtual ~Clock() = default;
  virtual double NowS() = 0;
  virtual void SleepS(double seconds) = 0;
};

// std::chrono::steady_clock; sleeps really.
class RealClock final : public Clock {
 public:
  double NowS() override;
  void SleepS(double seconds) override;
};

// Time of an EventScheduler; sleeping runs the scheduler's events.
class VirtualClock final : public Clock {
 public:
  explicit VirtualClock(EventScheduler* scheduler) : scheduler_(scheduler) {}
  double NowS() override { return scheduler_->now_s(); }
  void SleepS(double seconds) override { scheduler_->RunUntil(scheduler_->now_s() + (seconds > 0 ? seconds : 0)); }
  EventScheduler* scheduler() { return scheduler_; }

 private:
  EventScheduler* scheduler_;
};

}  // namespace formloop::cnc
