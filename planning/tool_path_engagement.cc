#include "planning/tool_path_engagement.h"

#include <algorithm>
#include <cmath>
#include <limits>

#include "core/json_io.h"
#include "nc-gen/moves.h"
#include "nc-gen/post.h"
#include "nc-gen/toolpath.h"
#include "planning/program_edit.h"
#include "reconstruction/analytic_surface.h"
#include "reconstruction/bspline_surface.h"

namespace formloop::planning {
namespace {

// The plane z = 0 over [0, 300] × [0, 1].
class FloorPlane : public recon::AnalyticSurface {
 public:
  std::string name() const override { return "floor"; }
  std::string description() const override { return "plane z = 0 over [0, 300] x [0, 1]"; }
  recon::ParamDomain domain() const override { return {0, 300, 0, 1}; }
  bool is_graph() const override { return true; }
  recon::SurfaceDerivatives Derivatives(double x, double y) const override {
    recon::SurfaceDerivatives d;
    d.p = Eigen::Vector3d(x, y, 0);
    d.su = Eigen::Vector3d::UnitX();
    d.sv = Eigen::Vector3d::UnitY();
    d.suu = d.suv = d.svv = Eigen::Vector3d::Zero();
    return d;
  }
};

}  // namespace

Result<StockDescription> StockFromJson(const nlohmann::json& json, const std::string& source) {
  if (!json.is_object()) return Status::BadInput(Where{.file = source}, "the stock file must be a JSON object");
  JsonFields root(json, source);
  FL_RETURN_IF_ERROR(root.CheckKnown({"cell_mm", "prisms", "comment"}));
  StockDescription out;
  FL_RETURN_IF_ERROR(root.OptionalNumber("cell_mm", &out.cell_mm, {.min = 0.005, .max = 1}));
  if (!json.contains("prisms") || !json["prisms"].is_array() || json["prisms"].empty()) {
    return Status::BadInput(Where{.file = source, .field = "prisms"}, "expected a non-empty array of prisms");
  }
  for (std::size_t i = 0; i < json["prisms"].size(); ++i) {
    const std::string prefix = "prisms[" + std::to_string(i) + "].";
    const nlohmann::json& p = json["prisms"][i];
    if (!p.is_object()) return Status::BadInput(Where{.file = source, .field = prefix}, "must be an object");
    JsonFields f(p, source, prefix);
    FL_RETURN_IF_ERROR(f.CheckKnown({"outline_mm", "top_z_mm"}));
    StockPrism prism;
    FL_RETURN_IF_ERROR(f.Number("top_z_mm", &prism.top_z_mm));
    const nlohmann::json& outline = p.contains("outline_mm") ? p["outline_mm"] : nlohmann::json();
    if (!outline.is_array() || outline.size() < 3) {
      return Status::BadInput(Where{.file = source, .field = prefix + "outline_mm"},
                              "expected at least three [x, y] vertices");
    }
    for (std::size_t k = 0; k < outline.size(); ++k) {
      const nlohmann::json& v = outline[k];
      if (!v.is_array() || v.size() != 2 || !v[0].is_number() || !v[1].is_number()) {
        return Status::BadInput(Where{.file = source, .field = prefix + "outline_mm[" + std::to_string(k) + "]"},
                                "expected [x, y] in mm");
      }
      prism.outline_mm.emplace_back(v[0].get<double>(), v[1].get<double>());
    }
    out.prisms.push_back(std::move(prism));
  }
  return out;
}

Result<ProgramEngagement> EngagementOfProgram(const std::string& text, const std::string& dialect,
                                              const std::string& source, const StockDescription& stock, double r,
                                              double piece_mm) {
  FL_ASSIGN_OR_RETURN(const std::vector<nc::ProgramMove> moves, nc::ReadProgram(text, dialect, source));
  ProgramEngagement out;
  // The Z-map covers the stock and the path, with a tool radius of margin.
  Eigen::Vector2d lo = Eigen::Vector2d::Constant(std::numeric_limits<double>::infinity()), hi = -lo;
  for (const StockPrism& p : stock.prisms) {
    for (const Eigen::Vector2d& v : p.outline_mm) {
      lo = lo.cwiseMin(v);
      hi = hi.cwiseMax(v);
    }
  }
  for (const nc::ProgramMove& m : moves) {
    out.tips.push_back(m.tip);
    out.fed.push_back(!m.rapid);
    out.lines.push_back(m.line);
  }
  FL_ASSIGN_OR_RETURN(sim::ZMapStock zmap, sim::ZMapStock::Create({.x_min_mm = lo.x() - r - 1,
                                                                   .y_min_mm = lo.y() - r - 1,
                                                                   .x_max_mm = hi.x() + r + 1,
                                                                   .y_max_mm = hi.y() + r + 1,
                                                                   .cell_mm = stock.cell_mm}));
  for (const StockPrism& p : stock.prisms) zmap.AddPrism(p.outline_mm, p.top_z_mm);
  FL_ASSIGN_OR_RETURN(out.engagement, sim::EngagementAlongPath(&zmap, out.tips, out.fed, r, piece_mm));
  return out;
}

Result<std::vector<BlockEngagement>> BlockEngagementOfProgram(const std::string& text, const std::string& dialect,
                                                              const std::string& source,
                                                              const ProgramEngagement& engagement) {
  FL_ASSIGN_OR_RETURN(const EditableProgram program, EditableProgram::Parse(text, dialect, source));
  const bool numbered = program.NumberedBlocks();
  std::vector<BlockEngagement> out;
  for (std::size_t i = 0; i < engagement.tips.size(); ++i) {
    const double a_e = engagement.engagement.segment_a_e_max_mm[i];
    if (!engagement.fed[i] || a_e <= 0) continue;
    const auto line = static_cast<std::size_t>(engagement.lines[i] - 1);
    const long block = numbered ? program.lines()[line].number : engagement.lines[i];
    out.push_back({block, engagement.engagement.segment_a_p_max_mm[i], a_e});
  }
  return out;
}

Result<WallStepScenario> WallStepEngagement() {
  const FloorPlane plane;
  recon::FitReport report;
  FL_ASSIGN_OR_RETURN(const recon::BSplineSurface floor, recon::FitAnalytic(plane, 31, 4, {}, 0, 1, &report));
  nc::ToolpathOptions o;
  o.tool.radius_mm = 5;
  o.scallop_um = 25;  // step-over sqrt(8 h r) = 1 mm on the plane
  o.chord_tolerance_um = 1;
  o.max_point_spacing_mm = 5;
  o.lead_mm = 0;
  o.feed_mm_per_min = 2942;
  o.spindle_rpm = 5963;
  o.clearance_mm = 10;
  FL_ASSIGN_OR_RETURN(const nc::Toolpath path, nc::PlanRaster(floor, o));
  FL_ASSIGN_OR_RETURN(const nc::MoveList list, nc::BuildMoveList(path));
  nc::PostOptions post;
  post.title = "formloop wall-step scenario (spec/process-optimization.md 2.6)";
  post.block_numbers = true;
  FL_ASSIGN_OR_RETURN(const std::string text, nc::Post(list, "linuxcnc", post));
  WallStepScenario out;
  out.program = text;
  out.stock.cell_mm = 0.05;
  out.stock.prisms.push_back({{{6, 4}, {100, 4}, {100, 2}, {200, 2}, {294, 2 + 2 * 0.94}, {294, 20}, {6, 20}}, 5.0});
  FL_ASSIGN_OR_RETURN(ProgramEngagement e, EngagementOfProgram(text, "linuxcnc", "wall-step.ngc", out.stock, 5.0));
  static_cast<ProgramEngagement&>(out) = std::move(e);
  return out;
}

}  // namespace formloop::planning
