#pragma once
// The penalised least-squares system of a scattered fit for fixed knots and parameters (TensorLsq), internal to
// reconstruction/scattered_fit.cc and scattered_choice.cc: the tensor-product normal equations assembled knot
// cell by knot cell, the thin-plate energy of S − S₀ (S₀ the points' cubic trend) with optional local weights,
// the LDLᵀ solve and the trace of the influence matrix for GCV (selected inversion). The model and the
// measurements behind the choices are in scattered_fit.h and beside the constants in scattered_lsq.cc.

#include <Eigen/Core>
#include <array>
#include <limits>
#include <utility>
#include <vector>

#include "reconstruction/bspline_basis.h"
#include "reconstruction/scattered_fit.h"

namespace formloop::recon::scattered_internal {

class TensorLsq {
 public:
  using RowMatrix = Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>;
  // The thin-plate energy is integrated over `region` (Q's whole domain, see DataKnots).
  TensorLsq(KnotVector ku, KnotVector kv, const ParamDomain& region);

  int n() const { return nu_ * nv_; }
  const KnotVector& ku() const { return ku_; }
  const KnotVector& kv() const { return kv_; }
  double lambda_scale() const { return lambda_scale_; }

  // Coefficients of s^j, j = 0 .. K (s = (x − c)/l), in the clamped basis `k` (degree p ≥ K),
  // n_poles × (K + 1), from their blossoms (Marsden's identity; de Boor, A Practical Guide to
  // Splines, ch. IX): coefficient i of s^j is e_j(τ_{i+1}, ..., τ_{i+p}) / C(p, j), e_j the
  // elementary symmetric polynomial of the scaled knots τ.
  static Eigen::MatrixXd MonomialCoefficients(const KnotVector& k, double c, double l, int degree);

  // Basis values at every (u_i, v_i), AᵀA and AᵀX (x centred by the caller), and the trend's ΦᵀΦ, ΦᵀX
  // and ΦᵀA. The points are taken knot cell by knot cell (a counting sort): all points of a cell touch the
  // same (p + 1)² poles, so their products are summed in a small dense block (upper triangle, in cache)
  // and added to the band once per cell. Measured on 100,000 points, 25 × 25 cubic: 5-8 times faster than
  // scattering every point's (p + 1)⁴ products into the band (bench/fit_default_bench.cc).
  // with_trend = false (least squares with the weight at its floor, kNone and the net ladder): no trend;
  // the energy then acts on S itself, which at λ = kScatteredNoneLambda only fixes poles without data.
  void Assemble(const std::vector<double>& u, const std::vector<double>& v, const std::vector<Eigen::Vector3d>& x,
                bool with_trend = true);

  struct Trial {
    double lambda = 0;  // dimensionless
    bool ok = false;
    Eigen::MatrixXd poles;  // n × 3, centred coordinates
    double rss = 0;         // Σ_i |x_i − S(u_i, v_i)|² (parametric)
    double trace = 0;       // tr H
    double gcv = std::numeric_limits<double>::infinity();
    double min_weight = 1, mean_weight = 1;  // of the thin-plate energy's local weights
  };

  // Solves (AᵀA + λ_s R) P = AᵀX + λ_s R c₀: the penalty is the thin-plate energy of S − S₀, S₀ the
  // least-squares polynomial trend of the points (degree kTrendDegree in (u, v); c₀ its
  // coefficients). The energy's natural boundary conditions drive the curvature (and at corners
  // the twist) towards zero at the domain's edge, which biases any curved surface there; measured
  // against the trend they bend only the part the trend does not explain (saddle with 5 µm noise
  // at its GCV weight: 11 µm of bias in the outer 0.5 mm without the trend, none with it). For
  // λ → 0 the trend has no effect. with_trace adds tr H and the GCV score.
  // rss_from_reference (the λ search): the first such solve after Assemble sums the residuals over the
  // points and keeps its poles P₀ and Aᵀ(X − A P₀); later ones get the RSS from those in O(n) (exact up to
  // rounding: |X − A P|² = |X − A P₀|² − 2 ⟨P − P₀, Aᵀ(X − A P₀)⟩ + ⟨P − P₀, AᵀA (P − P₀)⟩).
  Trial Solve(double lambda, bool with_trace, bool rss_from_reference = false);

  // The thin-plate energy with weight w(s_u, s_v) on knot span (s_u, s_v) (w: (n_u − p) × (n_v − p),
  // see LocalWeights), or uniform (nullptr): R_w = Σ_spans w R_span, R_span the energy of S − S₀
  // integrated over that span alone.
  void WeightEnergy(const Eigen::MatrixXd* w);

