#pragma once
// Seeded random offset-tuning scenarios with K like real parts (tests and bench of issue 21).
//
// Offsets: tool radius wear (≈ 45 %), tool length wear (≈ 30 %) and work offsets along X/Y/Z
// (≈ 25 %). Dimensions, each drawn from the kinds a prismatic part has (spec §1.2):
//   outer size (boss width, outer diameter)      K = +2 on one radius wear
//   inner size (slot width, bore)                 K = −2 on one radius wear
//   wall placed from a datum                      K = ±1 radius wear, +1 on a work offset
//   height of a top face above a datum            K = +1 length wear (+1 work Z)
//   pocket depth from an uncut face               K = −1 length wear
//   step between faces of two tools               K = +1 / −1 on two length wears
//   feature position                              K = ±1 on a work offset
// The measured deviation is e = K·c_true + t_true + noise, with c_true the offset error (inside the
// offset bounds) and t_true the part of each dimension no offset reaches (inside the central half of its
// band, so the scenario is feasible). An infeasible scenario adds a second copy of one dimension (same K
// row) whose t lies beyond the band on the opposite side, so no offset can bring both in.
//
// After a change δq is applied, the next part is simulated as K·(c_true + δq) + t_true + fresh process
// noise.

#include <algorithm>
#include <cstdint>
#include <string>
#include <vector>

#include <Eigen/Core>
#include <Eigen/SparseCore>

#include "core/random.h"
#include "tuning/offset_solve.h"

