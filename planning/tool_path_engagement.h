#pragma once
// The engagement along a formloop program: its feed moves, read back with the dialect's own reader,
// cut a Z-map stock (simulation/engagement.h) with a flat end mill. This gives the spindle-current
// plant its path (Level 2, spec/process-optimization.md §2.6) and Level 1 its per-block a_p and a_e.
//
// Stock file (JSON): {"cell_mm": 0.05, "prisms": [{"outline_mm": [[x, y], ...], "top_z_mm": 5}, ...]}:
// each prism is material from below the path up to top_z_mm inside its outline (a polygon in XY).
//
// nc-gen plans ball-end paths only; a path cut here as a flat end mill is read as the tool's bottom
// face at the programmed tip (for a flat floor the two coincide).

#include <Eigen/Core>
#include <nlohmann/json.hpp>
#include <string>
#include <vector>

#include "core/status.h"
#include "planning/cutting_program.h"
#include "simulation/engagement.h"

namespace formloop::planning {

struct StockPrism {
  std::vector<Eigen::Vector2d> outline_mm;
  double top_z_mm = 0;
};

struct StockDescription {
  double cell_mm = 0.05;
  std::vector<StockPrism> prisms;
};
Result<StockDescription> StockFromJson(const nlohmann::json& json, const std::string& source);

struct ProgramEngagement {
  std::vector<Eigen::Vector3d> tips;  // programmed positions in program order (moves)
  std::vector<bool> fed;              // reached by a feed move
  std::vector<long> lines;            // 1-based program line of each move
  sim::PathEngagement engagement;     // profile against cutting path length; per-move maxima
};

// Cuts the stock with the program's feed moves (tool radius r, pieces of piece_mm).
Result<ProgramEngagement> EngagementOfProgram(const std::string& text, const std::string& dialect,
                                              const std::string& source, const StockDescription& stock,
                                              double tool_radius_mm, double piece_mm = 1.0);

// Per cutting block (feed move with a_e > 0): its largest a_e and deepest cut, named by N word or line,
// for the Level-1 depth check and write-back.
Result<std::vector<BlockEngagement>> BlockEngagementOfProgram(const std::string& text, const std::string& dialect,
                                                              const std::string& source,
                                                              const ProgramEngagement& engagement);

// The §2.6 scenario on a real formloop path: PlanRaster on the plane z = 0 over [0, 300] × [0, 1]
// (passes along x, step-over 1 mm, no leads, feed 2942 mm/min, 5963 rpm, radius 5), posted for
// LinuxCNC with block numbers and read back; the stock a 5 mm high wall on x ∈ [6, 294] whose face
// lies at y = 4 (a_e = 1) up to x = 100, at y = 2 (a_e = 3) from x = 100 to 200, tapering back to y = 4
// at x = 300. Returns the engagement and the program text (`program`).
struct WallStepScenario : ProgramEngagement {
  std::string program;
  StockDescription stock;
};
Result<WallStepScenario> WallStepEngagement();

}  // namespace formloop::planning
