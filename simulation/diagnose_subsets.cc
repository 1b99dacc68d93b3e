// Exhaustive best-subset search for diagnose (diagnose_engine.h, BestSubset). Greedy forward steps can
// settle on a wrong set when effects overlap (a set-up offset standing in for the tool radius, thermal
// drift for wear); every subset of at most four units is scored here on the Gram matrix of all their
// columns, so the search costs one n × m product and then microseconds per subset.

#include <algorithm>
#include <bit>
#include <cmath>
#include <cstdint>
#include <limits>
#include <unordered_map>

#include <Eigen/Cholesky>
#include <Eigen/QR>
#include <boost/math/distributions/fisher_f.hpp>

#include "simulation/diagnose_engine.h"

namespace formloop::sim::detail {
namespace {

constexpr int kTauGrid = 9;  // coarse: the chosen subset's τ is profiled properly afterwards

struct Entry {
  double rss = 0;
  int tau = -1;  // grid index of the nonlinear unit's τ (−1: none in the subset)
  int params = 0;
  bool plausible = true;
};

}  // namespace

SubsetSearch BestSubset(const Problem& prob, const std::vector<Term>& units, const DiagnoseOptions& options,
                        double nugget, double tau_lo, double tau_hi, int max_size) {
  SubsetSearch out;
  const int n = prob.n();
  const int u_count = static_cast<int>(units.size());
  if (u_count == 0 || u_count > 30) return out;
  // The bank: every linear unit's columns, the nonlinear unit's linear columns at each grid τ; columns
  // scaled to unit norm (a zero column stays out).
  std::vector<Eigen::VectorXd> columns;
  std::vector<double> norms;
  std::vector<std::vector<int>> linear_cols(units.size());            // per unit (linear units)
  std::vector<std::vector<std::vector<int>>> tau_cols(units.size());  // per unit, per grid τ (nonlinear)
  std::vector<std::vector<int>> param_of(units.size());               // per bank column of a unit: its parameter index
  std::vector<double> taus(kTauGrid);
  for (int g = 0; g < kTauGrid; ++g) {
    taus[g] = std::exp(std::log(tau_lo) + (std::log(tau_hi) - std::log(tau_lo)) * g / (kTauGrid - 1));
  }
  int nonlinear_units = 0;
  auto add = [&](const Eigen::MatrixXd& m, std::vector<int>* into) {
    for (Eigen::Index c = 0; c < m.cols(); ++c) {
      const double norm = m.col(c).norm();
      if (!(norm > 0)) {
        into->push_back(-1);
        continue;
      }
      into->push_back(static_cast<int>(columns.size()));
      columns.push_back(m.col(c) / norm);
      norms.push_back(norm);
    }
  };
  for (int u = 0; u < u_count; ++u) {
    if (units[u].effect->linear()) {
      add(prob.Columns(units[u], {}), &linear_cols[u]);
    } else {
      ++nonlinear_units;
      for (int g = 0; g < kTauGrid; ++g) {
        tau_cols[u].emplace_back();
        add(LinearColumnsAt(prob, units[u], taus[g]), &tau_cols[u].back());
      }
    }
  }
  if (nonlinear_units > 1 || columns.empty()) return out;  // (the catalogue has one nonlinear effect)
  const int m = static_cast<int>(columns.size());
  Eigen::MatrixXd z(n, m);
  for (int c = 0; c < m; ++c) z.col(c) = columns[c];
  const Eigen::MatrixXd gram = z.transpose() * z;
  const Eigen::VectorXd zr = z.transpose() * prob.r;
  const double rr = prob.r.squaredNorm();

  // RSS and coefficients of a set of bank columns.
  auto solve = [&](const std::vector<int>& cols, Eigen::VectorXd* beta) {
    const int k = static_cast<int>(cols.size());
    Eigen::MatrixXd a(k, k);
    Eigen::VectorXd b(k);
    for (int i = 0; i < k; ++i) {
      b[i] = zr[cols[i]];
      for (int j = 0; j < k; ++j) a(i, j) = gram(cols[i], cols[j]);
    }
    Eigen::LDLT<Eigen::MatrixXd> ldlt(a);
    const Eigen::VectorXd d = ldlt.vectorD();
    if (ldlt.info() == Eigen::Success && d.minCoeff() > 1e-10 * std::max(1.0, d.maxCoeff())) {
      *beta = ldlt.solve(b);
    } else {
      *beta = a.completeOrthogonalDecomposition().solve(b);  // collinear columns: one least-norm split
    }
    return std::max(0.0, rr - b.dot(*beta));
  };
  auto plausible = [&](const std::vector<int>& us, const std::vector<int>& cols, const Eigen::VectorXd& beta) {
    std::size_t at = 0;
    for (int u : us) {
      const Effect& e = *units[u].effect;
      const int p = e.parameter_count();
      const std::vector<int>& mine = e.linear() ? linear_cols[u] : tau_cols[u][0];
      for (std::size_t j = 0; j < mine.size(); ++j) {
        if (mine[j] < 0) continue;
        const int param = e.linear() ? static_cast<int>(j) % p : 0;  // thermal: A (τ is on the grid, in range)
        const ParameterRange* r = options.plausible.Find(e, param);
        const double value = beta[static_cast<Eigen::Index>(at)] / norms[static_cast<std::size_t>(cols[at])];
        ++at;
        if (r != nullptr && !r->Contains(value)) return false;
      }
    }
    return true;
  };

  std::unordered_map<std::uint32_t, Entry> table;
  table[0] = {rr, -1, 0, true};
  const double k_tests = static_cast<double>(u_count);
  const double log_n = std::log(static_cast<double>(n));
  auto bic = [&](const Entry& e) { return n * std::log(std::max(e.rss, 1e-300) / n) + e.params * log_n; };
  out.best_bic = bic(table[0]);
  bool have_implausible = false;
  for (int size = 1; size <= std::min(max_size, u_count); ++size) {
    // Masks of `size` bits in increasing order (Gosper's hack).
    for (std::uint32_t mask = (1u << size) - 1; mask < (1u << u_count);) {
      std::vector<int> us;
      for (int u = 0; u < u_count; ++u) {
        if (mask & (1u << u)) us.push_back(u);
      }
      Entry best_entry{std::numeric_limits<double>::infinity(), -1, 0, true};
      int nonlinear = -1;
      for (int u : us) {
        if (!units[u].effect->linear()) nonlinear = u;
      }
      for (int g = 0; g < (nonlinear >= 0 ? kTauGrid : 1); ++g) {
        std::vector<int> cols;
        int params = 0;
        for (int u : us) {
          const std::vector<int>& mine = units[u].effect->linear() ? linear_cols[u] : tau_cols[u][g];
          for (int c : mine) {
            if (c >= 0) cols.push_back(c);
          }
          params += prob.Width(units[u]);
        }
        Eigen::VectorXd beta;
        const double rss = cols.empty() ? rr : solve(cols, &beta);
        if (rss < best_entry.rss) {
          best_entry = {rss, nonlinear >= 0 ? g : -1, params, cols.empty() || plausible(us, cols, beta)};
        }
      }
      table[mask] = best_entry;
      // Every unit significant given the others, paying for itself, explaining its share.
      bool valid = true;
      const int dof = n - best_entry.params;
      for (int u : us) {
        if (dof < 1) {
          valid = false;
          break;
        }
        const Entry& without = table[mask & ~(1u << u)];
        const int q = best_entry.params - without.params;
        const double drop = without.rss - best_entry.rss;
        if (!(drop > 0) || q < 1) {
          valid = false;
          break;
        }
        const double f = (drop / q) / (best_entry.rss / dof);
        const double p = boost::math::cdf(boost::math::complement(boost::math::fisher_f(q, dof), f));
        const double delta_bic = n * std::log(best_entry.rss / without.rss) + q * log_n;
        const double systematic = without.rss - n * nugget;
        const double share = systematic > 0 ? drop / systematic : 1.0;
        if (!(p < options.alpha / k_tests) || !(delta_bic < 0) || share < options.min_share) {
          valid = false;
          break;
        }
      }
      const double b = bic(best_entry);
      if (valid && best_entry.plausible && b < out.best_bic) {
        out.best_bic = b;
        out.best = us;
      }
      if (valid && !best_entry.plausible && (!have_implausible || b < out.implausible_bic)) {
        have_implausible = true;
        out.implausible_bic = b;
        out.implausible = us;
      }
      // Next mask with the same number of bits.
      const std::uint32_t c = mask & (~mask + 1u), r = mask + c;
      mask = (((r ^ mask) >> 2) / c) | r;
    }
  }
  if (have_implausible && !(out.implausible_bic < out.best_bic)) out.implausible.clear();
  return out;
}

}  // namespace formloop::sim::detail
