#pragma once
// A smooth systematic deviation field d_s(u, v) interpolated from scattered values (spec/nc-gen.md §4,
// metrology.md §7): a thin-plate spline in the parameter plane with a linear polynomial part,
//
//   d_s(u, v) = Σ_i w_i φ(|p − p_i|) + a_0 + a_1 û + a_2 v̂,   φ(r) = r² log r,
//
// where p = (û, v̂) are (u, v) centred on the data and scaled by the larger half-extent of their
// bounding box (conditioning only: the TPS with a linear part is invariant under this change). The
// weights solve the dense system [K + λ I, P; Pᵀ, 0] [w; a] = [d; 0]:
//   λ = 0  interpolates: exact at every data point;
//   λ > 0  smooths (in the scaled coordinates, data in µm); λ → ∞ tends to the least-squares plane.
// Any linear field a + b u + c v is reproduced exactly for every λ (the kernel part is then zero).
//
// Limits: the dense solve (a Cholesky factorisation on the null space of Pᵀ, SolveThinPlate in
// deviation_field.cc) costs O(n³) time and two n × n matrices of doubles, so at most
// kMaxDeviationSamples points are accepted (3000: 72 MB a matrix and a few seconds); more is refused with
// a BadInput naming the count and the fix (thin the samples or smooth them first). At least three
// samples not on one line are needed; with λ = 0 two samples at the same (u, v) are refused (lines named).
//
// Fast evaluation (Tabulate): the field is evaluated at millions of cutter locations, where the direct
// sum costs n kernel evaluations (logarithms) per point. The tabulated field splits the sum per cell of a
// uniform grid over the samples' box (a quarter of its extent added on each side, about 3.3 √n cells per
// side): the centres in the 11 × 11 cells around a point's cell are summed exactly, the rest — smooth
// there, its nearest centre at least five cells away — comes from a bicubic Hermite patch of that cell
// (values, gradients and cross derivatives of the far sum at its corners, exact from the kernel's
// derivatives), and the linear part is added exactly. The interpolation error is measured when the
// table is built, against the direct sum at the centres of every third cell in each direction and at
// seeded random points: it must be ≤ kTabulatedToleranceUm (the grid is refined once by 1.5 otherwise,
// then Tabulate fails and callers keep the direct sum). Points outside the grid are summed directly.
//
// CSV (ReadDeviationSamples): a header row naming the columns, ',' separated; lines starting with '#'
// and blank lines are comments. Columns u, v, ds_um are required (parameters of the CC point on Q and
// the systematic deviation in µm, positive = material left); any other column is ignored. Errors name
// file, line and field.

#include <cstddef>
#include <filesystem>
#include <string>
#include <vector>

#include <Eigen/Core>

#include "core/status.h"
#include "nc-gen/compensation.h"

namespace formloop::nc {

inline constexpr std::size_t kMaxDeviationSamples = 3000;
// The largest difference from the direct sum a tabulated field may have (µm): 1 nm, a hundredth of the
// 0.1 µm a program's four decimals resolve.
inline constexpr double kTabulatedToleranceUm = 1e-3;

class TabulatedDeviationField;

struct DeviationSample {
  double u = 0, v = 0;
  double ds_um = 0;
  long line = 0;  // 1-based line in the file it came from (0 = not from a file); used in messages
};

struct DeviationFieldOptions {
  double smoothing = 0;  // λ ≥ 0, see above
  Status Validate() const;
};

class DeviationField {
 public:
  // `source` names the samples in messages (a path, "loop 2 decomposition").
  static Result<DeviationField> Fit(const std::vector<DeviationSample>& samples, const DeviationFieldOptions& options,
                                    const std::string& source = "deviation samples");

  double EvaluateUm(double u, double v) const;
  double EvaluateMm(double u, double v) const { return 1e-3 * EvaluateUm(u, v); }
  // d_s in mm, as CompensateToolpath and CheckCompensation take it. The field is copied into it.
  SystematicField AsSystematicField() const;
  std::size_t size() const { return centres_.rows(); }

  // The tabulated field (above); Failed when its measured error exceeds kTabulatedToleranceUm.
  Result<TabulatedDeviationField> Tabulate() const;
  // d_s in mm for `evaluations` points to come: the tabulated field when the direct sum would cost more
  // than kTabulateAboveKernelEvaluations kernel evaluations and the table meets its tolerance, else the
  // direct sum. *tabulated_error_um (when given) is the table's measured error, or −1 for the direct sum.
  SystematicField AsSystematicField(std::size_t evaluations, double* tabulated_error_um = nullptr) const;
  static constexpr double kTabulateAboveKernelEvaluations = 2e8;

 private:
  friend class TabulatedDeviationField;
  Eigen::Vector2d Scaled(double u, double v) const;
  Eigen::MatrixX2d centres_;                          // scaled data points
  Eigen::VectorXd weights_;                           // kernel weights w_i
  Eigen::Vector3d linear_ = Eigen::Vector3d::Zero();  // a_0, a_1, a_2 (scaled coordinates)
  Eigen::Vector2d centre_ = Eigen::Vector2d::Zero();
  double scale_ = 1;
};

class TabulatedDeviationField {
 public:
  double EvaluateUm(double u, double v) const;
  double EvaluateMm(double u, double v) const { return 1e-3 * EvaluateUm(u, v); }
  double measured_error_um() const { return measured_error_um_; }  // max |table − direct sum| at the checks
  int cells_per_side() const { return cells_; }

 private:
  friend class DeviationField;
  static Result<TabulatedDeviationField> Build(const DeviationField& field, int cells);
  double FarUm(long cell, double x, double y) const;

  DeviationField field_;
  double x0_ = 0, y0_ = 0, h_ = 1;  // grid origin and cell size (scaled coordinates)
  int cells_ = 0;                   // cells per side
  std::vector<double> patches_;  // per cell, per corner (00, 10, 01, 11): f, h·f_x, h·f_y, h²·f_xy of the far sum
  std::vector<int> near_start_, near_;  // per cell: the centres in its 5 × 5 block (CSR)
  double measured_error_um_ = 0;
};

// Reads u, v, ds_um from a CSV file (format above).
Result<std::vector<DeviationSample>> ReadDeviationSamples(const std::filesystem::path& path);
// ReadDeviationSamples + DeviationField::Fit.
Result<DeviationField> ReadDeviationField(const std::filesystem::path& path, const DeviationFieldOptions& options = {});

}  // namespace formloop::nc
