#pragma once
// The simulated workpiece of a LinuxCNC machine: a reference surface that the touch probe finds, built
// from HAL's real-time math components so that LinuxCNC's own motion controller trips G38.2 on it.
//
// The probe. The programmed (and logged) point is the stylus-ball centre c; the ball of radius r
// touches the workpiece when c comes within r of the surface. The HAL net computes, every servo
// period, a number that is negative exactly when that happens, and a comparator drives
// motion.probe-input with it (cnc/linuxcnc_config.h). LinuxCNC then records the commanded position of
// the first servo period with the input set, so the trigger lags the true contact by up to one period's
// travel, v·T (F10 with T = 1 ms: 0.17 µm).
//
// The surfaces. HAL has no general expression component, so the surface must be one that sums,
// products, quotients and hypot can describe: a plane or a quadric, F(p) = pᵀAp + bᵀp + c = 0 with
// F > 0 on the probe's side (QuadricThrough finds it from the reference surface's own points). The ball
// touches where the centre is at distance r along the normal, i.e. c − r·n(foot) lies on the surface.
// The net finds the foot direction by the fixed-point iteration
//
//   p₀ = c,   p_{k+1} = c − r·∇F(p_k)/|∇F(p_k)|,     gap = F(p_K)
//
// which is exact after one step for planes and spheres and contracts by about r·κ per step otherwise
// (κ the curvature, so 1/150 for a 1 mm ball on the saddle). gap ≤ 0 can only happen when p_K, a
// point within r of c, is inside the material, so the net never trips early; how late it can trip is
// measured, not assumed: BuildProbeSurface evaluates the net exactly as the components do (sum2:
// in0·gain0 + in1·gain1 + offset; mult2; div2; hypot: sqrt(in0² + in1² + in2²)) along the exact normal
// of each point of a grid over the surface, finds where the gap changes sign by bisection and compares
// that distance with r. It adds iterations until the largest difference is within the tolerance.
//
// The workpiece may sit off its programmed position (SetupPose): the surface as placed is
// {R(ω)·p + s}, ω a rotation vector about the part origin and s a shift. To first order every point
// moves by s + ω × p, which is the displacement D of the catalogue's setup_offset (t = s, µm) and
// setup_rotation (ω, µrad) effects (simulation/effects_setup.cc), so `formloop diagnose` should name
// those values.
//
// Other surfaces (egg_box, franke, blade) are not quadrics and are refused with the list of those that
// are; they would need a user-space HAL component, which runs outside the servo thread.

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <nlohmann/json.hpp>
#include <string>
#include <vector>

#include "core/status.h"
#include "reconstruction/analytic_surface.h"

