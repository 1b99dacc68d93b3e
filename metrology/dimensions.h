#pragma once
// Drawing dimensions from probe points, their standard uncertainty and the OK/NG judgement
// (spec/tuning-and-link.md §2). Points are surface points (stylus radius already allowed for) in the
// process WCS, corrected with the standard block (metrology/standard_block.h). Lengths in mm, angles
// in degrees.
//
// Each dimension names its points by role. What each type computes (a = the dimension's axis, X/Y/Z;
// circles lie in the plane normal to a, and a "centre" is the circle centre at the mean height of its
// points along a):
//
//   type               method        roles                          value
//   LENGTH             TWO_POINT     WALL_A, WALL_B (≥ 1 each)      |a·mean(B) − a·mean(A)|  (widths of bosses,
//                                                                   slots, steps between two walls)
//   LENGTH             FACE_TO_FACE  FACE_A (≥ 3), FACE_B (≥ 1)     |mean n_A·(p − p̄_A)| over B (step heights,
//                                                                   thickness between faces)
//   DIAMETER / RADIUS  CIRCLE        FEATURE (≥ 3)                  2r / r of the geometric LS circle
//   DIAMETER / RADIUS  CYLINDER      FEATURE (≥ 5, ≥ 2 heights)     2r / r of the LS cylinder (axis near a)
//   POSITION           POINT|CIRCLE  FEATURE, DATUM (optional)      a·(c_F − c_D); c = mean of the points
//                                                                   (POINT) or circle centre (CIRCLE, the
//                                                                   circle normal to feature_axis);
//                                                                   DATUM: a circle under CIRCLE when it has
//                                                                   ≥ 3 points, else the mean of its points;
//                                                                   no DATUM: the WCS origin. Plane height:
//                                                                   POINT over the face's points
//   TRUE_POSITION      CIRCLE|POINT  FEATURE, DATUM (optional)      2·√(Δu² + Δv²), Δ = c_F − c_D − nominal
//                                                                   position (the two axes normal to a)
//   FLATNESS                         FEATURE (≥ 3)                  max h − min h about the LS plane
//   ROUNDNESS                        FEATURE (≥ 3)                  max ρ − min ρ about the LS circle
//   PARALLELISM                      DATUM (plane), FEATURE         max n_D·p − min n_D·p over FEATURE
//   PERPENDICULARITY   PLANE         DATUM (plane), FEATURE (plane) w = normalise(n_F − (n_F·n_D)n_D);
//                                                                   max w·p − min w·p over FEATURE
//   PERPENDICULARITY   AXIS          DATUM (plane), LEVEL_1,        ‖(c2 − c1) − ((c2 − c1)·n_D)·n_D‖
//                                    LEVEL_2 (circles)
//   COAXIALITY                       DATUM_1 [, DATUM_2] (circles), datum axis through the datum centres (one
//                                    FEATURE_1 [, FEATURE_2 ...]    circle: along a); 2·max_j dist(c_j, axis)
//   SYMMETRY                         WALL_A, WALL_B, DATUM_A,       medians m_i = (p_Ai + p_Bi)/2 (paired in
//                                    DATUM_B (paired in order)      order); μ_D the mean datum median along a;
//                                                                   2·max_i |a·m_i − μ_D|
//   ANGLE              PLANE         FACE_A, FACE_B (planes)        angle between the outward normals (each
//                                                                   oriented against its points' mean
//                                                                   approach), 0..180°; without approach
//                                                                   directions the acute angle 0..90°
//   ANGLE              LINE          LINE_A, LINE_B (≥ 2, in the    angle between the LS lines, each oriented
//                                    plane normal to a)             from its first point to its last, 0..180°
//
// Zone types (TRUE_POSITION, FLATNESS, ROUNDNESS, PARALLELISM, PERPENDICULARITY, COAXIALITY, SYMMETRY)
// have nominal 0 and the band [0, t]; FLATNESS and ROUNDNESS are LS-referenced, so never below the
// minimum-zone value.
//
// Uncertainty. Each point carries a standard uncertainty u_p (mm) on the axes its mask says were
// measured. The dimension's standard uncertainty follows the GUM law of propagation for uncorrelated
// inputs, u² = Σ_i Σ_axes (∂value/∂p_ia)²·u_p,i², with the sensitivities by central differences of the
// whole evaluation (fits included; step 1e-5 mm). For max/min values (zones) the sensitivity is that of
// the extreme points, the usual first-order treatment. The expanded uncertainty is U = 2u (k = 2).
//
// Judgement. dev = value − nominal; OK when l − ε ≤ dev ≤ u + ε (zones: value ≤ t + ε), ε = 1e-9 mm;
// excess = max(0, dev − u, l − dev). `ambiguous` flags a value within U of a limit (ISO 14253-1: neither
// conformance nor non-conformance is proven); the OK/NG call itself follows the spec.

