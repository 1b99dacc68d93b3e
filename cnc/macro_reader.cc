// Readers of the three machine-side dialects into MacroCode (cnc/macro_code.h). One cursor and one
// expression parser serve all three; what differs (brackets, operator spellings and precedence,
// function semantics, statements, variable ranges) is spelled out per dialect below.
//
// Why one file of ~1,200 lines: the three readers (about 200 lines each) are thin over the shared cursor,
// expression parser, variable rules and word builder, which are internal to this file; splitting by
// dialect would publish those internals in a header for no reader's benefit.

#include <cctype>
#include <charconv>
#include <cmath>
#include <functional>
#include <string_view>

#include "cnc/macro_code.h"

namespace formloop::cnc {

const char* DialectName(Dialect dialect) {
  switch (dialect) {
    case Dialect::kFanuc:
      return "fanuc";
    case Dialect::kLinuxCnc:
      return "linuxcnc";
    case Dialect::kSinumerik:
      return "sinumerik";
  }
  return "?";
}

Result<Dialect> ParseDialect(const std::string& name) {
  if (name == "fanuc") return Dialect::kFanuc;
  if (name == "linuxcnc") return Dialect::kLinuxCnc;
  if (name == "sinumerik") return Dialect::kSinumerik;
  return Status::BadInput("unknown controller dialect '" + name + "'; use fanuc, linuxcnc or sinumerik");
}

namespace {

std::string Upper(std::string_view s) {
  std::string out(s);
  for (char& c : out) c = static_cast<char>(std::toupper(static_cast<unsigned char>(c)));
  return out;
}

std::string_view Trim(std::string_view s) {
  while (!s.empty() && std::isspace(static_cast<unsigned char>(s.front()))) s.remove_prefix(1);
  while (!s.empty() && std::isspace(static_cast<unsigned char>(s.back()))) s.remove_suffix(1);
  return s;
}

// A parse failure inside one line; the reader adds file and line.
struct LineError {
  std::string what;
};

// Cursor over one line (upper-cased for Fanuc and Sinumerik keywords; LinuxCNC is case-insensitive
// too, so every dialect parses the upper-cased text and keeps the original only for messages).
class Cursor {
 public:
  explicit Cursor(std::string_view text) : s_(text) {}
  void SkipSpaces() {
    while (pos_ < s_.size() && (s_[pos_] == ' ' || s_[pos_] == '\t')) ++pos_;
  }
  bool AtEnd() {
    SkipSpaces();
    return pos_ >= s_.size();
  }
  char Peek() {
    SkipSpaces();
    return pos_ < s_.size() ? s_[pos_] : '\0';
  }
  char PeekRaw() const { return pos_ < s_.size() ? s_[pos_] : '\0'; }
  bool Accept(char c) {
    if (Peek() != c) return false;
    ++pos_;
    return true;
  }
  void Expect(char c, const char* context) {
    if (!Accept(c)) throw LineError{std::string("expected '") + c + "' " + context + Near()};
  }
  // A keyword that is not followed by a letter or digit (so "END1" does not match "ENDWHILE").
  bool AcceptWord(std::string_view word, bool allow_digit_after = false) {
    SkipSpaces();
    if (s_.substr(pos_, word.size()) != word) return false;
    const std::size_t after = pos_ + word.size();
    if (after < s_.size()) {
      const char c = s_[after];
      if (std::isalpha(static_cast<unsigned char>(c)) || c == '_') return false;
      if (!allow_digit_after && std::isdigit(static_cast<unsigned char>(c))) return false;
    }
    pos_ = after;
    return true;
  }
  bool AcceptPrefix(std::string_view word) {
    SkipSpaces();
    if (s_.substr(pos_, word.size()) != word) return false;
    pos_ += word.size();
    return true;
  }
  // An unsigned decimal number "12", "12.5", ".5" (no exponent: none of the dialects' subsets has one).
  std::optional<double> Number() {
    SkipSpaces();
    const std::size_t start = pos_;
    bool digits = false;
    while (pos_ < s_.size() && std::isdigit(static_cast<unsigned char>(s_[pos_]))) ++pos_, digits = true;
    if (pos_ < s_.size() && s_[pos_] == '.') {
      ++pos_;
      while (pos_ < s_.size() && std::isdigit(static_cast<unsigned char>(s_[pos_]))) ++pos_, digits = true;
    }
    if (!digits) {
      pos_ = start;
      return std::nullopt;
    }
    double value = 0;
    const auto [p, ec] = std::from_chars(s_.data() + start, s_.data() + pos_, value);
    if (ec != std::errc() || p != s_.data() + pos_) throw LineError{"malformed number" + Near()};
    return value;
  }
  int Integer(const char* what) {
    SkipSpaces();
    const std::size_t start = pos_;
    while (pos_ < s_.size() && std::isdigit(static_cast<unsigned char>(s_[pos_]))) ++pos_;
    if (start == pos_) throw LineError{std::string("expected ") + what + Near()};
    int value = 0;
    const auto [p, ec] = std::from_chars(s_.data() + start, s_.data() + pos_, value);
    if (ec != std::errc()) throw LineError{std::string(what) + " is too large" + Near()};
    return value;
  }
  std::string Identifier() {
    SkipSpaces();
    const std::size_t start = pos_;
    while (pos_ < s_.size() && (std::isalnum(static_cast<unsigned char>(s_[pos_])) || s_[pos_] == '_')) ++pos_;
    return std::string(s_.substr(start, pos_ - start));
  }
  std::string Near() const {
    if (pos_ >= s_.size()) return " at the end of the line";
    return " at '" + std::string(s_.substr(pos_, 12)) + "'";
  }
  std::string_view Rest() const { return s_.substr(pos_); }
  std::size_t pos() const { return pos_; }

