#include "core/work_estimate.h"

#include <unistd.h>

#include <atomic>
#include <cmath>

#include "core/log.h"
#include "core/number_text.h"

namespace formloop {
namespace {

std::atomic<bool> g_confirmed{false};

std::string Count(double n) {
  if (n >= 1e9) return FormatSignificant(n / 1e9, 3) + " billion";
  if (n >= 1e6) return FormatSignificant(n / 1e6, 3) + " million";
  return FormatSignificant(std::round(n), 7);
}

std::string Bytes(double b) {
  if (b >= 1e12) return FormatSignificant(b / 1e12, 3) + " TB";
  if (b >= 1e9) return FormatSignificant(b / 1e9, 3) + " GB";
  if (b >= 1e6) return FormatSignificant(b / 1e6, 3) + " MB";
  return FormatSignificant(std::max(b, 0.0) / 1e3, 3) + " kB";
}

std::string Duration(double s) {
  if (s >= 86400 * 2) return FormatSignificant(s / 86400, 3) + " days";
  if (s >= 3600) return FormatSignificant(s / 3600, 3) + " h";
  return FormatSignificant(s / 60, 3) + " min";
}

}  // namespace

std::string WorkEstimate::Describe() const {
  std::string text = Count(points) + " points, about " + Bytes(memory_bytes) + " of memory";
  if (machining_s > 0) text += ", " + Duration(machining_s) + " on the machine";
  if (output_bytes > 0) text += ", " + Bytes(output_bytes) + " written";
  return text;
}

void SetLargeWorkConfirmed(bool confirmed) { g_confirmed = confirmed; }
bool LargeWorkConfirmed() { return g_confirmed; }

double PhysicalMemoryBytes() {
  const long pages = ::sysconf(_SC_PHYS_PAGES);
  const long page = ::sysconf(_SC_PAGESIZE);
  if (pages <= 0 || page <= 0) return 0;
  return static_cast<double>(pages) * static_cast<double>(page);
}

Status CheckWork(const WorkEstimate& e, const std::string& source, const std::string& field) {
  const Where where{.file = source, .field = field};
  const std::string fix_value = "check the value and its unit (mm or um?)";
  // What no confirmation can make possible.
  const double physical = PhysicalMemoryBytes();
  if (!(e.points < 2147483647.0) || !std::isfinite(e.memory_bytes) ||
      (physical > 0 && e.memory_bytes > 0.8 * physical)) {
    return Status::BadInput(where,
                            e.what + " would need " + e.Describe() + "; that is more than this computer can hold (" +
                                Bytes(physical) + " of memory)",
                            fix_value);
  }
  std::string exceeded;
  const WorkLimits& limit = kWorkLimits;
  if (e.points > limit.points)
    exceeded = "more than " + Count(limit.points) + " points";
  else if (e.memory_bytes > limit.memory_bytes)
    exceeded = "more than " + Bytes(limit.memory_bytes) + " of memory";
  else if (e.machining_s > limit.machining_s)
    exceeded = "more than " + Duration(limit.machining_s) + " on the machine";
  else if (e.output_bytes > limit.output_bytes)
    exceeded = "more than " + Bytes(limit.output_bytes) + " of output";
  if (exceeded.empty()) return Status::Ok();
  if (LargeWorkConfirmed()) {
    log::Warn("{} will need {} ({}); going ahead because --yes was given", e.what, e.Describe(), exceeded);
    return Status::Ok();
  }
  return Status::BadInput(where,
                          e.what + " would need " + e.Describe() + ": " + exceeded + " (formloop's stated limit)",
                          fix_value + ", or pass --yes to go ahead");
}

}  // namespace formloop
