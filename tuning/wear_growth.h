#pragma once
// Tool-wear growth: a model that predicts how much a tool wears before the next measurement, so the wear
// offset can follow it, and its evaluation against a constant-rate baseline (issue 21; seed 004 applies
// measured corrections only).
//
// Model. The wear rate grows with the wear itself (the longer the flank wear land, the larger the contact
// and the faster it wears; the accelerating third stage of the classical three-stage curve):
//   dVB/dt = r·exp(γ·VB)   ⇔   W(VB) = (1 − exp(−γ·VB))/γ = W0 + r·t,
// so in the transformed wear W a tool's history is a straight line. W0 absorbs the fast initial
// (break-in) wear, r is the tool's own rate, γ (1/mm) the shape, shared by tools of a process and learned
// from other tools; γ = 0 is the constant-rate baseline (W = VB). A prediction is anchored at the last
// measurement: VB(t) = W⁻¹(W(VB_k) + r·(t − t_k)); when 1 − γ·W reaches 0 the model's wear diverges and the
// prediction is capped at W⁻¹ of 1 − 1e-12 (a sign the tool is at the end of its life).
//
// Fitting. (W0, r): least squares of the line in W over the tool's history. γ: minimises the squared error,
// over training tools, of predicting the second half of each tool's measurements from its first half
// (grid over [gamma_min, gamma_max], then golden section around the best grid point).
//
// Evaluation (EvaluateWearGrowth). Per case, in-sample: the line fitted to all its points with γ from all
// cases, RMSE against γ = 0. Leave one case out: γ from the other cases, then (a) one step ahead: each
// measurement i + 1 predicted from the measurements 0..i (≥ min_history of them); (b) horizon: the second
// half from the first half. Both against the constant-rate baseline on the same points.
//
// From flank wear to a radius offset: a flank wear land VB on a clearance face at angle α (rake γ_r)
// moves the cutting edge back by VB·tanα/(1 − tanα·tanγ_r) (the geometric relation of the flank wear land;
// M. C. Shaw, Metal Cutting Principles, 2nd ed., 2005, ch. 12). VB as in ISO 3685 / ISO 8688-2.

#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "core/status.h"

namespace formloop::tuning {

struct WearSeries {
  std::string name;
  std::vector<double> time;     // increasing (min, cycles, parts: any unit, used consistently)
  std::vector<double> wear_mm;  // VB
};

struct WearLine {
  double w0 = 0;    // W at t = 0
  double rate = 0;  // r, W per time unit
};

double WearTransform(double vb_mm, double gamma);
double WearInverse(double w, double gamma);
// Least-squares line in W over points [first, first + count) of the series; count ≥ 2 with distinct times.
Result<WearLine> FitWearLine(const WearSeries& series, double gamma, std::size_t first, std::size_t count);
// VB at time t, anchored at the measurement (t_last, vb_last).
double PredictWear(const WearLine& line, double gamma, double t_last, double vb_last, double t);
// The wear increase from the last of the first `history` measurements to time t_next: the next offset
// change (in VB; see RadialWearFromFlankWear).
Result<double> PredictNextWearChange(const WearSeries& series, std::size_t history, double gamma, double t_next);
// Radial recession of the cutting edge for a flank wear land (see header).
double RadialWearFromFlankWear(double vb_mm, double clearance_deg, double rake_deg = 0);

struct WearGrowthOptions {
  double gamma_min = -3, gamma_max = 8;  // 1/mm
  int grid = 45;                         // grid points before the golden section
  double horizon_fraction = 0.5;         // the first half predicts the second
  int min_history = 2;                   // measurements before a one-step prediction
  Status Validate() const;
};

// The shape γ that best predicts the second half of each training series from its first half.
Result<double> FitGrowthShape(const std::vector<WearSeries>& training, const WearGrowthOptions& options = {});

struct WearCaseEvaluation {
  std::string name;
  int points = 0;
  double fit_rmse_model = 0, fit_rmse_constant = 0;  // in-sample, mm
  double gamma_loco = 0;                             // γ from the other cases
  int one_step_n = 0;
  double one_step_rmse_model = 0, one_step_rmse_constant = 0;  // leave one case out, mm
  int horizon_n = 0;
  double horizon_rmse_model = 0, horizon_rmse_constant = 0;  // leave one case out, mm
};

struct WearEvaluation {
  double gamma_all = 0;
  std::vector<WearCaseEvaluation> cases;
  // Pooled over every predicted point of every case (√(Σe²/n)).
  double one_step_rmse_model = 0, one_step_rmse_constant = 0;
  double horizon_rmse_model = 0, horizon_rmse_constant = 0;
  double fit_rmse_model = 0, fit_rmse_constant = 0;
  nlohmann::json ToJson() const;
};

// Needs at least 3 series with at least 3 measurements each (shorter series are an error naming them).
Result<WearEvaluation> EvaluateWearGrowth(const std::vector<WearSeries>& cases, const WearGrowthOptions& options = {});

}  // namespace formloop::tuning