 private:
  std::string_view s_;
  std::size_t pos_ = 0;
};

Expr Number(double v) {
  Expr e;
  e.op = Expr::Op::kNumber;
  e.number = v;
  return e;
}
Expr Unary(Expr::Op op, Expr a) {
  Expr e;
  e.op = op;
  e.args.push_back(std::move(a));
  return e;
}
Expr Binary(Expr::Op op, Expr a, Expr b) {
  Expr e;
  e.op = op;
  e.args.push_back(std::move(a));
  e.args.push_back(std::move(b));
  return e;
}

// Variable ranges of each dialect.
class VariableRules {
 public:
  VariableRules(Dialect dialect, const MacroLimits& limits) : dialect_(dialect), limits_(limits) {}
  void CheckRead(int n) const {
    switch (dialect_) {
      case Dialect::kFanuc:
        if (n == 0 || (n >= 1 && n <= 33) || (n >= 100 && n <= 199) || (n >= 500 && n <= 999) ||
            (n >= 5061 && n <= 5063)) {
          return;
        }
        throw LineError{"#" + std::to_string(n) +
                        " is not a Fanuc variable this subset reads (#0, #1-#33, #100-#199, #500-#999, #5061-#5063)"};
      case Dialect::kLinuxCnc:
        if ((n >= 1 && n <= 5000) || (n >= 5061 && n <= 5063) || n == 5070 || n == 5399) return;
        throw LineError{"#" + std::to_string(n) +
                        " is not a LinuxCNC parameter this subset reads (#1-#5000, #5061-#5063, #5070, #5399)"};
      case Dialect::kSinumerik:
        if (n >= 0 && n <= limits_.sinumerik_r_last) return;
        throw LineError{"R" + std::to_string(n) + " is beyond R" + std::to_string(limits_.sinumerik_r_last) +
                        " (MD28050 MM_NUM_R_PARAM)"};
    }
  }
  void CheckWrite(int n) const {
    switch (dialect_) {
      case Dialect::kFanuc:
        if ((n >= 1 && n <= 33) || (n >= 100 && n <= 199) || (n >= 500 && n <= 999)) return;
        throw LineError{"#" + std::to_string(n) + " cannot be written (Fanuc: #1-#33, #100-#199, #500-#999)"};
      case Dialect::kLinuxCnc:
        if (n >= 31 && n <= 5000) return;
        throw LineError{"#" + std::to_string(n) + " cannot be written (LinuxCNC user parameters #31-#5000)"};
      case Dialect::kSinumerik:
        CheckRead(n);
        return;
    }
  }

 private:
  Dialect dialect_;
  MacroLimits limits_;
};

// The expression parser. Fanuc: comparison < additive (+ - OR) < multiplicative (* / AND) < unary;
// LinuxCNC: logical (AND OR) < comparison < additive < multiplicative < unary; Sinumerik: OR < AND <
// comparison < additive < multiplicative < unary.
class ExprParser {
 public:
  ExprParser(Dialect dialect, const VariableRules& rules) : d_(dialect), rules_(rules) {}

  Expr Parse(Cursor& c) {
    switch (d_) {
      case Dialect::kFanuc:
        return Comparison(c);
      case Dialect::kLinuxCnc:
        return LinuxLogical(c);
      case Dialect::kSinumerik:
        return SinumerikOr(c);
    }
    return {};
  }
  // The group brackets: [] for Fanuc and LinuxCNC, () for Sinumerik.
  char open() const { return d_ == Dialect::kSinumerik ? '(' : '['; }
  char close() const { return d_ == Dialect::kSinumerik ? ')' : ']'; }
  Expr Group(Cursor& c) {
    c.Expect(open(), "to open an expression");
    Expr e = Parse(c);
    c.Expect(close(), "to close an expression");
    return e;
  }
  // A primary (what a G-code word's value may be).
  Expr Primary(Cursor& c) {
    const char ch = c.Peek();
    if (ch == open()) return Group(c);
    if (auto n = c.Number()) return Number(*n);
    if (d_ != Dialect::kSinumerik && c.Accept('#')) {
      if (c.Peek() == '[' || c.Peek() == '<')
        throw LineError{"indirect or named parameters are not in the subset" + c.Near()};
      const int n = c.Integer("a variable number after '#'");
      rules_.CheckRead(n);
      return Var(VarRef{VarRef::Space::kNumbered, n});
    }
    if (d_ == Dialect::kSinumerik) {
      if (c.AcceptPrefix("$AA_MW[")) {
        const char axis = c.Peek();
        if (axis != 'X' && axis != 'Y' && axis != 'Z') throw LineError{"$AA_MW needs X, Y or Z" + c.Near()};
        c.Accept(axis);
        c.Expect(']', "after the axis of $AA_MW");
        return Var(VarRef{VarRef::Space::kMeasured, axis - 'X'});
      }
      if (c.AcceptPrefix("$AC_MEA[")) {
        if (c.Integer("a probe number") != 1) throw LineError{"only probe 1 ($AC_MEA[1]) is in the subset"};
        c.Expect(']', "after $AC_MEA[1");
        return Var(VarRef{VarRef::Space::kMeasureStatus, 0});
      }
      if (c.PeekRaw() == 'R' || c.Peek() == 'R') {
        Cursor probe = c;
        probe.Accept('R');
        if (std::isdigit(static_cast<unsigned char>(probe.PeekRaw()))) {
          c.Accept('R');
          const int n = c.Integer("an R parameter number");
          rules_.CheckRead(n);
          return Var(VarRef{VarRef::Space::kNumbered, n});
        }
      }
    }
    const std::string name = c.Identifier();
    if (!name.empty()) return Function(c, name);
    throw LineError{"expected a number, a variable or '" + std::string(1, open()) + "'" + c.Near()};
  }