namespace formloop::testing {

enum class OffsetKind { kRadiusWear, kLengthWear, kWork };

struct TuningScenario {
  tuning::OffsetProblem problem;
  std::vector<OffsetKind> kinds;
  Eigen::VectorXd c_true_mm;  // offset error shown by the part (δ = −c corrects it)
  Eigen::VectorXd t_true_mm;  // the non-compensable part of each dimension
  double process_sigma_mm = 0.0005;
  bool infeasible = false;  // built infeasible (see header)
};

struct ScenarioOptions {
  double measurement_sigma_mm = 0.0003;
  double process_sigma_mm = 0.0005;
  bool infeasible = false;
  bool single_offset_rows = false;  // every dimension on exactly one tool-wear offset (seed-004 parts)
  // t_true spread as a fraction of each half band (0.5: the central half, always feasible; > 1: some
  // dimensions beyond reach, so tolerance bounds become active) and the share of offsets whose bounds are
  // tight (±0.005 mm, so offset bounds become active). The bench uses both to exercise the bounded path.
  double t_spread = 0.5;
  double tight_offset_share = 0.0;
};

inline TuningScenario MakeTuningScenario(std::uint64_t seed, int n, int k, const ScenarioOptions& options = {}) {
  Rng rng(seed);
  TuningScenario s;
  s.process_sigma_mm = options.process_sigma_mm;
  s.infeasible = options.infeasible;
  auto& p = s.problem;
  // Offsets.
  s.kinds.resize(k);
  std::vector<int> radius, length, work;
  std::vector<int> work_axis(k, 0);
  for (int j = 0; j < k; ++j) {
    const double u = rng.Uniform();
    OffsetKind kind = u < 0.45 ? OffsetKind::kRadiusWear : (u < 0.75 ? OffsetKind::kLengthWear : OffsetKind::kWork);
    if (options.single_offset_rows) kind = j % 3 == 2 ? OffsetKind::kLengthWear : OffsetKind::kRadiusWear;
    if (j == 0) kind = OffsetKind::kRadiusWear;
    s.kinds[j] = kind;
    if (kind == OffsetKind::kRadiusWear) radius.push_back(j);
    if (kind == OffsetKind::kLengthWear) length.push_back(j);
    if (kind == OffsetKind::kWork) {
      work_axis[j] = static_cast<int>(work.size() % 3);
      work.push_back(j);
    }
    p.offset_ids.push_back((kind == OffsetKind::kRadiusWear   ? "R"
                            : kind == OffsetKind::kLengthWear ? "L"
                                                              : "W") +
                           std::to_string(j));
  }
  auto pick = [&](const std::vector<int>& from) { return from[rng.UniformIndex(from.size())]; };
  std::vector<Eigen::Triplet<double>> triplets;
  std::vector<std::vector<std::pair<int, double>>> rows;
  const int n_total = n + (options.infeasible ? 1 : 0);
  for (int i = 0; i < n; ++i) {
    std::vector<std::pair<int, double>> row;
    // The first k dimensions visit every offset once so no column is empty.
    const int forced = i < k ? i : -1;
    const OffsetKind want = forced >= 0 ? s.kinds[forced]
                                        : (options.single_offset_rows ? s.kinds[rng.UniformIndex(k)]
                                                                      : static_cast<OffsetKind>(rng.UniformIndex(3)));
    if (options.single_offset_rows) {
      const int j =
          forced >= 0 ? forced : (want == OffsetKind::kRadiusWear || length.empty() ? pick(radius) : pick(length));
      if (s.kinds[j] == OffsetKind::kRadiusWear) {
        row.push_back({j, rng.Uniform() < 0.5 ? 2.0 : -2.0});
      } else {
        row.push_back({j, rng.Uniform() < 0.5 ? 1.0 : -1.0});
      }
    } else if (want == OffsetKind::kRadiusWear || (want == OffsetKind::kLengthWear && length.empty()) ||
               (want == OffsetKind::kWork && work.empty())) {
      const int j = forced >= 0 && s.kinds[forced] == OffsetKind::kRadiusWear ? forced : pick(radius);
      const double u = rng.Uniform();
      if (u < 0.35) {
        row.push_back({j, 2.0});
      } else if (u < 0.7) {
        row.push_back({j, -2.0});
      } else {
        row.push_back({j, rng.Uniform() < 0.5 ? 1.0 : -1.0});
        if (!work.empty()) row.push_back({pick(work), 1.0});
      }
    } else if (want == OffsetKind::kLengthWear) {
      const int j = forced >= 0 ? forced : pick(length);
      const double u = rng.Uniform();
      if (u < 0.4) {
        row.push_back({j, 1.0});
        if (!work.empty() && rng.Uniform() < 0.5) row.push_back({pick(work), 1.0});
      } else if (u < 0.7 || length.size() < 2) {
        row.push_back({j, -1.0});
      } else {
        int j2 = pick(length);
        while (j2 == j) j2 = pick(length);
        row.push_back({j, 1.0});
        row.push_back({j2, -1.0});
      }
    } else {
      const int j = forced >= 0 ? forced : pick(work);
      row.push_back({j, rng.Uniform() < 0.5 ? 1.0 : -1.0});
    }
    rows.push_back(row);
  }
  if (options.infeasible) rows.push_back(rows[rng.UniformIndex(n)]);
  p.k.resize(n_total, k);
  for (int i = 0; i < n_total; ++i) {
    for (const auto& [j, v] : rows[i]) triplets.emplace_back(i, j, v);
  }
  p.k.setFromTriplets(triplets.begin(), triplets.end());
  // Tolerances, weights, targets.
  p.tol_lower_mm.resize(n_total);
  p.tol_upper_mm.resize(n_total);
  p.target_mm.resize(n_total);
  p.weight.resize(n_total);
  for (int i = 0; i < n_total; ++i) {
    p.dimension_ids.push_back("D" + std::to_string(i + 1));
    const double half = 0.001 * std::round(rng.Uniform(10, 40));
    const double u = rng.Uniform();
    if (u < 0.6) {
      p.tol_lower_mm(i) = -half;
      p.tol_upper_mm(i) = half;
    } else if (u < 0.8) {
      p.tol_lower_mm(i) = 0;
      p.tol_upper_mm(i) = 2 * half;
    } else {
      p.tol_lower_mm(i) = -2 * half;
      p.tol_upper_mm(i) = 0;
    }
    const bool centre = rng.Uniform() < 0.5 || p.tol_lower_mm(i) == 0 || p.tol_upper_mm(i) == 0;
    p.target_mm(i) = centre ? 0.5 * (p.tol_lower_mm(i) + p.tol_upper_mm(i)) : 0.0;
    p.weight(i) = 1 + std::floor(rng.Uniform(0, 3));
  }
  // The infeasible copy: same K row and band as its original, t beyond the band on the other side.
  int original = -1;
  for (int i = 0; options.infeasible && i < n && original < 0; ++i) {
    if (rows[i] == rows[n]) original = i;
  }
  if (options.infeasible) {
    p.tol_lower_mm(n) = p.tol_lower_mm(original);
    p.tol_upper_mm(n) = p.tol_upper_mm(original);
    p.target_mm(n) = p.target_mm(original);
  }
  // Offsets' bounds and true errors.
  p.delta_min_mm.resize(k);
  p.delta_max_mm.resize(k);
  p.offset_weight = Eigen::VectorXd::Constant(k, 1e-4);
  p.resolution_mm = Eigen::VectorXd::Constant(k, 0.001);
  s.c_true_mm.resize(k);
  for (int j = 0; j < k; ++j) {
    const double bound = s.kinds[j] == OffsetKind::kWork ? 0.1 : 0.05;
    const bool tight = options.tight_offset_share > 0 && rng.Uniform() < options.tight_offset_share;
    p.delta_min_mm(j) = tight ? -0.005 : -bound;
    p.delta_max_mm(j) = tight ? 0.005 : bound;
    s.c_true_mm(j) = rng.Uniform(-0.6, 0.6) * bound;
  }
  s.t_true_mm.resize(n_total);
  for (int i = 0; i < n_total; ++i) {
    const double centre = 0.5 * (p.tol_lower_mm(i) + p.tol_upper_mm(i));
    const double half = 0.5 * (p.tol_upper_mm(i) - p.tol_lower_mm(i));
    s.t_true_mm(i) = centre + rng.Uniform(-options.t_spread, options.t_spread) * half;
  }
  if (options.infeasible) {
    const double margin = 0.010;
    s.t_true_mm(original) = p.tol_upper_mm(original) + margin;
    s.t_true_mm(n) = p.tol_lower_mm(n) - margin;
  }
  const Eigen::MatrixXd kd(p.k);
  p.deviation_mm = kd * s.c_true_mm + s.t_true_mm;
  for (int i = 0; i < n_total; ++i) p.deviation_mm(i) += rng.Normal(0, options.measurement_sigma_mm);
  return s;
}

// The next part after applying δq: K·(c_true + δq) + t_true + process noise; returns the share of
// dimensions within tolerance and fills the deviations.
inline Eigen::VectorXd SimulateNextPart(const TuningScenario& s, const Eigen::VectorXd& delta_mm, std::uint64_t seed) {
  Rng rng(seed);
  const Eigen::MatrixXd kd(s.problem.k);
  Eigen::VectorXd next = kd * (s.c_true_mm + delta_mm) + s.t_true_mm;
  for (int i = 0; i < next.size(); ++i) next(i) += rng.Normal(0, s.process_sigma_mm);
  return next;
}

}  // namespace formloop::testing
