#pragma once
// Optional registration of measured points to the ideal surface Q (spec/metrology.md §3).
//
// In-situ points are taken in the machine frame that cut the part, so a setup error is part of what is
// measured: registration is off by default, and when it is asked for the transform is reported, never
// silently absorbed. The transform moves measured points onto Q with a chosen subset of the six degrees
// of freedom:
//   x' = R (x − pivot) + pivot + t,   R = Rz(rz)·Ry(ry)·Rx(rx),   t = (tx, ty, tz)
// with the pivot at the centroid of the points (so rotations and translations are not confounded by
// the lever arm to the machine origin). A DOF that is not in the mask is exactly zero.
//
// Method: point-to-plane Gauss-Newton (Chen & Medioni, "Object modelling by registration of multiple
// range images", Image and Vision Computing 10(3):145-155, 1992; the point-to-surface variant of ICP,
// Besl & McKay, IEEE PAMI 14(2):239-256, 1992). Each iteration projects the moved points onto Q
// (recon::FootPointProjector: foot point q_i and unit normal n_i), linearises r_i = (x'_i − q_i)·n_i in the
// free parameters and solves the least-squares step by column-pivoted QR; steps that do not lower
// Σr² are halved. Stops when the step is below 1e-10 (mm or rad) or after max_iterations.
//
// Points whose foot point is farther than max_distance_mm (before registration) are an error naming the
// point: registration is not an outlier filter. A mask whose DOF the surface does not constrain (e.g. tx
// on a plane z = 0) gives a rank-deficient step; that is an error naming the DOF.

#include <array>
#include <string>
#include <vector>

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <nlohmann/json.hpp>

#include "core/status.h"
#include "reconstruction/foot_point.h"

namespace formloop::metrology {

enum Dof { kTx = 0, kTy, kTz, kRx, kRy, kRz };
inline constexpr const char* kDofNames[6] = {"tx", "ty", "tz", "rx", "ry", "rz"};

// Which of tx, ty, tz, rx, ry, rz are free. All false (registration off) by default.
using DofMask = std::array<bool, 6>;
// "tx,ty,rz", "all" (the six), "none" or "" (off). Unknown names are an error naming `field`.
Result<DofMask> ParseDofMask(const std::string& text, const std::string& field = "--register");
std::string DofMaskToString(const DofMask& mask);

struct RegistrationOptions {
  DofMask dofs = {false, false, false, false, false, false};  // off by default (spec §3)
  int max_iterations = 50;                                    // converges in 3-6 for setup-size offsets
  double max_distance_mm = 1.0;  // stated search distance: points farther from Q are an error
  Status Validate() const;
};

struct RegistrationReport {
  bool enabled = false;  // false: mask empty, identity transform, nothing fitted
  DofMask dofs{};        // the free DOF
  Eigen::Vector3d pivot_mm = Eigen::Vector3d::Zero();
  std::array<double, 6> values{};           // tx, ty, tz (mm), rx, ry, rz (rad); zero for masked DOF
  std::array<double, 6> standard_errors{};  // same units; zero for masked DOF
  Eigen::Isometry3d part_from_machine = Eigen::Isometry3d::Identity();  // x' = part_from_machine · x
  double rms_before_mm = 0, rms_after_mm = 0;
  int points = 0, iterations = 0;
  nlohmann::json ToJson() const;
};

// The transform from the six values (header comment).
Eigen::Isometry3d RegistrationTransform(const std::array<double, 6>& values, const Eigen::Vector3d& pivot_mm);

// Registers points (machine frame, mm; e.g. compensated contact points) to the surface of `projector`.
Result<RegistrationReport> RegisterToSurface(const std::vector<Eigen::Vector3d>& points_mm,
                                             const recon::FootPointProjector& projector,
                                             const RegistrationOptions& options);

}  // namespace formloop::metrology
