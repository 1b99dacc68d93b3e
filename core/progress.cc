#include "core/progress.h"

#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <cstdio>

namespace formloop {
namespace {
std::atomic<bool> g_enabled{true};
}

void Progress::SetEnabled(bool enabled) { g_enabled = enabled; }

Progress::Progress(std::string label, std::size_t total, double plain_interval_s)
    : label_(std::move(label)),
      total_(total),
      plain_interval_s_(plain_interval_s),
      tty_(::isatty(STDERR_FILENO) != 0),
      start_(std::chrono::steady_clock::now()),
      last_draw_(start_) {}

Progress::~Progress() { Finish(); }

void Progress::Advance(std::size_t steps) {
  done_ = std::min(total_, done_ + steps);
  const auto now = std::chrono::steady_clock::now();
  const double since = std::chrono::duration<double>(now - last_draw_).count();
  if (tty_ ? since >= 0.1 : since >= plain_interval_s_) Draw(false);
}

void Progress::Finish() {
  if (finished_) return;
  finished_ = true;
  done_ = total_;
  Draw(true);
}

void Progress::Draw(bool final) {
  last_draw_ = std::chrono::steady_clock::now();
  if (!g_enabled) return;
  const double elapsed = std::chrono::duration<double>(last_draw_ - start_).count();
  const double fraction = total_ == 0 ? 1.0 : static_cast<double>(done_) / static_cast<double>(total_);
  if (tty_) {
    constexpr int kWidth = 30;
    const int filled = static_cast<int>(fraction * kWidth);
    std::string bar(static_cast<std::size_t>(filled), '#');
    bar.resize(kWidth, '.');
    std::fprintf(stderr, "\r%s [%s] %3.0f%% (%zu/%zu, %.1f s)%s", label_.c_str(), bar.c_str(), 100.0 * fraction, done_,
                 total_, elapsed, final ? "\n" : "");
  } else if (final || fraction < 1.0) {
    std::fprintf(stderr, "%s: %zu/%zu (%.0f%%) %.1f s\n", label_.c_str(), done_, total_, 100.0 * fraction, elapsed);
  }
  std::fflush(stderr);
}

}  // namespace formloop
