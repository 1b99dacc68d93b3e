// The systematic / random decomposition (spec/metrology.md §7–8) on synthetic deviation fields with
// known truth: a smooth systematic field plus i.i.d. normal noise at random (u, v), many seeds.
//
// Rates are printed (e.g. "independent 200/200") so the log records what was measured, not only
// that a bound held.

#include "metrology/decomposition.h"

#include <gtest/gtest.h>
#include <Eigen/QR>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <limits>
#include <numbers>
#include <string>
#include <vector>

#include "core/random.h"
#include "metrology/spatial_weights.h"

namespace formloop::metrology {
namespace {

constexpr double kSigmaMm = 0.001;  // noise σ: 1 µm
constexpr int kSeeds = 200;
const recon::ParamDomain kDomain{.u_min = -50, .u_max = 50, .v_min = -40, .v_max = 40};

// A smooth systematic field on the domain: tilt + quadric + one long wave + one broad bump, random
// in every coefficient, with zero mean over the domain and the given RMS (both on a fine grid).
// Features are no narrower than a fifth of the part (wave length ≥ 0.8, bump σ ≥ 0.2 of the extent):
// the scale of the machining errors of spec/simulation.md (deflection, thermal drift, radius error).
class SmoothField {
 public:
  SmoothField(std::uint64_t seed, double rms_mm) {
    Rng rng(seed);
    for (double& a : poly_) a = rng.Normal();
    wave_ = rng.Normal();
    const double angle = rng.Uniform(0, std::numbers::pi);
    kx_ = std::cos(angle) / rng.Uniform(0.8, 1.6);
    ky_ = std::sin(angle) / rng.Uniform(0.8, 1.6);
    phase_ = rng.Uniform(0, 2 * std::numbers::pi);
    bump_ = rng.Normal();
    bx_ = rng.Uniform(0.2, 0.8);
    by_ = rng.Uniform(0.2, 0.8);
    bw_ = rng.Uniform(0.2, 0.35);
    double sum = 0, sum2 = 0;
    const int g = 101;
    for (int i = 0; i < g; ++i) {
      for (int j = 0; j < g; ++j) {
        const double f = Raw(i / (g - 1.0), j / (g - 1.0));
        sum += f;
        sum2 += f * f;
      }
    }
    mean_ = sum / (g * g);
    scale_ = rms_mm / std::sqrt(sum2 / (g * g) - mean_ * mean_);
  }
  double operator()(double u, double v) const {
    return scale_ * (Raw((u - kDomain.u_min) / kDomain.u_span(), (v - kDomain.v_min) / kDomain.v_span()) - mean_);
  }

