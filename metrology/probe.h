#pragma once
// Probing plans, probe logs and probe compensation (spec/metrology.md §1, §2).
//
// A probe log row is `id, x, y, z, ax, ay, az, t`: the stylus-ball centre c at trigger (machine
// frame, mm), the unit approach direction a (from the probe towards the surface) and the time (s).
// The contact point is p = c + R_eff(a)·a with R_eff(a) = R_nom − δ(a) (δ: pretravel). This first
// model has a constant pretravel; the direction-dependent lobing model and the sphere calibration
// come with the metrology issue.

#include <cstdint>
#include <filesystem>
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
  nlohmann::json ToJson() const;
};

// nu × nv points equidistant in parameter space, inset from the domain edges by `inset_fraction`
// of each span (probing right at an edge risks missing the part). Ids are 1..nu·nv, row-major.
Result<ProbingPlan> PlanProbingGrid(const recon::BSplineSurface& surface, int nu, int nv, double inset_fraction);

struct ProbeRecord {
  std::int64_t id = 0;
  Eigen::Vector3d centre = Eigen::Vector3d::Zero();    // ball centre at trigger, mm
  Eigen::Vector3d approach = -Eigen::Vector3d::UnitZ();// unit approach direction
  double t_s = 0;
};

struct ProbeLog {
  std::vector<ProbeRecord> records;
};

Result<ProbeLog> ReadProbeLog(const std::filesystem::path& path);
Status WriteProbeLog(const std::filesystem::path& path, const ProbeLog& log);

struct ProbeModel {
  double ball_radius_mm = 1.0;  // nominal stylus-ball radius
  double pretravel_mm = 0.0;    // constant pretravel δ (direction-independent in this first model)
  Status Validate() const;
  double EffectiveRadius(const Eigen::Vector3d& /*approach*/) const { return ball_radius_mm - pretravel_mm; }
};

// Contact point p = c + R_eff(a)·a.
Eigen::Vector3d ContactPoint(const ProbeRecord& record, const ProbeModel& model);

}  // namespace formloop::metrology
