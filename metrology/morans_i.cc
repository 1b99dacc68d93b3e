#include "metrology/morans_i.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <numeric>
#include <vector>

#include <Eigen/Cholesky>
#include <Eigen/QR>

#include "core/random.h"

namespace formloop::metrology {
namespace {

using RowSparse = Eigen::SparseMatrix<double, Eigen::RowMajor>;

struct WeightSums {
  double s0 = 0, s1 = 0, s2 = 0;
};

// Rows with strictly ascending columns (every SpatialWeights builder writes them so).
bool RowsAscending(const RowSparse& w) {
  for (Eigen::Index i = 0; i < w.outerSize(); ++i) {
    const int* col = w.innerIndexPtr() + w.outerIndexPtr()[i];
    const int* end = w.innerIndexPtr() +
                     (w.isCompressed() ? w.outerIndexPtr()[i + 1] : w.outerIndexPtr()[i] + w.innerNonZeroPtr()[i]);
    for (; col + 1 < end; ++col) {
      if (col[0] >= col[1]) return false;
    }
  }
  return true;
}

// S0 = Σ w_ij; S1 = ½ Σ (w_ij + w_ji)² over the union of (i, j) and (j, i), i.e. Σ w_ij² + Σ w_ij w_ji;
// S2 = Σ (w_i. + w_.i)². Straight from the compressed rows, without forming wᵀ or w + wᵀ: w_ji of an
// entry (i, j), j > i, is found by bisecting row j (the pair then counts twice), column sums are
// scattered. One pass in row order: the same bits on any thread count.
WeightSums ComputeSums(const RowSparse& w_in) {
  if (!w_in.isCompressed() || !RowsAscending(w_in)) {
    // Any other layout (unsorted or repeated columns): the canonical form, duplicates summed.
    std::vector<Eigen::Triplet<double>> entries;
    entries.reserve(static_cast<std::size_t>(w_in.nonZeros()));
    for (Eigen::Index i = 0; i < w_in.outerSize(); ++i) {
      for (RowSparse::InnerIterator it(w_in, i); it; ++it) entries.emplace_back(it.row(), it.col(), it.value());
    }
    RowSparse canonical(w_in.rows(), w_in.cols());
    canonical.setFromTriplets(entries.begin(), entries.end());
    return ComputeSums(canonical);
  }
  const RowSparse& w = w_in;
  const int* outer = w.outerIndexPtr();
  const int* inner = w.innerIndexPtr();
  const double* value = w.valuePtr();
  const long n = w.rows();
  std::vector<double> col(static_cast<std::size_t>(w.cols()), 0.0), row(static_cast<std::size_t>(n), 0.0);
  double squares = 0, cross = 0;
  constexpr int kShortRow = 16;
  constexpr long kAhead = 8;  // rows: the scattered reads of a later row are requested now
  for (long i = 0; i < n; ++i) {
    if (i + kAhead < n) {
      for (int e = outer[i + kAhead]; e < outer[i + kAhead + 1]; ++e) {
        const int j = inner[e];
        __builtin_prefetch(col.data() + j, 1);
        if (j > i + kAhead) {
          __builtin_prefetch(inner + outer[j]);
          __builtin_prefetch(value + outer[j]);
        }
      }
    }
    double row_sum = 0;
    for (int e = outer[i]; e < outer[i + 1]; ++e) {
      const int j = inner[e];
      const double v = value[e];
      row_sum += v;
      col[static_cast<std::size_t>(j)] += v;
      squares += v * v;
      if (j == i) {
        cross += v * v;
      } else if (j > i && j < n) {
        // w_ji (0 when j does not list i): a branch-free scan of a short row, else bisection.
        double back = 0;
        if (outer[j + 1] - outer[j] <= kShortRow) {
          for (int f = outer[j]; f < outer[j + 1]; ++f) back = inner[f] == i ? value[f] : back;
        } else {
          const int* at = std::lower_bound(inner + outer[j], inner + outer[j + 1], static_cast<int>(i));
          if (at != inner + outer[j + 1] && *at == i) back = value[at - inner];
        }
        cross += 2.0 * v * back;
      }
    }
    row[static_cast<std::size_t>(i)] = row_sum;
  }
  WeightSums s;
  for (long i = 0; i < n; ++i) {
    s.s0 += row[static_cast<std::size_t>(i)];
    const double both = row[static_cast<std::size_t>(i)] + col[static_cast<std::size_t>(i)];
    s.s2 += both * both;
  }
  s.s1 = squares + cross;
  return s;
}

Status CheckSize(const SpatialWeights& weights, long n) {
  if (weights.w.rows() != n || weights.w.cols() != n) {
    return Status::Internal("Moran's I: weights are " + std::to_string(weights.w.rows()) + " × " +
                            std::to_string(weights.w.cols()) + " for " + std::to_string(n) + " values");
  }
  return Status::Ok();
}

Status CheckCount(long n) {
  if (n < 4) return Status::BadInput("Moran's I needs at least 4 values, got " + std::to_string(n));
  return Status::Ok();
}

// Rows of `m` listed in `rows`.
Eigen::MatrixXd SelectRows(const Eigen::MatrixXd& m, const std::vector<int>& rows) {
  Eigen::MatrixXd out(static_cast<long>(rows.size()), m.cols());
  for (std::size_t r = 0; r < rows.size(); ++r) out.row(static_cast<long>(r)) = m.row(rows[r]);
  return out;
}
Eigen::VectorXd SelectRows(const Eigen::VectorXd& v, const std::vector<int>& rows) {
  Eigen::VectorXd out(static_cast<long>(rows.size()));
  for (std::size_t r = 0; r < rows.size(); ++r) out[static_cast<long>(r)] = v[rows[r]];
  return out;
}

IslandReport Report(const IslandResolution& r) { return {r.policy, r.islands, r.dropped}; }

// In-place Fisher–Yates shuffle from core/random.h (the same sequence on every standard library).
void Shuffle(Eigen::VectorXd* v, Rng* rng) {
  for (long m = v->size() - 1; m > 0; --m) {
    const long j = static_cast<long>(rng->UniformIndex(static_cast<std::uint64_t>(m + 1)));
    std::swap((*v)[m], (*v)[j]);
  }
}

// A permuted statistic counts as "at least as large" when within rounding of the observed one: a
// permutation that reproduces the observed neighbourhood sums in another order must count.
bool AtLeast(double sim, double observed) { return sim >= observed - 1e-12 * std::abs(observed); }

// PySAL's folding of the permutation count to the smaller tail.
int FoldLarger(int larger, int permutations) { return permutations - larger < larger ? permutations - larger : larger; }

// A thin orthonormal basis Q (n × p, p = rank) of the design's column space and the least-squares
// coefficients.
struct ThinQr {
  Eigen::MatrixXd q;
  Eigen::VectorXd coefficients;
};

// CholeskyQR2 (Fukaya, Nakatsukasa, Yanagisawa & Yamamoto 2014) on the column-equilibrated design:
// two passes of G = XᵀX, G = RᵀR, Q = XR⁻¹. It needs only GEMM-like products (about twice as fast
// as a Householder QR plus forming Q for n = 100,000, p = 100) and gives Q orthonormal to rounding
// when cond(X) ≲ 10⁸. The second pass is accepted only when the first one's Q was already close to
// orthonormal (‖Q₁ᵀQ₁ − I‖_F ≤ 0.1, which bounds the final loss of orthogonality at O(p·ε));
// otherwise, or when the Cholesky factorisation fails (a (nearly) rank-deficient design), the
// rank-revealing column-pivoting Householder QR is used.
Result<ThinQr> OrthonormalBasis(const Eigen::MatrixXd& x, const Eigen::VectorXd& y) {
  const long n = x.rows(), p = x.cols();
  ThinQr out;
  if (p <= n) {
    const Eigen::VectorXd norms = x.colwise().norm().transpose();
    if (norms.minCoeff() > 0 && norms.allFinite()) {
      Eigen::MatrixXd q = x * norms.cwiseInverse().asDiagonal();
      Eigen::MatrixXd g = Eigen::MatrixXd::Zero(p, p);
      g.selfadjointView<Eigen::Lower>().rankUpdate(q.transpose());
      Eigen::LLT<Eigen::MatrixXd> first(g);
      if (first.info() == Eigen::Success) {
        Eigen::MatrixXd r1 = first.matrixU();
        r1.triangularView<Eigen::Upper>().solveInPlace<Eigen::OnTheRight>(q);
        g.setZero();
        g.selfadjointView<Eigen::Lower>().rankUpdate(q.transpose());
        g.triangularView<Eigen::StrictlyUpper>() = g.transpose();
        const bool near_orthonormal = (g - Eigen::MatrixXd::Identity(p, p)).norm() <= 0.1;
        Eigen::LLT<Eigen::MatrixXd> second(g);
        if (near_orthonormal && second.info() == Eigen::Success) {
          const Eigen::MatrixXd r2 = second.matrixU();
          r2.triangularView<Eigen::Upper>().solveInPlace<Eigen::OnTheRight>(q);
          // X D⁻¹ = Q R2 R1, so β = D⁻¹ (R2 R1)⁻¹ Qᵀ y.
          const Eigen::MatrixXd r = r2.triangularView<Eigen::Upper>() * r1;
          Eigen::VectorXd beta = q.transpose() * y;
          r.triangularView<Eigen::Upper>().solveInPlace(beta);
          out.coefficients = beta.cwiseQuotient(norms);
          out.q = std::move(q);
          return out;
        }
      }
    }
  }
  Eigen::ColPivHouseholderQR<Eigen::MatrixXd> pivoted(x);
  const long rank = pivoted.rank();
  if (rank < 1) return Status::BadInput("residual Moran's I: the design has no non-zero column");
  out.coefficients = pivoted.solve(y);
  out.q = pivoted.householderQ() * Eigen::MatrixXd::Identity(n, rank);
  return out;
}

// The common start of global and local Moran: sizes and permutation count checked, islands resolved by
// the policy, the kept values centred (z = y − ȳ, Σz²), constant values refused.
struct CentredValues {
  IslandResolution resolved;
  Eigen::VectorXd z;
  double sum_z2 = 0;
  // The kept weights and the number of kept values, as the statistics use them.
  const RowSparse& w() const { return unchanged ? *unchanged : resolved.weights.w; }
  const RowSparse* unchanged = nullptr;  // the caller's weights when there was no island to resolve (no copy)
  double n() const { return static_cast<double>(z.size()); }
};

Result<CentredValues> CentreValues(const Eigen::VectorXd& values, const SpatialWeights& weights, IslandPolicy islands,
                                   int permutations, const std::string& what) {
  FL_RETURN_IF_ERROR(CheckSize(weights, values.size()));
  if (permutations < 0) {
    return Status::BadInput(Where{.field = "permutations"}, "must be >= 0", "use e.g. 999, or 0 for none");
  }
  CentredValues out;
  if (weights.islands == 0) {
    out.resolved.policy = islands;
    out.resolved.kept.resize(static_cast<std::size_t>(weights.n()));
    std::iota(out.resolved.kept.begin(), out.resolved.kept.end(), 0);
    out.unchanged = &weights.w;
  } else {
    FL_ASSIGN_OR_RETURN(out.resolved, ResolveIslands(weights, islands));
  }
  const Eigen::VectorXd y = out.resolved.dropped.empty() ? values : SelectRows(values, out.resolved.kept);
  FL_RETURN_IF_ERROR(CheckCount(y.size()));
  out.z = y.array() - y.mean();
  out.sum_z2 = out.z.squaredNorm();
  if (!(out.sum_z2 > 0)) return Status::BadInput(what + ": all values are equal; spatial correlation is undefined");
  return out;
}

}  // namespace

double NormalUpperTail(double z) { return 0.5 * std::erfc(z / std::sqrt(2.0)); }

Result<MoranResult> MoranI(const Eigen::VectorXd& values, const SpatialWeights& weights, const MoranOptions& options) {
  FL_ASSIGN_OR_RETURN(const CentredValues centred,
                      CentreValues(values, weights, options.islands, options.permutations, "Moran's I"));
  const RowSparse& w = centred.w();
  const double n = centred.n(), m2 = centred.sum_z2;
  const Eigen::VectorXd& z = centred.z;
  const WeightSums s = ComputeSums(w);
  if (!(s.s0 > 0)) return Status::BadInput("Moran's I: the weights have no neighbour pairs (S0 = 0)");
  MoranResult r;
  r.n = static_cast<int>(z.size());
  r.s0 = s.s0;
  r.s1 = s.s1;
  r.s2 = s.s2;
  r.islands = Report(centred.resolved);
  const double scale = n / s.s0;
  r.i = scale * z.dot(w * z) / m2;
  r.expected = -1.0 / (n - 1.0);
  const double e2 = r.expected * r.expected;
  r.variance_normality = (n * n * s.s1 - n * s.s2 + 3.0 * s.s0 * s.s0) / ((n * n - 1.0) * s.s0 * s.s0) - e2;
  const double b2 = n * z.array().square().square().sum() / (m2 * m2);
  r.variance_randomisation = (n * ((n * n - 3.0 * n + 3.0) * s.s1 - n * s.s2 + 3.0 * s.s0 * s.s0) -
                              b2 * ((n * n - n) * s.s1 - 2.0 * n * s.s2 + 6.0 * s.s0 * s.s0)) /
                                 ((n - 1.0) * (n - 2.0) * (n - 3.0) * s.s0 * s.s0) -
                             e2;
  r.z_normality = (r.i - r.expected) / std::sqrt(r.variance_normality);
  r.z_randomisation = (r.i - r.expected) / std::sqrt(r.variance_randomisation);
  r.p_normality = NormalUpperTail(r.z_normality);
  r.p_randomisation = NormalUpperTail(r.z_randomisation);

  if (options.permutations > 0) {
    // Permute all n values (zero rows included, as PySAL); m2 is invariant under permutation.
    PermutationTest& t = r.permutation;
    t.permutations = options.permutations;
    t.seed = options.seed;
    Rng rng(options.seed);
    Eigen::VectorXd perm = z;
    double sum = 0, sum2 = 0;
    int larger = 0;
    for (int k = 0; k < options.permutations; ++k) {
      Shuffle(&perm, &rng);
      const double sim = scale * perm.dot(w * perm) / m2;
      if (AtLeast(sim, r.i)) ++larger;
      sum += sim;
      sum2 += sim * sim;
    }
    const double count = static_cast<double>(options.permutations);
    t.larger = FoldLarger(larger, options.permutations);
    t.p_sim = (t.larger + 1.0) / (count + 1.0);
    t.mean = sum / count;
    t.sd = std::sqrt(std::max(0.0, sum2 / count - t.mean * t.mean));
    t.z_sim = t.sd > 0 ? (r.i - t.mean) / t.sd : std::numeric_limits<double>::quiet_NaN();
    t.p_z_sim = t.sd > 0 ? NormalUpperTail(std::abs(t.z_sim)) : 1.0;
  }
  return r;
}

Result<ResidualMoranResult> ResidualMoranI(const Eigen::VectorXd& y_in, const Eigen::MatrixXd& design_in,
                                           const SpatialWeights& weights, IslandPolicy islands) {
  FL_RETURN_IF_ERROR(CheckSize(weights, y_in.size()));
  if (design_in.rows() != y_in.size()) return Status::Internal("ResidualMoranI: design rows differ from values");
  FL_ASSIGN_OR_RETURN(const IslandResolution resolved, ResolveIslands(weights, islands));
  const bool subset = !resolved.dropped.empty();
  const Eigen::VectorXd y = subset ? SelectRows(y_in, resolved.kept) : y_in;
  const Eigen::MatrixXd design = subset ? SelectRows(design_in, resolved.kept) : Eigen::MatrixXd();
  const Eigen::MatrixXd& x = subset ? design : design_in;
  const RowSparse& w = resolved.weights.w;
  const long n_long = y.size();
  FL_RETURN_IF_ERROR(CheckCount(n_long));
  if (x.cols() < 1) return Status::Internal("ResidualMoranI: the design has no columns");

  ResidualMoranResult r;
  r.n = static_cast<int>(n_long);
  r.islands = Report(resolved);
  FL_ASSIGN_OR_RETURN(const ThinQr thin, OrthonormalBasis(x, y));
  const Eigen::MatrixXd& q = thin.q;
  r.p = static_cast<int>(q.cols());
  r.coefficients = thin.coefficients;
  const int p = r.p;
  if (n_long - p < 3) {
    return Status::BadInput("residual Moran's I: " + std::to_string(n_long) + " values cannot support " +
                            std::to_string(p) + " regressors. Fix: use a simpler model or more points");
  }
  // e = (I − QQᵀ) y: the residual of the projection, independent of how β was solved.
  r.residuals = y - q * (q.transpose() * y);

  // WQ and WᵀQ in column blocks, so at most one n × 32 block of each exists beside Q.
  const RowSparse wt = w.transpose();
  Eigen::MatrixXd b(p, p);  // QᵀWQ
  double wq_norm2 = 0, wtq_norm2 = 0, cross = 0;
  constexpr int kBlock = 32;
  for (int c0 = 0; c0 < p; c0 += kBlock) {
    const int width = std::min(kBlock, p - c0);
    const Eigen::MatrixXd wq = w * q.middleCols(c0, width);
    const Eigen::MatrixXd wtq = wt * q.middleCols(c0, width);
    b.middleCols(c0, width).noalias() = q.transpose() * wq;
    wq_norm2 += wq.squaredNorm();
    wtq_norm2 += wtq.squaredNorm();
    cross += wtq.cwiseProduct(wq).sum();
  }
  const double n = static_cast<double>(n_long);
  const double s0 = w.sum();
  if (!(s0 > 0)) return Status::BadInput("residual Moran's I: the weights have no neighbour pairs (S0 = 0)");
  const double tr_w = w.diagonal().sum();
  const double tr_mw = tr_w - b.trace();
  const double tr_wwt = w.squaredNorm();
  const double tr_ww = w.cwiseProduct(wt).sum();  // Σ_ij w_ij w_ji
  const double tr_mwmwt = tr_wwt - wq_norm2 - wtq_norm2 + b.squaredNorm();
  const double tr_mwmw = tr_ww - 2.0 * cross + b.cwiseProduct(b.transpose()).sum();  // tr(B²) = Σ b_ij b_ji
  const double ete = r.residuals.squaredNorm();
  if (!(ete > 0)) return Status::BadInput("residual Moran's I: the model fits the values exactly; no residual left");
  const double scale = n / s0;
  r.i = scale * r.residuals.dot(w * r.residuals) / ete;
  const double dof = n - p;
  r.expected = scale * tr_mw / dof;
  r.variance = scale * scale * (tr_mwmwt + tr_mwmw + tr_mw * tr_mw) / (dof * (dof + 2.0)) - r.expected * r.expected;
  r.z = (r.i - r.expected) / std::sqrt(r.variance);
  r.p_value = NormalUpperTail(r.z);
  return r;
}

const char* LisaClusterName(LisaCluster cluster) {
  switch (cluster) {
    case LisaCluster::kNotSignificant:
      return "not significant";
    case LisaCluster::kHighHigh:
      return "HH";
    case LisaCluster::kLowHigh:
      return "LH";
    case LisaCluster::kLowLow:
      return "LL";
    case LisaCluster::kHighLow:
      return "HL";
    case LisaCluster::kIsland:
      return "island";
  }
  return "?";
}

Result<LocalMoranResult> LocalMoranI(const Eigen::VectorXd& values, const SpatialWeights& weights,
                                     const LocalMoranOptions& options) {
  if (!(options.alpha > 0 && options.alpha < 1)) {
    return Status::BadInput(Where{.field = "alpha"}, "the significance level must be in (0, 1)", "use e.g. 0.05");
  }
  FL_ASSIGN_OR_RETURN(const CentredValues centred,
                      CentreValues(values, weights, options.islands, options.permutations, "local Moran"));
  const IslandResolution& resolved = centred.resolved;
  const RowSparse& w = centred.w();
  const double n = centred.n(), sum_z2 = centred.sum_z2, c = (n - 1.0) / sum_z2;
  const Eigen::VectorXd& z = centred.z;
  const long n_long = z.size();

  const long rows = values.size();
  const double nan = std::numeric_limits<double>::quiet_NaN();
  LocalMoranResult r;
  r.n = static_cast<int>(n_long);
  r.permutations = options.permutations;
  r.seed = options.seed;
  r.alpha = options.alpha;
  r.islands = Report(resolved);
  r.i = r.lag = r.expected = r.variance = r.z = r.p_sim = Eigen::VectorXd::Constant(rows, nan);
  r.p_analytical = Eigen::VectorXd::Ones(rows);
  r.quadrant.assign(static_cast<std::size_t>(rows), 0);
  r.cluster.assign(static_cast<std::size_t>(rows), LisaCluster::kIsland);

  const Eigen::VectorXd lag = w * z;
  Rng rng(options.seed);
  // Pool of indices for the conditional draws; `where` tracks each index's position in it.
  std::vector<int> pool(static_cast<std::size_t>(n_long)), where(static_cast<std::size_t>(n_long));
  std::iota(pool.begin(), pool.end(), 0);
  std::iota(where.begin(), where.end(), 0);
  auto swap_pool = [&](long a, long b) {
    std::swap(pool[static_cast<std::size_t>(a)], pool[static_cast<std::size_t>(b)]);
    where[static_cast<std::size_t>(pool[static_cast<std::size_t>(a)])] = static_cast<int>(a);
    where[static_cast<std::size_t>(pool[static_cast<std::size_t>(b)])] = static_cast<int>(b);
  };
  std::vector<double> row_weights;
  for (long k = 0; k < n_long; ++k) {
    const long out = resolved.kept[static_cast<std::size_t>(k)];
    row_weights.clear();
    for (RowSparse::InnerIterator it(w, k); it; ++it) {
      if (it.value() != 0) row_weights.push_back(it.value());
    }
    if (row_weights.empty()) continue;  // a zero row (kZero): island
    const double zi = z[k];
    const double ii = c * zi * lag[k];
    r.i[out] = ii;
    r.lag[out] = lag[k];
    // Conditional-randomisation moments (Sokal et al. 1998, A7–A8).
    double wi = 0, wi2 = 0;
    for (double v : row_weights) {
      wi += v;
      wi2 += v * v;
    }
    const double mean_others = -zi / (n - 1.0);
    const double var_others = (sum_z2 - zi * zi) / (n - 1.0) - mean_others * mean_others;
    r.expected[out] = c * zi * wi * mean_others;
    r.variance[out] = c * c * zi * zi * var_others * (n - 1.0) / (n - 2.0) * (wi2 - wi * wi / (n - 1.0));
    r.z[out] = r.variance[out] > 0 ? (ii - r.expected[out]) / std::sqrt(r.variance[out]) : nan;
    r.p_analytical[out] = r.variance[out] > 0 ? NormalUpperTail(std::abs(r.z[out])) : 1.0;
    // Quadrant as esda: z > 0 is high, lag > 0 is high (zero counts as low).
    const bool high = zi > 0, high_lag = lag[k] > 0;
    const int q = high ? (high_lag ? 1 : 4) : (high_lag ? 2 : 3);
    r.quadrant[static_cast<std::size_t>(out)] = q;

    if (options.permutations > 0) {
      // Draw |N(i)| distinct others uniformly (partial Fisher–Yates over the pool without i).
      const long kn = static_cast<long>(row_weights.size());
      if (kn > n_long - 1) return Status::Internal("local Moran: a row has more neighbours than values");
      swap_pool(where[static_cast<std::size_t>(k)], n_long - 1);
      int larger = 0;
      for (int perm = 0; perm < options.permutations; ++perm) {
        double sim_lag = 0;
        for (long m = 0; m < kn; ++m) {
          const long pick = m + static_cast<long>(rng.UniformIndex(static_cast<std::uint64_t>(n_long - 1 - m)));
          swap_pool(m, pick);
          sim_lag += row_weights[static_cast<std::size_t>(m)] * z[pool[static_cast<std::size_t>(m)]];
        }
        if (AtLeast(c * zi * sim_lag, ii)) ++larger;
      }
      const int folded = FoldLarger(larger, options.permutations);
      // z_i = 0 (or a row whose draws cannot vary) makes every permuted I_i equal I_i: no evidence
      // either way, p = 1. (esda's folding would report 1/(N + 1) there.)
      r.p_sim[out] = r.variance[out] > 0 ? (folded + 1.0) / (options.permutations + 1.0) : 1.0;
    }
    const double p = options.permutations > 0 ? r.p_sim[out] : r.p_analytical[out];
    r.cluster[static_cast<std::size_t>(out)] =
        p < options.alpha ? static_cast<LisaCluster>(q) : LisaCluster::kNotSignificant;
  }
  return r;
}

nlohmann::json IslandReport::ToJson() const {
  return {{"policy", IslandPolicyName(policy)}, {"islands", islands}, {"dropped_rows", dropped}};
}

nlohmann::json PermutationTest::ToJson() const {
  return {{"permutations", permutations},
          {"seed", seed},
          {"larger", larger},
          {"p_sim", p_sim},
          {"mean", mean},
          {"sd", sd},
          {"z_sim", z_sim},
          {"p_z_sim", p_z_sim}};
}

nlohmann::json MoranResult::ToJson() const {
  nlohmann::json j = {{"n", n},
                      {"I", i},
                      {"expected", expected},
                      {"variance_normality", variance_normality},
                      {"variance_randomisation", variance_randomisation},
                      {"z_normality", z_normality},
                      {"z_randomisation", z_randomisation},
                      {"p_normality", p_normality},
                      {"p_randomisation", p_randomisation},
                      {"S0", s0},
                      {"S1", s1},
                      {"S2", s2},
                      {"islands", islands.ToJson()},
                      {"systematic", z_normality > kMoranZCritical}};
  if (permutation.permutations > 0) j["permutation"] = permutation.ToJson();
  return j;
}

nlohmann::json ResidualMoranResult::ToJson() const {
  return {{"n", n},
          {"p", p},
          {"I", i},
          {"expected", expected},
          {"variance", variance},
          {"z", z},
          {"p_value", p_value},
          {"islands", islands.ToJson()}};
}

Result<Eigen::VectorXd> SpatialLag(const Eigen::VectorXd& values, const SpatialWeights& weights) {
  FL_ASSIGN_OR_RETURN(const CentredValues centred,
                      CentreValues(values, weights, IslandPolicy::kRefuse, 0, "spatial lag"));
  return Eigen::VectorXd(centred.w() * centred.z);
}

nlohmann::json LocalMoranResult::SummaryJson() const {
  nlohmann::json counts = nlohmann::json::object();
  for (LisaCluster c : {LisaCluster::kHighHigh, LisaCluster::kLowLow, LisaCluster::kHighLow, LisaCluster::kLowHigh,
                        LisaCluster::kNotSignificant, LisaCluster::kIsland}) {
    counts[LisaClusterName(c)] = std::count(cluster.begin(), cluster.end(), c);
  }
  return {{"n", n},
          {"permutations", permutations},
          {"seed", seed},
          {"alpha", alpha},
          {"p_value", permutations > 0 ? "conditional permutation (p_sim)" : "analytical (conditional randomisation)"},
          {"clusters", counts},
          {"islands", islands.ToJson()}};
}

}  // namespace formloop::metrology