 private:
  static Expr Var(VarRef v) {
    Expr e;
    e.op = Expr::Op::kVar;
    e.var = v;
    return e;
  }
  Expr Function(Cursor& c, const std::string& name) {
    Expr::Op op;
    if (d_ == Dialect::kFanuc && name == "FIX") {
      op = Expr::Op::kTrunc;
    } else if (d_ == Dialect::kFanuc && name == "FUP") {
      op = Expr::Op::kAwayFromZero;
    } else if (d_ == Dialect::kLinuxCnc && name == "FIX") {
      op = Expr::Op::kFloor;
    } else if (d_ == Dialect::kLinuxCnc && name == "FUP") {
      op = Expr::Op::kCeil;
    } else if (d_ == Dialect::kLinuxCnc && name == "ROUND") {
      op = Expr::Op::kRoundCInt;
    } else if (name == "ROUND") {
      op = Expr::Op::kRound;
    } else if (d_ == Dialect::kSinumerik && name == "TRUNC") {
      op = Expr::Op::kTrunc;
    } else if (name == "ABS") {
      op = Expr::Op::kAbs;
    } else {
      throw LineError{"function '" + name + "' is not in the " + DialectName(d_) + " subset"};
    }
    return Unary(op, Group(c));
  }
  Expr UnaryExpr(Cursor& c) {
    if (c.Accept('-')) return Unary(Expr::Op::kNeg, UnaryExpr(c));
    if (c.Accept('+')) return UnaryExpr(c);
    return Primary(c);
  }
  // One left-associative precedence level: operands from `next`, joined by any of `ops` (a symbol,
  // or a keyword when `word`).
  struct BinaryOp {
    const char* token;
    bool word;
    Expr::Op op;
  };
  template <typename Next>
  Expr LeftAssoc(Cursor& c, std::initializer_list<BinaryOp> ops, Next next) {
    Expr e = next(c);
    for (;;) {
      const BinaryOp* hit = nullptr;
      for (const BinaryOp& op : ops) {
        if (op.word ? c.AcceptWord(op.token) : c.AcceptPrefix(op.token)) {
          hit = &op;
          break;
        }
      }
      if (hit == nullptr) return e;
      e = Binary(hit->op, std::move(e), next(c));
    }
  }
  // Fanuc: * / AND and + - OR (AND binds like *, OR like +); LinuxCNC and Sinumerik: * / and + -.
  Expr Multiplicative(Cursor& c) {
    auto next = [this](Cursor& k) { return UnaryExpr(k); };
    if (d_ == Dialect::kFanuc) {
      return LeftAssoc(c, {{"*", false, Expr::Op::kMul}, {"/", false, Expr::Op::kDiv}, {"AND", true, Expr::Op::kAnd}},
                       next);
    }
    return LeftAssoc(c, {{"*", false, Expr::Op::kMul}, {"/", false, Expr::Op::kDiv}}, next);
  }
  Expr Additive(Cursor& c) {
    auto next = [this](Cursor& k) { return Multiplicative(k); };
    if (d_ == Dialect::kFanuc) {
      return LeftAssoc(c, {{"+", false, Expr::Op::kAdd}, {"-", false, Expr::Op::kSub}, {"OR", true, Expr::Op::kOr}},
                       next);
    }
    return LeftAssoc(c, {{"+", false, Expr::Op::kAdd}, {"-", false, Expr::Op::kSub}}, next);
  }
  std::optional<Expr::Op> ComparisonOp(Cursor& c) {
    if (d_ == Dialect::kSinumerik) {
      if (c.AcceptPrefix("==")) return Expr::Op::kEq;
      if (c.AcceptPrefix("<>")) return Expr::Op::kNe;
      if (c.AcceptPrefix(">=")) return Expr::Op::kGe;
      if (c.AcceptPrefix("<=")) return Expr::Op::kLe;
      if (c.AcceptPrefix(">")) return Expr::Op::kGt;
      if (c.AcceptPrefix("<")) return Expr::Op::kLt;
      return std::nullopt;
    }
    static const std::pair<const char*, Expr::Op> kOps[] = {{"EQ", Expr::Op::kEq}, {"NE", Expr::Op::kNe},
                                                            {"GT", Expr::Op::kGt}, {"GE", Expr::Op::kGe},
                                                            {"LT", Expr::Op::kLt}, {"LE", Expr::Op::kLe}};
    for (const auto& [word, op] : kOps) {
      if (c.AcceptWord(word)) return op;
    }
    return std::nullopt;
  }
  Expr Comparison(Cursor& c) {
    Expr e = Additive(c);
    if (auto op = ComparisonOp(c)) e = Binary(*op, std::move(e), Additive(c));
    return e;
  }
  Expr LinuxLogical(Cursor& c) {
    return LeftAssoc(c, {{"AND", true, Expr::Op::kAnd}, {"OR", true, Expr::Op::kOr}},
                     [this](Cursor& k) { return Comparison(k); });
  }
  Expr SinumerikAnd(Cursor& c) {
    return LeftAssoc(c, {{"AND", true, Expr::Op::kAnd}}, [this](Cursor& k) { return Comparison(k); });
  }
  Expr SinumerikOr(Cursor& c) {
    return LeftAssoc(c, {{"OR", true, Expr::Op::kOr}}, [this](Cursor& k) { return SinumerikAnd(k); });
  }

 private:
  Dialect d_;
  const VariableRules& rules_;
};

// "point 17" (any case) → 17; 0 otherwise.
int PointMark(std::string_view comment) {
  const std::string up = Upper(Trim(comment));
  if (up.rfind("POINT ", 0) != 0) return 0;
  int id = 0;
  const std::string digits = up.substr(6);
  const auto [p, ec] = std::from_chars(digits.data(), digits.data() + digits.size(), id);
  return ec == std::errc() && p == digits.data() + digits.size() ? id : 0;
}

// The common part of the three readers: instruction list, open blocks, labels and calls to resolve.
class Builder {
 public:
  Builder(Dialect dialect, const MacroLimits& limits) : rules_(dialect, limits), expr_(dialect, rules_) {
    code_.dialect = dialect;
  }
  MacroCode& code() { return code_; }
  const VariableRules& rules() const { return rules_; }
  ExprParser& expr() { return expr_; }
  SourcePos pos;

  int Emit(Instr instr) {
    instr.pos = pos;
    code_.instrs.push_back(std::move(instr));
    return static_cast<int>(code_.instrs.size()) - 1;
  }
  int Next() const { return static_cast<int>(code_.instrs.size()); }
  void Mark(int id) {
    if (id <= 0) return;
    Instr nop;
    nop.mark = id;
    code_.marks.emplace(id, Emit(std::move(nop)));
  }

  // Open control blocks (while / if), identified by a key the dialect chooses ("DO1", "o101").
  struct Block {
    std::string key;
    enum Kind { kWhile, kIf, kSub } kind;
    int start;         // the loop's condition / the sub's jump-over
    int pending = -1;  // a jump to patch at the block's end (if: the JumpIfNot, or the else's Jump)
    bool has_else = false;
    SourcePos opened;
  };
  std::vector<Block> blocks;
  Block* Top(const std::string& key) { return blocks.empty() || blocks.back().key != key ? nullptr : &blocks.back(); }

  // Jumps and calls resolved once every label is known.
  struct Fixup {
    int instr;
    std::string label;  // scope-qualified label or sub name
    SourcePos where;
  };
  std::vector<Fixup> fixups;
  std::map<std::string, int> labels;

