#pragma once
// Section-plane raster tool path for a ball-end cutter on the ideal surface Q
// (spec/nc-gen.md §1, §2).
//
// Passes are the intersections of Q with vertical planes whose normal m = (−sin θ, cos θ, 0) lies in
// the XY plane at the raster angle θ; a pass runs along d = (cos θ, sin θ, 0) (zig-zag: every other pass
// runs along −d). A point of pass c at abscissa s solves S(u, v)·m = c, S(u, v)·d = s by Newton in
// (u, v), so every CC point lies on its plane to rounding. The planes cover the range of S·m over Q;
// each plane meets the boundary of the domain at its two ends (found on the four domain edges). This
// needs Q to be a graph over the XY plane along each plane (every 3-axis ball-end surface seen from
// above is); a plane that meets the domain in more than one piece is refused.
//
// Step-over from plane c to the next keeps the scallop below the target: on the surface the passes are
// l = sqrt(8h / (1/r + κ)) apart (κ > 0 the convex normal curvature across the pass), which is a plane
// spacing Δc = l·|m_t| (m_t the projection of m on the tangent plane); the smallest Δc over this pass
// and the next is taken. Point spacing along a pass bounds the sag of the straight feed segment between
// ball centres (the centre path bends by κ_c + r κ_n² on convex parts, κ_c = |κ_n| / |N·n| by Meusnier,
// N the section curve's principal normal) by the chord tolerance. Where a CC point lies within r
// (horizontally) of a point whose smallest principal curvature is below −1/r, a drop-cutter test
// against a dense local sample of Q lifts the CL along ẑ until the ball touches Q only from above;
// those CLs are flagged (lifted_*). The drop-cutter test is local (gouges from distant parts of Q, e.g.
// steep walls folding back, are not searched for).
//
// Each pass starts and ends with a lead: a quarter-circle arc of radius lead_mm, tangential to the tip
// path at the pass end and curving away from Q along its normal (smaller where Q is concave; see
// LeadArc in toolpath.cc), so the cutter enters and leaves the surface already moving along the path;
// lead points are CL points of kind kLeadIn/kLeadOut, off Q, never compensated.
// Cutter location: ball centre B = i + r·n, programmed tip T = B − r·ẑ.
//
// Trimmed Q (reconstruction/trim.h). A CC point is usable when its (u, v) lies inside the trim (OpenCASCADE's
// classification; on the edge counts as inside) and the ball there stays clear of the neighbouring faces
// (distance from its centre ≥ r − kNeighbourClearanceToleranceMm). Each section is traced over Q's whole
// parameter box as above (the step-over is planned there, so it never depends on where the trim cuts a
// plane), then cut into the runs of usable samples (every 0.25 mm along the plane); where a run ends, the
// end is found by bisection on the plane to 1e-7 mm, so passes start and end at the trim. A trim feature
// narrower than that sampling along a plane can be missed by it; the contour passes still follow it.
// Passes ending at a boundary that runs along them leave a wedge between the last pass and the boundary, so
// after the raster one contour pass follows every trimming loop (outer and holes) with its CC points on the
// loop (the loop's pcurve samples, every kTrimLoopSpacingMm, thinned to the chord tolerance and
// max_point_spacing_mm), split where the ball would reach a neighbour. A lead that would bring the ball
// nearer than r to a neighbouring face (or whose vertical retract column above its outer end would) is
// replaced by a straight lead along the normal, then by a vertical one; if none is clear the plan is refused.
// Safe Z is at least the top of the neighbouring faces within reach plus the clearance.

#include <limits>
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
  double scallop_um = 3.0;            // target scallop height between passes
  double chord_tolerance_um = 1.0;    // max chord error along a pass
  double max_point_spacing_mm = 0.5;  // cap on CC spacing along a pass (feeds the virtual machine's resolution)
  double raster_angle_deg = 0;        // angle θ of the cutting direction d in the XY plane, from +X
  bool zigzag = true;                 // alternate direction of successive passes (false: one-way)
  double lead_mm = 2.0;               // radius of the arc lead-in/out at each pass end (0: none)
  double feed_mm_per_min = 1500;      // cutting feed
  double plunge_feed_mm_per_min = 300;
  double spindle_rpm = 12000;
  double clearance_mm = 5.0;  // above the highest tip point for rapids between passes
  Status Validate() const;
};

