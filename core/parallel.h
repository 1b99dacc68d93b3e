#pragma once
// Both cores where it pays, with results bit-identical to a single-threaded run (issue 26).
//
// ParallelFor cuts [0, n) into fixed chunks of `grain` indices (the last one shorter) and runs
// body(begin, end) on each, on TBB's worker threads. The chunking depends only on n and grain, never
// on the thread count or the scheduling, and a body must write only to its own indices (no shared
// floating-point accumulator): then the output is the same bytes for 1, 2 or 64 threads. Sums over
// chunks, where needed, are added afterwards in chunk order by the caller.
//
// The thread count is process-wide: SetThreadCount(n) (the CLI's --threads) caps TBB's arena for the
// rest of the process; 0 means all cores (the default).

#include <functional>

namespace formloop {

// Caps the worker threads at `threads` (>= 1), or lifts the cap (0: all cores).
void SetThreadCount(int threads);
// The threads parallel loops may use now (>= 1).
int ThreadCount();

// Runs body(begin, end) over the fixed chunks [c·grain, min((c+1)·grain, n)), c = 0, 1, ...; in
// parallel when more than one chunk and more than one thread, in chunk order otherwise.
void ParallelFor(long n, long grain, const std::function<void(long begin, long end)>& body);

}  // namespace formloop