 private:
  MacroCode code_;
  VariableRules rules_;
  ExprParser expr_;
};

// ---- G-code words (shared by the three dialects) -------------------------------------------------

struct Words {
  std::vector<double> g;  // G numbers (38.2 kept as 38.2)
  std::vector<int> m;
  std::array<std::optional<Expr>, 3> axes;
  std::optional<Expr> f, p, e, q, l;
  std::optional<Expr> t, h, d;  // tool, its length offset (G43 H), Sinumerik's cutting edge (D1)
  bool meas = false;            // Sinumerik MEAS=1
};

// Parses the rest of the line as words. Fanuc/LinuxCNC: letter + value (number, #n, [expr], -...).
// Sinumerik: letter + number, or letter '=' expression; MEAS=1.
Words ParseWords(Cursor& c, Builder& b, Dialect d) {
  Words w;
  while (!c.AtEnd()) {
    if (d == Dialect::kSinumerik && c.AcceptWord("MEAS")) {
      c.Expect('=', "after MEAS");
      if (c.Integer("a probe number") != 1) throw LineError{"only MEAS=1 is in the subset"};
      w.meas = true;
      continue;
    }
    const char letter = c.Peek();
    if (!std::isalpha(static_cast<unsigned char>(letter))) throw LineError{"expected a word letter" + c.Near()};
    c.Accept(letter);
    if (letter == 'G' || letter == 'M') {
      const auto n = c.Number();
      if (!n) throw LineError{std::string("expected a number after ") + letter + c.Near()};
      if (letter == 'G') {
        w.g.push_back(*n);
      } else {
        w.m.push_back(static_cast<int>(*n));
      }
      continue;
    }
    Expr value;
    if (d == Dialect::kSinumerik) {
      if (c.Accept('=')) {
        value = b.expr().Parse(c);
      } else {
        const bool neg = c.Accept('-');
        const auto n = c.Number();
        if (!n) throw LineError{std::string("expected a number or '=' after ") + letter + c.Near()};
        value = Number(neg ? -*n : *n);
      }
    } else {
      // A leading minus applies to the primary (X-10.5, X-#101, X-[..]).
      const bool neg = c.Accept('-');
      value = b.expr().Primary(c);
      if (neg) value = Unary(Expr::Op::kNeg, std::move(value));
    }
    std::optional<Expr>* slot = nullptr;
    if (letter >= 'X' && letter <= 'Z') {
      slot = &w.axes[letter - 'X'];
      if (*slot) throw LineError{std::string("two ") + letter + " words in one block"};
    } else {
      const std::pair<char, std::optional<Expr>*> kSlots[] = {{'F', &w.f}, {'P', &w.p}, {'E', &w.e}, {'Q', &w.q},
                                                              {'L', &w.l}, {'T', &w.t}, {'H', &w.h}, {'D', &w.d}};
      for (const auto& [l, where] : kSlots) slot = l == letter ? where : slot;
    }
    if (slot == nullptr) throw LineError{std::string("word ") + letter + " is not in the subset"};
    *slot = std::move(value);
  }
  return w;
}

// Modal codes the subset accepts and ignores (units mm, absolute, XY plane, feed per minute, no
// cutter compensation, no canned cycle). The tool words (T.. M6, G43 H.., Sinumerik D..) are accepted
// too and have no effect here: the program's positions are the controlled point, the stylus-ball centre,
// which the probe's length offset on the machine makes them.
bool IsModalNop(double g, Dialect d) {
  static const double kFanuc[] = {17, 21, 40, 49, 80, 90, 94};
  static const double kLinux[] = {17, 21, 40, 49, 80, 90, 94};
  static const double kSinumerik[] = {17, 40, 71, 90, 94};
  const double* begin = d == Dialect::kSinumerik ? kSinumerik : d == Dialect::kFanuc ? kFanuc : kLinux;
  const std::size_t n = d == Dialect::kSinumerik ? 5 : 7;
  for (std::size_t i = 0; i < n; ++i) {
    if (std::fabs(begin[i] - g) < 1e-9) return true;
  }
  return false;
}

// A motion/dwell/probe/modal block from its words. Returns false when the words hold nothing to do.
void EmitWords(Builder& b, Words w, Dialect d, const std::function<void(int m, const Words&)>& on_m) {
  std::optional<double> motion;
  bool length_offset = false;
  for (double g : w.g) {
    if (IsModalNop(g, d)) continue;
    if (g == 43 && d != Dialect::kSinumerik) {
      length_offset = true;
      continue;
    }
    if (g == 0 || g == 1 || g == 4 || (d == Dialect::kFanuc && g == 31) ||
        (d == Dialect::kLinuxCnc && std::fabs(g - 38.2) < 1e-9)) {
      if (motion) throw LineError{"two motion codes in one block"};
      motion = g;
      continue;
    }
    throw LineError{"G" + std::to_string(g) + " is not in the " + std::string(DialectName(d)) + " subset"};
  }
  if (length_offset != w.h.has_value()) throw LineError{length_offset ? "G43 needs H<offset>" : "H without G43"};
  if (w.d && d != Dialect::kSinumerik) throw LineError{"word D is not in the subset"};
  for (const std::optional<Expr>* number : {&w.t, &w.h, &w.d}) {
    if (*number && (*number)->op != Expr::Op::kNumber) throw LineError{"T, H and D take a number here"};
  }
  const bool has_axes = w.axes[0] || w.axes[1] || w.axes[2];
  if (motion && *motion == 4) {
    Instr dwell;
    dwell.kind = Instr::Kind::kDwell;
    if (d == Dialect::kFanuc) {
      if (!w.axes[0] || w.p || w.axes[1] || w.axes[2]) throw LineError{"Fanuc G04 needs X<seconds> (and nothing else)"};
      dwell.value = std::move(*w.axes[0]);
    } else if (d == Dialect::kLinuxCnc) {
      if (!w.p || has_axes) throw LineError{"LinuxCNC G4 needs P<seconds>"};
      dwell.value = std::move(*w.p);
    } else {
      if (!w.f || has_axes) throw LineError{"Sinumerik G4 needs F<seconds>"};
      dwell.value = std::move(*w.f);
    }
    b.Emit(std::move(dwell));
  } else if (motion || has_axes) {
    if (!motion) throw LineError{"axis words without a motion code (the subset states G0/G1 in every block)"};
    Instr move;
    const bool probe = (*motion == 31 || std::fabs(*motion - 38.2) < 1e-9 || (w.meas && *motion == 1));
    if (w.meas && !probe) throw LineError{"MEAS=1 needs G1"};
    move.kind = probe ? Instr::Kind::kProbe : Instr::Kind::kMove;
    move.rapid = *motion == 0;
    move.axes = std::move(w.axes);
    move.feed = std::move(w.f);
    if (probe && (!move.axes[0] || !move.axes[1] || !move.axes[2])) {
      throw LineError{"a probing move names X, Y and Z"};
    }
    if (probe && !move.feed) throw LineError{"a probing move needs its feed (F)"};
    if (!move.axes[0] && !move.axes[1] && !move.axes[2]) throw LineError{"a motion block without axis words"};
    b.Emit(std::move(move));
  } else if (w.f) {
    throw LineError{"a feed word without a move"};
  }
  for (int m : w.m) on_m(m, w);
}

// ---- Fanuc ---------------------------------------------------------------------------------------

class FanucReader {
 public:
  explicit FanucReader(Builder& b) : b_(b) {}

