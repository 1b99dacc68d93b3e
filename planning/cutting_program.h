#pragma once
// Level 1 on a program (spec/process-optimization.md §1.2, §1.8): the per-block depth-of-cut safety
// check, then the metal-removal-rate optimum per group of blocks written into the program's F and S
// words.
//
// Input: a word-address program — RS274NGC ("linuxcnc") and Fanuc programs read as shop programs through the
// G-code reader (planning/program_edit.h, ProgramReading::kShopProgram: arcs, helices, G91, G20), Sinumerik
// as formloop writes it — and the engagement of its cutting blocks
// (a_p axial, a_e radial, from the path generator's stock model or simulation/engagement.h). Blocks
// without an engagement row, rapids and blocks with a_e = 0 pass through unchanged.
//
// Depth check (§1.2), before anything else: every cutting block needs 0 < a_p ≤ a_p,max = min(0.9 L_c,
// k_ap d) and 0 < a_e ≤ a_e,max = d, with k_ap of the material for slotting (a_e ≥ d) or side milling.
// Any failure stops with L1-DOC-RANGE (StatusCode::kSafetyLimit) listing every failing block (N, tool,
// a_p, a_e, limits); nothing is written.
//
// Write-back (§1.8): blocks are grouped by (a_p, a_e) within ±2 % (first fit, in program order); each
// group is optimised once by the GA at its largest a_p and a_e, so its limits hold for every block of
// the group. The spindle speed stays constant in the tool operation: n_op is the (fused) optimum of the
// group that removes the most volume, rounded to whole rpm; every other group gets f_z = min(f_z,max,
// cap_g(n_op)). Each cutting block's F becomes f_z z n_op rounded down to whole mm/min (in a G20
// section inch/min rounded down to 0.01; never above the optimum); non-cutting feed blocks keep their original feed (an
// F word is added where the modal feed would otherwise carry over). Header comments record the parent's SHA-256, the
// coefficient set, the seed and w_m. One tool per program (formloop programs change tools never).

#include <cstdint>
#include <nlohmann/json.hpp>
#include <string>
#include <vector>

#include "core/status.h"
#include "planning/cutting_model.h"
#include "planning/cutting_optimisation.h"

namespace formloop::planning {

// The engagement of one cutting block.
struct BlockEngagement {
  long block = -1;  // the N word, or the 1-based line when the program has no block numbers
  double a_p_mm = 0, a_e_mm = 0;
};
// {"blocks": [{"block": 120, "a_p_mm": 5, "a_e_mm": 1}, ...]}; errors name `source`, the index and member.
Result<std::vector<BlockEngagement>> BlockEngagementFromJson(const nlohmann::json& json, const std::string& source);

struct DepthOfCutLimits {
  double a_p_max_mm = 0, a_e_max_mm = 0;
  std::string operation;  // "slotting" (a_e ≥ d) or "side_milling"
};
DepthOfCutLimits DepthOfCutLimitsFor(const CuttingCoefficients& k, double a_e_mm);

struct CuttingProgramOptions {
  std::uint64_t seed = 1;
  AgaOptions ga = CuttingGaDefaults();
  double group_tolerance = 0.02;                // relative band of a_p and a_e within one group
  double model_credibility = 0.3;               // c_model (§1.8): 0.3 = uncalibrated
  std::vector<CuttingDataRecord> cutting_data;  // the case library's records (may be empty)
  Status Validate() const;
};

struct CuttingGroup {
  double a_p_mm = 0, a_e_mm = 0;  // the group's largest engagement (optimised at)
  std::vector<std::string> blocks;
  double volume_mm3 = 0;
  CuttingOptimum model;  // the GA optimum of the group
  CuttingState state;    // the written point: f_z at n_op, feed rounded down
  bool sets_spindle = false;
  nlohmann::json ToJson() const;
};

struct CuttingProgramReport {
  std::string program;  // the re-optimised text (verified by reading it back)
  std::string parent_sha256;
  std::string coefficient_set;
  std::uint64_t seed = 0;
  int tool_number = 0;
  double spindle_rpm = 0;  // n_op
  FusedCuttingPoint fusion;
  std::vector<CuttingGroup> groups;
  int cutting_blocks = 0, lines_changed = 0;
  double cutting_time_before_min = 0, cutting_time_after_min = 0;  // engaged blocks at their feeds
  std::vector<std::string> warnings;
  nlohmann::json ToJson() const;  // without the program text
};

// The §1.2 check alone (also run by OptimiseCuttingProgram): Ok, or L1-DOC-RANGE listing every failing block.
Status CheckDepthOfCut(const std::string& program_text, const std::string& dialect, const std::string& source,
                       const std::vector<BlockEngagement>& engagement, const CuttingCoefficients& coefficients);

Result<CuttingProgramReport> OptimiseCuttingProgram(const std::string& program_text, const std::string& dialect,
                                                    const std::string& source,
                                                    const std::vector<BlockEngagement>& engagement,
                                                    const CuttingCoefficients& coefficients,
                                                    const CuttingProgramOptions& options);

}  // namespace formloop::planning
