#include "tuning/offset_solve.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <map>
#include <numeric>
#include <string>

#include <Eigen/Dense>

namespace formloop::tuning {
namespace {

constexpr double kEpsMm = 1e-9;  // judgement slack (spec §2)

bool InBand(double dev, double lo, double hi) { return lo - kEpsMm <= dev && dev <= hi + kEpsMm; }

Status FiniteVector(const Eigen::VectorXd& v, const std::vector<std::string>& ids, const std::string& field,
                    const std::string& what) {
  for (int i = 0; i < v.size(); ++i) {
    if (!std::isfinite(v(i))) {
      return Status::BadInput(Where{.field = field}, what + " " + ids[i] + ": value is not finite",
                              "give a finite number");
    }
  }
  return Status::Ok();
}

// Union-find over offsets for the groups K cannot tell apart.
int Root(std::vector<int>& parent, int i) {
  while (parent[i] != i) i = parent[i] = parent[parent[i]];
  return i;
}

}  // namespace

Status OffsetProblem::Validate() const {
  const int n = static_cast<int>(dimension_ids.size());
  const int k_count = static_cast<int>(offset_ids.size());
  if (k.rows() != n || k.cols() != k_count || deviation_mm.size() != n || tol_lower_mm.size() != n ||
      tol_upper_mm.size() != n || target_mm.size() != n || weight.size() != n || delta_min_mm.size() != k_count ||
      delta_max_mm.size() != k_count || offset_weight.size() != k_count || resolution_mm.size() != k_count) {
    return Status::Internal("offset problem: sizes disagree with " + std::to_string(n) + " dimensions and " +
                            std::to_string(k_count) + " offsets");
  }
  FL_RETURN_IF_ERROR(FiniteVector(deviation_mm, dimension_ids, "deviation_mm", "dimension"));
  FL_RETURN_IF_ERROR(FiniteVector(target_mm, dimension_ids, "target", "dimension"));
  for (int i = 0; i < n; ++i) {
    if (!(tol_lower_mm(i) < tol_upper_mm(i))) {
      return Status::BadInput(Where{.field = "tol_lower_mm"},
                              "dimension " + dimension_ids[i] + ": lower tolerance " + std::to_string(tol_lower_mm(i)) +
                                  " is not below upper " + std::to_string(tol_upper_mm(i)),
                              "give tolerances as signed deviations with tol_lower_mm < tol_upper_mm");
    }
    if (!(weight(i) > 0) || !std::isfinite(weight(i))) {
      return Status::BadInput(Where{.field = "weight"}, "dimension " + dimension_ids[i] + ": weight must be > 0",
                              "give a positive importance (default 1)");
    }
  }
  for (int j = 0; j < k_count; ++j) {
    if (!(delta_min_mm(j) <= 0 && delta_max_mm(j) >= 0) || !std::isfinite(delta_min_mm(j)) ||
        !std::isfinite(delta_max_mm(j))) {
      return Status::BadInput(Where{.field = "delta_min_mm/delta_max_mm"},
                              "offset " + offset_ids[j] + ": bounds [" + std::to_string(delta_min_mm(j)) + ", " +
                                  std::to_string(delta_max_mm(j)) + "] do not contain 0",
                              "give delta_min_mm <= 0 <= delta_max_mm (no change must always be allowed)");
    }
    if (!(resolution_mm(j) > 0) || !std::isfinite(resolution_mm(j))) {
      return Status::BadInput(Where{.field = "resolution_mm"}, "offset " + offset_ids[j] + ": resolution must be > 0",
                              "give the controller's offset resolution, e.g. 0.001");
    }
    if (!(offset_weight(j) > 0) || !std::isfinite(offset_weight(j))) {
      return Status::BadInput(Where{.field = "weight"}, "offset " + offset_ids[j] + ": weight must be > 0",
                              "leave it out for the default 1e-4");
    }
  }
  for (int j = 0; j < k.outerSize(); ++j) {
    for (Eigen::SparseMatrix<double>::InnerIterator it(k, j); it; ++it) {
      if (!std::isfinite(it.value())) {
        return Status::BadInput(
            Where{.field = "k_row"},
            "dimension " + dimension_ids[it.row()] + ", offset " + offset_ids[j] + ": coefficient is not finite",
            "give a finite K coefficient");
      }
    }
  }
  return Status::Ok();
}

Status OffsetSolveOptions::Validate() const {
  if (!(rho > 0)) return Status::BadInput(Where{.field = "rho"}, "must be > 0", "use the default 1000");
  if (!(band_shrink > 0 && band_shrink <= 1)) {
    return Status::BadInput(Where{.field = "band_shrink"}, "must be in (0, 1]", "1 aims anywhere inside the band");
  }
  if (!(reach_tolerance_um > 0)) {
    return Status::BadInput(Where{.field = "reach_tolerance_um"}, "must be > 0", "use the default 0.001");
  }
  if (exhaustive_rounding_max < 0 || exhaustive_rounding_max > 20) {
    return Status::BadInput(Where{.field = "exhaustive_rounding_max"}, "must be in 0..20", "use the default 10");
  }
  return lsq.Validate();
}

Result<PenaltyForm> BuildPenaltyForm(const OffsetProblem& p, const OffsetSolveOptions& options) {
  FL_RETURN_IF_ERROR(p.Validate());
  FL_RETURN_IF_ERROR(options.Validate());
  const int n = static_cast<int>(p.dimension_ids.size());
  const int k = static_cast<int>(p.offset_ids.size());
  PenaltyForm form;
  std::vector<int> column_of(k, -1);
  for (int j = 0; j < k; ++j) {
    const bool fixed = p.delta_min_mm(j) == p.delta_max_mm(j);
    bool zero = true;
    for (Eigen::SparseMatrix<double>::InnerIterator it(p.k, j); it; ++it) zero = zero && it.value() == 0;
    if (fixed || zero) continue;
    column_of[j] = static_cast<int>(form.kept.size());
    form.kept.push_back(j);
  }
  const int kk = static_cast<int>(form.kept.size());
  // e' = e + K_fixed·δ_fixed, in µm.
  Eigen::VectorXd e = p.deviation_mm;
  for (int j = 0; j < k; ++j) {
    if (p.delta_min_mm(j) != p.delta_max_mm(j)) continue;
    for (Eigen::SparseMatrix<double>::InnerIterator it(p.k, j); it; ++it) e(it.row()) += it.value() * p.delta_min_mm(j);
  }
  e *= 1e3;
  const double w_max = p.weight.maxCoeff();
  const int rows = 2 * n + kk, cols = kk + n;
  std::vector<Eigen::Triplet<double>> triplets;
  form.b = Eigen::VectorXd::Zero(rows);
  form.lb.resize(cols);
  form.ub.resize(cols);
  for (int j = 0; j < k; ++j) {
    if (column_of[j] < 0) continue;
    for (Eigen::SparseMatrix<double>::InnerIterator it(p.k, j); it; ++it) {
      if (it.value() == 0) continue;
      const double omega = std::sqrt(p.weight(it.row()) / w_max);
      triplets.emplace_back(it.row(), column_of[j], options.rho * omega * it.value());
    }
    const int c = column_of[j];
    triplets.emplace_back(n + c, c, std::sqrt(p.offset_weight(j)));
    form.lb(c) = -p.delta_max_mm(j) * 1e3;
    form.ub(c) = -p.delta_min_mm(j) * 1e3;
  }
  for (int i = 0; i < n; ++i) {
    const double wt = p.weight(i) / w_max;
    const double omega = std::sqrt(wt);
    triplets.emplace_back(i, kk + i, options.rho * omega);
    form.b(i) = options.rho * omega * e(i);
    triplets.emplace_back(n + kk + i, kk + i, omega);
    form.b(n + kk + i) = omega * p.target_mm(i) * 1e3;
    const double centre = 0.5 * (p.tol_upper_mm(i) + p.tol_lower_mm(i)) * 1e3;
    const double half = 0.5 * (p.tol_upper_mm(i) - p.tol_lower_mm(i)) * 1e3 * options.band_shrink;
    form.lb(kk + i) = centre - half;
    form.ub(kk + i) = centre + half;
  }
  form.a.resize(rows, cols);
  form.a.setFromTriplets(triplets.begin(), triplets.end());
  form.a.makeCompressed();
  return form;
}

bool OffsetSolution::reachable() const {
  return std::none_of(not_reachable.begin(), not_reachable.end(), [](bool b) { return b; });
}

Result<RoundedOffsets> RoundOffsets(const OffsetProblem& p, const Eigen::VectorXd& delta_mm,
                                    const OffsetSolveOptions& options) {
  FL_RETURN_IF_ERROR(p.Validate());
  FL_RETURN_IF_ERROR(options.Validate());
  const int n = static_cast<int>(p.dimension_ids.size());
  const int k = static_cast<int>(p.offset_ids.size());
  if (delta_mm.size() != k) return Status::Internal("RoundOffsets: delta has the wrong size");
  RoundedOffsets out;
  out.delta_mm = delta_mm;
  const Eigen::MatrixXd kd = Eigen::MatrixXd(p.k);
  std::vector<char> kept_mask(k, 0);
  for (int j = 0; j < k; ++j) kept_mask[j] = kd.col(j).cwiseAbs().maxCoeff() > 0 ? 1 : 0;
  const Eigen::VectorXd w_t = p.weight / p.weight.maxCoeff();
  auto objective = [&](const Eigen::VectorXd& dq) {
    double f = 0;
    for (int j = 0; j < k; ++j) {
      if (!kept_mask[j] || p.delta_min_mm(j) == p.delta_max_mm(j)) continue;
      const double cj = -dq(j) * 1e3;
      f += p.offset_weight(j) * cj * cj;
    }
    const Eigen::VectorXd t = (p.deviation_mm + kd * dq) * 1e3;
    for (int i = 0; i < n; ++i) f += w_t(i) * (t(i) - p.target_mm(i) * 1e3) * (t(i) - p.target_mm(i) * 1e3);
    return 0.5 * f;
  };
  auto inside = [&](int j, double v) { return v >= p.delta_min_mm(j) - 1e-12 && v <= p.delta_max_mm(j) + 1e-12; };
  out.delta_rounded_mm = out.delta_mm;
  out.rule.assign(k, "");
  std::vector<double> floor_v(k), ceil_v(k);
  for (int j = 0; j < k; ++j) {
    const double q = p.resolution_mm(j);
    if (p.delta_min_mm(j) == p.delta_max_mm(j)) {
      out.rule[j] = "fixed by the model (delta_min_mm = delta_max_mm)";
      floor_v[j] = ceil_v[j] = out.delta_mm(j);
      continue;
    }
    if (!kept_mask[j]) {
      out.delta_rounded_mm(j) = 0;
      out.rule[j] = "no COMPENSATE dimension depends on it: no change";
      floor_v[j] = ceil_v[j] = 0;
      continue;
    }
    const double ratio = out.delta_mm(j) / q;
    double v = q * std::round(ratio);
    std::string rule = "nearest multiple of the resolution (halves away from zero)";
    if (!inside(j, v)) {
      v = v > p.delta_max_mm(j) ? q * std::floor(p.delta_max_mm(j) / q + 1e-9)
                                : q * std::ceil(p.delta_min_mm(j) / q - 1e-9);
      rule = "largest multiple of the resolution inside [delta_min_mm, delta_max_mm]";
    }
    out.delta_rounded_mm(j) = v;
    out.rule[j] = rule;
    floor_v[j] = q * std::floor(ratio);
    ceil_v[j] = q * std::ceil(ratio);
  }
  const Eigen::VectorXd continuous_pred = p.deviation_mm + kd * out.delta_mm;
  std::vector<bool> ok_before(n);
  for (int i = 0; i < n; ++i) ok_before[i] = InBand(continuous_pred(i), p.tol_lower_mm(i), p.tol_upper_mm(i));
  auto feasible = [&](const Eigen::VectorXd& dq) {
    for (int j = 0; j < k; ++j) {
      if (!inside(j, dq(j))) return false;
    }
    const Eigen::VectorXd pred = p.deviation_mm + kd * dq;
    for (int i = 0; i < n; ++i) {
      if (ok_before[i] && !InBand(pred(i), p.tol_lower_mm(i), p.tol_upper_mm(i))) return false;
    }
    return true;
  };
  std::vector<std::string> broken;
  {
    const Eigen::VectorXd pred = p.deviation_mm + kd * out.delta_rounded_mm;
    for (int i = 0; i < n; ++i) {
      if (ok_before[i] && !InBand(pred(i), p.tol_lower_mm(i), p.tol_upper_mm(i))) broken.push_back(p.dimension_ids[i]);
    }
  }
  if (!broken.empty()) {
    std::vector<int> involved;
    std::vector<char> seen(k, 0);
    const Eigen::VectorXd pred = p.deviation_mm + kd * out.delta_rounded_mm;
    for (int i = 0; i < n; ++i) {
      if (!(ok_before[i] && !InBand(pred(i), p.tol_lower_mm(i), p.tol_upper_mm(i)))) continue;
      for (int j = 0; j < k; ++j) {
        if (kd(i, j) != 0 && kept_mask[j] && !seen[j] && floor_v[j] != ceil_v[j]) {
          seen[j] = 1;
          involved.push_back(j);
        }
      }
    }
    std::string broken_list;
    for (const auto& id : broken) broken_list += (broken_list.empty() ? "" : ", ") + id;
    Eigen::VectorXd best = out.delta_rounded_mm;
    double best_f = feasible(best) ? objective(best) : std::numeric_limits<double>::infinity();
    auto consider = [&](const Eigen::VectorXd& candidate) {
      if (!feasible(candidate)) return;
      const double f = objective(candidate);
      if (f < best_f) {
        best_f = f;
        best = candidate;
      }
    };
    const int m = static_cast<int>(involved.size());
    if (m <= options.exhaustive_rounding_max) {
      for (long mask = 0; mask < (1L << m); ++mask) {
        Eigen::VectorXd candidate = out.delta_rounded_mm;
        for (int b = 0; b < m; ++b)
          candidate(involved[b]) = (mask >> b) & 1 ? ceil_v[involved[b]] : floor_v[involved[b]];
        consider(candidate);
      }
    } else {
      for (int j : involved) {
        for (double v : {floor_v[j], ceil_v[j]}) {
          Eigen::VectorXd candidate = out.delta_rounded_mm;
          candidate(j) = v;
          consider(candidate);
        }
      }
    }
    if (std::isfinite(best_f)) {
      for (int j : involved) {
        if (best(j) == out.delta_rounded_mm(j)) continue;
        out.rule[j] = std::string(best(j) < out.delta_mm(j) ? "floor" : "ceiling") +
                      " of the continuous value instead of the nearest, to keep " + broken_list +
                      " within tolerance (smallest objective among the feasible floor/ceiling choices)";
      }
      out.delta_rounded_mm = best;
    } else {
      out.ng_after_rounding = broken;
    }
  }
  out.predicted_mm = p.deviation_mm + kd * out.delta_rounded_mm;
  out.predicted_ok.resize(n);
  for (int i = 0; i < n; ++i) out.predicted_ok[i] = InBand(out.predicted_mm(i), p.tol_lower_mm(i), p.tol_upper_mm(i));
  return out;
}

Result<OffsetSolution> SolveOffsets(const OffsetProblem& p, const OffsetSolveOptions& options) {
  FL_ASSIGN_OR_RETURN(const PenaltyForm form, BuildPenaltyForm(p, options));
  const int n = static_cast<int>(p.dimension_ids.size());
  const int k = static_cast<int>(p.offset_ids.size());
  const int kk = static_cast<int>(form.kept.size());
  OffsetSolution sol;
  sol.dimension_ids = p.dimension_ids;
  sol.offset_ids = p.offset_ids;
  sol.kept = form.kept;
  FL_ASSIGN_OR_RETURN(sol.solver, SolveBoundedLsq(form.a, form.b, form.lb, form.ub, options.lsq));
  sol.objective = sol.solver.cost;
  const Eigen::VectorXd& x = sol.solver.x;

  Eigen::VectorXd delta = Eigen::VectorXd::Zero(k);
  for (int j = 0; j < k; ++j) {
    if (p.delta_min_mm(j) == p.delta_max_mm(j)) {
      delta(j) = p.delta_min_mm(j);
      sol.fixed_offsets.push_back(p.offset_ids[j]);
    }
  }
  std::vector<char> kept_mask(k, 0);
  for (int c = 0; c < kk; ++c) {
    delta(form.kept[c]) = -x(c) * 1e-3;
    kept_mask[form.kept[c]] = 1;
  }
  for (int j = 0; j < k; ++j) {
    if (!kept_mask[j] && p.delta_min_mm(j) != p.delta_max_mm(j)) sol.zero_offsets.push_back(p.offset_ids[j]);
  }
  const Eigen::MatrixXd kd = Eigen::MatrixXd(p.k);
  sol.t_mm = x.tail(n) * 1e-3;
  sol.r_eq_mm = p.deviation_mm + kd * delta - sol.t_mm;
  sol.not_reachable.resize(n);
  for (int i = 0; i < n; ++i) sol.not_reachable[i] = std::abs(sol.r_eq_mm(i)) * 1e3 > options.reach_tolerance_um;

  // Rank of K over the solved offsets and the groups it cannot separate.
  if (kk > 0) {
    Eigen::MatrixXd kr(n, kk);
    for (int c = 0; c < kk; ++c) kr.col(c) = kd.col(form.kept[c]);
    Eigen::ColPivHouseholderQR<Eigen::MatrixXd> qr(kr);
    qr.setThreshold(1e-9);
    sol.k_rank = static_cast<int>(qr.rank());
    if (sol.k_rank < kk) {
      Eigen::FullPivLU<Eigen::MatrixXd> lu(kr);
      lu.setThreshold(1e-9);
      const Eigen::MatrixXd kernel = lu.kernel();
      std::vector<int> parent(kk);
      std::iota(parent.begin(), parent.end(), 0);
      std::vector<char> involved(kk, 0);
      for (int v = 0; v < kernel.cols(); ++v) {
        const double scale = kernel.col(v).cwiseAbs().maxCoeff();
        int first = -1;
        for (int c = 0; c < kk; ++c) {
          if (std::abs(kernel(c, v)) <= 1e-9 * scale) continue;
          involved[c] = 1;
          if (first < 0)
            first = c;
          else
            parent[Root(parent, c)] = Root(parent, first);
        }
      }
      std::map<int, std::vector<std::string>> groups;
      for (int c = 0; c < kk; ++c) {
        if (involved[c]) groups[Root(parent, c)].push_back(p.offset_ids[form.kept[c]]);
      }
      for (auto& [root, ids] : groups) sol.indistinguishable.push_back(ids);
    }
  }

  FL_ASSIGN_OR_RETURN(sol.rounded, RoundOffsets(p, delta, options));
  return sol;
}

nlohmann::json OffsetSolution::ToJson() const {
  nlohmann::json j;
  j["solver"] = solver.ToJson();
  j["objective"] = objective;
  j["k_rank"] = k_rank;
  j["indistinguishable_offsets"] = indistinguishable;
  j["fixed_offsets"] = fixed_offsets;
  j["offsets_without_dimensions"] = zero_offsets;
  std::vector<std::string> unreachable;
  for (std::size_t i = 0; i < not_reachable.size(); ++i) {
    if (not_reachable[i]) unreachable.push_back(dimension_ids[i]);
  }
  j["not_reachable"] = unreachable;
  j["ng_after_rounding"] = rounded.ng_after_rounding;
  // The active set by name (spec §4.3: each run reports it): offsets whose change sits on a bound and
  // dimensions that land on an edge of their (shrunk) band.
  std::vector<std::string> offsets_at_bound, dimensions_at_band_edge;
  for (std::size_t c = 0; c < kept.size(); ++c) {
    if (solver.active[c] != 0) offsets_at_bound.push_back(offset_ids[kept[c]]);
  }
  for (std::size_t i = 0; i < dimension_ids.size(); ++i) {
    if (solver.active[kept.size() + i] != 0) dimensions_at_band_edge.push_back(dimension_ids[i]);
  }
  j["offsets_at_bound"] = offsets_at_bound;
  j["dimensions_at_band_edge"] = dimensions_at_band_edge;
  return j;
}

}  // namespace formloop::tuning
