#include "nc-gen/probe_program.h"

// Dialect conventions (the cutting posts' headers, nc-gen/post_*.cc, cite the manuals for the common parts):
//
// Fanuc 0i/30i: G31 is the one-shot skip function (group 00): a linear move at F that stops when the skip
//   signal (probe) arrives, the rest of the move is discarded, and the position at the signal is stored in
//   system variables #5061..#5063 (axes 1..3, workpiece coordinate system). Without a signal the move ends
//   at the programmed point and #5061.. hold that point: no alarm, so a miss shows up as a result equal to
//   the search end. Results are copied into common variables (#100..#199 are cleared at power-off,
//   #500..#999 are kept). Comments upper case in parentheses, '%' and the O-number as in the cutting post.
//
// Heidenhain TNC 640: TCH PROBE 444 (PROBING IN 3-D), from the TNC 640 "Programming of measuring cycles
//   for workpieces and tools" manual as far as recalled here; the parameter numbers below are NOT checked
//   against the manual of a particular software version and must be verified on the control before use:
//     Q263 / Q264 / Q294   nominal point on the surface, 1st / 2nd / 3rd axis (the cycle adds the stylus
//                          radius itself, so the surface point, not the ball centre, is programmed)
//     Q581 / Q582 / Q583   components of the surface normal (the probing direction is −n)
//     Q320                 set-up clearance along the normal (added to SET_UP of the touch-probe table)
//     Q260                 clearance height (absolute, in the probe axis)
//     Q281                 measuring log (0 none, 1 log file TCHPR444.TXT)
//   The brief that started this post named Q265 for the 3rd axis and Q271..Q273 for the normal; this post
//   uses Q294 and Q581..Q583, which is the recollection of the cycle 444 screen, not a verified fact. The
//   cycle's other parameters (tolerances Q280, program stop Q309, tool monitoring Q330, ...) are not
//   written; a control that needs them refuses the block when the program is loaded, it does not move.
//   The probing feed and the search distance come from the touch-probe table (F, DIST), not the program;
//   probe_feed_mm_per_min and search_mm are still checked against the limits like in the other dialects.
//   M30 rides on the last retract (an L block), as in the cutting post. The cycle block is written in the
//   TNC 640 multi-line form: the block's first line carries the number, each parameter follows on an
//   unnumbered indented line "Q263=+1.000 ;1ST POINT 1ST AXIS", and lines end with " ~" while the block
//   continues (the older iTNC form has no "~"; which form a given software version wants is unverified).
//
// Sinumerik 840D sl (Programming Manual Job Planning, "Measuring with touch-trigger probe (MEAS, MEAW)"):
//   MEAS=1 G1 X.. Y.. Z.. F.. moves linearly and on the rising edge of probe 1 stores the position and
//   deletes the distance to go; $AA_MW[axis] is the measured value in the workpiece coordinate system
//   ($AA_MM[axis] the same in the machine coordinate system). MEAS is chosen over CYCLE978 because it is
//   part of the language (no measuring-cycle package, no cycle data or calibration fields to fill in) and
//   its semantics are the same as G38.2 and G31, so all four programs probe the same way. $AA_MW rather than
//   $AA_MM: the plan and the other dialects' results are in the part (workpiece) frame. STOPRE stops the
//   preprocessing so the values are read after the measuring block has run.

#include <cctype>
#include <sstream>

#include "core/number_text.h"
#include "nc-gen/post_text.h"

