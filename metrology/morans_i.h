#pragma once
// Moran's I (Moran 1950; Cliff & Ord 1981), spec/metrology.md §6.
//
// MoranI: raw values with moments under normality and randomisation (Cliff & Ord 1981, §2.3), and
//   optionally a seeded permutation test with PySAL's pseudo p-value (larger + 1)/(N + 1).
// ResidualMoranI: least-squares residuals e = M y, M = I − X(XᵀX)⁻¹Xᵀ, with the exact moments of
//   Cliff & Ord (1981, §8.3). The traces tr(MW), tr(MWMWᵀ), tr((MW)²) are computed from a thin
//   orthonormal basis Q of X (H = QQᵀ) in O(n·k·p + n·p²) time and O(n·p) memory:
//     tr(MW)     = tr(W) − tr(QᵀWQ)
//     tr(MWMWᵀ)  = ‖W‖² − ‖WQ‖² − ‖WᵀQ‖² + ‖QᵀWQ‖²
//     tr((MW)²)  = tr(WW) − 2 Σ (WᵀQ)∘(WQ) + tr((QᵀWQ)²)
//   No n × n dense matrix is ever formed. Q comes from CholeskyQR2 on the column-equilibrated design
//   (falling back to a column-pivoting Householder QR when the design is ill-conditioned or rank
//   deficient); tests/metrology/morans_i_test.cc checks I, E[I], Var[I] against the dense formulas
//   to 1e-12, bench/moran_bench.cc times n = 100,000, p = 100.
// LocalMoranI: local Moran I_i (LISA, Anselin 1995) with conditional-permutation pseudo p-values and
//   the exact conditional-randomisation moments (Sokal, Oden & Thomson 1998, eqs. A7–A8), and
//   the HH/LL/HL/LH cluster map at a significance alpha.
//
// Islands: every function takes an IslandPolicy (metrology/spatial_weights.h) and reports what it did.

#include <cstdint>
#include <string>
#include <vector>

#include <Eigen/Core>
#include <nlohmann/json.hpp>

#include "core/status.h"
#include "metrology/spatial_weights.h"

