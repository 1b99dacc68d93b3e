#include "planning/program_edit.h"

#include <algorithm>
#include <cctype>
#include <cmath>

#include "core/point_io.h"
#include "nc-gen/gcode_reader.h"

namespace formloop::planning {
namespace {

// [begin, end) of the code part of a line: everything outside comments is code in formloop's output,
// where comments fill whole lines; a ';' starts a comment to the end of the line (Sinumerik).
struct Token {
  std::size_t begin, end;
};

bool IsCommentLine(const std::string& text, bool semicolon) {
  std::size_t i = 0;
  while (i < text.size() && std::isspace(static_cast<unsigned char>(text[i]))) ++i;
  if (i == text.size()) return false;
  return semicolon ? text[i] == ';' : text[i] == '(';
}

// Whitespace-separated tokens of the code part (up to the first comment).
std::vector<Token> CodeTokens(const std::string& text, bool semicolon) {
  std::vector<Token> out;
  std::size_t i = 0;
  while (i < text.size()) {
    while (i < text.size() && std::isspace(static_cast<unsigned char>(text[i]))) ++i;
    if (i >= text.size() || text[i] == '(' || (semicolon && text[i] == ';')) break;
    const std::size_t b = i;
    while (i < text.size() && !std::isspace(static_cast<unsigned char>(text[i])) && text[i] != '(' &&
           !(semicolon && text[i] == ';')) {
      ++i;
    }
    out.push_back({b, i});
  }
  return out;
}

bool IsWord(const std::string& text, const Token& t, char letter) {
  if (t.end - t.begin < 2 || std::toupper(static_cast<unsigned char>(text[t.begin])) != letter) return false;
  const char c = text[t.begin + 1];
  return std::isdigit(static_cast<unsigned char>(c)) || c == '-' || c == '+' || c == '.';
}

// A word of a shop program as the G-code reader sees it: a letter, optional blanks, a signed number;
// words may follow each other without blanks ("G1X10F300"), letters may be lower case. Comments "( )"
// and ';' to the end of the line are skipped.
struct ShopWord {
  char letter;
  std::size_t begin, value_begin, end;
};

std::vector<ShopWord> ShopWords(const std::string& t) {
  std::vector<ShopWord> out;
  std::size_t i = 0;
  const std::size_t n = t.size();
  while (i < n) {
    const char c = t[i];
    if (c == '(') {
      const std::size_t close = t.find(')', i);
      i = close == std::string::npos ? n : close + 1;
      continue;
    }
    if (c == ';') break;
    if (!std::isalpha(static_cast<unsigned char>(c))) {
      ++i;
      continue;
    }
    std::size_t j = i + 1;
    while (j < n && (t[j] == ' ' || t[j] == '\t')) ++j;
    const std::size_t value_begin = j;
    if (j < n && (t[j] == '+' || t[j] == '-')) ++j;
    const std::size_t digits = j;
    while (j < n && (std::isdigit(static_cast<unsigned char>(t[j])) || t[j] == '.')) ++j;
    if (j > digits) {
      out.push_back({static_cast<char>(std::toupper(static_cast<unsigned char>(c))), i, value_begin, j});
      i = j;
    } else {
      i = i + 1;
    }
  }
  return out;
}

// Notes of the reader that make an F/S edit unsafe to prove: the reader does not know the word, or the
// feed and path depend on code it does not execute.
bool RefusedForEdit(const nc::Note& note) {
  if (note.kind == nc::NoteKind::kUnknown) return true;
  static const char* const kRefused[] = {"#", "[", "O", "M98", "M99", "M198", "G65", "G66", "G66.1", "G67"};
  for (const char* w : kRefused) {
    if (note.word == w) return true;
  }
  return note.what.find("canned cycle") != std::string::npos;
}

std::string LineName(long number, std::size_t index) {
  return number >= 0 ? "N" + std::to_string(number) + " (line " + std::to_string(index + 1) + ")"
                     : "line " + std::to_string(index + 1);
}

}  // namespace

std::string FeedWord(double feed_mm_per_min) { return FormatFixed(feed_mm_per_min, 0); }

Result<EditableProgram> EditableProgram::Parse(const std::string& text, const std::string& dialect,
                                               const std::string& source, ProgramReading reading) {
  if (dialect != "linuxcnc" && dialect != "fanuc" && dialect != "sinumerik") {
    return Status::BadInput(Where{.file = source, .field = "dialect"},
                            "'" + dialect + "' programs cannot be edited word by word",
                            "use a LinuxCNC, Fanuc or Sinumerik program (word-address G-code)");
  }
  EditableProgram p;
  p.dialect_ = dialect;
  p.reading_ = reading;
  if (reading == ProgramReading::kFormloopSubset) {
    FL_ASSIGN_OR_RETURN(p.moves_, nc::ReadProgram(text, dialect, source));
  }
  std::size_t start = 0;
  while (true) {
    const std::size_t end = text.find('\n', start);
    if (end == std::string::npos) {
      p.trailing_ = text.substr(start);
      break;
    }
    p.lines_.push_back({text.substr(start, end - start), -1, -1});
    start = end + 1;
  }
  if (reading == ProgramReading::kShopProgram) {
    p.original_ = text;
    FL_RETURN_IF_ERROR(p.ReadShop(source));
    return p;
  }
  const bool semicolon = dialect == "sinumerik";
  bool decimals_found = false;
  for (ProgramLine& line : p.lines_) {
    if (IsCommentLine(line.text, semicolon)) continue;
    const std::vector<Token> tokens = CodeTokens(line.text, semicolon);
    if (!tokens.empty() && IsWord(line.text, tokens[0], 'N')) {
      line.number = std::stol(line.text.substr(tokens[0].begin + 1, tokens[0].end - tokens[0].begin - 1));
    }
    for (const Token& t : tokens) {
      if (decimals_found || !(IsWord(line.text, t, 'X') || IsWord(line.text, t, 'Y') || IsWord(line.text, t, 'Z'))) {
        continue;
      }
      const std::string word = line.text.substr(t.begin, t.end - t.begin);
      const std::size_t dot = word.find('.');
      p.decimals_ = dot == std::string::npos ? 0 : static_cast<int>(word.size() - dot - 1);
      decimals_found = true;
    }
  }
  for (std::size_t i = 0; i < p.moves_.size(); ++i) {
    const auto line = static_cast<std::size_t>(p.moves_[i].line - 1);
    if (line < p.lines_.size()) p.lines_[line].move = static_cast<int>(i);
    const Eigen::Vector3d a = p.MoveStart(i), b = p.moves_[i].tip;
    p.length_mm_.push_back(a.allFinite() && b.allFinite() ? (b - a).norm() : std::nan(""));
  }
  return p;
}

Status EditableProgram::ReadShop(const std::string& source) {
  if (dialect_ == "sinumerik") {
    return Status::BadInput(Where{.file = source, .field = "dialect"},
                            "shop programs are read as RS274NGC (linuxcnc) or Fanuc programs",
                            "give --dialect linuxcnc or fanuc");
  }
  FL_ASSIGN_OR_RETURN(const nc::GcodeDialect d, nc::ParseGcodeDialect(dialect_));
  nc::ReaderOptions options;
  options.dialect = d;
  nc::GcodeReader reader(options, source);
  nc::Block block;
  bool compensation_warned = false;
  int percent = 0;
  units_.assign(lines_.size() + 1, LineUnits{});
  // The same blocks, in the same order, as nc::ReadProgramPath takes for moves (Verified compares them).
  const std::size_t count = lines_.size() + (trailing_.empty() ? 0 : 1);
  for (std::size_t i = 0; i < count; ++i) {
    std::string_view view = i < lines_.size() ? std::string_view(lines_[i].text) : std::string_view(trailing_);
    if (!view.empty() && view.back() == '\r') view.remove_suffix(1);
    FL_RETURN_IF_ERROR(reader.Read(view, &block));
    const std::string name = LineName(block.n_word, i);
    const Where where{.file = source, .line = static_cast<long>(i + 1)};
    for (const nc::Note& note : block.notes) {
      if (RefusedForEdit(note)) {
        return Status::BadInput(where,
                                name + ": " + note.word + " (" + note.what +
                                    "): F and S cannot be rewritten safely where the reader does not model the "
                                    "program",
                                "optimise a program without macro code, sub-programs, canned cycles or unknown words "
                                "(expand them with the CAM system's post)");
      }
      if (note.kind == nc::NoteKind::kCompensation && !compensation_warned) {
        warnings_.push_back(source + " " + name + ": cutter radius compensation " + note.word +
                            " is active; block lengths are those of the programmed contour");
        compensation_warned = true;
      }
    }
    if (block.HasG(96)) {
      return Status::BadInput(where, name + ": G96 constant surface speed: S is a surface speed there, not rpm",
                              "program the spindle in G97 (rpm) to have S optimised");
    }
    if (i < lines_.size()) {
      lines_[i].number = block.n_word;
      units_[i].mm_per_unit = block.mm_per_unit();
    }
    if (block.percent && ++percent == 2) break;
    if (block.motion != nc::Motion::kNone) {
      const bool rapid = block.motion == nc::Motion::kRapid;
      if (!rapid && block.feed_mode != nc::FeedMode::kUnitsPerMinute) {
        return Status::BadInput(
            where,
            name + ": feed move in " +
                (block.feed_mode == nc::FeedMode::kInverseTime ? "G93 inverse-time" : "G95 per-revolution") +
                " feed mode: a feed in mm/min cannot be written into it",
            "program the operation in G94 (units per minute)");
      }
      nc::ProgramMove m;
      m.rapid = rapid;
      m.line = static_cast<long>(i + 1);
      const double mpu = block.mm_per_unit();
      for (int a = 0; a < 3; ++a) m.tip[a] = (block.end_known >> a & 1u) ? block.end[a] * mpu : std::nan("");
      m.feed_mm_per_min = block.feed * mpu;
      if (i < lines_.size()) lines_[i].move = static_cast<int>(moves_.size());
      moves_.push_back(m);
      length_mm_.push_back(block.ends_known() ? block.LengthMm() : std::nan(""));
    }
    if (block.program_end) break;
  }
  for (std::size_t i = 0; i < lines_.size() && decimals_ == 4; ++i) {
    for (const ShopWord& w : ShopWords(lines_[i].text)) {
      if (w.letter != 'X' && w.letter != 'Y' && w.letter != 'Z') continue;
      const std::string v = lines_[i].text.substr(w.value_begin, w.end - w.value_begin);
      const std::size_t dot = v.find('.');
      decimals_ = dot == std::string::npos ? 0 : static_cast<int>(v.size() - dot - 1);
      break;
    }
  }
  return Status::Ok();
}

double EditableProgram::MoveLengthMm(std::size_t i) const { return length_mm_[i]; }

Eigen::Vector3d EditableProgram::MoveStart(std::size_t i) const {
  if (i == 0) return Eigen::Vector3d::Constant(std::nan(""));
  return moves_[i - 1].tip;
}

bool EditableProgram::NumberedBlocks() const {
  for (const ProgramLine& l : lines_) {
    if (l.number >= 0) return true;
  }
  return false;
}

std::string EditableProgram::BlockName(std::size_t line_index) const {
  const ProgramLine& l = lines_[line_index];
  if (l.number >= 0) return "N" + std::to_string(l.number);
  return "line " + std::to_string(line_index + 1);
}

void EditableProgram::SetWord(std::size_t line_index, char letter, const std::string& value) {
  lines_[line_index].text = WithWords(line_index, {{letter, value}});
}

std::string EditableProgram::WithWords(std::size_t line_index,
                                       const std::vector<std::pair<char, std::string>>& words) const {
  std::string text = lines_[line_index].text;
  const bool semicolon = dialect_ == "sinumerik";
  if (reading_ == ProgramReading::kShopProgram) {
    for (const auto& [letter, value] : words) {
      const std::vector<ShopWord> found = ShopWords(text);
      // A named copy: C++20 lets a lambda capture a structured binding, clang 14 (fuzzing, sanitizers) does not.
      const char wanted = letter;
      auto it = std::find_if(found.begin(), found.end(), [wanted](const ShopWord& w) { return w.letter == wanted; });
      if (it != found.end()) {
        text.replace(it->value_begin, it->end - it->value_begin, value);
        continue;
      }
      // Spelled like the line: a blank before the new word when the line separates its words.
      const std::size_t at = found.empty() ? text.size() : found.back().end;
      const bool blanks = found.size() < 2 || text.find_first_of(" \t", found.front().begin) < at;
      text.insert(at, std::string(blanks ? " " : "") + letter + value);
    }
    return text;
  }
  for (const auto& [letter, value] : words) {
    const std::vector<Token> tokens = CodeTokens(text, semicolon);
    bool done = false;
    for (const Token& t : tokens) {
      if (IsWord(text, t, letter)) {
        text.replace(t.begin + 1, t.end - t.begin - 1, value);
        done = true;
        break;
      }
    }
    if (done) continue;
    const std::size_t at = tokens.empty() ? text.size() : tokens.back().end;
    text.insert(at, std::string(tokens.empty() ? "" : " ") + letter + value);
  }
  return text;
}

bool EditableProgram::GetWord(std::size_t line_index, char letter, std::string* value) const {
  const std::string& text = lines_[line_index].text;
  if (reading_ == ProgramReading::kShopProgram) {
    for (const ShopWord& w : ShopWords(text)) {
      if (w.letter != letter) continue;
      *value = text.substr(w.value_begin, w.end - w.value_begin);
      return true;
    }
    return false;
  }
  for (const Token& t : CodeTokens(text, dialect_ == "sinumerik")) {
    if (IsWord(text, t, letter)) {
      *value = text.substr(t.begin + 1, t.end - t.begin - 1);
      return true;
    }
  }
  return false;
}

void EditableProgram::SetFeeds(const std::map<std::size_t, double>& feed_of_move) {
  if (reading_ == ProgramReading::kShopProgram) return SetShopFeeds(feed_of_move);
  double modal = -1;  // the feed in effect in the edited program
  std::string word;
  for (std::size_t i = 0; i < lines_.size(); ++i) {
    const int m = lines_[i].move;
    const bool has_f = GetWord(i, 'F', &word);
    if (m < 0) {
      if (has_f && !ParseDouble(word, &modal)) modal = -1;  // a feed-only block sets the modal feed
      continue;
    }
    const nc::ProgramMove& move = moves_[static_cast<std::size_t>(m)];
    if (move.rapid) continue;
    auto it = feed_of_move.find(static_cast<std::size_t>(m));
    const double want = it != feed_of_move.end() ? it->second : move.feed_mm_per_min;
    if (has_f || want != modal) SetWord(i, 'F', FeedWord(want));
    modal = want;
  }
}

void EditableProgram::SetShopFeeds(const std::map<std::size_t, double>& feed_of_move) {
  // The modal feed of the edited program, mm/min (the reader carries it across G20/G21 changes).
  double modal_mm = -1;
  std::string word;
  expected_feed_mm_.clear();
  for (std::size_t i = 0; i < lines_.size(); ++i) {
    const double mpu = units_[i].mm_per_unit;
    const int m = lines_[i].move;
    const bool has_f = GetWord(i, 'F', &word);
    double value = 0;
    const bool f_read = has_f && ParseDouble(word, &value);
    if (m < 0 || moves_[static_cast<std::size_t>(m)].rapid) {
      if (f_read) modal_mm = value * mpu;  // a feed on a non-feed block sets the modal feed
      continue;
    }
    const auto move = static_cast<std::size_t>(m);
    auto it = feed_of_move.find(move);
    std::string text;
    if (it != feed_of_move.end()) {
      // Rounded down in the program's units: never above the optimum.
      const int decimals = mpu == 1.0 ? 0 : 2;
      const double scale = std::pow(10.0, decimals);
      text = FormatFixed(std::floor(it->second / mpu * scale + 1e-9) / scale, decimals);
    } else if (f_read || std::abs(moves_[move].feed_mm_per_min - modal_mm) <= 1e-9 * moves_[move].feed_mm_per_min) {
      modal_mm = f_read ? value * mpu : modal_mm;  // unchanged: the original F word, or none needed
      expected_feed_mm_[move] = modal_mm;
      continue;
    } else {
      text = nc::FormatCoordinate(moves_[move].feed_mm_per_min / mpu, 4);  // the original feed restored
    }
    ParseDouble(text, &value);
    if (has_f || std::abs(value * mpu - modal_mm) > 1e-9 * value * mpu) SetWord(i, 'F', text);
    modal_mm = value * mpu;
    expected_feed_mm_[move] = modal_mm;
  }
}

void EditableProgram::InsertLines(std::size_t line_index, const std::vector<std::string>& texts) {
  if (reading_ == ProgramReading::kShopProgram) {
    units_.insert(units_.begin() + static_cast<std::ptrdiff_t>(line_index), texts.size(), LineUnits{});
  }
  std::vector<ProgramLine> added;
  for (const std::string& t : texts) added.push_back({t, -1, -1});
  lines_.insert(lines_.begin() + static_cast<std::ptrdiff_t>(line_index), added.begin(), added.end());
}

std::string EditableProgram::CommentLine(const std::string& text) const {
  if (dialect_ == "sinumerik") return "; " + text;
  std::string t = nc::CommentText(text);
  if (dialect_ == "fanuc") {
    for (char& c : t) c = static_cast<char>(std::toupper(static_cast<unsigned char>(c)));
  }
  return "(" + t + ")";
}

void EditableProgram::InsertHeaderComments(const std::vector<std::string>& comments) {
  const bool semicolon = dialect_ == "sinumerik";
  std::size_t at = 0;
  while (at < lines_.size()) {
    const std::string& t = lines_[at].text;
    const bool program_number = t.size() > 1 && t[0] == 'O' && std::isdigit(static_cast<unsigned char>(t[1]));
    if (!(t == "%" || program_number || IsCommentLine(t, semicolon))) break;
    ++at;
  }
  std::vector<std::string> texts;
  for (const std::string& c : comments) texts.push_back(CommentLine(c));
  InsertLines(at, texts);
}

std::string EditableProgram::Text() const {
  std::string out;
  for (const ProgramLine& l : lines_) {
    out += l.text;
    out += '\n';
  }
  return out + trailing_;
}

Result<std::string> EditableProgram::Verified(const std::string& source) const {
  if (reading_ == ProgramReading::kShopProgram) return VerifiedShop(source);
  std::string text = Text();
  auto read = nc::ReadProgram(text, dialect_, source);
  if (!read.ok()) return Status::Internal("the edited program does not read back: " + read.status().message());
  return text;
}

Result<std::string> EditableProgram::VerifiedShop(const std::string& source) const {
  std::string text = Text();
  FL_ASSIGN_OR_RETURN(const nc::GcodeDialect d, nc::ParseGcodeDialect(dialect_));
  nc::ReaderOptions options;
  options.dialect = d;
  auto before = nc::ReadProgramPath(original_, options, source);
  auto after = nc::ReadProgramPath(text, options, source);
  if (!before.ok() || !after.ok()) {
    return Status::Internal("the edited program does not read back: " +
                            (before.ok() ? after.status() : before.status()).message());
  }
  const std::vector<nc::PathMove>&a = before->moves, &b = after->moves;
  if (a.size() != b.size()) {
    return Status::Internal("the edited program reads back with " + std::to_string(b.size()) + " moves, the original " +
                            std::to_string(a.size()));
  }
  for (std::size_t k = 0; k < a.size(); ++k) {
    const nc::PathMove &p = a[k], &q = b[k];
    bool same = p.motion == q.motion && p.start_known == q.start_known && p.end_known == q.end_known &&
                p.has_arc == q.has_arc && p.units == q.units && p.rotary_known == q.rotary_known &&
                p.cutter_comp == q.cutter_comp;
    for (int i = 0; i < 3 && same; ++i) {
      same = (!(p.start_known >> i & 1u) || p.start[i] == q.start[i]) &&
             (!(p.end_known >> i & 1u) || p.end[i] == q.end[i]) &&
             (!(p.rotary_known >> i & 1u) ||
              p.rotary[static_cast<std::size_t>(i)] == q.rotary[static_cast<std::size_t>(i)]);
    }
    if (same && p.has_arc) {
      same = p.arc.centre == q.arc.centre && p.arc.sweep_rad == q.arc.sweep_rad && p.arc.rise == q.arc.rise &&
             p.arc.ccw == q.arc.ccw && p.arc.plane == q.arc.plane;
    }
    const double mpu = q.units == nc::Units::kInch ? nc::kMmPerInch : 1.0;
    auto want = expected_feed_mm_.find(k);
    if (same && want != expected_feed_mm_.end()) same = std::abs(q.feed * mpu - want->second) <= 1e-6 * want->second;
    if (!same) {
      return Status::Internal("the edited program's move at line " + std::to_string(q.line) +
                              " differs from the original's at line " + std::to_string(p.line) +
                              " beyond its feed (feed " + FormatFixed(q.feed * mpu, 4) + " mm/min read back, " +
                              (want != expected_feed_mm_.end() ? FormatFixed(want->second, 4) : std::string("none")) +
                              " written): nothing written");
    }
  }
  return text;
}

}  // namespace formloop::planning
