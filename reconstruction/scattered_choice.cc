// The choice of λ and of the automatic control net for a scattered fit (scattered_choice.h).

#include "reconstruction/scattered_choice.h"

#include <algorithm>
#include <cmath>
#include <limits>

#include "core/golden_section.h"
#include "core/number_text.h"

namespace formloop::recon::scattered_internal {

namespace {

using Eigen::Vector3d;

// log10 of the dimensionless λ searched by GCV and kTolerance. Below 1e-12 the penalty is lost in
// the rounding of AᵀA (its entries carry ~1e-16 relative error, times the net's conditioning);
// above 1e6 the surface is the penalty's limit (the polynomial trend) to many digits.
constexpr double kLogLambdaMin = -12;
constexpr double kLogLambdaMax = 6;

// ---------------------------------------------------------------------------------------------
// Choice of λ for fixed parameters.

// GCV: a grid over log10 λ, then golden-section search around the best grid point (see below for
// the grid); previous_log is the choice of the previous correction round, NaN for the first.
LambdaChoice ChooseByGcv(TensorLsq& lsq, double previous_log) {
  std::vector<std::pair<double, TensorLsq::Trial>> grid;
  auto eval = [&](double log_lambda) {
    for (const auto& [x, t] : grid) {
      if (x == log_lambda) return t.gcv;
    }
    grid.emplace_back(log_lambda, lsq.Solve(std::pow(10.0, log_lambda), true, true));
    return grid.back().second.gcv;
  };
  auto best_index = [&] {
    std::size_t best = 0;
    for (std::size_t k = 1; k < grid.size(); ++k) {
      if (grid[k].second.gcv < grid[best].second.gcv) best = k;
    }
    return best;
  };
  // First choice: every second decade of the range (V is smooth in log λ), then golden section
  // over ±2 decades. Later rounds (same data, parameters moved): a ±1 decade window around the
  // previous choice in half decades, widened while its minimum sits on an edge that is not the
  // range's.
  double lo = kLogLambdaMin, hi = kLogLambdaMax, step = 2;
  if (std::isfinite(previous_log)) {
    // Usually the choice does not move: keep it when it is still a local minimum at ±1/4 decade
    // (the GCV curve is flat to a few per cent over that distance).
    const double x0 = std::clamp(previous_log, kLogLambdaMin, kLogLambdaMax);
    const double f0 = eval(x0);
    const double below = x0 - 0.25 >= kLogLambdaMin ? eval(x0 - 0.25) : std::numeric_limits<double>::infinity();
    const double above = x0 + 0.25 <= kLogLambdaMax ? eval(x0 + 0.25) : std::numeric_limits<double>::infinity();
    if (std::isfinite(f0) && f0 <= below && f0 <= above) return LambdaChoice{grid[best_index()].second, ""};
    lo = std::max(kLogLambdaMin, previous_log - 1);
    hi = std::min(kLogLambdaMax, previous_log + 1);
    step = 0.5;
  }
  for (double x = lo; x <= hi + 1e-9; x += step) eval(std::min(x, hi));
  // No λ in the window gave a positive definite system (poles without data need smoothing):
  // search upwards.
  while (!std::isfinite(grid[best_index()].second.gcv) && hi < kLogLambdaMax) {
    hi = std::min(kLogLambdaMax, hi + 1);
    lo = hi;
    eval(hi);
  }
  if (!std::isfinite(grid[best_index()].second.gcv)) return LambdaChoice{grid[best_index()].second, ""};
  for (;;) {
    const double x = grid[best_index()].first;
    if (x <= lo && lo > kLogLambdaMin) {
      lo = std::max(kLogLambdaMin, lo - step);
      eval(lo);
    } else if (x >= hi && hi < kLogLambdaMax) {
      hi = std::min(kLogLambdaMax, hi + step);
      eval(hi);
    } else {
      break;
    }
  }
  const double centre = grid[best_index()].first;
  double a = std::max(kLogLambdaMin, centre - step), b = std::min(kLogLambdaMax, centre + step);
  GoldenSectionOptions golden;  // every evaluation lands in the grid; the best one is chosen below
  golden.tolerance = 0.1;
  golden.ties_keep_left = true;
  GoldenSectionMinimise(eval, a, b, golden);
  LambdaChoice choice;
  choice.trial = grid[best_index()].second;
  return choice;
}

// kTolerance: bisection on log10 λ for RMS(λ) = tolerance (RMS grows with λ).
LambdaChoice ChooseByTolerance(TensorLsq& lsq, double tolerance_mm, int m) {
  auto rms = [&](const TensorLsq::Trial& t) {
    return t.ok ? std::sqrt(t.rss / m) : std::numeric_limits<double>::infinity();
  };
  LambdaChoice choice;
  TensorLsq::Trial low = lsq.Solve(std::pow(10.0, kLogLambdaMin), false);
  if (!(rms(low) < tolerance_mm)) {
    choice.trial = low;
    choice.note = "smoothing to a tolerance: even the smallest weight (lambda = 1e-12) leaves an RMS residual of " +
                  FormatSignificant(rms(low), 6) + " mm > the target " + FormatSignificant(tolerance_mm, 6) +
                  " mm: the points scatter more than that about any surface of this net (noise, or a net too "
                  "coarse for the shape: then more poles or adaptive refinement help)";
    return choice;
  }
  TensorLsq::Trial high = lsq.Solve(std::pow(10.0, kLogLambdaMax), false);
  if (rms(high) <= tolerance_mm) {
    choice.trial = high;
    choice.note =
        "smoothing to a tolerance: the smoothest surface searched (lambda = 1e6) already has an RMS "
        "residual of " +
        FormatSignificant(rms(high), 6) + " mm <= the target " + FormatSignificant(tolerance_mm, 6) + " mm";
    return choice;
  }
  double a = kLogLambdaMin, b = kLogLambdaMax;
  TensorLsq::Trial best = low;
  for (int iter = 0; iter < 60 && b - a > 1e-4; ++iter) {
    const double mid = 0.5 * (a + b);
    TensorLsq::Trial t = lsq.Solve(std::pow(10.0, mid), false);
    const double r = rms(t);
    if (r <= tolerance_mm) {
      a = mid;
      best = std::move(t);
      if (r >= tolerance_mm * (1 - 1e-3)) break;
    } else {
      b = mid;
    }
  }
  choice.trial = std::move(best);
  return choice;
}

// The ladder stops at the first rung that scores worse when the best rung's score fell by less than this
// (relative) from the rung before it; otherwise it climbs on to the finest rung. Measured: 100,000 points on
// issue 26's recipe fall by 0.08 % at the best rung (25 × 25) and rise after it; egg_box with 10,000 points
// scores 5 × 4 far better than 4 × 4 and then worse for several rungs (aliasing) before a fine net fits it
// (stopping there left 0.9 mm of error).
constexpr double kNetFlatGain = 0.05;
// ... and only once the best score is below this share of the first (coarsest) rung's: a flat stretch above
// it means the nets do not resolve the shape yet (egg_box, 10,000 points: 4 × 4 to 6 × 5 all score 0.31-0.32
// mm²), not that they reached the noise. Data a coarse net already fits (a plane) so climb the whole ladder.
constexpr double kNetResolved = 0.1;

}  // namespace

// target_mm: the parametric RMS kTolerance aims at (see FitWithCorrection).
LambdaChoice ChooseLambda(TensorLsq& lsq, const ScatteredFitOptions& options, double previous_log, int m,
                          double target_mm) {
  switch (options.smoothing) {
    case ScatteredFitOptions::Smoothing::kGcv: {
      // λ by GCV with the uniform energy, then the energy weighted locally from that pilot's bias
      // (TensorLsq::LocalWeights) and the fit solved again at the same λ.
      lsq.WeightEnergy(nullptr);
      LambdaChoice choice = ChooseByGcv(lsq, previous_log);
      if (!choice.trial.ok) return choice;
      const Eigen::MatrixXd weights = lsq.LocalWeights(choice.trial);
      if (weights.minCoeff() >= 1) return choice;  // no weight lowered: the pilot is the fit
      lsq.WeightEnergy(&weights);
      TensorLsq::Trial local = lsq.Solve(choice.trial.lambda, true);
      if (local.ok) {
        local.min_weight = weights.minCoeff();
        local.mean_weight = weights.mean();
        choice.trial = std::move(local);
      }
      return choice;
    }
    case ScatteredFitOptions::Smoothing::kTolerance: {
      // The search needs no trace; the chosen fit gets it for the report.
      LambdaChoice choice = ChooseByTolerance(lsq, target_mm, m);
      if (choice.trial.ok) choice.trial = lsq.Solve(choice.trial.lambda, true);
      return choice;
    }
    case ScatteredFitOptions::Smoothing::kNone: {
      LambdaChoice choice;
      choice.trial = lsq.Solve(kScatteredNoneLambda, true);
      return choice;
    }
    case ScatteredFitOptions::Smoothing::kFixed:
      break;
  }
  LambdaChoice choice;
  choice.trial = lsq.Solve(options.lambda, true);
  return choice;
}

// ---------------------------------------------------------------------------------------------
// The automatic control net.

Result<NetChoice> ChooseNet(const std::vector<Vector3d>& centred, const std::vector<double>& u,
                            const std::vector<double>& v, int p, int nu_max, int nv_max, const NetKnots& knots) {
  const int m = static_cast<int>(centred.size());
  std::vector<int> rungs;
  for (int a = p + 1; a < nu_max; a = std::max(a + 1, static_cast<int>(std::lround(a * kScatteredNetLadderRatio)))) {
    rungs.push_back(a);
  }
  rungs.push_back(nu_max);
  NetChoice best;
  double best_score = std::numeric_limits<double>::infinity();
  double last_gain = 1;  // relative fall of the score at the best rung (the first rung: not flat)
  double first_score = std::numeric_limits<double>::quiet_NaN();
  for (const int a : rungs) {
    const int b = std::clamp(static_cast<int>(std::lround(static_cast<double>(a) * nv_max / nu_max)), p + 1, nv_max);
    const double unknowns = static_cast<double>(a) * b;
    if (unknowns >= m) break;
    const auto [ku, kv] = knots(a, b);
    FL_RETURN_IF_ERROR(ku.status());
    FL_RETURN_IF_ERROR(kv.status());
    auto lsq = std::make_unique<TensorLsq>(*ku, *kv, ParamDomain{ku->lo(), ku->hi(), kv->lo(), kv->hi()});
    lsq->Assemble(u, v, centred, false);
    const TensorLsq::Trial trial = lsq->Solve(kScatteredNoneLambda, false);
    const double dof_left = 1 - unknowns / m;
    const double score =
        trial.ok ? (trial.rss / (3.0 * m)) / (dof_left * dof_left) : std::numeric_limits<double>::infinity();
    best.ladder.push_back({a, b, score});
    if (std::isnan(first_score)) first_score = score;
    if (score < best_score) {
      last_gain = std::isfinite(best_score) ? (best_score - score) / best_score : 1.0;
      best_score = score;
      best.nu = a;
      best.nv = b;
      best.assembled = std::move(lsq);
    } else if (best.nu > 0 && last_gain < kNetFlatGain && best_score < kNetResolved * first_score) {
      // The score stopped falling where it had flattened (the noise floor). Where it was still falling
      // steeply the ladder goes on: a coarse net can alias an oscillating surface, so the next rungs may
      // score worse before a fine enough one fits it.
      break;
    }
  }
  if (best.nu == 0) {
    return Status::Failed("scattered fit: no control net of the automatic ladder could be fitted (" +
                          std::to_string(m) + " points); give --poles");
  }
  return best;
}

}  // namespace formloop::recon::scattered_internal