namespace formloop::metrology {

// One-sided critical value at significance 0.01 (the seed rounds it to 2.33).
inline constexpr double kMoranZCritical = 2.326;

// What an island policy did, for the result's report.
struct IslandReport {
  IslandPolicy policy = IslandPolicy::kRefuse;
  int islands = 0;           // islands in the weights as given
  std::vector<int> dropped;  // 0-based rows removed (kDrop)
  nlohmann::json ToJson() const;
};

struct MoranOptions {
  IslandPolicy islands = IslandPolicy::kRefuse;
  // Random permutations of the values for the pseudo p-value; 0 = no permutation test. PySAL's
  // default is 999 (p resolution 0.001).
  int permutations = 0;
  std::uint64_t seed = 1;  // core/random.h stream of the permutations
};

// Permutation test of a global I (as PySAL esda.Moran): `larger` counts the permuted I ≥ the observed
// one, folded to the smaller tail (if N − larger < larger, larger = N − larger), and
// p_sim = (larger + 1)/(N + 1). mean/sd (population sd) of the permuted I give z_sim and the
// folded normal tail p_z_sim.
struct PermutationTest {
  int permutations = 0;
  std::uint64_t seed = 0;
  int larger = 0;
  double p_sim = 1;
  double mean = 0;
  double sd = 0;
  double z_sim = 0;
  double p_z_sim = 1;
  nlohmann::json ToJson() const;
};

struct MoranResult {
  int n = 0;  // values used (n of the formulas; islands included under kZero)
  double i = 0;
  double expected = 0;  // E[I] = −1/(n − 1)
  double variance_normality = 0;
  double variance_randomisation = 0;
  double z_normality = 0;
  double z_randomisation = 0;
  double p_normality = 0;  // one-sided, upper tail
  double p_randomisation = 0;
  double s0 = 0, s1 = 0, s2 = 0;  // weight sums of the formulas
  IslandReport islands;
  PermutationTest permutation;  // permutations == 0 when not run
  nlohmann::json ToJson() const;
};

// values: n; weights: n × n. With options.islands == kDrop the result's n counts the values kept.
Result<MoranResult> MoranI(const Eigen::VectorXd& values, const SpatialWeights& weights,
                           const MoranOptions& options = {});

struct ResidualMoranResult {
  int n = 0;
  int p = 0;  // rank of the design
  double i = 0;
  double expected = 0;
  double variance = 0;
  double z = 0;
  double p_value = 0;            // one-sided, upper tail
  Eigen::VectorXd coefficients;  // least-squares coefficients of the design columns
  Eigen::VectorXd residuals;     // e = y − Xβ (over the rows used)
  IslandReport islands;
  nlohmann::json ToJson() const;
};

// y: n; design: n × p (include a constant column for a mean); weights n × n. A rank-deficient design
// is handled (p is the numerical rank; coefficients are a basic solution).
Result<ResidualMoranResult> ResidualMoranI(const Eigen::VectorXd& y, const Eigen::MatrixXd& design,
                                           const SpatialWeights& weights, IslandPolicy islands = IslandPolicy::kRefuse);

// LISA cluster labels; the numbers are PySAL esda's quadrants q (1 HH, 2 LH, 3 LL, 4 HL).
enum class LisaCluster {
  kNotSignificant = 0,
  kHighHigh = 1,
  kLowHigh = 2,
  kLowLow = 3,
  kHighLow = 4,
  kIsland = 5,  // no neighbours (kZero) or dropped (kDrop): no local statistic
};
const char* LisaClusterName(LisaCluster cluster);  // "HH", "LH", "LL", "HL", "not significant", "island"

struct LocalMoranOptions {
  IslandPolicy islands = IslandPolicy::kRefuse;
  // Conditional permutations per point (esda's default 999); 0 = analytical p-values only.
  int permutations = 999;
  std::uint64_t seed = 1;
  // A point is significant when its p-value < alpha (esda/splot's lisa_cluster convention). The
  // p-value is the permutation p_sim when permutations > 0, else the analytical p.
  double alpha = 0.05;
};

// Local Moran (Anselin 1995), scaled like PySAL esda.Moran_Local:
//   z_i = y_i − ȳ,  I_i = (n − 1) z_i Σ_j w_ij z_j / Σ_k z_k²
// (Anselin's m2 = Σ z²/n replaced by Σ z²/(n − 1)). Σ_i I_i = (n − 1)/n · S0 · I.
// Conditional randomisation (z_i fixed, the other n − 1 values permuted), with c = (n − 1)/Σz²,
// w_i = Σ_j w_ij, w_i(2) = Σ_j w_ij² and s_i² the population variance of {z_k : k ≠ i}:
//   E[I_i]   = −c z_i² w_i / (n − 1)
//   Var[I_i] = c² z_i² s_i² (n − 1)/(n − 2) · (w_i(2) − w_i²/(n − 1))
// (Sokal et al. 1998, A7–A8), exact for that null; z_i = (I_i − E)/√Var, p_i = 1 − Φ(|z_i|).
// Permutation p_sim per point as esda: folded count of conditionally permuted I_i ≥ I_i.
// Arrays have one entry per input row; dropped rows (kDrop) and zero rows (kZero) hold NaN
// statistics, p = 1 and LisaCluster::kIsland.
struct LocalMoranResult {
  int n = 0;                     // values used
  Eigen::VectorXd i;             // I_i
  Eigen::VectorXd lag;           // Σ_j w_ij z_j
  Eigen::VectorXd expected;      // E[I_i], conditional randomisation
  Eigen::VectorXd variance;      // Var[I_i], conditional randomisation
  Eigen::VectorXd z;             // (I_i − E)/√Var
  Eigen::VectorXd p_analytical;  // 1 − Φ(|z_i|)
  Eigen::VectorXd p_sim;         // permutation pseudo p (NaN when permutations == 0)
  std::vector<int> quadrant;     // 1 HH, 2 LH, 3 LL, 4 HL (0 for islands)
  std::vector<LisaCluster> cluster;
  int permutations = 0;
  std::uint64_t seed = 0;
  double alpha = 0.05;
  IslandReport islands;
  // Summary (counts per cluster, settings); the per-point arrays go to a table, not JSON.
  nlohmann::json SummaryJson() const;
};

Result<LocalMoranResult> LocalMoranI(const Eigen::VectorXd& values, const SpatialWeights& weights,
                                     const LocalMoranOptions& options = {});

// The spatial lag of the centred values, Σ_j w_ij (y_j − ȳ), one per row, in the values' unit: the
// y-axis of the Moran scatter plot (LocalMoranResult::lag of the same values). Islands are refused.
Result<Eigen::VectorXd> SpatialLag(const Eigen::VectorXd& values, const SpatialWeights& weights);

// Upper-tail probability of the standard normal.
double NormalUpperTail(double z);

}  // namespace formloop::metrology
