#include "planning/program_edit.h"

#include <cctype>
#include <cmath>

#include "core/point_io.h"

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

}  // namespace

std::string FeedWord(double feed_mm_per_min) { return FormatFixed(feed_mm_per_min, 0); }

Result<EditableProgram> EditableProgram::Parse(const std::string& text, const std::string& dialect,
                                               const std::string& source) {
  if (dialect != "linuxcnc" && dialect != "fanuc" && dialect != "sinumerik") {
    return Status::BadInput(Where{.file = source, .field = "dialect"},
                            "'" + dialect + "' programs cannot be edited word by word",
                            "use a LinuxCNC, Fanuc or Sinumerik program (word-address G-code)");
  }
  EditableProgram p;
  p.dialect_ = dialect;
  FL_ASSIGN_OR_RETURN(p.moves_, nc::ReadProgram(text, dialect, source));
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
  }
  return p;
}

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
  for (const Token& t : CodeTokens(text, dialect_ == "sinumerik")) {
    if (IsWord(text, t, letter)) {
      *value = text.substr(t.begin + 1, t.end - t.begin - 1);
      return true;
    }
  }
  return false;
}

void EditableProgram::SetFeeds(const std::map<std::size_t, double>& feed_of_move) {
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

void EditableProgram::InsertLines(std::size_t line_index, const std::vector<std::string>& texts) {
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
  std::string text = Text();
  auto read = nc::ReadProgram(text, dialect_, source);
  if (!read.ok()) return Status::Internal("the edited program does not read back: " + read.status().message());
  return text;
}

}  // namespace formloop::planning
