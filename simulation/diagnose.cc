#include "simulation/diagnose.h"

#include <algorithm>
#include <cmath>
#include <fstream>
#include <functional>
#include <limits>
#include <map>
#include <optional>
#include <sstream>

#include <fmt/format.h>
#include <Eigen/QR>
#include <boost/math/distributions/fisher_f.hpp>

#include "metrology/deviations.h"
#include "metrology/morans_i.h"
#include "metrology/spatial_cv.h"
#include "metrology/spatial_weights.h"
#include "simulation/virtual_machine.h"

namespace formloop::sim {
namespace {

// What distinguishes an effect's basis: the hint given when two effects are confounded.
std::string SeparateHint(std::string_view effect) {
  static const std::map<std::string, std::string, std::less<>> hints = {
      {"tool_radius", "a constant offset along n: measure the tool (tool setter) or probe a datum"},
      {"tool_wear", "grows with cutting path length: probe regions cut early and late, or cut in another order"},
      {"tool_deflection", "grows with wall steepness and engagement: probe steep and flat regions"},
      {"thermal_drift_z",
       "saturates over cutting time and acts on n_z: include pauses or a longer cut, probe inclined regions"},
      {"axis_scale_x", "grows with x: probe across the whole x range"},
      {"axis_scale_y", "grows with y: probe across the whole y range"},
      {"axis_scale_z", "grows with z: probe across the whole z range"},
      {"squareness_xy", "x displacement growing with y: probe x-facing slopes across y"},
      {"squareness_yz", "y displacement growing with z: probe y-facing slopes at several heights"},
      {"squareness_zx", "x displacement growing with z: probe x-facing slopes at several heights"},
      {"backlash_x", "flips with the x feed direction: compare zig-zag with one-way passes"},
      {"backlash_y", "flips with the y feed direction: cut passes along y in both directions"},
      {"setup_offset", "a rigid shift: probe surfaces facing x, y and z"},
      {"setup_rotation", "grows with distance from the part origin: probe far from it in every direction"},
      {"probe_radius", "acts along the approach: probe some points at a tilt to the normal, or calibrate on a sphere"},
      {"probe_lobing", "varies with the approach azimuth: probe from many azimuths, or calibrate on a sphere"},
  };
  const auto it = hints.find(effect);
  return it == hints.end() ? std::string() : it->second;
}

// The observations the engine fits: residual r, design blocks per effect, spatial structure.
struct Problem {
  Eigen::VectorXd r;                         // µm
  Eigen::MatrixXd xy;                        // n × 2 positions for CV blocks
  Eigen::MatrixXd pos;                       // n × d positions the k-NN lists were built from
  std::vector<std::vector<int>> neighbours;  // for Moran's I
  std::function<bool(const Effect*)> applicable;
  // n × p Jacobian of effect e at θ.
  std::function<Eigen::MatrixXd(const Effect*, const std::vector<double>&)> jacobian;
  double time_scale_s = 1;  // for the τ search range
  int n() const { return static_cast<int>(r.size()); }
};

struct Fit {
  Eigen::VectorXd beta;  // over [X, J]
  Eigen::VectorXd residual;
  double rss = 0;
  Eigen::MatrixXd cov;  // σ² (AᵀA)⁻¹
  int rank = 0;
};

Fit LeastSquares(const Eigen::MatrixXd& a, const Eigen::VectorXd& r) {
  Fit fit;
  if (a.cols() == 0) {
    fit.residual = r;
    fit.rss = r.squaredNorm();
    return fit;
  }
  Eigen::ColPivHouseholderQR<Eigen::MatrixXd> qr(a);
  qr.setThreshold(1e-10);
  fit.beta = qr.solve(r);
  fit.residual = r - a * fit.beta;
  fit.rss = fit.residual.squaredNorm();
  fit.rank = static_cast<int>(qr.rank());
  const double dof = std::max(1.0, static_cast<double>(r.size() - fit.rank));
  const double s2 = fit.rss / dof;
  const Eigen::MatrixXd ata = a.transpose() * a;
  fit.cov = s2 * ata.completeOrthogonalDecomposition().pseudoInverse();
  return fit;
}

struct EffectFit {
  const Effect* effect = nullptr;
  std::vector<double> theta;  // fitted parameters
  Eigen::MatrixXd columns;    // n × p linear(ised) columns at theta (linear parameters only for profiling)
  Fit fit;                    // of [X, columns]
  std::vector<double> std_errors;
};

// Fits effect e together with the current design X. Linear effects: one least squares. An effect
// with one nonlinear parameter (τ): profile the RSS over a log grid, refine by golden section, then
// the standard errors from the full Jacobian (linearised in τ).
EffectFit FitEffect(const Problem& prob, const Effect* e, const Eigen::MatrixXd& x) {
  EffectFit out;
  out.effect = e;
  const auto& spec = e->parameters();
  const int p = static_cast<int>(spec.size());
  auto assemble = [&](const Eigen::MatrixXd& cols) {
    Eigen::MatrixXd a(prob.n(), x.cols() + cols.cols());
    a << x, cols;
    return a;
  };
  int nonlinear = -1;
  for (int k = 0; k < p; ++k) {
    if (!spec[k].linear) nonlinear = k;
  }
  if (nonlinear < 0) {
    out.columns = prob.jacobian(e, std::vector<double>(p, 0.0));
    out.fit = LeastSquares(assemble(out.columns), prob.r);
    for (int k = 0; k < p; ++k) {
      out.theta.push_back(out.fit.beta[x.cols() + k]);
      out.std_errors.push_back(std::sqrt(std::max(0.0, out.fit.cov(x.cols() + k, x.cols() + k))));
    }
    return out;
  }
  // Linear columns at a value of the nonlinear parameter (linear parameters set to 1: the columns of
  // a separable model do not depend on them).
  auto linear_columns = [&](double q) {
    std::vector<double> theta(p, 1.0);
    theta[nonlinear] = q;
    const Eigen::MatrixXd j = prob.jacobian(e, theta);
    Eigen::MatrixXd cols(prob.n(), p - 1);
    for (int k = 0, c = 0; k < p; ++k) {
      if (k != nonlinear) cols.col(c++) = j.col(k);
    }
    return cols;
  };
  auto rss_at = [&](double log_q) { return LeastSquares(assemble(linear_columns(std::exp(log_q))), prob.r).rss; };
  const double lo = std::log(prob.time_scale_s / 100.0), hi = std::log(prob.time_scale_s * 100.0);
  constexpr int kGrid = 33;
  int best = 0;
  std::vector<double> grid(kGrid), rss(kGrid);
  for (int g = 0; g < kGrid; ++g) {
    grid[g] = lo + (hi - lo) * g / (kGrid - 1);
    rss[g] = rss_at(grid[g]);
    if (rss[g] < rss[best]) best = g;
  }
  double a = grid[std::max(0, best - 1)], b = grid[std::min(kGrid - 1, best + 1)];
  const double phi = 0.5 * (std::sqrt(5.0) - 1.0);
  double c = b - phi * (b - a), d = a + phi * (b - a);
  double fc = rss_at(c), fd = rss_at(d);
  for (int it = 0; it < 40 && b - a > 1e-6; ++it) {
    if (fc < fd) {
      b = d, d = c, fd = fc, c = b - phi * (b - a), fc = rss_at(c);
    } else {
      a = c, c = d, fc = fd, d = a + phi * (b - a), fd = rss_at(d);
    }
  }
  const double q = std::exp(0.5 * (a + b));
  const Eigen::MatrixXd lin = linear_columns(q);
  const Fit lin_fit = LeastSquares(assemble(lin), prob.r);
  std::vector<double> theta(p);
  for (int k = 0, col = 0; k < p; ++k) theta[k] = k == nonlinear ? q : lin_fit.beta[x.cols() + col++];
  // Full linearised Jacobian at the optimum for the standard errors (and the "columns" reported).
  out.columns = prob.jacobian(e, theta);
  Fit full = LeastSquares(assemble(out.columns), prob.r);
  full.residual = lin_fit.residual;  // the exact nonlinear residual
  full.rss = lin_fit.rss;
  const double s2 = full.rss / std::max(1.0, static_cast<double>(prob.n() - x.cols() - p));
  const Eigen::MatrixXd af = assemble(out.columns);
  full.cov = s2 * (af.transpose() * af).completeOrthogonalDecomposition().pseudoInverse();
  out.fit = full;
  out.theta = theta;
  for (int k = 0; k < p; ++k) out.std_errors.push_back(std::sqrt(std::max(0.0, full.cov(x.cols() + k, x.cols() + k))));
  return out;
}

double MoranZ(const Eigen::VectorXd& residual, const Eigen::MatrixXd& design, const metrology::SpatialWeights& w) {
  Eigen::MatrixXd x(residual.size(), design.cols() + 1);
  x << Eigen::VectorXd::Ones(residual.size()), design;
  const auto m = metrology::ResidualMoranI(residual, x, w, metrology::IslandPolicy::kZero);
  // The weights come from k-NN lists (no islands) and x has full column count ≤ n, so this cannot
  // fail short of a bug; NaN makes one visible in the report instead of passing as "independent".
  return m.ok() ? m->z : std::numeric_limits<double>::quiet_NaN();
}

double NuggetVariance(const Eigen::VectorXd& r, const std::vector<std::vector<int>>& neighbours) {
  // Half the mean squared difference to the nearest listed neighbour: the variance of the i.i.d. part
  // when the systematic part changes little between neighbours.
  double sum = 0;
  int n = 0;
  for (int i = 0; i < r.size(); ++i) {
    if (neighbours[i].empty()) continue;
    const double d = r[i] - r[neighbours[i].front()];
    sum += 0.5 * d * d;
    ++n;
  }
  return n > 0 ? sum / n : 0.0;
}

// Spatial block CV (metrology/spatial_cv.h): leave one x-y block out, refit the named columns on the rest,
// predict it.
double BlockCvRms(const Problem& prob, const Eigen::MatrixXd& design, int blocks) {
  const int n = prob.n();
  if (design.cols() == 0) return std::sqrt(prob.r.squaredNorm() / n);
  const std::vector<int> block = metrology::GridBlocks(prob.xy.col(0), prob.xy.col(1), blocks);
  return metrology::SpatialBlockCv(block, blocks * blocks, prob.r,
                                   [&](const std::vector<int>& train) {
                                     Eigen::MatrixXd a(train.size(), design.cols());
                                     Eigen::VectorXd y(train.size());
                                     for (std::size_t t = 0; t < train.size(); ++t) {
                                       a.row(t) = design.row(train[t]);
                                       y[t] = prob.r[train[t]];
                                     }
                                     Eigen::ColPivHouseholderQR<Eigen::MatrixXd> qr(a);
                                     qr.setThreshold(1e-10);
                                     const Eigen::VectorXd beta = qr.solve(y);
                                     return std::optional<metrology::HeldOutPredictor>(
                                         [&design, beta](int i) { return design.row(i).dot(beta); });
                                   })
      .rms;
}

Result<Diagnosis> SelectCauses(const Problem& prob, const Model& baseline, const DiagnoseOptions& options) {
  const int n = prob.n();
  Diagnosis out;
  out.n = n;
  out.extended = baseline;
  std::vector<double> r_std(prob.r.data(), prob.r.data() + n);
  out.residual_um = r_std;
  FL_ASSIGN_OR_RETURN(const metrology::SpatialWeights w,
                      metrology::WeightsFromNeighbours(prob.neighbours, metrology::WeightStyle::kRowStandardised));

  // Candidates: applicable catalogue effects with parameters, not in the baseline, as asked.
  std::vector<const Effect*> candidates;
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
    candidates.push_back(e);
  }
  const Eigen::MatrixXd empty(n, 0);
  out.rms_before_um = std::sqrt(prob.r.squaredNorm() / n);
  out.z_before = MoranZ(prob.r, empty, w);
  const double nugget = NuggetVariance(prob.r, prob.neighbours);
  out.noise_sigma_um = std::sqrt(nugget);
  const double rss0 = prob.r.squaredNorm();