namespace formloop::nc {
namespace {

using internal::FanucComment;
using internal::Numbering;
using internal::PlainComment;
using internal::ProgramText;

// One probe point's positions (ball centre), all checked against the limits before any text.
struct Station {
  std::int64_t id = 0;
  Eigen::Vector3d surface, normal, above, start, target;
};

Result<std::vector<Station>> Stations(const metrology::ProbingPlan& plan, const ProbeProgramOptions& options) {
  FL_RETURN_IF_ERROR(options.Validate());
  if (plan.points.empty()) return Status::BadInput("the probing plan has no points");
  if (options.probe_feed_mm_per_min > options.post.limits.max_feed_mm_per_min) {
    return Status::SafetyLimit("probe feed exceeds the machine's feed limit; no probing program was written");
  }
  std::vector<Station> stations;
  for (const metrology::ProbePoint& p : plan.points) {
    Station s;
    s.id = p.id;
    s.surface = p.point;
    s.normal = p.normal;
    const Eigen::Vector3d centre_on_surface = p.point + options.ball_radius_mm * p.normal;
    s.start = centre_on_surface + options.clearance_mm * p.normal;
    s.target = centre_on_surface - options.search_mm * p.normal;
    s.above = s.start;
    s.above.z() = options.safe_z_mm;
    const std::string what = "probe point " + std::to_string(p.id);
    FL_RETURN_IF_ERROR(CheckTravel(options.post.limits, s.above, what));
    FL_RETURN_IF_ERROR(CheckTravel(options.post.limits, s.start, what));
    FL_RETURN_IF_ERROR(CheckTravel(options.post.limits, s.target, what));
    stations.push_back(s);
  }
  return stations;
}

std::string Xyz(const ProgramText& w, const Eigen::Vector3d& p) {
  return "X" + w.Num(p.x()) + " Y" + w.Num(p.y()) + " Z" + w.Num(p.z());
}

std::string Header(const ProbeProgramOptions& options, std::size_t points) {
  return "stylus ball radius " + FormatFixed(options.ball_radius_mm, 4) +
         " mm; programmed point = ball centre; " + std::to_string(points) + " points";
}

std::string Signed(const std::string& s) { return s.front() == '-' ? s : "+" + s; }

Result<std::string> LinuxCnc(const metrology::ProbingPlan& plan, const ProbeProgramOptions& options) {
  const auto stations = Stations(plan, options);
  if (!stations.ok()) return stations.status();
  const int dec = options.post.decimals;
  auto xyz = [dec](const Eigen::Vector3d& p) {
    return "X" + FormatFixed(p.x(), dec) + " Y" + FormatFixed(p.y(), dec) + " Z" + FormatFixed(p.z(), dec);
  };
  std::ostringstream out;
  out << "%\n(" << CommentText(options.post.title) << ")\n";
  out << "(" << Header(options, plan.points.size()) << ")\n";
  out << "G21 G90 G17 G94 G40 G49 G80\n";
  out << "G0 Z" << FormatFixed(options.safe_z_mm, dec) << "\n";
  out << "(PROBEOPEN " << CommentText(options.results_file) << ")\n";
  for (const Station& s : *stations) {
    out << "(point " << s.id << ")\n";
    out << "G0 X" << FormatFixed(s.start.x(), dec) << " Y" << FormatFixed(s.start.y(), dec) << "\n";
    out << "G0 Z" << FormatFixed(s.start.z(), dec) << "\n";
    out << "G38.2 " << xyz(s.target) << " F" << FormatFixed(options.probe_feed_mm_per_min, 0) << "\n";
    out << "G0 " << xyz(s.start) << "\n";
    out << "G0 Z" << FormatFixed(options.safe_z_mm, dec) << "\n";
  }
  out << "(PROBECLOSE)\nM30\n%\n";
  return out.str();
}

Result<std::string> Fanuc(const metrology::ProbingPlan& plan, const ProbeProgramOptions& options) {
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
  const auto stations = Stations(plan, options);
  if (!stations.ok()) return stations.status();
  ProgramText w(options.post, Numbering::kBlocks, "(", ")");
  w.Raw("%");
  const std::string number = std::to_string(options.post.program_number);
  w.Raw("O" + std::string(4 - number.size(), '0') + number);
  w.Comment(FanucComment(options.post.title));
  w.Comment(FanucComment(Header(options, plan.points.size())));
  w.Comment(FanucComment("results X Y Z per point in macro variables " + std::to_string(base) + " - " +
                         std::to_string(last)));
  w.Block("G21 G90 G17 G94 G40 G49 G80");
  w.Block("G00 Z" + w.Num(options.safe_z_mm));
  const std::string feed = " F" + FormatFixed(options.probe_feed_mm_per_min, 0);
  long var = base;
  for (const Station& s : *stations) {
    w.Comment(FanucComment("point " + std::to_string(s.id)));
    w.Block("G00 X" + w.Num(s.start.x()) + " Y" + w.Num(s.start.y()));
    w.Block("G00 Z" + w.Num(s.start.z()));
    w.Block("G31 " + Xyz(w, s.target) + feed);
    for (int axis = 0; axis < 3; ++axis) w.Block("#" + std::to_string(var++) + "=#" + std::to_string(5061 + axis));
    w.Block("G00 " + Xyz(w, s.start));
    w.Block("G00 Z" + w.Num(options.safe_z_mm));
  }
  w.Block("M30");
  w.Raw("%");
  return w.Finish();
}

Result<std::string> Sinumerik(const metrology::ProbingPlan& plan, const ProbeProgramOptions& options) {
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
  const auto stations = Stations(plan, options);
  if (!stations.ok()) return stations.status();
  ProgramText w(options.post, Numbering::kBlocks, "; ", "");
  w.Comment(PlainComment(options.post.title));
  w.Comment(Header(options, plan.points.size()));
  w.Comment("results X Y Z per point in R" + std::to_string(base) + " .. R" + std::to_string(last));
  w.Block("G71 G90 G17 G40 G94");
  w.Block("G0 Z" + w.Num(options.safe_z_mm));
  const std::string feed = " F" + FormatFixed(options.probe_feed_mm_per_min, 0);
  long r = base;
  for (const Station& s : *stations) {
    w.Comment("point " + std::to_string(s.id));
    w.Block("G0 X" + w.Num(s.start.x()) + " Y" + w.Num(s.start.y()));
    w.Block("G0 Z" + w.Num(s.start.z()));
    w.Block("MEAS=1 G1 " + Xyz(w, s.target) + feed);
    w.Block("STOPRE");
    for (const char* axis : {"X", "Y", "Z"}) w.Block("R" + std::to_string(r++) + "=$AA_MW[" + axis + "]");
    w.Block("G0 " + Xyz(w, s.start));
    w.Block("G0 Z" + w.Num(options.safe_z_mm));
  }
  w.Block("M30");
  return w.Finish();
}

// Heidenhain lines: every block numbered from 0, cycle parameters on unnumbered continuation lines.
class KlartextWriter {
 public:
  explicit KlartextWriter(const PostOptions& options) : options_(options) {}
  void Block(const std::string& text) { Emit(std::to_string(next_++) + " " + text); }
  void Continuation(const std::string& text) { Emit("    " + text); }
  void Comment(const std::string& text) {
    const std::size_t limit = static_cast<std::size_t>(options_.max_line_length);
    const std::size_t frame = std::to_string(next_ + 1000).size() + 3;  // "<n> ; ", generous
    if (limit == 0 || text.size() + frame <= limit || limit <= frame + 8) {
      Block("; " + text);
      return;
    }
    std::string rest = text;
    while (!rest.empty()) {
      std::size_t cut = rest.size();
      if (cut > limit - frame) {
        cut = rest.rfind(' ', limit - frame);
        if (cut == std::string::npos || cut == 0) cut = limit - frame;
      }
      Block("; " + rest.substr(0, cut));
      rest = rest.substr(cut);
      while (!rest.empty() && rest.front() == ' ') rest.erase(rest.begin());
    }
  }
  Result<std::string> Finish() const {
    if (!error_.ok()) return error_;
    return out_;
  }