#include <array>
#include <string>
#include <vector>

#include <Eigen/Core>
#include <nlohmann/json.hpp>

#include "core/status.h"

namespace formloop::metrology {

enum class DimensionType {
  kLength,
  kDiameter,
  kRadius,
  kPosition,
  kTruePosition,
  kFlatness,
  kRoundness,
  kParallelism,
  kPerpendicularity,
  kCoaxiality,
  kSymmetry,
  kAngle,
};
enum class DimensionMethod { kDefault, kTwoPoint, kFaceToFace, kCircle, kCylinder, kPoint, kPlane, kAxis, kLine };

const char* DimensionTypeName(DimensionType type);
const char* DimensionMethodName(DimensionMethod method);
// "LENGTH" ... (upper case, as in the spec); false when unknown.
bool ParseDimensionType(const std::string& text, DimensionType* type);
bool ParseDimensionMethod(const std::string& text, DimensionMethod* method);
// The method used when kDefault is given (LENGTH: TWO_POINT, DIAMETER/RADIUS: CIRCLE, POSITION: POINT,
// TRUE_POSITION: CIRCLE, PERPENDICULARITY: PLANE, ANGLE: PLANE; others have one method).
DimensionMethod ResolvedMethod(DimensionType type, DimensionMethod method);
// Zone types: nominal 0, band [0, t], never driven by offsets.
bool IsZoneType(DimensionType type);
// The methods a type accepts (for model validation messages).
std::vector<DimensionMethod> MethodsOf(DimensionType type);
// The roles a type/method requires, and the roles it accepts (prefix matches for COAXIALITY's
// DATUM_*/FEATURE_*).
std::vector<std::string> RequiredRoles(DimensionType type, DimensionMethod method);
bool RoleAccepted(DimensionType type, DimensionMethod method, const std::string& role);

// A probed surface point as a dimension uses it.
struct ProbedPoint {
  int id = 0;
  Eigen::Vector3d position = Eigen::Vector3d::Zero();  // mm, process WCS, block-corrected
  Eigen::Vector3d approach = Eigen::Vector3d::Zero();  // probing direction (into the material); 0 = unknown
  std::array<bool, 3> measured = {true, true, true};   // axes the probe measured (the others are nominal)
  double u_mm = 0;                                     // standard uncertainty on each measured axis
};

struct RolePoints {
  std::string role;
  std::vector<ProbedPoint> points;
};

struct DimensionDefinition {
  std::string id;
  DimensionType type = DimensionType::kLength;
  DimensionMethod method = DimensionMethod::kDefault;
  int axis = 0;  // 0 = X, 1 = Y, 2 = Z
  // POSITION with method CIRCLE: the circle's axis (normal of its plane); `axis` is then the measuring
  // direction. Default Z (a bore in the XY plane).
  int feature_axis = 2;
  // TRUE_POSITION: nominal position of the feature relative to the datum (or origin) along the two axes
  // normal to `axis`, in the order (X, Y), (Y, Z) or (Z, X) for axis Z, X, Y.
  Eigen::Vector2d nominal_position = Eigen::Vector2d::Zero();
};

// The value alone (no uncertainty). BadInput names the dimension and the role when points are missing
// or degenerate (DIM_INSUFFICIENT_POINTS).
Result<double> EvaluateDimensionValue(const DimensionDefinition& definition, const std::vector<RolePoints>& roles);

struct DimensionEvaluation {
  double value = 0;       // mm (deg for ANGLE)
  double u = 0;           // standard uncertainty, same unit
  double expanded_u = 0;  // U = 2u
  int points = 0;
};
Result<DimensionEvaluation> EvaluateDimension(const DimensionDefinition& definition,
                                              const std::vector<RolePoints>& roles);

struct Tolerance {
  double nominal = 0;
  double upper = 0;  // signed deviation limits, lower < upper; zones: lower 0, upper t
  double lower = 0;
  bool zone = false;  // zone type: only the upper limit is a specification limit (for `ambiguous`)
};

struct Judgement {
  double deviation = 0;  // value − nominal
  bool ok = false;
  double excess = 0;       // max(0, dev − u, l − dev)
  bool ambiguous = false;  // a limit lies within U of the value
};
inline constexpr double kJudgementEpsilonMm = 1e-9;
Judgement Judge(const Tolerance& tolerance, double value, double expanded_u = 0);

}  // namespace formloop::metrology
