#include "tuning/wear_growth.h"

#include <algorithm>
#include <cmath>
#include <numbers>

#include "core/golden_section.h"

namespace formloop::tuning {
namespace {

constexpr double kTinyGamma = 1e-12;

// Index of the last measurement of the first part: ⌈fraction·n⌉ measurements, at least 2.
std::size_t HistoryCount(std::size_t n, double fraction) {
  return std::max<std::size_t>(2, static_cast<std::size_t>(std::ceil(fraction * static_cast<double>(n))));
}

// Squared errors of predicting the points after the first `history` from them.
void HorizonErrors(const WearSeries& s, double gamma, std::size_t history, std::vector<double>* errors) {
  auto line = FitWearLine(s, gamma, 0, history);
  if (!line.ok()) return;
  for (std::size_t i = history; i < s.time.size(); ++i) {
    const double p = PredictWear(*line, gamma, s.time[history - 1], s.wear_mm[history - 1], s.time[i]);
    errors->push_back(p - s.wear_mm[i]);
  }
}

void OneStepErrors(const WearSeries& s, double gamma, int min_history, std::vector<double>* errors) {
  for (std::size_t i = static_cast<std::size_t>(min_history); i < s.time.size(); ++i) {
    auto change = PredictNextWearChange(s, i, gamma, s.time[i]);
    if (!change.ok()) continue;
    errors->push_back(s.wear_mm[i - 1] + *change - s.wear_mm[i]);
  }
}

double Rms(const std::vector<double>& e) {
  if (e.empty()) return 0;
  double s = 0;
  for (double v : e) s += v * v;
  return std::sqrt(s / static_cast<double>(e.size()));
}

}  // namespace

double WearTransform(double vb, double gamma) {
  return std::abs(gamma) < kTinyGamma ? vb : (1 - std::exp(-gamma * vb)) / gamma;
}

double WearInverse(double w, double gamma) {
  return std::abs(gamma) < kTinyGamma ? w : -std::log(std::max(1 - gamma * w, 1e-12)) / gamma;
}

Result<WearLine> FitWearLine(const WearSeries& s, double gamma, std::size_t first, std::size_t count) {
  if (count < 2 || first + count > s.time.size() || s.time.size() != s.wear_mm.size()) {
    return Status::BadInput("wear series '" + s.name + "': a line needs 2 measurements or more");
  }
  double mt = 0, mw = 0;
  for (std::size_t i = first; i < first + count; ++i) {
    mt += s.time[i];
    mw += WearTransform(s.wear_mm[i], gamma);
  }
  mt /= static_cast<double>(count);
  mw /= static_cast<double>(count);
  double stt = 0, stw = 0;
  for (std::size_t i = first; i < first + count; ++i) {
    stt += (s.time[i] - mt) * (s.time[i] - mt);
    stw += (s.time[i] - mt) * (WearTransform(s.wear_mm[i], gamma) - mw);
  }
  if (!(stt > 0)) return Status::BadInput("wear series '" + s.name + "': the measurements share one time");
  WearLine line;
  line.rate = stw / stt;
  line.w0 = mw - line.rate * mt;
  return line;
}

double PredictWear(const WearLine& line, double gamma, double t_last, double vb_last, double t) {
  return WearInverse(WearTransform(vb_last, gamma) + line.rate * (t - t_last), gamma);
}

Result<double> PredictNextWearChange(const WearSeries& s, std::size_t history, double gamma, double t_next) {
  FL_ASSIGN_OR_RETURN(const WearLine line, FitWearLine(s, gamma, 0, history));
  const double last = s.wear_mm[history - 1];
  return PredictWear(line, gamma, s.time[history - 1], last, t_next) - last;
}

double RadialWearFromFlankWear(double vb_mm, double clearance_deg, double rake_deg) {
  const double ta = std::tan(clearance_deg * std::numbers::pi / 180);
  const double tg = std::tan(rake_deg * std::numbers::pi / 180);
  return vb_mm * ta / (1 - ta * tg);
}

Status WearGrowthOptions::Validate() const {
  if (!(gamma_min < gamma_max))
    return Status::BadInput(Where{.field = "gamma_min/gamma_max"}, "need gamma_min < gamma_max");
  if (grid < 3) return Status::BadInput(Where{.field = "grid"}, "must be >= 3");
  if (!(horizon_fraction > 0 && horizon_fraction < 1)) {
    return Status::BadInput(Where{.field = "horizon_fraction"}, "must be in (0, 1)");
  }
  if (min_history < 2) return Status::BadInput(Where{.field = "min_history"}, "must be >= 2");
  return Status::Ok();
}

Result<double> FitGrowthShape(const std::vector<WearSeries>& training, const WearGrowthOptions& options) {
  FL_RETURN_IF_ERROR(options.Validate());
  if (training.empty()) return Status::BadInput("wear growth: no training series");
  auto cost = [&](double gamma) {
    std::vector<double> e;
    for (const auto& s : training) HorizonErrors(s, gamma, HistoryCount(s.time.size(), options.horizon_fraction), &e);
    double sum = 0;
    for (double v : e) sum += v * v;
    return sum;
  };
  const double step = (options.gamma_max - options.gamma_min) / (options.grid - 1);
  int best = 0;
  double best_cost = cost(options.gamma_min);
  for (int i = 1; i < options.grid; ++i) {
    const double c = cost(options.gamma_min + i * step);
    if (c < best_cost) {
      best_cost = c;
      best = i;
    }
  }
  // Golden section on the bracket around the best grid point.
  const double lo = options.gamma_min + std::max(0, best - 1) * step,
               hi = options.gamma_min + std::min(options.grid - 1, best + 1) * step;
  const double gamma = GoldenSectionMinimise(cost, lo, hi, {.tolerance = 1e-7, .max_iterations = 60}).Mid();
  return cost(gamma) <= best_cost ? gamma : options.gamma_min + best * step;
}

Result<WearEvaluation> EvaluateWearGrowth(const std::vector<WearSeries>& cases, const WearGrowthOptions& options) {
  FL_RETURN_IF_ERROR(options.Validate());
  if (cases.size() < 3) return Status::BadInput("wear growth: leave-one-case-out needs at least 3 series");
  for (const auto& s : cases) {
    if (s.time.size() < 3 || s.time.size() != s.wear_mm.size()) {
      return Status::BadInput("wear series '" + s.name + "': needs at least 3 measurements (has " +
                              std::to_string(s.time.size()) + ")");
    }
  }
  WearEvaluation out;
  FL_ASSIGN_OR_RETURN(out.gamma_all, FitGrowthShape(cases, options));
  std::vector<double> fit_m, fit_c, one_m, one_c, hor_m, hor_c;
  for (std::size_t c = 0; c < cases.size(); ++c) {
    const WearSeries& s = cases[c];
    WearCaseEvaluation e;
    e.name = s.name;
    e.points = static_cast<int>(s.time.size());
    // In-sample: the line through every point, γ from all cases vs γ = 0.
    std::vector<double> rm, rc;
    for (const auto& [gamma, res] : {std::pair<double, std::vector<double>*>{out.gamma_all, &rm}, {0.0, &rc}}) {
      FL_ASSIGN_OR_RETURN(const WearLine line, FitWearLine(s, gamma, 0, s.time.size()));
      for (std::size_t i = 0; i < s.time.size(); ++i) {
        res->push_back(WearInverse(line.w0 + line.rate * s.time[i], gamma) - s.wear_mm[i]);
      }
    }
    e.fit_rmse_model = Rms(rm);
    e.fit_rmse_constant = Rms(rc);
    fit_m.insert(fit_m.end(), rm.begin(), rm.end());
    fit_c.insert(fit_c.end(), rc.begin(), rc.end());
    // Leave this case out for γ.
    std::vector<WearSeries> others;
    for (std::size_t o = 0; o < cases.size(); ++o) {
      if (o != c) others.push_back(cases[o]);
    }
    FL_ASSIGN_OR_RETURN(e.gamma_loco, FitGrowthShape(others, options));
    std::vector<double> om, oc, hm, hc;
    OneStepErrors(s, e.gamma_loco, options.min_history, &om);
    OneStepErrors(s, 0.0, options.min_history, &oc);
    const std::size_t history = HistoryCount(s.time.size(), options.horizon_fraction);
    HorizonErrors(s, e.gamma_loco, history, &hm);
    HorizonErrors(s, 0.0, history, &hc);
    e.one_step_n = static_cast<int>(om.size());
    e.one_step_rmse_model = Rms(om);
    e.one_step_rmse_constant = Rms(oc);
    e.horizon_n = static_cast<int>(hm.size());
    e.horizon_rmse_model = Rms(hm);
    e.horizon_rmse_constant = Rms(hc);
    one_m.insert(one_m.end(), om.begin(), om.end());
    one_c.insert(one_c.end(), oc.begin(), oc.end());
    hor_m.insert(hor_m.end(), hm.begin(), hm.end());
    hor_c.insert(hor_c.end(), hc.begin(), hc.end());
    out.cases.push_back(e);
  }
  out.fit_rmse_model = Rms(fit_m);
  out.fit_rmse_constant = Rms(fit_c);
  out.one_step_rmse_model = Rms(one_m);
  out.one_step_rmse_constant = Rms(one_c);
  out.horizon_rmse_model = Rms(hor_m);
  out.horizon_rmse_constant = Rms(hor_c);
  return out;
}

nlohmann::json WearEvaluation::ToJson() const {
  nlohmann::json cs = nlohmann::json::array();
  for (const auto& c : cases) {
    cs.push_back({{"name", c.name},
                  {"points", c.points},
                  {"fit_rmse_model_mm", c.fit_rmse_model},
                  {"fit_rmse_constant_mm", c.fit_rmse_constant},
                  {"gamma_loco_per_mm", c.gamma_loco},
                  {"one_step_n", c.one_step_n},
                  {"one_step_rmse_model_mm", c.one_step_rmse_model},
                  {"one_step_rmse_constant_mm", c.one_step_rmse_constant},
                  {"horizon_n", c.horizon_n},
                  {"horizon_rmse_model_mm", c.horizon_rmse_model},
                  {"horizon_rmse_constant_mm", c.horizon_rmse_constant}});
  }
  return {{"gamma_all_per_mm", gamma_all},
          {"fit_rmse_model_mm", fit_rmse_model},
          {"fit_rmse_constant_mm", fit_rmse_constant},
          {"one_step_rmse_model_mm", one_step_rmse_model},
          {"one_step_rmse_constant_mm", one_step_rmse_constant},
          {"horizon_rmse_model_mm", horizon_rmse_model},
          {"horizon_rmse_constant_mm", horizon_rmse_constant},
          {"cases", cs}};
}

}  // namespace formloop::tuning
