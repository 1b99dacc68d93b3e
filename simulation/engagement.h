#pragma once
// The engagement of a flat end mill along a tool path, from a Z-map stock model (the height-field
// stock of Choi & Jerard, "Sculptured Surface Machining", 1998, §8: one column per grid cell, holding
// the height of the stock's top; no column: no material).
//
// Moving the tool's bottom face along a feed segment at height z lowers every column under the swept
// disc of radius r to z. Over a piece of path of length Δs (XY) the cut removes the area ΔA (XY) and
// the volume ΔV; for a straight feed
//   a_e = ΔA / Δs   (width of the strip removed across the feed: the radial engagement)
//   a_p = ΔV / ΔA   (mean height of the removed material: the axial depth)
// so Q = a_e a_p v_f holds exactly, the metal-removal rate of spec/process-optimization.md §1.3. Each
// Euler sub-step visits only the cells the disc newly covers (per grid row, the part of the new disc's
// interval outside the previous disc's), so a path costs O(rows × steps), not O(disc area × steps).
// Accuracy: cell size c gives a_e within about c/Δs·r of the exact crescent over a piece Δs.
//
// Rapid moves do not cut (a rapid into stock would be a collision; it is not modelled).

#include <Eigen/Core>
#include <vector>

#include "core/status.h"
#include "simulation/spindle_plant.h"

namespace formloop::sim {

struct ZMapOptions {
  double x_min_mm = 0, y_min_mm = 0, x_max_mm = 100, y_max_mm = 100;
  double cell_mm = 0.05;
  Status Validate() const;
};

class ZMapStock {
 public:
  static Result<ZMapStock> Create(const ZMapOptions& options);
  // Columns whose cell centre lies inside the polygon (x, y vertices, either orientation) get top z.
  void AddPrism(const std::vector<Eigen::Vector2d>& outline_mm, double top_z_mm);
  // Height of the column at (x, y); −∞ when there is no material or outside the grid.
  double TopAt(double x_mm, double y_mm) const;

  struct Removed {
    double area_mm2 = 0, volume_mm3 = 0, max_depth_mm = 0;
  };
  // Moves a flat end mill of radius r (bottom at the path's z) from a to b in sub-steps of at most one
  // cell; `fresh` = the tool was not just at a (after a rapid): the whole first disc is cut.
  Removed CutSegment(const Eigen::Vector3d& a, const Eigen::Vector3d& b, double radius_mm, bool fresh);

 private:
  void CutDisc(double cx, double cy, double z, double r, const double* prev_cx, const double* prev_cy, Removed* out);
  ZMapOptions options_;
  int nx_ = 0, ny_ = 0;
  std::vector<float> top_;  // ny × nx, row-major; −∞ = no material
};

// One piece of feed path with its engagement.
struct PathEngagement {
  EngagementProfile profile;               // a_e, a_p at the middle of each piece, against cutting path length
  std::vector<double> segment_a_e_max_mm;  // per path segment (tips[i-1] -> tips[i]): largest a_e of its pieces
  std::vector<double> segment_a_p_max_mm;  // and the deepest cut column
};

// tips: tool-bottom positions in path order; fed[i]: reached from tips[i − 1] by a feed move (fed[0]
// ignored). Path length accumulates over feed moves (XY length). Each feed segment is cut in pieces of
// at most piece_mm. BadInput when no feed segment has XY length.
Result<PathEngagement> EngagementAlongPath(ZMapStock* stock, const std::vector<Eigen::Vector3d>& tips,
                                           const std::vector<bool>& fed, double tool_radius_mm, double piece_mm = 1.0);

}  // namespace formloop::sim
