#pragma once
// Mirror compensation of a tool path (spec/nc-gen.md §4): the compensated cutter-contact point is
// A = i − d_s(i)·n(i) (remove what was left, add back what was over-cut), then the cutter location
// as usual. Every moved CL point is recorded in a side file (nominal tip, applied offset vector,
// source) so a checker can recompute it from the two programs.

#include <filesystem>
#include <functional>
#include <string>
#include <vector>

#include <Eigen/Core>

#include "core/status.h"
#include "nc-gen/post.h"
#include "nc-gen/toolpath.h"

namespace formloop::nc {

struct CompensationOptions {
  double max_offset_um = 200;  // safety: refuse any single offset larger than this
  Status Validate() const;
};

struct CompensationEntry {
  std::size_t cl_index = 0;
  long nominal_line = 0;       // line of the move in the nominal program (filled by caller)
  long compensated_line = 0;   // line in the compensated program (filled by caller)
  Eigen::Vector3d nominal_tip = Eigen::Vector3d::Zero();
  Eigen::Vector3d offset_mm = Eigen::Vector3d::Zero();  // compensated tip − nominal tip
  double systematic_um = 0;    // d_s at the CC point
};

struct Compensation {
  Toolpath path;                          // the compensated tool path
  std::vector<CompensationEntry> entries; // one per CL point
  double max_offset_um = 0;
  std::string source;                     // e.g. "systematic field (Legendre degree 2) from loop 0"
};

// d_s(u, v) in mm at the CC point's parameters; loops pass the sum of every loop's field.
using SystematicField = std::function<double(double u, double v)>;

Result<Compensation> CompensateToolpath(const Toolpath& nominal, const SystematicField& systematic,
                                        const std::string& source, const CompensationOptions& options);

// Fills nominal_line / compensated_line: the i-th feed move of each program is CL point i.
Status AssignProgramLines(const std::vector<ProgramMove>& nominal, const std::vector<ProgramMove>& compensated,
                          Compensation* compensation);

// CSV side file: block,cl_index,pass,nominal_line,compensated_line,nominal_x..z,offset_x..z,ds_um,source.
Status WriteSideFile(const std::filesystem::path& path, const Compensation& compensation);

// Recomputes every offset from the two programs and compares with the side entries; returns the
// largest disagreement in µm (the program resolution limits it to about 0.1 µm).
Result<double> VerifyCompensation(const std::vector<ProgramMove>& nominal, const std::vector<ProgramMove>& compensated,
                                  const Compensation& compensation);

}  // namespace formloop::nc
