// Fanuc 0i/30i post (Fanuc Series 0i-MODEL F / 30i-MODEL B operator's manuals, "Program configuration" and
// "Decimal point programming"): a program sits between '%' lines and starts with its O-number; comments
// are control-out/control-in parentheses and only a restricted upper-case character set is safe in them;
// an axis value without a decimal point is read in least input increments (X10 = 0.010 mm on IS-B), so
// every coordinate carries a decimal point (PostOptions::decimals >= 1) and IS-B machines want decimals
// <= 3; F and S are whole mm/min and rpm. Codes written: G21 mm, G90 absolute, G17 XY plane, G40/G49/G80
// cancel radius compensation, length compensation and canned cycles, G00/G01, T.. M06, S.. M03, M05, M30.
// Tool length compensation: "G43 H<n>" with the first Z move after the tool change ("G00 G43 H2 Z10.000",
// operator's manual "Tool length compensation (G43, G44, G49)": the offset of register H<n> is added to
// the Z end point, so the programmed point is the tool tip when the register holds the length to the tip).
// H is numbered like the tool. The probing program does the same with the probe tool.

// Probing (FormatProbing):
// Fanuc 0i/30i: G31 is the one-shot skip function (group 00): a linear move at F that stops when the skip
//   signal (probe) arrives, the rest of the move is discarded, and the position at the signal is stored in
//   system variables #5061..#5063 (axes 1..3, workpiece coordinate system). Without a signal the move ends
//   at the programmed point and #5061.. hold that point: no alarm, so a miss shows up as a result equal to
//   the search end. Results are copied into common variables (#100..#199 are cleared at power-off,
//   #500..#999 are kept). Comments upper case in parentheses, '%' and the O-number as in the cutting post.
//

#include <cctype>
#include <string>

#include "core/number_text.h"
#include "nc-gen/post.h"
#include "nc-gen/post_text.h"

namespace formloop::nc::internal {

// Upper case; anything outside letters, digits, space and . , - + / * = : becomes a space (parentheses
// would end the comment early and '%' ends the program on tape-style transfers); runs of spaces collapse.
std::string FanucComment(const std::string& text) {
  static const std::string kSafe = " .,-+/*=:";
  std::string out;
  for (char c : text) {
    const unsigned char u = static_cast<unsigned char>(c);
    if (std::isalnum(u)) {
      out += static_cast<char>(std::toupper(u));
    } else {
      out += kSafe.find(c) != std::string::npos ? c : ' ';
    }
    if (out.size() >= 2 && out.back() == ' ' && out[out.size() - 2] == ' ') out.pop_back();  // one space per run
  }
  while (!out.empty() && out.back() == ' ') out.pop_back();
  return out;
}

namespace {

class FanucPost : public PostDialect {
 public:
  std::string_view Name() const override { return "fanuc"; }
  std::string_view FileExtension() const override { return ".nc"; }
  // An axis word takes 4 decimals on IS-C (0.0001 mm) and 3 on IS-B (0.001 mm), the common increment system.
  int MaxDecimals() const override { return 4; }
  int DefaultDecimals() const override { return 3; }
  std::size_t ProbeResultCapacity(const ProbeProgramOptions& options) const override {
    const long base = options.fanuc_result_base;
    const long top = base >= 100 && base <= 199 ? 199 : (base >= 500 && base <= 999 ? 999 : -1);
    return top < 0 ? 0 : static_cast<std::size_t>((top - base + 1) / 3);
  }

