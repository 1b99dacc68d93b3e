#include "planning/feed_control.h"

#include <algorithm>
#include <cmath>
#include <optional>

namespace formloop::planning {
namespace {

// The load factor a_p^x_F a_e^u_F of the force law (0 in air).
double Load(const sim::SpindlePlantOptions& o, const sim::EngagementSample& e) {
  if (e.a_e_mm <= 0 || e.a_p_mm <= 0) return 0;
  return std::pow(e.a_p_mm, o.x_f) * std::pow(e.a_e_mm, o.u_f);
}

std::vector<double> StepPositions(const sim::EngagementProfile& profile, const sim::SpindlePlantOptions& o) {
  std::vector<double> out;
  for (const sim::EngagementSample& k : profile.samples()) {
    if (!out.empty() && k.s_mm < out.back() + 10) continue;  // one rise, one step
    const double now = Load(o, k), ahead = Load(o, profile.At(k.s_mm + 5));
    if (ahead > 0 && ahead >= 1.2 * now) out.push_back(k.s_mm);
  }
  return out;
}

// Runs the plant; `controller` null: the constant feed.
Result<FeedControlResult> Loop(const sim::EngagementProfile& profile, const FeedControlOptions& options,
                               FuzzyFeedController* controller, double constant_feed) {
  FL_RETURN_IF_ERROR(options.Validate());
  if (profile.length_mm() <= 0) return Status::BadInput("feed control: the engagement profile has no length");
  const double v0 = controller != nullptr ? options.controller.initial_feed_mm_per_min : constant_feed;
  sim::SpindlePlant plant(options.plant, profile, v0, options.noise_seed);
  const int steps = std::max(1, static_cast<int>(std::lround(options.controller.sample_s / options.plant.step_s)));
  const double overload = options.controller.OverloadCurrentA();
  FeedControlResult out;
  double peak = 0, above = 0;  // at the plant's step since the previous sample
  while (!plant.finished() && plant.time_s() <= options.max_time_s) {
    FeedSample s;
    s.t_s = plant.time_s();
    s.s_mm = plant.path_mm();
    s.current_a = plant.current_a();
    s.measured_a = plant.MeasuredCurrentA();
    s.voltage_v = plant.SupplyVoltageV();
    s.feed_command = controller != nullptr ? controller->Update(s.measured_a, s.voltage_v) : constant_feed;
    s.feed_actual = plant.actual_feed();
    const sim::EngagementSample e = profile.At(s.s_mm);
    s.a_e_mm = e.a_e_mm;
    s.a_p_mm = e.a_p_mm;
    s.mode = controller != nullptr ? controller->mode() : FeedMode::kRules;
    out.samples.push_back(s);
    for (int k = 0; k < steps && !plant.finished(); ++k) {
      plant.Step(s.feed_command);
      peak = std::max(peak, plant.current_a());
      if (plant.current_a() > overload) above += options.plant.step_s;
    }
    if (controller != nullptr &&
        (controller->mode() == FeedMode::kTrip || controller->mode() == FeedMode::kSupplyAlarm) &&
        plant.actual_feed() < 1e-6) {
      break;  // held: the path will not finish
    }
  }
  out.figures = FiguresOf(out.samples, profile, options);
  out.figures.finished = plant.finished();
  out.figures.machining_time_s = plant.time_s();
  out.figures.peak_a = std::max(out.figures.peak_a, peak);
  out.figures.above_overload_s = above;
  if (controller != nullptr) out.figures.alarms = controller->alarms();
  return out;
}

}  // namespace

Status FeedControlOptions::Validate() const {
  FL_RETURN_IF_ERROR(plant.Validate());
  FL_RETURN_IF_ERROR(controller.Validate());
  if (!(max_time_s > 0)) return Status::BadInput(Where{.field = "max_time_s"}, "must be > 0");
  return Status::Ok();
}

nlohmann::json FeedControlFigures::ToJson() const {
  nlohmann::json s = nlohmann::json::array();
  for (const StepResponse& r : steps) {
    s.push_back({{"s_mm", r.s_mm},
                 {"t_cross_s", r.t_cross_s},
                 {"settle_s", r.settle_s},
                 {"peak_a", r.peak_a},
                 {"above_overload_s", r.above_overload_s}});
  }
  return {{"reference_a", reference_a},
          {"overload_a", overload_a},
          {"machining_time_s", machining_time_s},
          {"finished", finished},
          {"peak_a", peak_a},
          {"above_overload_s", above_overload_s},
          {"max_regulation_error", max_regulation_error},
          {"max_regulation_error_t_s", max_regulation_error_t_s},
          {"max_regulation_error_s_mm", max_regulation_error_s_mm},
          {"steps", s},
          {"alarms", alarms}};
}

FeedControlFigures FiguresOf(const std::vector<FeedSample>& samples, const sim::EngagementProfile& profile,
                             const FeedControlOptions& options) {
  FeedControlFigures f;
  f.reference_a = options.controller.ReferenceCurrentA();
  f.overload_a = options.controller.OverloadCurrentA();
  const double dt = options.controller.sample_s;
  std::vector<std::pair<double, double>> excluded;  // time windows left out of the regulation figure
  for (double s_step : StepPositions(profile, options.plant)) {
    auto cross = std::find_if(samples.begin(), samples.end(), [&](const FeedSample& x) { return x.s_mm >= s_step; });
    if (cross == samples.end()) continue;
    StepResponse r{s_step, cross->t_s, 0, 0, 0};
    for (auto it = cross; it != samples.end() && it->t_s <= r.t_cross_s + 1.0; ++it) {
      r.peak_a = std::max(r.peak_a, it->current_a);
      if (it->current_a > f.overload_a) r.above_overload_s += dt;
      if (std::abs(it->current_a - f.reference_a) > 0.05 * f.reference_a) r.settle_s = it->t_s - r.t_cross_s;
    }
    excluded.emplace_back(r.t_cross_s, r.t_cross_s + 1.0);
    f.steps.push_back(r);
  }
  std::optional<double> air_until;
  for (const FeedSample& x : samples) {
    f.peak_a = std::max(f.peak_a, x.current_a);
    if (x.a_e_mm <= 0 || x.a_p_mm <= 0) {
      air_until = x.t_s + 1.0;
      continue;
    }
    if (x.t_s < 1.0 || (air_until && x.t_s <= *air_until)) continue;
    bool leaving = false;  // air within the next 10 mm: the load runs out, nothing to regulate
    for (int k = 1; k <= 10 && !leaving; ++k) leaving = Load(options.plant, profile.At(x.s_mm + k)) == 0;
    if (leaving) continue;
    bool skip = false;
    for (const auto& w : excluded) skip = skip || (x.t_s >= w.first && x.t_s <= w.second);
    const double error = std::abs(x.current_a - f.reference_a) / f.reference_a;
    if (!skip && error > f.max_regulation_error) {
      f.max_regulation_error = error;
      f.max_regulation_error_t_s = x.t_s;
      f.max_regulation_error_s_mm = x.s_mm;
    }
  }
  return f;
}

Result<FeedControlResult> RunFeedControl(const sim::EngagementProfile& profile, const FeedControlOptions& options) {
  FL_ASSIGN_OR_RETURN(FuzzyFeedController controller, FuzzyFeedController::Create(options.controller));
  return Loop(profile, options, &controller, 0);
}

Result<FeedControlResult> RunConstantFeed(const sim::EngagementProfile& profile, const FeedControlOptions& options,
                                          double feed) {
  if (!(feed > 0)) return Status::BadInput("the constant feed must be > 0");
  return Loop(profile, options, nullptr, feed);
}

double ConservativeFeed(const sim::EngagementProfile& profile, const FeedControlOptions& options) {
  sim::EngagementSample heaviest;
  double load = 0;
  for (const sim::EngagementSample& e : profile.samples()) {
    if (Load(options.plant, e) > load) {
      load = Load(options.plant, e);
      heaviest = e;
    }
  }
  const sim::SpindlePlant plant(options.plant, profile, 1, 0);
  return plant.FeedForForce(heaviest, options.controller.rho_ref * options.controller.max_force_n);
}

FeedControlOptions ReferenceFeedControlOptions() {
  FeedControlOptions o;
  o.plant = sim::SpindlePlantOptions::Reference();
  FuzzyFeedOptions& c = o.controller;
  c.idle_current_a = o.plant.idle_current_a;
  c.current_per_force_a_per_n = o.plant.current_per_force_a_per_n;
  c.max_force_n = 300;
  c.rho_ref = 5.0 / 6.0;
  c.initial_feed_mm_per_min = 2942;
  c.max_feed_mm_per_min = std::min(0.15 * o.plant.flutes * o.plant.spindle_rpm, 5000.0);
  return o;
}

}  // namespace formloop::planning
