#pragma once
// Independent cross-checks of the bounded least-squares solver (spec/tuning-and-link.md §4.4), kept out of
// the product (STYLE.md habit 11): they share no code with tuning/trust_region_lsq.cc.
//
//  - KktCertificate: the first-order conditions at a given x, with ε_g = 1e-8·max(1, ‖Aᵀb‖∞).
//  - Bvls: the bounded-variable least-squares active-set method of P. B. Stark and R. L. Parker,
//    "Bounded-variable least-squares: an algorithm and applications", Computational Statistics 10:129-141,
//    1995 (dense, Householder QR on the free columns at every step; fine up to a few hundred unknowns).
//  - BruteForce: every free/lower/upper pattern (3^N, N ≤ 12); the best feasible pattern is the optimum.

#include <algorithm>
#include <cmath>
#include <limits>
#include <vector>

#include <Eigen/Dense>

namespace formloop::testing {

struct KktResult {
  bool ok = true;
  bool feasible = true;
  double worst_violation = 0;  // largest violation of a sign/zero condition, in gradient units
  double eps_g = 0;
};

// x must lie in [lb, ub]; a component counts as on a bound within at_bound_tol·max(1, range).
inline KktResult KktCertificate(const Eigen::MatrixXd& a, const Eigen::VectorXd& b, const Eigen::VectorXd& lb,
                                const Eigen::VectorXd& ub, const Eigen::VectorXd& x, double at_bound_tol = 1e-9) {
  KktResult out;
  out.eps_g = 1e-8 * std::max(1.0, (a.transpose() * b).cwiseAbs().maxCoeff());
  const Eigen::VectorXd g = a.transpose() * (a * x - b);
  for (int i = 0; i < x.size(); ++i) {
    if (x(i) < lb(i) || x(i) > ub(i)) out.feasible = false;
    const double range = std::isfinite(ub(i) - lb(i)) ? std::max(1.0, ub(i) - lb(i)) : 1.0;
    const bool at_lower = std::isfinite(lb(i)) && x(i) - lb(i) <= at_bound_tol * range;
    const bool at_upper = std::isfinite(ub(i)) && ub(i) - x(i) <= at_bound_tol * range;
    double violation = 0;
    if (at_lower && !at_upper)
      violation = std::max(0.0, -g(i));
    else if (at_upper && !at_lower)
      violation = std::max(0.0, g(i));
    else if (!at_lower && !at_upper)
      violation = std::abs(g(i));
    out.worst_violation = std::max(out.worst_violation, violation);
  }
  out.ok = out.feasible && out.worst_violation <= out.eps_g;
  return out;
}

struct ActiveSetResult {
  Eigen::VectorXd x;
  double cost = 0;
  int iterations = 0;
  bool converged = false;
};

// Stark–Parker BVLS. Variables start at a finite bound (free when both are infinite).
inline ActiveSetResult Bvls(const Eigen::MatrixXd& a, const Eigen::VectorXd& b, const Eigen::VectorXd& lb,
                            const Eigen::VectorXd& ub, int max_iterations = 0) {
  const int n = a.cols();
  if (max_iterations <= 0) max_iterations = 20 * n + 100;
  ActiveSetResult out;
  Eigen::VectorXd x(n);
  std::vector<int> state(n);  // −1 at lower, +1 at upper, 0 free
  for (int i = 0; i < n; ++i) {
    if (std::isfinite(lb(i))) {
      x(i) = lb(i);
      state[i] = -1;
    } else if (std::isfinite(ub(i))) {
      x(i) = ub(i);
      state[i] = 1;
    } else {
      x(i) = 0;
      state[i] = 0;
    }
  }
  const double tol = 1e-13 * std::max(1.0, (a.transpose() * b).cwiseAbs().maxCoeff());
  auto solve_free = [&](const std::vector<int>& free) {
    Eigen::MatrixXd af(a.rows(), free.size());
    Eigen::VectorXd rhs = b;
    for (int i = 0; i < n; ++i) {
      if (state[i] != 0) rhs -= a.col(i) * x(i);
    }
    for (std::size_t c = 0; c < free.size(); ++c) af.col(c) = a.col(free[c]);
    return Eigen::VectorXd(af.colPivHouseholderQr().solve(rhs));
  };
  // Initial free variables (both bounds infinite) get their least-squares values.
  {
    std::vector<int> free;
    for (int i = 0; i < n; ++i) {
      if (state[i] == 0) free.push_back(i);
    }
    if (!free.empty()) {
      const Eigen::VectorXd z = solve_free(free);
      for (std::size_t c = 0; c < free.size(); ++c) x(free[c]) = z(c);
    }
  }
  std::vector<char> excluded(n, 0);
  for (out.iterations = 0; out.iterations < max_iterations; ++out.iterations) {
    const Eigen::VectorXd w = a.transpose() * (b - a * x);
    int t = -1;
    double best = tol;
    for (int i = 0; i < n; ++i) {
      if (excluded[i] || state[i] == 0) continue;
      const double push = state[i] < 0 ? w(i) : -w(i);  // > 0: the objective falls by moving inside
      if (push > best) {
        best = push;
        t = i;
      }
    }
    if (t < 0) {
      out.converged = true;
      break;
    }
    const int came_from = state[t];
    state[t] = 0;
    bool first_inner = true;
    for (int inner = 0; inner <= n; ++inner) {  // each pass fixes at least one variable
      std::vector<int> free;
      for (int i = 0; i < n; ++i) {
        if (state[i] == 0) free.push_back(i);
      }
      if (free.empty()) break;
      const Eigen::VectorXd z = solve_free(free);
      // The freshly freed variable wants to leave through the bound it came from: keep it there.
      if (first_inner) {
        first_inner = false;
        for (std::size_t c = 0; c < free.size(); ++c) {
          if (free[c] != t) continue;
          if ((came_from < 0 && z(c) <= lb(t)) || (came_from > 0 && z(c) >= ub(t))) {
            state[t] = came_from;
            excluded[t] = 1;
          }
        }
        if (excluded[t]) break;
      }
      bool inside = true;
      for (std::size_t c = 0; c < free.size(); ++c) inside = inside && z(c) > lb(free[c]) && z(c) < ub(free[c]);
      if (inside) {
        for (std::size_t c = 0; c < free.size(); ++c) x(free[c]) = z(c);
        std::fill(excluded.begin(), excluded.end(), 0);
        break;
      }
      double alpha = 1;
      for (std::size_t c = 0; c < free.size(); ++c) {
        const int i = free[c];
        const double step = z(c) - x(i);
        if (z(c) <= lb(i) && step < 0) alpha = std::min(alpha, (lb(i) - x(i)) / step);
        if (z(c) >= ub(i) && step > 0) alpha = std::min(alpha, (ub(i) - x(i)) / step);
      }
      alpha = std::clamp(alpha, 0.0, 1.0);
      for (std::size_t c = 0; c < free.size(); ++c) {
        const int i = free[c];
        x(i) += alpha * (z(c) - x(i));
        const double range = std::isfinite(ub(i) - lb(i)) ? ub(i) - lb(i) : 1.0;
        if (std::isfinite(lb(i)) && x(i) <= lb(i) + 1e-14 * range) {
          x(i) = lb(i);
          state[i] = -1;
        } else if (std::isfinite(ub(i)) && x(i) >= ub(i) - 1e-14 * range) {
          x(i) = ub(i);
          state[i] = 1;
        }
      }
    }
  }
  out.cost = 0.5 * (a * x - b).squaredNorm();
  out.x = x;
  return out;
}

// Every free/lower/upper pattern; N ≤ 12 and finite bounds.
inline ActiveSetResult BruteForce(const Eigen::MatrixXd& a, const Eigen::VectorXd& b, const Eigen::VectorXd& lb,
                                  const Eigen::VectorXd& ub) {
  const int n = a.cols();
  ActiveSetResult out;
  out.cost = std::numeric_limits<double>::infinity();
  long patterns = 1;
  for (int i = 0; i < n; ++i) patterns *= 3;
  std::vector<int> state(n);
  for (long code = 0; code < patterns; ++code) {
    long c = code;
    std::vector<int> free;
    Eigen::VectorXd x(n);
    Eigen::VectorXd rhs = b;
    for (int i = 0; i < n; ++i) {
      state[i] = static_cast<int>(c % 3) - 1;
      c /= 3;
      if (state[i] == 0) {
        free.push_back(i);
      } else {
        x(i) = state[i] < 0 ? lb(i) : ub(i);
        rhs -= a.col(i) * x(i);
      }
    }
    if (!free.empty()) {
      Eigen::MatrixXd af(a.rows(), free.size());
      for (std::size_t k = 0; k < free.size(); ++k) af.col(k) = a.col(free[k]);
      const Eigen::VectorXd z = af.colPivHouseholderQr().solve(rhs);
      bool inside = true;
      for (std::size_t k = 0; k < free.size(); ++k) {
        inside = inside && z(k) >= lb(free[k]) && z(k) <= ub(free[k]);
        x(free[k]) = z(k);
      }
      if (!inside) continue;
    }
    const double cost = 0.5 * (a * x - b).squaredNorm();
    ++out.iterations;
    if (cost < out.cost) {
      out.cost = cost;
      out.x = x;
    }
  }
  out.converged = std::isfinite(out.cost);
  return out;
}

}  // namespace formloop::testing
