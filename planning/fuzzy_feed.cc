#include "planning/fuzzy_feed.h"

#include <fl/Headers.h>

#include <algorithm>
#include <cmath>

#include "core/point_io.h"

namespace formloop::planning {

const int kFuzzyFeedRuleTable[7][7] = {
    // EC: NB  NM  NS  ZO  PS  PM  PB
    {-3, -3, -3, -3, -2, -1, -1},  // E = NB
    {-3, -3, -3, -2, -1, -1, -1},  // E = NM
    {-3, -3, -2, -1, 0, 1, 2},     // E = NS
    {-3, -2, -1, 0, 1, 2, 3},      // E = ZO
    {-2, -1, 0, 1, 2, 3, 3},       // E = PS
    {-1, 0, 1, 2, 3, 3, 3},        // E = PM
    {0, 1, 2, 3, 3, 3, 3},         // E = PB
};

namespace {

const char* const kValues[7] = {"NB", "NM", "NS", "ZO", "PS", "PM", "PB"};

// The seven triangles of §2.2 on a variable (peaks −6, −4, ..., 6, feet ±2).
template <typename Variable>
void AddTerms(Variable* v) {
  for (int i = 0; i < 7; ++i) v->addTerm(new fl::Triangle(kValues[i], -8.0 + 2 * i, -6.0 + 2 * i, -4.0 + 2 * i));
}

}  // namespace

struct FuzzyFeedRules::Engine {
  fl::Engine engine;
  fl::InputVariable* e = nullptr;
  fl::InputVariable* ec = nullptr;
  fl::OutputVariable* u = nullptr;
};

FuzzyFeedRules::FuzzyFeedRules() : engine_(std::make_unique<Engine>()) {
  fl::Engine& eng = engine_->engine;
  eng.setName("formloop_feed");
  auto input = [&](const char* name) {
    auto* v = new fl::InputVariable(name, -6, 6);
    v->setLockValueInRange(true);
    AddTerms(v);
    eng.addInputVariable(v);
    return v;
  };
  engine_->e = input("E");
  engine_->ec = input("EC");
  auto* u = new fl::OutputVariable("U", -6.5, 6.5);
  u->setAggregation(new fl::Maximum);
  u->setDefuzzifier(new fl::Centroid(13));  // samples at −6, −5, ..., 6: the weighted average of §2.4
  u->setDefaultValue(0);
  AddTerms(u);
  eng.addOutputVariable(u);
  engine_->u = u;
  auto* block = new fl::RuleBlock("rules");
  block->setConjunction(new fl::Minimum);
  block->setDisjunction(new fl::Maximum);
  block->setImplication(new fl::Minimum);
  block->setActivation(new fl::General);
  for (int i = 0; i < 7; ++i) {
    for (int j = 0; j < 7; ++j) {
      const std::string rule = std::string("if E is ") + kValues[i] + " and EC is " + kValues[j] + " then U is " +
                               kValues[kFuzzyFeedRuleTable[i][j] + 3];
      block->addRule(fl::Rule::parse(rule, &eng));
    }
  }
  eng.addRuleBlock(block);
}

FuzzyFeedRules::~FuzzyFeedRules() = default;
FuzzyFeedRules::FuzzyFeedRules(FuzzyFeedRules&&) noexcept = default;
FuzzyFeedRules& FuzzyFeedRules::operator=(FuzzyFeedRules&&) noexcept = default;

double FuzzyFeedRules::Infer(double e, double ec) {
  engine_->e->setValue(std::clamp(e, -6.0, 6.0));
  engine_->ec->setValue(std::clamp(ec, -6.0, 6.0));
  engine_->engine.process();
  return engine_->u->getValue();
}

std::string FuzzyFeedRules::Fll() const { return fl::FllExporter().toString(&engine_->engine); }

const char* FeedModeName(FeedMode mode) {
  switch (mode) {
    case FeedMode::kRules:
      return "rules";
    case FeedMode::kOverload:
      return "overload";
    case FeedMode::kAirCut:
      return "air_cut";
    case FeedMode::kVoltageHold:
      return "voltage_hold";
    case FeedMode::kTrip:
      return "trip";
    case FeedMode::kSupplyAlarm:
      return "supply_alarm";
  }
  return "unknown";
}

Status FuzzyFeedOptions::Validate() const {
  if (!(sample_s >= 0.005 && sample_s <= 0.050)) {
    return Status::BadInput(Where{.field = "sample_s"}, "the sample time must lie in 5-50 ms");
  }
  for (double v : {e_max_a, ec_max_a_per_s, gain_per_level, current_per_force_a_per_n, max_force_n,
                   initial_feed_mm_per_min, max_feed_mm_per_min, nominal_voltage_v, override_resolution}) {
    if (!(v > 0)) {
      return Status::BadInput(
          "fuzzy feed control: E_max, EC_max, gain, k_I, F_max, v_f,0, v_f,max, U_nom and the "
          "override resolution must be > 0");
    }
  }
  if (!(idle_current_a >= 0)) return Status::BadInput(Where{.field = "idle_current_a"}, "must be >= 0");
  if (!(rho_ref >= 0.7 && rho_ref <= 1.0)) {
    return Status::BadInput(Where{.field = "rho_ref"}, "must lie in [0.7, 1.0] (§2.1)");
  }
  return Status::Ok();
}

double FuzzyFeedOptions::ReferenceCurrentA() const {
  return idle_current_a + current_per_force_a_per_n * rho_ref * max_force_n;
}
double FuzzyFeedOptions::OverloadCurrentA() const {
  return idle_current_a + current_per_force_a_per_n * 1.25 * max_force_n;
}
double FuzzyFeedOptions::TripCurrentA() const { return idle_current_a + current_per_force_a_per_n * 1.6 * max_force_n; }

Result<FuzzyFeedController> FuzzyFeedController::Create(const FuzzyFeedOptions& options) {
  FL_RETURN_IF_ERROR(options.Validate());
  FuzzyFeedController c;
  c.options_ = options;
  c.feed_ = options.initial_feed_mm_per_min;
  c.command_ = c.feed_;
  return c;
}

double FuzzyFeedController::Update(double current, double voltage) {
  const FuzzyFeedOptions& o = options_;
  const double v0 = o.initial_feed_mm_per_min;
  const double i_ref = o.ReferenceCurrentA();
  const double e = i_ref - current;
  const double ec = first_ ? 0.0 : (e - e_prev_) / o.sample_s;
  first_ = false;
  e_prev_ = e;
  const double du = (voltage - o.nominal_voltage_v) / o.nominal_voltage_v;

  trip_count_ = current >= o.TripCurrentA() ? trip_count_ + 1 : 0;
  low_count_ = du < -0.15 ? low_count_ + 1 : 0;
  if (mode_ != FeedMode::kTrip && trip_count_ >= 3) {
    mode_ = FeedMode::kTrip;
    alarms_.push_back("L2-TRIP: load current at or above I_trip = " + FormatFixed(o.TripCurrentA(), 2) +
                      " A for 3 samples; feed held");
  }
  if (mode_ != FeedMode::kTrip && mode_ != FeedMode::kSupplyAlarm && low_count_ >= 10) {
    mode_ = FeedMode::kSupplyAlarm;
    alarms_.push_back("L2-SUPPLY: supply voltage more than 15 % low for 10 samples; feed held");
  }
  if (mode_ == FeedMode::kTrip || mode_ == FeedMode::kSupplyAlarm) {
    feed_ = 0;
    command_ = 0;
    return command_;
  }
  // Voltage hold: entered beyond ±5 %, left after 20 samples within ±3 % (E_{k−1} := E_k: no EC kick).
  bool leaving_hold = false;
  if (std::abs(du) > 0.05) {
    voltage_hold_ = true;
    ok_count_ = 0;
  } else if (voltage_hold_) {
    ok_count_ = std::abs(du) <= 0.03 ? ok_count_ + 1 : 0;
    if (ok_count_ >= 20) {
      voltage_hold_ = false;
      leaving_hold = true;
    }
  }
  const double hi = std::min(2 * v0, o.max_feed_mm_per_min), lo = 0.1 * v0;
  const double k_u = o.gain_per_level * v0;
  if (current >= o.OverloadCurrentA()) {
    mode_ = FeedMode::kOverload;
    feed_ += k_u * -6;
  } else if (current < o.idle_current_a + 0.1 * (i_ref - o.idle_current_a)) {
    mode_ = FeedMode::kAirCut;
    feed_ = v0;
  } else if (voltage_hold_) {
    mode_ = FeedMode::kVoltageHold;
  } else {
    mode_ = FeedMode::kRules;
    const double ec_used = leaving_hold ? 0.0 : ec;
    feed_ += k_u * rules_.Infer(6 * e / o.e_max_a, 6 * ec_used / o.ec_max_a_per_s);
  }
  feed_ = std::clamp(feed_, lo, std::max(lo, hi));
  // Sent as an override of v_f,0 with the controller's resolution.
  command_ = v0 * o.override_resolution * std::round(feed_ / (v0 * o.override_resolution));
  return command_;
}

}  // namespace formloop::planning