namespace formloop::cnc {

// Where the workpiece sits relative to its programmed position (header comment).
struct SetupPose {
  Eigen::Vector3d shift_um = Eigen::Vector3d::Zero();       // s
  Eigen::Vector3d rotation_urad = Eigen::Vector3d::Zero();  // ω: axis ω/|ω|, angle |ω|
  // p ↦ R(ω)·p + s, mm.
  Eigen::Isometry3d Transform() const;
  bool IsIdentity() const { return shift_um.isZero() && rotation_urad.isZero(); }
  nlohmann::json ToJson() const;
};

// F(p) = pᵀ A p + bᵀ p + c (A symmetric), F > 0 on the probe's side of the surface. Scaled so that
// |∇F| ≈ 1 on the surface (F is then about the distance in mm near it).
struct ImplicitQuadric {
  Eigen::Matrix3d a = Eigen::Matrix3d::Zero();
  Eigen::Vector3d b = Eigen::Vector3d::UnitZ();
  double c = 0;
  double Evaluate(const Eigen::Vector3d& p) const { return p.dot(a * p) + b.dot(p) + c; }
  Eigen::Vector3d Gradient(const Eigen::Vector3d& p) const { return 2 * a * p + b; }
  bool IsPlane() const { return a.isZero(0); }
  // The same surface moved by `placement` (p ↦ placement·p).
  ImplicitQuadric Moved(const Eigen::Isometry3d& placement) const;
  nlohmann::json ToJson() const;
};

// The quadric through a reference surface, from its own points: a plane when [x y z 1] of a grid of
// samples has a null vector, else the null vector of the ten monomials of degree ≤ 2 (SVD in centred,
// scaled coordinates), which must be unique. Oriented with the surface normal. BadInput when the surface
// is not a quadric, naming the reference surfaces that are.
Result<ImplicitQuadric> QuadricThrough(const recon::AnalyticSurface& surface);

// A straight-line network of HAL math components (sum2, mult2, div2, hypot) on three inputs, the
// stylus-ball centre x, y, z. Values are affine forms (Σ coefficient·node + constant) until a product,
// quotient, hypot or the output needs them as a signal; then one chain of sum2 (two terms each, the
// constant in the last offset) makes the signal. So constants fold into gains and offsets and a plane
// costs two sum2. Emitted as HAL commands and evaluated in C++ with the components' own arithmetic.
class HalNet {
 public:
  struct Value {
    double constant = 0;
    std::vector<std::pair<double, int>> terms;  // (coefficient, node)
    bool is_constant() const { return terms.empty(); }
  };
  HalNet();
  static Value Input(int axis) { return {0, {{1.0, axis}}}; }  // 0 x, 1 y, 2 z
  static Value Constant(double c) { return {c, {}}; }
  static Value Affine(const std::vector<std::pair<double, Value>>& terms, double offset);
  // The value as one signal (a node with coefficient 1), emitting the sum2 chain when needed.
  Value Signal(const Value& v);
  Value Product(const Value& a, const Value& b);
  Value Quotient(const Value& dividend, const Value& divisor);
  Value Hypot(const Value& a, const Value& b, const Value& c);
  Status SetOutput(const Value& v);

  // The gap at the ball centre (the components' arithmetic, in order).
  double Evaluate(const Eigen::Vector3d& centre) const;
  int components() const { return static_cast<int>(nodes_.size()) - 3; }
  // HAL commands: loadrt per component type with `prefix`-named instances, addf in evaluation order
  // to `thread`, set pins and nets. The inputs are the signals named by `inputs` (they must exist), the
  // output drives the signal `output`.
  std::string Hal(const std::string& prefix, const std::string& thread, const std::vector<std::string>& inputs,
                  const std::string& output) const;

 private:
  enum class Kind { kInput, kSum, kProduct, kQuotient, kHypot };
  struct Pin {
    int node = -1;  // -1: a constant set on the pin
    double constant = 0;
  };
  struct Node {
    Kind kind = Kind::kInput;
    std::vector<Pin> in;  // sum2: 2, mult2/div2: 2, hypot: 3
    double gain0 = 1, gain1 = 1, offset = 0;
  };
  int Add(Node node);
  Pin PinOf(const Value& v);
  std::vector<Node> nodes_;
  int output_ = -1;
};

struct ProbeSurfaceOptions {
  std::string surface = "saddle";  // a reference surface that is a quadric
  SetupPose pose;
  double ball_radius_mm = 1.0;        // r: the net trips where the centre is r from the surface
  double max_trigger_error_nm = 1.0;  // the check's limit on |trip distance − r|
  int max_iterations = 8;             // of the fixed-point step; more is refused
  int check_grid = 21;                // the check probes check_grid² points over the domain
  Status Validate() const;
};

struct ProbeSurfaceReport {
  std::string surface, description;
  SetupPose pose;
  double ball_radius_mm = 0;
  ImplicitQuadric nominal;  // part frame, as programmed
  ImplicitQuadric placed;   // as it sits on the machine
  int iterations = 0;
  int components = 0;
  int checked_points = 0;
  double max_trigger_error_nm = 0;  // largest |trip distance − r| over the check
  nlohmann::json ToJson() const;
};

struct ProbeSurface {
  HalNet net;
  ProbeSurfaceReport report;
};

// The net for `options`, checked as the header describes. Errors: not a quadric (BadInput), the check
// not within max_trigger_error_nm after max_iterations (Failed, with the error reached).
Result<ProbeSurface> BuildProbeSurface(const ProbeSurfaceOptions& options);

}  // namespace formloop::cnc
