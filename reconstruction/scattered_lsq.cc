// The penalised least-squares system of a scattered fit (scattered_lsq.h): the normal matrix's band pattern,
// the thin-plate energy from exact Gram matrices, TensorLsq, and the selected inversion behind the GCV trace.

#include "reconstruction/scattered_lsq.h"

#include <Eigen/Dense>
#include <algorithm>
#include <cmath>
#include <cstdint>

#include "core/random.h"

namespace formloop::recon::scattered_internal {

namespace {

using Eigen::Vector3d;

// Total degree of the polynomial trend whose deviation the thin-plate energy measures (at most the
// spline degree), see TensorLsq::Solve. Cubic: measured with 5 µm noise on franke (10,000
// points), the worst error in the outer 5 % band (inside the samples' hull) over the interior
// worst fell from 2.0 (quadratic trend) to 1.33.
constexpr int kTrendDegree = 3;
// Local penalty weights (TensorLsq::LocalWeights). The noise of the fit and of the bias estimate
// is measured by smoothing kNoiseProbes fixed random ±1 vectors (the same for every fit, so the
// result is deterministic); with 16 the noisy test's band ratios moved by at most 0.03.
constexpr int kNoiseProbes = 32;
constexpr std::uint64_t kNoiseProbeSeed = 0x70b1a5;
// Bias and variance are pooled over windows of (2k + 1)² knot spans, k = kWeightWindowSpans: a
// corner's bias reaches a few spans in, and with k = 1 the estimates are noisier (measured with
// 5 µm noise, sphere_cap: band max 8.5 µm, ratio 1.94, against 7.9 µm and 1.83 with k = 2).
constexpr int kWeightWindowSpans = 2;
// The share of the bias that the twicing correction recovers (its expectation is H b, the smoothed
// bias b). Measured without noise at the noisy fits' λ, at the worst point of the outer 5 % band:
// one twicing step removed 29 % (cylinder), 46 % (blade), 50 % (sphere_cap) and 61 %
// (ellipsoid_cap) of the error. With 5 µm noise, 0.35 and 0.7 also kept all nine reference surfaces'
// band ratios ≤ 2 (ScatteredFitNoise); 1.0 (δ taken as the bias) left sphere_cap, ellipsoid_cap and
// blade at 2.03, 2.14 and 2.06.
constexpr double kBiasRecovered = 0.5;
// Floor of the local weights: the energy still fixes poles without data (a corner hole).
constexpr double kMinPenaltyWeight = 0.01;

// ---------------------------------------------------------------------------------------------
// Sparse pattern of the tensor-product normal matrix: pole k = a + n_u b couples with the poles
// (a', b') with |a − a'| ≤ p and |b − b'| ≤ p (their supports overlap). Full symmetric pattern,
// rows sorted within each column, explicit zeros kept so N, R and N + λR share one pattern.

SparseMatrix BandPattern(int nu, int nv, int p) {
  const int n = nu * nv;
  SparseMatrix pattern(n, n);
  Eigen::VectorXi per_column(n);
  for (int col = 0; col < n; ++col) {
    const int a = col % nu, b = col / nu;
    per_column(col) =
        (std::min(nu - 1, a + p) - std::max(0, a - p) + 1) * (std::min(nv - 1, b + p) - std::max(0, b - p) + 1);
  }
  pattern.reserve(per_column);
  for (int col = 0; col < n; ++col) {
    const int a0 = col % nu, b0 = col / nu;
    for (int b = std::max(0, b0 - p); b <= std::min(nv - 1, b0 + p); ++b) {
      for (int a = std::max(0, a0 - p); a <= std::min(nu - 1, a0 + p); ++a) pattern.insert(a + nu * b, col) = 0.0;
    }
  }
  pattern.makeCompressed();
  return pattern;
}

// R(k, k') from the 1-D Gram matrices over `region`, written into the values of the band pattern r.
void FillThinPlate(const KnotVector& ku, const KnotVector& kv, const ParamDomain& region, SparseMatrix* r) {
  const int nu = ku.n_poles();
  const double u0 = region.u_min, u1 = region.u_max, v0 = region.v_min, v1 = region.v_max;
  const Eigen::MatrixXd g0u = GramMatrix(ku, 0, u0, u1), g1u = GramMatrix(ku, 1, u0, u1),
                        g2u = GramMatrix(ku, 2, u0, u1);
  const Eigen::MatrixXd g0v = GramMatrix(kv, 0, v0, v1), g1v = GramMatrix(kv, 1, v0, v1),
                        g2v = GramMatrix(kv, 2, v0, v1);
  for (int col = 0; col < r->outerSize(); ++col) {
    const int a1 = col % nu, b1 = col / nu;
    for (SparseMatrix::InnerIterator it(*r, col); it; ++it) {
      const int a = static_cast<int>(it.row()) % nu, b = static_cast<int>(it.row()) / nu;
      it.valueRef() = g2u(a, a1) * g0v(b, b1) + 2 * g1u(a, a1) * g1v(b, b1) + g0u(a, a1) * g2v(b, b1);
    }
  }
}

// Gram matrices of the 0th, 1st and 2nd derivatives over each knot span s (degree ≤ s < n_poles)
// alone, (p + 1) × (p + 1) over the basis functions N_{s−p} .. N_s non-zero there; summed over the
// spans they give GramMatrix. Exact as GramMatrix (p + 1 Gauss–Legendre points).
std::vector<std::array<Eigen::MatrixXd, 3>> SpanGrams(const KnotVector& k) {
  const int n = k.n_poles(), p = k.degree();
  std::vector<double> nodes, weights;
  GaussLegendre(p + 1, &nodes, &weights);
  std::vector<std::array<Eigen::MatrixXd, 3>> out;
  Eigen::MatrixXd ders;
  for (int s = p; s < n; ++s) {
    std::array<Eigen::MatrixXd, 3> g;
    for (Eigen::MatrixXd& gd : g) gd = Eigen::MatrixXd::Zero(p + 1, p + 1);
    const double a = k.knots()[static_cast<std::size_t>(s)], b = k.knots()[static_cast<std::size_t>(s) + 1];
    const double half = 0.5 * (b - a);
    for (std::size_t q = 0; b > a && q < nodes.size(); ++q) {
      k.BasisDerivatives(s, a + half * (nodes[q] + 1), 2, &ders);
      for (int d = 0; d < 3; ++d) {
        const Eigen::RowVectorXd row = ders.row(d);
        g[static_cast<std::size_t>(d)].noalias() += (weights[q] * half) * row.transpose() * row;
      }
    }
    out.push_back(std::move(g));
  }
  return out;
}

// block += b bᵀ on and above the diagonal (n × n, row-major); kN > 0 fixes n at compile time (the
// bicubic case, n = 16, fully unrolled), 0 takes it at run time.
template <int kN>
inline void AddOuterUpper(int n_runtime, const double* b, double* block) {
  const int n = kN > 0 ? kN : n_runtime;
  for (int t1 = 0; t1 < n; ++t1) {
    const double b1 = b[t1];
    double* row = block + t1 * n;
    for (int t2 = t1; t2 < n; ++t2) row[t2] += b1 * b[t2];
  }
}

}  // namespace

// ---------------------------------------------------------------------------------------------
// The penalised least-squares problem for fixed knots and parameters.

TensorLsq::TensorLsq(KnotVector ku, KnotVector kv, const ParamDomain& region) : ku_(std::move(ku)), kv_(std::move(kv)) {
  p_ = ku_.degree();
  nu_ = ku_.n_poles();
  nv_ = kv_.n_poles();
  normal_ = BandPattern(nu_, nv_, p_);
  thin_plate_ = normal_;
  FillThinPlate(ku_, kv_, region, &thin_plate_);
  system_ = normal_;
  // The trend's monomials s^a t^b (a + b ≤ K) in scaled parameters s = (u − cu)/Lu,
  // t = (v − cv)/Lv, as B-spline coefficients (one column each) and their image under R.
  cu_ = 0.5 * (ku_.lo() + ku_.hi());
  lu_ = 0.5 * (ku_.hi() - ku_.lo());
  cv_ = 0.5 * (kv_.lo() + kv_.hi());
  lv_ = 0.5 * (kv_.hi() - kv_.lo());
  const int degree = std::min(p_, kTrendDegree);
  for (int total = 0; total <= degree; ++total) {
    for (int b = 0; b <= total; ++b) monomials_.emplace_back(total - b, b);
  }
  const Eigen::MatrixXd mu = MonomialCoefficients(ku_, cu_, lu_, degree);
  const Eigen::MatrixXd mv = MonomialCoefficients(kv_, cv_, lv_, degree);
  trend_basis_.resize(n(), static_cast<Eigen::Index>(monomials_.size()));
  for (int b = 0; b < nv_; ++b) {
    for (int a = 0; a < nu_; ++a) {
      for (std::size_t k = 0; k < monomials_.size(); ++k) {
        trend_basis_(a + nu_ * b, static_cast<Eigen::Index>(k)) =
            mu(a, monomials_[k].first) * mv(b, monomials_[k].second);
      }
    }
  }
  thin_plate_trend_ = thin_plate_ * trend_basis_;
  uniform_thin_plate_ = thin_plate_;
  span_grams_u_ = SpanGrams(ku_);
  span_grams_v_ = SpanGrams(kv_);
}

Eigen::MatrixXd TensorLsq::MonomialCoefficients(const KnotVector& k, double c, double l, int degree) {
  const int p = k.degree(), n = k.n_poles();
  Eigen::MatrixXd out(n, degree + 1);
  std::vector<double> e(static_cast<std::size_t>(degree + 1));
  for (int i = 0; i < n; ++i) {
    std::fill(e.begin(), e.end(), 0.0);
    e[0] = 1;
    for (int j = 1; j <= p; ++j) {
      const double tau = (k.knots()[static_cast<std::size_t>(i + j)] - c) / l;
      for (int d = degree; d >= 1; --d) e[static_cast<std::size_t>(d)] += tau * e[static_cast<std::size_t>(d - 1)];
    }
    double binomial = 1;  // C(p, d)
    for (int d = 0; d <= degree; ++d) {
      out(i, d) = e[static_cast<std::size_t>(d)] / binomial;
      binomial = binomial * (p - d) / (d + 1);
    }
  }
  return out;
}

void TensorLsq::Assemble(const std::vector<double>& u, const std::vector<double>& v, const std::vector<Vector3d>& x,
                         bool with_trend) {
  const int m = static_cast<int>(x.size()), q = p_ + 1, w = 2 * p_ + 1, qq = q * q;
  const int cells_u = nu_ - p_, cells = (nu_ - p_) * (nv_ - p_);
  span_u_.resize(static_cast<std::size_t>(m));
  span_v_.resize(static_cast<std::size_t>(m));
  basis_u_.resize(static_cast<std::size_t>(m) * q);
  basis_v_.resize(static_cast<std::size_t>(m) * q);
  x_ = &x;
  reference_poles_.resize(0, 3);  // the RSS reference of the λ search belongs to the old system
  std::vector<int> start(static_cast<std::size_t>(cells) + 1, 0), order(static_cast<std::size_t>(m));
  for (int i = 0; i < m; ++i) {
    const std::size_t si = static_cast<std::size_t>(i);
    const int su = ku_.FindSpan(u[si]), sv = kv_.FindSpan(v[si]);
    span_u_[si] = su;
    span_v_[si] = sv;
    ku_.BasisFunctions(su, u[si], &basis_u_[si * q]);
    kv_.BasisFunctions(sv, v[si], &basis_v_[si * q]);
    ++start[static_cast<std::size_t>((su - p_) + cells_u * (sv - p_)) + 1];
  }
  for (int c = 0; c < cells; ++c) start[static_cast<std::size_t>(c) + 1] += start[static_cast<std::size_t>(c)];
  // Each point's basis values, coordinates and scaled parameters copied into cell order (reading them
  // in input order and writing out of order: the reads that feed the sums stay sequential).
  const int stride = 2 * q + 5;
  std::vector<double>& record = record_;
  record.resize(static_cast<std::size_t>(m) * stride);
  {
    std::vector<int> fill(start.begin(), start.end() - 1);
    for (int i = 0; i < m; ++i) {
      const std::size_t si = static_cast<std::size_t>(i);
      const int slot = fill[static_cast<std::size_t>((span_u_[si] - p_) + cells_u * (span_v_[si] - p_))]++;
      order[static_cast<std::size_t>(slot)] = i;
      double* r = &record[static_cast<std::size_t>(slot) * stride];
      for (int j = 0; j < q; ++j) {
        r[j] = basis_u_[si * q + j];
        r[q + j] = basis_v_[si * q + j];
      }
      r[2 * q] = x[si].x();
      r[2 * q + 1] = x[si].y();
      r[2 * q + 2] = x[si].z();
      r[2 * q + 3] = (u[si] - cu_) / lu_;
      r[2 * q + 4] = (v[si] - cv_) / lv_;
    }
  }
  const int nt = with_trend ? static_cast<int>(monomials_.size()) : 0;
  // Dense band accumulator: band[k * w² + (db + p) w + (da + p)] = N(k, k + da + n_u db).
  std::vector<double> band(static_cast<std::size_t>(n()) * w * w, 0.0);
  rhs_ = Eigen::MatrixXd::Zero(n(), 3);
  phi_a_ = Eigen::MatrixXd::Zero(nt, n());
  phi_.resize(m, nt);
  Eigen::MatrixXd gram = Eigen::MatrixXd::Zero(nt, nt);
  Eigen::MatrixXd phi_x = Eigen::MatrixXd::Zero(nt, 3);
  // Per cell: block = Σ b bᵀ (upper triangle), block_x = Σ b xᵀ, block_phi = Σ φ bᵀ (b: the (p + 1)² products
  // N_a M_b, t = jb (p + 1) + ja; φ: the trend's monomials).
  std::vector<double> block(static_cast<std::size_t>(qq) * qq), block_x(static_cast<std::size_t>(qq) * 3),
      block_phi(static_cast<std::size_t>(nt) * qq), b(static_cast<std::size_t>(qq)), phi(static_cast<std::size_t>(nt));
  std::vector<double> gram_acc(static_cast<std::size_t>(nt) * nt, 0.0),
      phi_x_acc(static_cast<std::size_t>(nt) * 3, 0.0);
  const int degree = std::min(p_, kTrendDegree);
  for (int c = 0; c < cells; ++c) {
    const int begin = start[static_cast<std::size_t>(c)], end = start[static_cast<std::size_t>(c) + 1];
    if (begin == end) continue;
    std::fill(block.begin(), block.end(), 0.0);
    std::fill(block_x.begin(), block_x.end(), 0.0);
    std::fill(block_phi.begin(), block_phi.end(), 0.0);
    for (int o = begin; o < end; ++o) {
      const int i = order[static_cast<std::size_t>(o)];
      const double* r = &record[static_cast<std::size_t>(o) * stride];
      const double* bu = r;
      const double* bv = r + q;
      for (int jb = 0; jb < q; ++jb) {
        for (int ja = 0; ja < q; ++ja) b[static_cast<std::size_t>(jb * q + ja)] = bu[ja] * bv[jb];
      }
      if (q == 4) {
        AddOuterUpper<16>(qq, b.data(), block.data());
      } else {
        AddOuterUpper<0>(qq, b.data(), block.data());
      }
      const double* xi = r + 2 * q;
      for (int t = 0; t < qq; ++t) {
        const double bt = b[static_cast<std::size_t>(t)];
        block_x[static_cast<std::size_t>(t) * 3] += bt * xi[0];
        block_x[static_cast<std::size_t>(t) * 3 + 1] += bt * xi[1];
        block_x[static_cast<std::size_t>(t) * 3 + 2] += bt * xi[2];
      }
      // The trend's monomials s^a t^b in scaled parameters.
      const double ss = r[2 * q + 3], tt = r[2 * q + 4];
      double ps[kTrendDegree + 1], pt[kTrendDegree + 1];
      ps[0] = pt[0] = 1;
      for (int d = 1; d <= degree; ++d) {
        ps[d] = ps[d - 1] * ss;
        pt[d] = pt[d - 1] * tt;
      }
      for (int k = 0; k < nt; ++k) {
        const double f =
            ps[monomials_[static_cast<std::size_t>(k)].first] * pt[monomials_[static_cast<std::size_t>(k)].second];
        phi[static_cast<std::size_t>(k)] = f;
        phi_(i, k) = f;
        double* pb = &block_phi[static_cast<std::size_t>(k) * qq];
        for (int t = 0; t < qq; ++t) pb[t] += f * b[static_cast<std::size_t>(t)];
      }
      for (int k = 0; k < nt; ++k) {
        const double f = phi[static_cast<std::size_t>(k)];
        for (int k2 = k; k2 < nt; ++k2)
          gram_acc[static_cast<std::size_t>(k) * nt + k2] += f * phi[static_cast<std::size_t>(k2)];
        phi_x_acc[static_cast<std::size_t>(k) * 3] += f * xi[0];
        phi_x_acc[static_cast<std::size_t>(k) * 3 + 1] += f * xi[1];
        phi_x_acc[static_cast<std::size_t>(k) * 3 + 2] += f * xi[2];
      }
    }
    // Flush the cell's block into the band, AᵀX and ΦᵀA.
    const int cu = c % cells_u, cv = c / cells_u;  // the cell's first poles: (cu, cv)
    for (int t1 = 0; t1 < qq; ++t1) {
      const int ja1 = t1 % q, jb1 = t1 / q;
      const int k1 = (cu + ja1) + nu_ * (cv + jb1);
      for (int t2 = t1; t2 < qq; ++t2) {
        const int ja2 = t2 % q, jb2 = t2 / q;
        const int k2 = (cu + ja2) + nu_ * (cv + jb2);
        const double g = block[static_cast<std::size_t>(t1) * qq + t2];
        band[static_cast<std::size_t>(k1) * w * w + (jb2 - jb1 + p_) * w + (ja2 - ja1 + p_)] += g;
        if (t2 != t1) band[static_cast<std::size_t>(k2) * w * w + (jb1 - jb2 + p_) * w + (ja1 - ja2 + p_)] += g;
      }
      for (int d = 0; d < 3; ++d) rhs_(k1, d) += block_x[static_cast<std::size_t>(t1) * 3 + d];
      for (int k = 0; k < nt; ++k) phi_a_(k, k1) += block_phi[static_cast<std::size_t>(k) * qq + t1];
    }
  }
  for (int k = 0; k < nt; ++k) {
    for (int k2 = k; k2 < nt; ++k2) gram(k, k2) = gram(k2, k) = gram_acc[static_cast<std::size_t>(k) * nt + k2];
    for (int d = 0; d < 3; ++d) phi_x(k, d) = phi_x_acc[static_cast<std::size_t>(k) * 3 + d];
  }
  // Least-squares polynomial trend of the points in (s, t): a = G⁻¹ Φᵀ X, G = ΦᵀΦ; also ΦᵀA
  // (T × n) for the trace of the influence matrix, and Φ (m × T) for smoothing other data.
  const Eigen::Index all = static_cast<Eigen::Index>(monomials_.size());
  if (with_trend) {
    const Eigen::CompleteOrthogonalDecomposition<Eigen::MatrixXd> cod(gram);
    gram_inv_ = cod.pseudoInverse();
    trend_ = cod.solve(phi_x);
  } else {  // a zero trend: the terms below vanish
    gram_inv_ = Eigen::MatrixXd::Zero(all, all);
    trend_ = Eigen::MatrixXd::Zero(all, 3);
    phi_a_ = Eigen::MatrixXd::Zero(all, n());
  }
  thin_plate_trend_rhs_ = thin_plate_trend_ * trend_;  // R c₀, c₀ = C a

  double trace_n = 0, trace_r = 0;
  for (int col = 0; col < normal_.outerSize(); ++col) {
    const int a1 = col % nu_, b1 = col / nu_;
    for (SparseMatrix::InnerIterator it(normal_, col); it; ++it) {
      const int a = static_cast<int>(it.row()) % nu_, bb = static_cast<int>(it.row()) / nu_;
      it.valueRef() = band[static_cast<std::size_t>(col) * w * w + (bb - b1 + p_) * w + (a - a1 + p_)];
      if (it.row() == col) trace_n += it.value();
    }
  }
  for (int k = 0; k < n(); ++k) trace_r += thin_plate_.coeff(k, k);
  lambda_scale_ = trace_r > 0 ? trace_n / trace_r : 1.0;
}

TensorLsq::Trial TensorLsq::Solve(double lambda, bool with_trace, bool rss_from_reference) {
  Trial trial;
  trial.lambda = lambda;
  const double lambda_s = lambda * lambda_scale_;
  if (!Factorize(lambda_s)) return trial;
  trial.poles = ldlt_.solve(rhs_ + lambda_s * thin_plate_trend_rhs_);
  if (!trial.poles.allFinite()) return trial;
  const int m = static_cast<int>(x_->size());
  if (rss_from_reference && reference_poles_.rows() == n()) {
    // |X − A P|² = |X − A P₀|² − 2 ⟨P − P₀, Aᵀ(X − A P₀)⟩ + ⟨P − P₀, AᵀA (P − P₀)⟩: exact, and no cancellation
    // of large terms (P − P₀ and the reference's residual are both small).
    const Eigen::MatrixXd d = trial.poles - reference_poles_;
    trial.rss = reference_rss_ - 2 * (d.array() * reference_gradient_.array()).sum() +
                (d.array() * (normal_ * d).array()).sum();
  } else {
    trial.rss = 0;
    const bool keep = rss_from_reference;  // this solution becomes the reference of the later ones
    if (keep) reference_gradient_ = Eigen::MatrixXd::Zero(n(), 3);
    const int q = p_ + 1;
    for (int i = 0; i < m; ++i) {
      const Vector3d r = (*x_)[static_cast<std::size_t>(i)] - Evaluate(trial.poles, i);
      trial.rss += r.squaredNorm();
      if (!keep) continue;
      const std::size_t si = static_cast<std::size_t>(i);
      const double* bu = &basis_u_[si * q];
      const double* bv = &basis_v_[si * q];
      for (int jb = 0; jb < q; ++jb) {
        const int base = (span_u_[si] - p_) + nu_ * (span_v_[si] - p_ + jb);
        for (int ja = 0; ja < q; ++ja) {
          const double b = bu[ja] * bv[jb];
          for (int c = 0; c < 3; ++c) reference_gradient_(base + ja, c) += b * r(c);
        }
      }
    }
    if (keep) {
      reference_poles_ = trial.poles;
      reference_rss_ = trial.rss;
    }
  }
  trial.ok = true;
  if (with_trace) {
    if (lambda_s == 0) {
      // Plain least squares (AᵀA positive definite: factorised above): tr H = tr((AᵀA)⁻¹ AᵀA) = n exactly, no
      // selected inversion needed.
      trial.trace = n();
    } else {
      const Result<double> trace = scattered_internal::TraceOfInverseTimes(ldlt_, normal_);
      if (!trace.ok()) {
        trial.ok = false;
        return trial;
      }
      // H = A M⁻¹ (Aᵀ + λ_s R C G⁻¹ Φᵀ): the trend adds λ_s tr(G⁻¹ ΦᵀA M⁻¹ R C), between 0 and the
      // number of trend monomials the energy no longer penalises (10 − 3 for a cubic trend).
      const Eigen::MatrixXd w = ldlt_.solve(thin_plate_trend_);
      trial.trace = *trace + lambda_s * (gram_inv_ * (phi_a_ * w)).trace();
    }
    const double dof_left = 1.0 - trial.trace / m;
    trial.gcv =
        dof_left > 0 ? (trial.rss / (3.0 * m)) / (dof_left * dof_left) : std::numeric_limits<double>::infinity();
  }
  return trial;
}

void TensorLsq::WeightEnergy(const Eigen::MatrixXd* w) {
  if (w == nullptr) {
    thin_plate_ = uniform_thin_plate_;
  } else {
    for (int col = 0; col < thin_plate_.outerSize(); ++col) {
      const int a1 = col % nu_, b1 = col / nu_;
      for (SparseMatrix::InnerIterator it(thin_plate_, col); it; ++it) {
        const int a = static_cast<int>(it.row()) % nu_, b = static_cast<int>(it.row()) / nu_;
        // Spans s where both N_a and N_a1 are non-zero: max(a, a1) ≤ s ≤ min(a, a1) + p.
        double sum = 0;
        for (int su = std::max({a, a1, p_}); su <= std::min({a, a1}) + p_ && su < nu_; ++su) {
          const auto& gu = span_grams_u_[static_cast<std::size_t>(su - p_)];
          const int ia = a - su + p_, ia1 = a1 - su + p_;
          for (int sv = std::max({b, b1, p_}); sv <= std::min({b, b1}) + p_ && sv < nv_; ++sv) {
            const auto& gv = span_grams_v_[static_cast<std::size_t>(sv - p_)];
            const int ib = b - sv + p_, ib1 = b1 - sv + p_;
            sum += (*w)(su - p_, sv - p_) * (gu[2](ia, ia1) * gv[0](ib, ib1) + 2 * gu[1](ia, ia1) * gv[1](ib, ib1) +
                                             gu[0](ia, ia1) * gv[2](ib, ib1));
          }
        }
        it.valueRef() = sum;
      }
    }
  }
  thin_plate_trend_ = thin_plate_ * trend_basis_;
  thin_plate_trend_rhs_ = thin_plate_trend_ * trend_;
}

Eigen::MatrixXd TensorLsq::LocalWeights(const Trial& pilot) {
  const int m = static_cast<int>(x_->size());
  const double lambda_s = pilot.lambda * lambda_scale_;
  const double sigma2 = pilot.rss / std::max(1.0, m - pilot.trace);
  const int su_count = nu_ - p_, sv_count = nv_ - p_;
  Eigen::MatrixXd w = Eigen::MatrixXd::Ones(su_count, sv_count);
  if (!Factorize(lambda_s)) return w;  // the λ search may have left another factor
  if (probes_.rows() != m) {           // drawn once per point count (only the GCV mode needs them)
    Rng rng(kNoiseProbeSeed);
    probes_.resize(m, kNoiseProbes);
    // Every bit of each draw is one sign.
    std::uint64_t bits = 0;
    int left = 0;
    for (Eigen::Index c = 0; c < probes_.cols(); ++c) {
      for (int i = 0; i < m; ++i) {
        if (left == 0) {
          bits = rng.NextU64();
          left = 64;
        }
        probes_(i, c) = (bits & 1) != 0 ? 1.0 : -1.0;
        bits >>= 1;
        --left;
      }
    }
  }
  Eigen::MatrixXd residual(m, 3);
  for (int i = 0; i < m; ++i) {
    residual.row(i) = ((*x_)[static_cast<std::size_t>(i)] - Evaluate(pilot.poles, i)).transpose();
  }
  const Eigen::MatrixXd delta = Smooth(residual, lambda_s);
  Eigen::MatrixXd fit_noise, delta_noise;
  SmoothProbes(lambda_s, &fit_noise, &delta_noise);
  // Per span (i, j): Σ over its (p + 1)² poles of |δ·n|², var δ·n and var S.
  Eigen::MatrixXd bias2 = Eigen::MatrixXd::Zero(su_count, sv_count), var_delta = bias2, var_fit = bias2;
  auto pole = [&](int a, int b) -> Vector3d {
    return pilot.poles.row(std::clamp(a, 0, nu_ - 1) + nu_ * std::clamp(b, 0, nv_ - 1)).transpose();
  };
  for (int b = 0; b < nv_; ++b) {
    for (int a = 0; a < nu_; ++a) {
      const int k = a + nu_ * b;
      const Vector3d normal = (pole(a + 1, b) - pole(a - 1, b)).cross(pole(a, b + 1) - pole(a, b - 1));
      const double along = normal.norm() > 0 ? delta.row(k).dot(normal.normalized().transpose()) : delta.row(k).norm();
      const double b2 = along * along;
      const double vd = sigma2 * delta_noise.row(k).squaredNorm() / kNoiseProbes;
      const double vf = sigma2 * fit_noise.row(k).squaredNorm() / kNoiseProbes;
      // Pole (a, b) belongs to the spans s_u = a .. a + p, s_v = b .. b + p (indices from p).
      for (int j = std::max(0, b - p_); j <= std::min(sv_count - 1, b); ++j) {
        for (int i = std::max(0, a - p_); i <= std::min(su_count - 1, a); ++i) {
          bias2(i, j) += b2;
          var_delta(i, j) += vd;
          var_fit(i, j) += vf;
        }
      }
    }
  }
  for (int j = 0; j < sv_count; ++j) {
    for (int i = 0; i < su_count; ++i) {
      double sb = 0, sd = 0, sf = 0;
      for (int jj = std::max(0, j - kWeightWindowSpans); jj <= std::min(sv_count - 1, j + kWeightWindowSpans); ++jj) {
        for (int ii = std::max(0, i - kWeightWindowSpans); ii <= std::min(su_count - 1, i + kWeightWindowSpans); ++ii) {
          sb += bias2(ii, jj);
          sd += var_delta(ii, jj);
          sf += var_fit(ii, jj);
        }
      }
      const double b2 = (sb - sd) / (kBiasRecovered * kBiasRecovered);
      if (b2 > 0) w(i, j) = std::clamp(std::pow(sf / (2 * b2), 2.0 / 3.0), kMinPenaltyWeight, 1.0);
    }
  }
  return w;
}

Eigen::Vector3d TensorLsq::Evaluate(const Eigen::MatrixXd& poles, int i) const {
  const int q = p_ + 1;
  const std::size_t si = static_cast<std::size_t>(i);
  const double* bu = &basis_u_[si * q];
  const double* bv = &basis_v_[si * q];
  Vector3d s = Vector3d::Zero();
  for (int jb = 0; jb < q; ++jb) {
    Vector3d row = Vector3d::Zero();
    const int base = (span_u_[si] - p_) + nu_ * (span_v_[si] - p_ + jb);
    for (int ja = 0; ja < q; ++ja) row += bu[ja] * poles.row(base + ja).transpose();
    s += bv[jb] * row;
  }
  return s;
}

bool TensorLsq::Factorize(double lambda_s) {
  const double* nv = normal_.valuePtr();
  const double* rv = thin_plate_.valuePtr();
  double* sv = system_.valuePtr();
  for (Eigen::Index k = 0; k < system_.nonZeros(); ++k) sv[k] = nv[k] + lambda_s * rv[k];
  if (!analysed_) {
    ldlt_.analyzePattern(system_);
    analysed_ = true;
  }
  ldlt_.factorize(system_);
  return ldlt_.info() == Eigen::Success && ldlt_.vectorD().minCoeff() > 0;
}

Eigen::MatrixXd TensorLsq::Smooth(const Eigen::MatrixXd& r, double lambda_s) const {
  // Row-major copies: each point's row of r, and each pole's row of the right-hand side, contiguous.
  const int q = p_ + 1;
  const RowMatrix rows = r;
  RowMatrix rhs = RowMatrix::Zero(n(), r.cols());
  for (Eigen::Index i = 0; i < r.rows(); ++i) {
    const std::size_t si = static_cast<std::size_t>(i);
    const double* bu = &basis_u_[si * q];
    const double* bv = &basis_v_[si * q];
    for (int jb = 0; jb < q; ++jb) {
      for (int ja = 0; ja < q; ++ja) {
        rhs.row((span_u_[si] - p_ + ja) + nu_ * (span_v_[si] - p_ + jb)) += (bu[ja] * bv[jb]) * rows.row(i);
      }
    }
  }
  Eigen::MatrixXd out = rhs;
  out += lambda_s * (thin_plate_trend_ * (gram_inv_ * (phi_.transpose() * r)));
  return ldlt_.solve(out);
}

void TensorLsq::SmoothProbes(double lambda_s, Eigen::MatrixXd* fit_noise, Eigen::MatrixXd* delta_noise) const {
  // Row-major n × K and T × K accumulators; each point's K probe values are contiguous (probes_ is row-major), so
  // the inner loops run over the probes. No m × K temporary is formed.
  const int q = p_ + 1, m = static_cast<int>(span_u_.size()), nt = static_cast<int>(phi_.cols());
  constexpr int kK = kNoiseProbes;
  auto smooth = [&](const RowMatrix& aty, const RowMatrix& phity) -> Eigen::MatrixXd {
    Eigen::MatrixXd out = aty;
    out += lambda_s * (thin_plate_trend_ * (gram_inv_ * Eigen::MatrixXd(phity)));
    return ldlt_.solve(out);
  };
  RowMatrix aty = RowMatrix::Zero(n(), kK), phity = RowMatrix::Zero(nt, kK);
  // Point i's row y (K values) into Aᵀ Y and Φᵀ Y.
  auto add = [&](int i, const double* y) {
    const std::size_t si = static_cast<std::size_t>(i);
    const double* bu = &basis_u_[si * q];
    const double* bv = &basis_v_[si * q];
    for (int jb = 0; jb < q; ++jb) {
      double* row = aty.data() + static_cast<std::size_t>((span_u_[si] - p_) + nu_ * (span_v_[si] - p_ + jb)) * kK;
      for (int ja = 0; ja < q; ++ja, row += kK) {
        const double b = bu[ja] * bv[jb];
        for (int c = 0; c < kK; ++c) row[c] += b * y[c];
      }
    }
    for (int t = 0; t < nt; ++t) {
      const double f = phi_(i, t);
      double* row = phity.data() + static_cast<std::size_t>(t) * kK;
      for (int c = 0; c < kK; ++c) row[c] += f * y[c];
    }
  };
  for (int i = 0; i < m; ++i) add(i, probes_.data() + static_cast<std::size_t>(i) * kK);
  *fit_noise = smooth(aty, phity);
  // δ's noise: the same smoother applied to z − A · fit_noise.
  const RowMatrix fit_rows = *fit_noise;
  aty.setZero();
  phity.setZero();
  double d[kK];
  for (int i = 0; i < m; ++i) {
    const std::size_t si = static_cast<std::size_t>(i);
    const double* z = probes_.data() + si * kK;
    const double* bu = &basis_u_[si * q];
    const double* bv = &basis_v_[si * q];
    for (int c = 0; c < kK; ++c) d[c] = z[c];
    for (int jb = 0; jb < q; ++jb) {
      const double* row =
          fit_rows.data() + static_cast<std::size_t>((span_u_[si] - p_) + nu_ * (span_v_[si] - p_ + jb)) * kK;
      for (int ja = 0; ja < q; ++ja, row += kK) {
        const double b = bu[ja] * bv[jb];
        for (int c = 0; c < kK; ++c) d[c] -= b * row[c];
      }
    }
    add(i, d);
  }
  *delta_noise = smooth(aty, phity);
}

// ---------------------------------------------------------------------------------------------
// Building blocks (scattered_fit.h)

SparseMatrix ThinPlateMatrix(const KnotVector& u_knots, const KnotVector& v_knots, const ParamDomain* region) {
  SparseMatrix r = BandPattern(u_knots.n_poles(), v_knots.n_poles(), u_knots.degree());
  FillThinPlate(u_knots, v_knots,
                region != nullptr ? *region : ParamDomain{u_knots.lo(), u_knots.hi(), v_knots.lo(), v_knots.hi()}, &r);
  return r;
}

Result<double> TraceOfInverseTimes(const Ldlt& ldlt, const SparseMatrix& b) {
  // P M Pᵀ = L D Lᵀ (L unit lower, strictly lower part stored by columns, rows ascending).
  // Z = (L D Lᵀ)⁻¹ satisfies Z = D⁻¹L⁻¹ + (I − Lᵀ) Z, hence for j from n − 1 down to 0 and the rows
  // i > j of column j of L:  Z_ij = −Σ_k L_kj Z_ik,  Z_jj = 1/D_j − Σ_k L_kj Z_kj  (k over the same
  // rows). Every Z_ik needed lies on L's pattern (i, k > j both in column j ⇒ L_ik is structurally
  // non-zero), so Z is formed on that pattern only.
  const SparseMatrix& l = ldlt.matrixL().nestedExpression();
  if (!l.isCompressed()) return Status::Internal("selected inversion: the LDLT factor is not compressed");
  const int n = static_cast<int>(l.cols());
  const int* lp = l.outerIndexPtr();
  const int* li = l.innerIndexPtr();
  const double* lx = l.valuePtr();
  const Eigen::VectorXd d = ldlt.vectorD();
  std::vector<double> zx(static_cast<std::size_t>(l.nonZeros()), 0.0), zd(static_cast<std::size_t>(n), 0.0);
  // Position of (row, col), row > col, in L's storage, or −1.
  auto find = [&](int row, int col) -> int {
    const int* begin = li + lp[col];
    const int* end = li + lp[col + 1];
    const int* it = std::lower_bound(begin, end, row);
    return it != end && *it == row ? static_cast<int>(it - li) : -1;
  };
  // For column j with rows R_j: s_i = Σ_{k ∈ R_j} L_kj Z_ik. Each pair k < i of R_j is visited once,
  // scanning column k of Z (which holds R_j ∩ (k, n), see above) against a scatter map of R_j; the
  // cost is Σ_j Σ_{k ∈ R_j} |column k|: measured about three times the numeric factorisation.
  bool missing = false;
  std::vector<double> s;
  std::vector<int> where(static_cast<std::size_t>(n), -1);
  for (int j = n - 1; j >= 0; --j) {
    const int begin = lp[j], count = lp[j + 1] - lp[j];
    const int* rows = li + begin;
    const double* l_col = lx + begin;
    s.assign(static_cast<std::size_t>(count), 0.0);
    for (int a = 0; a < count; ++a) where[static_cast<std::size_t>(rows[a])] = a;
    for (int a = 0; a < count; ++a) {
      const int k = rows[a];
      const double l_kj = l_col[a];
      double s_a = l_kj * zd[static_cast<std::size_t>(k)];
      int matched = 0;
      for (int q = lp[k]; q < lp[k + 1]; ++q) {
        const int pos = where[static_cast<std::size_t>(li[q])];
        if (pos < 0) continue;
        const double z_ik = zx[static_cast<std::size_t>(q)];
        s[static_cast<std::size_t>(pos)] += l_kj * z_ik;
        s_a += l_col[pos] * z_ik;
        ++matched;
      }
      s[static_cast<std::size_t>(a)] += s_a;
      missing = missing || matched != count - a - 1;
    }
    double diag = 0;
    for (int a = 0; a < count; ++a) {
      where[static_cast<std::size_t>(rows[a])] = -1;
      zx[static_cast<std::size_t>(begin + a)] = -s[static_cast<std::size_t>(a)];
      diag += l_col[a] * zx[static_cast<std::size_t>(begin + a)];
    }
    zd[static_cast<std::size_t>(j)] = 1.0 / d(j) - diag;
  }
  if (missing) return Status::Internal("selected inversion: an entry of the inverse lies off the factor's pattern");
  // (M⁻¹)_rc = Z_{π(r), π(c)} with π = P's index map.
  const auto& perm = ldlt.permutationP().indices();
  double trace = 0;
  for (int col = 0; col < b.outerSize(); ++col) {
    for (SparseMatrix::InnerIterator it(b, col); it; ++it) {
      const int r = perm(static_cast<int>(it.row())), c = perm(col);
      double z;
      if (r == c) {
        z = zd[static_cast<std::size_t>(r)];
      } else {
        const int pos = find(std::max(r, c), std::min(r, c));
        if (pos < 0) return Status::Internal("selected inversion: B has an entry off the factor's pattern");
        z = zx[static_cast<std::size_t>(pos)];
      }
      trace += z * it.value();
    }
  }
  return trace;
}

}  // namespace formloop::recon::scattered_internal
