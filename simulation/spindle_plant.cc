#include "simulation/spindle_plant.h"

#include <algorithm>
#include <cmath>
#include <string>

namespace formloop::sim {

Result<EngagementProfile> EngagementProfile::Create(std::vector<EngagementSample> samples) {
  if (samples.size() < 2) return Status::BadInput("an engagement profile needs at least two samples");
  for (std::size_t i = 0; i < samples.size(); ++i) {
    const EngagementSample& e = samples[i];
    if (!std::isfinite(e.s_mm) || !std::isfinite(e.a_e_mm) || !std::isfinite(e.a_p_mm) || e.a_e_mm < 0 ||
        e.a_p_mm < 0) {
      return Status::BadInput("engagement sample " + std::to_string(i) + ": s, a_e, a_p must be finite, a_e, a_p >= 0");
    }
    if (i > 0 && !(e.s_mm > samples[i - 1].s_mm)) {
      return Status::BadInput("engagement sample " + std::to_string(i) + ": s must increase strictly");
    }
  }
  EngagementProfile p;
  p.samples_ = std::move(samples);
  return p;
}

EngagementProfile EngagementProfile::Reference(bool hard_step, double gap_from_mm, double gap_to_mm) {
  std::vector<EngagementSample> s = {{0, 1, 5}};
  const double eps = 1e-9;
  if (gap_to_mm > gap_from_mm && gap_from_mm > 0 && gap_to_mm < 100) {  // a_e = 0 on [from, to): two steps
    s.push_back({gap_from_mm - eps, 1, 5});
    s.push_back({gap_from_mm, 0, 5});
    s.push_back({gap_to_mm - eps, 0, 5});
    s.push_back({gap_to_mm, 1, 5});
  }
  if (hard_step) {
    s.push_back({100 - eps, 1, 5});
    s.push_back({100, 3, 5});
  } else {
    s.push_back({100, 1, 5});
    s.push_back({103, 3, 5});
  }
  s.push_back({200, 3, 5});
  s.push_back({300, 1, 5});
  return Create(std::move(s)).value();
}

EngagementSample EngagementProfile::At(double s) const {
  if (samples_.empty()) return {};
  if (s <= samples_.front().s_mm) return samples_.front();
  if (s >= samples_.back().s_mm) return samples_.back();
  if (hint_ + 1 >= samples_.size() || samples_[hint_].s_mm > s) hint_ = 0;
  while (samples_[hint_ + 1].s_mm < s) ++hint_;
  const EngagementSample &a = samples_[hint_], &b = samples_[hint_ + 1];
  const double t = (s - a.s_mm) / (b.s_mm - a.s_mm);
  return {s, a.a_e_mm + t * (b.a_e_mm - a.a_e_mm), a.a_p_mm + t * (b.a_p_mm - a.a_p_mm)};
}

Status SpindlePlantOptions::Validate() const {
  for (double v : {c_f, k_f, y_f, diameter_mm, spindle_rpm, current_per_force_a_per_n, feed_lag_s, current_lag_s,
                   step_s, nominal_voltage_v}) {
    if (!(std::isfinite(v) && v > 0)) {
      return Status::BadInput("spindle plant: force law, tool, spindle speed, k_I, lags, step and voltage must be > 0");
    }
  }
  if (flutes < 1) return Status::BadInput("spindle plant: flutes must be at least 1");
  if (!(idle_current_a >= 0) || !(noise_a >= 0)) return Status::BadInput("spindle plant: I_0 and noise must be >= 0");
  if (step_s > 0.2 * std::min(feed_lag_s, current_lag_s)) {
    return Status::BadInput("spindle plant: the Euler step must be at most a fifth of the shortest lag");
  }
  for (const SupplySag& sag : sags) {
    if (!(sag.duration_s >= 0) || !(sag.depth > -1)) return Status::BadInput("spindle plant: bad supply sag");
  }
  return Status::Ok();
}

SpindlePlant::SpindlePlant(const SpindlePlantOptions& options, EngagementProfile profile,
                           double initial_feed_mm_per_min, std::uint64_t noise_seed)
    : options_(options),
      profile_(std::move(profile)),
      rng_(noise_seed),
      v_act_(initial_feed_mm_per_min),
      i_(options.idle_current_a) {}

double SpindlePlant::SteadyCurrentA(const EngagementSample& e, double feed) const {
  const SpindlePlantOptions& o = options_;
  if (e.a_e_mm <= 0 || e.a_p_mm <= 0 || feed <= 0) return o.idle_current_a;
  const double f_z = feed / (o.flutes * o.spindle_rpm);
  const double force = o.k_f * o.c_f * std::pow(e.a_p_mm, o.x_f) * std::pow(f_z, o.y_f) * std::pow(e.a_e_mm, o.u_f) *
                       o.flutes / (std::pow(o.diameter_mm, o.q_f) * std::pow(o.spindle_rpm, o.w_f));
  return o.idle_current_a + o.current_per_force_a_per_n * force;
}

double SpindlePlant::FeedForForce(const EngagementSample& e, double force_n) const {
  const SpindlePlantOptions& o = options_;
  const double per_fz = o.k_f * o.c_f * std::pow(e.a_p_mm, o.x_f) * std::pow(e.a_e_mm, o.u_f) * o.flutes /
                        (std::pow(o.diameter_mm, o.q_f) * std::pow(o.spindle_rpm, o.w_f));
  return std::pow(force_n / per_fz, 1 / o.y_f) * o.flutes * o.spindle_rpm;
}

double SpindlePlant::ForceN() const {
  return (SteadyCurrentA(profile_.At(s_), v_act_) - options_.idle_current_a) / options_.current_per_force_a_per_n;
}

double SpindlePlant::DeltaU() const {
  double d = 0;
  for (const SupplySag& sag : options_.sags) {
    if (t_ >= sag.start_s && t_ < sag.start_s + sag.duration_s) d = sag.depth;
  }
  return d;
}

void SpindlePlant::Step(double commanded) {
  const SpindlePlantOptions& o = options_;
  const double dt = o.step_s;
  const double target_i = SteadyCurrentA(profile_.At(s_), v_act_);
  s_ += v_act_ / 60 * dt;
  v_act_ += dt / o.feed_lag_s * (commanded - v_act_);
  i_ += dt / o.current_lag_s * (target_i - i_);
  t_ += dt;
  if (std::isfinite(o.fault_current_a) && t_ >= o.fault_start_s) i_ = o.fault_current_a;
}

double SpindlePlant::MeasuredCurrentA() { return i_ / (1 + DeltaU()) + options_.noise_a * rng_.Normal(); }

double SpindlePlant::SupplyVoltageV() const { return options_.nominal_voltage_v * (1 + DeltaU()); }

}  // namespace formloop::sim