  void Line(std::string_view raw) {
    std::string_view text = Trim(raw);
    if (text.empty() || text == "%") return;
    // The comment: Fanuc comments are "( ... )", at most one per block here.
    std::string comment;
    std::string body;
    {
      const auto open = text.find('(');
      if (open != std::string_view::npos) {
        const auto close = text.find(')', open);
        if (close == std::string_view::npos) throw LineError{"unclosed comment"};
        if (text.find('(', close) != std::string_view::npos) throw LineError{"two comments in one block"};
        comment = std::string(text.substr(open + 1, close - open - 1));
        body = Upper(std::string(text.substr(0, open)) + std::string(text.substr(close + 1)));
      } else {
        body = Upper(text);
      }
    }
    Cursor c(body);
    if (c.AtEnd()) {
      b_.Mark(PointMark(comment));
      return;
    }
    if (c.Peek() == 'O') {
      c.Accept('O');
      const int number = c.Integer("a program number after O");
      if (!c.AtEnd()) throw LineError{"text after the program number"};
      if (in_program_)
        throw LineError{"program O" + std::to_string(number) + " starts before O" + program_ + " ended (M30/M99)"};
      program_ = std::to_string(number);
      in_program_ = true;
      if (b_.code().subs.count(program_) != 0) throw LineError{"program O" + program_ + " is defined twice"};
      b_.code().subs[program_] = b_.Next();
      if (first_program_) {
        b_.code().entry = b_.Next();
        first_program_ = false;
      }
      return;
    }
    if (!in_program_) throw LineError{"a block outside a program (no O number before it)"};
    if (c.Peek() == 'N') {
      c.Accept('N');
      const int n = c.Integer("a sequence number after N");
      const std::string label = program_ + ":" + std::to_string(n);
      if (b_.labels.count(label) != 0) throw LineError{"N" + std::to_string(n) + " appears twice in O" + program_};
      b_.labels[label] = b_.Next();
    }
    if (c.AtEnd()) return;
    if (c.Peek() == '#') {
      Assignment(c, comment);
      return;
    }
    if (c.AcceptWord("IF")) {
      Expr cond = b_.expr().Group(c);
      if (c.AcceptWord("GOTO", true)) {
        Instr jump;
        jump.kind = Instr::Kind::kJumpIf;
        jump.value = std::move(cond);
        Goto(c, b_.Emit(std::move(jump)));
        return;
      }
      if (c.AcceptWord("THEN")) {
        Instr skip;
        skip.kind = Instr::Kind::kJumpIfNot;
        skip.value = std::move(cond);
        const int at = b_.Emit(std::move(skip));
        if (c.Peek() != '#') throw LineError{"IF .. THEN takes one assignment"};
        Assignment(c, comment);
        b_.code().instrs[at].jump = b_.Next();
        return;
      }
      throw LineError{"IF [..] must be followed by GOTO n or THEN" + c.Near()};
    }
    if (c.AcceptWord("GOTO", true)) {
      Instr jump;
      jump.kind = Instr::Kind::kJump;
      Goto(c, b_.Emit(std::move(jump)));
      return;
    }
    if (c.AcceptWord("WHILE")) {
      Expr cond = b_.expr().Group(c);
      if (!c.AcceptWord("DO", true)) throw LineError{"WHILE [..] must be followed by DO1..DO3"};
      const int m = c.Integer("the loop number after DO");
      if (m < 1 || m > 3) throw LineError{"DO" + std::to_string(m) + ": Fanuc loop numbers are 1..3"};
      if (!c.AtEnd()) throw LineError{"text after DO" + std::to_string(m)};
      for (const auto& blk : b_.blocks) {
        if (blk.key == "DO" + std::to_string(m)) throw LineError{"DO" + std::to_string(m) + " is already open"};
      }
      Instr test;
      test.kind = Instr::Kind::kJumpIfNot;
      test.value = std::move(cond);
      b_.blocks.push_back(
          {"DO" + std::to_string(m), Builder::Block::kWhile, b_.Emit(std::move(test)), -1, false, b_.pos});
      return;
    }
    if (c.AcceptWord("END", true)) {
      const int m = c.Integer("the loop number after END");
      auto* blk = b_.Top("DO" + std::to_string(m));
      if (blk == nullptr)
        throw LineError{"END" + std::to_string(m) + " without a matching open DO" + std::to_string(m)};
      Instr back;
      back.kind = Instr::Kind::kJump;
      back.jump = blk->start;
      b_.Emit(std::move(back));
      b_.code().instrs[blk->start].jump = b_.Next();
      b_.blocks.pop_back();
      return;
    }
    Words w = ParseWords(c, b_, Dialect::kFanuc);
    EmitWords(b_, std::move(w), Dialect::kFanuc, [&](int m, const Words& words) { MCode(m, words); });
  }

  void Finish() {
    if (in_program_) throw LineError{"program O" + program_ + " has no M30 or M99 at its end"};
    if (first_program_) throw LineError{"no program (O number) in the file"};
  }

 private:
  void Assignment(Cursor& c, const std::string& comment) {
    c.Accept('#');
    const int n = c.Integer("a variable number after '#'");
    c.Expect('=', "after the variable");
    if (n == 3000 || n == 3006) {
      const auto value = c.Number();
      if (!value || *value != std::floor(*value) || *value < 0 || *value > 999) {
        throw LineError{"#" + std::to_string(n) + " takes a whole number 0..999 and the text in a comment"};
      }
      if (!c.AtEnd())
        throw LineError{"text after #" + std::to_string(n) + "=" + std::to_string(static_cast<int>(*value))};
      Instr i;
      i.kind = n == 3000 ? Instr::Kind::kAlarm : Instr::Kind::kMessage;
      i.number = (n == 3000 ? 3000 : 0) + static_cast<int>(*value);
      i.text = comment;
      b_.Emit(std::move(i));
      return;
    }
    b_.rules().CheckWrite(n);
    Instr i;
    i.kind = Instr::Kind::kAssign;
    i.target = VarRef{VarRef::Space::kNumbered, n};
    i.value = b_.expr().Parse(c);
    if (!c.AtEnd()) throw LineError{"unexpected text after the expression" + c.Near()};
    b_.Emit(std::move(i));
  }
  void Goto(Cursor& c, int at) {
    const int n = c.Integer("a sequence number after GOTO");
    if (!c.AtEnd()) throw LineError{"text after GOTO " + std::to_string(n)};
    b_.fixups.push_back({at, program_ + ":" + std::to_string(n), b_.pos});
  }
  void MCode(int m, const Words& w) {
    if (m == 98) {
      if (!w.p || w.p->op != Expr::Op::kNumber) throw LineError{"M98 needs P<program number>"};
      Instr call;
      call.kind = Instr::Kind::kCall;
      const int at = b_.Emit(std::move(call));
      b_.fixups.push_back({at, "O" + std::to_string(static_cast<int>(w.p->number)), b_.pos});
    } else if (m == 6) {
      // Tool change: nothing to do on the emulator (EmitWords).
    } else if (m == 99 || m == 30 || m == 2) {
      if (!b_.blocks.empty()) throw LineError{"the program ends inside an open loop (" + b_.blocks.back().key + ")"};
      Instr end;
      end.kind = m == 99 ? Instr::Kind::kReturn : Instr::Kind::kEnd;
      b_.Emit(std::move(end));
      in_program_ = false;
    } else {
      throw LineError{"M" + std::to_string(m) + " is not in the Fanuc subset"};
    }
  }

