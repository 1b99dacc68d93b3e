#pragma once
// The size of a job, estimated before it starts, and the stated limits above which formloop refuses
// (or goes ahead only with the global option --yes).
//
// A value typed in the wrong unit (a scallop of 0.003 um meant as 0.003 mm, a grid of 100000 x 100000)
// must not start hours of planning, fill the disk or end in std::bad_alloc. A command first estimates
// what the job will take (points, memory, machining time, bytes written) from its inputs and calls
// CheckWork: within kLimits it goes ahead; above one of them it refuses with the estimate, the limit and
// the field that drives it, unless the user confirmed with --yes. Above what this computer can hold
// (memory beyond its physical memory, more points than an index can address) it refuses even then.

#include <string>

#include "core/status.h"

namespace formloop {

struct WorkEstimate {
  std::string what;         // "the tool path of part 'demo'", in the message
  double points = 0;        // samples, cutter locations or probe points the job creates
  double memory_bytes = 0;  // peak memory, roughly
  double machining_s = 0;   // time on the machine (cutting and probing), 0 when none
  double output_bytes = 0;  // bytes written, roughly

  std::string Describe() const;  // "2.4 million points, about 3.1 GB of memory, 11.4 h on the machine, ..."
};

// The stated limits of a job that goes ahead without --yes.
struct WorkLimits {
  double points = 20e6;
  double memory_bytes = 4e9;
  double machining_s = 8 * 3600.0;
  double output_bytes = 2e9;
};
inline constexpr WorkLimits kWorkLimits{};

// --yes: the user accepts jobs above the stated limits (never above what the computer can hold).
void SetLargeWorkConfirmed(bool confirmed);
bool LargeWorkConfirmed();

// Physical memory of this computer in bytes (0 when unknown).
double PhysicalMemoryBytes();

// Ok within the limits (or above them with --yes, logged as a warning). Otherwise BadInput with
// Where{.file = source, .field = field}: the estimate, the limit it exceeds, and the fix (check the
// value and its unit, or pass --yes). Above the physical memory, or more than 2^31 points: refused
// even with --yes.
Status CheckWork(const WorkEstimate& estimate, const std::string& source, const std::string& field);

}  // namespace formloop
