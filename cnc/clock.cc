#include "cnc/clock.h"

#include <chrono>
#include <limits>
#include <thread>

namespace formloop::cnc {

void EventScheduler::At(double t_s, Action action) {
  queue_.push(Event{t_s < now_s_ ? now_s_ : t_s, seq_++, std::move(action)});
}

double EventScheduler::NextTime() const {
  return queue_.empty() ? std::numeric_limits<double>::infinity() : queue_.top().t_s;
}

bool EventScheduler::RunNext() {
  if (queue_.empty()) return false;
  Event event = queue_.top();
  queue_.pop();
  if (event.t_s > now_s_) now_s_ = event.t_s;
  event.action();
  return true;
}

void EventScheduler::RunUntil(double t_s) {
  while (!queue_.empty() && queue_.top().t_s <= t_s) RunNext();
  if (t_s > now_s_) now_s_ = t_s;
}

double RealClock::NowS() {
  return std::chrono::duration<double>(std::chrono::steady_clock::now().time_since_epoch()).count();
}

void RealClock::SleepS(double seconds) {
  if (seconds > 0) std::this_thread::sleep_for(std::chrono::duration<double>(seconds));
}

}  // namespace formloop::cnc
