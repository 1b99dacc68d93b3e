#include "nc-gen/deviation_field.h"

#include <algorithm>
#include <cmath>
#include <map>
#include <memory>
#include <tuple>
#include <utility>

#include <Eigen/Dense>

#include "core/atomic_file.h"
#include "core/csv.h"
#include "core/number_text.h"
#include "core/parallel.h"
#include "core/random.h"

namespace formloop::nc {
namespace {

double Kernel(double r2) { return r2 > 0 ? 0.5 * r2 * std::log(r2) : 0.0; }  // r² log r

// [K + λI, P; Pᵀ, 0] [w; a] = [d; 0] (P of rank 3) by the null-space method (Wendland, "Scattered Data
// Approximation", §8.5; Golub & Van Loan §12.1.4): with P = Q [R; 0] (Householder) and Z the last n − 3
// columns of Q, Pᵀw = 0 means w = Z γ, and Zᵀ(K + λI)Z γ = Zᵀ d. φ = r² log r is conditionally positive
// definite of order 2, so that matrix is positive definite for distinct points (λ ≥ 0 keeps it so) and a
// Cholesky factorisation solves it in half the work of an LU of the whole system; then R a = Q₁ᵀ(d − (K + λI)w).
// A failed factorisation (numerically not positive definite) falls back to the pivoted LU of the whole system.
Eigen::VectorXd SolveThinPlate(const Eigen::MatrixXd& a, const Eigen::VectorXd& rhs, Eigen::Index n) {
  const Eigen::HouseholderQR<Eigen::MatrixXd> qr(a.block(0, n, n, 3));
  Eigen::MatrixXd b = a.topLeftCorner(n, n);
  b.applyOnTheLeft(qr.householderQ().adjoint());
  b.applyOnTheRight(qr.householderQ());
  Eigen::VectorXd qd = rhs.head(n);
  qd.applyOnTheLeft(qr.householderQ().adjoint());
  Eigen::Ref<Eigen::MatrixXd> zkz = b.bottomRightCorner(n - 3, n - 3);
  const Eigen::LLT<Eigen::Ref<Eigen::MatrixXd>, Eigen::Lower> llt(zkz);  // in place: no third n × n matrix
  if (llt.info() != Eigen::Success) return a.partialPivLu().solve(rhs);
  Eigen::VectorXd zg = Eigen::VectorXd::Zero(n);
  zg.tail(n - 3) = llt.solve(qd.tail(n - 3));
  Eigen::VectorXd x(n + 3);
  x.head(n) = qr.householderQ() * zg;  // w = Z γ
  Eigen::VectorXd r = rhs.head(n) - a.topLeftCorner(n, n).selfadjointView<Eigen::Lower>() * x.head(n);
  r.applyOnTheLeft(qr.householderQ().adjoint());
  x.tail(3) = qr.matrixQR().topLeftCorner(3, 3).triangularView<Eigen::Upper>().solve(r.head(3));
  return x;
}

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
  const Eigen::VectorXd x = SolveThinPlate(a, rhs, ni);
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

SystematicField DeviationField::AsSystematicField(std::size_t evaluations, double* tabulated_error_um) const {
  if (tabulated_error_um) *tabulated_error_um = -1;
  if (static_cast<double>(evaluations) * static_cast<double>(size()) > kTabulateAboveKernelEvaluations) {
    auto table = Tabulate();
    if (table.ok()) {
      if (tabulated_error_um) *tabulated_error_um = table->measured_error_um();
      return [t = std::make_shared<const TabulatedDeviationField>(*std::move(table))](double u, double v) {
        return t->EvaluateMm(u, v);
      };
    }
  }
  return AsSystematicField();
}

namespace {

// φ(r) = r² log r with its derivatives, from d = p − c: φ_x = d_x (log s + 1), φ_y = d_y (log s + 1),
// φ_xy = 2 d_x d_y / s (s = |d|²; all zero at s = 0, where the two sides of a subtraction cancel).
struct KernelJet {
  double f = 0, fx = 0, fy = 0, fxy = 0;
};
KernelJet Jet(double dx, double dy) {
  const double s = dx * dx + dy * dy;
  if (!(s > 0)) return {};
  const double l = std::log(s);
  return {0.5 * s * l, dx * (l + 1), dy * (l + 1), 2 * dx * dy / s};
}

// Cubic Hermite basis on [0, 1]: value at 0, value at 1, slope at 0, slope at 1.
void Hermite(double t, double* b) {
  const double t2 = t * t, t3 = t2 * t;
  b[0] = 2 * t3 - 3 * t2 + 1;
  b[1] = -2 * t3 + 3 * t2;
  b[2] = t3 - 2 * t2 + t;
  b[3] = t3 - t2;
}

// The near block: cells within 5 of a point's cell (11 × 11). The interpolation error of a far centre
// at distance r >= 5h is about |w| h^4 / (192 r^2) <= |w| h^2 / 4800 (the kernel's fourth derivative is
// -2/r^2): with ~3.3 sqrt(n) cells per side (about 0.2 centres per cell) it stays inside the tolerance
// at ~25 exact terms per point.
constexpr int kNear = 5;

}  // namespace

Result<TabulatedDeviationField> DeviationField::Tabulate() const {
  const int base = static_cast<int>(std::ceil(3.3 * std::sqrt(static_cast<double>(size()))));
  for (int cells = std::max(base, 16), attempt = 0; attempt < 2; ++attempt, cells = cells * 3 / 2) {
    FL_ASSIGN_OR_RETURN(TabulatedDeviationField table, TabulatedDeviationField::Build(*this, cells));
    if (table.measured_error_um() <= kTabulatedToleranceUm) return table;
  }
  return Status::Failed("the tabulated deviation field misses its " + FormatExact(kTabulatedToleranceUm) +
                        " um tolerance; the direct sum is used");
}

Result<TabulatedDeviationField> TabulatedDeviationField::Build(const DeviationField& field, int cells) {
  TabulatedDeviationField t;
  t.field_ = field;
  t.cells_ = cells;
  // The centres lie in [−1, 1]² (scaled coordinates); the grid adds a quarter of that on each side.
  t.x0_ = t.y0_ = -1.5;
  t.h_ = 3.0 / cells;
  const long n = static_cast<long>(field.size());
  const long c2 = static_cast<long>(cells) * cells;
  auto cell_index = [&](double value) {
    return std::clamp(static_cast<long>(std::floor((value + 1.5) / t.h_)), 0L, static_cast<long>(cells) - 1);
  };
  // Centres by cell, then each cell's near block.
  std::vector<std::vector<int>> in_cell(static_cast<std::size_t>(c2));
  for (long i = 0; i < n; ++i) {
    const long cx = cell_index(field.centres_(i, 0)), cy = cell_index(field.centres_(i, 1));
    in_cell[static_cast<std::size_t>(cy * cells + cx)].push_back(static_cast<int>(i));
  }
  t.near_start_.assign(static_cast<std::size_t>(c2) + 1, 0);
  for (long cy = 0; cy < cells; ++cy) {
    for (long cx = 0; cx < cells; ++cx) {
      for (long by = std::max(0L, cy - kNear); by <= std::min<long>(cells - 1, cy + kNear); ++by) {
        for (long bx = std::max(0L, cx - kNear); bx <= std::min<long>(cells - 1, cx + kNear); ++bx) {
          const auto& list = in_cell[static_cast<std::size_t>(by * cells + bx)];
          t.near_.insert(t.near_.end(), list.begin(), list.end());
        }
      }
      t.near_start_[static_cast<std::size_t>(cy * cells + cx) + 1] = static_cast<int>(t.near_.size());
    }
  }
  // The whole kernel sum and its derivatives at every node.
  const long nodes_per_side = cells + 1;
  std::vector<KernelJet> node(static_cast<std::size_t>(nodes_per_side * nodes_per_side));
  ParallelFor(static_cast<long>(node.size()), 64, [&](long begin, long end) {
    for (long k = begin; k < end; ++k) {
      const double x = t.x0_ + static_cast<double>(k % nodes_per_side) * t.h_;
      const double y = t.y0_ + static_cast<double>(k / nodes_per_side) * t.h_;
      KernelJet sum;
      for (long i = 0; i < n; ++i) {
        const KernelJet j = Jet(x - field.centres_(i, 0), y - field.centres_(i, 1));
        const double w = field.weights_[i];
        sum.f += w * j.f;
        sum.fx += w * j.fx;
        sum.fy += w * j.fy;
        sum.fxy += w * j.fxy;
      }
      node[static_cast<std::size_t>(k)] = sum;
    }
  });
  // Per cell: the corners' far sum (the whole sum less the near block), scaled for the Hermite basis.
  t.patches_.resize(static_cast<std::size_t>(c2) * 16);
  ParallelFor(c2, 256, [&](long begin, long end) {
    for (long c = begin; c < end; ++c) {
      const long cx = c % cells, cy = c / cells;
      for (int corner = 0; corner < 4; ++corner) {
        const long nx = cx + (corner & 1), ny = cy + (corner >> 1);
        const double x = t.x0_ + static_cast<double>(nx) * t.h_, y = t.y0_ + static_cast<double>(ny) * t.h_;
        KernelJet far = node[static_cast<std::size_t>(ny * nodes_per_side + nx)];
        for (int s = t.near_start_[static_cast<std::size_t>(c)]; s < t.near_start_[static_cast<std::size_t>(c) + 1];
             ++s) {
          const int i = t.near_[static_cast<std::size_t>(s)];
          const KernelJet j = Jet(x - field.centres_(i, 0), y - field.centres_(i, 1));
          const double w = field.weights_[i];
          far.f -= w * j.f;
          far.fx -= w * j.fx;
          far.fy -= w * j.fy;
          far.fxy -= w * j.fxy;
        }
        double* out = &t.patches_[static_cast<std::size_t>(c) * 16 + static_cast<std::size_t>(corner) * 4];
        out[0] = far.f;
        out[1] = t.h_ * far.fx;
        out[2] = t.h_ * far.fy;
        out[3] = t.h_ * t.h_ * far.fxy;
      }
    }
  });
  // The measured error: the centre (the farthest point from the corners) of every third cell in each
  // direction and seeded random points over the samples' box.
  std::vector<Eigen::Vector2d> checks;
  for (long cy = 1; cy < cells; cy += 3) {
    for (long cx = 1; cx < cells; cx += 3) {
      checks.emplace_back(t.x0_ + (static_cast<double>(cx) + 0.5) * t.h_,
                          t.y0_ + (static_cast<double>(cy) + 0.5) * t.h_);
    }
  }
  Rng rng(26);
  for (int m = 0; m < 2000; ++m) checks.emplace_back(2 * rng.Uniform() - 1, 2 * rng.Uniform() - 1);
  std::vector<double> error(checks.size());
  ParallelFor(static_cast<long>(checks.size()), 64, [&](long begin, long end) {
    for (long m = begin; m < end; ++m) {
      const Eigen::Vector2d p = field.centre_ + field.scale_ * checks[static_cast<std::size_t>(m)];
      error[static_cast<std::size_t>(m)] = std::abs(t.EvaluateUm(p.x(), p.y()) - field.EvaluateUm(p.x(), p.y()));
    }
  });
  t.measured_error_um_ = *std::max_element(error.begin(), error.end());
  return t;
}

double TabulatedDeviationField::FarUm(long cell, double x, double y) const {
  const double tx = (x - (x0_ + static_cast<double>(cell % cells_) * h_)) / h_;
  const double ty = (y - (y0_ + static_cast<double>(cell / cells_) * h_)) / h_;
  double bx[4], by[4];
  Hermite(tx, bx);
  Hermite(ty, by);
  const double* p = &patches_[static_cast<std::size_t>(cell) * 16];
  double sum = 0;
  for (int corner = 0; corner < 4; ++corner) {
    const int ax = corner & 1, ay = corner >> 1;
    const double* q = p + corner * 4;
    sum += q[0] * bx[ax] * by[ay] + q[1] * bx[2 + ax] * by[ay] + q[2] * bx[ax] * by[2 + ay] +
           q[3] * bx[2 + ax] * by[2 + ay];
  }
  return sum;
}

double TabulatedDeviationField::EvaluateUm(double u, double v) const {
  const Eigen::Vector2d p = field_.Scaled(u, v);
  const double gx = (p.x() - x0_) / h_, gy = (p.y() - y0_) / h_;
  if (!(gx >= 0 && gy >= 0 && gx < cells_ && gy < cells_)) return field_.EvaluateUm(u, v);  // off the grid
  const long cell = static_cast<long>(gy) * cells_ + static_cast<long>(gx);
  double value = field_.linear_[0] + field_.linear_[1] * p.x() + field_.linear_[2] * p.y() + FarUm(cell, p.x(), p.y());
  for (int s = near_start_[static_cast<std::size_t>(cell)]; s < near_start_[static_cast<std::size_t>(cell) + 1]; ++s) {
    const int i = near_[static_cast<std::size_t>(s)];
    value += field_.weights_[i] * Kernel((field_.centres_.row(i).transpose() - p).squaredNorm());
  }
  return value;
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
