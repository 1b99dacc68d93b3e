#pragma once
// Calibration of a touch-trigger probe on a standard sphere, the ISO 10360-5 probing test, and a
// synthetic generator of sphere probe logs (spec/metrology.md §2).
//
// Measurement model. A reference sphere of certified radius R_s and unknown centre S is probed along
// its normals n (approach a = −n). With the pretravel δ of metrology/probe.h the recorded ball centre is
//   c = S + (R_s + R_eff(a))·n,   R_eff(a) = R_nom − δ(a) = R_eff,0 − lobing(a),
// so each point gives the residual r = ‖c − S‖ − R_s − R_eff,0 + lobing(a). The unknowns are S (3),
// the constant effective radius R_eff,0 and the lobing coefficients a_kj, b_kj; they are fitted jointly
// by nonlinear least squares (Gauss-Newton on the column-pivoted Householder QR of the Jacobian, with
// step halving; the problem is linear in everything but S, so it converges in a few steps from the
// algebraic sphere fit). Standard errors come from σ̂² (JᵀJ)⁻¹ with σ̂² = Σr²/(n − p).
//
// Which terms are fitted. With points on one hemisphere some terms move the ball centres exactly like
// a shift of the sphere centre and cannot be told apart from it:
//  - k = 1 (cos θ, sin θ times any g(φ)) against the centre's x and y (a shift Δx changes the radius by
//    Δx cos φ cos θ, which a low-order polynomial in sin φ reproduces almost exactly);
//  - k = 0, j = 1 (sin φ) against the centre's z (Δz changes the radius by Δz sin φ, exactly);
//  - k = 0, j = 0 is R_eff,0 itself.
// They are never fitted, and the report lists them with that reason. The fitted terms are k = 0 with
// j = 2..D and k = 2..K with j = 0..D, cosine and sine. Elevation terms need points at more than D
// elevations: when the points sit at fewer (e.g. all on the equator) the degree is lowered to what
// the elevations identify and a warning says so. A Jacobian that is still rank-deficient (too few
// azimuths on the rings for the harmonics asked for) is an error naming the parameters; a condition
// number above 1e4 (columns scaled to unit norm) is a warning. So is a touch more than 1° off the
// fitted sphere normal (more than 10° is an error naming the row) and a residual beyond 5 robust σ (MAD); the
// warnings name the ids.
//
// ISO 10360-5 report (ISO 10360-5:2010, "Geometrical product specifications (GPS) — Acceptance and
// reverification tests for coordinate measuring machines (CMM) — Part 5: CMMs using single and
// multiple stylus contacting probing systems"; its pattern is 25 points: the pole, then 4, 8, 4 and 8
// points at 22.5°, 45°, 67.5° and 90° from the pole, i.e. at elevations 67.5°, 45°, 22.5°, 0°): an unconstrained
// least-squares (Gaussian) sphere through the contact points gives the probing form error
// P_form = range of the radial distances and the size error = fitted diameter − certified diameter.
// It is evaluated twice: with the nominal ball and no pretravel model (the probe as the ISO test sees
// it) and with the calibrated profile (what is left after compensation).
//
// References: ISO 10360-5:2010 (above); J. A. Estler et al., "Error compensation for CMM touch trigger
// probes", Precision Engineering 19(2-3):85-97, 1996, and "Practical aspects of touch-trigger probe
// error compensation", Precision Engineering 21(1):1-17, 1997 (lobing model, sphere calibration).

#include <cstdint>
#include <string>
#include <vector>

#include <Eigen/Core>
#include <nlohmann/json.hpp>

#include "core/status.h"
#include "metrology/probe.h"

