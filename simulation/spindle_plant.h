#pragma once
// The spindle-current plant of spec/process-optimization.md §2.6: a milling cut along a path whose
// engagement (a_e radial, a_p axial) varies with the path length s, a feed drive and a spindle motor
// with first-order lags, the measured current with seeded noise, and the supply voltage with sags.
//
//   feed drive   τ_f dv_f,act/dt = v_f,cmd − v_f,act                    (τ_f = 0.02 s)
//   chip load    f_z = v_f,act / (z n)
//   force        F_c = K_F C_F a_p^x_F f_z^y_F a_e^u_F z / (d^q_F n^w_F)    (the §1.3 force law)
//   spindle      τ_I dI/dt = I_0 + k_I F_c − I                           (τ_I = 0.05 s, k_I = d/(2000 K_t))
//   path         ds/dt = v_f,act / 60
//   measurement  I_m = I / (1 + δU) + N(0, σ²)   (a sag of the supply raises the current drawn for the
//                same load: constant power), δU = (U_s − U_nom)/U_nom
// integrated by explicit Euler at dt (0.5 ms). A fault can force the current to a value from a time on
// (the trip test of §5.2). Noise comes from formloop::Rng (seeded), so a run is reproducible.
//
// The engagement along a real tool path comes from simulation/engagement.h (a Z-map stock model).

#include <cstdint>
#include <limits>
#include <vector>

#include "core/random.h"
#include "core/status.h"

namespace formloop::sim {

// Engagement at path length s_mm; between samples it is linear, beyond the ends constant.
struct EngagementSample {
  double s_mm = 0;
  double a_e_mm = 0, a_p_mm = 0;
};

class EngagementProfile {
 public:
  EngagementProfile() = default;
  // Samples sorted by s (strictly increasing); BadInput otherwise.
  static Result<EngagementProfile> Create(std::vector<EngagementSample> samples);
  // The reference profile of §2.6 (300 mm: a_e 1 below s = 100, ramp to 3 over 100-103 — or a jump at
  // 100 when hard_step — 3 to 200, linear 3 -> 1 to 300; a_p = 5), with an optional air gap (a_e = 0
  // on [gap_from, gap_to), inside (0, 100); the §5.2 air-cut test uses 40-60).
  static EngagementProfile Reference(bool hard_step = false, double gap_from_mm = 0, double gap_to_mm = 0);
  EngagementSample At(double s_mm) const;
  double length_mm() const { return samples_.empty() ? 0 : samples_.back().s_mm; }
  const std::vector<EngagementSample>& samples() const { return samples_; }

 private:
  std::vector<EngagementSample> samples_;
  mutable std::size_t hint_ = 0;  // last segment found (At is called with increasing s)
};

struct SupplySag {
  double start_s = 0, duration_s = 0;
  double depth = -0.10;  // δU during the sag
};

struct SpindlePlantOptions {
  // Force law (§1.3) and the cut.
  double c_f = 125, x_f = 1.0, y_f = 0.75, u_f = 0.85, q_f = 0.73, w_f = -0.13, k_f = 1;
  double diameter_mm = 10;
  int flutes = 4;
  double spindle_rpm = 5963;
  // Motor and drive.
  double idle_current_a = 3.0;              // I_0
  double current_per_force_a_per_n = 0.02;  // k_I = d / (2000 K_t), K_t = 0.25 N·m/A
  double feed_lag_s = 0.02;                 // τ_f
  double current_lag_s = 0.05;              // τ_I
  double step_s = 0.5e-3;                   // Euler step dt
  double noise_a = 0.03;                    // σ of the measurement noise
  double nominal_voltage_v = 400;
  std::vector<SupplySag> sags;
  // Fault: from fault_start_s on, I is forced to fault_current_a (NaN: no fault).
  double fault_start_s = 0;
  double fault_current_a = std::numeric_limits<double>::quiet_NaN();
  Status Validate() const;
  // The §2.6 reference plant (tool S1, n = 5963).
  static SpindlePlantOptions Reference() { return {}; }
};

class SpindlePlant {
 public:
  SpindlePlant(const SpindlePlantOptions& options, EngagementProfile profile, double initial_feed_mm_per_min,
               std::uint64_t noise_seed);
  // Advances by one Euler step with the commanded feed.
  void Step(double commanded_feed_mm_per_min);
  // Reads the sensors at the current time (draws one noise sample).
  double MeasuredCurrentA();
  double SupplyVoltageV() const;
  double ForceN() const;  // F_c at the current state
  // The steady current I_0 + k_I F_c at engagement e and feed v_f (no lag, no noise).
  double SteadyCurrentA(const EngagementSample& e, double feed_mm_per_min) const;
  // The feed giving force `force_n` at engagement e.
  double FeedForForce(const EngagementSample& e, double force_n) const;

  double time_s() const { return t_; }
  double path_mm() const { return s_; }
  double actual_feed() const { return v_act_; }
  double current_a() const { return i_; }  // the true current I (before sag and noise)
  bool finished() const { return s_ >= profile_.length_mm(); }
  const EngagementProfile& profile() const { return profile_; }
  const SpindlePlantOptions& options() const { return options_; }

 private:
  double DeltaU() const;
  SpindlePlantOptions options_;
  EngagementProfile profile_;
  Rng rng_;
  double t_ = 0, s_ = 0, v_act_ = 0, i_ = 0;
};

}  // namespace formloop::sim
