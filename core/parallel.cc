#include "core/parallel.h"

#include <algorithm>
#include <memory>
#include <mutex>

#include <tbb/blocked_range.h>
#include <tbb/global_control.h>
#include <tbb/parallel_for.h>
#include <tbb/partitioner.h>

namespace formloop {
namespace {

std::mutex control_mutex;
std::unique_ptr<tbb::global_control> control;  // null: no cap

}  // namespace

void SetThreadCount(int threads) {
  const std::lock_guard<std::mutex> lock(control_mutex);
  control.reset();
  if (threads > 0) {
    control = std::make_unique<tbb::global_control>(tbb::global_control::max_allowed_parallelism,
                                                    static_cast<std::size_t>(threads));
  }
}

int ThreadCount() {
  return std::max<int>(
      1, static_cast<int>(tbb::global_control::active_value(tbb::global_control::max_allowed_parallelism)));
}

void ParallelFor(long n, long grain, const std::function<void(long begin, long end)>& body) {
  if (n <= 0) return;
  grain = std::max(1L, grain);
  const long chunks = (n + grain - 1) / grain;
  if (chunks == 1 || ThreadCount() == 1) {
    for (long c = 0; c < chunks; ++c) body(c * grain, std::min(n, (c + 1) * grain));
    return;
  }
  // One task per fixed chunk: simple_partitioner with grain 1 over the chunk numbers never merges or
  // splits them, so which indices share a body call does not depend on the scheduling.
  tbb::parallel_for(
      tbb::blocked_range<long>(0, chunks, 1),
      [&](const tbb::blocked_range<long>& r) {
        for (long c = r.begin(); c < r.end(); ++c) body(c * grain, std::min(n, (c + 1) * grain));
      },
      tbb::simple_partitioner());
}

}  // namespace formloop
