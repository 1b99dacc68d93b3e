#pragma once
// Progress of long work on stderr: a live bar redrawn in place when stderr is a terminal, plain
// lines every `plain_interval_s` seconds (and at the end) otherwise, so CI logs stay readable.
//
//   Progress progress("projecting points", n);
//   for (...) { ...; progress.Advance(); }
//   progress.Finish();

#include <chrono>
#include <cstddef>
#include <string>

namespace formloop {

class Progress {
 public:
  Progress(std::string label, std::size_t total, double plain_interval_s = 5.0);
  ~Progress();
  void Advance(std::size_t steps = 1);
  void Finish();
  // Disables every output (tests, --quiet). Global for the process.
  static void SetEnabled(bool enabled);

 private:
  void Draw(bool final);
  std::string label_;
  std::size_t total_;
  std::size_t done_ = 0;
  double plain_interval_s_;
  bool tty_;
  bool finished_ = false;
  std::chrono::steady_clock::time_point start_, last_draw_;
};

}  // namespace formloop
