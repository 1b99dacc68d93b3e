// Heidenhain TNC conversational (Klartext) post (HEIDENHAIN TNC 640 User's Manual "Klartext
// programming": "Program structure", "Path contours - Cartesian coordinates", "Tool call"):
//   - every line begins with its block number, 0 for BEGIN PGM, consecutive; the control renumbers on edit;
//   - BEGIN PGM <name> MM / END PGM <name> MM bracket the program (MM = metric);
//   - TOOL CALL <n> Z S<rpm> selects the tool along the Z axis and the spindle speed (length from the table);
//   - L X+10.000 Y-2.000 Z+1.000 R0 F1200: straight line, coordinates with an explicit sign, R0 = no radius
//     compensation, F modal in mm/min; FMAX = rapid for this block only (the last F applies again after);
//   - M functions ride on a positioning block (M3 acts at its start, M30 = program end with spindle and
//     coolant off, at its end);
//   - "; text" is a comment line.
// BLK FORM (the graphics' workpiece blank) is not written: the control does not need it to run.

// Probing (FormatProbing):
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

#include <algorithm>
#include <cctype>
#include <cmath>
#include <sstream>
#include <string>

#include "core/number_text.h"
#include "nc-gen/post.h"
#include "nc-gen/post_text.h"

namespace formloop::nc::internal {
namespace {

std::string WithSign(const std::string& s) { return s.front() == '-' ? s : "+" + s; }

std::string Signed(const ProgramText& w, double value) {
  const std::string s = w.Num(value);
  return s.front() == '-' ? s : "+" + s;
}

class HeidenhainPost : public PostDialect {
 public:
  std::string_view Name() const override { return "heidenhain"; }
  std::string_view FileExtension() const override { return ".h"; }

  Result<std::string> Format(const MoveSequence& moves, const PostOptions& options) const override {
    ProgramText w(options, Numbering::kAllLines, "; ", "");
    const MoveListHeader& h = moves.Header();
    const std::size_t none = moves.Size();
    std::size_t first_motion = none, last_motion = 0;
    FL_RETURN_IF_ERROR(moves.ForEach([&](std::size_t i, const Move& m) {
      if (m.type == MoveType::kRapid || m.type == MoveType::kFeed) {
        first_motion = std::min(first_motion, i);
        last_motion = i;
      }
      return Status::Ok();
    }));
    if (first_motion == none) return Status::BadInput("the move list has no motion; nothing to post");
    w.Reserve(40 * moves.Size());  // "12345 L X+123.4567 Y+123.4567 Z+12.3456 R0" and a newline is about 40
    w.Block("BEGIN PGM " + options.program_name + " MM");
    w.Comment(PlainComment(options.title));
    w.Comment("ball-end tool T" + std::to_string(h.tool_number) + " radius " + w.Num(h.tool_radius_mm) +
              " mm; programmed point = ball tip [TOOL CALL: length L of the tool table to the ball tip]; " +
              std::to_string(h.passes) + " passes");
    w.Block("TOOL CALL " + std::to_string(h.tool_number) + " Z S" + FormatFixed(h.spindle_rpm, 0));
    // The modal state before a move: the last numeric F in the program (FMAX does not change it; -1: none).
    const auto format = [&](const Move& m, std::size_t i, const double& written_feed, LineBatch* out) {
      if (m.type == MoveType::kComment) {
        out->Comment(PlainComment(m.text));
        return;
      }
      if (m.type == MoveType::kSetFeed) return;  // no block of its own: the next L carries the new F
      std::string block = "L";
      static const char kAxis[] = {'X', 'Y', 'Z'};
      for (int a = 0; a < 3; ++a) {
        if ((m.axes & (1u << a)) != 0) block += std::string(" ") + kAxis[a] + Signed(w, m.tip[a]);
      }
      block += " R0";
      if (m.type == MoveType::kRapid) {
        block += " FMAX";
      } else if (m.feed_mm_per_min != written_feed) {
        block += " F" + FormatFixed(m.feed_mm_per_min, 0);
      }
      if (i == first_motion) block += h.coolant ? " M3 M8" : " M3";
      if (i == last_motion) block += " M30";
      out->Block(block);
    };
    const auto advance = [](double* written_feed, const Move& m) {
      if (m.type == MoveType::kFeed) *written_feed = m.feed_mm_per_min;
    };
    FL_RETURN_IF_ERROR(FormatMovesInChunks(moves, -1.0, format, advance, &w));
    w.Block("END PGM " + options.program_name + " MM");
    return w.Finish();
  }

