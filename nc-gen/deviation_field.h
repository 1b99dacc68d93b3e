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
// Limits: the dense LU solve costs O(n³) time and (n+3)² doubles of memory, so at most
// kMaxDeviationSamples points are accepted (3000: about 72 MB and a few seconds); more is refused with
// a BadInput naming the count and the fix (thin the samples or smooth them first). At least three
// samples not on one line are needed; with λ = 0 two samples at the same (u, v) are refused (lines named).
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

 private:
  Eigen::Vector2d Scaled(double u, double v) const;
  Eigen::MatrixX2d centres_;                          // scaled data points
  Eigen::VectorXd weights_;                           // kernel weights w_i
  Eigen::Vector3d linear_ = Eigen::Vector3d::Zero();  // a_0, a_1, a_2 (scaled coordinates)
  Eigen::Vector2d centre_ = Eigen::Vector2d::Zero();
  double scale_ = 1;
};

// Reads u, v, ds_um from a CSV file (format above).
Result<std::vector<DeviationSample>> ReadDeviationSamples(const std::filesystem::path& path);
// ReadDeviationSamples + DeviationField::Fit.
Result<DeviationField> ReadDeviationField(const std::filesystem::path& path, const DeviationFieldOptions& options = {});

}  // namespace formloop::nc