  Result<std::string> Format(const MoveSequence& moves, const PostOptions& options) const override {
    ProgramText w(options, Numbering::kBlocks, "(", ")");
    const MoveListHeader& h = moves.Header();
    w.Raw("%");
    std::string number = std::to_string(options.program_number);
    w.Raw("O" + std::string(4 - number.size(), '0') + number);  // O0001..O9999
    w.Comment(FanucComment(options.title));
    w.Comment(FanucComment("ball-end tool T" + std::to_string(h.tool_number) + " radius " + w.Num(h.tool_radius_mm) +
                           " mm, programmed point = ball tip, G43 H" + std::to_string(h.tool_number) +
                           " tool length to the ball tip, " + std::to_string(h.passes) + " passes"));
    w.Block("G21 G90 G17 G40 G49 G80");
    w.Block("T" + std::to_string(h.tool_number) + " M06");
    w.Block("S" + FormatFixed(h.spindle_rpm, 0) + " M03");
    if (h.coolant) w.Block("M08");
    FL_RETURN_IF_ERROR(WriteWordAddressBody(moves, "G00", "G01", FanucComment, &w, LengthOffsetWords(h.tool_number)));
    if (h.coolant) w.Block("M09");
    w.Block("M05");
    w.Block("M30");
    w.Raw("%");
    return w.Finish();
  }

  Result<std::vector<ProgramMove>> Read(const std::string& text, const std::string& source) const override {
    static const WordDialect kDialect{.name = "Fanuc", .gcode = GcodeDialect::kFanuc};
    return ReadWordAddress(text, source, kDialect);
  }

  Result<std::string> FormatProbing(const metrology::ProbingPlan& plan,
                                    const ProbeProgramOptions& options) const override {
    FL_RETURN_IF_ERROR(options.post.Validate());
    const long base = options.fanuc_result_base;
    const long last = base + 3 * static_cast<long>(plan.points.size()) - 1;
    const bool volatile_range = base >= 100 && base <= 199;
    if (!(volatile_range || (base >= 500 && base <= 999))) {
      return Status::BadInput(Where{.field = "probe.fanuc_result_base"},
                              "#" + std::to_string(base) + " is not a common macro variable",
                              "use a base in #100..#199 or #500..#999");
    }
    if (last > (volatile_range ? 199 : 999)) {
      return Status::BadInput(Where{.field = "probe.fanuc_result_base"},
                              std::to_string(plan.points.size()) + " probe points need #" + std::to_string(base) +
                                  "..#" + std::to_string(last) + ", beyond #" + (volatile_range ? "199" : "999") +
                                  "; no probing program was written",
                              "lower the base or split the plan");
    }
    const auto stations = ProbeStations(plan, options);
    if (!stations.ok()) return stations.status();
    ProgramText w(options.post, Numbering::kBlocks, "(", ")");
    w.Raw("%");
    const std::string number = std::to_string(options.post.program_number);
    w.Raw("O" + std::string(4 - number.size(), '0') + number);
    w.Comment(FanucComment(options.post.title));
    w.Comment(FanucComment(ProbeHeader(options, plan.points.size())));
    w.Comment(FanucComment("results X Y Z per point in macro variables " + std::to_string(base) + " - " +
                           std::to_string(last)));
    w.Block("G21 G90 G17 G94 G40 G49 G80");
    w.Block("T" + std::to_string(options.probe_tool) + " M06");
    w.Block("G00 " + LengthOffsetWords(options.probe_tool) + " Z" + w.Num(options.safe_z_mm));
    const std::string feed = " F" + FormatFixed(options.probe_feed_mm_per_min, 0);
    long var = base;
    for (const ProbeStation& s : *stations) {
      w.Comment(FanucComment("point " + std::to_string(s.id)));
      w.Block("G00 X" + w.Num(s.start.x()) + " Y" + w.Num(s.start.y()));
      w.Block("G00 Z" + w.Num(s.start.z()));
      w.Block("G31 " + XyzWords(w, s.target) + feed);
      for (int axis = 0; axis < 3; ++axis) w.Block("#" + std::to_string(var++) + "=#" + std::to_string(5061 + axis));
      w.Block("G00 " + XyzWords(w, s.start));
      w.Block("G00 Z" + w.Num(options.safe_z_mm));
    }
    w.Block("M30");
    w.Raw("%");
    return w.Finish();
  }
};

}  // namespace

std::unique_ptr<PostDialect> MakeFanucPost() { return std::make_unique<FanucPost>(); }

}  // namespace formloop::nc::internal
