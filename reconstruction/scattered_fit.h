#pragma once
// Tensor-product B-spline surface from scattered points (spec/reconstruction.md §2): penalised least
// squares with a thin-plate energy, the weight chosen by generalised cross-validation and adapted
// locally to the estimated bias, parameter correction (orthogonal-distance fitting) and optional
// adaptive knot insertion.
//
// Model. S(u, v) = Σ_ab P_ab N_a(u) M_b(v) with one clamped basis per direction (bspline_basis.h);
// x, y and z share the basis, so one sparse system with three right-hand sides is solved:
//   (AᵀA + λ_s R) P = AᵀX + λ_s R P₀,   A_ik = N_a(u_i) M_b(v_i) ((p + 1)² non-zeros a row, never stored),
//   R = G2u ⊗ G0v + 2 G1u ⊗ G1v + G0u ⊗ G2v   (thin-plate energy ∫∫ S_uu² + 2 S_uv² + S_vv² du dv over
//   Q's domain; Gk = exact Gram matrices of the k-th derivatives, Gauss–Legendre per span),
// solved by sparse LDLᵀ (Eigen::SimplicialLDLT, AMD ordering). λ_s = λ · tr(AᵀA) / tr(R), so the
// reported λ is dimensionless (independent of units, point count and net size). The energy is
// taken of S − S₀, S₀ (coefficients P₀) the least-squares cubic polynomial trend of the points in
// (u, v): the energy's natural boundary conditions flatten curvature and twist at the domain's
// edge, which biases any curved surface there; relative to the trend only what the trend does not
// explain is flattened (measured with 5 µm noise: 11 µm of edge bias on the saddle without it,
// none with it). For noise-free data GCV drives λ → 0 and the trend has no effect.
//
// Knots (scattered_layout.cc, DataKnots), chosen by coverage: the largest hole the initial parameters
// leave in their box (in practice at a corner), in widths of a uniform span of the net.
// - Sparse (hole > 0.4 spans, e.g. the automatic net's ~8 points a pole; always with a base
//   surface): uniform over the points' parameter box except the two end spans, which are twice as
//   wide: edge pieces see data from one side only, and a corner hole is extrapolated badly by a
//   standard-width corner piece. With PCA parameters Q's domain reaches a "margin" beyond each end
//   of the points (at least 2 point spacings, or a span, wide) and the end spans reach with it (no
//   knot at the points' box, no pole of its own): it lets the boundary of the sampled surface,
//   which the points miss by up to a spacing, project inside Q, keeps the energy's boundary off
//   the data, and beyond the data Q continues the end piece's polynomial (into a corner hole that
//   extrapolates better than a separate margin span decided by the energy alone; measured in the
//   test ScatteredFitReference).
// - Dense (PCA parameters, hole ≤ 0.4 spans, e.g. 100,000 points on a 24 × 24 net): every span is
//   well filled whatever its width, so the knots follow the shape. A first fit on uniform spans
//   over the box widened by 2 point spacings at each end, then the knots are redistributed to
//   equidistribute the approximation error (de Boor's NEWNOT per direction, from the jumps of the
//   fit's p-th derivative; scattered_layout.cc, RedistributedKnots) and the fit is repeated from its
//   foot points. Measured on franke at 24 × 24 with 1 µm noise (bench/scattered_fit_bench.cc):
//   orthogonal RMS 1.231 µm with the sparse layout, 1.153 µm uniform, 1.055 µm redistributed
//   (error against the true surface: RMS 0.571 -> 0.346 µm, max 6.6 -> 2.6 µm).
// The report's "edge_spans" (margin or uniform), "initial_gap_spans" and "knots_redistributed"
// say which applied.
//
// λ by GCV (Craven & Wahba 1979, "Smoothing noisy data with spline functions", Numer. Math. 31:
// 377–403): minimise V(λ) = (RSS/3m) / (1 − tr H/m)² over a log grid and then a golden-section
// search, with H(λ) the influence matrix shared by the three coordinates. tr((AᵀA + λ_s R)⁻¹ AᵀA)
// is computed exactly from the sparse LDLᵀ factor by selected inversion (Takahashi, Fagan & Chen
// 1973; Erisman & Tinney 1975, CACM 18: 177–179): only the entries of the inverse on the factor's
// pattern are formed, at about three times the cost of the factorisation (measured), so no dense
// matrix and no stochastic estimate is needed (the approach of Hutchinson & de Hoog 1985 for
// smoothing splines, here on a 2-D net); the trend adds an exact 10 × 10 term.
//
// Local smoothing weights (kGcv). GCV's λ balances bias against noise over the whole surface, but
// the energy's natural boundary conditions put the bias at the edges and corners where a surface
// curves away from its cubic trend (measured without noise at the λ GCV takes for 5 µm noise:
// ellipsoid_cap 7.6 µm at a corner against 1.5 µm inside). So the energy is weighted per knot span,
// R_w = Σ_spans w R_span, 0.01 ≤ w ≤ 1, and the fit solved again at GCV's λ: w minimises the local
// mean squared error w B² + V / √w (edge bias ∝ (λ w)^½, variance ∝ (λ w)^−½), with the pilot's
// bias B estimated by Tukey's twicing correction (the residuals smoothed again; J. W. Tukey,
// Exploratory Data Analysis, Addison-Wesley 1977) and the variances V of the fit and of that
// estimate by smoothing 32 fixed random ±1 vectors (deterministic), pooled over 5 × 5 spans
// (scattered_lsq.cc, TensorLsq::LocalWeights) — a local λ in the manner of spatially adaptive
// penalties (Ruppert & Carroll 2000, "Spatially-adaptive penalties for spline fitting", Aust. N. Z.
// J. Stat. 42: 205–223), here set by a plug-in rule rather than searched. Measured on the nine
// reference surfaces with 10,000 points and 5 µm noise (tests/reconstruction/scattered_fit_test.cc):
// the worst error in the outer 5 % band over the interior's worst from 2.50 / 2.75 to 1.73 / 1.92 on
// ellipsoid_cap / blade (all nine ≤ 1.92), the error against the true surface (RMS) 1 % higher on
// the three surfaces the trend already fits and 0.5-6 % lower on the six others, at 0.85-1.35
// times the fit time (blade 2.2: one more correction round). kTolerance and kFixed keep the uniform
// energy.
//
// Parameters. Initial (u, v): orthogonal projection onto the plane of the two largest principal
// components, rotated in that plane to the minimum-area bounding rectangle of the projected points
// (rotating calipers on their convex hull; Freeman & Shapira 1975) so a rectangular patch fills its
// parameter box. u runs along the longer side; v is flipped if needed so that the normal S_u × S_v
// points to +z (the tool and probe side for the part frame). With *base, (u, v) are the foot points
// on base and Q takes base's domain and orientation. Parameter correction (Hoschek 1988; Eck & Hoppe
// 1996 "Automatic reconstruction of B-spline surfaces of arbitrary topological type", SIGGRAPH;
// Wang, Pottmann & Liu 2006 "Fitting B-spline curves to point clouds by curvature-based squared
// distance minimization", ACM TOG 25) re-projects every point onto the current surface with
// ProjectFrom and refits, until the orthogonal RMS falls by less than 1e-3 (relative).
//
// Adaptive refinement: spans (in u and in v) holding a point whose orthogonal residual exceeds
// tolerance_mm get a knot at their midpoint (with the sparse layout the part of an end span over
// the data is split 2 : 1 so it stays twice as wide as its neighbour; no knot goes into the
// margin); refit; repeat.
//
// Coverage. Where the points leave a gap (a corner of the patch, typically) Q is extrapolated and
// the residuals say nothing about its error; the report gives the largest gap and a note when it
// exceeds two point spacings.

