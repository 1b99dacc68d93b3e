#include "metrology/spatial_cv.h"

#include <algorithm>
#include <cmath>
#include <numeric>

#include "core/random.h"

namespace formloop::metrology {

std::vector<int> GridBlocks(const Eigen::VectorXd& x, const Eigen::VectorXd& y, int blocks) {
  const double x_lo = x.minCoeff(), x_hi = x.maxCoeff(), y_lo = y.minCoeff(), y_hi = y.maxCoeff();
  auto cell = [&](double v, double a, double c) {
    if (!(c > a)) return 0;
    return std::clamp(static_cast<int>(std::floor((v - a) / (c - a) * blocks)), 0, blocks - 1);
  };
  std::vector<int> block(static_cast<std::size_t>(x.size()));
  for (Eigen::Index i = 0; i < x.size(); ++i) {
    block[static_cast<std::size_t>(i)] = cell(x[i], x_lo, x_hi) * blocks + cell(y[i], y_lo, y_hi);
  }
  return block;
}

std::vector<int> DealBlocksToFolds(int blocks, int folds, std::uint64_t seed) {
  std::vector<int> order(static_cast<std::size_t>(blocks * blocks));
  std::iota(order.begin(), order.end(), 0);
  Rng rng(seed);
  for (std::size_t k = order.size(); k > 1; --k) std::swap(order[k - 1], order[rng.UniformIndex(k)]);
  std::vector<int> block_fold(order.size(), -1);
  std::vector<int> filled(static_cast<std::size_t>(folds), 0);
  for (std::size_t k = 0; k < order.size(); ++k) {
    const int b = order[k], bu = b / blocks, bv = b % blocks;
    std::vector<bool> used(static_cast<std::size_t>(folds), false);
    for (int du = -1; du <= 1; ++du) {
      for (int dv = -1; dv <= 1; ++dv) {
        const int nu = bu + du, nv = bv + dv;
        if (nu < 0 || nv < 0 || nu >= blocks || nv >= blocks) continue;
        const int f = block_fold[static_cast<std::size_t>(nu * blocks + nv)];
        if (f >= 0) used[static_cast<std::size_t>(f)] = true;
      }
    }
    int best = -1, ties = 0;
    for (int pass = 0; pass < 2 && best < 0; ++pass) {
      for (int f = 0; f < folds; ++f) {
        if (pass == 0 && used[static_cast<std::size_t>(f)]) continue;
        if (best < 0 || filled[static_cast<std::size_t>(f)] < filled[static_cast<std::size_t>(best)]) {
          best = f;
          ties = 1;
        } else if (filled[static_cast<std::size_t>(f)] == filled[static_cast<std::size_t>(best)] &&
                   rng.UniformIndex(static_cast<std::uint64_t>(++ties)) == 0) {
          best = f;
        }
      }
    }
    block_fold[static_cast<std::size_t>(b)] = best;
    ++filled[static_cast<std::size_t>(best)];
  }
  return block_fold;
}

HeldOutErrors SpatialBlockCv(const std::vector<int>& fold, int folds, const Eigen::VectorXd& y,
                             const FitOnTraining& fit) {
  const int n = static_cast<int>(y.size());
  HeldOutErrors out;
  std::vector<double> squared(static_cast<std::size_t>(n), 0.0);
  double sse = 0;
  int held = 0;
  std::vector<int> training, testing;
  for (int f = 0; f < folds; ++f) {
    training.clear();
    testing.clear();
    for (int i = 0; i < n; ++i) (fold[static_cast<std::size_t>(i)] == f ? testing : training).push_back(i);
    if (testing.empty()) continue;
    const std::optional<HeldOutPredictor> predict = fit(training);
    if (!predict) return out;
    for (int i : testing) {
      const double e = y[i] - (*predict)(i);
      squared[static_cast<std::size_t>(i)] = e * e;
      sse += e * e;
      ++held;
    }
  }
  if (held == 0) return out;
  out.rms = std::sqrt(sse / held);
  out.squared = std::move(squared);
  return out;
}

PairedCvDifference ComparePaired(const HeldOutErrors& rich, const HeldOutErrors& current, const std::vector<int>& unit,
                                 int units) {
  PairedCvDifference out;
  if (rich.squared.empty() || current.squared.empty()) {
    out.difference = std::numeric_limits<double>::infinity();
    return out;
  }
  const std::size_t n = rich.squared.size();
  std::vector<double> sum(static_cast<std::size_t>(units), 0.0);
  std::vector<int> count(static_cast<std::size_t>(units), 0);
  double total = 0;
  for (std::size_t i = 0; i < n; ++i) {
    const double d = rich.squared[i] - current.squared[i];
    sum[static_cast<std::size_t>(unit[i])] += d;
    ++count[static_cast<std::size_t>(unit[i])];
    total += d;
  }
  int used = 0;
  for (int c : count) used += c > 0 ? 1 : 0;
  const double mean = total / std::max(1, used);
  double spread = 0;
  for (std::size_t k = 0; k < sum.size(); ++k) {
    if (count[k] > 0) spread += (sum[k] - mean) * (sum[k] - mean);
  }
  out.difference = total / static_cast<double>(n);
  out.standard_error = used > 1 ? std::sqrt(used / (used - 1.0) * spread) / static_cast<double>(n) : 0.0;
  return out;
}

}  // namespace formloop::metrology