  Builder& b_;
  std::string program_;
  bool in_program_ = false;
  bool first_program_ = true;
};

// ---- LinuxCNC ------------------------------------------------------------------------------------

class LinuxCncReader {
 public:
  LinuxCncReader(Builder& b, const MacroLimits& limits) : b_(b), limits_(limits) {}

  void Line(std::string_view raw) {
    std::string_view text = Trim(raw);
    if (text.empty() || text == "%") return;
    if (const auto semi = text.find(';'); semi != std::string_view::npos) text = Trim(text.substr(0, semi));
    std::string body;
    std::string comment;
    std::size_t i = 0;
    while (i < text.size()) {
      if (text[i] == '(') {
        const auto close = text.find(')', i);
        if (close == std::string_view::npos) throw LineError{"unclosed comment"};
        if (!comment.empty()) throw LineError{"two comments in one block"};
        comment = std::string(text.substr(i + 1, close - i - 1));
        i = close + 1;
      } else {
        body += text[i++];
      }
    }
    body = Upper(body);
    Cursor c(body);
    if (!comment.empty()) Comment(comment, !c.AtEnd());
    if (c.AtEnd()) return;
    if (c.Peek() == 'O') {
      OWord(c);
      return;
    }
    if (c.Peek() == '#') {
      c.Accept('#');
      const int n = c.Integer("a parameter number after '#'");
      b_.rules().CheckWrite(n);
      c.Expect('=', "after the parameter");
      Instr a;
      a.kind = Instr::Kind::kAssign;
      a.target = VarRef{VarRef::Space::kNumbered, n};
      // One value after '=': operators need a [group] (rs274: "Bad character '+' used").
      const bool neg = c.Accept('-');
      a.value = b_.expr().Primary(c);
      if (neg) a.value = Unary(Expr::Op::kNeg, std::move(a.value));
      if (!c.AtEnd()) throw LineError{"an expression after '=' must be bracketed ([..])" + c.Near()};
      b_.Emit(std::move(a));
      return;
    }
    Words w = ParseWords(c, b_, Dialect::kLinuxCnc);
    EmitWords(b_, std::move(w), Dialect::kLinuxCnc, [&](int m, const Words& words) { MCode(m, words); });
  }

  void Finish() {
    if (!b_.blocks.empty()) {
      throw LineError{"o" + b_.blocks.back().key + " opened on line " + std::to_string(b_.blocks.back().opened.line) +
                      " is never closed"};
    }
    if (!ended_) throw LineError{"the program has no M2 or M30"};
  }

 private:
  void Comment(const std::string& comment, bool with_code) {
    const std::string up = Upper(Trim(comment));
    const auto kind = [&](const char* prefix) { return up.rfind(prefix, 0) == 0; };
    if (kind("MSG,") || kind("ABORT,") || kind("DEBUG,")) {
      if (with_code) throw LineError{"a (msg/abort/debug, ...) comment shares its line with code"};
      Instr i;
      const auto comma = comment.find(',');
      i.text = std::string(Trim(std::string_view(comment).substr(comma + 1)));
      i.kind = kind("ABORT,") ? Instr::Kind::kAlarm : Instr::Kind::kMessage;
      b_.Emit(std::move(i));
      return;
    }
    if (!with_code) b_.Mark(PointMark(comment));
  }
  void OWord(Cursor& c) {
    c.Accept('O');
    std::string key;
    if (c.Accept('<')) {
      key = c.Identifier();
      c.Expect('>', "to close the o-word name");
      if (key.empty()) throw LineError{"empty o-word name"};
    } else {
      key = std::to_string(c.Integer("an o-word number"));
    }
    if (c.AcceptWord("SUB")) {
      if (!b_.blocks.empty()) throw LineError{"o<" + key + "> sub inside another block"};
      if (b_.code().subs.count(key) != 0) throw LineError{"o<" + key + "> is defined twice"};
      Instr over;
      over.kind = Instr::Kind::kJump;
      const int at = b_.Emit(std::move(over));
      b_.code().subs[key] = b_.Next();
      b_.blocks.push_back({key, Builder::Block::kSub, at, -1, false, b_.pos});
    } else if (c.AcceptWord("ENDSUB")) {
      auto* blk = b_.Top(key);
      if (blk == nullptr || blk->kind != Builder::Block::kSub) throw LineError{"o" + key + " endsub without its sub"};
      Instr ret;
      ret.kind = Instr::Kind::kReturn;
      b_.Emit(std::move(ret));
      b_.code().instrs[blk->start].jump = b_.Next();
      b_.blocks.pop_back();
    } else if (c.AcceptWord("CALL")) {
      if (b_.code().subs.count(key) == 0) throw LineError{"o<" + key + "> is called before it is defined"};
      if (!c.AtEnd()) throw LineError{"arguments to o<" + key + "> call are not in the subset"};
      Instr call;
      call.kind = Instr::Kind::kCall;
      call.jump = b_.code().subs[key];
      b_.Emit(std::move(call));
    } else if (c.AcceptWord("WHILE")) {
      Instr test;
      test.kind = Instr::Kind::kJumpIfNot;
      test.value = b_.expr().Group(c);
      b_.blocks.push_back({key, Builder::Block::kWhile, b_.Emit(std::move(test)), -1, false, b_.pos});
    } else if (c.AcceptWord("ENDWHILE")) {
      auto* blk = b_.Top(key);
      if (blk == nullptr || blk->kind != Builder::Block::kWhile)
        throw LineError{"o" + key + " endwhile without its while"};
      Instr back;
      back.kind = Instr::Kind::kJump;
      back.jump = blk->start;
      b_.Emit(std::move(back));
      b_.code().instrs[blk->start].jump = b_.Next();
      b_.blocks.pop_back();
    } else if (c.AcceptWord("IF")) {
      Instr test;
      test.kind = Instr::Kind::kJumpIfNot;
      test.value = b_.expr().Group(c);
      const int at = b_.Emit(std::move(test));
      b_.blocks.push_back({key, Builder::Block::kIf, at, at, false, b_.pos});
    } else if (c.AcceptWord("ELSE")) {
      auto* blk = b_.Top(key);
      if (blk == nullptr || blk->kind != Builder::Block::kIf || blk->has_else)
        throw LineError{"o" + key + " else without its if"};
      Instr skip;
      skip.kind = Instr::Kind::kJump;
      const int at = b_.Emit(std::move(skip));
      b_.code().instrs[blk->pending].jump = b_.Next();
      blk->pending = at;
      blk->has_else = true;
    } else if (c.AcceptWord("ENDIF")) {
      auto* blk = b_.Top(key);
      if (blk == nullptr || blk->kind != Builder::Block::kIf) throw LineError{"o" + key + " endif without its if"};
      b_.code().instrs[blk->pending].jump = b_.Next();
      b_.blocks.pop_back();
    } else {
      throw LineError{"o" + key + ": expected sub, endsub, call, while, endwhile, if, else or endif" + c.Near()};
    }
    if (!c.AtEnd()) throw LineError{"unexpected text after the o-word" + c.Near()};
  }
  void MCode(int m, const Words& w) {
    if (m == 6) return;  // tool change: nothing to do on the emulator (EmitWords)
    if (m == 2 || m == 30) {
      if (!b_.blocks.empty()) throw LineError{"the program ends inside o" + b_.blocks.back().key};
      Instr end;
      end.kind = Instr::Kind::kEnd;
      b_.Emit(std::move(end));
      ended_ = true;
      return;
    }
    // HAL I/O: M64/M65 P<k> digital out, M66 P<k> L0 digital in, M66 E<k> L0 analog in, M68 E<k> Q analog out.
    const bool digital = m == 64 || m == 65 || (m == 66 && w.p && !w.e);
    if (digital || m == 66 || m == 68) {
      const std::optional<Expr>& word = digital ? w.p : w.e;
      const std::string kind = digital ? "digital" : "analog";
      const std::string letter = digital ? "P" : "E";
      if (!word || word->op != Expr::Op::kNumber) {
        throw LineError{"M" + std::to_string(m) + " needs " + letter + "<" + kind + " port>"};
      }
      const int port = static_cast<int>(word->number);
      if (port < 0 || port >= limits_.linuxcnc_ports) {
        throw LineError{kind + " port " + letter + std::to_string(port) + " is beyond motion.num_" +
                        (digital ? "dio" : "aio") + " = " + std::to_string(limits_.linuxcnc_ports)};
      }
      Instr io;
      io.number = port;
      if (m == 66) {
        if (!w.l || w.l->op != Expr::Op::kNumber || w.l->number != 0)
          throw LineError{"M66 reads immediately (L0) here"};
        io.kind = digital ? Instr::Kind::kDigitalIn : Instr::Kind::kPortIn;
      } else if (digital) {
        io.kind = Instr::Kind::kDigitalOut;
        io.value.op = Expr::Op::kNumber;
        io.value.number = m == 64 ? 1 : 0;
      } else {
        if (!w.q) throw LineError{"M68 needs Q<value>"};
        io.kind = Instr::Kind::kPortOut;
        io.value = *w.q;
      }
      b_.Emit(std::move(io));
      return;
    }
    throw LineError{"M" + std::to_string(m) + " is not in the LinuxCNC subset"};
  }