  Result<std::vector<ProgramMove>> Read(const std::string& text, const std::string& source) const override {
    const std::string fix = "only formloop's own Heidenhain output can be read back";
    std::vector<ProgramMove> moves;
    moves.reserve(LineCount(text));  // at most a move per line: allocated once
    Eigen::Vector3d position = Eigen::Vector3d::Constant(std::nan(""));
    double feed = 0;
    bool begun = false, ended = false;
    std::istringstream in(text);
    std::string raw;
    long line_no = 0;
    while (std::getline(in, raw)) {
      ++line_no;
      const Where where{.file = source, .line = line_no};
      if (ended) return Status::BadInput(where, "text after END PGM", fix);
      // The block number: digits, one space, consecutive from 0.
      std::size_t k = 0;
      while (k < raw.size() && std::isdigit(static_cast<unsigned char>(raw[k]))) ++k;
      if (k == 0 || k >= raw.size() || raw[k] != ' ' || raw.substr(0, k) != std::to_string(line_no - 1)) {
        return Status::BadInput(where, "expected block number " + std::to_string(line_no - 1) + " and a space", fix);
      }
      const std::string body = raw.substr(k + 1);
      if (body.starts_with(";")) continue;
      std::istringstream words(body);
      std::vector<std::string> w;
      for (std::string word; words >> word;) w.push_back(word);
      if (w.empty()) return Status::BadInput(where, "empty block", fix);
      if (!begun) {
        if (w.size() != 4 || w[0] != "BEGIN" || w[1] != "PGM")
          return Status::BadInput(where, "expected BEGIN PGM", fix);
        if (w[3] != "MM") {
          return Status::BadInput(where, "unit '" + w[3] + "' is not supported", "program in millimetres (MM)");
        }
        begun = true;
        continue;
      }
      if (w[0] == "END") {
        if (w.size() != 4 || w[1] != "PGM" || w[3] != "MM") return Status::BadInput(where, "malformed END PGM", fix);
        ended = true;
        continue;
      }
      if (w[0] == "TOOL") {
        if (w.size() != 5 || w[1] != "CALL" || w[3] != "Z" || !w[4].starts_with("S")) {
          return Status::BadInput(where, "expected TOOL CALL <n> Z S<rpm>", fix);
        }
        continue;
      }
      if (w[0] != "L") return Status::BadInput(where, "unsupported block '" + w[0] + "'", fix);
      bool rapid = false, has_xyz = false, r0 = false;
      for (std::size_t j = 1; j < w.size(); ++j) {
        const std::string& word = w[j];
        double value = 0;
        if (word == "FMAX") {
          rapid = true;
        } else if (word == "R0") {
          r0 = true;
        } else if ((word[0] == 'X' || word[0] == 'Y' || word[0] == 'Z') && word.size() > 2 &&
                   (word[1] == '+' || word[1] == '-') && ParseDouble(word.substr(1), &value)) {
          position[word[0] - 'X'] = value;
          has_xyz = true;
        } else if (word[0] == 'F' && ParseDouble(word.substr(1), &value)) {
          feed = value;
        } else if (word[0] == 'M' && ParseDouble(word.substr(1), &value)) {
          // spindle and program-end functions: no motion
        } else {
          return Status::BadInput(where, "unsupported word '" + word + "'",
                                  "incremental (IX), radius compensation (RL/RR) and unsigned coordinates are not "
                                  "formloop output; " +
                                      fix);
        }
      }
      if (!r0) return Status::BadInput(where, "L block without R0", fix);
      if (has_xyz) {
        moves.push_back({.rapid = rapid, .tip = position, .line = line_no, .feed_mm_per_min = feed});
      }
    }
    if (!ended) return Status::BadInput(Where{.file = source, .line = line_no}, "no END PGM line", fix);
    return moves;
  }