 private:
  double Raw(double s, double t) const {
    const double x = s - 0.5, y = t - 0.5;
    const double poly = poly_[0] * x + poly_[1] * y + poly_[2] * x * x + poly_[3] * x * y + poly_[4] * y * y;
    const double wave = wave_ * 0.3 * std::sin(2 * std::numbers::pi * (kx_ * s + ky_ * t) + phase_);
    const double r2 = (s - bx_) * (s - bx_) + (t - by_) * (t - by_);
    return poly + wave + bump_ * 0.3 * std::exp(-r2 / (2 * bw_ * bw_));
  }
  double poly_[5];
  double wave_, kx_, ky_, phase_, bump_, bx_, by_, bw_;
  double mean_ = 0, scale_ = 1;
};

// n points uniform over the domain; deviation = field + N(0, σ²).
template <typename Field>
std::vector<Deviation> Sample(std::uint64_t seed, int n, const Field& field, std::vector<double>* truth = nullptr) {
  Rng rng(seed ^ 0x5eedULL);
  std::vector<Deviation> out(static_cast<std::size_t>(n));
  if (truth) truth->resize(static_cast<std::size_t>(n));
  for (int i = 0; i < n; ++i) {
    Deviation& d = out[static_cast<std::size_t>(i)];
    d.id = i + 1;
    d.u = rng.Uniform(kDomain.u_min, kDomain.u_max);
    d.v = rng.Uniform(kDomain.v_min, kDomain.v_max);
    const double f = field(d.u, d.v);
    if (truth) (*truth)[static_cast<std::size_t>(i)] = f;
    d.deviation_mm = f + kSigmaMm * rng.Normal();
  }
  return out;
}

const auto kZero = [](double, double) { return 0.0; };

// The selection rule of decomposition.h, checked on a report: the constant is accepted first; a later
// step is accepted exactly when the guard accepts it against the model current before it (for the
// strict guard: it lowers the CV error); the ladder stops right after the first current model whose
// residual is independent; the chosen step is the last accepted one (for the strict guard it has the
// least CV error of all steps tried).
void ExpectTheRuleWasFollowed(const Decomposition& d, CvGuard guard) {
  ASSERT_FALSE(d.steps.empty());
  EXPECT_TRUE(d.steps[0].accepted);
  std::size_t current = 0;
  for (std::size_t k = 1; k < d.steps.size(); ++k) {
    const DecompositionStep& s = d.steps[k];
    EXPECT_FALSE(d.steps[current].independent) << "step " << k << " tried after an independent current model";
    const bool lower = s.cv_rms_um < d.steps[current].cv_rms_um;
    const bool within_se = std::isfinite(s.cv_rms_um) && s.cv_difference_um2 <= s.cv_difference_se_um2;
    bool expected = lower;
    if (guard == CvGuard::kOneStandardError || guard == CvGuard::kOneStandardErrorFolds) expected = within_se;
    if (guard == CvGuard::kIndependentWithinOneStandardError) expected = lower || (s.independent && within_se);
    EXPECT_EQ(s.accepted, expected) << "step " << k;
    EXPECT_GE(s.cv_difference_se_um2, 0) << "step " << k;
    if (s.accepted) current = k;
  }
  EXPECT_EQ(static_cast<std::size_t>(d.chosen_step), current);
  if (guard == CvGuard::kLowerHeldOutError) {
    for (const auto& s : d.steps) EXPECT_GE(s.cv_rms_um, d.steps[current].cv_rms_um);
  }
  EXPECT_EQ(d.field_independent, d.steps[current].independent);
  EXPECT_EQ(d.steps[current].model, d.systematic.name());
  // The filter runs exactly when the field's residual is correlated; d = d_s + d_f + d_u.
  EXPECT_EQ(d.filter.has_value(), !d.field_independent);
  if (d.filter) {
    EXPECT_EQ(d.independent, d.filter->independent);
    EXPECT_EQ(d.residual_moran_z, d.filter->final.z);
    EXPECT_EQ(d.independent, d.residual_moran_z <= kMoranZCritical);
    EXPECT_EQ(d.filter->final.p, d.systematic.parameters() + d.filter->vectors);
  } else {
    EXPECT_EQ(d.independent, d.field_independent);
    EXPECT_EQ(d.residual_moran_z, d.steps[current].residual_moran_z);
    for (double f : d.fine_scale_mm) EXPECT_EQ(f, 0);
  }
}

std::string Rate(int k, int n) { return std::to_string(k) + "/" + std::to_string(n); }
std::string Seeds(const std::vector<int>& seeds) {
  std::string out;
  for (int s : seeds) out += (out.empty() ? "" : " ") + std::to_string(s);
  return out.empty() ? "none" : out;
}

// The four figures of issue 5 item 4 for one set of options, each over kSeeds seeds (1,000 points,
// σ = 1 µm): smooth fields of RMS 1..4 σ (residual independent, d_s within 0.3 σ at the points and on
// a 41 × 41 grid), pure noise (constant chosen) and a field of RMS σ (detected).
struct ItemFourFigures {
  int independent = 0, recovered_points = 0, recovered_grid = 0, constant_on_noise = 0, detected = 0;
  int field_independent = 0, filtered = 0, filter_vectors_max = 0;
  double fine_scale_rms_max = 0;    // largest d_f RMS / σ where the filter ran
  std::vector<double> grid_errors;  // d_s RMS error on the grid / σ, sorted
  std::vector<int> model_counts = std::vector<int>(12, 0);
  std::vector<int> not_independent;  // seeds of the smooth fields whose chosen residual is correlated
  // The oracle: the noise alone (deviation − true field) under the same test (residual Moran of the
  // constant model on the same weights). The test rejects at level 0.01, so even the exact field
  // leaves a "correlated" residual in about 1 % of seeds: no honest rule can do better than this.
  std::vector<int> noise_not_independent;
};

void MeasureSmoothFields(const DecompositionOptions& options, ItemFourFigures* f) {
  for (int seed = 1; seed <= kSeeds; ++seed) {
    Rng pick(static_cast<std::uint64_t>(seed) * 7919);
    const SmoothField field(static_cast<std::uint64_t>(seed), kSigmaMm * pick.Uniform(1.0, 4.0));
    std::vector<double> truth;
    const auto deviations = Sample(static_cast<std::uint64_t>(seed), 1000, field, &truth);
    const auto d = Decompose(deviations, kDomain, options);
    ASSERT_TRUE(d.ok()) << d.status().message();
    const DecompositionStep& chosen = d->steps[static_cast<std::size_t>(d->chosen_step)];
    EXPECT_EQ(chosen.model, d->systematic.name());
    ++f->model_counts[static_cast<std::size_t>(d->chosen_step)];
    if (d->filter) {
      ++f->filtered;
      f->fine_scale_rms_max = std::max(f->fine_scale_rms_max, 1e-3 * d->fine_scale_rms_um / kSigmaMm);
      f->filter_vectors_max = std::max(f->filter_vectors_max, d->filter->vectors);
    }
    if (d->field_independent) ++f->field_independent;
    if (d->independent && d->residual_moran_z <= kMoranZCritical) {
      ++f->independent;
    } else {
      f->not_independent.push_back(seed);
    }
    ExpectTheRuleWasFollowed(*d, options.cv_guard);
    {
      Eigen::MatrixXd uv(2, static_cast<Eigen::Index>(truth.size()));
      Eigen::VectorXd noise(static_cast<Eigen::Index>(truth.size()));
      for (std::size_t i = 0; i < truth.size(); ++i) {
        uv(0, static_cast<Eigen::Index>(i)) = deviations[i].u;
        uv(1, static_cast<Eigen::Index>(i)) = deviations[i].v;
        noise[static_cast<Eigen::Index>(i)] = deviations[i].deviation_mm - truth[i];
      }
      const auto w = KnnWeights(uv, options.neighbours, WeightStyle::kRowStandardised);
      ASSERT_TRUE(w.ok());
      const auto oracle = ResidualMoranI(noise, Eigen::MatrixXd::Ones(noise.size(), 1), *w);
      ASSERT_TRUE(oracle.ok());
      if (oracle->z > kMoranZCritical) f->noise_not_independent.push_back(seed);
    }
    double e2 = 0;
    for (std::size_t i = 0; i < truth.size(); ++i) e2 += std::pow(d->systematic_mm[i] - truth[i], 2);
    if (std::sqrt(e2 / static_cast<double>(truth.size())) <= 0.3 * kSigmaMm) ++f->recovered_points;
    double g2 = 0;
    const int g = 41;
    for (int i = 0; i < g; ++i) {
      for (int j = 0; j < g; ++j) {
        const double u = kDomain.u_min + kDomain.u_span() * i / (g - 1.0);
        const double v = kDomain.v_min + kDomain.v_span() * j / (g - 1.0);
        g2 += std::pow(d->systematic.Evaluate(u, v) - field(u, v), 2);
      }
    }
    const double grid_rms = std::sqrt(g2 / (g * g));
    f->grid_errors.push_back(grid_rms / kSigmaMm);
    if (grid_rms <= 0.3 * kSigmaMm) ++f->recovered_grid;
  }
  std::sort(f->grid_errors.begin(), f->grid_errors.end());
}

void MeasurePureNoise(const DecompositionOptions& options, ItemFourFigures* f) {
  for (int seed = 1; seed <= kSeeds; ++seed) {
    const auto d = Decompose(Sample(static_cast<std::uint64_t>(seed) + 1000, 1000, kZero), kDomain, options);
    ASSERT_TRUE(d.ok()) << d.status().message();
    if (d->systematic.kind() == FieldModel::Kind::kConstant) ++f->constant_on_noise;
  }
}

void MeasureDetection(const DecompositionOptions& options, ItemFourFigures* f) {
  for (int seed = 1; seed <= kSeeds; ++seed) {
    const SmoothField field(static_cast<std::uint64_t>(seed) + 2000, kSigmaMm);
    const auto d = Decompose(Sample(static_cast<std::uint64_t>(seed) + 2000, 1000, field), kDomain, options);
    ASSERT_TRUE(d.ok()) << d.status().message();
    if (d->steps[0].residual_moran_z > kMoranZCritical && d->systematic.kind() != FieldModel::Kind::kConstant) {
      ++f->detected;
    }
  }
}

// Claims 1 and 2 of issue 5 item 4: on smooth fields (RMS 1..4 σ) + noise with 1,000 points the
// chosen model's residual d_u passes the Moran test in every seed, and d_s is recovered to ≤ 30 % of σ
// RMS at the points in every seed (and on a 41 × 41 grid over the domain, where the compensation
// evaluates it, in ≥ 95 %).
TEST(DecompositionTest, SmoothFieldsGiveAnIndependentResidualAndRecoverTheField) {
  ItemFourFigures f;
  MeasureSmoothFields({}, &f);
  std::printf("smooth fields, n = 1000: d_u independent %s, d_s within 0.3 sigma at points %s, on grid %s\n",
              Rate(f.independent, kSeeds).c_str(), Rate(f.recovered_points, kSeeds).c_str(),
              Rate(f.recovered_grid, kSeeds).c_str());
  std::printf(
      "  the field's own residual independent %s (the noise alone fails the same test in %s: %s); "
      "filtered %d, at most %d vectors, d_f RMS at most %.3f sigma\n",
      Rate(f.field_independent, kSeeds).c_str(), Rate(static_cast<int>(f.noise_not_independent.size()), kSeeds).c_str(),
      Seeds(f.noise_not_independent).c_str(), f.filtered, f.filter_vectors_max, f.fine_scale_rms_max);
  std::printf(
      "  seeds whose d_u is correlated: %s; grid RMS error / sigma: median %.3f, 95th %.3f, max %.3f; "
      "chosen step counts:",
      Seeds(f.not_independent).c_str(), f.grid_errors[kSeeds / 2], f.grid_errors[kSeeds * 95 / 100],
      f.grid_errors.back());
  for (int c : f.model_counts) std::printf(" %d", c);
  std::printf("\n");
  EXPECT_EQ(f.independent, kSeeds);
  EXPECT_EQ(f.recovered_points, kSeeds);
  EXPECT_GE(f.recovered_grid, kSeeds * 95 / 100);
  // The field itself cannot be independent in every seed at test level 0.01 (see
  // noise_not_independent, and decomposition.h for the seeds where no ladder model is both
  // independent and within 0.3 σ). What the guard must not do is veto a model the data support: the
  // field's failures stay within two seeds of the oracle's count (measured: 3 against 4).
  EXPECT_LE(kSeeds - f.field_independent, static_cast<int>(f.noise_not_independent.size()) + 2);
  // What the filter takes out is fine-scale and small: chance structure, not the field.
  EXPECT_LE(f.fine_scale_rms_max, 0.25);
}

// Claim 3: on pure noise the constant model is chosen in ≥ 95 % of seeds (the Moran test at 0.01
// alone would give about 99 %).
TEST(DecompositionTest, PureNoiseChoosesTheConstantModel) {
  ItemFourFigures f;
  MeasurePureNoise({}, &f);
  std::printf("pure noise, n = 1000: constant model chosen %s\n", Rate(f.constant_on_noise, kSeeds).c_str());
  EXPECT_GE(f.constant_on_noise, kSeeds * 95 / 100);
}

// Claim 4: a smooth field whose RMS equals σ is detected with 1,000 points: the constant model's
// residual is significant and a non-constant model is chosen.
TEST(DecompositionTest, FieldOfOneSigmaIsDetectedWithAThousandPoints) {
  ItemFourFigures f;
  MeasureDetection({}, &f);
  std::printf("field RMS = sigma, n = 1000: detected %s\n", Rate(f.detected, kSeeds).c_str());
  EXPECT_GE(f.detected, kSeeds * 95 / 100);
}

// The study behind the default CV guard (issue 5 item 4: "the chosen model's residual z ≤ 2.326" in
// every seed against "never overfit"): the four figures for every guard of CvGuard, as a table.
// Disabled by default (about four times the three tests above); run with
//   formloop_metrology_tests --gtest_also_run_disabled_tests --gtest_filter='*CvGuardStudy*'
TEST(DecompositionTest, DISABLED_CvGuardStudy) {
  std::printf("%-40s %12s %12s %12s %12s %10s %10s  %s\n", "guard, field independent", "d_u indep.", "d_s@points",
              "d_s@grid", "noise->const", "detected", "grid_max", "seeds not independent");
  for (CvGuard guard : {CvGuard::kLowerHeldOutError, CvGuard::kOneStandardError, CvGuard::kOneStandardErrorFolds,
                        CvGuard::kIndependentWithinOneStandardError}) {
    DecompositionOptions options;
    options.cv_guard = guard;
    ItemFourFigures f;
    MeasureSmoothFields(options, &f);
    MeasurePureNoise(options, &f);
    MeasureDetection(options, &f);
    std::printf("%-40s %12s %12s %12s %12s %10s %10.3f  %s (noise alone: %s)\n",
                (std::string(CvGuardName(guard)) + ", field " + Rate(f.field_independent, kSeeds)).c_str(),
                Rate(f.independent, kSeeds).c_str(), Rate(f.recovered_points, kSeeds).c_str(),
                Rate(f.recovered_grid, kSeeds).c_str(), Rate(f.constant_on_noise, kSeeds).c_str(),
                Rate(f.detected, kSeeds).c_str(), f.grid_errors.back(), Seeds(f.not_independent).c_str(),
                Seeds(f.noise_not_independent).c_str());
    std::fflush(stdout);
  }
}

// The field d_s is usable away from the points: Evaluate reproduces the fitted values at the points,
// holds the boundary value outside the domain, and the report carries the per-step table.
TEST(DecompositionTest, FieldEvaluatesAnywhereAndTheReportCarriesTheTable) {
  const SmoothField field(7, 3 * kSigmaMm);
  const auto deviations = Sample(7, 1000, field);
  const auto d = Decompose(deviations, kDomain, {});
  ASSERT_TRUE(d.ok()) << d.status().message();
  ASSERT_EQ(d->systematic.kind(), FieldModel::Kind::kBSpline) << d->systematic.name();
  for (std::size_t i = 0; i < deviations.size(); i += 37) {
    EXPECT_NEAR(d->systematic.Evaluate(deviations[i].u, deviations[i].v), d->systematic_mm[i], 1e-12);
    EXPECT_NEAR(d->systematic_mm[i] + d->random_mm[i], deviations[i].deviation_mm, 1e-15);
  }
  EXPECT_EQ(d->systematic.Evaluate(kDomain.u_max + 30, 0.5), d->systematic.Evaluate(kDomain.u_max, 0.5));
  EXPECT_EQ(d->systematic.Evaluate(-1e3, -1e3), d->systematic.Evaluate(kDomain.u_min, kDomain.v_min));
  const nlohmann::json j = d->ToJson();
  ASSERT_EQ(j["models_tried"].size(), d->steps.size());
  for (const char* key : {"model", "parameters", "residual_rms_um", "residual_moran_I", "residual_moran_z", "cv_rms_um",
                          "accepted_by_cv", "independent"}) {
    EXPECT_TRUE(j["models_tried"][0].contains(key)) << key;
  }
  EXPECT_EQ(j["chosen_model"], d->systematic.name());
  EXPECT_EQ(j["systematic_field"]["coefficients_mm"].size(), static_cast<std::size_t>(d->systematic.parameters()));
  EXPECT_EQ(j["cross_validation"]["blocks_per_direction"], 16);  // round(√1000 / 2)
  EXPECT_FALSE(j.contains("evaluation"));
  // The same input gives the same report (seeded CV folds).
  const auto again = Decompose(deviations, kDomain, {});
  ASSERT_TRUE(again.ok());
  EXPECT_EQ(again->ToJson().dump(), j.dump());
}

// §8: form error = max|d_s| + 2 σ(d_u) against α, and the compensation decision.
TEST(DecompositionTest, EvaluationAgainstTheToleranceDecidesCompensation) {
  const SmoothField field(11, 10 * kSigmaMm);
  DecompositionOptions options;
  options.tolerance_mm = 0.010;
  const auto d = Decompose(Sample(11, 400, field), kDomain, options);
  ASSERT_TRUE(d.ok()) << d.status().message();
  ASSERT_TRUE(d->evaluation.has_value());
  EXPECT_NEAR(d->form_error_um, d->systematic_peak_um + 2 * d->random_sigma_um, 1e-12);
  EXPECT_FALSE(d->evaluation->within_tolerance);
  EXPECT_TRUE(d->evaluation->systematic_significant);
  EXPECT_TRUE(d->evaluation->compensate) << d->evaluation->decision;
  EXPECT_NEAR(d->evaluation->expected_after_um, 2 * d->random_sigma_um, 1e-12);
  EXPECT_TRUE(d->ToJson().contains("evaluation"));
  // A generous α: nothing to do.
  const auto loose = EvaluateForm(*d, 1.0);
  ASSERT_TRUE(loose.ok());
  EXPECT_TRUE(loose->within_tolerance);
  EXPECT_FALSE(loose->compensate);
  // Pure noise of σ = 1 µm against α = 1 µm: out of tolerance, but random: never compensated.
  const auto noise = Decompose(Sample(12, 400, kZero), kDomain, {});
  ASSERT_TRUE(noise.ok());
  ASSERT_EQ(noise->systematic.kind(), FieldModel::Kind::kConstant);
  const auto tight = EvaluateForm(*noise, 0.001);
  ASSERT_TRUE(tight.ok());
  EXPECT_FALSE(tight->within_tolerance);
  EXPECT_FALSE(tight->systematic_significant);
  EXPECT_FALSE(tight->compensate);
  EXPECT_NE(tight->decision.find("random"), std::string::npos) << tight->decision;
  // A uniform offset of 5 µm is systematic (the constant model, significant mean) and compensable.
  const auto offset = Decompose(Sample(13, 400, [](double, double) { return 0.005; }), kDomain, {});
  ASSERT_TRUE(offset.ok());
  EXPECT_EQ(offset->systematic.kind(), FieldModel::Kind::kConstant);
  const auto shifted = EvaluateForm(*offset, 0.004);
  ASSERT_TRUE(shifted.ok());
  EXPECT_TRUE(shifted->systematic_significant);
  EXPECT_TRUE(shifted->compensate) << shifted->decision;
  EXPECT_FALSE(EvaluateForm(*offset, 0).ok());
  EXPECT_FALSE(EvaluateForm(*offset, std::nan("")).ok());
}

// Issue 5 item 5 for the decomposition: too few points, NaN and out-of-domain input are clear errors
// naming the point; a ladder cut short by the point count says so.
TEST(DecompositionTest, BadInputIsRefusedWithAClearMessage) {
  const SmoothField field(3, 5 * kSigmaMm);
  auto few = Decompose(Sample(3, 19, field), kDomain, {});
  ASSERT_FALSE(few.ok());
  EXPECT_EQ(few.status().code(), StatusCode::kBadInput);
  EXPECT_NE(few.status().message().find("19 points are fewer than the 20"), std::string::npos)
      << few.status().message();
  EXPECT_TRUE(Decompose(Sample(3, 20, field), kDomain, {}).ok());

  // 60 points support at most 60 / 5 = 12 parameters: the quadric, not the 4 × 4 B-spline.
  const auto short_ladder = Decompose(Sample(3, 60, field), kDomain, {});
  ASSERT_TRUE(short_ladder.ok()) << short_ladder.status().message();
  for (const auto& s : short_ladder->steps) EXPECT_LE(s.parameters, 12) << s.model;
  // The field needs more than a quadric; the report says why the ladder stopped and what is left.
  EXPECT_FALSE(short_ladder->field_independent);
  EXPECT_NE(short_ladder->stop_reason.find("bspline 4x4 model (16 parameters) needs 80 points; there are 60"),
            std::string::npos)
      << short_ladder->stop_reason;
  EXPECT_NE(short_ladder->stop_reason.find("leaves a spatially correlated residual"), std::string::npos);
  // The filter takes the correlated rest out as d_f (at the points only, never compensated) and says so.
  ASSERT_TRUE(short_ladder->filter.has_value());
  EXPECT_GT(short_ladder->filter->vectors, 0);
  EXPECT_GT(short_ladder->fine_scale_rms_um, 0);
  EXPECT_NE(short_ladder->stop_reason.find("spatial filter"), std::string::npos) << short_ladder->stop_reason;
  // What is left of a 5 σ field beyond a quadric is no chance structure, and the report says so.
  EXPECT_GT(short_ladder->filter->z_before, kFineScaleChanceZ);
  EXPECT_EQ(short_ladder->fine_scale_assessment.rfind("not chance", 0), 0u) << short_ladder->fine_scale_assessment;
  EXPECT_EQ(FineScaleAssessment(2.5).rfind("consistent with chance", 0), 0u);
  EXPECT_NE(FineScaleAssessment(2.5).find("0.0062"), std::string::npos) << FineScaleAssessment(2.5);
  // Without the filter d_u stays correlated and the report says so.
  DecompositionOptions no_filter;
  no_filter.spatial_filter = false;
  const auto unfiltered = Decompose(Sample(3, 60, field), kDomain, no_filter);
  ASSERT_TRUE(unfiltered.ok());
  EXPECT_FALSE(unfiltered->independent);
  EXPECT_FALSE(unfiltered->filter.has_value());
  EXPECT_EQ(unfiltered->systematic.name(), short_ladder->systematic.name());
  EXPECT_EQ(unfiltered->systematic_mm, short_ladder->systematic_mm);

  auto with_nan = Sample(3, 100, field);
  with_nan[41].deviation_mm = std::nan("");
  auto r = Decompose(with_nan, kDomain, {});
  ASSERT_FALSE(r.ok());
  EXPECT_NE(r.status().message().find("point id 42 has a non-finite deviation"), std::string::npos)
      << r.status().message();
  auto with_nan_uv = Sample(3, 100, field);
  with_nan_uv[9].v = std::numeric_limits<double>::infinity();
  r = Decompose(with_nan_uv, kDomain, {});
  ASSERT_FALSE(r.ok());
  EXPECT_NE(r.status().message().find("point id 10 has a non-finite (u, v)"), std::string::npos)
      << r.status().message();
  auto outside = Sample(3, 100, field);
  outside[0].u = kDomain.u_max + 1;
  r = Decompose(outside, kDomain, {});
  ASSERT_FALSE(r.ok());
  EXPECT_NE(r.status().message().find("point id 1 at (u, v)"), std::string::npos) << r.status().message();
  EXPECT_FALSE(Decompose(Sample(3, 100, field), recon::ParamDomain{.u_min = 1, .u_max = 1}, {}).ok());

  DecompositionOptions bad;
  bad.neighbours = 0;
  EXPECT_FALSE(bad.Validate().ok());
  bad = {};
  bad.max_control_net = 2;
  EXPECT_FALSE(bad.Validate().ok());
  bad = {};
  bad.tolerance_mm = -1;
  EXPECT_FALSE(bad.Validate().ok());
  bad = {};
  bad.cv_folds = 1;
  EXPECT_FALSE(bad.Validate().ok());
}

// All deviations equal: a pure offset, reported as such rather than failing in Moran's I.
TEST(DecompositionTest, EqualDeviationsAreAConstantOffset) {
  std::vector<Deviation> same = Sample(5, 50, kZero);
  for (auto& d : same) d.deviation_mm = 0.003;
  const auto d = Decompose(same, kDomain, {});
  ASSERT_TRUE(d.ok()) << d.status().message();
  EXPECT_EQ(d->systematic.kind(), FieldModel::Kind::kConstant);
  EXPECT_NEAR(d->systematic.Evaluate(0, 0), 0.003, 1e-15);
  EXPECT_TRUE(d->independent);
  EXPECT_NE(d->stop_reason.find("all deviations are equal"), std::string::npos);
  EXPECT_EQ(d->random_sigma_um, 0);
}

// Why the filter and not a richer field: on seeds 127, 145 and 164 of the smooth-field test no model
// of the ladder, up to the 14 × 14 net (196 parameters, the most 1,000 points allow at 5 points per
// parameter), is both independent (z ≤ 2.326) and within 0.3 σ RMS of the true field at the points.
// (Seed 127's noise alone has z = 2.75.) Each model is fitted by least squares on its own.
TEST(DecompositionTest, OnSomeSeedsNoLadderModelIsBothIndependentAndAccurate) {
  for (int seed : {127, 145, 164}) {
    Rng pick(static_cast<std::uint64_t>(seed) * 7919);
    const SmoothField field(static_cast<std::uint64_t>(seed), kSigmaMm * pick.Uniform(1.0, 4.0));
    std::vector<double> truth;
    const auto deviations = Sample(static_cast<std::uint64_t>(seed), 1000, field, &truth);
    const Eigen::Index n = static_cast<Eigen::Index>(truth.size());
    Eigen::MatrixXd uv(2, n);
    Eigen::VectorXd y(n);
    for (Eigen::Index i = 0; i < n; ++i) {
      const auto k = static_cast<std::size_t>(i);
      uv.col(i) << deviations[k].u, deviations[k].v;
      y[i] = deviations[k].deviation_mm;
    }
    const auto w = KnnWeights(uv, 8, WeightStyle::kRowStandardised);
    ASSERT_TRUE(w.ok());
    std::printf("seed %d:", seed);
    for (int rung = 0; rung <= 13; ++rung) {  // 0..2 polynomials, then nets 4..14
      auto m = rung <= 2 ? FieldModel::Polynomial(rung, kDomain) : FieldModel::BSpline(rung + 1, kDomain);
      ASSERT_TRUE(m.ok());
      Eigen::MatrixXd x(n, m->parameters());
      for (Eigen::Index i = 0; i < n; ++i) {
        x.row(i) = m->Basis(deviations[static_cast<std::size_t>(i)].u, deviations[static_cast<std::size_t>(i)].v);
      }
      const auto r = ResidualMoranI(y, x, *w);
      ASSERT_TRUE(r.ok());
      const Eigen::VectorXd fit = y - r->residuals;
      double e2 = 0;
      for (Eigen::Index i = 0; i < n; ++i) e2 += std::pow(fit[i] - truth[static_cast<std::size_t>(i)], 2);
      const double error = std::sqrt(e2 / static_cast<double>(n)) / kSigmaMm;
      std::printf(" %s z %.2f err %.2f;", m->name().c_str(), r->z, error);
      EXPECT_FALSE(r->z <= kMoranZCritical && error <= 0.3) << "seed " << seed << ", " << m->name();
    }
    std::printf("\n");
  }
}

}  // namespace
}  // namespace formloop::metrology
