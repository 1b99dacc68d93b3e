// Siemens Sinumerik 840D sl post (SINUMERIK 840D sl Programming Manual "Fundamentals"): ';' starts a
// comment to the end of the block; G71 metric, G90 absolute, G17 XY plane, G40 no radius compensation,
// G94 feed in mm/min; "T1 D1" selects the tool and its first cutting edge, M6 changes it, and the length
// offset of D1 takes effect with the first Z move (the controlled point is the tool tip);
// G0/G1 with axis words (plain "X10.000" is the short form of "X=10.000"); M3/M5 spindle; M30 end.
// Block numbers are optional "N" words.

// Probing (FormatProbing):
// Sinumerik 840D sl (Programming Manual Job Planning, "Measuring with touch-trigger probe (MEAS, MEAW)"):
//   MEAS=1 G1 X.. Y.. Z.. F.. moves linearly and on the rising edge of probe 1 stores the position and
//   deletes the distance to go; $AA_MW[axis] is the measured value in the workpiece coordinate system
//   ($AA_MM[axis] the same in the machine coordinate system). MEAS is chosen over CYCLE978 because it is
//   part of the language (no measuring-cycle package, no cycle data or calibration fields to fill in) and
//   its semantics are the same as G38.2 and G31, so all four programs probe the same way. $AA_MW rather than
//   $AA_MM: the plan and the other dialects' results are in the part (workpiece) frame. STOPRE stops the
//   preprocessing so the values are read after the measuring block has run.

#include <string>

#include "core/number_text.h"
#include "nc-gen/post.h"
#include "nc-gen/post_text.h"

namespace formloop::nc::internal {
namespace {

class SinumerikPost : public PostDialect {
 public:
  std::string_view Name() const override { return "sinumerik"; }
  std::string_view FileExtension() const override { return ".mpf"; }
  std::size_t ProbeResultCapacity(const ProbeProgramOptions& options) const override {
    const long n = options.sinumerik_r_base < 0 ? 0 : (options.sinumerik_r_last - options.sinumerik_r_base + 1) / 3;
    return n > 0 ? static_cast<std::size_t>(n) : 0;
  }

  Result<std::string> Format(const MoveSequence& moves, const PostOptions& options) const override {
    ProgramText w(options, Numbering::kBlocks, "; ", "");
    const MoveListHeader& h = moves.Header();
    w.Comment(PlainComment(options.title));
    w.Comment("ball-end tool T" + std::to_string(h.tool_number) + " radius " + w.Num(h.tool_radius_mm) +
              " mm; programmed point = ball tip [T" + std::to_string(h.tool_number) +
              " D1: tool length to the ball tip]; " + std::to_string(h.passes) + " passes");
    w.Block("G71 G90 G17 G40 G94");
    w.Block("T" + std::to_string(h.tool_number) + " D1");
    w.Block("M6");
    w.Block("S" + FormatFixed(h.spindle_rpm, 0) + " M3");
    if (h.coolant) w.Block("M8");
    FL_RETURN_IF_ERROR(WriteWordAddressBody(moves, "G0", "G1", PlainComment, &w));
    if (h.coolant) w.Block("M9");
    w.Block("M5");
    w.Block("M30");
    return w.Finish();
  }

  Result<std::vector<ProgramMove>> Read(const std::string& text, const std::string& source) const override {
    static const WordDialect kDialect{.name = "Sinumerik", .gcode = GcodeDialect::kSinumerik};
    return ReadWordAddress(text, source, kDialect);
  }

  Result<std::string> FormatProbing(const metrology::ProbingPlan& plan,
                                    const ProbeProgramOptions& options) const override {
    FL_RETURN_IF_ERROR(options.post.Validate());
    const long base = options.sinumerik_r_base;
    const long last = base + 3 * static_cast<long>(plan.points.size()) - 1;
    if (base < 0) return Status::BadInput(Where{.field = "probe.sinumerik_r_base"}, "must be >= 0");
    if (last > options.sinumerik_r_last) {
      return Status::BadInput(Where{.field = "probe.sinumerik_r_base"},
                              std::to_string(plan.points.size()) + " probe points need R" + std::to_string(base) +
                                  "..R" + std::to_string(last) + ", beyond R" +
                                  std::to_string(options.sinumerik_r_last) + "; no probing program was written",
                              "lower the base, raise sinumerik_r_last to the control's MD28050 - 1, or split the plan");
    }
    const auto stations = ProbeStations(plan, options);
    if (!stations.ok()) return stations.status();
    ProgramText w(options.post, Numbering::kBlocks, "; ", "");
    w.Comment(PlainComment(options.post.title));
    w.Comment(ProbeHeader(options, plan.points.size()));
    w.Comment("results X Y Z per point in R" + std::to_string(base) + " .. R" + std::to_string(last));
    w.Block("G71 G90 G17 G40 G94");
    w.Block("T" + std::to_string(options.probe_tool) + " D1");
    w.Block("M6");
    w.Block("G0 Z" + w.Num(options.safe_z_mm));
    const std::string feed = " F" + FormatFixed(options.probe_feed_mm_per_min, 0);
    long r = base;
    for (const ProbeStation& s : *stations) {
      w.Comment("point " + std::to_string(s.id));
      w.Block("G0 X" + w.Num(s.start.x()) + " Y" + w.Num(s.start.y()));
      w.Block("G0 Z" + w.Num(s.start.z()));
      w.Block("MEAS=1 G1 " + XyzWords(w, s.target) + feed);
      w.Block("STOPRE");
      for (const char* axis : {"X", "Y", "Z"}) w.Block("R" + std::to_string(r++) + "=$AA_MW[" + axis + "]");
      w.Block("G0 " + XyzWords(w, s.start));
      w.Block("G0 Z" + w.Num(options.safe_z_mm));
    }
    w.Block("M30");
    return w.Finish();
  }
};

}  // namespace

std::unique_ptr<PostDialect> MakeSinumerikPost() { return std::make_unique<SinumerikPost>(); }

}  // namespace formloop::nc::internal