  Result<std::string> FormatProbing(const metrology::ProbingPlan& plan,
                                    const ProbeProgramOptions& options) const override {
    FL_RETURN_IF_ERROR(options.post.Validate());
    const auto stations = ProbeStations(plan, options);
    if (!stations.ok()) return stations.status();
    for (const ProbeStation& s : *stations) {
      if (s.tilted) {
        return Status::BadInput(Where{.field = "separating_experiment"},
                                "probe point " + std::to_string(s.id) +
                                    " has a tilted approach; Heidenhain's cycle 444 probes along the normal it is "
                                    "given, so a tilted approach cannot be programmed and no program was written",
                                "probe the tilted points on a linuxcnc, fanuc or sinumerik control, or leave the "
                                "separating experiment out of the part file");
      }
    }
    const int dec = options.post.decimals;
    auto num = [dec](double v) { return WithSign(FormatFixed(v, dec)); };
    auto unit = [](double v) { return WithSign(FormatFixed(v, 6)); };
    ProgramText w(options.post, Numbering::kAllLines, "; ", "");
    w.Block("BEGIN PGM " + options.post.program_name + " MM");
    w.Comment(PlainComment(options.post.title));
    w.Comment("touch probe T" + std::to_string(options.probe_tool) + " ball radius " +
              FormatFixed(options.ball_radius_mm, 4) + " mm; cycle 444 at the nominal surface point along -n; " +
              std::to_string(plan.points.size()) + " points");
    // formloop has not checked these Q-parameter numbers against a TNC 640 manual: the program says
    // so, so that nobody runs it on a machine before a dry run and a check of the cycle on the control.
    w.Comment("CHECK BEFORE USE: cycle 444 Q-parameter numbers not verified against the TNC manual; dry run first");
    w.Block("TOOL CALL " + std::to_string(options.probe_tool) + " Z");
    w.Block("L Z" + num(options.safe_z_mm) + " R0 FMAX");
    for (const ProbeStation& s : *stations) {
      w.Comment("point " + std::to_string(s.id));
      w.Block("L X" + num(s.above.x()) + " Y" + num(s.above.y()) + " R0 FMAX");
      w.Block("TCH PROBE 444 PROBING IN 3-D ~");
      w.Continuation("Q263=" + num(s.surface.x()) + " ;1ST POINT 1ST AXIS ~");
      w.Continuation("Q264=" + num(s.surface.y()) + " ;1ST POINT 2ND AXIS ~");
      w.Continuation("Q294=" + num(s.surface.z()) + " ;1ST POINT 3RD AXIS ~");
      w.Continuation("Q581=" + unit(s.normal.x()) + " ;NORMAL VECTOR 1ST AXIS ~");
      w.Continuation("Q582=" + unit(s.normal.y()) + " ;NORMAL VECTOR 2ND AXIS ~");
      w.Continuation("Q583=" + unit(s.normal.z()) + " ;NORMAL VECTOR 3RD AXIS ~");
      w.Continuation("Q320=" + num(s.clearance_mm) + " ;SET-UP CLEARANCE ~");
      w.Continuation("Q260=" + num(options.safe_z_mm) + " ;CLEARANCE HEIGHT ~");
      w.Continuation("Q281=+1 ;MEASURING LOG");
      // M30 (program end) rides on the last positioning block, as in the cutting post.
      w.Block("L Z" + num(options.safe_z_mm) + " R0 FMAX" + (&s == &stations->back() ? " M30" : ""));
    }
    w.Block("END PGM " + options.post.program_name + " MM");
    return w.Finish();
  }
};

}  // namespace

std::unique_ptr<PostDialect> MakeHeidenhainPost() { return std::make_unique<HeidenhainPost>(); }

}  // namespace formloop::nc::internal