  Eigen::MatrixXd x = empty;
  Fit current = LeastSquares(x, prob.r);
  double z_current = out.z_before;
  std::vector<EffectFit> named;
  while (static_cast<int>(named.size()) < options.max_causes && !candidates.empty()) {
    std::vector<ScreenedEffect> step;
    std::vector<EffectFit> fits;
    const double k_tests = static_cast<double>(candidates.size());
    int best = -1;
    for (const Effect* e : candidates) {
      EffectFit f = FitEffect(prob, e, x);
      ScreenedEffect s;
      s.effect = std::string(e->name());
      s.parameters = f.theta;
      s.std_errors = f.std_errors;
      s.rss_drop = current.rss - f.fit.rss;
      const int q = e->parameter_count();
      const int dof2 = n - static_cast<int>(x.cols()) - q;
      if (dof2 > 0 && f.fit.rss > 0 && s.rss_drop > 0) {
        s.f = (s.rss_drop / q) / (f.fit.rss / dof2);
        s.p_value = boost::math::cdf(boost::math::complement(boost::math::fisher_f(q, dof2), s.f));
      }
      s.delta_bic = n * std::log(std::max(f.fit.rss, 1e-300) / std::max(current.rss, 1e-300)) + q * std::log(n);
      const double systematic = current.rss - n * nugget;
      s.share = systematic > 0 ? s.rss_drop / systematic : (s.rss_drop > 0 ? 1.0 : 0.0);
      s.significant = s.p_value < options.alpha / k_tests && s.delta_bic < 0 && s.share >= options.min_share;
      step.push_back(s);
      fits.push_back(std::move(f));
      const int idx = static_cast<int>(step.size()) - 1;
      if (s.significant && (best < 0 || s.delta_bic < step[best].delta_bic)) best = idx;
    }
    // Moran's z after each candidate, for the screening table.
    for (std::size_t i = 0; i < step.size(); ++i) {
      Eigen::MatrixXd a(n, x.cols() + fits[i].columns.cols());
      a << x, fits[i].columns;
      step[i].z_after = MoranZ(fits[i].fit.residual, a, w);
    }
    std::sort(step.begin(), step.end(), [](const ScreenedEffect& a, const ScreenedEffect& b) {
      return a.delta_bic < b.delta_bic || (a.delta_bic == b.delta_bic && a.effect < b.effect);
    });
    if (best < 0) {
      out.screening.push_back(std::move(step));
      break;
    }
    EffectFit chosen = std::move(fits[best]);
    const Effect* e = chosen.effect;
    Cause cause;
    cause.effect = std::string(e->name());
    for (const auto& p : e->parameters()) cause.parameter_names.push_back(p.name);
    cause.z_before = z_current;
    Eigen::MatrixXd a(n, x.cols() + chosen.columns.cols());
    a << x, chosen.columns;
    cause.z_after = MoranZ(chosen.fit.residual, a, w);
    cause.variance_explained = rss0 > 0 ? (current.rss - chosen.fit.rss) / rss0 : 0.0;
    // Confounding: how well each other candidate reproduces this effect's contribution.
    const Eigen::VectorXd contribution =
        chosen.columns * Eigen::Map<const Eigen::VectorXd>(chosen.theta.data(), chosen.theta.size());
    for (std::size_t i = 0; i < candidates.size(); ++i) {
      if (candidates[i] == e) continue;
      const Eigen::MatrixXd cols = fits[i].columns;
      if (cols.cols() == 0) continue;
      const Fit g = LeastSquares(cols, contribution);
      const double total = contribution.squaredNorm();
      if (total <= 0) continue;
      const double corr = std::sqrt(std::max(0.0, 1.0 - g.rss / total));
      if (corr >= options.confounded_correlation) {
        out.confounded.push_back({cause.effect, std::string(candidates[i]->name()), corr,
                                  SeparateHint(cause.effect) + "; " + SeparateHint(candidates[i]->name())});
      }
    }
    z_current = cause.z_after;
    x = a;
    current = chosen.fit;
    candidates.erase(std::find(candidates.begin(), candidates.end(), e));
    out.causes.push_back(cause);
    out.screening.push_back(std::move(step));
    named.push_back(std::move(chosen));
  }
  // Final joint parameters and standard errors of the named effects. A nonlinear parameter (τ) was
  // profiled with only the effects named before it; profile it again against all the others (twice:
  // enough for the weak coupling left), then rebuild the design.
  for (int sweep = 0; sweep < 2; ++sweep) {
    for (std::size_t k = 0; k < named.size(); ++k) {
      if (named[k].effect->linear()) continue;
      Eigen::MatrixXd others(n, 0);
      for (std::size_t o = 0; o < named.size(); ++o) {
        if (o == k) continue;
        Eigen::MatrixXd grown(n, others.cols() + named[o].columns.cols());
        grown << others, named[o].columns;
        others = grown;
      }
      named[k] = FitEffect(prob, named[k].effect, others);
    }
  }
  if (!named.empty()) {
    x.resize(n, 0);
    for (const auto& f : named) {
      Eigen::MatrixXd grown(n, x.cols() + f.columns.cols());
      grown << x, f.columns;
      x = grown;
    }
    const Fit joint = LeastSquares(x, prob.r);
    int col = 0;
    for (std::size_t k = 0; k < named.size(); ++k) {
      const Effect* e = named[k].effect;
      Cause& cause = out.causes[k];
      cause.parameters.clear();
      cause.std_errors.clear();
      for (int j = 0; j < e->parameter_count(); ++j, ++col) {
        if (x.col(col).norm() == 0) {
          // Not observable in these data (e.g. a z parameter from 2-D feature positions): reported as
          // null, kept at 0 in the extended model.
          cause.parameters.push_back(std::numeric_limits<double>::quiet_NaN());
          cause.std_errors.push_back(std::numeric_limits<double>::quiet_NaN());
          continue;
        }
        // A nonlinear parameter (τ) keeps its profiled optimum, where its column's coefficient is ~0;
        // its standard error comes from the joint linearised fit like the others'.
        cause.parameters.push_back(e->parameters()[j].linear ? joint.beta[col] : named[k].theta[j]);
        cause.std_errors.push_back(std::sqrt(std::max(0.0, joint.cov(col, col))));
      }
      std::vector<double> v = cause.parameters, se = cause.std_errors;
      for (std::size_t j = 0; j < v.size(); ++j) {
        if (std::isnan(v[j])) v[j] = se[j] = 0.0;
      }
      (void)out.extended.Set(e->name(), v, se);
    }
    current = joint;
  }
  out.residual_after_um.assign(current.residual.data(), current.residual.data() + n);
  out.rms_after_um = std::sqrt(current.rss / n);
  out.z_after = MoranZ(current.residual, x, w);
  out.heldout_rms_before_um = out.rms_before_um;
  out.heldout_rms_after_um = BlockCvRms(prob, x, options.cv_blocks);
  out.explained_by_baseline = out.causes.empty() && out.z_before <= options.z_critical;
  out.unexplained = out.z_after > options.z_critical;
  if (out.unexplained) {
    // Where: local Moran clusters of the remaining residual (analytical p, α = 0.01).
    metrology::LocalMoranOptions lo;
    lo.permutations = 0;
    lo.alpha = 0.01;
    lo.islands = metrology::IslandPolicy::kZero;
    const auto lisa = metrology::LocalMoranI(current.residual, w, lo);
    if (lisa.ok()) {
      for (int q : {1, 3}) {
        int count = 0;
        Eigen::Vector2d centroid = Eigen::Vector2d::Zero();
        double mean = 0;
        for (int i = 0; i < n; ++i) {
          if (lisa->quadrant[i] == q && lisa->p_analytical[i] < lo.alpha) {
            ++count;
            centroid += prob.xy.row(i).transpose();
            mean += current.residual[i];
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
  out.extended.provenance = {
      {"baseline", baseline.provenance}, {"diagnosed_points", n}, {"named", nlohmann::json::array()}};
  for (const auto& c : out.causes) out.extended.provenance["named"].push_back(c.effect);
  return out;
}

// points: n × d (one point per row).
Result<std::vector<std::vector<int>>> KnnLists(const Eigen::MatrixXd& points, int k) {
  FL_ASSIGN_OR_RETURN(const auto w, metrology::KnnWeights(points.transpose(), k, metrology::WeightStyle::kBinary));
  return w.Neighbours();
}

// The rows `keep` of a problem, with k-NN lists rebuilt among them.
Result<Problem> Subset(const Problem& prob, const std::vector<int>& keep, int knn);

// Points of significant local Moran HH/LL clusters of r (α = 0.01, analytical), grown by `rings` rings
// of neighbours: the region a localised pattern occupies.
std::vector<bool> AnomalyRegion(const Problem& prob, const metrology::SpatialWeights& w, int rings) {
  std::vector<bool> in(prob.n(), false);
  metrology::LocalMoranOptions lo;
  lo.permutations = 0;
  lo.alpha = 0.01;
  lo.islands = metrology::IslandPolicy::kZero;
  const auto lisa = metrology::LocalMoranI(prob.r, w, lo);
  if (!lisa.ok()) return in;
  for (int i = 0; i < prob.n(); ++i) {
    in[i] = (lisa->quadrant[i] == 1 || lisa->quadrant[i] == 3) && lisa->p_analytical[i] < lo.alpha;
  }
  for (int ring = 0; ring < rings; ++ring) {
    std::vector<bool> grown = in;
    for (int i = 0; i < prob.n(); ++i) {
      if (!in[i]) continue;
      for (int j : prob.neighbours[i]) grown[j] = true;
    }
    in = grown;
  }
  return in;
}

// Names the causes (SelectCauses) and then guards against a pattern outside the catalogue: when the
// residual after the named effects is still correlated, the named effects may be fitting a sliver of
// that pattern. The pattern's region (AnomalyRegion of the baseline residual: its significant local
// Moran clusters, grown ring by ring — 2, 4, 8, 16 rings — while the rest still shows a correlated
// residual) is set aside and the selection repeated on the rest; what it names there stands, fitted
// there, and the region is reported as the unexplained systematic residual. A real global effect is
// named either way; a bump is not pinned on one. When no region under half the part leaves an
// uncorrelated rest, the pattern is not localised and the first selection stands (still reported as
// leaving an unexplained systematic residual).
Result<Diagnosis> RunEngine(const Problem& prob, const Model& baseline, const DiagnoseOptions& options) {
  FL_RETURN_IF_ERROR(options.Validate());
  FL_ASSIGN_OR_RETURN(Diagnosis first, SelectCauses(prob, baseline, options));
  // (Feature data has no positions for rebuilding neighbours: its observations are coordinates.)
  if (!first.unexplained || first.causes.empty() || prob.pos.cols() == 0) return first;
  FL_ASSIGN_OR_RETURN(const metrology::SpatialWeights w,
                      metrology::WeightsFromNeighbours(prob.neighbours, metrology::WeightStyle::kRowStandardised));
  std::vector<bool> region;
  int set_aside = 0;
  Diagnosis second;
  bool isolated = false;
  for (int rings : {2, 4, 8, 16}) {
    region = AnomalyRegion(prob, w, rings);
    std::vector<int> keep;
    for (int i = 0; i < prob.n(); ++i) {
      if (!region[i]) keep.push_back(i);
    }
    set_aside = prob.n() - static_cast<int>(keep.size());
    if (set_aside == 0 || set_aside > prob.n() / 2 || static_cast<int>(keep.size()) < 20) break;
    FL_ASSIGN_OR_RETURN(const Problem outside, Subset(prob, keep, options.knn));
    FL_ASSIGN_OR_RETURN(second, SelectCauses(outside, baseline, options));
    if (!second.unexplained) {
      isolated = true;
      break;
    }
  }
  if (!isolated) return first;
  // Apply the causes found outside to every point.
  Diagnosis out = first;
  out.causes = second.causes;
  out.screening = second.screening;
  out.confounded = second.confounded;
  out.extended = second.extended;
  Eigen::VectorXd predicted = Eigen::VectorXd::Zero(prob.n());
  Eigen::MatrixXd design(prob.n(), 0);
  for (const Cause& c : out.causes) {
    const Effect* e = FindEffect(c.effect);
    const Eigen::MatrixXd j = prob.jacobian(e, c.parameters);
    for (int k = 0; k < e->parameter_count(); ++k) {
      if (e->parameters()[k].linear) predicted += j.col(k) * c.parameters[k];
    }
    Eigen::MatrixXd grown(prob.n(), design.cols() + j.cols());
    grown << design, j;
    design = grown;
  }
  const Eigen::VectorXd residual = prob.r - predicted;
  out.residual_after_um.assign(residual.data(), residual.data() + prob.n());
  out.rms_after_um = std::sqrt(residual.squaredNorm() / prob.n());
  out.z_after = MoranZ(residual, Eigen::MatrixXd(prob.n(), 0), w);
  out.heldout_rms_after_um = BlockCvRms(prob, design, options.cv_blocks);
  out.unexplained = true;
  out.unexplained_where = nlohmann::json::array();
  Eigen::Vector2d centroid = Eigen::Vector2d::Zero();
  double peak = 0, mean = 0;
  Eigen::Vector2d peak_xy = Eigen::Vector2d::Zero();
  for (int i = 0; i < prob.n(); ++i) {
    if (!region[i]) continue;
    centroid += prob.xy.row(i).transpose();
    mean += residual[i];
    if (std::abs(residual[i]) > std::abs(peak)) {
      peak = residual[i];
      peak_xy = prob.xy.row(i).transpose();
    }
  }
  out.unexplained_where.push_back({{"region", "local Moran clusters of the baseline residual, grown by two rings"},
                                   {"points", set_aside},
                                   {"centroid_xy_mm", {centroid.x() / set_aside, centroid.y() / set_aside}},
                                   {"mean_residual_um", mean / set_aside},
                                   {"peak_residual_um", peak},
                                   {"peak_xy_mm", {peak_xy.x(), peak_xy.y()}},
                                   {"causes_named_before_setting_it_aside", nlohmann::json::array()}});
  for (const Cause& c : first.causes)
    out.unexplained_where.back()["causes_named_before_setting_it_aside"].push_back(c.effect);
  return out;
}

Result<Problem> Subset(const Problem& prob, const std::vector<int>& keep, int knn) {
  Problem sub;
  const int m = static_cast<int>(keep.size());
  sub.r.resize(m);
  sub.xy.resize(m, 2);
  sub.pos.resize(m, prob.pos.cols());
  for (int t = 0; t < m; ++t) {
    sub.r[t] = prob.r[keep[t]];
    sub.xy.row(t) = prob.xy.row(keep[t]);
    sub.pos.row(t) = prob.pos.row(keep[t]);
  }
  FL_ASSIGN_OR_RETURN(sub.neighbours, KnnLists(sub.pos, std::min(knn, m - 1)));
  sub.applicable = prob.applicable;
  sub.time_scale_s = prob.time_scale_s;
  const auto full_jacobian = prob.jacobian;
  sub.jacobian = [full_jacobian, keep](const Effect* e, const std::vector<double>& theta) {
    const Eigen::MatrixXd j = full_jacobian(e, theta);
    Eigen::MatrixXd out(keep.size(), j.cols());
    for (std::size_t t = 0; t < keep.size(); ++t) out.row(static_cast<Eigen::Index>(t)) = j.row(keep[t]);
    return out;
  };
  return sub;
}

Eigen::MatrixXd ProbeJacobian(const std::vector<PointContext>& contexts, const Effect* e,
                              const std::vector<double>& theta) {
  const int p = e->parameter_count();
  Eigen::MatrixXd j(contexts.size(), p);
  std::vector<double> row(p);
  for (std::size_t i = 0; i < contexts.size(); ++i) {
    e->Jacobian(contexts[i], theta, row);
    for (int k = 0; k < p; ++k) j(static_cast<Eigen::Index>(i), k) = row[k];
  }
  return j;
}

}  // namespace

Status DiagnoseOptions::Validate() const {
  if (!(alpha > 0 && alpha < 1)) return Status::BadInput(Where{.field = "alpha"}, "must be in (0, 1)");
  if (!(min_share >= 0 && min_share < 1)) return Status::BadInput(Where{.field = "min_share"}, "must be in [0, 1)");
  if (knn < 1) return Status::BadInput(Where{.field = "knn"}, "must be >= 1");
  if (cv_blocks < 2) return Status::BadInput(Where{.field = "cv_blocks"}, "must be >= 2");
  for (const auto& c : candidates) {
    if (FindEffect(c) == nullptr) {
      return Status::BadInput(Where{.field = "candidates"}, "unknown effect '" + c + "'",
                              "use one of " + EffectNames());
    }
  }
  return Status::Ok();
}

Result<Diagnosis> DiagnoseResiduals(const std::vector<PointContext>& contexts, const Eigen::VectorXd& residual_um,
                                    const Model& baseline, const DiagnoseOptions& options,
                                    const MeasurementSensitivity* sensitivity) {
  const int n = static_cast<int>(contexts.size());
  if (residual_um.size() != n) return Status::Internal("residuals and contexts differ in size");
  if (n < 20) return Status::BadInput("diagnose needs at least 20 measured points, got " + std::to_string(n));
  Problem prob;
  prob.r = residual_um;
  prob.xy.resize(n, 2);
  Eigen::MatrixXd xyz(n, 3);
  double t_max = 0;
  for (int i = 0; i < n; ++i) {
    prob.xy.row(i) = contexts[i].point.head<2>().transpose();
    xyz.row(i) = contexts[i].point.transpose();
    t_max = std::max(t_max, contexts[i].cut_time_s);
  }
  FL_ASSIGN_OR_RETURN(prob.neighbours, KnnLists(xyz, std::min(options.knn, n - 1)));
  prob.pos = xyz;
  prob.applicable = [](const Effect*) { return true; };
  if (sensitivity != nullptr && (sensitivity->surface.size() != n || sensitivity->radius.size() != n)) {
    return Status::Internal("measurement sensitivities and contexts differ in size");
  }
  prob.jacobian = [&contexts, sensitivity](const Effect* e, const std::vector<double>& theta) {
    Eigen::MatrixXd j = ProbeJacobian(contexts, e, theta);
    if (sensitivity == nullptr) return j;
    for (Eigen::Index i = 0; i < j.rows(); ++i) {
      const PointContext& c = contexts[static_cast<std::size_t>(i)];
      if (e->kind() == EffectKind::kMeasurement) {
        // The basis is ΔR·c_a; the measured response to ΔR is radius[i].
        const double ca = std::max(1e-6, -c.approach.dot(c.normal));
        j.row(i) *= sensitivity->radius[i] / ca;
      } else {
        j.row(i) *= sensitivity->surface[i];
      }
    }
    return j;
  };
  prob.time_scale_s = std::max(1.0, t_max);
  return RunEngine(prob, baseline, options);
}

Result<ProbeResidualData> ProbeResiduals(const ProbeDataInput& in, const Model& baseline) {
  if (in.surface == nullptr || in.cutter_locations == nullptr || in.plan == nullptr || in.measured == nullptr) {
    return Status::Internal("ProbeResiduals: missing input");
  }
  std::map<std::int64_t, const metrology::ProbePoint*> by_id;
  for (const auto& p : in.plan->points) by_id[p.id] = &p;
  std::vector<MeasuredPoint> points;
  for (const auto& rec : in.measured->records) {
    const auto it = by_id.find(rec.id);
    if (it == by_id.end()) {
      return Status::BadInput(Where{.file = in.measured->source, .line = rec.line},
                              "probe id " + std::to_string(rec.id) + " is not in the probing plan",
                              "give the plan the log was measured with");
    }
    points.push_back({rec.id, it->second->point, it->second->normal, rec.approach});
  }
  ProbeResidualData out;
  FL_ASSIGN_OR_RETURN(out.contexts, AssociateWithToolpath(*in.cutter_locations, in.tool_radius_mm, points));
  auto deviations_um = [&](const metrology::ProbeLog& log) -> Result<Eigen::VectorXd> {
    FL_ASSIGN_OR_RETURN(const auto dev, metrology::ComputeDeviations(*in.surface, *in.plan, log, in.probe));
    Eigen::VectorXd d(static_cast<Eigen::Index>(dev.size()));
    for (std::size_t i = 0; i < dev.size(); ++i) d[static_cast<Eigen::Index>(i)] = 1e3 * dev[i].deviation_mm;
    return d;
  };
  FL_ASSIGN_OR_RETURN(const Eigen::VectorXd measured, deviations_um(*in.measured));
  FL_ASSIGN_OR_RETURN(const Eigen::VectorXd simulated,
                      deviations_um(PredictProbeLog(out.contexts, baseline, in.probe)));
  out.residual_um = measured - simulated;
  // Sensitivities by a 1 µm step through the same chain (the response is linear to ~1e-4 over tens of µm).
  FL_ASSIGN_OR_RETURN(const Eigen::VectorXd shifted,
                      deviations_um(PredictProbeLog(out.contexts, baseline, in.probe, 1.0, 0.0)));
  FL_ASSIGN_OR_RETURN(const Eigen::VectorXd widened,
                      deviations_um(PredictProbeLog(out.contexts, baseline, in.probe, 0.0, 1.0)));
  out.sensitivity.surface = shifted - simulated;
  out.sensitivity.radius = widened - simulated;
  return out;
}

Result<Diagnosis> Diagnose(const ProbeDataInput& input, const Model& baseline, const DiagnoseOptions& options) {
  FL_ASSIGN_OR_RETURN(const ProbeResidualData data, ProbeResiduals(input, baseline));
  return DiagnoseResiduals(data.contexts, data.residual_um, baseline, options, &data.sensitivity);
}

Result<double> PredictionRms(const ProbeDataInput& input, const Model& model) {
  FL_ASSIGN_OR_RETURN(const ProbeResidualData data, ProbeResiduals(input, model));
  return std::sqrt(data.residual_um.squaredNorm() / std::max<Eigen::Index>(1, data.residual_um.size()));
}

Result<Diagnosis> DiagnosePlanOnly(const metrology::ProbingPlan& plan, const metrology::ProbeLog& measured,
                                   const metrology::ProbeModel& probe, const Model& baseline, DiagnoseOptions options) {
  std::map<std::int64_t, const metrology::ProbePoint*> by_id;
  for (const auto& p : plan.points) by_id[p.id] = &p;
  std::vector<PointContext> contexts;
  Eigen::VectorXd r(static_cast<Eigen::Index>(measured.records.size()));
  for (std::size_t i = 0; i < measured.records.size(); ++i) {
    const auto& rec = measured.records[i];
    const auto it = by_id.find(rec.id);
    if (it == by_id.end()) {
      return Status::BadInput(Where{.file = measured.source, .line = rec.line},
                              "probe id " + std::to_string(rec.id) + " is not in the probing plan",
                              "give the plan the log was measured with");
    }
    PointContext c;
    c.id = rec.id;
    c.point = it->second->point;
    c.normal = it->second->normal;
    c.approach = rec.approach;
    const double measured_um = 1e3 * (metrology::ContactPoint(rec, probe) - c.point).dot(c.normal);
    r[static_cast<Eigen::Index>(i)] = measured_um - baseline.DeviationUm(c);
    contexts.push_back(c);
  }
  options.toolpath_known = false;
  return DiagnoseResiduals(contexts, r, baseline, options);
}

Result<std::vector<FeaturePosition>> ReadFeatures(const std::string& path) {
  std::ifstream in(path);
  if (!in) return Status::NotFound("cannot open feature file '" + path + "'");
  std::string line;
  long line_no = 0;
  std::vector<std::string> header;
  std::vector<FeaturePosition> out;
  auto split = [](const std::string& s) {
    std::vector<std::string> cells;
    std::stringstream ss(s);
    std::string cell;
    while (std::getline(ss, cell, ',')) {
      cell.erase(0, cell.find_first_not_of(" \t\r"));
      cell.erase(cell.find_last_not_of(" \t\r") + 1);
      cells.push_back(cell);
    }
    return cells;
  };
  std::map<std::string, int> col;
  while (std::getline(in, line)) {
    ++line_no;
    if (line.empty() || line[0] == '#') continue;
    const auto cells = split(line);
    if (col.empty()) {
      for (std::size_t i = 0; i < cells.size(); ++i) col[cells[i]] = static_cast<int>(i);
      for (const char* need : {"id", "x_nom", "y_nom", "x", "y"}) {
        if (!col.count(need)) {
          return Status::BadInput(Where{.file = path, .line = line_no, .field = need}, "missing column",
                                  "the header must name id, x_nom, y_nom, [z_nom,] x, y, [z]");
        }
      }
      if (col.count("z_nom") != col.count("z")) {
        return Status::BadInput(Where{.file = path, .line = line_no, .field = col.count("z") ? "z_nom" : "z"},
                                "missing column", "give both z_nom and z, or neither");
      }
      continue;
    }
    if (cells.size() < col.size()) {
      return Status::BadInput(Where{.file = path, .line = line_no},
                              "expected " + std::to_string(col.size()) + " cells");
    }
    FeaturePosition f;
    f.id = cells[col["id"]];
    f.has_z = col.count("z") > 0;
    auto number = [&](const char* name, double* value) -> Status {
      const std::string& s = cells[col[name]];
      char* end = nullptr;
      *value = std::strtod(s.c_str(), &end);
      if (s.empty() || end != s.c_str() + s.size() || !std::isfinite(*value)) {
        return Status::BadInput(Where{.file = path, .line = line_no, .field = name},
                                "'" + s + "' is not a finite number");
      }
      return Status::Ok();
    };
    FL_RETURN_IF_ERROR(number("x_nom", &f.nominal.x()));
    FL_RETURN_IF_ERROR(number("y_nom", &f.nominal.y()));
    FL_RETURN_IF_ERROR(number("x", &f.measured.x()));
    FL_RETURN_IF_ERROR(number("y", &f.measured.y()));
    if (f.has_z) {
      FL_RETURN_IF_ERROR(number("z_nom", &f.nominal.z()));
      FL_RETURN_IF_ERROR(number("z", &f.measured.z()));
    }
    for (const auto& other : out) {
      if (other.id == f.id) {
        return Status::BadInput(Where{.file = path, .line = line_no, .field = "id"}, "duplicated id '" + f.id + "'");
      }
    }
    out.push_back(f);
  }
  if (col.empty()) return Status::BadInput(Where{.file = path}, "empty file", "give a header and one row per feature");
  return out;
}

Result<Diagnosis> DiagnoseFeatures(const std::vector<FeaturePosition>& features, const Model& baseline,
                                   const DiagnoseOptions& options) {
  if (features.size() < 4) return Status::BadInput("feature diagnosis needs at least 4 features");
  const bool has_z = features.front().has_z;
  const int dims = has_z ? 3 : 2;
  const int m = static_cast<int>(features.size());
  const int n = m * dims;
  Problem prob;
  prob.r.resize(n);
  prob.xy.resize(n, 2);
  Eigen::MatrixXd pos(m, 3);
  for (int i = 0; i < m; ++i) {
    const auto& f = features[i];
    pos.row(i) = f.nominal.transpose();
    Eigen::Vector3d predicted = Eigen::Vector3d::Zero();
    for (const auto& e : baseline.effects) {
      if (e.effect->acts_on_positions()) predicted += e.effect->DisplacementUm(f.nominal, e.values);
    }
    const Eigen::Vector3d d = 1e3 * (f.measured - f.nominal) - predicted;
    for (int k = 0; k < dims; ++k) {
      prob.r[i * dims + k] = d[k];
      prob.xy.row(i * dims + k) = f.nominal.head<2>().transpose();
    }
  }
  // Neighbours: the same coordinate of the k nearest features.
  FL_ASSIGN_OR_RETURN(const auto feature_nn,
                      KnnLists(has_z ? pos : Eigen::MatrixXd(pos.leftCols(2)), std::min(options.knn, m - 1)));
  prob.neighbours.resize(n);
  for (int i = 0; i < m; ++i) {
    for (int k = 0; k < dims; ++k) {
      for (int j : feature_nn[i]) prob.neighbours[i * dims + k].push_back(j * dims + k);
    }
  }
  prob.applicable = [has_z](const Effect* e) {
    if (!e->acts_on_positions()) return false;
    // Without z, effects that only move z or depend on z are not observable.
    if (!has_z) {
      const std::string_view name = e->name();
      if (name == "axis_scale_z" || name == "squareness_yz" || name == "squareness_zx") return false;
    }
    return true;
  };
  prob.jacobian = [&features, dims, n](const Effect* e, const std::vector<double>&) {
    const int p = e->parameter_count();
    Eigen::MatrixXd j(n, p);
    for (int k = 0; k < p; ++k) {
      std::vector<double> unit(p, 0.0);
      unit[k] = 1.0;
      for (std::size_t i = 0; i < features.size(); ++i) {
        const Eigen::Vector3d d = e->DisplacementUm(features[i].nominal, unit);
        for (int c = 0; c < dims; ++c) j(static_cast<Eigen::Index>(i) * dims + c, k) = d[c];
      }
    }
    return j;
  };
  // 2-D data: setup_offset's and setup_rotation's out-of-plane parts have zero columns; they are
  // reported as not observable (null) and kept at 0 in the extended model.
  return RunEngine(prob, baseline, options);
}

nlohmann::json Diagnosis::ToJson() const {
  nlohmann::json causes_json = nlohmann::json::array();
  for (const auto& c : causes) {
    nlohmann::json params = nlohmann::json::object(), errors = nlohmann::json::object();
    for (std::size_t k = 0; k < c.parameter_names.size(); ++k) {
      params[c.parameter_names[k]] = c.parameters[k];
      errors[c.parameter_names[k]] = c.std_errors[k];
    }
    causes_json.push_back({{"effect", c.effect},
                           {"parameters", params},
                           {"std_errors", errors},
                           {"variance_explained", c.variance_explained},
                           {"z_before", c.z_before},
                           {"z_after", c.z_after}});
  }
  nlohmann::json screening_json = nlohmann::json::array();
  for (const auto& step : screening) {
    nlohmann::json rows = nlohmann::json::array();
    for (const auto& s : step) {
      rows.push_back({{"effect", s.effect},
                      {"parameters", s.parameters},
                      {"std_errors", s.std_errors},
                      {"rss_drop_um2", s.rss_drop},
                      {"F", s.f},
                      {"p", s.p_value},
                      {"delta_bic", s.delta_bic},
                      {"share_of_systematic", s.share},
                      {"z_after", s.z_after},
                      {"significant", s.significant}});
    }
    screening_json.push_back(rows);
  }
  nlohmann::json confounded_json = nlohmann::json::array();
  for (const auto& c : confounded) {
    confounded_json.push_back(
        {{"named", c.named}, {"with", c.other}, {"correlation", c.correlation}, {"separate_by", c.separate_by}});
  }
  nlohmann::json unexplained_json = nullptr;
  if (unexplained) {
    unexplained_json = {{"message", "unexplained systematic residual"}, {"z", z_after}, {"where", unexplained_where}};
  }
  return {{"format", "formloop-diagnosis"},
          {"version", 1},
          {"n", n},
          {"residual", {{"rms_um", rms_before_um}, {"z", z_before}, {"noise_sigma_um", noise_sigma_um}}},
          {"explained_by_baseline", explained_by_baseline},
          {"causes", causes_json},
          {"unexplained", unexplained_json},
          {"confounded", confounded_json},
          {"not_screened",
           {{"effects", not_screened},
            {"reason", not_screened.empty() ? "" : "needs the tool path (give the run folder)"}}},
          {"gain",
           {{"rms_before_um", rms_before_um},
            {"rms_after_um", rms_after_um},
            {"heldout_rms_before_um", heldout_rms_before_um},
            {"heldout_rms_after_um", heldout_rms_after_um}}},
          {"screening", screening_json},
          {"extended_model", extended.ToJson()}};
}

std::string Diagnosis::Summary() const {
  std::string s = fmt::format("diagnose: {} points, residual rms {:.2f} um, Moran z {:.2f}, noise sigma ~{:.2f} um\n",
                              n, rms_before_um, z_before, noise_sigma_um);
  if (explained_by_baseline) return s + "  the simulation explains the data: no cause named\n";
  for (const auto& c : causes) {
    s += fmt::format("  cause: {} (", c.effect);
    for (std::size_t k = 0; k < c.parameter_names.size(); ++k) {
      s +=
          fmt::format("{}{} = {:.4g} +- {:.2g}", k ? ", " : "", c.parameter_names[k], c.parameters[k], c.std_errors[k]);
    }
    s += fmt::format("); explains {:.0f}% of the residual variance; Moran z {:.2f} -> {:.2f}\n",
                     100 * c.variance_explained, c.z_before, c.z_after);
  }
  for (const auto& c : confounded) {
    s += fmt::format("  confounded: {} with {} (correlation {:.3f}); to separate: {}\n", c.named, c.other,
                     c.correlation, c.separate_by);
  }
  if (unexplained)
    s += fmt::format("  unexplained systematic residual (Moran z {:.2f} after the named causes)\n", z_after);
  s += fmt::format("  gain: rms {:.2f} -> {:.2f} um; held-out (block CV) {:.2f} -> {:.2f} um\n", rms_before_um,
                   rms_after_um, heldout_rms_before_um, heldout_rms_after_um);
  return s;
}

}  // namespace formloop::sim
