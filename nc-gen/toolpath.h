#pragma once
// Section-plane raster tool path for a ball-end cutter on the ideal surface Q
// (spec/nc-gen.md §1, §2).
//
// Step-over per pass uses the largest convex normal curvature across the passes on this pass and on
// the next one; point spacing along a pass bounds the sag of the straight feed segment between ball
// centres (the centre path bends by κ_c + r κ_n² on convex parts) by the chord tolerance. Where a CC
// point lies within r (horizontally) of a point whose smallest principal curvature is below −1/r, a
// drop-cutter test against a dense local sample of Q lifts the CL along ẑ until the ball touches Q
// only from above; those CLs are flagged (lifted_*). The drop-cutter test is local (gouges from
// distant parts of Q, e.g. steep walls folding back, are not searched for).
//
// This first planner cuts along iso-v curves of Q. For a B-spline fitted to a graph surface
// (z = f(x, y), u = x, v = y) these are exactly the section planes y = const (raster angle 0°).
// Step-over between passes keeps the scallop height below the target using the curvature across the
// passes (h ≈ s²/8 · (1/r + κ), κ > 0 convex); points along a pass keep the chord error below the
// chord tolerance. Cutter location: ball centre B = i + r·n, programmed tip T = B − r·ẑ.

#include <string>
#include <vector>

#include <Eigen/Core>
#include <nlohmann/json.hpp>

#include "core/status.h"
#include "reconstruction/bspline_surface.h"

namespace formloop::nc {

struct BallEndTool {
  int number = 1;
  double radius_mm = 3.0;
};

struct ToolpathOptions {
  BallEndTool tool;
  double scallop_um = 3.0;          // target scallop height between passes
  double chord_tolerance_um = 1.0;  // max chord error along a pass
  double max_point_spacing_mm = 0.5;// cap on CC spacing along a pass (feeds the virtual machine's resolution)
  bool zigzag = true;               // alternate direction of successive passes
  double feed_mm_per_min = 1500;    // cutting feed
  double plunge_feed_mm_per_min = 300;
  double spindle_rpm = 12000;
  double clearance_mm = 5.0;        // above the highest tip point for rapids between passes
  Status Validate() const;
};

// One cutter location with its provenance.
struct ClPoint {
  int pass = 0;                      // pass index from 0
  int index_in_pass = 0;
  double u = 0, v = 0;               // parameters of the CC point on Q
  Eigen::Vector3d cc = Eigen::Vector3d::Zero();      // cutter-contact point i on Q, mm
  Eigen::Vector3d normal = Eigen::Vector3d::UnitZ(); // unit normal of Q at i
  Eigen::Vector3d centre = Eigen::Vector3d::Zero();  // ball centre B = i + r n + lift ẑ
  Eigen::Vector3d tip = Eigen::Vector3d::Zero();     // programmed tip point B − r ẑ
  // Lift along the tool axis (ẑ) that keeps the ball out of Q where the concave radius is below r (the
  // ball then touches Q only from above, spec §2 "lift and flag"); 0 elsewhere.
  double lift_mm = 0;
  double path_length_mm = 0;         // cutting path length from the program start to here
  double time_s = 0;                 // cutting time from the program start (feed moves only)
};

struct Toolpath {
  ToolpathOptions options;
  std::vector<ClPoint> points;       // in cutting order
  int passes = 0;
  double safe_z_mm = 0;
  // Report figures.
  double min_step_over_mm = 0, max_step_over_mm = 0;
  double total_length_mm = 0, total_time_s = 0;
  int gouge_risk_points = 0;         // CC points whose concave radius is below the ball radius
  // Gouge avoidance (spec §2): CL points lifted along ẑ so the ball stays out of Q. The region they
  // cover is NOT cut to Q ("never cut"): the indices into points, the bounding box of their CC points
  // and the largest lift.
  int lifted_points = 0;
  std::vector<int> lifted_indices;
  Eigen::Vector3d lifted_box_min = Eigen::Vector3d::Zero(), lifted_box_max = Eigen::Vector3d::Zero();
  double max_lift_mm = 0;
  nlohmann::json ReportJson() const;
};

Result<Toolpath> PlanRaster(const recon::BSplineSurface& surface, const ToolpathOptions& options);

// Recomputes centre, tip, path length and time after the CC points moved (compensation).
void UpdateCutterLocations(Toolpath* path);

}  // namespace formloop::nc