#include <Eigen/Core>
#include <Eigen/SparseCholesky>
#include <Eigen/SparseCore>
#include <vector>

#include "core/status.h"
#include "reconstruction/bspline_basis.h"
#include "reconstruction/bspline_surface.h"

namespace formloop::recon {

struct ScatteredFitOptions {
  int degree = 3;  // both directions; cubic (C²) is the CAM norm; 2 ≤ degree ≤ 7
  // Control net. 0 = automatic. With kNone (the default) and kGcv, chosen from the data (density and noise): a
  // ladder of nets from (degree + 1) poles a side upwards, each a factor kScatteredNetLadderRatio finer,
  // fitted by least squares at the initial parameters and scored by GCV, V(n) = (RSS/3m) / (1 − n/m)²
  // (n poles, m points: an estimate of the prediction error, Craven & Wahba 1979, with the influence
  // matrix's trace n for least squares); the ladder stops at the first rung that scores worse once the
  // score has flattened below a tenth of the coarsest rung's (scattered_choice.cc, ChooseNet), and the best
  // rung is taken. Where the points leave a hole wider than 0.4 of that net's spans (sparse coverage,
  // e.g. 10,000 points), the thin-plate GCV fit on the point-count net below takes over (least squares
  // would extrapolate holes freely). kGcv then chooses λ by GCV on that net (until 2026-11 it kept the
  // point-count net: with 10,000 points its band and truth errors were larger on every reference surface,
  // scattered_fit.cc). kTolerance and kFixed: about one pole per kScatteredPointsPerPole points, at most
  // kScatteredMaxAutoPoles a side. Poles are split between u and v in the ratio of the points' parameter box.
  // Measured on issue 26's recipe (100,000 points, 5 µm noise; bench/fit_default_bench.cc): 25 × 25 poles, truth
  // RMS 0.410 µm (kGcv 0.409 µm) against SciPy's 0.413 µm at 24 × 24.
  // Explicit values: degree + 1 ≤ poles ≤ 1000.
  int u_poles = 0, v_poles = 0;
  enum class Smoothing { kNone, kGcv, kTolerance, kFixed };
  // kNone (default): least squares on the net, the thin-plate weight only a floor
  // (kScatteredNoneLambda) that keeps a pole without data determined; the net (chosen as above)
  // does the smoothing. Its edges are less damped than the thin-plate modes': measured with 10,000
  // points and 5 µm noise the worst error in the outer 5 % band is 1.7-3.9 times the interior's (GCV on the
  // same nets: 1.2-3.2, its band max 5-59 % lower), and beyond the samples' hull up to 32σ (egg_box, GCV 7σ;
  // tests ScatteredFitNoiseDefault and ScatteredFitNoise). Otherwise the thin-plate
  // weight λ (dimensionless, see above): by GCV (no noise level needs to be known; the energy is then weighted locally,
  // see above), the λ whose orthogonal RMS residual equals tolerance_mm (the smoothest surface that close to the
  // points; reached within 0.5 % or a note says what was reached), or fixed.
  Smoothing smoothing = Smoothing::kNone;
  // For kFixed, ≥ 0. 0 = plain least squares: every pole then needs data (a pole whose support holds
  // no point makes the fit fail with Failed); a small λ such as 1e-9 avoids that.
  double lambda = 0;
  double tolerance_mm = 1e-3;  // kTolerance target RMS, and the residual limit of adaptive refinement
  // Parameter-correction rounds (orthogonal-distance fitting); stops earlier when the orthogonal
  // RMS falls by less than 1e-3 (relative) or rises. 0 = keep the initial parameters.
  int max_correction_iterations = 10;
  bool adaptive = false;  // insert knots where |residual| > tolerance_mm, refit, repeat
  int max_refinements = 6;
  Status Validate() const;
};

// About this many points per control point per coordinate when the net is chosen automatically:
// enough that a random (Poisson-like) scatter leaves few spans empty, while the net still resolves
// features a few spans wide. With 5,000 points a 100 × 80 mm patch gets 28 × 22 poles.
inline constexpr int kScatteredPointsPerPole = 8;
inline constexpr int kScatteredMaxAutoPoles = 200;
// Ratio of pole counts a side between the rungs of the automatic net's ladder (see u_poles).
inline constexpr double kScatteredNetLadderRatio = 1.25;
// Thin-plate weight (dimensionless) of kNone and of the ladder's fits: at the rounding floor of AᵀA
// (measured with λ = 1e-9 against plain least squares on franke, 24 × 24: the same residual to
// 1e-3 µm), but it keeps a pole whose support holds no point determined.
inline constexpr double kScatteredNoneLambda = 1e-9;

// Points in mm (any frame). Returns Q with its FitReport:
// - rms_mm, max_mm, max_at: orthogonal residual |p_i − foot point on Q| (report->residual says so);
// - details: "degree", "u_poles", "v_poles", "u_knots"/"v_knots" (distinct values), "smoothing",
//   "lambda" (dimensionless), "lambda_scale" (tr AᵀA / tr R), "gcv_score_mm2", "effective_dof"
//   (tr H), "penalty_weight_min" and "penalty_weight_mean" (the local weights, 1 unless kGcv),
//   "parametric_rms_mm", "correction_iterations" (of the final fit) and
//   "correction_iterations_per_fit", "rms_history_mm", "refinements", "knots_inserted_u"/"_v",
//   "parameterisation" (pca-plane or base-surface), "frame" (PCA case: origin and axes of the
//   parameter plane, u ≈ (p − origin)·u_axis — a good start for foot-point searches on Q),
//   "domain" (Q's), "data_box" (the points' parameter box), "edge_spans" and "initial_gap_spans"
//   (PCA case: the knot layout and the coverage that chose it), "point_spacing_mm", "largest_gap_mm"
//   and "largest_gap_at_uv", "knots_redistributed" (dense case, see above), "boundary_feet" (points
//   whose foot point is clamped to Q's edge), "failed_projections";
// - notes when a tolerance was not reached (with the figure reached), a gap in the points, or
//   other caveats.
// BadInput, before any work: invalid options, fewer points than unknowns (says how many are
// needed), a non-finite point (its index), two identical points (both indices), collinear or
// coincident points (second principal variance ~0 relative to the first), an invalid base.
Result<BSplineSurface> FitScattered(const std::vector<Eigen::Vector3d>& points, const ScatteredFitOptions& options,
                                    FitReport* report, const BSplineSurface* base = nullptr);

// Building blocks, exposed for the tests and the benchmark.
namespace scattered_internal {

using SparseMatrix = Eigen::SparseMatrix<double, Eigen::ColMajor, int>;
using Ldlt = Eigen::SimplicialLDLT<SparseMatrix, Eigen::Lower, Eigen::AMDOrdering<int>>;

// Thin-plate energy matrix R (n_u n_v × n_u n_v, pole index a + n_u b) for the tensor-product basis:
// cᵀ R c = ∫∫ f_uu² + 2 f_uv² + f_vv² du dv for f = Σ c_ab N_a M_b, over `region` (default: the
// whole knot box). Stored with the full (symmetric) band pattern |a − a'| ≤ p, |b − b'| ≤ p.
SparseMatrix ThinPlateMatrix(const KnotVector& u_knots, const KnotVector& v_knots, const ParamDomain* region = nullptr);

// tr(M⁻¹ B) for the matrix M factored in `ldlt` and a symmetric B whose pattern lies within M's, by
// selected inversion of the LDLᵀ factor (Takahashi–Fagan–Chen). Internal error if the factor's
// pattern misses an entry (cannot happen for a symbolic Cholesky pattern).
Result<double> TraceOfInverseTimes(const Ldlt& ldlt, const SparseMatrix& b);

}  // namespace scattered_internal
}  // namespace formloop::recon
