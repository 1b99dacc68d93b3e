#pragma once
// Level 2 of the self-optimising NC (spec/process-optimization.md §2): real-time feed control from the
// spindle load current by a Mamdani fuzzy controller, built on fuzzylite 6 (Rada-Vilela, "The FuzzyLite
// Libraries for Fuzzy Logic Control", 2018; Debian libfuzzylite-dev, GPL-3.0) rather than hand-written
// inference.
//
// Every T_s the controller reads the load current I_m and the supply voltage U_s. Inputs E = I_ref − I_m
// and EC = (E_k − E_{k−1})/T_s are quantised onto 13-level universes {−6..6} (e = clamp(6 E/E_max),
// ec = clamp(6 EC/EC_max), unrounded); seven values NB NM NS ZO PS PM PB (triangles peaking at −6, −4,
// ..., 6 with feet ±2) on E, EC and the output U; the 49 rules of the table below (U = sat(E + EC),
// an incremental PI, with the overload override: while E is NB or NM, U ≤ NS); Mamdani min implication,
// max aggregation (max-min composition) and the weighted average over the 13 output levels
// (fuzzylite's Centroid with 13 samples on [−6.5, 6.5], which fall exactly on −6..6). The feed moves by
// Δv_f = k_u U, k_u = gain · v_f,0 per level.
//
// Supervision (§2.5), in this order each sample:
//   trip      I_m ≥ I_trip = I_0 + 1.6 k_I F_max for 3 samples: feed 0, alarm L2-TRIP (latched)
//   supply    δU < −0.15 for 10 samples: feed 0, alarm L2-SUPPLY (latched)
//   overload  I_m ≥ I_over = I_0 + 1.25 k_I F_max: U = −6 without the rules
//   air cut   I_m < I_0 + 0.1 (I_ref − I_0): v_f = v_f,0 (no wind-up in air)
//   voltage   |δU| > 0.05: hold (Δv_f = 0) until 20 samples with |δU| ≤ 0.03, then E_{k−1} := E_k
//   rules     otherwise
// v_f is clamped to [0.1 v_f,0, min(2 v_f,0, v_f,hi)] and sent as an override of v_f,0 with a 1 %
// resolution. I_ref = I_0 + k_I ρ_ref F_max.

#include <memory>
#include <string>
#include <vector>

#include "core/status.h"

namespace formloop::planning {

struct FuzzyFeedOptions {
  double sample_s = 0.010;                  // T_s (5-50 ms)
  double e_max_a = 3.0;                     // E at level 6 (k_e = 6/E_max)
  double ec_max_a_per_s = 60.0;             // EC at level 6
  double gain_per_level = 0.03;             // k_u / v_f,0: a step is at most 18 % of v_f,0
  double idle_current_a = 3.0;              // I_0(n)
  double current_per_force_a_per_n = 0.02;  // k_I = d/(2000 K_t)
  double max_force_n = 300;                 // F_max of Level 1
  double rho_ref = 0.83;                    // I_ref at ρ_ref F_max (0.7-1.0)
  double initial_feed_mm_per_min = 2942;    // v_f,0: the block's Level-1 feed
  double max_feed_mm_per_min = 1e300;       // min(f_z,max z n, v_f,max)
  double nominal_voltage_v = 400;
  double override_resolution = 0.01;  // of v_f,0
  Status Validate() const;
  double ReferenceCurrentA() const;
  double OverloadCurrentA() const;
  double TripCurrentA() const;
};

// The rule table of §2.3: kRuleTable[e + 3][ec + 3] = u, values −3 (NB) .. 3 (PB).
extern const int kFuzzyFeedRuleTable[7][7];

// The fuzzylite engine of the rule base: U for quantised inputs e, ec ∈ [−6, 6] (clamped).
class FuzzyFeedRules {
 public:
  FuzzyFeedRules();
  ~FuzzyFeedRules();
  FuzzyFeedRules(FuzzyFeedRules&&) noexcept;
  FuzzyFeedRules& operator=(FuzzyFeedRules&&) noexcept;
  double Infer(double e, double ec);
  // The engine in fuzzylite's FLL language, for the record.
  std::string Fll() const;

 private:
  struct Engine;
  std::unique_ptr<Engine> engine_;
};

enum class FeedMode { kRules, kOverload, kAirCut, kVoltageHold, kTrip, kSupplyAlarm };
const char* FeedModeName(FeedMode mode);

class FuzzyFeedController {
 public:
  static Result<FuzzyFeedController> Create(const FuzzyFeedOptions& options);
  // One sample: returns the commanded feed (mm/min).
  double Update(double current_a, double voltage_v);
  double command() const { return command_; }
  FeedMode mode() const { return mode_; }
  const std::vector<std::string>& alarms() const { return alarms_; }
  const FuzzyFeedOptions& options() const { return options_; }

 private:
  FuzzyFeedOptions options_;
  FuzzyFeedRules rules_;
  double feed_ = 0, command_ = 0;
  double e_prev_ = 0;
  bool first_ = true;
  int trip_count_ = 0, low_count_ = 0, ok_count_ = 0;
  bool voltage_hold_ = false;
  FeedMode mode_ = FeedMode::kRules;
  std::vector<std::string> alarms_;
};

}  // namespace formloop::planning
