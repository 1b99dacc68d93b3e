#pragma once
// Probing plans, probe logs, probe models and probe profiles (spec/metrology.md §1, §2).
//
// A probe log row is `id, x, y, z, ax, ay, az, t`: the stylus-ball centre c at trigger (machine
// frame, mm), the unit approach direction a (from the probe towards the surface) and the time (s).
// The contact point is p = c + R_eff(a)·a with R_eff(a) = R_nom − δ(a), where δ is the pretravel:
// the ball centre lags along a by δ when the trigger fires.
//
// Direction-dependent pretravel ("lobing"). Kinematic-seat touch-trigger probes trigger after a
// deflection that depends on the direction of the contact force, with a 3-fold pattern in azimuth
// from the three seats and a dependence on elevation (Estler, Phillips, Borchardt, Hopp, Witzgall,
// Levenson, Eberhardt, McClain, Shen, Zhang: "Error compensation for CMM touch trigger probes",
// Precision Engineering 19(2-3):85-97, 1996; Estler et al., "Practical aspects of touch-trigger
// probe error compensation", Precision Engineering 21(1):1-17, 1997). The model here is
//
//   δ(θ, φ) = pretravel_mm + Σ_{k=0..K} Σ_{j=0..D} sin^j φ · [a_kj cos kθ + b_kj sin kθ]
//
// i.e. Σ_k [a_k cos kθ + b_k sin kθ]·g_k(φ) with g_k a polynomial of degree D in sin φ. The angles are
// those of the probing direction d = −a (from the contact towards the ball centre; the outward surface
// normal when probing along the normal): θ = atan2(d_y, d_x) is its azimuth in the machine XY plane and
// φ = asin(d_z) its elevation (φ = 90° for a vertical touch from above). At the pole (|d_xy| < 1e-9) the
// azimuth is undefined and only the k = 0 terms apply. The ISO 10360-5 test of a probing system and the
// calibration on a standard sphere that determines the coefficients are in metrology/probe_calibration.h.

#include <cstdint>
#include <filesystem>
#include <string>
#include <vector>

#include <Eigen/Core>
#include <nlohmann/json.hpp>

#include "core/status.h"
#include "reconstruction/bspline_surface.h"

namespace formloop::metrology {

// A planned probe point on the ideal surface Q.
struct ProbePoint {
  std::int64_t id = 0;
  double u = 0, v = 0;                                // parameters on Q
  Eigen::Vector3d point = Eigen::Vector3d::Zero();    // nominal point on Q, mm
  Eigen::Vector3d normal = Eigen::Vector3d::UnitZ();  // unit outward normal of Q there
};

struct ProbingPlan {
  std::vector<ProbePoint> points;
  // On a trimmed Q (reconstruction/trim.h): the margin kept from the trim's edges and how many planned
  // positions were left out (outside the trim, or nearer its edge than the margin).
  bool trimmed = false;
  double edge_margin_mm = 0;
  int left_out = 0;
  nlohmann::json ToJson() const;
};

// Default margin of probe points from a trim's edge (3-D distance, mm): the 1 mm radius of the usual
// stylus ball, which touches the part up to that far around the point on a tilted approach, plus 1 mm
// for the part's set-up and the edge's own tolerance.
inline constexpr double kProbeEdgeMarginMm = 2.0;

// nu × nv points equidistant in parameter space, inset from the domain edges by `inset_fraction`
// of each span (probing right at an edge risks missing the part). Ids are 1..nu·nv, row-major. On a
// trimmed Q, positions outside the trim (OpenCASCADE's classification) or nearer than edge_margin_mm
// to one of its loops (3-D distance) are left out, keeping the ids of the others; BadInput when none is
// left.
Result<ProbingPlan> PlanProbingGrid(const recon::BSplineSurface& surface, int nu, int nv, double inset_fraction,
                                    double edge_margin_mm = kProbeEdgeMarginMm);
// True when a probe point at (u, v) with nominal point p may be planned on Q: always without a trim,
// else inside it and at least edge_margin_mm from its loops.
bool ProbePositionAllowed(const recon::BSplineSurface& surface, double u, double v, const Eigen::Vector3d& p,
                          double edge_margin_mm);

struct ProbeRecord {
  std::int64_t id = 0;
  Eigen::Vector3d centre = Eigen::Vector3d::Zero();      // ball centre at trigger, mm
  Eigen::Vector3d approach = -Eigen::Vector3d::UnitZ();  // unit approach direction
  double t_s = 0;
  long line = 0;  // 1-based line in the log file it was read from; 0 = not read from a file
};

struct ProbeLog {
  std::vector<ProbeRecord> records;
  std::string source;  // the file it was read from (for messages); empty when made in memory
};

// Largest accepted |‖a‖ − 1| of an approach vector in a log. Vectors within it are rescaled to unit
// length (rounding of the written digits: 6 decimals give at most 0.9e-6); beyond it the row is an
// error naming the line, since a vector that is not unit usually means a wrong column or a normal
// that was never normalised, and guessing would hide that.
inline constexpr double kApproachUnitTolerance = 1e-5;

// Reads a probe log (CSV with the columns id,x,y,z,ax,ay,az,t in any order; '#' comments). Errors
// name the file, the line and the field: missing columns, non-numbers, zero or non-unit approach
// vectors (kApproachUnitTolerance), duplicated ids.
Result<ProbeLog> ReadProbeLog(const std::filesystem::path& path);
Status WriteProbeLog(const std::filesystem::path& path, const ProbeLog& log);

// Checks a log against the plan it was measured with: every id must be a planned id (an error naming
// the line otherwise). Returns the planned ids that have no record (not an error: a probe that missed
// the part is reported by the caller), in plan order.
Result<std::vector<std::int64_t>> CheckProbeLogAgainstPlan(const ProbeLog& log, const ProbingPlan& plan);

// Azimuth θ (rad, in (−π, π]) and elevation φ (rad, in [−π/2, π/2]) of the probing direction −a.
struct ProbingAngles {
  double azimuth_rad = 0;
  double elevation_rad = 0;
  bool at_pole = false;  // |horizontal part| < 1e-9: θ undefined, azimuth terms are not applied
};
ProbingAngles AnglesOfApproach(const Eigen::Vector3d& approach);

// The lobing part of the pretravel (header comment). cos_mm(k, j) = a_kj and sin_mm(k, j) = b_kj, both
// (K+1) × (D+1), mm; b_0j must be 0 (sin 0θ = 0). Empty (K = D = 0, zero coefficients) by default,
// which gives the constant-pretravel model.
struct PretravelLobing {
  static constexpr int kMaxOrder = 3;            // K ≤ 3: tri-lobe and below (spec §2)
  static constexpr int kMaxElevationDegree = 3;  // D ≤ 3: low order in sin φ
  int max_order = 0;                             // K
  int elevation_degree = 0;                      // D
  Eigen::MatrixXd cos_mm = Eigen::MatrixXd::Zero(1, 1);
  Eigen::MatrixXd sin_mm = Eigen::MatrixXd::Zero(1, 1);

