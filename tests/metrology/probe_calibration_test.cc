// Probe compensation with direction-dependent pretravel and its calibration on a standard sphere
// (metrology/probe.h, metrology/probe_calibration.h; issue 5 "what it must show" 3).
//
// Every fixture is a seeded synthetic sphere log (GenerateSphereProbeLog) with a known true probe, so
// recovered coefficients are compared with the truth, not with stored numbers.

#include <algorithm>
#include <cmath>
#include <complex>
#include <cstdio>
#include <filesystem>
#include <map>
#include <numbers>
#include <string>
#include <vector>

#include <gtest/gtest.h>
#include <Eigen/Dense>

#include "core/json_io.h"
#include "core/log.h"
#include "core/random.h"
#include "metrology/probe.h"
#include "metrology/probe_calibration.h"

namespace formloop::metrology {
namespace {

namespace fs = std::filesystem;
constexpr double kPi = std::numbers::pi;

// Unit approach a whose probing direction −a has azimuth θ and elevation φ (degrees).
Eigen::Vector3d Approach(double theta_deg, double phi_deg) {
  const double t = theta_deg * kPi / 180, f = phi_deg * kPi / 180;
  return -Eigen::Vector3d(std::cos(f) * std::cos(t), std::cos(f) * std::sin(t), std::sin(f));
}

// The true probe of the recovery tests: R_nom 1 mm, 1.5 µm constant pretravel, a tri-lobe of amplitude
// A and phase ψ.
ProbeModel TrueProbe(double amplitude_um, double phase_rad) {
  ProbeModel probe;
  probe.ball_radius_mm = 1.0;
  probe.pretravel_mm = 0.0015;
  probe.lobing = TriLobe(amplitude_um * 1e-3, phase_rad);
  return probe;
}

SphereCalibrationOptions CalibrationOptions() {
  SphereCalibrationOptions o;
  o.sphere_radius_mm = 12.5;
  o.ball_radius_mm = 1.0;
  return o;
}

// Complex k = 3 coefficient Σ_j (a_3j + i b_3j) sin^j φ of a lobing model at elevation φ (deg).
std::complex<double> TriLobeAt(const PretravelLobing& lobing, double phi_deg) {
  if (lobing.max_order < 3) return 0.0;
  const double s = std::sin(phi_deg * kPi / 180);
  std::complex<double> c = 0;
  double power = 1;
  for (int j = 0; j <= lobing.elevation_degree; ++j, power *= s) {
    c += power * std::complex<double>(lobing.cos_mm(3, j), lobing.sin_mm(3, j));
  }
  return c;
}

// Largest error of the recovered tri-lobe over the calibrated ring elevations, mm.
double TriLobeError(const PretravelLobing& fitted, const PretravelLobing& truth) {
  double worst = 0;
  for (double phi : {0.0, 22.5, 45.0, 67.5})
    worst = std::max(worst, std::abs(TriLobeAt(fitted, phi) - TriLobeAt(truth, phi)));
  return worst;
}

// Largest |δ_fitted − δ_true| over directions on the calibrated band (θ every 5°, φ 0..67.5°), mm.
double PretravelError(const ProbeModel& fitted, const ProbeModel& truth) {
  double worst = 0;
  for (double phi = 0; phi <= 67.5; phi += 7.5) {
    for (double theta = 0; theta < 360; theta += 5) {
      const Eigen::Vector3d a = Approach(theta, phi);
      worst = std::max(worst, std::abs(fitted.Pretravel(a) - truth.Pretravel(a)));
    }
  }
  return worst;
}

TEST(ProbeModelTest, ContactPointIsCentrePlusEffectiveRadiusAlongTheApproach) {
  ProbeModel model;
  model.ball_radius_mm = 2.0;
  model.pretravel_mm = 0.003;
  model.lobing = TriLobe(0.004, 0.0);  // δ_lobing = 4 µm · cos 3θ
  ProbeRecord r;
  r.centre = Eigen::Vector3d(10, 20, 30);
  // Horizontal touch in −x: probing direction +x, θ = 0, cos 3θ = 1: δ = 3 + 4 µm, R_eff = 1.993 mm.
  r.approach = Eigen::Vector3d(-1, 0, 0);
  EXPECT_NEAR(model.EffectiveRadius(r.approach), 2.0 - 0.007, 1e-15);
  EXPECT_TRUE(ContactPoint(r, model).isApprox(Eigen::Vector3d(10 - 1.993, 20, 30), 1e-15));
  // θ = 60°: cos 180° = −1: δ = 3 − 4 µm, R_eff = 2.001 mm.
  r.approach = Approach(60, 0);
  EXPECT_NEAR(model.EffectiveRadius(r.approach), 2.001, 1e-15);
  EXPECT_TRUE(ContactPoint(r, model).isApprox(r.centre + 2.001 * r.approach, 1e-15));
  // Vertical touch from above (the pole): azimuth undefined, only the constant part applies.
  r.approach = Eigen::Vector3d(0, 0, -1);
  EXPECT_NEAR(model.EffectiveRadius(r.approach), 1.997, 1e-15);
  EXPECT_TRUE(ContactPoint(r, model).isApprox(Eigen::Vector3d(10, 20, 30 - 1.997), 1e-15));
  // The default model is the constant-pretravel model of before: R_nom − pretravel in every direction.
  ProbeModel constant;
  constant.ball_radius_mm = 1.0;
  constant.pretravel_mm = 0.002;
  for (double theta : {0.0, 17.0, 200.0}) EXPECT_EQ(constant.EffectiveRadius(Approach(theta, 30)), 0.998);
}

TEST(ProbeModelTest, AnglesAreThoseOfTheProbingDirection) {
  ProbingAngles a = AnglesOfApproach(Approach(135, 30));
  EXPECT_NEAR(a.azimuth_rad, 0.75 * kPi, 1e-14);
  EXPECT_NEAR(a.elevation_rad, kPi / 6, 1e-14);
  EXPECT_FALSE(a.at_pole);
  a = AnglesOfApproach(Eigen::Vector3d(0, 0, -1));
  EXPECT_TRUE(a.at_pole);
  EXPECT_NEAR(a.elevation_rad, kPi / 2, 1e-15);
  // Elevation terms: δ = (1 + 2 sin φ) µm for k = 0, j = 0..1.
  PretravelLobing l = PretravelLobing::Zero(0, 1);
  l.cos_mm(0, 0) = 0.001;
  l.cos_mm(0, 1) = 0.002;
  EXPECT_NEAR(l.Evaluate(Approach(10, 30)), 0.002, 1e-15);
  EXPECT_NEAR(l.Evaluate(Approach(10, 0)), 0.001, 1e-15);
}

TEST(ProbeModelTest, ValidateRejectsImplausibleModels) {
  ProbeModel m;
  m.lobing = TriLobe(2.0, 0.0);  // 2 mm lobing on a 1 mm ball: units mixed up
  Status s = m.Validate();
  EXPECT_FALSE(s.ok());
  EXPECT_NE(s.message().find("probe.lobing"), std::string::npos) << s.message();
  m.lobing = PretravelLobing::Zero(3, 0);
  m.lobing.sin_mm(0, 0) = 1e-3;
  s = m.Validate();
  EXPECT_FALSE(s.ok());
  EXPECT_NE(s.message().find("k = 0"), std::string::npos) << s.message();
}

class ProbeProfileTest : public ::testing::Test {
 protected:
  void SetUp() override {
    log::SetLevel(log::Level::kError);
    dir_ = fs::temp_directory_path() /
           ("formloop-profile-" + std::string(::testing::UnitTest::GetInstance()->current_test_info()->name()));
    fs::remove_all(dir_);
    fs::create_directories(dir_);
  }
  void TearDown() override { fs::remove_all(dir_); }
  Status ReadBad(const std::string& json_text) {
    const fs::path path = dir_ / "bad.json";
    std::FILE* f = std::fopen(path.c_str(), "w");
    std::fputs(json_text.c_str(), f);
    std::fclose(f);
    return ReadProbeProfile(path).status();
  }
  fs::path dir_;
};

TEST_F(ProbeProfileTest, RoundTripsExactly) {
  ProbeModel m;
  m.ball_radius_mm = 1.5;
  m.pretravel_mm = 0.0012;
  m.lobing = PretravelLobing::Zero(3, 1);
  m.lobing.cos_mm(3, 0) = 0.004;
  m.lobing.sin_mm(3, 0) = -0.0021;
  m.lobing.cos_mm(3, 1) = 0.0007;
  m.lobing.cos_mm(0, 1) = -0.0003;
  m.lobing.sin_mm(2, 1) = 1.0 / 3.0 * 1e-3;
  const fs::path path = dir_ / "p.json";
  ASSERT_TRUE(WriteProbeProfile(path, m, nlohmann::json{{"note", "test"}}).ok());
  Result<ProbeModel> back = ReadProbeProfile(path);
  ASSERT_TRUE(back.ok()) << back.status().ToString();
  EXPECT_EQ(back->ball_radius_mm, m.ball_radius_mm);
  EXPECT_EQ(back->pretravel_mm, m.pretravel_mm);
  EXPECT_EQ(back->lobing.max_order, 3);
  EXPECT_EQ(back->lobing.elevation_degree, 1);
  EXPECT_EQ(back->lobing.cos_mm, m.lobing.cos_mm);
  EXPECT_EQ(back->lobing.sin_mm, m.lobing.sin_mm);
}

TEST_F(ProbeProfileTest, BadProfilesNameTheField) {
  const std::string head = R"({"format": "formloop probe profile", "version": 1, "ball_radius_mm": 1, )";
  struct Case {
    std::string text, field;
  };
  const std::vector<Case> cases = {
      {R"({"format": "x", "version": 1, "ball_radius_mm": 1, "pretravel_mm": 0})", "'format'"},
      {head + R"("pretravel_mm": 0, "version2": 3})", "'version2'"},
      {head + R"("pretravel_mm": "0"})", "'pretravel_mm'"},
      {head + R"("pretravel_mm": 0, "lobing": {"max_order": 4, "elevation_degree": 0}})", "'lobing.max_order'"},
      {head +
           R"("pretravel_mm": 0, "lobing": {"max_order": 3, "elevation_degree": 0, "terms": [{"k": 3, "j": 1, "cos_mm": 0}]}})",
       "'lobing.terms[0].j'"},
      {head +
           R"("pretravel_mm": 0, "lobing": {"max_order": 3, "elevation_degree": 0, "terms": [{"k": 3, "j": 0, "cos_mm": 0}, {"k": 3, "j": 0, "cos_mm": 1e-3}]}})",
       "'lobing.terms[1].k'"},
      {head +
           R"("pretravel_mm": 0, "lobing": {"max_order": 3, "elevation_degree": 0, "terms": [{"k": 0, "j": 0, "cos_mm": 0, "sin_mm": 1e-3}]}})",
       "'lobing.terms[0].sin_mm'"},
      {head + R"("pretravel_mm": 0, "lobing": {"max_order": 3, "elevation_degree": 0, "terms": [{"k": 3, "j": 0}]}})",
       "'lobing.terms[0].cos_mm'"},
  };
  for (const Case& c : cases) {
    const Status s = ReadBad(c.text);
    EXPECT_EQ(s.code(), StatusCode::kBadInput) << c.text;
    EXPECT_NE(s.message().find("bad.json"), std::string::npos) << s.message();
    EXPECT_NE(s.message().find(c.field), std::string::npos) << "want " << c.field << " in: " << s.message();
  }
}

TEST(SphereLogTest, IsoPatternAndExactGeometry) {
  SphereLogOptions o;
  o.probe = TrueProbe(5, 0.3);
  o.noise_um = 0;
  Result<ProbeLog> log = GenerateSphereProbeLog(o);
  ASSERT_TRUE(log.ok()) << log.status().ToString();
  ASSERT_EQ(log->records.size(), 25u);
  // ISO 10360-5: the pole, 4 at 67.5°, 8 at 45°, 4 at 22.5°, 8 on the equator (elevation of −a).
  std::map<long, int> by_elevation;
  for (const ProbeRecord& r : log->records) {
    ++by_elevation[std::lround(AnglesOfApproach(r.approach).elevation_rad * 180 / kPi * 10)];
    // c = S + (R_s + R_eff(a))·n with n = −a, exactly.
    EXPECT_NEAR((r.centre - o.centre_mm).norm(), o.sphere_radius_mm + o.probe.EffectiveRadius(r.approach), 1e-12);
  }
  EXPECT_EQ(by_elevation, (std::map<long, int>{{900, 1}, {675, 4}, {450, 8}, {225, 4}, {0, 8}}));
  // Deterministic: the same seed gives the same log, another seed another noise draw.
  o.noise_um = 0.5;
  Result<ProbeLog> a = GenerateSphereProbeLog(o), b = GenerateSphereProbeLog(o);
  o.seed = 2;
  Result<ProbeLog> c = GenerateSphereProbeLog(o);
  ASSERT_TRUE(a.ok() && b.ok() && c.ok());
  for (std::size_t i = 0; i < 25; ++i) EXPECT_EQ(a->records[i].centre, b->records[i].centre);
  EXPECT_NE(a->records[3].centre, c->records[3].centre);
  // 50 and 100 points keep the 2:1:2:1 share over the rings.
  for (int n : {50, 100}) {
    o.points = n;
    Result<ProbeLog> big = GenerateSphereProbeLog(o);
    ASSERT_TRUE(big.ok());
    EXPECT_EQ(static_cast<int>(big->records.size()), n);
  }
}

TEST(SphereCalibrationTest, NoiseFreeLogIsRecoveredExactly) {
  SphereLogOptions o;
  o.probe = TrueProbe(6, 1.1);
  o.probe.lobing = PretravelLobing::Zero(3, 1);  // a general model inside the fitted family
  o.probe.lobing.cos_mm(3, 0) = 0.004;
  o.probe.lobing.sin_mm(3, 0) = -0.003;
  o.probe.lobing.cos_mm(3, 1) = -0.0015;
  o.probe.lobing.sin_mm(2, 0) = 0.0008;
  o.noise_um = 0;
  o.points = 50;
  Result<ProbeLog> log = GenerateSphereProbeLog(o);
  ASSERT_TRUE(log.ok());
  SphereCalibrationOptions options = CalibrationOptions();
  options.elevation_degree = 1;
  Result<SphereCalibrationReport> cal = CalibrateOnSphere(*log, options);
  ASSERT_TRUE(cal.ok()) << cal.status().ToString();
  EXPECT_TRUE(cal->centre_mm.isApprox(o.centre_mm, 1e-12));
  EXPECT_NEAR(cal->profile.pretravel_mm, o.probe.pretravel_mm, 1e-10);
  EXPECT_LT(PretravelError(cal->profile, o.probe), 1e-10);
  EXPECT_LT(cal->form_error_mm, 1e-10);
  EXPECT_LT(cal->iso_compensated.form_error_mm, 1e-10);
  EXPECT_NEAR(cal->iso_compensated_size_error_mm, 0, 1e-10);
  EXPECT_GT(cal->iso_nominal.form_error_mm, 0.005);  // the lobing is what the ISO test sees
  EXPECT_TRUE(cal->warnings.empty());
  EXPECT_LE(cal->iterations, 10);
}

// Standard error of the complex tri-lobe coefficient at elevation φ from the reported coefficient standard
// errors (Σ_j sin^j φ · max(se_cos, se_sin): an upper bound that needs no covariances), mm.
double TriLobeStandardError(const SphereCalibrationReport& cal, double phi_deg) {
  double se = 0;
  for (const FittedLobingTerm& t : cal.terms) {
    if (t.k == 3) se += std::pow(std::sin(phi_deg * kPi / 180), t.j) * std::max(t.cos_se_mm, t.sin_se_mm);
  }
  return se;
}

// Issue 5, "what it must show" 3: a tri-lobe of amplitude A in [2, 10] µm and random phase plus 0.5 µm
// noise, calibrated from 25, 50 and 100 sphere points (default options: K = 3, D = 0).
//
// What 10 % can mean here. The recovered tri-lobe is a linear estimate from the ring points; with noise σ
// its cosine and sine coefficients have standard error σ·√(2/m) for m ring points (σ√(2/24) = 0.14 µm at
// 25 points, 0.10 µm at 50, 0.071 µm at 100), whatever the estimator. 10 % of A is inside 3 such
// standard errors only from A ≈ 4.3 µm (25 points), 3.0 µm (50) and 2.1 µm (100) on; below that no fit can
// promise it. So the test asserts, for every case, that the error is within max(10 % A, 3·se) with se the
// standard error the calibration itself reports, and within 10 % A outright wherever 3·se ≤ 10 % A. The
// error is the complex one, |ĉ₃ − c₃| (amplitude and phase together); the amplitude error |Â − A| is
// printed beside it.
TEST(SphereCalibrationTest, TriLobeIsRecoveredWithinTenPercentWhereTheNoiseAllows) {
  std::printf("%6s %5s %7s %9s %10s %10s %9s %10s %9s %9s %9s\n", "points", "seed", "A_um", "phase_deg", "err/A",
              "|dA|/A", "3se/A", "pretr_e/A", "Pform0_um", "Pform1_um", "size0_um");
  int within_ten_percent = 0, cases = 0;
  for (int points : {25, 50, 100}) {
    for (std::uint64_t seed = 1; seed <= 10; ++seed) {
      Rng rng(1000 + seed);
      const double amplitude_um = rng.Uniform(2, 10), phase = rng.Uniform(0, 2 * kPi);
      SphereLogOptions o;
      o.probe = TrueProbe(amplitude_um, phase);
      o.points = points;
      o.seed = seed;
      Result<ProbeLog> log = GenerateSphereProbeLog(o);
      ASSERT_TRUE(log.ok());
      Result<SphereCalibrationReport> cal = CalibrateOnSphere(*log, CalibrationOptions());
      ASSERT_TRUE(cal.ok()) << cal.status().ToString();
      const double a_mm = amplitude_um * 1e-3;
      const double err = TriLobeError(cal->profile.lobing, o.probe.lobing);
      const double amplitude_err = std::abs(std::abs(TriLobeAt(cal->profile.lobing, 0)) - a_mm);
      const double se = TriLobeStandardError(*cal, 0);
      std::printf("%6d %5d %7.3f %9.1f %10.4f %10.4f %9.4f %10.4f %9.3f %9.3f %9.3f\n", points, static_cast<int>(seed),
                  amplitude_um, phase * 180 / kPi, err / a_mm, amplitude_err / a_mm, 3 * se / a_mm,
                  PretravelError(cal->profile, o.probe) / a_mm, cal->iso_nominal.form_error_mm * 1e3,
                  cal->form_error_mm * 1e3, cal->iso_nominal_size_error_mm * 1e3);
      ++cases;
      within_ten_percent += err <= 0.1 * a_mm ? 1 : 0;
      EXPECT_LE(err, std::max(0.1 * a_mm, 3 * se)) << points << " points, seed " << seed;
      if (3 * se <= 0.1 * a_mm) {
        EXPECT_LE(err, 0.1 * a_mm) << points << " points, seed " << seed;
      }
      // The reported standard error is of the order of the design's σ√(2/m): not exactly, since σ̂ is
      // estimated from n − p residuals (±17 % at 25 points) and the 4-point rings carry k = 3 poorly.
      const double design_se = 0.5e-3 * std::sqrt(2.0 / (points - 1));
      EXPECT_GT(se, 0.6 * design_se);
      EXPECT_LT(se, 1.8 * design_se);
      // ISO 10360-5 with the nominal ball sees the lobing: P_form about 2 A; after the fit, the noise.
      EXPECT_GT(cal->iso_nominal.form_error_mm, 1.5 * a_mm);
      EXPECT_LT(cal->iso_compensated.form_error_mm, 8 * 0.5e-3);
    }
  }
  std::printf("within 10 %% of A: %d of %d cases\n", within_ten_percent, cases);
}

// Elevation-dependent lobing g_3(φ) = 1 − 0.6 sin φ is recovered with --elevation-degree 1 from 100 points.
// Where the noise does not allow 10 %, the calibration says so and how many points would: at A = 2 µm
// from 25 points the amplitude's expanded uncertainty is about 15 % of A; the advised count then
// brings it within 10 %. At A = 10 µm from 25 points nothing is advised.
TEST(SphereCalibrationTest, AdvisesThePointCountForATenPercentAmplitude) {
  auto term3 = [](const SphereCalibrationReport& cal) {
    for (const auto& t : cal.terms) {
      if (t.k == 3 && t.j == 0) return t;
    }
    return FittedLobingTerm{};
  };
  SphereLogOptions o;
  o.probe = TrueProbe(2.0, 0.7);
  o.points = 25;
  o.seed = 3;
  auto cal = CalibrateOnSphere(*GenerateSphereProbeLog(o), CalibrationOptions());
  ASSERT_TRUE(cal.ok());
  const FittedLobingTerm t = term3(*cal);
  EXPECT_NEAR(t.amplitude_mm, 2e-3, 0.5e-3);
  EXPECT_GT(2 * t.amplitude_se_mm, 0.1 * t.amplitude_mm);
  EXPECT_GE(t.points_for_target, 40);
  EXPECT_LE(t.points_for_target, 90);
  const bool warned = std::any_of(cal->warnings.begin(), cal->warnings.end(), [&](const std::string& w) {
    return w.find("k = 3 lobing amplitude") != std::string::npos &&
           w.find("probe about " + std::to_string(t.points_for_target) + " points") != std::string::npos;
  });
  EXPECT_TRUE(warned);
  EXPECT_EQ(cal->ToJson()["fit"]["terms"].size(), cal->terms.size());

  o.points = t.points_for_target;
  auto more = CalibrateOnSphere(*GenerateSphereProbeLog(o), CalibrationOptions());
  ASSERT_TRUE(more.ok());
  const FittedLobingTerm t_more = term3(*more);
  std::printf("A = 2 um: 25 points give +-%.3f um (k = 2); the advised %d points give +-%.3f um\n",
              2e3 * t.amplitude_se_mm, t.points_for_target, 2e3 * t_more.amplitude_se_mm);
  EXPECT_LE(2 * t_more.amplitude_se_mm, 0.11 * 2e-3);  // σ̂ itself varies by ±10 % or so

  o.probe = TrueProbe(10.0, 0.7);
  o.points = 25;
  auto big = CalibrateOnSphere(*GenerateSphereProbeLog(o), CalibrationOptions());
  ASSERT_TRUE(big.ok());
  EXPECT_EQ(term3(*big).points_for_target, 0);
  for (const auto& w : big->warnings) EXPECT_EQ(w.find("lobing amplitude"), std::string::npos) << w;
}

// The study behind the note on item 3 (run with --gtest_also_run_disabled_tests): for each point count
// and amplitude, 500 seeds of random phase; the share of seeds whose amplitude |Â − A| and complex
// coefficient |ĉ₃ − c₃| are within 10 % of A, the empirical RMS of the complex error per component
// against the design's σ√(2/m) (m = points − 1 off the pole), and the share an efficient unbiased
// estimator would reach, P(|N(0, se)| ≤ 0.1 A) with se = the RMS per component measured.
TEST(SphereCalibrationTest, DISABLED_TriLobeRecoveryStudy) {
  std::printf("%6s %6s %10s %10s %12s %12s %12s\n", "points", "A_um", "|dA|<=10%", "|dc|<=10%", "rms_comp_um",
              "sqrt(2/m)s", "efficient");
  for (int points : {25, 50, 100}) {
    for (double amplitude_um : {2.0, 3.0, 5.0, 10.0}) {
      int amp_ok = 0, complex_ok = 0;
      double sum2 = 0;
      const int seeds = 500;
      for (int seed = 1; seed <= seeds; ++seed) {
        Rng rng(50000 + static_cast<std::uint64_t>(seed));
        const double phase = rng.Uniform(0, 2 * kPi);
        SphereLogOptions o;
        o.probe = TrueProbe(amplitude_um, phase);
        o.points = points;
        o.seed = static_cast<std::uint64_t>(seed) + 7000;
        Result<ProbeLog> log = GenerateSphereProbeLog(o);
        ASSERT_TRUE(log.ok());
        Result<SphereCalibrationReport> cal = CalibrateOnSphere(*log, CalibrationOptions());
        ASSERT_TRUE(cal.ok());
        const double a_mm = amplitude_um * 1e-3;
        const std::complex<double> dc = TriLobeAt(cal->profile.lobing, 0) - TriLobeAt(o.probe.lobing, 0);
        sum2 += std::norm(dc) / 2;
        amp_ok += std::abs(std::abs(TriLobeAt(cal->profile.lobing, 0)) - a_mm) <= 0.1 * a_mm;
        complex_ok += std::abs(dc) <= 0.1 * a_mm;
      }
      const double rms_um = 1e3 * std::sqrt(sum2 / seeds);
      const double design_um = 0.5 * std::sqrt(2.0 / (points - 1));
      const double efficient = std::erf(0.1 * amplitude_um / (rms_um * std::sqrt(2.0)));
      std::printf("%6d %6.1f %9.1f%% %9.1f%% %12.4f %12.4f %11.1f%%\n", points, amplitude_um, 100.0 * amp_ok / seeds,
                  100.0 * complex_ok / seeds, rms_um, design_um, 100 * efficient);
      std::fflush(stdout);
    }
  }
}

TEST(SphereCalibrationTest, ElevationDependentLobingIsRecoveredWithDegreeOne) {
  for (std::uint64_t seed = 1; seed <= 5; ++seed) {
    SphereLogOptions o;
    o.probe = TrueProbe(6, 0.7 * static_cast<double>(seed));
    o.probe.lobing = PretravelLobing::Zero(3, 1);
    o.probe.lobing.cos_mm.row(3) << 0.006 * std::cos(0.7 * seed), -0.0036 * std::cos(0.7 * seed);
    o.probe.lobing.sin_mm.row(3) << 0.006 * std::sin(0.7 * seed), -0.0036 * std::sin(0.7 * seed);
    o.points = 100;
    o.seed = 50 + seed;
    Result<ProbeLog> log = GenerateSphereProbeLog(o);
    ASSERT_TRUE(log.ok());
    SphereCalibrationOptions options = CalibrationOptions();
    options.elevation_degree = 1;
    Result<SphereCalibrationReport> cal = CalibrateOnSphere(*log, options);
    ASSERT_TRUE(cal.ok()) << cal.status().ToString();
    EXPECT_EQ(cal->elevation_degree_used, 1);
    const double err = TriLobeError(cal->profile.lobing, o.probe.lobing);
    std::printf("seed %d: tri-lobe error %.4f µm = %.2f %% of 6 µm\n", static_cast<int>(seed), err * 1e3,
                err / 0.006 * 100);
    EXPECT_LE(err, 0.1 * 0.006);
    // With D = 0 the same data leave the elevation trend in the residuals: a larger form error.
    options.elevation_degree = 0;
    Result<SphereCalibrationReport> flat = CalibrateOnSphere(*log, options);
    ASSERT_TRUE(flat.ok());
    EXPECT_GT(flat->residual_rms_mm, 1.5 * cal->residual_rms_mm);
  }
}

// Regression of values y on [1, cos 3θ, sin 3θ]: the tri-lobe amplitude √(c² + s²) and its standard error
// (σ̂ √(2/n)-like, from σ̂² (XᵀX)⁻¹ on the two harmonic coefficients, taking the larger).
struct TriLobeRegression {
  double amplitude = 0, standard_error = 0;
};
TriLobeRegression RegressOnTriLobe(const std::vector<double>& theta, const std::vector<double>& y) {
  const int n = static_cast<int>(y.size());
  Eigen::MatrixXd X(n, 3);
  Eigen::VectorXd Y(n);
  for (int i = 0; i < n; ++i) {
    X.row(i) << 1.0, std::cos(3 * theta[i]), std::sin(3 * theta[i]);
    Y(i) = y[i];
  }
  const Eigen::Vector3d beta = X.colPivHouseholderQr().solve(Y);
  const double sigma2 = (Y - X * beta).squaredNorm() / (n - 3);
  const Eigen::Matrix3d cov = sigma2 * (X.transpose() * X).inverse();
  return {std::hypot(beta(1), beta(2)), std::sqrt(std::max(cov(1, 1), cov(2, 2)))};
}

// Issue 5, "what it must show" 3, second half: after applying the calibrated profile, deviations of a
// part probed from many azimuths carry no direction-correlated (tri-lobe) residual.
//
// The part is a perfect convex dome (sphere of radius 40 mm) probed along its normals at 5 elevations
// (20°..60°) × 36 azimuths with the true probe and fresh 0.5 µm noise; its deviations are the radial
// distances of the contact points to the dome. Bound on the tri-lobe left after compensation: what is
// left is the calibration's own error of the tri-lobe, whose standard error se_cal the calibration
// reports, plus the estimation noise of the regression on the part, se_reg; both are Gaussian, so the
// amplitude stays below 3·√(se_cal² + se_reg²) unless the model is wrong (a 3σ bound; with 180 part
// points and a 50-point calibration that is about 0.4 µm, under the 0.5 µm noise σ).
TEST(SphereCalibrationTest, CompensatedPartDeviationsShowNoDirectionCorrelatedResidual) {
  std::printf("%5s %7s %14s %12s %14s %12s %9s\n", "seed", "A_um", "before_amp_um", "before_t", "after_amp_um",
              "bound_um", "after_t");
  for (std::uint64_t seed = 1; seed <= 6; ++seed) {
    Rng rng(2000 + seed);
    const double amplitude_um = rng.Uniform(2, 10), phase = rng.Uniform(0, 2 * kPi);
    const ProbeModel truth = TrueProbe(amplitude_um, phase);
    SphereLogOptions o;
    o.probe = truth;
    o.points = 50;
    o.seed = seed;
    Result<ProbeLog> sphere_log = GenerateSphereProbeLog(o);
    ASSERT_TRUE(sphere_log.ok());
    Result<SphereCalibrationReport> cal = CalibrateOnSphere(*sphere_log, CalibrationOptions());
    ASSERT_TRUE(cal.ok()) << cal.status().ToString();

    // The part, probed with the true probe.
    const Eigen::Vector3d dome_centre(30, -10, -25);
    const double dome_radius = 40;
    Rng noise(3000 + seed);
    std::vector<ProbeRecord> records;
    std::vector<double> theta;
    for (double phi : {20.0, 30.0, 40.0, 50.0, 60.0}) {
      for (int i = 0; i < 36; ++i) {
        const double az = 10.0 * i + 2.5 * phi / 10;  // rings turned against each other
        ProbeRecord r;
        r.approach = Approach(az, phi);
        const Eigen::Vector3d n = -r.approach;
        r.centre = dome_centre + (dome_radius + truth.EffectiveRadius(r.approach) + 0.5e-3 * noise.Normal()) * n;
        records.push_back(r);
        theta.push_back(az * kPi / 180);
      }
    }
    ProbeModel nominal;  // radius compensation only, as before this issue
    nominal.ball_radius_mm = 1.0;
    nominal.pretravel_mm = cal->profile.pretravel_mm;  // even with the right constant pretravel
    std::vector<double> before_um, after_um;
    for (const ProbeRecord& r : records) {
      before_um.push_back(((ContactPoint(r, nominal) - dome_centre).norm() - dome_radius) * 1e3);
      after_um.push_back(((ContactPoint(r, cal->profile) - dome_centre).norm() - dome_radius) * 1e3);
    }
    const TriLobeRegression before = RegressOnTriLobe(theta, before_um);
    const TriLobeRegression after = RegressOnTriLobe(theta, after_um);
    double se_cal_um = 0;
    for (const FittedLobingTerm& t : cal->terms) {
      if (t.k == 3) se_cal_um += std::max(t.cos_se_mm, t.sin_se_mm) * 1e3;  // Σ_j se_j ≥ se of Σ_j c_j s^j
    }
    const double bound_um = 3 * std::hypot(se_cal_um, after.standard_error);
    std::printf("%5d %7.3f %14.4f %12.1f %14.4f %12.4f %9.2f\n", static_cast<int>(seed), amplitude_um, before.amplitude,
                before.amplitude / before.standard_error, after.amplitude, bound_um,
                after.amplitude / after.standard_error);
    // Before: the full tri-lobe, highly significant. After: below the 3σ bound and under the noise σ.
    EXPECT_NEAR(before.amplitude, amplitude_um, 0.1 * amplitude_um);
    EXPECT_GT(before.amplitude / before.standard_error, 10);
    EXPECT_LT(after.amplitude, bound_um) << "seed " << seed;
    EXPECT_LT(bound_um, 0.5);
  }
}

}  // namespace
}  // namespace formloop::metrology
