#include "metrology/decomposition.h"

#include <Eigen/Cholesky>
#include <algorithm>
#include <cmath>
#include <limits>
#include <numeric>
#include <optional>

#include "core/number_text.h"
#include "metrology/spatial_cv.h"

namespace formloop::metrology {
namespace {

// Fewest points a decomposition accepts: the constant model with k = 8 neighbours and 10 CV folds
// needs a sample on which Moran's normal approximation and a held-out error mean something.
constexpr int kMinimumPoints = 20;
constexpr int kSplineDegree = 3;
// Relative weight of the CV fits' second-difference penalty (see the header).
constexpr double kCvPenalty = 1e-6;
// Two-sided 0.01 quantile for the constant offset's significance.
constexpr double kOffsetZ = 2.576;

// Legendre P_0..P_degree at x ∈ [−1, 1] by the three-term recurrence.
void Legendre(int degree, double x, double* p) {
  p[0] = 1.0;
  if (degree >= 1) p[1] = x;
  for (int k = 2; k <= degree; ++k) p[k] = ((2.0 * k - 1.0) * x * p[k - 1] - (k - 1.0) * p[k - 2]) / k;
}

double Rms(const std::vector<double>& v) {
  double s = 0;
  for (double x : v) s += x * x;
  return v.empty() ? 0 : std::sqrt(s / static_cast<double>(v.size()));
}

double PeakAbs(const std::vector<double>& v) {
  double m = 0;
  for (double x : v) m = std::max(m, std::abs(x));
  return m;
}

std::string Num(double x) { return FormatSignificant(x, 4); }

Status CheckDomain(const recon::ParamDomain& d) {
  if (!std::isfinite(d.u_min) || !std::isfinite(d.u_max) || !std::isfinite(d.v_min) || !std::isfinite(d.v_max) ||
      !(d.u_span() > 0) || !(d.v_span() > 0)) {
    return Status::BadInput(Where{.field = "domain"},
                            "decomposition: the parameter domain [" + Num(d.u_min) + ", " + Num(d.u_max) + "] × [" +
                                Num(d.v_min) + ", " + Num(d.v_max) + "] is not a rectangle",
                            "pass the surface's domain with u_min < u_max and v_min < v_max");
  }
  return Status::Ok();
}

// Basis rows of a model at every point, sparse: row i has entries index[i*nnz + j], value[...].
struct Rows {
  int nnz = 0;
  std::vector<int> index;
  std::vector<double> value;
};

Rows BuildRows(const FieldModel& model, const Eigen::MatrixXd& uv) {
  Rows rows;
  std::vector<int> idx;
  std::vector<double> val;
  for (Eigen::Index i = 0; i < uv.cols(); ++i) {
    model.BasisRow(uv(0, i), uv(1, i), &idx, &val);
    rows.nnz = static_cast<int>(idx.size());
    rows.index.insert(rows.index.end(), idx.begin(), idx.end());
    rows.value.insert(rows.value.end(), val.begin(), val.end());
  }
  return rows;
}

Eigen::MatrixXd DenseDesign(const Rows& rows, int n, int p) {
  Eigen::MatrixXd x = Eigen::MatrixXd::Zero(n, p);
  for (int i = 0; i < n; ++i) {
    for (int j = 0; j < rows.nnz; ++j) {
      const std::size_t k =
          static_cast<std::size_t>(i) * static_cast<std::size_t>(rows.nnz) + static_cast<std::size_t>(j);
      x(i, rows.index[k]) += rows.value[k];
    }
  }
  return x;
}

// Second-difference penalty DᵀD on a net × net control net (index iu·net + iv), both directions.
Eigen::MatrixXd DifferencePenalty(int net) {
  const int p = net * net;
  Eigen::MatrixXd penalty = Eigen::MatrixXd::Zero(p, p);
  auto add = [&](int a, int b, int c) {
    const int idx[3] = {a, b, c};
    const double w[3] = {1.0, -2.0, 1.0};
    for (int r = 0; r < 3; ++r) {
      for (int s = 0; s < 3; ++s) penalty(idx[r], idx[s]) += w[r] * w[s];
    }
  };
  for (int a = 0; a < net; ++a) {
    for (int b = 1; b + 1 < net; ++b) {
      add((b - 1) * net + a, b * net + a, (b + 1) * net + a);  // along u
      add(a * net + b - 1, a * net + b, a * net + b + 1);      // along v
    }
  }
  return penalty;
}

// Spatial block CV of a model given its rows (metrology/spatial_cv.h): the fit on a fold's complement
// solves the normal equations by Cholesky, accumulated from the sparse rows, with the second-difference
// penalty for B-spline nets; fails when the training points cannot determine the model.
HeldOutErrors BlockCv(const Rows& rows, const Eigen::VectorXd& y, const std::vector<int>& fold, int folds, int p,
                      const Eigen::MatrixXd* penalty) {
  const auto nnz = static_cast<std::size_t>(rows.nnz);
  return SpatialBlockCv(fold, folds, y, [&](const std::vector<int>& training) -> std::optional<HeldOutPredictor> {
    Eigen::MatrixXd gram = Eigen::MatrixXd::Zero(p, p);
    Eigen::VectorXd rhs = Eigen::VectorXd::Zero(p);
    for (int i : training) {
      const std::size_t base = static_cast<std::size_t>(i) * nnz;
      for (std::size_t a = 0; a < nnz; ++a) {
        const int ia = rows.index[base + a];
        const double va = rows.value[base + a];
        rhs[ia] += va * y[i];
        for (std::size_t b = 0; b < nnz; ++b) gram(ia, rows.index[base + b]) += va * rows.value[base + b];
      }
    }
    if (static_cast<int>(training.size()) < p && penalty == nullptr) return std::nullopt;
    if (penalty != nullptr) gram += kCvPenalty * gram.trace() / penalty->trace() * *penalty;
    const Eigen::LLT<Eigen::MatrixXd> llt(gram);
    if (llt.info() != Eigen::Success) return std::nullopt;
    Eigen::VectorXd c = llt.solve(rhs);
    if (!c.allFinite()) return std::nullopt;
    return [&rows, nnz, c = std::move(c)](int i) {
      const std::size_t base = static_cast<std::size_t>(i) * nnz;
      double prediction = 0;
      for (std::size_t a = 0; a < nnz; ++a) prediction += rows.value[base + a] * c[rows.index[base + a]];
      return prediction;
    };
  });
}

// Blocks per direction when the options leave it to the data: about 4 points per block, so a held-out
// block is a gap of about two probe spacings (see the header).
int AutoBlocks(int n) {
  return std::clamp(static_cast<int>(std::lround(std::sqrt(static_cast<double>(n)) / 2.0)), 4, 50);
}

// The ladder of §7 in order: constant, plane, quadric, B-spline nets 4..max_control_net.
std::vector<FieldModel> Ladder(const recon::ParamDomain& domain, int max_control_net) {
  std::vector<FieldModel> ladder;
  for (int degree = 0; degree <= 2; ++degree) ladder.push_back(FieldModel::Polynomial(degree, domain).value());
  for (int net = kSplineDegree + 1; net <= max_control_net; ++net) {
    ladder.push_back(FieldModel::BSpline(net, domain).value());
  }
  return ladder;
}

}  // namespace

// ---------------------------------------------------------------------------------------------
// FieldModel

Result<FieldModel> FieldModel::Polynomial(int degree, const recon::ParamDomain& domain) {
  FL_RETURN_IF_ERROR(CheckDomain(domain));
  if (degree < 0 || degree > 2) {
    return Status::BadInput(Where{.field = "degree"}, "polynomial field of degree " + std::to_string(degree),
                            "use 0 (constant), 1 (plane) or 2 (quadric); richer fields are B-splines");
  }
  FieldModel m;
  m.kind_ = degree == 0 ? Kind::kConstant : degree == 1 ? Kind::kPlane : Kind::kQuadric;
  m.degree_ = degree;
  m.domain_ = domain;
  m.coefficients_ = Eigen::VectorXd::Zero(m.parameters());
  return m;
}

Result<FieldModel> FieldModel::BSpline(int net, const recon::ParamDomain& domain) {
  FL_RETURN_IF_ERROR(CheckDomain(domain));
  if (net < kSplineDegree + 1) {
    return Status::BadInput(
        Where{.field = "net"},
        "a bicubic control net of " + std::to_string(net) + " × " + std::to_string(net) + " is too small",
        "use at least 4 × 4");
  }
  FieldModel m;
  m.kind_ = Kind::kBSpline;
  m.degree_ = kSplineDegree;
  m.net_ = net;
  m.domain_ = domain;
  FL_ASSIGN_OR_RETURN(m.u_knots_, recon::KnotVector::Uniform(kSplineDegree, net, domain.u_min, domain.u_max));
  FL_ASSIGN_OR_RETURN(m.v_knots_, recon::KnotVector::Uniform(kSplineDegree, net, domain.v_min, domain.v_max));
  m.coefficients_ = Eigen::VectorXd::Zero(m.parameters());
  return m;
}

std::string FieldModel::name() const {
  switch (kind_) {
    case Kind::kConstant:
      return "constant";
    case Kind::kPlane:
      return "plane";
    case Kind::kQuadric:
      return "quadric";
    case Kind::kBSpline:
      return "bspline " + std::to_string(net_) + "x" + std::to_string(net_);
  }
  return "?";
}

int FieldModel::parameters() const { return kind_ == Kind::kBSpline ? net_ * net_ : (degree_ + 1) * (degree_ + 2) / 2; }

void FieldModel::BasisRow(double u, double v, std::vector<int>* index, std::vector<double>* value) const {
  u = std::clamp(u, domain_.u_min, domain_.u_max);
  v = std::clamp(v, domain_.v_min, domain_.v_max);
  index->clear();
  value->clear();
  if (kind_ != Kind::kBSpline) {
    double pu[3], pv[3];
    Legendre(degree_, 2.0 * (u - domain_.u_min) / domain_.u_span() - 1.0, pu);
    Legendre(degree_, 2.0 * (v - domain_.v_min) / domain_.v_span() - 1.0, pv);
    int k = 0;
    for (int total = 0; total <= degree_; ++total) {
      for (int i = total; i >= 0; --i) {
        index->push_back(k++);
        value->push_back(pu[i] * pv[total - i]);
      }
    }
    return;
  }
  const int su = u_knots_.FindSpan(u), sv = v_knots_.FindSpan(v);
  double nu[kSplineDegree + 1], nv[kSplineDegree + 1];
  u_knots_.BasisFunctions(su, u, nu);
  v_knots_.BasisFunctions(sv, v, nv);
  for (int a = 0; a <= kSplineDegree; ++a) {
    for (int b = 0; b <= kSplineDegree; ++b) {
      index->push_back((su - kSplineDegree + a) * net_ + (sv - kSplineDegree + b));
      value->push_back(nu[a] * nv[b]);
    }
  }
}

Eigen::VectorXd FieldModel::Basis(double u, double v) const {
  std::vector<int> index;
  std::vector<double> value;
  BasisRow(u, v, &index, &value);
  Eigen::VectorXd row = Eigen::VectorXd::Zero(parameters());
  for (std::size_t k = 0; k < index.size(); ++k) row[index[k]] += value[k];
  return row;
}

double FieldModel::Evaluate(double u, double v) const {
  std::vector<int> index;
  std::vector<double> value;
  BasisRow(u, v, &index, &value);
  double sum = 0;
  for (std::size_t k = 0; k < index.size(); ++k) sum += value[k] * coefficients_[index[k]];
  return sum;
}

Status FieldModel::SetCoefficients(const Eigen::VectorXd& coefficients_mm) {
  if (coefficients_mm.size() != parameters()) {
    return Status::BadInput(Where{.field = "coefficients"}, name() + " has " + std::to_string(parameters()) +
                                                                " coefficients, got " +
                                                                std::to_string(coefficients_mm.size()));
  }
  coefficients_ = coefficients_mm;
  return Status::Ok();
}

nlohmann::json FieldModel::ToJson() const {
  nlohmann::json j = {
      {"model", name()},
      {"parameters", parameters()},
      {"domain",
       {{"u_min", domain_.u_min}, {"u_max", domain_.u_max}, {"v_min", domain_.v_min}, {"v_max", domain_.v_max}}},
      {"coefficients_mm", std::vector<double>(coefficients_.data(), coefficients_.data() + coefficients_.size())}};
  if (kind_ == Kind::kBSpline) {
    j["basis"] = "tensor-product B-spline, degree 3 in u and v, uniform clamped knots over the domain";
    j["control_net"] = {net_, net_};
    j["coefficient_order"] = "c[i * net + j], i along u, j along v";
  } else {
    j["basis"] = "Legendre P_i(u') P_j(v'), u', v' in [-1, 1] over the domain, i + j <= " + std::to_string(degree_);
    j["degree"] = degree_;
    j["coefficient_order"] = "by total degree, then decreasing power of u'";
  }
  j["outside_domain"] = "clamped to the domain";
  return j;
}

// ---------------------------------------------------------------------------------------------
// Options, evaluation

const char* CvGuardName(CvGuard guard) {
  switch (guard) {
    case CvGuard::kLowerHeldOutError:
      return "lower held-out error";
    case CvGuard::kOneStandardError:
      return "one standard error (blocks)";
    case CvGuard::kOneStandardErrorFolds:
      return "one standard error (folds)";
    case CvGuard::kIndependentWithinOneStandardError:
      return "independent within one standard error";
  }
  return "?";
}

const char* CvGuardRule(CvGuard guard) {
  switch (guard) {
    case CvGuard::kLowerHeldOutError:
      return "its spatial block CV error is lower than the current model's";
    case CvGuard::kOneStandardError:
      return "its spatial block CV mean-square error is not worse than the current model's by more than one "
             "standard error of the paired difference, the CV blocks being the replicates";
    case CvGuard::kOneStandardErrorFolds:
      return "its spatial block CV mean-square error is not worse than the current model's by more than one "
             "standard error of the paired difference, the CV folds being the replicates";
    case CvGuard::kIndependentWithinOneStandardError:
      return "its spatial block CV error is lower than the current model's, or its residual is independent and its "
             "CV mean-square error is not worse by more than one standard error of the paired block-wise difference";
  }
  return "?";
}

Status DecompositionOptions::Validate() const {
  if (neighbours < 1 || neighbours > 64) {
    return Status::BadInput(Where{.field = "analysis.neighbours"}, "must be between 1 and 64");
  }
  if (max_control_net < 3 || max_control_net > 20) {
    return Status::BadInput(Where{.field = "analysis.max_control_net"}, "must be between 3 and 20",
                            "3 tries the polynomials only; 8 (64 parameters) suits a few hundred points");
  }
  if (points_per_parameter < 2) {
    return Status::BadInput(Where{.field = "analysis.points_per_parameter"}, "must be >= 2");
  }
  if (cv_blocks != 0 && (cv_blocks < 2 || cv_blocks > 50)) {
    return Status::BadInput(Where{.field = "analysis.cv_blocks"}, "must be 0 (automatic) or between 2 and 50");
  }
  if (cv_folds < 2 || cv_folds > 50 || (cv_blocks != 0 && cv_folds > cv_blocks * cv_blocks)) {
    return Status::BadInput(Where{.field = "analysis.cv_folds"}, "must be between 2 and 50 and at most cv_blocks²");
  }
  if (!(coverage_factor > 0) || !std::isfinite(coverage_factor)) {
    return Status::BadInput(Where{.field = "analysis.coverage_factor"}, "must be > 0");
  }
  if (tolerance_mm && !(*tolerance_mm > 0 && std::isfinite(*tolerance_mm))) {
    return Status::BadInput(Where{.field = "tolerance_mm"}, "the form tolerance α must be > 0");
  }
  return Status::Ok();
}

Result<FormEvaluation> EvaluateForm(const Decomposition& d, double tolerance_mm) {
  if (!(tolerance_mm > 0) || !std::isfinite(tolerance_mm)) {
    return Status::BadInput(Where{.field = "tolerance_mm"},
                            "the form tolerance α must be > 0, got " + Num(tolerance_mm));
  }
  FormEvaluation e;
  e.tolerance_um = tolerance_mm * 1e3;
  e.form_error_um = d.form_error_um;
  e.within_tolerance = e.form_error_um <= e.tolerance_um;
  const bool non_constant = d.systematic.kind() != FieldModel::Kind::kConstant;
  e.systematic_significant = non_constant || std::abs(d.mean_offset_um) > kOffsetZ * d.mean_offset_se_um;
  e.compensate = !e.within_tolerance && e.systematic_significant;
  e.expected_after_um = d.coverage_factor * d.random_sigma_um;
  if (e.within_tolerance) {
    e.decision = "within tolerance: no compensation";
  } else if (!e.systematic_significant) {
    e.decision = "out of tolerance but the error is random: compensation cannot help";
  } else if (e.expected_after_um <= e.tolerance_um) {
    e.decision =
        "out of tolerance with a significant systematic error (" + d.systematic.name() + "): compensate by -d_s";
  } else {
    e.decision = "out of tolerance with a significant systematic error (" + d.systematic.name() +
                 "): compensate by -d_s, but the random part alone (k*sigma = " + Num(e.expected_after_um) +
                 " um) exceeds the tolerance, so compensation cannot bring the part in";
  }
  return e;
}

nlohmann::json FormEvaluation::ToJson() const {
  return {{"tolerance_um", tolerance_um},
          {"form_error_um", form_error_um},
          {"within_tolerance", within_tolerance},
          {"systematic_significant", systematic_significant},
          {"compensate", compensate},
          {"expected_after_compensation_um", expected_after_um},
          {"decision", decision},
          {"rule",
           "compensate by -d_s when form error > tolerance and d_s is significant (a non-constant model was chosen, "
           "or |mean| > 2.576 standard errors); random error is never compensated"}};
}

// ---------------------------------------------------------------------------------------------
// Decompose

Result<Decomposition> Decompose(const std::vector<Deviation>& deviations, const recon::ParamDomain& domain,
                                const DecompositionOptions& options) {
  FL_RETURN_IF_ERROR(options.Validate());
  FL_RETURN_IF_ERROR(CheckDomain(domain));
  const int n = static_cast<int>(deviations.size());
  const int minimum = std::max({kMinimumPoints, options.neighbours + 1, options.points_per_parameter});
  if (n < minimum) {
    return Status::BadInput(Where{.field = "deviations"},
                            "decomposition: " + std::to_string(n) + " points are fewer than the " +
                                std::to_string(minimum) + " the constant model and its Moran test need",
                            "probe at least " + std::to_string(minimum) + " points");
  }
  const double tol_u = 1e-9 * domain.u_span(), tol_v = 1e-9 * domain.v_span();
  Eigen::MatrixXd uv(2, n);
  Eigen::VectorXd y(n);
  for (int i = 0; i < n; ++i) {
    const Deviation& d = deviations[static_cast<std::size_t>(i)];
    const std::string id = "point id " + std::to_string(d.id);
    if (!std::isfinite(d.u) || !std::isfinite(d.v)) {
      return Status::BadInput(Where{.field = "u, v"}, "decomposition: " + id + " has a non-finite (u, v)",
                              "drop or re-measure the point");
    }
    if (!std::isfinite(d.deviation_mm)) {
      return Status::BadInput(Where{.field = "deviation_mm"}, "decomposition: " + id + " has a non-finite deviation",
                              "drop or re-measure the point");
    }
    if (d.u < domain.u_min - tol_u || d.u > domain.u_max + tol_u || d.v < domain.v_min - tol_v ||
        d.v > domain.v_max + tol_v) {
      return Status::BadInput(
          Where{.field = "u, v"},
          "decomposition: " + id + " at (u, v) = (" + Num(d.u) + ", " + Num(d.v) + ") lies outside the surface domain",
          "compute the deviations against the same surface");
    }
    uv(0, i) = d.u;
    uv(1, i) = d.v;
    y[i] = d.deviation_mm;
  }

  Decomposition result;
  result.coverage_factor = options.coverage_factor;
  result.cv_folds = options.cv_folds;
  result.cv_guard = options.cv_guard;
  result.cv_seed = options.cv_seed;
  FL_ASSIGN_OR_RETURN(SpatialWeights weights, KnnWeights(uv, options.neighbours, WeightStyle::kRowStandardised));
  const int blocks = options.cv_blocks > 0 ? options.cv_blocks : AutoBlocks(n);
  result.cv_blocks = blocks;
  // Blocks of the points' bounding box in (u, v), dealt to folds (metrology/spatial_cv.h).
  const std::vector<int> block_of_point = GridBlocks(uv.row(0).transpose(), uv.row(1).transpose(), blocks);
  const std::vector<int> block_fold = DealBlocksToFolds(blocks, options.cv_folds, options.cv_seed);
  std::vector<int> fold(block_of_point.size());
  for (std::size_t i = 0; i < fold.size(); ++i) fold[i] = block_fold[static_cast<std::size_t>(block_of_point[i])];
  {
    std::vector<int> count(static_cast<std::size_t>(options.cv_folds), 0);
    for (int f : fold) ++count[static_cast<std::size_t>(f)];
    if (std::count_if(count.begin(), count.end(), [](int c) { return c > 0; }) < 2) {
      return Status::BadInput(Where{.field = "deviations"},
                              "decomposition: the points fall into fewer than two cross-validation folds",
                              "probe points spread over the surface");
    }
  }

  const std::vector<FieldModel> ladder = Ladder(domain, options.max_control_net);
  FieldModel current = ladder[0];
  ResidualMoranResult current_fit;
  const double y_mean = y.mean();
  if ((y.array() - y_mean).abs().maxCoeff() == 0) {
    // Every deviation is the same: a pure offset, nothing spatial to test.
    FL_RETURN_IF_ERROR(current.SetCoefficients(Eigen::VectorXd::Constant(1, y_mean)));
    current_fit.p = 1;
    current_fit.residuals = Eigen::VectorXd::Zero(n);
    DecompositionStep step;
    step.model = current.name();
    step.parameters = 1;
    step.residual_moran_i = step.residual_moran_expected = step.residual_moran_z = std::nan("");
    step.accepted = step.independent = true;
    result.steps.push_back(step);
    result.independent = true;
    result.stop_reason = "all deviations are equal: a constant offset, nothing spatial left to test";
    result.raw.n = n;
  } else {
    FL_ASSIGN_OR_RETURN(result.raw, MoranI(y, weights));
    HeldOutErrors current_cv;
    const bool by_folds = options.cv_guard == CvGuard::kOneStandardErrorFolds;
    const std::vector<int>& se_unit = by_folds ? fold : block_of_point;
    const int se_units = by_folds ? options.cv_folds : blocks * blocks;
    for (std::size_t m = 0; m < ladder.size(); ++m) {
      const FieldModel& model = ladder[m];
      const int p = model.parameters();
      if (m > 0 && result.steps[static_cast<std::size_t>(result.chosen_step)].independent) {
        result.stop_reason = "the residual of the " + current.name() +
                             " model is spatially independent (z = " + Num(current_fit.z) +
                             " <= " + Num(kMoranZCritical) + ")";
        break;
      }
      if (n < options.points_per_parameter * p) {
        result.stop_reason = "the " + model.name() + " model (" + std::to_string(p) + " parameters) needs " +
                             std::to_string(options.points_per_parameter * p) + " points; there are " +
                             std::to_string(n);
        break;
      }
      const Rows rows = BuildRows(model, uv);
      Result<ResidualMoranResult> tested = ResidualMoranI(y, DenseDesign(rows, n, p), weights);
      if (!tested.ok()) {
        if (m == 0) return tested.status();
        result.stop_reason = "the " + model.name() + " model could not be tested: " + tested.status().message();
        break;
      }
      ResidualMoranResult fit = std::move(tested).value();
      if (fit.p < p) {
        result.stop_reason = "the points do not determine the " + model.name() + " model (design rank " +
                             std::to_string(fit.p) + " of " + std::to_string(p) + ")";
        break;
      }
      Eigen::MatrixXd penalty;
      if (model.kind() == FieldModel::Kind::kBSpline) penalty = DifferencePenalty(model.net());
      HeldOutErrors cv = BlockCv(rows, y, fold, options.cv_folds, p, penalty.size() > 0 ? &penalty : nullptr);
      DecompositionStep step;
      step.model = model.name();
      step.parameters = p;
      step.residual_rms_um = 1e3 * std::sqrt(fit.residuals.squaredNorm() / n);
      step.residual_moran_i = fit.i;
      step.residual_moran_expected = fit.expected;
      step.residual_moran_z = fit.z;
      step.cv_rms_um = 1e3 * cv.rms;
      step.independent = fit.z <= kMoranZCritical;
      if (m == 0) {
        step.accepted = true;
      } else {
        const PairedCvDifference paired = ComparePaired(cv, current_cv, se_unit, se_units);
        step.cv_difference_um2 = 1e6 * paired.difference;
        step.cv_difference_se_um2 = 1e6 * paired.standard_error;
        const bool finite = std::isfinite(cv.rms);
        switch (options.cv_guard) {
          case CvGuard::kLowerHeldOutError:
            step.accepted = cv.rms < current_cv.rms;
            break;
          case CvGuard::kOneStandardError:
          case CvGuard::kOneStandardErrorFolds:
            step.accepted = finite && paired.difference <= paired.standard_error;
            break;
          case CvGuard::kIndependentWithinOneStandardError:
            step.accepted =
                cv.rms < current_cv.rms || (finite && step.independent && paired.difference <= paired.standard_error);
            break;
        }
      }
      result.steps.push_back(step);
      if (step.accepted) {
        current = model;
        FL_RETURN_IF_ERROR(current.SetCoefficients(fit.coefficients));
        current_fit = std::move(fit);
        current_cv = cv;
        result.chosen_step = static_cast<int>(result.steps.size()) - 1;
      }
      if (m + 1 == ladder.size()) result.stop_reason = "the ladder ended at " + model.name();
    }
    result.independent = result.steps[static_cast<std::size_t>(result.chosen_step)].independent;
    if (!result.independent && options.spatial_filter) {
      SpatialFilterOptions filter_options = options.filter;
      filter_options.z_critical = kMoranZCritical;
      const Rows rows = BuildRows(current, uv);
      FL_ASSIGN_OR_RETURN(SpatialFilter filter,
                          FilterResidual(y, DenseDesign(rows, n, current.parameters()), weights, filter_options));
      result.filter = std::move(filter);
    }
    if (result.independent && result.stop_reason.rfind("the ladder ended", 0) == 0) {
      result.stop_reason = "the residual of the " + current.name() +
                           " model is spatially independent (z = " + Num(current_fit.z) +
                           " <= " + Num(kMoranZCritical) + ")";
    }
    if (!result.independent) {
      result.stop_reason += "; the chosen " + current.name() + " model (the last one the CV guard accepted) " +
                            "leaves a spatially correlated residual (z = " + Num(current_fit.z) + ")";
    }
  }

  result.systematic = current;
  result.field_independent = result.independent;
  result.residual_moran_z = result.steps[static_cast<std::size_t>(result.chosen_step)].residual_moran_z;
  result.systematic_mm.resize(static_cast<std::size_t>(n));
  result.fine_scale_mm.assign(static_cast<std::size_t>(n), 0.0);
  result.random_mm.resize(static_cast<std::size_t>(n));
  for (int i = 0; i < n; ++i) {
    result.random_mm[static_cast<std::size_t>(i)] = current_fit.residuals[i];
    result.systematic_mm[static_cast<std::size_t>(i)] = y[i] - current_fit.residuals[i];
  }
  if (result.filter) {
    const SpatialFilter& f = *result.filter;
    result.residual_moran_z = f.final.z;
    result.independent = f.independent;
    for (int i = 0; i < n; ++i) {
      result.fine_scale_mm[static_cast<std::size_t>(i)] = f.fitted[i];
      result.random_mm[static_cast<std::size_t>(i)] = current_fit.residuals[i] - f.fitted[i];
    }
    result.fine_scale_rms_um = 1e3 * Rms(result.fine_scale_mm);
    result.fine_scale_peak_um = 1e3 * PeakAbs(result.fine_scale_mm);
    result.fine_scale_assessment = FineScaleAssessment(f.z_before);
    result.stop_reason += f.independent
                              ? "; a spatial filter of " + std::to_string(f.vectors) + " Moran eigenvector" +
                                    (f.vectors == 1 ? "" : "s") + " takes the correlated fine-scale part d_f (RMS " +
                                    Num(result.fine_scale_rms_um) +
                                    " um) out of the residual, leaving d_u independent (z = " + Num(f.final.z) +
                                    "); d_f is " + result.fine_scale_assessment
                              : "; the spatial filter did not make the residual independent (" + f.stop_reason +
                                    ", z = " + Num(f.final.z) + ")";
  }
  const std::vector<double> all(y.data(), y.data() + n);
  result.deviation_rms_um = 1e3 * Rms(all);
  result.deviation_peak_um = 1e3 * PeakAbs(all);
  result.systematic_peak_um = 1e3 * PeakAbs(result.systematic_mm);
  result.systematic_rms_um = 1e3 * Rms(result.systematic_mm);
  result.random_rms_um = 1e3 * Rms(result.random_mm);
  result.random_peak_um = 1e3 * PeakAbs(result.random_mm);
  const int dof = std::max(1, n - current.parameters());
  result.random_sigma_um = 1e3 * std::sqrt(current_fit.residuals.squaredNorm() / dof);
  result.mean_offset_um = 1e3 * y_mean;
  result.mean_offset_se_um = result.random_sigma_um / std::sqrt(static_cast<double>(n));
  result.form_error_um = result.systematic_peak_um + options.coverage_factor * result.random_sigma_um;
  if (options.tolerance_mm) {
    FL_ASSIGN_OR_RETURN(result.evaluation, EvaluateForm(result, *options.tolerance_mm));
  }
  return result;
}

std::string FineScaleAssessment(double field_residual_z) {
  const double p = NormalUpperTail(field_residual_z);
  const std::string p_text = FormatSignificant(p, 2);
  if (field_residual_z <= kFineScaleChanceZ) {
    return "consistent with chance: an independent residual reaches the field's z = " + Num(field_residual_z) +
           " with probability " + p_text;
  }
  return "not chance (the field's residual z = " + Num(field_residual_z) + ", p = " + p_text +
         "): a real error finer than the field the probe points support; probe denser where it matters";
}

nlohmann::json Decomposition::ToJson() const {
  nlohmann::json steps_json = nlohmann::json::array();
  for (const auto& s : steps) {
    steps_json.push_back({{"model", s.model},
                          {"parameters", s.parameters},
                          {"residual_rms_um", s.residual_rms_um},
                          {"residual_moran_I", s.residual_moran_i},
                          {"residual_moran_expected", s.residual_moran_expected},
                          {"residual_moran_z", s.residual_moran_z},
                          {"cv_rms_um", s.cv_rms_um},
                          {"cv_difference_um2", s.cv_difference_um2},
                          {"cv_difference_se_um2", s.cv_difference_se_um2},
                          {"accepted_by_cv", s.accepted},
                          {"independent", s.independent}});
  }
  nlohmann::json j = {
      {"raw_moran", raw.ToJson()},
      {"models_tried", steps_json},
      {"chosen_model", systematic.name()},
      {"chosen_step", chosen_step},
      {"residual_independent", independent},
      {"residual_moran_z", residual_moran_z},
      {"field_residual_independent", field_independent},
      {"spatial_filter", filter ? filter->ToJson() : nlohmann::json(nullptr)},
      {"fine_scale_rms_um", fine_scale_rms_um},
      {"fine_scale_peak_um", fine_scale_peak_um},
      {"fine_scale_assessment",
       fine_scale_assessment.empty() ? nlohmann::json(nullptr) : nlohmann::json(fine_scale_assessment)},
      {"fine_scale_note",
       "d_f: spatially correlated structure finer than the field (chance at the 1 % level, or a real error finer than "
       "the probe spacing); at the probe points only, never compensated"},
      {"stop_reason", stop_reason},
      {"selection_rule",
       "walk constant, plane, quadric, bicubic B-spline nets of increasing size; a richer model becomes current only "
       "if the CV guard accepts it (" +
           std::string(CvGuardRule(cv_guard)) +
           "); stop at the first current model whose residual Moran z (Cliff-Ord, that model's design) is <= 2.326; "
           "if the ladder ends on a correlated residual, a Moran eigenvector spatial filter takes the correlated part "
           "out as d_f (y = d_s + d_f + d_u)"},
      {"cross_validation",
       {{"blocks_per_direction", cv_blocks},
        {"folds", cv_folds},
        {"seed", cv_seed},
        {"guard", CvGuardName(cv_guard)},
        {"error", "RMS over all points of the residual predicted by the fit without the point's fold"}}},
      {"systematic_field", systematic.ToJson()},
      {"deviation_rms_um", deviation_rms_um},
      {"deviation_peak_um", deviation_peak_um},
      {"systematic_peak_um", systematic_peak_um},
      {"systematic_rms_um", systematic_rms_um},
      {"random_rms_um", random_rms_um},
      {"random_peak_um", random_peak_um},
      {"random_sigma_um", random_sigma_um},
      {"mean_offset_um", mean_offset_um},
      {"mean_offset_se_um", mean_offset_se_um},
      {"form_error_rule", "max|d_s| + k*sigma(d_u), sigma(d_u) = sqrt(sum d_u^2 / (n - p))"},
      {"coverage_factor", coverage_factor},
      {"form_error_um", form_error_um}};
  if (evaluation) j["evaluation"] = evaluation->ToJson();
  return j;
}

}  // namespace formloop::metrology
