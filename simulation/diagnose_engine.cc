// The engine's building blocks (diagnose_engine.h): problems, least squares, one term's fit with a
// profiled τ, Moran's z, nugget, k-NN lists, block cross-validation, and RunEngine — the selection
// (diagnose_select.cc) guarded against a localised pattern outside the catalogue.

#include "simulation/diagnose_engine.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <map>
#include <optional>

#include <Eigen/QR>
#include <Eigen/SVD>

#include "core/golden_section.h"
#include "core/parallel.h"
#include "metrology/morans_i.h"
#include "metrology/spatial_cv.h"

namespace formloop::sim::detail {

Eigen::MatrixXd Problem::Columns(const Term& t, const std::vector<double>& theta) const {
  const int p = t.effect->parameter_count();
  std::vector<double> own(static_cast<std::size_t>(p), 0.0);
  for (int k = 0; k < p && k < static_cast<int>(theta.size()); ++k) own[k] = theta[k];
  Eigen::MatrixXd j = jacobian(t.effect, own);
  if (t.part == kEachPart) {
    Eigen::MatrixXd blocks = Eigen::MatrixXd::Zero(j.rows(), p * parts());
    for (Eigen::Index i = 0; i < j.rows(); ++i) {
      blocks.block(i, p * part_of[static_cast<std::size_t>(i)], 1, p) = weight[i] * j.row(i);
    }
    return blocks;
  }
  for (Eigen::Index i = 0; i < j.rows(); ++i) {
    if (t.part >= 0 && part_of[static_cast<std::size_t>(i)] != t.part) {
      j.row(i).setZero();
    } else {
      j.row(i) *= weight[i];
    }
  }
  return j;
}

int Problem::Width(const Term& t) const { return t.effect->parameter_count() * (t.part == kEachPart ? parts() : 1); }

std::string Problem::Label(const Term& t) const {
  std::string label(t.effect->name());
  if (t.part >= 0) label += "@" + part_names[static_cast<std::size_t>(t.part)];
  if (t.part == kEachPart) label += "@each part";
  return label;
}

Eigen::MatrixXd Concat(const Eigen::MatrixXd& a, const Eigen::MatrixXd& b) {
  if (a.cols() == 0) return b;
  if (b.cols() == 0) return a;
  Eigen::MatrixXd out(a.rows(), a.cols() + b.cols());
  out << a, b;
  return out;
}

namespace {

// Unit column norms (a zero column keeps scale 1): the rank decisions below compare columns of µm,
// µm/m and µrad effects on one scale, so an exactly duplicated column (a probe radius beside the tool
// radius probed along −n) is dropped and nothing else, whatever the rounding of the last bits.
Eigen::VectorXd ColumnScales(const Eigen::MatrixXd& a) {
  Eigen::VectorXd d(a.cols());
  for (Eigen::Index c = 0; c < a.cols(); ++c) {
    const double norm = a.col(c).norm();
    d[c] = norm > 0 ? 1.0 / norm : 1.0;
  }
  return d;
}

constexpr double kRankThreshold = 1e-10;  // relative to the largest pivot of the unit-norm columns

}  // namespace

Eigen::MatrixXd InverseGram(const Eigen::MatrixXd& a) {
  const Eigen::VectorXd d = ColumnScales(a);
  const Eigen::MatrixXd scaled = a * d.asDiagonal();
  // (AᵀA)⁺ = V Σ⁻² Vᵀ over the singular values above the threshold (thin SVD: p is small).
  Eigen::JacobiSVD<Eigen::MatrixXd, Eigen::ColPivHouseholderQRPreconditioner> svd(scaled, Eigen::ComputeThinV);
  const Eigen::VectorXd& sv = svd.singularValues();
  Eigen::VectorXd inv2 = Eigen::VectorXd::Zero(sv.size());
  const double cut = sv.size() > 0 ? kRankThreshold * sv[0] : 0.0;
  for (Eigen::Index k = 0; k < sv.size(); ++k) {
    if (sv[k] > cut) inv2[k] = 1.0 / (sv[k] * sv[k]);
  }
  const Eigen::MatrixXd& v = svd.matrixV();
  return d.asDiagonal() * (v * inv2.asDiagonal() * v.transpose()) * d.asDiagonal();
}

Fit LeastSquares(const Eigen::MatrixXd& a, const Eigen::VectorXd& r, bool covariance) {
  Fit fit;
  if (a.cols() == 0) {
    fit.residual = r;
    fit.rss = r.squaredNorm();
    return fit;
  }
  // Complete orthogonal decomposition of the unit-norm columns: the minimum-norm solution when
  // columns are (nearly) dependent, so an aliased direction carries no arbitrary value.
  const Eigen::VectorXd d = ColumnScales(a);
  // The threshold before the decomposition: COD's compute() completes the orthogonalisation at the
  // rank of its threshold then, and solve() uses the rank of the threshold now (a threshold set after
  // the constructor made solve() use a decomposition of another rank: results at the mercy of the
  // last bits, and the non-determinism of issue 20's regression part reg-pocket-a).
  Eigen::CompleteOrthogonalDecomposition<Eigen::MatrixXd> cod(a.rows(), a.cols());
  cod.setThreshold(kRankThreshold);
  cod.compute(a * d.asDiagonal());
  fit.beta = d.asDiagonal() * cod.solve(r);
  fit.residual = r - a * fit.beta;
  fit.rss = fit.residual.squaredNorm();
  fit.rank = static_cast<int>(cod.rank());
  if (!covariance) return fit;
  const double dof = std::max(1.0, static_cast<double>(r.size() - fit.rank));
  fit.cov = (fit.rss / dof) * InverseGram(a);
  return fit;
}

namespace {

int NonlinearIndex(const Effect& e) {
  for (int k = 0; k < e.parameter_count(); ++k) {
    if (!e.parameters()[k].linear) return k;
  }
  return -1;
}

}  // namespace

// Linear parameters set to 1: the columns of a separable model do not depend on them.
Eigen::MatrixXd LinearColumnsAt(const Problem& prob, const Term& term, double q) {
  const int nonlinear = NonlinearIndex(*term.effect);
  if (nonlinear < 0) return prob.Columns(term, {});
  const int p = term.effect->parameter_count();
  std::vector<double> theta(p, 1.0);
  theta[nonlinear] = q;
  const Eigen::MatrixXd j = prob.Columns(term, theta);
  Eigen::MatrixXd cols(prob.n(), p - 1);
  for (int k = 0, c = 0; k < p; ++k) {
    if (k != nonlinear) cols.col(c++) = j.col(k);
  }
  return cols;
}

double ProfileRss(const Problem& prob, const Term& term, const Eigen::MatrixXd& x, double tau) {
  return LeastSquares(Concat(x, LinearColumnsAt(prob, term, tau)), prob.r, false).rss;
}

// Linear terms: one least squares. A term with one nonlinear parameter (τ): the RSS profiled over a
// log grid of 33 values in [tau_lo, tau_hi], refined by golden section, then the standard errors from
// the full Jacobian (linearised in τ) at the optimum.
TermFit FitTerm(const Problem& prob, const Term& term, const Eigen::MatrixXd& x, double tau_lo, double tau_hi) {
  TermFit out;
  out.term = term;
  const Effect* e = term.effect;
  const auto& spec = e->parameters();
  const int p = static_cast<int>(spec.size());
  const int nonlinear = NonlinearIndex(*e);
  if (nonlinear < 0) {
    out.columns = prob.Columns(term, {});
    out.fit = LeastSquares(Concat(x, out.columns), prob.r);
    for (int k = 0; k < prob.Width(term); ++k) {
      out.theta.push_back(out.fit.beta[x.cols() + k]);
      out.std_errors.push_back(std::sqrt(std::max(0.0, out.fit.cov(x.cols() + k, x.cols() + k))));
    }
    return out;
  }
  auto linear_columns = [&](double q) { return LinearColumnsAt(prob, term, q); };
  auto rss_at = [&](double log_q) {
    return LeastSquares(Concat(x, linear_columns(std::exp(log_q))), prob.r, false).rss;
  };
  const double lo = std::log(tau_lo), hi = std::log(tau_hi);
  constexpr int kGrid = 33;
  int best = 0;
  std::vector<double> grid(kGrid), rss(kGrid);
  for (int g = 0; g < kGrid; ++g) grid[g] = lo + (hi - lo) * g / (kGrid - 1);
  ParallelFor(kGrid, 1, [&](long begin, long end) {
    for (long g = begin; g < end; ++g) rss[static_cast<std::size_t>(g)] = rss_at(grid[static_cast<std::size_t>(g)]);
  });
  for (int g = 0; g < kGrid; ++g) {
    if (rss[g] < rss[best]) best = g;
  }
  double a = grid[std::max(0, best - 1)], b = grid[std::min(kGrid - 1, best + 1)];
  GoldenSectionOptions golden;
  golden.tolerance = 1e-6;
  golden.max_iterations = 40;
  const GoldenSectionResult refined = GoldenSectionMinimise(rss_at, a, b, golden);
  double log_q = refined.Mid();
  // The grid's end points are candidates too (the golden section never reaches a bound exactly).
  if (rss[best] < rss_at(log_q)) log_q = grid[best];
  const double q = std::exp(log_q);
  const Fit lin_fit = LeastSquares(Concat(x, linear_columns(q)), prob.r, false);
  std::vector<double> theta(p);
  for (int k = 0, col = 0; k < p; ++k) theta[k] = k == nonlinear ? q : lin_fit.beta[x.cols() + col++];
  // Full linearised Jacobian at the optimum for the standard errors (and the columns later fits use).
  out.columns = prob.Columns(term, theta);
  const Eigen::MatrixXd af = Concat(x, out.columns);
  Fit full = LeastSquares(af, prob.r, false);
  full.residual = lin_fit.residual;  // the exact nonlinear residual
  full.rss = lin_fit.rss;
  const double s2 = full.rss / std::max(1.0, static_cast<double>(prob.n() - x.cols() - p));
  full.cov = s2 * InverseGram(af);
  out.fit = full;
  out.theta = theta;
  for (int k = 0; k < p; ++k) out.std_errors.push_back(std::sqrt(std::max(0.0, full.cov(x.cols() + k, x.cols() + k))));
  return out;
}

double MoranZ(const Eigen::VectorXd& residual, const Eigen::MatrixXd& design, const metrology::SpatialWeights& w) {
  const Eigen::Index points = w.n();
  Eigen::MatrixXd x(points, design.cols() + 1);
  x << Eigen::VectorXd::Ones(points), design.topRows(points);
  const auto m = metrology::ResidualMoranI(residual.head(points), x, w, metrology::IslandPolicy::kZero);
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

Result<metrology::SpatialWeights> PointWeights(const Problem& prob) {
  const std::vector<std::vector<int>> lists(prob.neighbours.begin(), prob.neighbours.begin() + prob.Points());
  return metrology::WeightsFromNeighbours(lists, metrology::WeightStyle::kRowStandardised);
}

Result<std::vector<std::vector<int>>> KnnLists(const Eigen::MatrixXd& points, int k, const std::vector<int>* part_of) {
  const int n = static_cast<int>(points.rows());
  if (part_of == nullptr) {
    FL_ASSIGN_OR_RETURN(const auto w, metrology::KnnWeights(points.transpose(), k, metrology::WeightStyle::kBinary));
    return w.Neighbours();
  }
  std::map<int, std::vector<int>> rows;
  for (int i = 0; i < n; ++i) rows[(*part_of)[static_cast<std::size_t>(i)]].push_back(i);
  std::vector<std::vector<int>> out(static_cast<std::size_t>(n));
  for (const auto& [part, idx] : rows) {
    Eigen::MatrixXd sub(idx.size(), points.cols());
    for (std::size_t t = 0; t < idx.size(); ++t) sub.row(static_cast<Eigen::Index>(t)) = points.row(idx[t]);
    FL_ASSIGN_OR_RETURN(const auto local, KnnLists(sub, std::min(k, static_cast<int>(idx.size()) - 1), nullptr));
    for (std::size_t t = 0; t < idx.size(); ++t) {
      for (int j : local[t]) out[static_cast<std::size_t>(idx[t])].push_back(idx[static_cast<std::size_t>(j)]);
    }
  }
  return out;
}

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

namespace {

// The rows `keep` of a problem, with k-NN lists rebuilt among them (per part).
Result<Problem> Subset(const Problem& prob, const std::vector<int>& keep, int knn) {
  Problem sub;
  const int m = static_cast<int>(keep.size());
  sub.r.resize(m);
  sub.weight.resize(m);
  sub.xy.resize(m, 2);
  sub.pos.resize(m, prob.pos.cols());
  for (int t = 0; t < m; ++t) {
    sub.r[t] = prob.r[keep[t]];
    sub.weight[t] = prob.weight[keep[t]];
    sub.xy.row(t) = prob.xy.row(keep[t]);
    sub.pos.row(t) = prob.pos.row(keep[t]);
    sub.part_of.push_back(prob.part_of[static_cast<std::size_t>(keep[t])]);
  }
  sub.part_names = prob.part_names;
  // `keep` lists the points kept, then every direct-measurement row.
  int points = 0;
  while (points < m && keep[points] < prob.Points()) ++points;
  if (points < m) sub.points = points;
  const std::vector<int> point_part(sub.part_of.begin(), sub.part_of.begin() + points);
  FL_ASSIGN_OR_RETURN(sub.neighbours, KnnLists(sub.pos.topRows(points), std::min(knn, points - 1), &point_part));
  sub.neighbours.resize(static_cast<std::size_t>(m));
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

// Points of significant local Moran HH/LL clusters of r (α = 0.01, analytical), grown by `rings` rings
// of neighbours: the region a localised pattern occupies.
std::vector<bool> AnomalyRegion(const Problem& prob, const metrology::SpatialWeights& w, int rings) {
  std::vector<bool> in(prob.n(), false);
  metrology::LocalMoranOptions lo;
  lo.permutations = 0;
  lo.alpha = 0.01;
  lo.islands = metrology::IslandPolicy::kZero;
  const auto lisa = metrology::LocalMoranI(prob.r.head(prob.Points()), w, lo);
  if (!lisa.ok()) return in;
  for (int i = 0; i < prob.Points(); ++i) {
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

}  // namespace

// Spatial block CV (metrology/spatial_cv.h): leave one x-y block of one part out (each part's bounding
// box cut into blocks × blocks), refit the design on the rest, predict it.
double BlockCvRms(const Problem& prob, const Eigen::MatrixXd& design, int blocks) {
  // Over the points; a direct-measurement row is in every training set (block −1) and never held out.
  const int n = prob.Points();
  if (design.cols() == 0) return std::sqrt(prob.r.head(n).cwiseQuotient(prob.weight.head(n)).squaredNorm() / n);
  std::vector<int> block(static_cast<std::size_t>(prob.n()), -1);
  for (int p = 0; p < prob.parts(); ++p) {
    std::vector<int> rows;
    for (int i = 0; i < n; ++i) {
      if (prob.part_of[static_cast<std::size_t>(i)] == p) rows.push_back(i);
    }
    if (rows.empty()) continue;  // a part whose every point lies in a region set aside (RunEngine)
    Eigen::VectorXd x(rows.size()), y(rows.size());
    for (std::size_t k = 0; k < rows.size(); ++k) {
      x[static_cast<Eigen::Index>(k)] = prob.xy(rows[k], 0);
      y[static_cast<Eigen::Index>(k)] = prob.xy(rows[k], 1);
    }
    const std::vector<int> own = metrology::GridBlocks(x, y, blocks);
    for (std::size_t k = 0; k < rows.size(); ++k)
      block[static_cast<std::size_t>(rows[k])] = p * blocks * blocks + own[k];
  }
  const metrology::HeldOutErrors held =
      metrology::SpatialBlockCv(block, prob.parts() * blocks * blocks, prob.r, [&](const std::vector<int>& train) {
        Eigen::MatrixXd a(train.size(), design.cols());
        Eigen::VectorXd y(train.size());
        for (std::size_t t = 0; t < train.size(); ++t) {
          a.row(static_cast<Eigen::Index>(t)) = design.row(train[t]);
          y[static_cast<Eigen::Index>(t)] = prob.r[train[t]];
        }
        Eigen::ColPivHouseholderQR<Eigen::MatrixXd> qr(a);
        qr.setThreshold(1e-10);
        const Eigen::VectorXd beta = qr.solve(y);
        return std::optional<metrology::HeldOutPredictor>([&design, beta](int i) { return design.row(i).dot(beta); });
      });
  if (held.squared.empty()) return held.rms;
  // The errors are of the weighted residual: back to micrometres before the RMS.
  double sse = 0;
  for (int i = 0; i < n; ++i) sse += held.squared[static_cast<std::size_t>(i)] / (prob.weight[i] * prob.weight[i]);
  return std::sqrt(sse / n);
}

// Names the causes (SelectCauses) and then guards against a pattern outside the catalogue: when the
// residual after the selected effects is still correlated, they may be fitting a sliver of that
// pattern. The pattern's region (AnomalyRegion of the baseline residual: its significant local Moran
// clusters, grown ring by ring — 2, 4, 8, 16 rings — while the rest still shows a correlated residual)
// is set aside and the selection repeated on the rest; what it finds there stands, fitted there, and
// the region is reported as the unexplained systematic residual. A real global effect is found either
// way; a bump is not pinned on one. When no region under half the part leaves an uncorrelated rest,
// the pattern is not localised and the first selection stands (still reported as leaving an
// unexplained systematic residual).
Result<Diagnosis> RunEngine(const Problem& prob, const Model& baseline, const DiagnoseOptions& options) {
  FL_RETURN_IF_ERROR(options.Validate());
  FL_ASSIGN_OR_RETURN(const Selection first_selection, SelectCauses(prob, baseline, options));
  const Diagnosis& first = first_selection.diagnosis;
  // (Feature data has no positions for rebuilding neighbours: its observations are coordinates.)
  if (!first.unexplained || (first.causes.empty() && first.alias_groups.empty()) || prob.pos.cols() == 0) {
    return first;
  }
  FL_ASSIGN_OR_RETURN(const metrology::SpatialWeights w, PointWeights(prob));
  std::vector<bool> region;
  int set_aside = 0;
  Selection second_selection;
  const Diagnosis& second = second_selection.diagnosis;
  bool isolated = false;
  for (int rings : {2, 4, 8, 16}) {
    region = AnomalyRegion(prob, w, rings);
    std::vector<int> keep;
    for (int i = 0; i < prob.Points(); ++i) {
      if (!region[i]) keep.push_back(i);
    }
    set_aside = prob.Points() - static_cast<int>(keep.size());
    if (set_aside == 0 || set_aside > prob.Points() / 2 || static_cast<int>(keep.size()) < 20) break;
    for (int i = prob.Points(); i < prob.n(); ++i) keep.push_back(i);
    FL_ASSIGN_OR_RETURN(const Problem outside, Subset(prob, keep, options.knn));
    FL_ASSIGN_OR_RETURN(second_selection, SelectCauses(outside, baseline, options));
    if (!second.unexplained) {
      isolated = true;
      break;
    }
  }
  if (!isolated) return first;
  // Apply what was found outside to every point: the extended model's effects beyond the baseline.
  Diagnosis out = first;
  out.causes = second.causes;
  out.alias_groups = second.alias_groups;
  out.implausible = second.implausible;
  out.screening = second.screening;
  out.confounded = second.confounded;
  out.extended = second.extended;
  Eigen::VectorXd predicted = Eigen::VectorXd::Zero(prob.n());
  Eigen::MatrixXd design(prob.n(), 0);
  for (std::size_t t = 0; t < second_selection.terms.size(); ++t) {
    const Term& term = second_selection.terms[t];
    const std::vector<double>& theta = second_selection.theta[t];
    const Eigen::MatrixXd j = prob.Columns(term, theta);
    const int p = term.effect->parameter_count();
    for (Eigen::Index k = 0; k < j.cols(); ++k) {
      if (term.effect->parameters()[k % p].linear) predicted += j.col(k) * theta[static_cast<std::size_t>(k)];
    }
    design = Concat(design, j);
  }
  const Eigen::VectorXd residual = prob.r - predicted;
  const Eigen::VectorXd residual_um = residual.cwiseQuotient(prob.weight);
  const int points = prob.Points();
  out.residual_after_um.assign(residual_um.data(), residual_um.data() + points);
  out.rms_after_um = std::sqrt(residual_um.head(points).squaredNorm() / points);
  out.z_after = MoranZ(residual, Eigen::MatrixXd(prob.n(), 0), w);
  out.heldout_rms_after_um = BlockCvRms(prob, design, options.cv_blocks);
  out.unexplained = true;
  out.unexplained_where = nlohmann::json::array();
  Eigen::Vector2d centroid = Eigen::Vector2d::Zero();
  double peak = 0, mean = 0;
  Eigen::Vector2d peak_xy = Eigen::Vector2d::Zero();
  for (int i = 0; i < points; ++i) {
    if (!region[i]) continue;
    centroid += prob.xy.row(i).transpose();
    mean += residual_um[i];
    if (std::abs(residual_um[i]) > std::abs(peak)) {
      peak = residual_um[i];
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
  for (const Cause& c : first.causes) {
    out.unexplained_where.back()["causes_named_before_setting_it_aside"].push_back(c.Label());
  }
  return out;
}

}  // namespace formloop::sim::detail
