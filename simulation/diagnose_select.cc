// Selection with identifiability (steps 3–6 and 8 of diagnose.h): forward steps, the best-subset
// search, exchange and backward elimination; alias groups from swap tests; plausibility of what is
// named; intervals; gain.

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <functional>
#include <limits>
#include <numeric>

#include <fmt/format.h>
#include <fmt/ranges.h>
#include <Eigen/Eigenvalues>
#include <boost/math/distributions/fisher_f.hpp>

#include "core/parallel.h"
#include "metrology/morans_i.h"
#include "simulation/diagnose_engine.h"

namespace formloop::sim::detail {
namespace {

// Estimates of two columns correlated at least this much given the rest of the model (each column
// inflating the other's variance by ≥ 1 / (1 − 0.95²) ≈ 10×) are nearly collinear.
constexpr double kCollinear = 0.95;

double FTail(double f, int q, int dof) {
  if (!(f > 0) || q < 1 || dof < 1) return 1.0;
  return boost::math::cdf(boost::math::complement(boost::math::fisher_f(q, dof), f));
}

// A linear term's values with their components along the directions its fit leaves undetermined
// (within 3 standard deviations of zero: a rotation about the axis of a surface of revolution, a part's
// rotation on a sphere cap about the line to the centre) set to zero — what the data say of the term.
std::vector<double> DeterminedPart(const std::vector<double>& values, const Eigen::MatrixXd& cov) {
  const Eigen::Index w = cov.rows();
  Eigen::VectorXd theta(w);
  for (Eigen::Index k = 0; k < w; ++k) {
    const double v = values[static_cast<std::size_t>(k)];
    theta[k] = std::isnan(v) ? 0.0 : v;
  }
  Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd> eig(cov);
  Eigen::VectorXd determined = Eigen::VectorXd::Zero(w);
  for (Eigen::Index k = 0; k < w; ++k) {
    const Eigen::VectorXd v = eig.eigenvectors().col(k);
    const double a = v.dot(theta);
    if (std::abs(a) > 3.0 * std::sqrt(std::max(0.0, eig.eigenvalues()[k]))) determined += a * v;
  }
  return std::vector<double>(determined.data(), determined.data() + w);
}

// Combinations of a selected linear term's own parameters that move nothing the data see beside the
// other selected terms: a part's rotation on a sphere cap about the line through the sphere's centre.
// Each is a unit vector u on the term's unit-norm columns G with ‖(I − P_others) G u‖² < 1e-4: what is
// left of the combination once the other terms are projected out is below 1 % of a single column's norm
// (the term's own columns cancel there, or the others take it).
struct OwnNullDirections {
  Eigen::VectorXd scale;                    // 1 / column norm
  std::vector<Eigen::VectorXd> directions;  // in the unit-norm columns' coordinates
};
OwnNullDirections NullDirectionsOf(const std::vector<TermFit>& s, int k) {
  constexpr double kNullShare = 1e-4;  // ‖·‖² share left after the projection
  OwnNullDirections out;
  const TermFit& t = s[static_cast<std::size_t>(k)];
  const Eigen::Index width = t.columns.cols();
  if (width < 2 || !t.term.effect->linear()) return out;
  out.scale = Eigen::VectorXd::Ones(width);
  Eigen::MatrixXd g = t.columns;
  for (Eigen::Index j = 0; j < width; ++j) {
    const double norm = g.col(j).norm();
    if (norm > 0) {
      out.scale[j] = 1.0 / norm;
      g.col(j) /= norm;
    }
  }
  if (s.size() > 1) {
    const Eigen::MatrixXd others = DesignOf(s, k);
    const Eigen::HouseholderQR<Eigen::MatrixXd> qr(others);
    const Eigen::MatrixXd q = qr.householderQ() * Eigen::MatrixXd::Identity(others.rows(), others.cols());
    g -= q * (q.transpose() * g);
  }
  const Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd> eig(g.transpose() * g);
  for (Eigen::Index j = 0; j < width; ++j) {
    if (eig.eigenvalues()[j] < kNullShare) out.directions.push_back(eig.eigenvectors().col(j));
  }
  return out;
}

// A null combination in the term's raw parameters, for the engineer (AliasGroup::Undetermined).
template <typename Label>
AliasGroup::Undetermined UndeterminedOf(const Eigen::VectorXd& u, const Eigen::VectorXd& scale,
                                        const Label& column_label, int k) {
  const Eigen::VectorXd raw = u.cwiseProduct(scale);
  Eigen::Index largest = 0;
  const double top = raw.cwiseAbs().maxCoeff(&largest);
  const double sign = raw[largest] < 0 ? -1.0 : 1.0;  // the largest component positive
  AliasGroup::Undetermined combination;
  for (Eigen::Index j = 0; j < raw.size(); ++j) {
    if (std::abs(raw[j]) < 0.05 * top) continue;
    combination.parameters.push_back(column_label(k, static_cast<int>(j)));
    combination.coefficients.push_back(sign * raw[j] / raw.norm());
  }
  return combination;
}

// The current model and the fits built on it. Every comparison uses the linearised design (a
// nonlinear term contributes its full Jacobian at its profiled τ), so RSS values are comparable.
class Selector {
 public:
  Selector(const Problem& prob, const DiagnoseOptions& options, double tau_lo, double tau_hi)
      : prob_(prob), options_(options), tau_lo_(tau_lo), tau_hi_(tau_hi), n_(prob.n()) {}

  static int Params(const std::vector<TermFit>& s, int skip = -1) {
    int p = 0;
    for (std::size_t k = 0; k < s.size(); ++k) {
      if (static_cast<int>(k) != skip) p += static_cast<int>(s[k].columns.cols());
    }
    return p;
  }
  double Bic(double rss, int k) const { return n_ * std::log(std::max(rss, 1e-300) / n_) + k * std::log(n_); }
  double Bic(const std::vector<TermFit>& s) const { return Bic(FitOf(s).rss, Params(s)); }
  TermFit With(const std::vector<TermFit>& s, const Term& c, int skip = -1) const {
    return FitTerm(prob_, c, DesignOf(s, skip), tau_lo_, tau_hi_);
  }
  Fit FitOf(const std::vector<TermFit>& s, int skip = -1) const {
    return LeastSquares(s.empty() ? Eigen::MatrixXd(n_, 0) : DesignOf(s, skip), prob_.r);
  }
  // A nonlinear parameter was profiled against the terms present then; profile it again against all
  // the others (twice: enough for the weak coupling left).
  void Refresh(std::vector<TermFit>* s) const {
    for (int sweep = 0; sweep < 2; ++sweep) {
      for (std::size_t k = 0; k < s->size(); ++k) {
        if ((*s)[k].term.effect->linear()) continue;
        (*s)[k] = With(*s, (*s)[k].term, static_cast<int>(k));
      }
    }
  }
  // The terms `units` fitted one after the other, then profiled again.
  std::vector<TermFit> Build(const std::vector<Term>& units) const {
    std::vector<TermFit> s;
    for (const Term& t : units) s.push_back(With(s, t));
    Refresh(&s);
    return s;
  }
  bool Plausible(const Term& t, const std::vector<double>& theta) const {
    const int p = t.effect->parameter_count();
    for (std::size_t k = 0; k < theta.size(); ++k) {
      const ParameterRange* r = options_.plausible.Find(*t.effect, static_cast<int>(k) % p);
      if (r != nullptr && !r->Contains(theta[k])) return false;
    }
    return true;
  }
  // Plausible in what the data determine: components of a linear term's values along directions its
  // fit leaves undetermined (within 3 standard deviations of zero, e.g. a rotation about the axis of a
  // surface of revolution) are set to zero before the ranges are checked.
  bool PlausibleFit(const TermFit& f) const {
    if (!f.term.effect->linear() || f.columns.cols() < 2) return Plausible(f.term, f.theta);
    const Eigen::Index w = f.columns.cols();
    return Plausible(f.term, DeterminedPart(f.theta, f.fit.cov.bottomRightCorner(w, w)));
  }

