#include "metrology/decomposition.h"

#include <algorithm>
#include <cmath>

namespace formloop::metrology {
namespace {

// Legendre P_0..P_degree at x ∈ [−1, 1] by the three-term recurrence.
std::vector<double> Legendre(int degree, double x) {
  std::vector<double> p(static_cast<std::size_t>(degree) + 1);
  p[0] = 1.0;
  if (degree >= 1) p[1] = x;
  for (int k = 2; k <= degree; ++k) {
    p[static_cast<std::size_t>(k)] =
        ((2.0 * k - 1.0) * x * p[static_cast<std::size_t>(k - 1)] - (k - 1.0) * p[static_cast<std::size_t>(k - 2)]) / k;
  }
  return p;
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

}  // namespace

Eigen::VectorXd PolynomialField::Basis(int degree, const recon::ParamDomain& domain, double u, double v) {
  const double un = 2.0 * (u - domain.u_min) / domain.u_span() - 1.0;
  const double vn = 2.0 * (v - domain.v_min) / domain.v_span() - 1.0;
  const std::vector<double> pu = Legendre(degree, un), pv = Legendre(degree, vn);
  Eigen::VectorXd row((degree + 1) * (degree + 2) / 2);
  int k = 0;
  for (int total = 0; total <= degree; ++total) {
    for (int i = total; i >= 0; --i) row[k++] = pu[static_cast<std::size_t>(i)] * pv[static_cast<std::size_t>(total - i)];
  }
  return row;
}

double PolynomialField::Evaluate(double u, double v) const { return Basis(degree, domain, u, v).dot(coefficients); }

nlohmann::json PolynomialField::ToJson() const {
  return {{"type", "legendre_total_degree"},
          {"degree", degree},
          {"domain", {domain.u_min, domain.u_max, domain.v_min, domain.v_max}},
          {"coefficients_mm", std::vector<double>(coefficients.data(), coefficients.data() + coefficients.size())}};
}

Status DecompositionOptions::Validate() const {
  if (max_degree < 0 || max_degree > 10) {
    return Status::BadInput(Where{.field = "analysis.max_degree"}, "must be between 0 and 10");
  }
  if (neighbours < 1) return Status::BadInput(Where{.field = "analysis.neighbours"}, "must be >= 1");
  if (!(coverage_factor > 0)) return Status::BadInput(Where{.field = "analysis.coverage_factor"}, "must be > 0");
  return Status::Ok();
}

Result<Decomposition> Decompose(const std::vector<Deviation>& deviations, const recon::ParamDomain& domain,
                                const DecompositionOptions& options) {
  FL_RETURN_IF_ERROR(options.Validate());
  const int n = static_cast<int>(deviations.size());
  Eigen::MatrixXd uv(2, n);
  Eigen::VectorXd y(n);
  for (int i = 0; i < n; ++i) {
    uv(0, i) = deviations[static_cast<std::size_t>(i)].u;
    uv(1, i) = deviations[static_cast<std::size_t>(i)].v;
    y[i] = deviations[static_cast<std::size_t>(i)].deviation_mm;
  }
  FL_ASSIGN_OR_RETURN(SpatialWeights weights, KnnWeights(uv, options.neighbours, WeightStyle::kRowStandardised));
  Decomposition result;
  result.coverage_factor = options.coverage_factor;
  FL_ASSIGN_OR_RETURN(result.raw, MoranI(y, weights));

  ResidualMoranResult chosen;
  int chosen_degree = -1;
  for (int degree = 0; degree <= options.max_degree; ++degree) {
    const int terms = (degree + 1) * (degree + 2) / 2;
    if (n - terms < 10) break;  // keep enough residual degrees of freedom for the test
    Eigen::MatrixXd design(n, terms);
    for (int i = 0; i < n; ++i) design.row(i) = PolynomialField::Basis(degree, domain, uv(0, i), uv(1, i)).transpose();
    FL_ASSIGN_OR_RETURN(ResidualMoranResult moran, ResidualMoranI(y, design, weights));
    DecompositionStep step;
    step.degree = degree;
    step.terms = terms;
    step.residual_rms_um = 1e3 * std::sqrt(moran.residuals.squaredNorm() / n);
    step.residual_moran_i = moran.i;
    step.residual_moran_z = moran.z;
    result.steps.push_back(step);
    chosen = moran;
    chosen_degree = degree;
    if (moran.z <= kMoranZCritical) {
      result.independent = true;
      break;
    }
  }
  if (chosen_degree < 0) {
    return Status::BadInput("decomposition: " + std::to_string(n) + " probe points are too few for a field model. " +
                            "Fix: probe at least 20 points");
  }
  result.systematic.degree = chosen_degree;
  result.systematic.domain = domain;
  result.systematic.coefficients = chosen.coefficients;
  for (int i = 0; i < n; ++i) {
    result.random_mm.push_back(chosen.residuals[i]);
    result.systematic_mm.push_back(y[i] - chosen.residuals[i]);
  }
  std::vector<double> all(y.data(), y.data() + n);
  result.deviation_rms_um = 1e3 * Rms(all);
  result.deviation_peak_um = 1e3 * PeakAbs(all);
  result.systematic_peak_um = 1e3 * PeakAbs(result.systematic_mm);
  result.systematic_rms_um = 1e3 * Rms(result.systematic_mm);
  double mean = 0;
  for (double r : result.random_mm) mean += r;
  mean /= n;
  double var = 0;
  for (double r : result.random_mm) var += (r - mean) * (r - mean);
  result.random_sigma_um = 1e3 * std::sqrt(var / std::max(1, n - chosen.p));
  result.form_error_um = result.systematic_peak_um + options.coverage_factor * result.random_sigma_um;
  return result;
}

nlohmann::json Decomposition::ToJson() const {
  nlohmann::json steps_json = nlohmann::json::array();
  for (const auto& s : steps) {
    steps_json.push_back({{"degree", s.degree},
                          {"terms", s.terms},
                          {"residual_rms_um", s.residual_rms_um},
                          {"residual_moran_I", s.residual_moran_i},
                          {"residual_moran_z", s.residual_moran_z}});
  }
  return {{"raw_moran", raw.ToJson()},
          {"models_tried", steps_json},
          {"residual_independent", independent},
          {"systematic_field", systematic.ToJson()},
          {"deviation_rms_um", deviation_rms_um},
          {"deviation_peak_um", deviation_peak_um},
          {"systematic_peak_um", systematic_peak_um},
          {"systematic_rms_um", systematic_rms_um},
          {"random_sigma_um", random_sigma_um},
          {"form_error_rule", "max|d_s| + k*sigma(d_u)"},
          {"coverage_factor", coverage_factor},
          {"form_error_um", form_error_um}};
}

}  // namespace formloop::metrology
