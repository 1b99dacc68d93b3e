#pragma once
// The catalogue of physical effects of the virtual machine (spec/simulation.md §3).
//
// An effect is a small class: a stable name (part of the output format: models, diagnosis.json),
// named parameters with units, the physics in one line, and its basis — how it moves the measured
// normal deviation at a probed point, written in the point's covariates (PointContext). Adding an
// effect is one class, one registry line in effects.cc and one physics test.
//
// Sign and frame conventions (all effects):
//   δ is the MEASURED normal deviation in µm, positive = material left (the convention of
//   metrology::Deviation). Surface effects move the machined surface: a tool-to-part displacement D
//   (µm) leaves δ = D·n, n the outward unit normal of Q. Measurement-only effects (probe_radius,
//   probe_lobing) change only what the probe reports; they act through the approach direction a:
//   an effective-radius error ΔR (true − assumed) enters as ΔR·c_a with c_a = −a·n (= 1 for an
//   approach along −n), because the trigger offset lies along a and the deviation is read along n.
//   Positions p are part coordinates in mm (the program's frame; rotations and scales act about its
//   origin).
//
// Every effect in this catalogue except thermal_drift_z is linear in its parameters: δ = J(c)·θ
// with J independent of θ. thermal_drift_z is linear in A and not in τ; Jacobian() is exact for it.

#include <span>
#include <string>
#include <string_view>
#include <vector>

#include <Eigen/Core>

namespace formloop::sim {

// What the tool path and the probe tell about one measured point: the covariates effects are
// written in (spec §2). Built by AssociateWithToolpath (covariates.h).
struct PointContext {
  std::int64_t id = 0;
  Eigen::Vector3d point = Eigen::Vector3d::Zero();       // nominal point on Q, mm (part frame)
  Eigen::Vector3d normal = Eigen::Vector3d::UnitZ();     // outward unit normal of Q there
  Eigen::Vector3d approach = -Eigen::Vector3d::UnitZ();  // unit probe approach direction
  double path_length_mm = 0;  // s: cutting path length from the program start to the cut that made the point
  double cut_time_s = 0;      // t_cut: cutting time from the program start to that cut
  int pass = 0;               // pass index of that cut
  Eigen::Vector3d feed = Eigen::Vector3d::UnitX();  // unit feed direction of that cut
  double engagement = 0;  // radial engagement a_e / r at that cut (local step-over over ball radius)
  double scallop_um = 0;  // geometric cusp height from the swept ball envelope (the scallop effect)
};

struct EffectParameter {
  std::string name;  // stable, with its unit: "k_w_um_per_m"
  std::string doc;   // one line
  bool linear = true;
  // Plausible range for a random draw in scenario generators and for the nonlinear search (the fitted
  // value is not clamped to it).
  double typical_min = 0, typical_max = 0;
};

enum class EffectKind {
  kGeometric,    // always on, no parameters (scallop)
  kSurface,      // moves the machined surface
  kMeasurement,  // changes only the probe's report
  kNoise,        // i.i.d. scatter; no mean contribution
};

class Effect {
 public:
  virtual ~Effect() = default;
  virtual std::string_view name() const = 0;
  virtual std::string_view physics() const = 0;  // one line: what happens on the machine
  virtual std::string_view basis() const = 0;    // the formula of δ in the covariates
  virtual EffectKind kind() const { return EffectKind::kSurface; }
  // True when the basis needs the tool path's covariates (path length, cut time, feed, engagement):
  // such an effect cannot be screened from a probing plan and a log alone.
  virtual bool uses_toolpath() const { return false; }
  // True when every part has its own value (the set-up: each part is clamped on its own), false when
  // the machine, tool or probe give every part the same (what a diagnosis over several parts shares).
  virtual bool part_specific() const { return false; }
  virtual const std::vector<EffectParameter>& parameters() const = 0;
  int parameter_count() const { return static_cast<int>(parameters().size()); }
  bool linear() const;

  // δ at c for parameters θ (size parameter_count()), µm.
  virtual double DeviationUm(const PointContext& c, std::span<const double> theta) const;
  // ∂δ/∂θ at θ into `jacobian` (size parameter_count()). Linear effects ignore θ.
  virtual void Jacobian(const PointContext& c, std::span<const double> theta, std::span<double> jacobian) const = 0;

  // Feature-position data (spec §5, `diagnose --features`): the displacement (µm) the effect gives a
  // point p (mm) of the part. Only rigid-body and axis effects act on positions.
  virtual bool acts_on_positions() const { return false; }
  virtual Eigen::Vector3d DisplacementUm(const Eigen::Vector3d& p_mm, std::span<const double> theta) const;
};

// Every effect, in the catalogue order of spec §3. The pointers live for the program's lifetime.
const std::vector<const Effect*>& EffectCatalogue();
// nullptr when no effect has that name.
const Effect* FindEffect(std::string_view name);
// "scallop, tool_radius, ..." for error messages.
std::string EffectNames();

// The azimuth factor of probe_lobing: ρ cos 3θ and ρ sin 3θ of the probing direction −a, where ρ is
// its horizontal length and θ its azimuth (tri-lobe of a kinematic probe, fading to nothing for a
// vertical approach).
Eigen::Vector2d TriLobeFactors(const Eigen::Vector3d& approach);

}  // namespace formloop::sim