  // One forward step: every candidate fitted with the current terms; the best qualifying one is added.
  bool Forward(std::vector<TermFit>* s, std::vector<Term>* pool, double nugget, const metrology::SpatialWeights& w,
               std::vector<ScreenedEffect>* table) const {
    if (pool->empty() || static_cast<int>(s->size()) >= options_.max_causes) return false;
    const Eigen::MatrixXd x = s->empty() ? Eigen::MatrixXd(n_, 0) : DesignOf(*s);
    const Fit current = LeastSquares(x, prob_.r);
    const double k_tests = static_cast<double>(pool->size());
    // Every candidate fitted on the cores --threads allows (each into its own slot), then taken in order.
    std::vector<TermFit> fits(pool->size());
    std::vector<ScreenedEffect> screened(pool->size());
    ParallelFor(static_cast<long>(pool->size()), 1, [&](long begin, long end) {
      for (auto i = static_cast<std::size_t>(begin); i < static_cast<std::size_t>(end); ++i) {
        const Term& c = (*pool)[i];
        TermFit& f = fits[i];
        f = With(*s, c);
        ScreenedEffect& e = screened[i];
        e.effect = prob_.Label(c);
        e.parameters = f.theta;
        e.std_errors = f.std_errors;
        e.rss_drop = current.rss - f.fit.rss;
        const int q = static_cast<int>(f.columns.cols());
        const int dof2 = n_ - static_cast<int>(x.cols()) - q;
        if (dof2 > 0 && f.fit.rss > 0 && e.rss_drop > 0) {
          e.f = (e.rss_drop / q) / (f.fit.rss / dof2);
          e.p_value = FTail(e.f, q, dof2);
        }
        e.delta_bic = n_ * std::log(std::max(f.fit.rss, 1e-300) / std::max(current.rss, 1e-300)) + q * std::log(n_);
        const double systematic = current.rss - n_ * nugget;
        e.share = systematic > 0 ? e.rss_drop / systematic : (e.rss_drop > 0 ? 1.0 : 0.0);
        e.significant = e.p_value < options_.alpha / k_tests && e.delta_bic < 0 && e.share >= options_.min_share;
        e.z_after = MoranZ(f.fit.residual, Concat(x, f.columns), w);
      }
    });
    int best = -1;
    for (const ScreenedEffect& e : screened) {
      if (e.significant && (best < 0 || e.delta_bic < (*table)[static_cast<std::size_t>(best)].delta_bic)) {
        best = static_cast<int>(table->size());
      }
      table->push_back(e);
    }
    int chosen = best;
    std::vector<int> order(table->size());
    std::iota(order.begin(), order.end(), 0);
    std::stable_sort(order.begin(), order.end(), [&](int a, int b) {
      return (*table)[a].delta_bic < (*table)[b].delta_bic ||
             ((*table)[a].delta_bic == (*table)[b].delta_bic && (*table)[a].effect < (*table)[b].effect);
    });
    std::vector<ScreenedEffect> sorted;
    for (int i : order) sorted.push_back((*table)[i]);
    *table = sorted;
    if (chosen < 0) return false;
    pool->erase(pool->begin() + chosen);
    s->push_back(std::move(fits[static_cast<std::size_t>(chosen)]));
    Refresh(s);
    return true;
  }

  // Exchange: the swap of a selected term for a candidate that lowers BIC most, if one does.
  bool Exchange(std::vector<TermFit>* s, std::vector<Term>* pool) const {
    if (s->empty() || pool->empty()) return false;
    const double bic0 = Bic(*s);
    double best_bic = bic0 - 1e-9 * std::abs(bic0) - 1e-9;
    int best_k = -1, best_c = -1;
    // Every swap (k, c) scored on the cores --threads allows (swap i = k · pool + c), then taken in order;
    // the winner is fitted again (the same numbers) rather than every fit kept.
    const std::size_t swaps = s->size() * pool->size();
    std::vector<double> bics(swaps);
    ParallelFor(static_cast<long>(swaps), 1, [&](long begin, long end) {
      for (auto i = static_cast<std::size_t>(begin); i < static_cast<std::size_t>(end); ++i) {
        const int k = static_cast<int>(i / pool->size());
        const TermFit f = With(*s, (*pool)[i % pool->size()], k);
        bics[i] = Bic(f.fit.rss, Params(*s, k) + static_cast<int>(f.columns.cols()));
      }
    });
    for (std::size_t k = 0; k < s->size(); ++k) {
      for (std::size_t c = 0; c < pool->size(); ++c) {
        const double bic = bics[k * pool->size() + c];
        if (bic < best_bic) {
          best_bic = bic;
          best_k = static_cast<int>(k);
          best_c = static_cast<int>(c);
        }
      }
    }
    if (best_k < 0) return false;
    TermFit best_fit = With(*s, (*pool)[static_cast<std::size_t>(best_c)], best_k);
    (*pool)[static_cast<std::size_t>(best_c)] = (*s)[static_cast<std::size_t>(best_k)].term;
    (*s)[static_cast<std::size_t>(best_k)] = std::move(best_fit);
    Refresh(s);
    return true;
  }

  // Backward elimination: the least significant selected term leaves when p ≥ α given the others.
  bool Backward(std::vector<TermFit>* s, std::vector<Term>* pool) const {
    if (s->empty()) return false;
    const Fit full = FitOf(*s);
    const int dof = n_ - Params(*s);
    if (dof < 1) return false;
    int worst = -1;
    double worst_p = 0;
    for (std::size_t k = 0; k < s->size(); ++k) {
      const double rss_without = FitOf(*s, static_cast<int>(k)).rss;
      const int q = static_cast<int>((*s)[k].columns.cols());
      const double p = FTail(((rss_without - full.rss) / q) / (full.rss / dof), q, dof);
      if (p > worst_p) {
        worst_p = p;
        worst = static_cast<int>(k);
      }
    }
    if (worst < 0 || worst_p < options_.alpha) return false;
    pool->push_back((*s)[static_cast<std::size_t>(worst)].term);
    s->erase(s->begin() + worst);
    Refresh(s);
    return true;
  }

  // Exchange, backward and forward steps until nothing changes.
  void Refine(std::vector<TermFit>* s, std::vector<Term>* pool, const std::function<bool()>& forward) const {
    for (int round = 0; round < 6; ++round) {
      bool changed = false;
      for (int swaps = 0; swaps < 8 && Exchange(s, pool); ++swaps) changed = true;
      while (Backward(s, pool)) changed = true;
      if (forward()) changed = true;
      if (!changed) break;
    }
  }

