#include "nc-gen/deviation_field.h"

#include <algorithm>
#include <cmath>
#include <map>
#include <tuple>
#include <utility>

#include <Eigen/Dense>

#include "core/atomic_file.h"
#include "core/csv.h"
#include "core/number_text.h"

namespace formloop::nc {
namespace {

double Kernel(double r2) { return r2 > 0 ? 0.5 * r2 * std::log(r2) : 0.0; }  // r² log r

}  // namespace

Status DeviationFieldOptions::Validate() const {
  if (!(smoothing >= 0) || !std::isfinite(smoothing)) {
    return Status::BadInput(Where{.field = "deviation_field.smoothing"}, "must be a finite number >= 0");
  }
  return Status::Ok();
}

Eigen::Vector2d DeviationField::Scaled(double u, double v) const { return (Eigen::Vector2d(u, v) - centre_) / scale_; }

Result<DeviationField> DeviationField::Fit(const std::vector<DeviationSample>& samples,
                                           const DeviationFieldOptions& options, const std::string& source) {
  FL_RETURN_IF_ERROR(options.Validate());
  const std::size_t n = samples.size();
  if (n > kMaxDeviationSamples) {
    return Status::BadInput(
        Where{.file = source},
        std::to_string(n) + " samples exceed the dense solver's limit of " + std::to_string(kMaxDeviationSamples),
        "thin the samples (or average them on a grid) before building the field");
  }
  if (n < 3) {
    return Status::BadInput(Where{.file = source},
                            "a deviation field needs at least 3 samples, got " + std::to_string(n));
  }
  for (const auto& s : samples) {
    if (!std::isfinite(s.u) || !std::isfinite(s.v) || !std::isfinite(s.ds_um)) {
      return Status::BadInput(Where{.file = source, .line = s.line}, "sample is not finite");
    }
  }
  if (options.smoothing == 0) {
    std::map<std::pair<double, double>, long> seen;
    for (const auto& s : samples) {
      const auto [it, inserted] = seen.emplace(std::make_pair(s.u, s.v), s.line);
      if (!inserted) {
        return Status::BadInput(Where{.file = source, .line = s.line},
                                "sample at (u, v) = (" + FormatExact(s.u) + ", " + FormatExact(s.v) +
                                    ") repeats the one on line " + std::to_string(it->second),
                                "remove or average repeated points, or use a smoothing > 0");
      }
    }
  }
  DeviationField f;
  Eigen::Vector2d lo(samples[0].u, samples[0].v), hi = lo;
  for (const auto& s : samples) {
    lo = lo.cwiseMin(Eigen::Vector2d(s.u, s.v));
    hi = hi.cwiseMax(Eigen::Vector2d(s.u, s.v));
  }
  f.centre_ = 0.5 * (lo + hi);
  f.scale_ = std::max(0.5 * (hi - lo).maxCoeff(), 1e-300);
  f.centres_.resize(static_cast<Eigen::Index>(n), 2);
  const auto ni = static_cast<Eigen::Index>(n);
  Eigen::MatrixXd a = Eigen::MatrixXd::Zero(ni + 3, ni + 3);
  Eigen::VectorXd rhs = Eigen::VectorXd::Zero(ni + 3);
  for (Eigen::Index i = 0; i < ni; ++i) {
    f.centres_.row(i) = f.Scaled(samples[i].u, samples[i].v).transpose();
  }
  for (Eigen::Index i = 0; i < ni; ++i) {
    for (Eigen::Index j = 0; j < i; ++j) {
      a(i, j) = a(j, i) = Kernel((f.centres_.row(i) - f.centres_.row(j)).squaredNorm());
    }
    a(i, i) = options.smoothing;
    a(i, ni) = a(ni, i) = 1;
    a(i, ni + 1) = a(ni + 1, i) = f.centres_(i, 0);
    a(i, ni + 2) = a(ni + 2, i) = f.centres_(i, 1);
    rhs(i) = samples[i].ds_um;
  }
  // The linear part needs three samples not on one line.
  Eigen::MatrixXd p = a.block(0, ni, ni, 3);
  Eigen::FullPivLU<Eigen::MatrixXd> plu(p);
  plu.setThreshold(1e-9);
  if (plu.rank() < 3) {
    return Status::BadInput(Where{.file = source}, "the samples lie on one line in (u, v)",
                            "add samples off that line");
  }
  const Eigen::VectorXd x = a.partialPivLu().solve(rhs);
  if (!x.allFinite() || (a * x - rhs).norm() > 1e-6 * (1 + rhs.norm())) {
    return Status::BadInput(Where{.file = source}, "the thin-plate-spline system is singular or ill-conditioned",
                            "remove near-duplicate samples or use a smoothing > 0");
  }
  f.weights_ = x.head(ni);
  f.linear_ = x.tail(3);
  return f;
}

double DeviationField::EvaluateUm(double u, double v) const {
  const Eigen::Vector2d p = Scaled(u, v);
  double value = linear_[0] + linear_[1] * p.x() + linear_[2] * p.y();
  for (Eigen::Index i = 0; i < centres_.rows(); ++i) {
    value += weights_[i] * Kernel((centres_.row(i).transpose() - p).squaredNorm());
  }
  return value;
}

SystematicField DeviationField::AsSystematicField() const {
  return [field = *this](double u, double v) { return field.EvaluateMm(u, v); };
}

Result<std::vector<DeviationSample>> ReadDeviationSamples(const std::filesystem::path& path) {
  FL_ASSIGN_OR_RETURN(std::string text, ReadTextFile(path));
  const std::string file = path.string();
  CsvReader rows(text);
  long number = 0;
  int col_u = -1, col_v = -1, col_ds = -1;
  std::size_t columns = 0;
  std::vector<DeviationSample> samples;
  while (rows.Next()) {
    number = rows.line_number();
    const std::vector<std::string> cells(rows.cells().begin(), rows.cells().end());
    if (columns == 0) {
      for (std::size_t c = 0; c < cells.size(); ++c) {
        if (cells[c] == "u") col_u = static_cast<int>(c);
        if (cells[c] == "v") col_v = static_cast<int>(c);
        if (cells[c] == "ds_um") col_ds = static_cast<int>(c);
      }
      for (auto [col, name] : {std::pair{col_u, "u"}, std::pair{col_v, "v"}, std::pair{col_ds, "ds_um"}}) {
        if (col < 0) {
          return Status::BadInput(Where{.file = file, .line = number, .field = name}, "header lacks the column",
                                  "the header must name the columns u, v, ds_um");
        }
      }
      columns = cells.size();
      continue;
    }
    if (cells.size() != columns) {
      return Status::BadInput(Where{.file = file, .line = number},
                              "has " + std::to_string(cells.size()) + " fields, the header " + std::to_string(columns));
    }
    DeviationSample s;
    s.line = number;
    for (auto [col, name, out] :
         {std::tuple{col_u, "u", &s.u}, std::tuple{col_v, "v", &s.v}, std::tuple{col_ds, "ds_um", &s.ds_um}}) {
      const std::string& cell = cells[static_cast<std::size_t>(col)];
      if (!ParseDouble(cell, out) || !std::isfinite(*out)) {
        return Status::BadInput(Where{.file = file, .line = number, .field = name},
                                "value '" + cell + "' is not a finite number");
      }
    }
    samples.push_back(s);
  }
  if (columns == 0) return Status::BadInput(Where{.file = file}, "no header row", "start with the row u,v,ds_um");
  if (samples.empty()) return Status::BadInput(Where{.file = file}, "no samples after the header");
  return samples;
}

Result<DeviationField> ReadDeviationField(const std::filesystem::path& path, const DeviationFieldOptions& options) {
  FL_ASSIGN_OR_RETURN(std::vector<DeviationSample> samples, ReadDeviationSamples(path));
  return DeviationField::Fit(samples, options, path.string());
}

}  // namespace formloop::nc