  Builder& b_;
  MacroLimits limits_;
  bool ended_ = false;
};

// ---- Sinumerik -----------------------------------------------------------------------------------

class SinumerikReader {
 public:
  explicit SinumerikReader(Builder& b) : b_(b) {}

  // file_index 0 is the main program (MPF); the others are subprograms (SPF) that start with PROC.
  void StartFile(int file_index) {
    main_ = file_index == 0;
    proc_seen_ = false;
    ended_ = false;
    if (main_) b_.code().entry = b_.Next();
  }

  void Line(std::string_view raw) {
    std::string_view text = Trim(raw);
    if (text.empty()) return;
    std::string comment;
    if (const auto semi = text.find(';'); semi != std::string_view::npos) {
      comment = std::string(text.substr(semi + 1));
      text = Trim(text.substr(0, semi));
    }
    if (text.empty()) {
      b_.Mark(PointMark(comment));
      return;
    }
    if (ended_) throw LineError{"a block after the program's end (M30/M17)"};
    // MSG("text") keeps its text's case.
    if (Upper(text.substr(0, 4)) == "MSG(") {
      const auto q1 = text.find('"'), q2 = text.rfind('"');
      if (q1 == std::string_view::npos || q2 == q1 || Trim(text.substr(q2 + 1)) != ")") {
        throw LineError{"MSG needs a quoted text: MSG(\"...\")"};
      }
      Instr m;
      m.kind = Instr::Kind::kMessage;
      m.text = std::string(text.substr(q1 + 1, q2 - q1 - 1));
      b_.Emit(std::move(m));
      return;
    }
    const std::string body = Upper(text);
    Cursor c(body);
    if (c.Peek() == 'N') {
      Cursor probe = c;
      probe.Accept('N');
      if (std::isdigit(static_cast<unsigned char>(probe.PeekRaw()))) {
        c.Accept('N');
        c.Integer("a block number");
      }
    }
    if (c.AcceptWord("PROC")) {
      if (main_ || proc_seen_ || b_.Next() != entry_of_file_) {
        throw LineError{"PROC must be the first line of a subprogram file"};
      }
      const std::string name = c.Identifier();
      if (name.empty()) throw LineError{"PROC needs the subprogram's name"};
      if (!c.AtEnd()) throw LineError{"parameters of PROC are not in the subset"};
      if (b_.code().subs.count(name) != 0) throw LineError{"subprogram " + name + " is defined twice"};
      b_.code().subs[name] = b_.Next();
      proc_seen_ = true;
      return;
    }
    if (!main_ && !proc_seen_) throw LineError{"a subprogram file must start with PROC <name>"};
    if (c.AcceptWord("WHILE")) {
      Instr test;
      test.kind = Instr::Kind::kJumpIfNot;
      test.value = b_.expr().Parse(c);
      End(c);
      b_.blocks.push_back({"WHILE", Builder::Block::kWhile, b_.Emit(std::move(test)), -1, false, b_.pos});
      return;
    }
    if (c.AcceptWord("ENDWHILE")) {
      End(c);
      auto* blk = b_.Top("WHILE");
      if (blk == nullptr) throw LineError{"ENDWHILE without WHILE"};
      Instr back;
      back.kind = Instr::Kind::kJump;
      back.jump = blk->start;
      b_.Emit(std::move(back));
      b_.code().instrs[blk->start].jump = b_.Next();
      b_.blocks.pop_back();
      return;
    }
    if (c.AcceptWord("IF")) {
      Instr test;
      test.kind = Instr::Kind::kJumpIfNot;
      test.value = b_.expr().Parse(c);
      End(c);
      const int at = b_.Emit(std::move(test));
      b_.blocks.push_back({"IF", Builder::Block::kIf, at, at, false, b_.pos});
      return;
    }
    if (c.AcceptWord("ELSE")) {
      End(c);
      auto* blk = b_.Top("IF");
      if (blk == nullptr || blk->has_else) throw LineError{"ELSE without IF"};
      Instr skip;
      skip.kind = Instr::Kind::kJump;
      const int at = b_.Emit(std::move(skip));
      b_.code().instrs[blk->pending].jump = b_.Next();
      blk->pending = at;
      blk->has_else = true;
      return;
    }
    if (c.AcceptWord("ENDIF")) {
      End(c);
      auto* blk = b_.Top("IF");
      if (blk == nullptr) throw LineError{"ENDIF without IF"};
      b_.code().instrs[blk->pending].jump = b_.Next();
      b_.blocks.pop_back();
      return;
    }
    if (c.AcceptWord("STOPRE")) {
      End(c);
      return;
    }
    if (c.AcceptWord("RET") || c.AcceptWord("M17")) {
      End(c);
      Finish("M17/RET", Instr::Kind::kReturn, !main_);
      return;
    }
    if (c.AcceptWord("M30")) {
      End(c);
      Finish("M30", Instr::Kind::kEnd, main_);
      return;
    }
    if (c.AcceptPrefix("SETAL(")) {
      const int n = c.Integer("an alarm number");
      c.Expect(')', "after the alarm number");
      End(c);
      if (n < 60000 || n > 69999) throw LineError{"SETAL(" + std::to_string(n) + "): cycle alarms are 60000..69999"};
      Instr a;
      a.kind = Instr::Kind::kAlarm;
      a.number = n;
      a.text = comment;
      b_.Emit(std::move(a));
      return;
    }
    if (c.Peek() == 'R') {
      Cursor probe = c;
      probe.Accept('R');
      if (std::isdigit(static_cast<unsigned char>(probe.PeekRaw()))) {
        c.Accept('R');
        const int n = c.Integer("an R parameter number");
        b_.rules().CheckWrite(n);
        c.Expect('=', "after the R parameter");
        Instr a;
        a.kind = Instr::Kind::kAssign;
        a.target = VarRef{VarRef::Space::kNumbered, n};
        a.value = b_.expr().Parse(c);
        End(c);
        b_.Emit(std::move(a));
        return;
      }
    }
    // A bare name is a subprogram call (a file NAME.SPF of the same program).
    {
      Cursor probe = c;
      const std::string name = probe.Identifier();
      if (name.size() > 2 && probe.AtEnd() && name.find('_') != std::string::npos) {
        Instr call;
        call.kind = Instr::Kind::kCall;
        const int at = b_.Emit(std::move(call));
        b_.fixups.push_back({at, name, b_.pos});
        return;
      }
    }
    Words w = ParseWords(c, b_, Dialect::kSinumerik);
    EmitWords(b_, std::move(w), Dialect::kSinumerik, [&](int m, const Words&) {
      if (m == 6) return;  // tool change
      throw LineError{"M" + std::to_string(m) + " is not in the Sinumerik subset (M30, M17 on their own line)"};
    });
  }