  // K and D with zero coefficients.
  static PretravelLobing Zero(int max_order, int elevation_degree);
  // Σ_kj sin^j φ [a_kj cos kθ + b_kj sin kθ] for the approach direction a (unit), mm.
  double Evaluate(const Eigen::Vector3d& approach) const;
  // An upper bound of |Evaluate| over all directions: Σ |a_kj| + |b_kj|.
  double BoundMm() const;
  bool IsZero() const;
  Status Validate(const std::string& field_prefix = "probe.lobing") const;
};

struct ProbeModel {
  double ball_radius_mm = 1.0;  // nominal stylus-ball radius R_nom
  double pretravel_mm = 0.0;    // direction-independent part of δ
  PretravelLobing lobing;       // direction-dependent part of δ (zero by default)
  Status Validate() const;
  // δ(a) = pretravel_mm + lobing(a), mm.
  double Pretravel(const Eigen::Vector3d& approach) const { return pretravel_mm + lobing.Evaluate(approach); }
  // R_eff(a) = R_nom − δ(a), mm.
  double EffectiveRadius(const Eigen::Vector3d& approach) const { return ball_radius_mm - Pretravel(approach); }
};

// Contact point p = c + R_eff(a)·a.
Eigen::Vector3d ContactPoint(const ProbeRecord& record, const ProbeModel& model);

// Probe profiles: a ProbeModel as JSON, written by `formloop calibrate sphere` and applied by
// `formloop analyse --probe-profile`.
//
//   {"format": "formloop probe profile", "version": 1,
//    "ball_radius_mm": 1.0, "pretravel_mm": 0.0012,
//    "lobing": {"max_order": 3, "elevation_degree": 1,
//               "terms": [{"k": 3, "j": 0, "cos_mm": 0.004, "sin_mm": -0.002}, ...]},
//    "calibration": {...}}          (optional, free-form: the report of the calibration that made it)
//
// Terms that are absent are zero. Reading validates every member and names it in errors
// ("P.json: field 'lobing.terms[2].k': ..."); unknown keys are errors so typos do not pass silently.
nlohmann::json ProbeProfileToJson(const ProbeModel& model);
Result<ProbeModel> ProbeProfileFromJson(const nlohmann::json& json, const std::string& source);
// `calibration` (may be null) is stored under "calibration". Written atomically.
Status WriteProbeProfile(const std::filesystem::path& path, const ProbeModel& model,
                         const nlohmann::json& calibration = nullptr);
Result<ProbeModel> ReadProbeProfile(const std::filesystem::path& path);

}  // namespace formloop::metrology
