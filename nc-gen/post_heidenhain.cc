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

std::string Signed(const ProgramText& w, double value) {
  const std::string s = w.Num(value);
  return s.front() == '-' ? s : "+" + s;
}

class HeidenhainPost : public PostDialect {
 public:
  std::string_view Name() const override { return "heidenhain"; }
  std::string_view FileExtension() const override { return ".h"; }

  Result<std::string> Format(const MoveList& list, const PostOptions& options) const override {
    ProgramText w(options, Numbering::kAllLines, "; ", "");
    const MoveListHeader& h = list.header;
    std::size_t first_motion = list.moves.size(), last_motion = 0;
    for (std::size_t i = 0; i < list.moves.size(); ++i) {
      if (list.moves[i].type == MoveType::kRapid || list.moves[i].type == MoveType::kFeed) {
        first_motion = std::min(first_motion, i);
        last_motion = i;
      }
    }
    if (first_motion == list.moves.size()) return Status::BadInput("the move list has no motion; nothing to post");
    w.Block("BEGIN PGM " + options.program_name + " MM");
    w.Comment(PlainComment(options.title));
    w.Comment("ball-end tool T" + std::to_string(h.tool_number) + " radius " + w.Num(h.tool_radius_mm) +
              " mm; programmed point = ball tip; " + std::to_string(h.passes) + " passes");
    w.Block("TOOL CALL " + std::to_string(h.tool_number) + " Z S" + FormatFixed(h.spindle_rpm, 0));
    double written_feed = -1;  // the last numeric F in the program (FMAX does not change it)
    for (std::size_t i = 0; i < list.moves.size(); ++i) {
      const Move& m = list.moves[i];
      if (m.type == MoveType::kComment) {
        w.Comment(PlainComment(m.text));
        continue;
      }
      if (m.type == MoveType::kSetFeed) continue;  // no block of its own: the next L carries the new F
      std::string block = "L";
      static const char kAxis[] = {'X', 'Y', 'Z'};
      for (int a = 0; a < 3; ++a) {
        if ((m.axes & (1u << a)) != 0) block += std::string(" ") + kAxis[a] + Signed(w, m.tip[a]);
      }
      block += " R0";
      if (m.type == MoveType::kRapid) {
        block += " FMAX";
      } else if (m.feed_mm_per_min != written_feed) {
        written_feed = m.feed_mm_per_min;
        block += " F" + FormatFixed(m.feed_mm_per_min, 0);
      }
      if (i == first_motion) block += h.coolant ? " M3 M8" : " M3";
      if (i == last_motion) block += " M30";
      w.Block(block);
    }
    w.Block("END PGM " + options.program_name + " MM");
    return w.Finish();
  }

  Result<std::vector<ProgramMove>> Read(const std::string& text, const std::string& source) const override {
    const std::string fix = "only formloop's own Heidenhain output can be read back";
    std::vector<ProgramMove> moves;
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
        moves.push_back({.rapid = rapid, .tip = position, .line = line_no, .feed_mm_per_min = feed, .comment = ""});
      }
    }
    if (!ended) return Status::BadInput(Where{.file = source, .line = line_no}, "no END PGM line", fix);
    return moves;
  }
};

}  // namespace

std::unique_ptr<PostDialect> MakeHeidenhainPost() { return std::make_unique<HeidenhainPost>(); }

}  // namespace formloop::nc::internal
