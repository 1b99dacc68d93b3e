// What the data determine (diagnose_engine.h): profile-likelihood intervals of the selected terms'
// parameters and the design correlation inside an alias group.

#include <algorithm>
#include <cmath>
#include <limits>

#include <Eigen/QR>
#include <Eigen/SVD>

#include "core/parallel.h"
#include "simulation/diagnose_engine.h"

namespace formloop::sim::detail {

Eigen::MatrixXd DesignOf(const std::vector<TermFit>& s, int skip) {
  Eigen::MatrixXd x(s.empty() ? 0 : s.front().columns.rows(), 0);
  for (std::size_t k = 0; k < s.size(); ++k) {
    if (static_cast<int>(k) != skip) x = Concat(x, s[k].columns);
  }
  return x;
}

namespace {

// Orthonormal basis of the column space of `a` (rank-revealing), n × rank.
Eigen::MatrixXd Basis(const Eigen::MatrixXd& a) {
  if (a.cols() == 0) return a;
  Eigen::ColPivHouseholderQR<Eigen::MatrixXd> qr(a);
  qr.setThreshold(1e-8);
  const Eigen::Index rank = qr.rank();
  Eigen::MatrixXd q = qr.householderQ() * Eigen::MatrixXd::Identity(a.rows(), rank);
  return q;
}

// Largest canonical correlation between the column spaces of a and b.
double CanonicalCorrelation(const Eigen::MatrixXd& a, const Eigen::MatrixXd& b) {
  const Eigen::MatrixXd qa = Basis(a), qb = Basis(b);
  if (qa.cols() == 0 || qb.cols() == 0) return 0.0;
  Eigen::JacobiSVD<Eigen::MatrixXd> svd(qa.transpose() * qb);
  return std::min(1.0, svd.singularValues()(0));
}

}  // namespace

std::vector<std::vector<std::pair<double, double>>> ProfileIntervals(const Problem& prob, const std::vector<TermFit>& s,
                                                                     double tau_lo, double tau_hi, int nu, double f95) {
  int nonlinear_term = -1;
  for (std::size_t k = 0; k < s.size(); ++k) {
    if (!s[k].term.effect->linear()) nonlinear_term = static_cast<int>(k);
  }
  const double nan = std::numeric_limits<double>::quiet_NaN();
  std::vector<std::vector<std::pair<double, double>>> out;
  for (const auto& t : s) out.emplace_back(prob.Width(t.term), std::make_pair(nan, nan));
  if (s.empty()) return out;
  // The fit at one τ (or the only fit): RSS, coefficients, (XᵀX)⁻¹, and per (term, parameter) its column.
  struct AtTau {
    double rss = 0;
    Eigen::VectorXd beta;
    Eigen::MatrixXd inverse;
    std::vector<std::vector<int>> column;  // −1: the nonlinear parameter (no column)
  };
  auto fit_at = [&](double tau) {
    AtTau a;
    Eigen::MatrixXd x(prob.n(), 0);
    for (std::size_t k = 0; k < s.size(); ++k) {
      const Effect& e = *s[k].term.effect;
      std::vector<int> cols;
      const Eigen::MatrixXd c =
          static_cast<int>(k) == nonlinear_term ? LinearColumnsAt(prob, s[k].term, tau) : s[k].columns;
      for (int j = 0, used = 0; j < prob.Width(s[k].term); ++j) {
        const bool has_column = static_cast<int>(k) != nonlinear_term || e.parameters()[j % e.parameter_count()].linear;
        cols.push_back(has_column ? static_cast<int>(x.cols()) + used++ : -1);
      }
      a.column.push_back(cols);
      x = Concat(x, c);
    }
    const Fit f = LeastSquares(x, prob.r, false);
    a.rss = f.rss;
    a.beta = f.beta;
    a.inverse = InverseGram(x);
    return a;
  };
  std::vector<AtTau> fits;
  std::vector<double> taus;
  if (nonlinear_term < 0) {
    fits.push_back(fit_at(0));
  } else {
    const int q = [&] {
      const Effect& e = *s[static_cast<std::size_t>(nonlinear_term)].term.effect;
      for (int j = 0; j < e.parameter_count(); ++j) {
        if (!e.parameters()[j].linear) return j;
      }
      return 0;
    }();
    const double tau_hat = s[static_cast<std::size_t>(nonlinear_term)].theta[static_cast<std::size_t>(q)];
    constexpr int kGrid = 64;
    for (int g = 0; g < kGrid; ++g) {
      taus.push_back(std::exp(std::log(tau_lo) + (std::log(tau_hi) - std::log(tau_lo)) * g / (kGrid - 1)));
    }
    taus.push_back(tau_hat);
    // One fit per τ, on the cores --threads allows (each into its own slot: the same numbers).
    fits.resize(taus.size());
    ParallelFor(static_cast<long>(taus.size()), 1, [&](long begin, long end) {
      for (long g = begin; g < end; ++g) fits[static_cast<std::size_t>(g)] = fit_at(taus[static_cast<std::size_t>(g)]);
    });
    // τ itself: bisection on its profile between the optimum and each end of the search range.
    const Eigen::MatrixXd others = DesignOf(s, nonlinear_term);
    const Term& term = s[static_cast<std::size_t>(nonlinear_term)].term;
    double rss_min = fits.back().rss;
    for (const auto& f : fits) rss_min = std::min(rss_min, f.rss);
    const double limit = rss_min * (1.0 + f95 / nu);
    auto crossing = [&](double end) {
      if (ProfileRss(prob, term, others, end) <= limit) return end;
      double a = std::log(tau_hat), b = std::log(end);
      for (int it = 0; it < 40; ++it) {
        const double m = 0.5 * (a + b);
        (ProfileRss(prob, term, others, std::exp(m)) <= limit ? a : b) = m;
      }
      return std::exp(0.5 * (a + b));
    };
    double ends[2] = {tau_lo, tau_hi};  // the two bisections side by side
    ParallelFor(2, 1, [&](long begin, long end) {
      for (long k = begin; k < end; ++k) ends[k] = crossing(ends[k]);
    });
    out[static_cast<std::size_t>(nonlinear_term)][static_cast<std::size_t>(q)] = {ends[0], ends[1]};
  }
  double rss_min = fits.front().rss;
  for (const auto& f : fits) rss_min = std::min(rss_min, f.rss);
  const double limit = rss_min * (1.0 + f95 / nu);
  for (std::size_t k = 0; k < s.size(); ++k) {
    for (int j = 0; j < prob.Width(s[k].term); ++j) {
      double lo = std::numeric_limits<double>::infinity(), hi = -lo;
      for (const auto& f : fits) {
        const int c = f.column[k][static_cast<std::size_t>(j)];
        if (c < 0 || f.rss > limit || !(f.inverse(c, c) > 0)) continue;
        const double half = std::sqrt((limit - f.rss) * f.inverse(c, c));
        lo = std::min(lo, f.beta[c] - half);
        hi = std::max(hi, f.beta[c] + half);
      }
      if (lo <= hi) out[k][static_cast<std::size_t>(j)] = {lo, hi};
    }
  }
  return out;
}

double GroupDesignCorrelation(const std::vector<Eigen::MatrixXd>& members, const Eigen::MatrixXd& others) {
  const Eigen::MatrixXd qo = Basis(others);
  auto project = [&](const Eigen::MatrixXd& m) -> Eigen::MatrixXd {
    return qo.cols() == 0 ? m : Eigen::MatrixXd(m - qo * (qo.transpose() * m));
  };
  double worst = 0;
  for (std::size_t m = 0; m < members.size(); ++m) {
    Eigen::MatrixXd rest(members[m].rows(), 0);
    for (std::size_t o = 0; o < members.size(); ++o) {
      if (o != m) rest = Concat(rest, members[o]);
    }
    worst = std::max(worst, CanonicalCorrelation(project(members[m]), project(rest)));
  }
  return worst;
}

}  // namespace formloop::sim::detail