enum class ClKind {
  kCut,      // on Q: CC point, normal and (u, v) are Q's
  kLeadIn,   // start of the tangential lead-in of a pass, off Q: cc = tip, normal = ẑ
  kLeadOut,  // end of the lead-out of a pass, off Q: cc = tip, normal = ẑ
  kOff,      // a point of a program formloop did not write where the tool does not touch Q (never moved)
};

// One cutter location with its provenance.
struct ClPoint {
  ClKind kind = ClKind::kCut;
  int pass = 0;  // pass index from 0
  int index_in_pass = 0;
  double u = 0, v = 0;                           // parameters of the CC point on Q (leads: of the pass end they extend)
  Eigen::Vector3d cc = Eigen::Vector3d::Zero();  // cutter-contact point i on Q, mm
  Eigen::Vector3d normal = Eigen::Vector3d::UnitZ();  // unit normal of Q at i
  Eigen::Vector3d centre = Eigen::Vector3d::Zero();   // ball centre B = i + r n + lift ẑ
  Eigen::Vector3d tip = Eigen::Vector3d::Zero();      // programmed tip point B − r ẑ
  // Lift along the tool axis (ẑ) that keeps the ball out of Q where the concave radius is below r (the
  // ball then touches Q only from above, spec §2 "lift and flag"); 0 elsewhere.
  double lift_mm = 0;
  double path_length_mm = 0;  // cutting path length from the program start to here
  double time_s = 0;          // cutting time from the program start (feed moves only)
};

struct Toolpath {
  ToolpathOptions options;
  std::vector<ClPoint> points;  // in cutting order
  int passes = 0;
  double safe_z_mm = 0;
  // Report figures.
  double min_step_over_mm = 0, max_step_over_mm = 0;
  double total_length_mm = 0, total_time_s = 0;
  int gouge_risk_points = 0;  // CC points whose concave radius is below the ball radius
  // Gouge avoidance (spec §2): CL points lifted along ẑ so the ball stays out of Q. The region they
  // cover is NOT cut to Q ("never cut"): the indices into points, the bounding box of their CC points
  // and the largest lift.
  int lifted_points = 0;
  std::vector<int> lifted_indices;
  Eigen::Vector3d lifted_box_min = Eigen::Vector3d::Zero(), lifted_box_max = Eigen::Vector3d::Zero();
  double max_lift_mm = 0;
  // Trimmed Q: passes clipped to the trim, contour passes along its loops (header comment).
  bool trimmed = false;
  int contour_passes = 0;
  // Untrimmed Q whose edges the passes meet at a slant: a contour pass along its parameter box's boundary
  // (counted in contour_passes), so the edges keep the scallop target.
  bool boundary_contour = false;
  // Neighbouring faces: usable-looking samples dropped because the ball would reach a neighbour, leads
  // changed to leave along the normal or vertically, and the lowest safe Z they allow (NaN: no neighbours
  // within reach).
  bool neighbours_checked = false;
  int neighbour_blocked_samples = 0;
  int leads_along_normal = 0, leads_vertical = 0;
  double min_safe_z_mm = std::numeric_limits<double>::quiet_NaN();
  nlohmann::json ReportJson() const;
  // The region left uncut, in words for a warning ("" when nothing is lifted): the gouge-risk and lifted
  // counts, the largest lift, the x/y range of the lifted CC points and that a smaller ball cuts it.
  std::string UncutRegionText() const;
};

// A ball nearer than r − this to a neighbouring face counts as touching it (mm).
inline constexpr double kNeighbourClearanceToleranceMm = 1e-4;

Result<Toolpath> PlanRaster(const recon::BSplineSurface& surface, const ToolpathOptions& options);

// The cutter location of a CC point: ball centre B = i + r·n + lift·ẑ and programmed tip T = B − r·ẑ.
inline Eigen::Vector3d BallCentre(const Eigen::Vector3d& cc, const Eigen::Vector3d& normal, double lift_mm,
                                  double radius_mm) {
  return cc + radius_mm * normal + lift_mm * Eigen::Vector3d::UnitZ();
}
inline Eigen::Vector3d TipOf(const Eigen::Vector3d& centre, double radius_mm) {
  return centre - radius_mm * Eigen::Vector3d::UnitZ();
}

// Recomputes centre, tip, path length and time after the CC points moved (compensation).
void UpdateCutterLocations(Toolpath* path);

// Rebuilds lifted_points, lifted_indices, the lifted box and max_lift_mm from the points' lift_mm.
void SummariseLifted(Toolpath* path);

}  // namespace formloop::nc