  double tau_lo() const { return tau_lo_; }
  double tau_hi() const { return tau_hi_; }

 private:
  const Problem& prob_;
  const DiagnoseOptions& options_;
  double tau_lo_, tau_hi_;
  int n_;
};

struct UnionFind {
  std::vector<int> parent;
  explicit UnionFind(int n) : parent(n) { std::iota(parent.begin(), parent.end(), 0); }
  int Find(int a) { return parent[a] == a ? a : parent[a] = Find(parent[a]); }
  void Join(int a, int b) { parent[Find(a)] = Find(b); }
  // Per node, the size of its set.
  std::vector<int> SetSizes() {
    std::vector<int> count(parent.size(), 0), size(parent.size());
    for (std::size_t m = 0; m < parent.size(); ++m) ++count[static_cast<std::size_t>(Find(static_cast<int>(m)))];
    for (std::size_t m = 0; m < parent.size(); ++m)
      size[m] = count[static_cast<std::size_t>(Find(static_cast<int>(m)))];
    return size;
  }
};

// Parameter values, standard errors and columns of the terms `s` in their joint fit: the linear
// parameters from the fit, a nonlinear one at its profiled value; NaN for a column the data leave at
// zero (e.g. a z parameter from 2-D feature positions).
struct JointValues {
  Fit fit;
  Eigen::MatrixXd x;
  std::vector<int> offsets;
  std::vector<std::vector<double>> values, std_errors;
};
JointValues Joint(const Problem& prob, const std::vector<TermFit>& s) {
  JointValues j;
  j.x = s.empty() ? Eigen::MatrixXd(prob.n(), 0) : DesignOf(s);
  j.fit = LeastSquares(j.x, prob.r);
  int col = 0;
  for (const auto& t : s) {
    j.offsets.push_back(col);
    const int p = t.term.effect->parameter_count();
    std::vector<double> v, se;
    for (int c = 0; c < static_cast<int>(t.columns.cols()); ++c, ++col) {
      if (j.x.col(col).norm() == 0) {
        v.push_back(std::numeric_limits<double>::quiet_NaN());
        se.push_back(std::numeric_limits<double>::quiet_NaN());
        continue;
      }
      v.push_back(t.term.effect->parameters()[c % p].linear ? j.fit.beta[col] : t.theta[static_cast<std::size_t>(c)]);
      se.push_back(std::sqrt(std::max(0.0, j.fit.cov(col, col))));
    }
    j.values.push_back(v);
    j.std_errors.push_back(se);
  }
  return j;
}

// s[k]'s values in the joint fit `jv`; a linear term of several columns with only what the data determine
// of it (DeterminedPart), which is what its plausibility is judged on.
std::vector<double> DeterminedValues(const std::vector<TermFit>& s, const JointValues& jv, int k) {
  const TermFit& t = s[static_cast<std::size_t>(k)];
  const Eigen::Index width = t.columns.cols();
  const std::vector<double>& values = jv.values[static_cast<std::size_t>(k)];
  if (!t.term.effect->linear() || width < 2) return values;
  const int at = jv.offsets[static_cast<std::size_t>(k)];
  return DeterminedPart(values, jv.fit.cov.block(at, at, width, width));
}

// How closely candidate columns `c` can stand in for s[k]: the multiple correlation of s[k]'s fitted
// contribution with c, both taken orthogonal to the other selected terms (1 = c does all its work).
double PartialCorrelation(const std::vector<TermFit>& s, int k, const Eigen::MatrixXd& c, const Fit& joint) {
  int offset = 0;
  for (int j = 0; j < k; ++j) offset += static_cast<int>(s[static_cast<std::size_t>(j)].columns.cols());
  const Eigen::MatrixXd& own = s[static_cast<std::size_t>(k)].columns;
  const Eigen::VectorXd contribution = own * joint.beta.segment(offset, own.cols());
  const Eigen::MatrixXd others = DesignOf(s, k);
  const double alone = LeastSquares(others, contribution).rss;
  if (!(alone > 0)) return 0.0;
  const double with_c = LeastSquares(Concat(others, c), contribution).rss;
  return std::sqrt(std::clamp(1.0 - with_c / alone, 0.0, 1.0));
}

}  // namespace

Result<Selection> SelectCauses(const Problem& prob, const Model& baseline, const DiagnoseOptions& options) {
  const int n = prob.n();
  const int points = prob.Points();  // the rows after them are direct measurements
  Selection result;
  Diagnosis& out = result.diagnosis;
  out.n = points;
  out.parts = prob.part_names;
  out.extended = baseline;
  const Eigen::VectorXd r_um = prob.r.cwiseQuotient(prob.weight).head(points);
  out.residual_um.assign(r_um.data(), r_um.data() + points);
  FL_ASSIGN_OR_RETURN(const metrology::SpatialWeights w, PointWeights(prob));

  // Candidates: applicable catalogue effects with parameters, not in the baseline, as asked; over
  // several parts a part-specific effect has each part's own parameters.
  std::vector<Term> candidates;
  for (const Effect* e : EffectCatalogue()) {
    if (e->kind() != EffectKind::kSurface && e->kind() != EffectKind::kMeasurement) continue;
    if (baseline.Has(e->name()) || !prob.applicable(e)) continue;
    if (e->uses_toolpath() && !options.toolpath_known) {
      out.not_screened.emplace_back(e->name());
      continue;
    }
    if (!options.candidates.empty() &&
        std::find(options.candidates.begin(), options.candidates.end(), e->name()) == options.candidates.end()) {
      continue;
    }
    candidates.push_back({e, e->part_specific() && prob.parts() > 1 ? kEachPart : kShared});
  }
  out.rms_before_um = std::sqrt(r_um.squaredNorm() / points);
  out.z_before = MoranZ(prob.r, Eigen::MatrixXd(n, 0), w);
  out.noise_sigma_um = std::sqrt(NuggetVariance(r_um, prob.neighbours));
  const double nugget = NuggetVariance(prob.r, prob.neighbours);
  const double rss0 = prob.r.squaredNorm();

  // τ inside its plausible range (the rule base), else two decades either side of the cutting time.
  double tau_lo = prob.time_scale_s / 100.0, tau_hi = prob.time_scale_s * 100.0;
  if (const ParameterRange* r = options.plausible.Find(*FindEffect("thermal_drift_z"), 1)) {
    tau_lo = r->min;
    tau_hi = r->max;
  }
  const Selector sel(prob, options, tau_lo, tau_hi);

  // Selection, repeated without an effect whose named value is implausible.
  std::vector<TermFit> s;
  std::vector<Term> pool;
  std::vector<std::vector<int>> groups;      // per alias group: indices into s (< s.size()) and pool (≥ s.size())
  std::vector<int> named;                    // indices into s
  std::vector<std::pair<int, int>> columns;  // the selected terms' parameters that can be aliased on their own
  std::vector<Term> excluded;
  auto report_implausible = [&](const Term& term, const std::vector<std::string>& violations,
                                const std::vector<double>& values) {
    const Effect& e = *term.effect;
    Implausible bad;
    bad.effect = std::string(e.name());
    bad.part = term.part >= 0 ? prob.part_names[static_cast<std::size_t>(term.part)] : "";
    for (std::size_t j = 0; j < values.size(); ++j) {
      const int p = e.parameter_count();
      bad.parameter_names.push_back(e.parameters()[j % p].name +
                                    (term.part == kEachPart ? "@" + prob.part_names[j / p] : std::string()));
      bad.parameters.push_back(values[j]);
    }
    bad.violations = violations;
    for (const auto& other : out.implausible) {
      if (other.effect == bad.effect && other.part == bad.part) return;
    }
    out.implausible.push_back(bad);
  };
  auto violations_of = [&](const Term& term, const std::vector<double>& values) {
    std::vector<std::string> v;
    const Effect& e = *term.effect;
    const int p = e.parameter_count();
    for (std::size_t j = 0; j < values.size(); ++j) {
      const ParameterRange* range = options.plausible.Find(e, static_cast<int>(j) % p);
      if (range != nullptr && e.parameters()[j % p].linear && !range->Contains(values[j])) {
        v.push_back(fmt::format("{} = {:.4g} outside [{:g}, {:g}]", e.parameters()[j % p].name, values[j], range->min,
                                range->max));
      }
    }
    return v;
  };
  for (int attempt = 0; attempt < 4; ++attempt) {
    pool.clear();
    for (const Term& t : candidates) {
      if (std::find(excluded.begin(), excluded.end(), t) == excluded.end()) pool.push_back(t);
    }
    const std::vector<Term> all = pool;
    s.clear();
    out.screening.clear();
    auto forward = [&] {
      std::vector<ScreenedEffect> table;
      const bool added = sel.Forward(&s, &pool, nugget, w, &table);
      if (!table.empty()) out.screening.push_back(std::move(table));
      return added;
    };
    while (forward()) {
    }
    sel.Refine(&s, &pool, forward);
    // The best subset of at most four: it replaces the greedy choice when its BIC is lower.
    const SubsetSearch search = BestSubset(prob, all, options, nugget, tau_lo, tau_hi, std::min(4, options.max_causes));
    if (!search.best.empty()) {
      std::vector<Term> units;
      for (int u : search.best) units.push_back(all[static_cast<std::size_t>(u)]);
      std::vector<TermFit> alternative = sel.Build(units);
      if (s.empty() || sel.Bic(alternative) < sel.Bic(s)) {
        s = std::move(alternative);
        pool.clear();
        for (const Term& t : all) {
          if (std::find(units.begin(), units.end(), t) == units.end()) pool.push_back(t);
        }
        sel.Refine(&s, &pool, forward);
      }
    }
    if (!search.implausible.empty()) {
      // A better fit the rule base does not believe: say which values it would need.
      std::vector<Term> units;
      for (int u : search.implausible) units.push_back(all[static_cast<std::size_t>(u)]);
      const std::vector<TermFit> fitted = sel.Build(units);
      const JointValues jv = Joint(prob, fitted);
      for (std::size_t k = 0; k < fitted.size(); ++k) {
        const auto v = violations_of(fitted[k].term, DeterminedValues(fitted, jv, static_cast<int>(k)));
        if (!v.empty()) report_implausible(fitted[k].term, v, jv.values[k]);
      }
    }
    // Identifiability: s[k] and candidate c are aliases when, with both in the model, s[k] is not
    // significant given c (and c's values there are plausible); one parameter of a selected term is
    // aliased with c when it is significant without c and not with it (c does that parameter's work).
    const int ns = static_cast<int>(s.size()), np = static_cast<int>(pool.size());
    columns.clear();
    for (int k = 0; k < ns; ++k) {
      if (s[static_cast<std::size_t>(k)].columns.cols() < 2) continue;
      for (int j = 0; j < static_cast<int>(s[static_cast<std::size_t>(k)].columns.cols()); ++j)
        columns.push_back({k, j});
    }
    const int nodes = ns + np + static_cast<int>(columns.size());
    const bool debug = std::getenv("FL_DEBUG_ALIAS") != nullptr;
    // A parameter counts as asked for by the data at alias_alpha / (the parameters so tested): Bonferroni
    // over the family, as a forward step over its candidates.
    const double parameter_alpha = options.alias_alpha / std::max<double>(1.0, static_cast<double>(columns.size()));
    UnionFind uf(nodes);
    const int p_s = Selector::Params(s);
    const Fit base = sel.FitOf(s);
    std::vector<int> offset(static_cast<std::size_t>(ns), 0);
    for (int k = 1; k < ns; ++k) offset[k] = offset[k - 1] + static_cast<int>(s[k - 1].columns.cols());
    auto column_p = [&](const Fit& f, int col, int dof) {
      const double var = f.cov(col, col);
      return var > 0 ? FTail(f.beta[col] * f.beta[col] / var, 1, dof) : 1.0;
    };
    struct Collinear {
      int term;            // a selected term of one column
      int candidate;       // index into pool
      double correlation;  // |correlation| of the two estimates
    };
    std::vector<Collinear> collinear;
    for (int c = 0; c < np; ++c) {
      const TermFit with = sel.With(s, pool[static_cast<std::size_t>(c)]);
      const int q_c = static_cast<int>(with.columns.cols());
      const int dof = n - p_s - q_c;
      if (dof < 1) continue;
      for (int k = 0; k < ns; ++k) {
        const TermFit swapped = sel.With(s, pool[static_cast<std::size_t>(c)], k);
        const int q = static_cast<int>(s[static_cast<std::size_t>(k)].columns.cols());
        const double f = ((swapped.fit.rss - with.fit.rss) / q) / (with.fit.rss / dof);
        if (debug) {
          std::fprintf(stderr, "alias test: %s given %s: F %.3f p %.3g plausible %d (%s)\n",
                       prob.Label(s[static_cast<std::size_t>(k)].term).c_str(),
                       prob.Label(pool[static_cast<std::size_t>(c)]).c_str(), f, FTail(f, q, dof),
                       sel.Plausible(swapped.term, swapped.theta),
                       fmt::format("{}", fmt::join(swapped.theta, ",")).c_str());
        }
        if (FTail(f, q, dof) >= options.alias_alpha && sel.PlausibleFit(swapped)) uf.Join(k, ns + c);
      }
      // Nearly collinear with a selected term of one column, asked for beside it (see below, after the groups).
      if (sel.PlausibleFit(with)) {
        for (int j = 0; j < q_c; ++j) {
          const int cj = p_s + j;
          if (column_p(with.fit, cj, dof) >= options.alias_alpha) continue;
          for (int k = 0; k < ns; ++k) {
            if (s[static_cast<std::size_t>(k)].columns.cols() != 1) continue;
            const int col = offset[k];
            const double scale = with.fit.cov(cj, cj) * with.fit.cov(col, col);
            if (!(scale > 0) || std::abs(with.fit.cov(cj, col)) < kCollinear * std::sqrt(scale)) continue;
            collinear.push_back({k, c, std::abs(with.fit.cov(cj, col)) / std::sqrt(scale)});
          }
        }
      }
      for (std::size_t m = 0; m < columns.size(); ++m) {
        const int col = offset[columns[m].first] + columns[m].second;
        if (debug && column_p(base, col, n - p_s) < parameter_alpha &&
            column_p(with.fit, col, dof) >= options.alias_alpha) {
          std::fprintf(stderr, "param alias: %s col %d given %s: p without %.3g with %.3g plausible %d\n",
                       prob.Label(s[static_cast<std::size_t>(columns[m].first)].term).c_str(), columns[m].second,
                       prob.Label(pool[static_cast<std::size_t>(c)]).c_str(), column_p(base, col, n - p_s),
                       column_p(with.fit, col, dof), sel.PlausibleFit(with));
        }
        if (column_p(base, col, n - p_s) < parameter_alpha && column_p(with.fit, col, dof) >= options.alias_alpha &&
            sel.PlausibleFit(with)) {
          uf.Join(ns + np + static_cast<int>(m), ns + c);
        }
      }
    }
    // A combination of a selected term's own parameters that moves nothing the data see (NullDirectionsOf)
    // makes the parameters it involves one alias group: on a sphere cap a part's three rotation angles
    // act as a shift perpendicular to the line to the centre, and which angles make it cannot be told.
    std::vector<std::pair<int, int>> own_null;  // {term, a column node of its null combination}
    for (int k = 0; k < ns; ++k) {
      for (const Eigen::VectorXd& u : NullDirectionsOf(s, k).directions) {
        int first = -1;
        for (std::size_t m = 0; m < columns.size(); ++m) {
          if (columns[m].first != k || std::abs(u[columns[m].second]) < 0.1) continue;
          const int node = ns + np + static_cast<int>(m);
          if (first < 0) {
            first = node;
            own_null.push_back({k, node});
          } else {
            uf.Join(first, node);
          }
        }
      }
    }
    // Two candidates together can do a selected term's work that neither does alone (a z scale on a
    // dome standing in for a tool radius and a deflection): s[k] is aliased with the pair when the
    // model with the pair in its place is plausible and not very strongly worse by BIC (ΔBIC <
    // alias_bic; Kass & Raftery 1995). The extra parameters of the pair count against it, so a single
    // effect is not grouped with a pair of look-alikes that needs more parameters to fit as well.
    // Only a minor term is tested so (one that removes less than `pair_alias_share` of the residual
    // variance given the others): for the term that carries the signal, one effect against a pair that
    // must come in the right proportion is parsimony's case (a scale in x on a saddle is exactly a
    // scale in y and z together; named, the single effect is right far more often than not), while a
    // minor term is of the size of its neighbours' model error. Linear candidates that each reproduce
    // part of s[k]'s contribution (partial correlation ≥ 0.3) are paired.
    if (options.alias_bic > 0) {
      const double bic_s = sel.Bic(base.rss, p_s);
      for (int k = 0; k < ns; ++k) {
        if (!(rss0 > 0) || sel.FitOf(s, k).rss - base.rss >= options.pair_alias_share * rss0) continue;
        std::vector<int> near;
        std::vector<Eigen::MatrixXd> near_columns;
        for (int c = 0; c < np; ++c) {
          const Term& term = pool[static_cast<std::size_t>(c)];
          if (!term.effect->linear()) continue;
          Eigen::MatrixXd cols = sel.With(s, term).columns;
          if (PartialCorrelation(s, k, cols, base) < 0.3) continue;
          near.push_back(c);
          near_columns.push_back(std::move(cols));
        }
        const Eigen::MatrixXd others = DesignOf(s, k);
        const int q = static_cast<int>(s[static_cast<std::size_t>(k)].columns.cols());
        for (std::size_t a = 0; a < near.size(); ++a) {
          for (std::size_t b = a + 1; b < near.size(); ++b) {
            const Eigen::MatrixXd pair = Concat(near_columns[a], near_columns[b]);
            const Fit swapped = LeastSquares(Concat(others, pair), prob.r);
            const double delta_bic = sel.Bic(swapped.rss, p_s - q + static_cast<int>(pair.cols())) - bic_s;
            if (!(delta_bic < options.alias_bic)) continue;
            const Eigen::Index at = others.cols();
            const Eigen::Index wa = near_columns[a].cols(), wb = near_columns[b].cols();
            const Eigen::VectorXd va = swapped.beta.segment(at, wa), vb = swapped.beta.segment(at + wa, wb);
            const Term& ta = pool[static_cast<std::size_t>(near[a])];
            const Term& tb = pool[static_cast<std::size_t>(near[b])];
            if (!sel.Plausible(ta, std::vector<double>(va.data(), va.data() + wa)) ||
                !sel.Plausible(tb, std::vector<double>(vb.data(), vb.data() + wb))) {
              continue;
            }
            uf.Join(k, ns + near[a]);
            uf.Join(k, ns + near[b]);
          }
        }
      }
    }
    // A candidate in no group yet, asked for beside the selected terms (one of its columns significant
    // at `alias_alpha` given them), whose column is nearly collinear with a selected term of one column
    // (their estimates correlated ≥ kCollinear given the rest: each inflates the other's variance ≥ 10×)
    // joins that term's group when the term is already in one: the data hold both, their split is not
    // determined, and the group that carries the prediction carries the candidate's part too. A tool
    // radius in a group with the probe radius on an egg box (n_z ≈ 1 almost everywhere) carries a 14 µm
    // set-up z offset that stays significant beside it but too weak to be selected with its three
    // parameters. A named term gains no group so: its interval is joined over the model with each
    // look-alike (below), and a look-alike significant by chance (1 % of the time at alias_alpha) must
    // not unname it. The candidate joins one group, its most collinear term's: one look-alike near two
    // groups would tie together what the tests above keep apart. Not a parameter of a term of several
    // columns (a set-up offset's tz): in the multi-effect suite (measured before a term was judged on
    // what the data determine of it), three of the five radius candidates so joined to a tz were effects
    // not there (pooled parts on sphere caps), and the groups they widened no longer split.
    {
      const std::vector<int> size = uf.SetSizes();              // before any of these joins
      std::vector<int> best(static_cast<std::size_t>(np), -1);  // per candidate, into collinear
      for (std::size_t e = 0; e < collinear.size(); ++e) {
        const Collinear& l = collinear[e];
        if (size[static_cast<std::size_t>(l.term)] < 2 || size[static_cast<std::size_t>(ns + l.candidate)] > 1)
          continue;
        int& b = best[static_cast<std::size_t>(l.candidate)];
        if (b < 0 || l.correlation > collinear[static_cast<std::size_t>(b)].correlation) b = static_cast<int>(e);
      }
      for (int c = 0; c < np; ++c) {
        if (best[static_cast<std::size_t>(c)] < 0) continue;
        const int k = collinear[static_cast<std::size_t>(best[static_cast<std::size_t>(c)])].term;
        if (debug) {
          std::fprintf(stderr, "collinear alias: %s with %s\n", prob.Label(s[static_cast<std::size_t>(k)].term).c_str(),
                       prob.Label(pool[static_cast<std::size_t>(c)]).c_str());
        }
        uf.Join(k, ns + c);
      }
    }
    // A selected term all of whose parameters are aliased is aliased as a whole when its candidates
    // together can do its work: in the model with all of them, the term is not significant at
    // `alias_alpha`. Each parameter aliased on its own is not enough: on a sphere cap a rotation about
    // the part origin moves it like a shift perpendicular to the line from the origin to the sphere's
    // centre, so tx, ty and tz each lose significance beside setup_rotation, yet the shift along that
    // line is something no rotation does — the set-up offset is there, only its components are not told
    // apart (it stays named, none of its parameters printed).
    {
      const std::vector<int> size = uf.SetSizes();
      for (int k = 0; k < ns; ++k) {
        std::vector<int> own;
        for (std::size_t m = 0; m < columns.size(); ++m) {
          if (columns[m].first == k) own.push_back(ns + np + static_cast<int>(m));
        }
        const bool every_column = !own.empty() && std::all_of(own.begin(), own.end(), [&](int m) {
          return size[static_cast<std::size_t>(m)] > 1;
        });
        if (!every_column) continue;
        std::vector<TermFit> partners;  // fitted one after the other beside the other selected terms
        Eigen::MatrixXd others = DesignOf(s, k);
        for (int c = 0; c < np; ++c) {
          const bool partner =
              std::any_of(own.begin(), own.end(), [&](int m) { return uf.Find(m) == uf.Find(ns + c); });
          if (!partner) continue;
          partners.push_back(FitTerm(prob, pool[static_cast<std::size_t>(c)], others, tau_lo, tau_hi));
          others = Concat(others, partners.back().columns);
        }
        const int q = static_cast<int>(s[static_cast<std::size_t>(k)].columns.cols());
        const Fit with_all = LeastSquares(Concat(others, s[static_cast<std::size_t>(k)].columns), prob.r, false);
        const Fit without = LeastSquares(others, prob.r, false);
        const int dof = n - static_cast<int>(others.cols()) - q;
        const double f = dof > 0 && with_all.rss > 0 ? ((without.rss - with_all.rss) / q) / (with_all.rss / dof) : 0;
        // (Each partner's own values were plausible when it took the parameter's work; together they may
        // trade huge values against each other, which says nothing for the term.)
        if (dof > 0 && FTail(f, q, dof) >= options.alias_alpha) {
          for (int m : own) uf.Join(k, m);
        }
      }
    }
    // A term grouped as a whole takes its null combination's parameters into its group (one finding).
    {
      std::vector<int> size(static_cast<std::size_t>(nodes), 0);
      for (int m = 0; m < nodes; ++m) ++size[static_cast<std::size_t>(uf.Find(m))];
      for (const auto& [k, node] : own_null) {
        if (size[static_cast<std::size_t>(uf.Find(k))] > 1) uf.Join(k, node);
      }
    }
    groups.clear();
    named.clear();
    std::vector<int> group_of(static_cast<std::size_t>(nodes), -1);
    for (int node = 0; node < nodes; ++node) {
      if (node >= ns && node < ns + np) continue;  // a group holds a selected term or parameter
      const int root = uf.Find(node);
      std::vector<int> members;
      for (int m = 0; m < nodes; ++m) {
        if (uf.Find(m) == root) members.push_back(m);
      }
      if (members.size() == 1) {
        if (node < ns) named.push_back(node);
      } else if (group_of[static_cast<std::size_t>(root)] < 0) {
        group_of[static_cast<std::size_t>(root)] = static_cast<int>(groups.size());
        groups.push_back(members);
      }
    }
    // Plausibility of what is selected, named or carrying an alias group's prediction: linear values
    // inside their ranges; τ not pinned at a bound of its range by data that ask significantly for a value
    // beyond it. A group member with an implausible value (a thermal amplitude of −380 µm cancelling a
    // tool radius) is excluded like a named one: the group's other members, or the effects it stood in
    // for, carry the prediction in the next attempt.
    const JointValues jv = Joint(prob, s);
    const int nu = std::max(1, n - p_s);
    const double f95 = boost::math::quantile(boost::math::fisher_f(1, nu), 0.95);
    bool redo = false;
    for (int k = 0; k < ns; ++k) {
      const TermFit& t = s[static_cast<std::size_t>(k)];
      const Effect& e = *t.term.effect;
      std::vector<std::string> v = violations_of(t.term, DeterminedValues(s, jv, k));
      for (int j = 0; j < e.parameter_count(); ++j) {
        const ParameterRange* range = options.plausible.Find(e, j);
        if (range == nullptr || e.parameters()[j].linear) continue;
        const double value = t.theta[static_cast<std::size_t>(j)];
        for (double bound : {range->min, range->max}) {
          if (std::abs(std::log(value / bound)) > 1e-3) continue;
          const double beyond = bound == range->min ? bound / 2 : bound * 2;
          const Eigen::MatrixXd others = DesignOf(s, k);
          const double at_bound = ProfileRss(prob, t.term, others, bound);
          if (ProfileRss(prob, t.term, others, beyond) < at_bound - f95 * at_bound / nu) {
            v.push_back(fmt::format("{}: the data ask for {} than {:g}", e.parameters()[j].name,
                                    bound == range->min ? "less" : "more", bound));
          }
        }
      }
      if (v.empty()) continue;
      report_implausible(t.term, v, jv.values[static_cast<std::size_t>(k)]);
      excluded.push_back(t.term);
      redo = true;
    }
    if (!redo) break;
  }

  // The final joint fit, parameters, intervals.
  const int ns = static_cast<int>(s.size()), np = static_cast<int>(pool.size());
  const JointValues jv = Joint(prob, s);
  const Eigen::MatrixXd& x = jv.x;
  const Fit& joint = jv.fit;
  const int p_s = Selector::Params(s);
  const int nu = std::max(1, n - p_s);
  const double f95 = boost::math::quantile(boost::math::fisher_f(1, nu), 0.95);
  // Each term's combinations that move nothing the data see (its values, and the alias groups' findings).
  std::vector<OwnNullDirections> nulls;
  for (int k = 0; k < ns; ++k) nulls.push_back(NullDirectionsOf(s, k));
  for (std::size_t k = 0; k < s.size(); ++k) {
    result.terms.push_back(s[k].term);
    std::vector<double> theta = jv.values[k];
    for (double& v : theta) v = std::isnan(v) ? 0.0 : v;
    // Along a combination that moves nothing the data see, the fit's value is noise: the model keeps none.
    const OwnNullDirections& null = nulls[k];
    for (const Eigen::VectorXd& u : null.directions) {
      Eigen::Map<Eigen::VectorXd> t(theta.data(), static_cast<Eigen::Index>(theta.size()));
      const Eigen::VectorXd normalised = t.cwiseQuotient(null.scale);
      t = (normalised - u * u.dot(normalised)).cwiseProduct(null.scale);
    }
    result.theta.push_back(theta);
  }
  // Intervals that do not assume the candidates left out are absent: the profile intervals of the
  // model joined with those of the model plus each candidate (whose fitted values are plausible). A
  // look-alike too weak to be selected can still shift a named parameter (a set-up z offset against the
  // tool radius, a thermal amplitude against wear); its model's interval then widens the reported one.
  auto intervals = ProfileIntervals(prob, s, tau_lo, tau_hi, nu, f95);
  // ... and with each alias group carried by another of its members: a selected term in a group is "one
  // or more of" its members, so a named term's interval must not assume it is the one that is there (a
  // z scale grouped with wear on a Franke part takes the slow part of a thermal drift, which then fits
  // a τ and an amplitude far from the truth with intervals that exclude it). Only named terms' intervals
  // are reported: with none, no swap is fitted.
  std::vector<std::pair<int, int>> swaps;  // {selected term in a group, candidate of the same group}
  for (const auto& g : groups) {
    for (int a : g) {
      for (int c : g) {
        if (!named.empty() && a < ns && c >= ns && c < ns + np) swaps.push_back({a, c - ns});
      }
    }
  }
  // One nonlinear term at a time: a nonlinear candidate only beside linear terms (s[skip] left out).
  auto nonlinear_besides = [&](int skip) {
    for (int k = 0; k < ns; ++k) {
      if (k != skip && !s[static_cast<std::size_t>(k)].term.effect->linear()) return true;
    }
    return false;
  };
  auto intervals_of = [&](const std::vector<TermFit>& model) {
    const int nu_m = std::max(1, n - Selector::Params(model));
    const double f95_m = boost::math::quantile(boost::math::fisher_f(1, nu_m), 0.95);
    return ProfileIntervals(prob, model, tau_lo, tau_hi, nu_m, f95_m);
  };
  // Each alternative's intervals on the cores --threads allows (empty: left out), then joined in order:
  // the model plus candidate i, then the model with swap i − np.
  std::vector<std::vector<std::vector<std::pair<double, double>>>> widened(pool.size() + swaps.size());
  ParallelFor(static_cast<long>(widened.size()), 1, [&](long begin, long end) {
    for (auto i = static_cast<std::size_t>(begin); i < static_cast<std::size_t>(end); ++i) {
      const bool swap = i >= pool.size();
      const int k = swap ? swaps[i - pool.size()].first : -1;
      const Term& c = pool[swap ? static_cast<std::size_t>(swaps[i - pool.size()].second) : i];
      if (!c.effect->linear() && nonlinear_besides(k)) continue;
      TermFit with = sel.With(s, c, k);
      if (!sel.PlausibleFit(with)) continue;
      std::vector<TermFit> model = s;
      if (swap) {
        model[static_cast<std::size_t>(k)] = std::move(with);
      } else {
        model.push_back(std::move(with));
      }
      widened[i] = intervals_of(model);
      if (swap) widened[i][static_cast<std::size_t>(k)].clear();  // the swapped-in term's, not s[k]'s
    }
  });
  for (const auto& wider : widened) {
    if (wider.empty()) continue;
    for (std::size_t k = 0; k < s.size(); ++k) {
      if (wider[k].size() != intervals[k].size()) continue;
      for (std::size_t j = 0; j < intervals[k].size(); ++j) {
        if (std::isnan(wider[k][j].first) || std::isnan(intervals[k][j].first)) continue;
        intervals[k][j].first = std::min(intervals[k][j].first, wider[k][j].first);
        intervals[k][j].second = std::max(intervals[k][j].second, wider[k][j].second);
      }
    }
  }
  for (int k : named) {
    const TermFit& t = s[static_cast<std::size_t>(k)];
    const Effect& e = *t.term.effect;
    const int p = e.parameter_count();
    const Fit without = sel.FitOf(s, k);
    const int copies = t.term.part == kEachPart ? prob.parts() : 1;
    for (int part = 0; part < copies; ++part) {
      Cause cause;
      cause.effect = std::string(e.name());
      if (t.term.part >= 0) cause.part = prob.part_names[static_cast<std::size_t>(t.term.part)];
      if (t.term.part == kEachPart) cause.part = prob.part_names[static_cast<std::size_t>(part)];
      for (int j = 0; j < p; ++j) {
        const std::size_t col = static_cast<std::size_t>(part * p + j);
        cause.parameter_names.push_back(e.parameters()[j].name);
        cause.parameters.push_back(jv.values[static_cast<std::size_t>(k)][col]);
        cause.std_errors.push_back(jv.std_errors[static_cast<std::size_t>(k)][col]);
        cause.lower.push_back(intervals[static_cast<std::size_t>(k)][col].first);
        cause.upper.push_back(intervals[static_cast<std::size_t>(k)][col].second);
      }
      cause.variance_explained = rss0 > 0 ? (without.rss - joint.rss) / rss0 : 0.0;
      cause.z_before = MoranZ(without.residual, DesignOf(s, k), w);
      cause.z_after = MoranZ(joint.residual, x, w);
      out.causes.push_back(cause);
    }
  }
  std::stable_sort(out.causes.begin(), out.causes.end(),
                   [](const Cause& a, const Cause& b) { return a.variance_explained > b.variance_explained; });

  // Alias groups: members, combined prediction, gain, design correlation, what separates them.
  std::vector<std::string> group_ids(s.size());
  std::vector<std::vector<bool>> column_aliased;
  for (const auto& t : s) column_aliased.emplace_back(static_cast<std::size_t>(t.columns.cols()), false);
  auto column_label = [&](int k, int j) {
    const Term& term = s[static_cast<std::size_t>(k)].term;
    const int p = term.effect->parameter_count();
    std::string label = std::string(term.effect->name()) + "(" + term.effect->parameters()[j % p].name + ")";
    if (term.part >= 0) label += "@" + prob.part_names[static_cast<std::size_t>(term.part)];
    if (term.part == kEachPart) label += "@" + prob.part_names[static_cast<std::size_t>(j / p)];
    return label;
  };
  for (std::size_t g = 0; g < groups.size(); ++g) {
    AliasGroup group;
    std::vector<bool> in_group(static_cast<std::size_t>(x.cols()), false);
    std::vector<Eigen::MatrixXd> member_columns;
    for (int m : groups[g]) {
      const Term* term = nullptr;
      if (m < ns) {
        term = &s[static_cast<std::size_t>(m)].term;
        group.members.push_back(prob.Label(*term));
        group.in_model.push_back(prob.Label(*term));
        group_ids[static_cast<std::size_t>(m)] = "G" + std::to_string(g + 1);
        member_columns.push_back(s[static_cast<std::size_t>(m)].columns);
        for (Eigen::Index c = 0; c < s[static_cast<std::size_t>(m)].columns.cols(); ++c) {
          in_group[static_cast<std::size_t>(jv.offsets[m] + c)] = true;
        }
      } else if (m < ns + np) {
        term = &pool[static_cast<std::size_t>(m - ns)];
        group.members.push_back(prob.Label(*term));
        member_columns.push_back(sel.With(s, *term).columns);
      } else {
        const auto [k, j] = columns[static_cast<std::size_t>(m - ns - np)];
        term = &s[static_cast<std::size_t>(k)].term;
        if (std::count(groups[g].begin(), groups[g].end(), k) > 0) continue;  // the whole term is a member
        group.members.push_back(column_label(k, j));
        group.in_model.push_back(column_label(k, j));
        column_aliased[static_cast<std::size_t>(k)][static_cast<std::size_t>(j)] = true;
        member_columns.push_back(x.col(jv.offsets[k] + j));
        in_group[static_cast<std::size_t>(jv.offsets[k] + j)] = true;
      }
      const std::string hint = SeparateHint(term->effect->name());
      if (!hint.empty() && group.separate_by.find(hint) == std::string::npos) {
        group.separate_by += (group.separate_by.empty() ? "" : "; ") + hint;
      }
    }
    Eigen::MatrixXd others(n, 0);
    Eigen::VectorXd combined = Eigen::VectorXd::Zero(n);
    for (Eigen::Index c = 0; c < x.cols(); ++c) {
      if (in_group[static_cast<std::size_t>(c)]) {
        combined += x.col(c) * joint.beta[c];
      } else {
        others = Concat(others, x.col(c));
      }
    }
    // What of a member the data do not see at all (a null combination of its own parameters, joined into
    // this group as a whole term or by its columns): said in the finding.
    const auto in_this_group = [&](int node) { return std::count(groups[g].begin(), groups[g].end(), node) > 0; };
    for (int k = 0; k < ns; ++k) {
      const OwnNullDirections& null = nulls[static_cast<std::size_t>(k)];
      for (const Eigen::VectorXd& u : null.directions) {
        bool here = in_this_group(k);
        for (std::size_t m = 0; !here && m < columns.size(); ++m) {
          here = columns[m].first == k && std::abs(u[columns[m].second]) >= 0.1 &&
                 in_this_group(ns + np + static_cast<int>(m));
        }
        if (here) group.undetermined.push_back(UndeterminedOf(u, null.scale, column_label, k));
      }
    }
    group.variance_explained = rss0 > 0 ? (LeastSquares(others, prob.r).rss - joint.rss) / rss0 : 0.0;
    group.combined_rms_um = std::sqrt(combined.cwiseQuotient(prob.weight).head(points).squaredNorm() / points);
    group.max_correlation = GroupDesignCorrelation(member_columns, others);
    out.alias_groups.push_back(group);
  }
  // A named effect's parameter inside an alias group is not an estimate: no value, no interval.
  for (Cause& cause : out.causes) {
    cause.aliased.assign(cause.parameters.size(), false);
    for (int k : named) {
      const Term& term = s[static_cast<std::size_t>(k)].term;
      if (term.effect->name() != cause.effect) continue;
      const int p = term.effect->parameter_count();
      int part = 0;
      for (std::size_t q = 0; q < prob.part_names.size(); ++q) {
        if (prob.part_names[q] == cause.part) part = static_cast<int>(q);
      }
      const int base_col = term.part == kEachPart ? part * p : 0;
      for (int j = 0; j < p; ++j) {
        if (!column_aliased[static_cast<std::size_t>(k)][static_cast<std::size_t>(base_col + j)]) continue;
        const double nan = std::numeric_limits<double>::quiet_NaN();
        cause.aliased[static_cast<std::size_t>(j)] = true;
        cause.parameters[static_cast<std::size_t>(j)] = cause.std_errors[static_cast<std::size_t>(j)] = nan;
        cause.lower[static_cast<std::size_t>(j)] = cause.upper[static_cast<std::size_t>(j)] = nan;
      }
    }
  }

  // Look-alikes of named effects that the data still separate (information for the engineer).
  for (int k : named) {
    const TermFit& t = s[static_cast<std::size_t>(k)];
    const Eigen::Index width = t.columns.cols();
    const Eigen::VectorXd contribution = x.middleCols(jv.offsets[k], width) * joint.beta.segment(jv.offsets[k], width);
    const double total = contribution.squaredNorm();
    if (total <= 0) continue;
    // A candidate in a group with one of this term's parameters is reported there, not as separated.
    std::vector<bool> grouped_with(pool.size(), false);
    for (const auto& members : groups) {
      const bool holds_own = std::any_of(members.begin(), members.end(), [&](int m) {
        return m >= ns + np && columns[static_cast<std::size_t>(m - ns - np)].first == k;
      });
      for (int m : members) {
        if (holds_own && m >= ns && m < ns + np) grouped_with[static_cast<std::size_t>(m - ns)] = true;
      }
    }
    for (std::size_t i = 0; i < pool.size(); ++i) {
      if (grouped_with[i]) continue;
      const Term& c = pool[i];
      const Eigen::MatrixXd cols = sel.With(s, c).columns;
      const double corr = std::sqrt(std::max(0.0, 1.0 - LeastSquares(cols, contribution).rss / total));
      if (corr >= options.confounded_correlation) {
        out.confounded.push_back({prob.Label(t.term), prob.Label(c), corr,
                                  SeparateHint(t.term.effect->name()) + "; " + SeparateHint(c.effect->name())});
      }
    }
  }

  // The extended model: named causes, and each alias group's combined prediction carried by its
  // members in the model. A part-specific effect enters with the first part's values (the set-up of
  // another part does not belong to it).
  for (int k = 0; k < ns; ++k) {
    const Term& term = s[static_cast<std::size_t>(k)].term;
    if (term.part > 0) continue;
    const int p = term.effect->parameter_count();
    std::vector<double> v(result.theta[static_cast<std::size_t>(k)].begin(),
                          result.theta[static_cast<std::size_t>(k)].begin() + p);
    std::vector<double> se;
    for (int j = 0; j < p; ++j) {
      const double e = jv.std_errors[static_cast<std::size_t>(k)][static_cast<std::size_t>(j)];
      se.push_back(std::isnan(e) ? 0.0 : e);
    }
    (void)out.extended.Set(term.effect->name(), v, se);
    for (auto& inst : out.extended.effects) {
      if (inst.effect == term.effect) inst.alias_group = group_ids[static_cast<std::size_t>(k)];
    }
  }
  for (std::size_t g = 0; g < out.alias_groups.size(); ++g) {
    out.extended.alias_groups.push_back({"G" + std::to_string(g + 1), out.alias_groups[g].members});
  }

  const Eigen::VectorXd after_um = joint.residual.cwiseQuotient(prob.weight).head(points);
  out.residual_after_um.assign(after_um.data(), after_um.data() + points);
  out.rms_after_um = std::sqrt(after_um.squaredNorm() / points);
  out.z_after = MoranZ(joint.residual, x, w);
  out.heldout_rms_before_um = out.rms_before_um;
  out.heldout_rms_after_um = BlockCvRms(prob, x, options.cv_blocks);
  out.explained_by_baseline = out.causes.empty() && out.alias_groups.empty() && out.z_before <= options.z_critical;
  out.unexplained = out.z_after > options.z_critical;
  if (out.unexplained) {
    // Where: local Moran clusters of the remaining residual (analytical p, α = 0.01).
    metrology::LocalMoranOptions lo;
    lo.permutations = 0;
    lo.alpha = 0.01;
    lo.islands = metrology::IslandPolicy::kZero;
    const auto lisa = metrology::LocalMoranI(joint.residual.head(points), w, lo);
    if (lisa.ok()) {
      for (int q : {1, 3}) {
        int count = 0;
        Eigen::Vector2d centroid = Eigen::Vector2d::Zero();
        double mean = 0;
        for (int i = 0; i < points; ++i) {
          if (lisa->quadrant[i] == q && lisa->p_analytical[i] < lo.alpha) {
            ++count;
            centroid += prob.xy.row(i).transpose();
            mean += after_um[i];
          }
        }
        if (count == 0) continue;
        out.unexplained_where.push_back({{"cluster", q == 1 ? "HH" : "LL"},
                                         {"points", count},
                                         {"centroid_xy_mm", {centroid.x() / count, centroid.y() / count}},
                                         {"mean_residual_um", mean / count}});
      }
    }
  }
  out.extended.provenance = {{"baseline", baseline.provenance},
                             {"diagnosed_points", points},
                             {"named", nlohmann::json::array()},
                             {"alias_groups", nlohmann::json::array()}};
  for (const auto& c : out.causes) out.extended.provenance["named"].push_back(c.Label());
  for (const auto& g : out.alias_groups) out.extended.provenance["alias_groups"].push_back(g.members);
  return result;
}

}  // namespace formloop::sim::detail