namespace formloop::metrology {

struct SphereCalibrationOptions {
  double sphere_radius_mm = 0;  // certified radius R_s of the standard sphere (required, > 0)
  double ball_radius_mm = 0;    // nominal stylus-ball radius R_nom (required, > 0)
  int max_order = 3;            // K: azimuth harmonics up to k = K (3 = tri-lobe); 0..3
  // D: degree of g_k in sin φ; 0..3. 0 by default: with the 25-point ISO pattern each elevation degree
  // adds 2 unknowns per harmonic and roughly doubles the variance of the tri-lobe away from the equator
  // (measured in tests/metrology/probe_calibration_test.cc). Raise it when the probe's lobing changes with
  // elevation (Estler 1997) and there are points to pay for it (≥ 50 over 4 elevations).
  int elevation_degree = 0;
  // Points whose sin φ differ by less than this are at the same elevation (counting elevations for the
  // identifiability of the elevation terms). 0.02 ≈ 1.1° at the equator.
  double same_elevation_tolerance = 0.02;
  int max_iterations = 50;  // Gauss-Newton steps; converges in 3-5 from the algebraic start
  // Wanted relative expanded uncertainty (k = 2) of each fitted lobing amplitude (k ≥ 2, j = 0). When a
  // significant amplitude (A > 3 se) is known less well, a warning gives the point count that would
  // reach it (see FittedLobingTerm::points_for_target). 0.10 = 10 % of A.
  double amplitude_target_relative = 0.10;
  Status Validate() const;
};

// A least-squares (Gaussian) sphere through points: ISO 10360-5 evaluation.
struct SphereFit {
  Eigen::Vector3d centre_mm = Eigen::Vector3d::Zero();
  double radius_mm = 0;
  double form_error_mm = 0;  // max − min of the radial distances (P_form)
  double rms_mm = 0;         // RMS of the radial residuals
  nlohmann::json ToJson() const;
};
// Needs at least 4 points not on one plane; BadInput otherwise.
Result<SphereFit> FitSphere(const std::vector<Eigen::Vector3d>& points_mm);

struct FittedLobingTerm {
  int k = 0, j = 0;
  double cos_mm = 0, sin_mm = 0;
  double cos_se_mm = 0, sin_se_mm = 0;  // standard errors (sin_se_mm = 0 for k = 0)
  // k > 0: amplitude A = √(c² + s²) and its standard error by the delta method, √((c·se_c)² + (s·se_s)²)/A
  // (the c, s covariance neglected: the ring designs make it small), and the points that would bring
  // 2·se to options.amplitude_target_relative · A: the variance falls as 1/(points off the pole), so
  // 1 + ⌈(points − 1)(2·se / (target · A))²⌉ (0 when the target is already met).
  double amplitude_mm = 0, amplitude_se_mm = 0;
  int points_for_target = 0;
};

struct SphereCalibrationReport {
  ProbeModel profile;  // R_nom, pretravel = R_nom − R_eff,0 and the fitted lobing: the probe profile
  Eigen::Vector3d centre_mm = Eigen::Vector3d::Zero();         // fitted sphere centre S
  Eigen::Vector3d centre_se_mm = Eigen::Vector3d::Zero();      // its standard errors
  double effective_radius_mm = 0, effective_radius_se_mm = 0;  // R_eff,0
  std::vector<FittedLobingTerm> terms;                         // the fitted terms with standard errors
  int elevation_degree_used = 0;                               // D after the identifiability check
  int points = 0, parameters = 0, iterations = 0;
  std::vector<double> residuals_mm;  // per record, after the fit, in log order
  double residual_rms_mm = 0;        // sqrt(Σr²/n)
  double sigma_mm = 0;               // σ̂ = sqrt(Σr²/(n − p))
  double form_error_mm = 0;          // max − min residual after the fit
  double condition_number = 0;       // of the column-scaled Jacobian at the solution
  SphereFit iso_nominal;             // ISO 10360-5 with the nominal ball, no pretravel model
  double iso_nominal_size_error_mm = 0;
  SphereFit iso_compensated;  // the same after compensation with `profile`
  double iso_compensated_size_error_mm = 0;
  double certified_radius_mm = 0;
  std::vector<std::string> warnings;  // identifiability and point-count warnings (also logged)
  nlohmann::json ToJson() const;
};

// Calibrates on a standard sphere probed along its normals (header comment). Errors: invalid options,
// fewer points than parameters + 1 (names the log and says how many are needed), points at a single
// elevation with only the pole, a rank-deficient Jacobian.
Result<SphereCalibrationReport> CalibrateOnSphere(const ProbeLog& log, const SphereCalibrationOptions& options);

// A pure tri-lobe δ = A cos(3θ − ψ) (K = 3, D = 0): amplitude A in mm, phase ψ in rad.
PretravelLobing TriLobe(double amplitude_mm, double phase_rad);

// Deterministic synthetic sphere probe logs (tests, `formloop calibrate synth-sphere`, the virtual
// machine). Pattern after ISO 10360-5: the pole, then rings at the given elevations; the points other
// than the pole are shared out over the rings in proportion to ring_weights (largest remainder), so
// 25 points give exactly the ISO pattern 1 + 8 (0°) + 4 (22.5°) + 8 (45°) + 4 (67.5°). Every second ring
// is turned by half its point spacing. Ball centres c = S + (R_s + R_eff(a) + e)·n with a = −n and e
// Gaussian radial noise (noise_um σ, seeded core/random.h); ids 1..N in probing order, t = 2 s per point.
struct SphereLogOptions {
  int points = 25;  // 5..10000
  Eigen::Vector3d centre_mm = Eigen::Vector3d(120.0, 80.0, 40.0);
  double sphere_radius_mm = 12.5;  // a 25 mm reference sphere
  ProbeModel probe;                // the true probe: R_nom, pretravel, lobing
  double noise_um = 0.5;           // σ of the radial noise
  std::uint64_t seed = 1;
  std::vector<double> elevations_deg = {0.0, 22.5, 45.0, 67.5};
  std::vector<double> ring_weights = {2, 1, 2, 1};  // empty: equal
  bool pole = true;
  Status Validate() const;
};
Result<ProbeLog> GenerateSphereProbeLog(const SphereLogOptions& options);

}  // namespace formloop::metrology
