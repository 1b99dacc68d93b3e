// LinuxCNC RS274NGC post (LinuxCNC G-code reference, "G Codes" and "Overview": comments in parentheses
// may not nest; '%' lines bracket a program; N words are optional; G64 P sets the path blending
// tolerance). Accepted by LinuxCNC's own rs274 interpreter (tests/nc-gen/post_test.cc).
// Tool length: "G43 H<n>" (LinuxCNC G-code reference, "G43 Tool Length Offset": the offset of tool-table
// entry n is applied, so the controlled point is the tool tip, the point the program gives) after the tool
// change "T<n> M6", in the first rapid, the retract to safe Z. G49 in the first block cancels what an earlier
// program left. tests/nc-gen/rs274_test.cc runs both programs through rs274 with a tool table whose
// tools have non-zero lengths.

#include <sstream>
#include <string>

#include "core/number_text.h"
#include "nc-gen/post.h"
#include "nc-gen/post_text.h"

namespace formloop::nc {

std::string CommentText(const std::string& text) {
  std::string out = text;
  for (char& c : out) {
    if (c == '(') c = '[';
    if (c == ')') c = ']';
    if (static_cast<unsigned char>(c) < 0x20) c = ' ';
  }
  return out;
}

namespace internal {
namespace {

class LinuxCncPost : public PostDialect {
 public:
  std::string_view Name() const override { return "linuxcnc"; }
  std::string_view FileExtension() const override { return ".ngc"; }

  Result<std::string> Format(const MoveSequence& moves, const PostOptions& options) const override {
    ProgramText w(options, Numbering::kBlocks, "(", ")");
    const MoveListHeader& h = moves.Header();
    w.Raw("%");
    w.Comment(CommentText(options.title));
    w.Comment("ball-end tool T" + std::to_string(h.tool_number) + " radius " + w.Num(h.tool_radius_mm) +
              " mm; programmed point = ball tip [G43 H" + std::to_string(h.tool_number) +
              ": tool length measured to the ball tip]; " + std::to_string(h.passes) + " passes");
    w.Block("G21 G90 G17 G94 G40 G49 G80");
    w.Block("G64 P0.001");  // blend within 1 µm: the path is a dense polyline, exact stop would dwell at each point
    w.Block("T" + std::to_string(h.tool_number) + " M6");
    w.Block("S" + FormatFixed(h.spindle_rpm, 0) + " M3");
    if (h.coolant) w.Block("M8");
    FL_RETURN_IF_ERROR(WriteWordAddressBody(moves, "G0", "G1", CommentText, &w, LengthOffsetWords(h.tool_number)));
    if (h.coolant) w.Block("M9");
    w.Block("M5");
    w.Block("M30");
    w.Raw("%");
    return w.Finish();
  }

  Result<std::vector<ProgramMove>> Read(const std::string& text, const std::string& source) const override {
    static const WordDialect kDialect{.name = "LinuxCNC", .gcode = GcodeDialect::kRs274ngc};
    return ReadWordAddress(text, source, kDialect);
  }

  // G38.2 probing toward the search end; the results are logged between (PROBEOPEN file) and (PROBECLOSE).
  // Two touches, the LOG file and the time input: nc-gen/probe_program.h.
  Result<std::string> FormatProbing(const metrology::ProbingPlan& plan,
                                    const ProbeProgramOptions& options) const override {
    const auto stations = ProbeStations(plan, options);
    if (!stations.ok()) return stations.status();
    const int dec = options.post.decimals;
    auto xyz = [dec](const Eigen::Vector3d& p) {
      return "X" + FormatFixed(p.x(), dec) + " Y" + FormatFixed(p.y(), dec) + " Z" + FormatFixed(p.z(), dec);
    };
    const bool two_touches = options.touch_feed_mm_per_min > 0;
    const bool logged = !options.linuxcnc_log_file.empty();
    const bool timed = options.linuxcnc_time_input >= 0;
    std::ostringstream out;
    out << "%\n(" << CommentText(options.post.title) << ")\n";
    out << "(" << ProbeHeader(options, plan.points.size()) << ")\n";
    out << "G21 G90 G17 G94 G40 G49 G80\n";
    out << "T" << options.probe_tool << " M6\n";
    out << "G0 " << LengthOffsetWords(options.probe_tool) << " Z" << FormatFixed(options.safe_z_mm, dec) << "\n";
    out << "(PROBEOPEN " << CommentText(options.results_file) << ")\n";
    if (logged) {
      out << "(LOGOPEN," << CommentText(options.linuxcnc_log_file) << ")\n";
      out << "(LOG,formloop probe log 1: point id x y z tripped ax ay az" << (timed ? " t_s" : "") << ")\n";
    }
    for (const ProbeStation& s : *stations) {
      out << "(point " << s.id << ")\n";
      out << "G0 X" << FormatFixed(s.start.x(), dec) << " Y" << FormatFixed(s.start.y(), dec) << "\n";
      out << "G0 Z" << FormatFixed(s.start.z(), dec) << "\n";
      out << "G38.2 " << xyz(s.target) << " F" << FormatFixed(options.probe_feed_mm_per_min, 0) << "\n";
      if (two_touches) {
        const Eigen::Vector3d back = -options.backoff_mm * s.approach;
        out << "G91 G0 " << xyz(back) << "\nG90\n";
        out << "G38.2 " << xyz(s.target) << " F" << FormatExact(options.touch_feed_mm_per_min) << "\n";
      }
      if (timed) out << "M66 E" << options.linuxcnc_time_input << " L0\n";
      if (logged) {
        const Eigen::Vector3d& a = s.approach;
        out << "(LOG,point " << s.id << " #5061 #5062 #5063 #5070 " << FormatFixed(a.x(), 9) << " "
            << FormatFixed(a.y(), 9) << " " << FormatFixed(a.z(), 9) << (timed ? " #5399" : "") << ")\n";
      }
      out << "G0 " << xyz(s.start) << "\n";
      out << "G0 Z" << FormatFixed(options.safe_z_mm, dec) << "\n";
    }
    out << "(PROBECLOSE)\n";
    if (logged) out << "(LOGCLOSE)\n";
    out << "M30\n%\n";
    return out.str();
  }
};

}  // namespace

std::unique_ptr<PostDialect> MakeLinuxCncPost() { return std::make_unique<LinuxCncPost>(); }

}  // namespace internal
}  // namespace formloop::nc
