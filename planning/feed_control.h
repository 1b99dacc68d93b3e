#pragma once
// Level 2 in closed loop (spec/process-optimization.md §2.6-2.7): the fuzzy feed controller
// (planning/fuzzy_feed.h) sampling the spindle-current plant (simulation/spindle_plant.h) every T_s,
// the plant integrated at its own Euler step in between; a constant-feed baseline through the same
// plant; and the figures §2.7 judges the controller by.
//
// Figures (from the true current I, not the noisy measurement):
//   steps        each rise of the engagement load a_p^x_F a_e^u_F by ≥ 20 % within 5 mm of path is an
//                engagement step at the s where the rise begins (rises within 10 mm count once); per step: the time s
//                is crossed, the peak current in the second after, the time spent above I_over, and the settle time =
//                the last moment within that second when |I − I_ref| > 5 % I_ref, less the crossing time.
//   regulation   the largest |I − I_ref| / I_ref at samples with t ≥ 1 s, outside the second after each
//                step, outside air cuts (a_e = 0) and the second after re-entry, and outside the last
//                10 mm before the tool leaves the material (the load runs out; nothing to regulate).
//   peak, time above I_over, machining time (until s reaches the end of the path), alarms.

#include <cstdint>
#include <nlohmann/json.hpp>
#include <string>
#include <vector>

#include "core/status.h"
#include "planning/fuzzy_feed.h"
#include "simulation/spindle_plant.h"

namespace formloop::planning {

struct FeedControlOptions {
  sim::SpindlePlantOptions plant = sim::SpindlePlantOptions::Reference();
  FuzzyFeedOptions controller;  // I_0, k_I, F_max should describe the same machine as the plant
  std::uint64_t noise_seed = 1;
  double max_time_s = 600;  // a run that has not finished the path by then fails
  Status Validate() const;
};

// One control sample.
struct FeedSample {
  double t_s = 0, s_mm = 0;
  double current_a = 0, measured_a = 0, voltage_v = 0;
  double feed_command = 0, feed_actual = 0;  // mm/min
  double a_e_mm = 0, a_p_mm = 0;
  FeedMode mode = FeedMode::kRules;
};

struct StepResponse {
  double s_mm = 0, t_cross_s = 0;
  double settle_s = 0;  // 0: never left the ±5 % band after the crossing
  double peak_a = 0;
  double above_overload_s = 0;
};

struct FeedControlFigures {
  double reference_a = 0, overload_a = 0;
  double machining_time_s = 0;
  bool finished = false;
  double peak_a = 0, above_overload_s = 0;
  double max_regulation_error = 0;                                     // relative
  double max_regulation_error_t_s = 0, max_regulation_error_s_mm = 0;  // where it occurred
  std::vector<StepResponse> steps;
  std::vector<std::string> alarms;
  nlohmann::json ToJson() const;
};

struct FeedControlResult {
  std::vector<FeedSample> samples;
  FeedControlFigures figures;
};

// The closed loop over the profile.
Result<FeedControlResult> RunFeedControl(const sim::EngagementProfile& profile, const FeedControlOptions& options);
// The same plant at a constant feed (no controller): the baseline.
Result<FeedControlResult> RunConstantFeed(const sim::EngagementProfile& profile, const FeedControlOptions& options,
                                          double feed_mm_per_min);
// The conservative constant feed: the one giving the reference force ρ_ref F_max at the heaviest
// engagement of the profile (§2.6: 664.3 mm/min for the reference plant).
double ConservativeFeed(const sim::EngagementProfile& profile, const FeedControlOptions& options);

// Figures of a finished run (also used for the baseline).
FeedControlFigures FiguresOf(const std::vector<FeedSample>& samples, const sim::EngagementProfile& profile,
                             const FeedControlOptions& options);

// The options of the §2.6 reference: plant S1 at n = 5963, I_0 = 3 A, k_I = 0.02 A/N, F_max = 300 N,
// ρ_ref = 5/6 (I_ref = 8 A), v_f,0 = 2942 mm/min.
FeedControlOptions ReferenceFeedControlOptions();

}  // namespace formloop::planning