  void FinishFile() {
    if (!b_.blocks.empty()) {
      throw LineError{b_.blocks.back().key + " opened on line " + std::to_string(b_.blocks.back().opened.line) +
                      " is never closed"};
    }
    if (!ended_) throw LineError{main_ ? "the main program has no M30" : "the subprogram has no M17 or RET"};
  }
  void set_entry_of_file(int at) { entry_of_file_ = at; }

 private:
  static void End(Cursor& c) {
    if (!c.AtEnd()) throw LineError{"unexpected text" + c.Near()};
  }
  void Finish(const char* what, Instr::Kind kind, bool allowed) {
    if (!allowed)
      throw LineError{std::string(what) + (main_ ? " ends a subprogram, not the main program"
                                                 : " ends the main program, not a subprogram")};
    if (!b_.blocks.empty()) throw LineError{std::string(what) + " inside an open " + b_.blocks.back().key};
    Instr end;
    end.kind = kind;
    b_.Emit(std::move(end));
    ended_ = true;
  }

  Builder& b_;
  bool main_ = true;
  bool proc_seen_ = false;
  bool ended_ = false;
  int entry_of_file_ = 0;
};

Status LineStatus(const std::string& file, int line, const std::string& what, Dialect d) {
  return Status::BadInput(Where{.file = file, .line = line}, what,
                          std::string("the ") + DialectName(d) +
                              " subset formloop writes is described in cnc/macro_code.h; regenerate the program with "
                              "`formloop link program` or correct this line");
}

}  // namespace

Result<MacroCode> ReadMacroProgram(Dialect dialect, const std::vector<MacroFile>& files, const MacroLimits& limits) {
  if (files.empty()) return Status::BadInput("no program files");
  Builder b(dialect, limits);
  FanucReader fanuc(b);
  LinuxCncReader linuxcnc(b, limits);
  SinumerikReader sinumerik(b);
  for (std::size_t f = 0; f < files.size(); ++f) {
    b.code().files.push_back(files[f].name);
    if (dialect != Dialect::kSinumerik && f > 0) {
      return Status::BadInput(Where{.file = files[f].name},
                              std::string(DialectName(dialect)) + " programs are one file");
    }
    if (dialect == Dialect::kSinumerik) {
      sinumerik.StartFile(static_cast<int>(f));
      sinumerik.set_entry_of_file(b.Next());
    }
    std::string_view text = files[f].text;
    int line_no = 0;
    try {
      while (!text.empty()) {
        const auto nl = text.find('\n');
        std::string_view line = text.substr(0, nl);
        text = nl == std::string_view::npos ? std::string_view() : text.substr(nl + 1);
        ++line_no;
        b.pos = SourcePos{static_cast<int>(f), line_no};
        if (!line.empty() && line.back() == '\r') line.remove_suffix(1);
        switch (dialect) {
          case Dialect::kFanuc:
            fanuc.Line(line);
            break;
          case Dialect::kLinuxCnc:
            linuxcnc.Line(line);
            break;
          case Dialect::kSinumerik:
            sinumerik.Line(line);
            break;
        }
      }
      b.pos.line = line_no;
      if (dialect == Dialect::kSinumerik) sinumerik.FinishFile();
    } catch (const LineError& e) {
      return LineStatus(files[f].name, b.pos.line, e.what, dialect);
    }
  }
  try {
    if (dialect == Dialect::kFanuc) fanuc.Finish();
    if (dialect == Dialect::kLinuxCnc) linuxcnc.Finish();
  } catch (const LineError& e) {
    return LineStatus(files.back().name, b.pos.line, e.what, dialect);
  }
  for (const auto& fix : b.fixups) {
    auto& instr = b.code().instrs[fix.instr];
    if (instr.kind == Instr::Kind::kCall) {
      const std::string name = dialect == Dialect::kFanuc ? fix.label.substr(1) : fix.label;
      const auto it = b.code().subs.find(name);
      if (it == b.code().subs.end()) {
        return LineStatus(b.code().files[fix.where.file], fix.where.line,
                          "call of " + fix.label + ", which is not in the program's files", dialect);
      }
      instr.jump = it->second;
    } else {
      const auto it = b.labels.find(fix.label);
      if (it == b.labels.end()) {
        return LineStatus(b.code().files[fix.where.file], fix.where.line,
                          "GOTO target N" + fix.label.substr(fix.label.find(':') + 1) + " is not in the same program",
                          dialect);
      }
      instr.jump = it->second;
    }
  }
  return std::move(b.code());
}

}  // namespace formloop::cnc