 private:
  void Emit(const std::string& line) {
    ++lines_;
    const std::size_t limit = static_cast<std::size_t>(options_.max_line_length);
    if (limit > 0 && line.size() > limit && error_.ok()) {
      error_ = Status::BadInput(Where{.line = lines_, .field = "post.max_line_length"},
                                "program line '" + line + "' is " + std::to_string(line.size()) +
                                    " characters, over the limit of " + std::to_string(limit) +
                                    "; no program was written",
                                "raise max_line_length or use fewer decimals");
    }
    out_ += line;
    out_ += '\n';
  }
  const PostOptions& options_;
  std::string out_;
  long next_ = 0;
  long lines_ = 0;
  Status error_ = Status::Ok();
};

Result<std::string> Heidenhain(const metrology::ProbingPlan& plan, const ProbeProgramOptions& options) {
  const auto stations = Stations(plan, options);
  if (!stations.ok()) return stations.status();
  const int dec = options.post.decimals;
  auto num = [dec](double v) { return Signed(FormatFixed(v, dec)); };
  auto unit = [](double v) { return Signed(FormatFixed(v, 6)); };
  KlartextWriter w(options.post);
  w.Block("BEGIN PGM " + options.post.program_name + " MM");
  w.Comment(PlainComment(options.post.title));
  w.Comment("touch probe ball radius " + FormatFixed(options.ball_radius_mm, 4) +
            " mm; cycle 444 at the nominal surface point along -n; " + std::to_string(plan.points.size()) +
            " points");
  // formloop has not checked these Q-parameter numbers against a TNC 640 manual: the program says
  // so, so that nobody runs it on a machine before a dry run and a check of the cycle on the control.
  w.Comment("CHECK BEFORE USE: cycle 444 Q-parameter numbers not verified against the TNC manual; dry run first");
  w.Block("L Z" + num(options.safe_z_mm) + " R0 FMAX");
  for (const Station& s : *stations) {
    w.Comment("point " + std::to_string(s.id));
    w.Block("L X" + num(s.above.x()) + " Y" + num(s.above.y()) + " R0 FMAX");
    w.Block("TCH PROBE 444 PROBING IN 3-D ~");
    w.Continuation("Q263=" + num(s.surface.x()) + " ;1ST POINT 1ST AXIS ~");
    w.Continuation("Q264=" + num(s.surface.y()) + " ;1ST POINT 2ND AXIS ~");
    w.Continuation("Q294=" + num(s.surface.z()) + " ;1ST POINT 3RD AXIS ~");
    w.Continuation("Q581=" + unit(s.normal.x()) + " ;NORMAL VECTOR 1ST AXIS ~");
    w.Continuation("Q582=" + unit(s.normal.y()) + " ;NORMAL VECTOR 2ND AXIS ~");
    w.Continuation("Q583=" + unit(s.normal.z()) + " ;NORMAL VECTOR 3RD AXIS ~");
    w.Continuation("Q320=" + num(options.clearance_mm) + " ;SET-UP CLEARANCE ~");
    w.Continuation("Q260=" + num(options.safe_z_mm) + " ;CLEARANCE HEIGHT ~");
    w.Continuation("Q281=+1 ;MEASURING LOG");
    // M30 (program end) rides on the last positioning block, as in the cutting post.
    w.Block("L Z" + num(options.safe_z_mm) + " R0 FMAX" + (&s == &stations->back() ? " M30" : ""));
  }
  w.Block("END PGM " + options.post.program_name + " MM");
  return w.Finish();
}

}  // namespace

Status ProbeProgramOptions::Validate() const {
  if (!(ball_radius_mm > 0)) return Status::BadInput(Where{.field = "probe.ball_radius_mm"}, "must be > 0");
  if (!(clearance_mm > 0)) return Status::BadInput(Where{.field = "probe.clearance_mm"}, "must be > 0");
  if (!(search_mm > 0)) return Status::BadInput(Where{.field = "probe.search_mm"}, "must be > 0");
  if (!(probe_feed_mm_per_min > 0)) return Status::BadInput(Where{.field = "probe.feed_mm_per_min"}, "must be > 0");
  return post.limits.Validate();
}

std::vector<std::string> ProbingDialectNames() { return {"linuxcnc", "fanuc", "heidenhain", "sinumerik"}; }

Result<std::string> PostProbing(const metrology::ProbingPlan& plan, std::string_view dialect,
                                const ProbeProgramOptions& options) {
  if (dialect == "linuxcnc") return LinuxCnc(plan, options);
  // The other dialects use the O-number, the program name, numbering and the line-length limit.
  if (dialect == "fanuc" || dialect == "heidenhain" || dialect == "sinumerik") {
    FL_RETURN_IF_ERROR(options.post.Validate());
  }
  if (dialect == "fanuc") return Fanuc(plan, options);
  if (dialect == "heidenhain") return Heidenhain(plan, options);
  if (dialect == "sinumerik") return Sinumerik(plan, options);
  return Status::BadInput(Where{.field = "post.dialect"},
                          "no probing post for dialect '" + std::string(dialect) + "'",
                          "use linuxcnc, fanuc, heidenhain or sinumerik");
}

Result<std::string> PostLinuxCncProbing(const metrology::ProbingPlan& plan, const ProbeProgramOptions& options) {
  return LinuxCnc(plan, options);
}

}  // namespace formloop::nc