  // Local weights of the thin-plate energy (for WeightEnergy) from a pilot fit at GCV's λ with the
  // uniform energy. GCV balances squared bias against variance over the whole surface, but the bias
  // is not spread like the variance: the energy's natural boundary conditions flatten S − S₀ at the
  // domain's edge, so where a surface curves away from the cubic trend near an edge or a corner the
  // bias there is several times the interior's (ellipsoid_cap without noise at the λ GCV takes for
  // 5 µm noise: 7.6 µm at a corner, 1.5 µm inside). A weight w acts locally as λ w; near an edge
  // the bias of a second-order penalty grows as (λ w)^½ and the variance of the fit falls as
  // (λ w)^−½ (in 2-D the smoother's width goes as (λ w)^¼), so the local mean squared error
  // w B² + V / √w, B and V the pilot's bias and variance there, is least at w = (V / 2B²)^⅔.
  // Weights are only lowered (w ≤ 1): where the bias is small GCV's λ stays.
  // Bias: Tukey's twicing correction δ = H r, the pilot's residuals r smoothed again by the same
  // smoother (J. W. Tukey, Exploratory Data Analysis, Addison-Wesley 1977), has expectation H b,
  // the smoothed bias b; B² = (|δ·n|² − var δ·n) / kBiasRecovered², n the normal at each pole.
  // Variances of the fit (H z) and of δ (H (I − H) z) from kNoiseProbes random ±1 vectors z,
  // scaled by σ̂² = RSS / (m − tr H) (the noise is along the normal). All three are summed over
  // the poles of each span and pooled over windows of spans (kWeightWindowSpans).
  Eigen::MatrixXd LocalWeights(const Trial& pilot);

  // S(u_i, v_i) from the stored basis values.
  Eigen::Vector3d Evaluate(const Eigen::MatrixXd& poles, int i) const;

 private:
  // LDLᵀ of AᵀA + λ_s R (the current weights); false if it is not positive definite.
  bool Factorize(double lambda_s);

  // Poles of the smoother applied to data columns r (m × c), with the current factor:
  // M⁻¹ (Aᵀ r + λ_s R C G⁻¹ Φᵀ r), i.e. what Solve gives for data r (their own trend included).
  Eigen::MatrixXd Smooth(const Eigen::MatrixXd& r, double lambda_s) const;

  // The smoother applied to the noise probes z (the columns of probes_): fit_noise = poles of H z, and
  // delta_noise = poles of H (z − A fit_noise), i.e. what Smooth gives for them, in two passes over the points.
  void SmoothProbes(double lambda_s, Eigen::MatrixXd* fit_noise, Eigen::MatrixXd* delta_noise) const;

  KnotVector ku_, kv_;
  int p_ = 3, nu_ = 0, nv_ = 0;
  SparseMatrix normal_, thin_plate_, system_;
  SparseMatrix uniform_thin_plate_;                                          // R with unit weights
  std::vector<std::array<Eigen::MatrixXd, 3>> span_grams_u_, span_grams_v_;  // SpanGrams
  Ldlt ldlt_;
  bool analysed_ = false;
  double lambda_scale_ = 1;
  Eigen::MatrixXd rhs_;
  double cu_ = 0, lu_ = 1, cv_ = 0, lv_ = 1;
  std::vector<std::pair<int, int>> monomials_;  // (a, b) of s^a t^b
  Eigen::MatrixXd trend_basis_;                 // n × T: B-spline coefficients of the monomials
  Eigen::MatrixXd thin_plate_trend_;            // R · trend_basis_
  Eigen::MatrixXd thin_plate_trend_rhs_;        // R c₀ (n × 3)
  Eigen::MatrixXd phi_a_;                       // ΦᵀA, T × n
  Eigen::MatrixXd gram_inv_;                    // (ΦᵀΦ)⁻¹, T × T
  RowMatrix phi_;                               // Φ, m × T
  Eigen::MatrixXd trend_;                       // trend coefficients a, T × 3
  RowMatrix probes_;                            // m × kNoiseProbes random ±1 (LocalWeights)
  Eigen::MatrixXd reference_poles_;             // P₀ of Solve's rss_from_reference (n × 3; empty: none yet)
  Eigen::MatrixXd reference_gradient_;          // Aᵀ(X − A P₀)
  double reference_rss_ = 0;
  const std::vector<Eigen::Vector3d>* x_ = nullptr;
  std::vector<int> span_u_, span_v_;
  std::vector<double> basis_u_, basis_v_;
  std::vector<double> record_;  // Assemble's points in cell order (kept to reuse the allocation)
};

}  // namespace formloop::recon::scattered_internal
