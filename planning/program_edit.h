#pragma once
// Editing a formloop word-address program (the LinuxCNC, Fanuc and Sinumerik output of nc-gen/post.h)
// in place: the feed (F), spindle (S) and axis (X, Y, Z) words of chosen blocks, new blocks between
// two blocks, and header comments. Every line the edit does not touch stays byte-identical, so a
// re-optimised program differs from its parent only where it must (spec/process-optimization.md §1.8,
// §3.4).
//
// The program is read with the dialect's own reader (nc::ReadProgram), which refuses anything that is
// not formloop's own output, naming the line; the edited text is read back the same way before it is
// returned (EditableProgram::Verified), so an edit can never produce a program the reader would not take.
// Heidenhain conversational programs (L X.. F..) are not word-address programs and are refused.
//
// ProgramReading::kShopProgram reads any RS274NGC (LinuxCNC) or Fanuc program through the G-code reader
// (nc-gen/gcode_reader.h) instead: arcs and helices (G2/G3, their exact length from the reader's arc
// geometry), G91 incremental sections, G20 inch programs, words without blanks between them ("G1X10F300"),
// lower-case letters, N words anywhere. Feeds are written in the program's own units at the block (G20:
// inch/min, two decimals, rounded down; G21: whole mm/min, rounded down) and only where a feed changes:
// a non-cutting block keeps its F word byte for byte, and an F word is added only where the modal feed of
// the edited program would otherwise differ from the original's. Refused, naming the line, because an
// F/S edit cannot be proven safe there: words the reader does not know, macro code (# parameters,
// [expressions], O-word control flow, M98/M99/G65/G66 sub-programs), canned cycles (G73-G89: their
// feeds are not moves the reader models), feed moves in inverse-time (G93) or per-revolution (G95) feed
// mode, constant surface speed (G96: S is a surface speed there). The edited program is read back by the
// reader and must give the same path (every move's kind, ends, arc centre, sweep and rise, units,
// rotary axes) with exactly the feeds written (Verified). Level 3 (planning/inspection_adjustment.h)
// edits axis words and stays on kFormloopSubset.
//
// A block is named in messages by its N word ("N120") when the program numbers its blocks, otherwise by
// its line ("line 57").

#include <Eigen/Core>
#include <map>
#include <string>
#include <utility>
#include <vector>

#include "core/status.h"
#include "nc-gen/post.h"

namespace formloop::planning {

struct ProgramLine {
  std::string text;
  long number = -1;  // N word, −1 when the line has none
  int move = -1;     // index into EditableProgram::moves() of the move this line commands, −1 if none
};

enum class ProgramReading {
  kFormloopSubset,  // nc::ReadProgram: formloop's own output (mm, absolute, straight moves)
  kShopProgram,     // nc::GcodeReader: RS274NGC / Fanuc shop programs (F and S edits only)
};

class EditableProgram {
 public:
  // Reads `text` in `dialect` ("linuxcnc", "fanuc", "sinumerik").
  static Result<EditableProgram> Parse(const std::string& text, const std::string& dialect, const std::string& source,
                                       ProgramReading reading = ProgramReading::kFormloopSubset);

  const std::string& dialect() const { return dialect_; }
  const std::vector<ProgramLine>& lines() const { return lines_; }
  // The moves as read (rapid/feed, end point, modal feed, 1-based line).
  const std::vector<nc::ProgramMove>& moves() const { return moves_; }
  // Start of move i: the end of move i − 1 (NaN axes before the first programmed position).
  Eigen::Vector3d MoveStart(std::size_t i) const;
  // Path length of move i, mm: the chord of a straight move, ArcGeometry::Length of an arc or helix
  // (kShopProgram); NaN when an end is not known (after G28, G53, G92 ...).
  double MoveLengthMm(std::size_t i) const;
  // What the reading found worth saying (kShopProgram: cutter radius compensation active).
  const std::vector<std::string>& warnings() const { return warnings_; }
  // Line index (0-based) of move i.
  std::size_t LineOfMove(std::size_t i) const { return static_cast<std::size_t>(moves_[i].line - 1); }
  bool NumberedBlocks() const;
  // "N120" or "line 57" for the line at 0-based index.
  std::string BlockName(std::size_t line_index) const;
  // Decimals the program writes coordinates with (from its first axis word; 4 if none).
  int Decimals() const { return decimals_; }

  // Sets (or adds) `letter`'s value on a line; the rest of the line keeps its bytes.
  void SetWord(std::size_t line_index, char letter, const std::string& value);
  // The line's text with these words set (or added), the program unchanged.
  std::string WithWords(std::size_t line_index, const std::vector<std::pair<char, std::string>>& words) const;
  // The value of `letter` on the line, when present outside comments.
  bool GetWord(std::size_t line_index, char letter, std::string* value) const;
  // Gives each feed move i in feed_of_move that feed and every other feed move its original one: an F word
  // is written where the modal feed would otherwise be wrong, and rewritten where the line has one.
  // Call before InsertLines (it works on the lines as parsed). kShopProgram: feeds in program units, a
  // non-cutting block's F word kept as it is (see the header comment).
  void SetFeeds(const std::map<std::size_t, double>& feed_of_move);
  // Inserts lines before line_index (their number/move fields are informational only).
  void InsertLines(std::size_t line_index, const std::vector<std::string>& texts);
  // Inserts comment lines after the leading comments (and '%', "O1234") of the program.
  void InsertHeaderComments(const std::vector<std::string>& comments);
  // A comment line in this dialect ("(...)" LinuxCNC/Fanuc, "; ..." Sinumerik).
  std::string CommentLine(const std::string& text) const;

  std::string Text() const;
  // The text after reading it back with the dialect's reader; the reader's refusal otherwise.
  Result<std::string> Verified(const std::string& source) const;

 private:
  struct LineUnits {
    double mm_per_unit = 1;  // units in effect at the line (after it)
  };
  Status ReadShop(const std::string& source);
  void SetShopFeeds(const std::map<std::size_t, double>& feed_of_move);
  Result<std::string> VerifiedShop(const std::string& source) const;

  std::string dialect_;
  ProgramReading reading_ = ProgramReading::kFormloopSubset;
  std::string original_;                            // kShopProgram: the text as read (the path Verified compares with)
  std::vector<LineUnits> units_;                    // kShopProgram: per line as parsed
  std::vector<double> length_mm_;                   // per move
  std::map<std::size_t, double> expected_feed_mm_;  // kShopProgram: move -> feed written by SetFeeds, mm/min
  std::vector<std::string> warnings_;
  std::string trailing_;  // what follows the last newline-terminated line
  std::vector<ProgramLine> lines_;
  std::vector<nc::ProgramMove> moves_;
  int decimals_ = 4;
};

// Fixed-point text of a feed (0 decimals) or coordinate, locale-free.
std::string FeedWord(double feed_mm_per_min);

}  // namespace formloop::planning
