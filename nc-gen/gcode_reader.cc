#include "nc-gen/gcode_reader.h"

#include <algorithm>
#include <cctype>
#include <charconv>
#include <cmath>
#include <cstring>
#include <numbers>

#include "core/point_io.h"

namespace formloop::nc {
namespace {

constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();
constexpr double kTwoPi = 2 * std::numbers::pi;
constexpr const char* kAxisLetters = "XYZ";

bool IsSpace(char c) { return c == ' ' || c == '\t' || c == '\r' || c == '\f' || c == '\v'; }
bool IsDigit(char c) { return c >= '0' && c <= '9'; }
bool IsAlpha(char c) { return (c >= 'A' && c <= 'Z') || (c >= 'a' && c <= 'z'); }
char Upper(char c) { return (c >= 'a' && c <= 'z') ? static_cast<char>(c - 'a' + 'A') : c; }

// G numbers are compared in tenths: G90.1 -> 901.
int Tenths(double g) { return static_cast<int>(std::lround(g * 10)); }

std::string GName(double g) {
  const int t = Tenths(g);
  return "G" + std::to_string(t / 10) + (t % 10 != 0 ? "." + std::to_string(t % 10) : "");
}

double Wrap2Pi(double a) {
  a = std::fmod(a, kTwoPi);
  if (a < 0) a += kTwoPi;
  return a;
}

// Index 0..8 of G54..G59.3 in the offset table, -1 for anything else.
int SystemIndex(int work_system) {
  if (work_system >= 54 && work_system <= 59) return work_system - 54;
  if (work_system >= 591 && work_system <= 593) return work_system - 591 + 6;
  return -1;
}

std::string WorkSystemName(int work_system) {
  if (work_system >= 5410) return "G54.1";
  if (work_system > 100) return GName(work_system / 10.0);
  return "G" + std::to_string(work_system);
}

}  // namespace

Result<GcodeDialect> ParseGcodeDialect(std::string_view name) {
  if (name == "linuxcnc" || name == "rs274ngc") return GcodeDialect::kRs274ngc;
  if (name == "fanuc") return GcodeDialect::kFanuc;
  if (name == "sinumerik") return GcodeDialect::kSinumerik;
  return Status::BadInput(Where{.field = "--dialect"}, "unknown G-code dialect '" + std::string(name) + "'",
                          "use linuxcnc (RS274NGC), fanuc or sinumerik");
}

const char* GcodeDialectName(GcodeDialect dialect) {
  switch (dialect) {
    case GcodeDialect::kFanuc:
      return "fanuc";
    case GcodeDialect::kSinumerik:
      return "sinumerik";
    case GcodeDialect::kRs274ngc:
      break;
  }
  return "linuxcnc";
}

PlaneAxes AxesOf(Plane plane) {
  switch (plane) {
    case Plane::kZX:
      return {2, 0, 1};
    case Plane::kYZ:
      return {1, 2, 0};
    case Plane::kXY:
      break;
  }
  return {0, 1, 2};
}

const char* PlaneCode(Plane plane) {
  switch (plane) {
    case Plane::kZX:
      return "G18";
    case Plane::kYZ:
      return "G19";
    case Plane::kXY:
      break;
  }
  return "G17";
}

Status ReaderOptions::Validate() const {
  if (!(least_increment_mm > 0) || !(least_increment_inch > 0)) {
    return Status::BadInput(Where{.field = "least_increment"}, "must be > 0");
  }
  if (!(arc_radius_tolerance_mm > 0)) {
    return Status::BadInput(Where{.field = "arc_radius_tolerance_mm"}, "must be > 0");
  }
  return Status::Ok();
}

std::size_t ReadReport::notes() const {
  std::size_t n = 0;
  for (const auto& [word, entry] : words) n += entry.count;
  return n;
}

std::size_t ReadReport::unknown() const {
  std::size_t n = 0;
  for (const auto& [word, entry] : words) n += entry.kind == NoteKind::kUnknown ? entry.count : 0;
  return n;
}

void ReadReport::Add(const Note& note) {
  Entry& e = words[note.word];
  if (e.count == 0) {
    e.kind = note.kind;
    e.what = note.what;
  }
  ++e.count;
  if (e.first_lines.size() < kLinesPerWord) e.first_lines.push_back(note.line);
}

nlohmann::json ReadReport::ToJson() const {
  nlohmann::json list = nlohmann::json::array();
  for (const auto& [word, e] : words) {
    list.push_back({{"word", word},
                    {"kind", e.kind == NoteKind::kUnknown        ? "unknown"
                             : e.kind == NoteKind::kCompensation ? "cutter compensation"
                                                                 : "not modelled"},
                    {"what", e.what},
                    {"count", e.count},
                    {"first_lines", e.first_lines}});
  }
  return {{"lines", lines},
          {"blocks", blocks},
          {"motion_blocks", motion_blocks},
          {"arcs", arcs},
          {"skipped_blocks", skipped_blocks},
          {"reported", list}};
}

double ArcGeometry::Length() const {
  const double arc = radius() * sweep_rad;
  return std::sqrt(arc * arc + rise * rise);
}

Eigen::Vector3d ArcGeometry::PointAt(double lambda) const {
  if (lambda <= 0) return start;
  if (lambda >= 1) return end;
  const PlaneAxes ax = AxesOf(plane);
  const double theta = theta_start_rad + (ccw ? 1.0 : -1.0) * lambda * sweep_rad;
  const double r = radius_start + lambda * (radius_end - radius_start);
  Eigen::Vector3d p;
  p[ax.u] = centre[ax.u] + r * std::cos(theta);
  p[ax.v] = centre[ax.v] + r * std::sin(theta);
  p[ax.w] = start[ax.w] + lambda * rise;
  return p;
}

Eigen::Vector3d ArcGeometry::TangentAt(double lambda) const {
  const PlaneAxes ax = AxesOf(plane);
  const double s = ccw ? 1.0 : -1.0;
  const double theta = theta_start_rad + s * lambda * sweep_rad;
  const double r = radius_start + lambda * (radius_end - radius_start);
  Eigen::Vector3d t;
  // d/dλ of the point: radial growth + tangential sweep + rise.
  const double dr = radius_end - radius_start;
  t[ax.u] = dr * std::cos(theta) - s * sweep_rad * r * std::sin(theta);
  t[ax.v] = dr * std::sin(theta) + s * sweep_rad * r * std::cos(theta);
  t[ax.w] = rise;
  const double n = t.norm();
  return n > 0 ? Eigen::Vector3d(t / n) : Eigen::Vector3d::Zero();
}

const Word* Block::Find(char letter) const {
  for (const Word& w : words) {
    if (w.letter == letter) return &w;
  }
  return nullptr;
}

bool Block::HasM(int code) const { return std::find(m_codes.begin(), m_codes.end(), code) != m_codes.end(); }

bool Block::HasG(double code) const {
  for (double g : g_codes) {
    if (Tenths(g) == Tenths(code)) return true;
  }
  return false;
}

double Block::LengthMm() const {
  if (motion == Motion::kNone || !ends_known()) return 0;
  if (has_arc) return arc.Length() * mm_per_unit();
  if (motion == Motion::kArcCw || motion == Motion::kArcCcw) return 0;
  return (end - start).norm() * mm_per_unit();
}

GcodeReader::GcodeReader(ReaderOptions options, std::string source)
    : options_(std::move(options)), source_(std::move(source)) {
  if (options_.no_point == NoPointUnit::kDialect) {
    options_.no_point = options_.dialect == GcodeDialect::kFanuc ? NoPointUnit::kLeastIncrement : NoPointUnit::kUnit;
  }
  position_ = Eigen::Vector3d::Constant(kNaN);
  rotary_.fill(kNaN);
}

Status GcodeReader::Fail(long line, const std::string& code, const std::string& what, const std::string& fix) const {
  return Status::BadInput(Where{.file = source_, .line = line}, code + ": " + what, fix);
}

void GcodeReader::Note(Block* block, NoteKind kind, std::string word, std::string what) {
  nc::Note note{.line = block->line, .kind = kind, .word = std::move(word), .what = std::move(what)};
  report_.Add(note);
  block->notes.push_back(std::move(note));
}

// Length and angle words without a decimal point: least increments where the dialect says so.
double GcodeReader::Scale(const Word& word, bool distance) const {
  if (word.has_point || options_.no_point != NoPointUnit::kLeastIncrement) return word.value;
  if (!distance) return word.value * 0.001;  // rotary axes: 0.001 degree on IS-B
  return word.value * (units_ == Units::kInch ? options_.least_increment_inch : options_.least_increment_mm);
}

Status GcodeReader::Read(std::string_view line, Block* block) {
  ++line_;
  ++report_.lines;
  block->line = line_;
  block->text = line;
  block->skipped = block->percent = block->slash = false;
  block->n_word = -1;
  block->head_end = 0;
  block->words.clear();
  block->comments.clear();
  block->m_codes.clear();
  block->g_codes.clear();
  block->notes.clear();
  block->motion = Motion::kNone;
  block->explicit_motion = false;
  block->has_arc = false;
  block->xyz_words = block->rotary_words = 0;
  block->rotary_moved = false;
  block->has_feed_word = false;
  block->program_end = false;
  block->start = block->end = position_;
  block->start_known = block->end_known = known_;
  FL_RETURN_IF_ERROR(Lex(line, block));
  if (!block->skipped && !block->percent) FL_RETURN_IF_ERROR(Interpret(block));
  // The modal state after the block.
  block->modal_motion = modal_motion_;
  block->plane = plane_;
  block->units = units_;
  block->incremental = incremental_;
  block->arc_absolute = arc_absolute_;
  block->feed_mode = feed_mode_;
  block->feed = feed_;
  block->cutter_comp = cutter_comp_;
  block->length_comp = length_comp_;
  block->tcp = Tenths(length_comp_) == 434 || Tenths(length_comp_) == 435;
  block->work_system = work_system_;
  block->transform_active = polar_ || scaling_ || mirror_ || rotation_;
  block->cycle_active = cycle_;
  block->rotary = rotary_;
  block->rotary_known = rotary_known_;
  if (block->motion != Motion::kNone) ++report_.motion_blocks;
  if (block->has_arc) ++report_.arcs;
  return Status::Ok();
}

Status GcodeReader::Lex(std::string_view line, Block* block) {
  std::size_t i = 0;
  const std::size_t n = line.size();
  while (i < n && IsSpace(line[i])) ++i;
  if (i < n && line[i] == '%') {
    block->percent = true;
    return Status::Ok();
  }
  if (i < n && line[i] == '/') {
    block->slash = true;
    ++i;
    while (i < n && IsDigit(line[i])) ++i;  // Fanuc optional block skip levels /1 .. /9
    if (options_.block_delete) {
      block->skipped = true;
      ++report_.skipped_blocks;
      return Status::Ok();
    }
  }
  block->head_end = static_cast<std::uint32_t>(i);
  while (i < n) {
    const char c = line[i];
    if (IsSpace(c)) {
      ++i;
      continue;
    }
    if (c == '(') {
      const std::size_t close = line.find(')', i + 1);
      if (close == std::string_view::npos) {
        return Fail(line_, "E_SYNTAX", "comment '(' without ')'", "close the comment on the same line");
      }
      block->comments.emplace_back(static_cast<std::uint32_t>(i), static_cast<std::uint32_t>(close + 1));
      i = close + 1;
      continue;
    }
    if (c == ';') {
      block->comments.emplace_back(static_cast<std::uint32_t>(i), static_cast<std::uint32_t>(n));
      break;
    }
    if (c == '#') {  // parameter assignment "#1 = 5", "#<name> = ...": a macro statement
      Note(block, NoteKind::kUnmodelled, "#", "macro variable or expression: its value is not computed");
      block->words.push_back(Word{.letter = '#',
                                  .value = kNaN,
                                  .begin = static_cast<std::uint32_t>(i),
                                  .end = static_cast<std::uint32_t>(n),
                                  .expression = true});
      break;
    }
    if (c == ',' && i + 1 < n && IsAlpha(line[i + 1])) {  // Fanuc corner words ,R / ,C
      std::size_t j = i + 2;
      while (j < n && (IsDigit(line[j]) || line[j] == '.' || line[j] == '-' || line[j] == '+' || IsSpace(line[j]))) ++j;
      Note(block, NoteKind::kUnmodelled, std::string(",") + Upper(line[i + 1]),
           "corner rounding or chamfer between blocks: the rounded corner is not modelled");
      i = j;
      continue;
    }
    if (!IsAlpha(c)) {
      if (c == '*' || c == '=' || c == '%' || c == ':' || c == ',' || c == '[' || c == ']' || c == '<' || c == '>' ||
          c == '"' || c == '\'') {
        if (c == ':' && options_.dialect == GcodeDialect::kFanuc) {  // ":1234" program number
          std::size_t j = i + 1;
          while (j < n && IsDigit(line[j])) ++j;
          i = j;
          continue;
        }
        Note(block, NoteKind::kUnknown, std::string(1, c), "character the reader does not know here");
        ++i;
        continue;
      }
      Note(block, NoteKind::kUnknown, std::string(1, c), "character the reader does not know here");
      ++i;
      continue;
    }
    const char letter = Upper(c);
    Word word{.letter = letter, .begin = static_cast<std::uint32_t>(i)};
    std::size_t j = i + 1;
    while (j < n && IsSpace(line[j])) ++j;
    if (letter == 'O' && options_.dialect == GcodeDialect::kRs274ngc) {
      // LinuxCNC O-words: sub-programs, loops, conditions. The rest of the line belongs to them.
      Note(block, NoteKind::kUnmodelled, "O", "O-word control flow (sub, call, if, while, ...): not executed");
      word.value = kNaN;
      word.expression = true;
      word.end = static_cast<std::uint32_t>(n);
      block->words.push_back(word);
      break;
    }
    if (j < n && (line[j] == '#' || line[j] == '[')) {
      // An expression or parameter as the value: a balanced [ ... ], #<name>, #[ ... ] or #digits.
      auto skip_brackets = [&line, n](std::size_t k) {
        int depth = 0;
        while (k < n) {
          if (line[k] == '[') ++depth;
          if (line[k] == ']' && --depth == 0) return k + 1;
          ++k;
        }
        return n;
      };
      std::size_t k = j;
      if (line[k] == '[') {
        k = skip_brackets(k);
      } else {
        ++k;
        if (k < n && line[k] == '<') {
          const std::size_t close = line.find('>', k);
          k = close == std::string_view::npos ? n : close + 1;
        } else if (k < n && line[k] == '[') {
          k = skip_brackets(k);
        } else {
          while (k < n && IsDigit(line[k])) ++k;
        }
      }
      word.value = kNaN;
      word.expression = true;
      word.end = static_cast<std::uint32_t>(k);
      Note(block, NoteKind::kUnmodelled, "#", "macro variable or expression: its value is not computed");
      block->words.push_back(word);
      i = k;
      continue;
    }
    std::size_t k = j;
    if (k < n && (line[k] == '+' || line[k] == '-')) ++k;
    const std::size_t digits_begin = k;
    bool digits = false;
    while (k < n && (IsDigit(line[k]) || line[k] == '.')) {
      if (line[k] == '.') {
        if (word.has_point) break;
        word.has_point = true;
      } else {
        digits = true;
      }
      ++k;
    }
    if (!digits) {
      return Fail(line_, "E_SYNTAX", std::string("word '") + letter + "' has no number",
                  "write the word's value after its letter, e.g. X10.5");
    }
    // std::from_chars takes no '+' sign.
    const char* first = line.data() + (line[j] == '+' ? j + 1 : j);
    const char* last = line.data() + k;
    double value = 0;
    const auto result = std::from_chars(first, last, value);
    if (result.ec != std::errc() || result.ptr != last) {
      // "5." and ".5" are read by from_chars; anything else here is malformed.
      return Fail(line_, "E_SYNTAX",
                  "cannot read the number '" + std::string(line.substr(j, k - j)) + "' of word " + letter,
                  "write a decimal number");
    }
    (void)digits_begin;
    // A word's number is bounded before anything converts it: N, G, M, P, ... become integers, and a number of
    // 20 digits (found by fuzz/fuzz_gcode: "N0170777...7") overflowed that conversion.
    if (!(std::abs(value) <= kMaxWordValue)) {
      return Fail(line_, "E_RANGE",
                  "the number of word " + std::string(1, letter) + " (" + std::string(line.substr(j, k - j)) +
                      ") is out of range: at most " + std::to_string(static_cast<long>(kMaxWordValue)) +
                      " in magnitude",
                  "check the word; no address of a program takes a number this large");
    }
    word.value = value;
    word.end = static_cast<std::uint32_t>(k);
    if (letter == 'N') {
      block->n_word = static_cast<long>(value);
      if (block->words.empty()) block->head_end = static_cast<std::uint32_t>(k);
    } else if (letter == 'O') {
      // Fanuc program number: no effect on the path.
    } else {
      block->words.push_back(word);
    }
    i = k;
  }
  return Status::Ok();
}

Status GcodeReader::Interpret(Block* block) {
  ++report_.blocks;
  const bool fanuc = options_.dialect == GcodeDialect::kFanuc;
  // Which words a G- or M-code of this block uses; a word nobody uses is reported.
  std::uint32_t used = 0;  // letters consumed, bit (letter - 'A'); '#' and 'O' words are always consumed
  auto use = [&used](const char* letters) {
    for (const char* c = letters; *c != 0; ++c) {
      if (*c >= 'A' && *c <= 'Z') used |= 1u << (*c - 'A');
    }
  };
  double motion_code = -1;     // G0..G3 in this block
  bool axis_consumer = false;  // G4/G10/G28/G30/G52/G53/G92: axis words are data, not a move
  bool unknown_position_all = false;
  bool unknown_given_axes = false;
  bool set_position_to_words = false;  // G92 / G10 L20 on the current system
  bool dwell = false;
  bool g10 = false, g52 = false, g92 = false;
  int new_work_system = work_system_;
  for (const Word& w : block->words) {
    if (w.letter == 'G') {
      if (w.expression) continue;
      block->g_codes.push_back(w.value);
    } else if (w.letter == 'M') {
      if (w.expression) continue;
      block->m_codes.push_back(static_cast<int>(std::lround(w.value)));
    }
  }
  for (double g : block->g_codes) {
    const int t = Tenths(g);
    const std::string name = GName(g);
    if (options_.dialect == GcodeDialect::kSinumerik && (t == 700 || t == 710)) {  // G70 inch, G71 mm
      SetUnits(t == 700 ? Units::kInch : Units::kMm);
      continue;
    }
    switch (t) {
      case 0:
      case 10:
      case 20:
      case 30:
        if (motion_code >= 0) {
          return Fail(line_, "E_MODAL_GROUP",
                      "two motion codes in one block (" + GName(motion_code) + ", " + name + ")", "split the block");
        }
        motion_code = g;
        break;
      case 40:  // dwell
        dwell = true;
        axis_consumer = true;
        use(fanuc ? "PXU" : "P");
        break;
      case 90:  // exact stop, one block
        break;
      case 100:
        g10 = true;
        axis_consumer = true;
        use("LPRXYZABCIJKQ");
        break;
      case 150:
        polar_ = false;
        break;
      case 160:
        polar_ = true;
        Note(block, NoteKind::kUnmodelled, name, "polar coordinates: the path is not modelled while G16 is on");
        break;
      case 170:
        plane_ = Plane::kXY;
        break;
      case 180:
        plane_ = Plane::kZX;
        break;
      case 190:
        plane_ = Plane::kYZ;
        break;
      case 200:
      case 210:
        SetUnits(t == 200 ? Units::kInch : Units::kMm);
        break;
      case 280:
      case 281:
      case 300:
      case 301:
        Note(block, NoteKind::kUnmodelled, name, "reference point return: the position after it is not known");
        axis_consumer = true;
        if (t == 280 || t == 300) {
          unknown_position_all = true;  // re-evaluated below when axis words restrict it
          unknown_given_axes = true;
        }
        use("PXYZABC");
        break;
      case 330:
      case 331:
      case 760:
        Note(block, NoteKind::kUnmodelled, name, "threading cycle: not modelled");
        unknown_position_all = true;
        use("KXYZIJRQLPEH");
        break;
      case 382:
      case 383:
      case 384:
      case 385:
      case 310:
        Note(block, NoteKind::kUnmodelled, name, "probing or skip move: where it stops is not known");
        axis_consumer = true;
        unknown_given_axes = true;
        use("XYZABCF");
        break;
      case 400:
        cutter_comp_ = 40;
        break;
      case 410:
      case 420:
      case 411:
      case 421:
        cutter_comp_ = t / 10;
        use("D");
        Note(block, NoteKind::kCompensation, name,
             "cutter radius compensation: the programmed contour is read; the controller offsets it");
        break;
      case 430:
      case 431:
      case 432:
      case 440:
      case 434:
      case 435:
        length_comp_ = g;
        use("H");
        break;
      case 490:
        length_comp_ = 49;
        break;
      case 500:
        scaling_ = false;
        break;
      case 510:
        scaling_ = true;
        use("IJKPXYZ");
        Note(block, NoteKind::kUnmodelled, name, "scaling: the path is not modelled while it is on");
        break;
      case 501:
        mirror_ = false;
        use("XYZ");
        break;
      case 511:
        mirror_ = true;
        use("XYZ");
        Note(block, NoteKind::kUnmodelled, name, "programmable mirror image: not modelled while it is on");
        break;
      case 520:
        g52 = true;
        axis_consumer = true;
        break;
      case 530:
        Note(block, NoteKind::kUnmodelled, name,
             "move in machine coordinates: the work position after it is not known");
        axis_consumer = true;
        unknown_given_axes = true;
        break;
      case 540:
      case 550:
      case 560:
      case 570:
      case 580:
      case 590:
        new_work_system = t / 10;
        break;
      case 591:
      case 592:
      case 593:
        new_work_system = 590 + t % 10;
        break;
      case 541:  // Fanuc additional work systems G54.1 Pn
        new_work_system = 5410;
        use("P");
        break;
      case 610:
      case 611:
      case 640:
        use("PQ");
        break;
      case 650:
      case 660:
      case 670:
        Note(block, NoteKind::kUnmodelled, name, "macro call: not executed");
        unknown_position_all = true;
        use("PLABCDEFHIJKMQRSTUVWXYZ");
        break;
      case 680:
      case 682:
        rotation_ = true;
        use("XYZIJKRPQABC");
        Note(block, NoteKind::kUnmodelled, name, "coordinate rotation or tilted plane: not modelled while it is on");
        axis_consumer = true;
        break;
      case 690:
        rotation_ = false;
        break;
      case 50:
      case 51:
      case 52:
      case 53:
        Note(block, NoteKind::kUnmodelled, name, "spline motion: not modelled");
        unknown_position_all = true;
        use("XYZIJKPQLR");
        break;
      case 70:
      case 80:
        Note(block, NoteKind::kUnmodelled, name, "lathe diameter/radius mode: not modelled");
        break;
      case 700:
      case 710:
      case 711:
      case 720:
      case 721:
      case 730:
      case 740:
      case 810:
      case 820:
      case 830:
      case 840:
      case 841:
      case 850:
      case 860:
      case 870:
      case 880:
      case 890:
        cycle_ = true;
        Note(block, NoteKind::kUnmodelled, name, "canned cycle: its moves are not modelled");
        use("XYZRQPLIJKDF");
        break;
      case 800:
        cycle_ = false;
        break;
      case 900:
        incremental_ = false;
        break;
      case 910:
        incremental_ = true;
        break;
      case 901:
        arc_absolute_ = true;
        break;
      case 911:
        arc_absolute_ = false;
        break;
      case 920:
        g92 = true;
        axis_consumer = true;
        break;
      case 921:
      case 922:
        Note(block, NoteKind::kUnmodelled, name, "offset cancel: the work position after it is not known");
        unknown_position_all = true;
        break;
      case 923:
        Note(block, NoteKind::kUnmodelled, name, "offset restore: the work position after it is not known");
        unknown_position_all = true;
        break;
      case 930:
        feed_mode_ = FeedMode::kInverseTime;
        break;
      case 940:
        feed_mode_ = FeedMode::kUnitsPerMinute;
        break;
      case 950:
        feed_mode_ = FeedMode::kUnitsPerRevolution;
        break;
      case 960:
      case 970:
        use("SD");
        break;
      case 980:
      case 990:
        break;
      default:
        Note(block, NoteKind::kUnknown, name, "G-code the reader does not know");
    }
  }
  // M-codes.
  for (int m : block->m_codes) {
    const std::string name = "M" + std::to_string(m);
    if (std::find(options_.caller_m_codes.begin(), options_.caller_m_codes.end(), m) != options_.caller_m_codes.end()) {
      use("PIJK");
      continue;
    }
    switch (m) {
      case 2:
      case 30:
        block->program_end = true;
        break;
      case 0:
      case 1:
      case 3:
      case 4:
      case 5:
      case 6:
      case 7:
      case 8:
      case 9:
      case 48:
      case 49:
      case 60:
        break;
      case 19:  // spindle orientation
        use("RQP");
        break;
      case 50:
      case 51:
      case 52:
      case 53:
      case 61:
      case 62:
      case 63:
      case 64:
      case 65:
      case 66:
      case 67:
      case 68:
      case 70:
      case 71:
      case 72:
      case 73:
        use("PQELR");
        break;
      case 98:
      case 99:
        Note(block, NoteKind::kUnmodelled, name, "sub-program call or return: not executed");
        unknown_position_all = true;
        use("PLQ");
        break;
      default:
        if (m >= 100 && m <= 199 && !fanuc) {
          Note(block, NoteKind::kUnmodelled, name, "user-defined M-code: assumed not to move the axes");
          use("PQ");
        } else {
          Note(block, NoteKind::kUnmodelled, name,
               "machine function the reader does not know: assumed not to move the axes");
          use("PQ");
        }
    }
  }
  // Feed, spindle, tool.
  for (const Word& w : block->words) {
    if (w.letter == 'F' && !w.expression) {
      feed_ = w.value;
      block->has_feed_word = true;
    }
  }
  use("FSTGMN#O");
  // Work coordinate system.
  if (new_work_system != work_system_) {
    const int from = SystemIndex(work_system_), to = SystemIndex(new_work_system);
    unsigned still = 0;
    for (int a = 0; a < 3; ++a) {
      const unsigned bit = 1u << a;
      if (from >= 0 && to >= 0 && (offset_known_[from] & bit) && (offset_known_[to] & bit) && (known_ & bit)) {
        position_[a] += offsets_[from][a] - offsets_[to][a];
        still |= bit;
      }
    }
    if (still != known_) {
      Note(block, NoteKind::kUnmodelled, WorkSystemName(new_work_system),
           "change of work coordinate system with offsets the program does not set: the position is not known "
           "until every axis is programmed again");
    }
    known_ = still;
    work_system_ = new_work_system;
  }
  if (motion_code >= 0) {
    const int t = Tenths(motion_code);
    modal_motion_ = t == 0 ? Motion::kRapid : t == 10 ? Motion::kLinear : t == 20 ? Motion::kArcCw : Motion::kArcCcw;
    block->explicit_motion = true;
    cycle_ = false;
  }
  // Collect axis words.
  Eigen::Vector3d target = position_;
  unsigned target_known = known_;
  bool has_axis = false;
  unsigned expression_axes = 0;
  std::array<double, 3> rotary_target = rotary_;
  unsigned rotary_target_known = rotary_known_;
  for (const Word& w : block->words) {
    int a = -1;
    bool rotary = false;
    switch (w.letter) {
      case 'X':
        a = 0;
        break;
      case 'Y':
        a = 1;
        break;
      case 'Z':
        a = 2;
        break;
      case 'A':
        a = 0;
        rotary = true;
        break;
      case 'B':
        a = 1;
        rotary = true;
        break;
      case 'C':
        a = 2;
        rotary = true;
        break;
      default:
        continue;
    }
    if (dwell && fanuc && w.letter == 'X') continue;  // G04 X = dwell time
    has_axis = true;
    const unsigned bit = 1u << a;
    if (rotary) {
      block->rotary_words |= bit;
      if (w.expression) {
        rotary_target_known &= ~bit;
        continue;
      }
      const double v = Scale(w, false);
      if (incremental_) {
        rotary_target[a] += v;
      } else {
        rotary_target[a] = v;
        rotary_target_known |= bit;
      }
      continue;
    }
    block->xyz_words |= bit;
    if (w.expression) {
      expression_axes |= bit;
      target_known &= ~bit;
      continue;
    }
    const double v = Scale(w, true);
    if (incremental_) {
      target[a] += v;  // stays unknown when the start is
    } else {
      target[a] = v;
      target_known |= bit;
    }
  }
  // Words of other letters: used by the motion below or by the codes above, else reported.
  const bool arc_mode = modal_motion_ == Motion::kArcCw || modal_motion_ == Motion::kArcCcw;
  if (arc_mode && !axis_consumer) use(fanuc ? "IJKR" : "IJKRP");
  for (const Word& w : block->words) {
    if (std::strchr("XYZABC", w.letter) != nullptr) continue;
    if (w.letter == '#' || w.letter == 'O' ||
        (w.letter >= 'A' && w.letter <= 'Z' && (used & (1u << (w.letter - 'A'))))) {
      continue;
    }
    if (w.letter == 'U' || w.letter == 'V' || w.letter == 'W') {
      Note(block, NoteKind::kUnmodelled, std::string(1, w.letter), "extra linear axis: not modelled");
      continue;
    }
    if (w.letter == 'D' || w.letter == 'H') {
      continue;  // offset numbers on their own: no effect on the programmed path
    }
    Note(block, NoteKind::kUnknown, std::string(1, w.letter),
         std::string("word ") + w.letter + " has no use in this block");
  }
  // Non-motion uses of axis words.
  if (axis_consumer) {
    if (g92 || g52 || g10) {
      const Word* l = block->Find('L');
      const Word* p = block->Find('P');
      const bool l20 = g10 && l != nullptr && std::lround(l->value) == 20;
      const bool l2 = g10 && l != nullptr && std::lround(l->value) == 2;
      int system = -1;
      if (g10 && p != nullptr && !p->expression) {
        const long pv = std::lround(p->value);
        system = pv == 0 ? SystemIndex(work_system_) : static_cast<int>(pv - 1);
      }
      if (g92) {
        // G92: the current point takes the given coordinates (the offset is whatever makes it so).
        Note(block, NoteKind::kUnmodelled, "G92", "coordinate system offset: the current point is renamed");
        set_position_to_words = true;
      } else if (g52) {
        Note(block, NoteKind::kUnmodelled, "G52", "local coordinate system: the position is not known after it");
        unknown_position_all = true;
      } else if (l2 && system >= 0 && system < 9) {
        for (const Word& w : block->words) {
          const char* axis = std::strchr(kAxisLetters, w.letter);
          if (axis == nullptr) continue;
          const int a = static_cast<int>(axis - kAxisLetters);
          const unsigned bit = 1u << a;
          const double old_offset = offsets_[system][a];
          const bool old_known = (offset_known_[system] & bit) != 0;
          if (w.expression) {
            offset_known_[system] &= ~bit;
          } else {
            offsets_[system][a] = Scale(w, true);
            offset_known_[system] |= bit;
          }
          if (system == SystemIndex(work_system_)) {
            if (old_known && (offset_known_[system] & bit) && (known_ & bit)) {
              position_[a] += old_offset - offsets_[system][a];
            } else if (known_ & bit) {
              known_ &= ~bit;
              Note(block, NoteKind::kUnmodelled, "G10",
                   "offset of the active work coordinate system changed from an unknown value: the position is "
                   "not known until it is programmed again");
            }
          }
        }
      } else if (l20 && system >= 0 && system < 9) {
        // The offset is whatever makes the current point take the given coordinates.
        offset_known_[system] &= ~block->xyz_words;
        set_position_to_words = system == SystemIndex(work_system_);
      } else if (g10) {
        Note(block, NoteKind::kUnmodelled, "G10", "data setting (tool or offset table): not applied");
      }
    }
    if (set_position_to_words) {
      for (const Word& w : block->words) {
        const char* axis = std::strchr(kAxisLetters, w.letter);
        if (axis == nullptr) continue;
        const int a = static_cast<int>(axis - kAxisLetters);
        if (w.expression) {
          known_ &= ~(1u << a);
        } else {
          position_[a] = Scale(w, true);
          known_ |= 1u << a;
        }
      }
    }
    if (unknown_given_axes && !unknown_position_all) known_ &= ~block->xyz_words;
    if (unknown_position_all) {
      if (unknown_given_axes && block->xyz_words != 0) {
        known_ &= ~block->xyz_words;
      } else {
        known_ = 0;
      }
    }
    block->start = block->end = position_;
    block->start_known = block->end_known = known_;
    return Status::Ok();
  }
  if (unknown_position_all) {
    known_ = 0;
    block->start_known = block->end_known = 0;
    return Status::Ok();
  }
  if (!has_axis) {
    // No motion. (An arc mode with only centre words and no axes is a full circle in LinuxCNC and Fanuc.)
    const bool centre_only = arc_mode && (block->Find('I') || block->Find('J') || block->Find('K'));
    if (!centre_only) return Status::Ok();
  }
  if (cycle_) {
    // Hole positions of a modal canned cycle: X and Y go where the words say, Z is not known.
    known_ = target_known & ~4u;
    position_ = target;
    block->end = position_;
    block->end_known = known_;
    rotary_ = rotary_target;
    rotary_known_ = rotary_target_known;
    return Status::Ok();
  }
  if (modal_motion_ == Motion::kNone) {
    return Fail(line_, "E_NO_MOTION_MODE", "coordinates without a motion mode (G0, G1, G2 or G3)",
                "put the motion code into the block");
  }
  if (polar_ || scaling_ || mirror_ || rotation_) target_known = 0;
  for (int a = 0; a < 3; ++a) {
    if (rotary_target[a] != rotary_[a] && !(std::isnan(rotary_target[a]) && std::isnan(rotary_[a]))) {
      block->rotary_moved = true;
    }
  }
  rotary_ = rotary_target;
  rotary_known_ = rotary_target_known;
  block->motion = modal_motion_;
  block->start = position_;
  block->start_known = known_;
  if (modal_motion_ == Motion::kArcCw || modal_motion_ == Motion::kArcCcw) {
    FL_RETURN_IF_ERROR(Arc(block, target, target_known));
  } else {
    block->end = target;
    block->end_known = target_known;
  }
  position_ = block->end;
  known_ = block->end_known;
  return Status::Ok();
}

void GcodeReader::SetUnits(Units units) {
  if (units == units_) return;
  const double f = units == Units::kInch ? 1.0 / kMmPerInch : kMmPerInch;  // the position stays where it is
  position_ *= f;
  feed_ *= f;
  units_ = units;
}

Status GcodeReader::Arc(Block* block, const Eigen::Vector3d& target, unsigned target_known) {
  const PlaneAxes ax = AxesOf(plane_);
  const bool ccw = modal_motion_ == Motion::kArcCcw;
  block->end = target;
  block->end_known = target_known;
  const char centre_letter[3] = {'I', 'J', 'K'};
  const Word* cu = block->Find(centre_letter[ax.u]);
  const Word* cv = block->Find(centre_letter[ax.v]);
  const Word* cw = block->Find(centre_letter[ax.w]);
  const Word* r_word = block->Find('R');
  const Word* turns = options_.dialect == GcodeDialect::kRs274ngc ? block->Find('P') : nullptr;
  if (cw != nullptr) {
    Note(block, NoteKind::kUnknown, std::string(1, centre_letter[ax.w]),
         std::string("centre word along the plane's normal (") + PlaneCode(plane_) + ")");
  }
  const bool centre_form = cu != nullptr || cv != nullptr;
  if (!centre_form && r_word == nullptr) {
    return Fail(line_, "E_ARC_NO_CENTRE",
                std::string("arc (") + (ccw ? "G3" : "G2") + ", " + PlaneCode(plane_) + ") without centre words " +
                    centre_letter[ax.u] + "/" + centre_letter[ax.v] + " or R",
                "give the centre or the radius");
  }
  const unsigned plane_bits = (1u << ax.u) | (1u << ax.v) | (1u << ax.w);
  const bool any_expression = (cu && cu->expression) || (cv && cv->expression) || (r_word && r_word->expression) ||
                              (turns && turns->expression);
  if ((block->start_known & plane_bits) != plane_bits || (target_known & plane_bits) != plane_bits || any_expression) {
    Note(block, NoteKind::kUnmodelled, ccw ? "G3" : "G2",
         "arc from or to a position that is not known: its path is not modelled");
    block->end_known &= ~plane_bits;
    if (!any_expression && (target_known & plane_bits) == plane_bits) block->end_known = target_known;
    return Status::Ok();
  }
  ArcGeometry& arc = block->arc;
  arc.plane = plane_;
  arc.ccw = ccw;
  arc.start = block->start;
  arc.end = target;
  arc.rise = target[ax.w] - block->start[ax.w];
  const Eigen::Vector2d s(block->start[ax.u], block->start[ax.v]);
  const Eigen::Vector2d e(target[ax.u], target[ax.v]);
  const double unit_mm = units_ == Units::kInch ? kMmPerInch : 1.0;
  const double tiny = 1e-9;
  Eigen::Vector2d c;
  if (centre_form) {
    const double du = cu != nullptr ? Scale(*cu, true) : 0.0;
    const double dv = cv != nullptr ? Scale(*cv, true) : 0.0;
    if (arc_absolute_) {
      if (cu == nullptr || cv == nullptr) {
        return Fail(line_, "E_ARC_NO_CENTRE", "absolute arc centre (G90.1) needs both centre words",
                    "give both centre words");
      }
      c = Eigen::Vector2d(du, dv);
    } else {
      c = s + Eigen::Vector2d(du, dv);
    }
    arc.radius_start = (s - c).norm();
    arc.radius_end = (e - c).norm();
    const double mismatch_mm = std::abs(arc.radius_start - arc.radius_end) * unit_mm;
    if (mismatch_mm > options_.arc_radius_tolerance_mm) {
      return Fail(line_, "E_ARC_RADIUS",
                  "arc start radius " + FormatFixed(arc.radius_start, 4) + " and end radius " +
                      FormatFixed(arc.radius_end, 4) + " differ by " + FormatFixed(mismatch_mm, 4) +
                      " mm, more than the tolerance " + FormatFixed(options_.arc_radius_tolerance_mm, 4) + " mm",
                  "correct the centre words or the end point (or raise the arc radius tolerance)");
    }
    if (arc.radius_start < tiny) {
      return Fail(line_, "E_ARC_RADIUS", "arc with zero radius", "correct the centre words");
    }
  } else {
    const double r = Scale(*r_word, true);
    const double chord = (e - s).norm();
    if (chord < tiny) {
      return Fail(line_, "E_ARC_R_FULLCIRCLE", "R-form arc whose start and end coincide (a full circle)",
                  "program a full circle with centre words (I, J, K)");
    }
    if (chord > 2 * std::abs(r) + options_.arc_radius_tolerance_mm / unit_mm) {
      return Fail(
          line_, "E_ARC_R",
          "R-form arc: chord " + FormatFixed(chord, 4) + " longer than the diameter " + FormatFixed(2 * std::abs(r), 4),
          "correct R or the end point");
    }
    const Eigen::Vector2d mid = 0.5 * (s + e);
    const Eigen::Vector2d t = (e - s) / chord;
    const Eigen::Vector2d left(-t.y(), t.x());
    const double d = std::sqrt(std::max(0.0, r * r - 0.25 * chord * chord));
    const double side = (ccw != (r < 0)) ? 1.0 : -1.0;
    c = mid + side * d * left;
    arc.radius_start = (s - c).norm();
    arc.radius_end = (e - c).norm();
  }
  arc.centre = block->start;
  arc.centre[ax.u] = c.x();
  arc.centre[ax.v] = c.y();
  arc.theta_start_rad = std::atan2(s.y() - c.y(), s.x() - c.x());
  const double theta_end = std::atan2(e.y() - c.y(), e.x() - c.x());
  if ((e - s).norm() < tiny) {
    arc.sweep_rad = kTwoPi;
  } else {
    arc.sweep_rad = ccw ? Wrap2Pi(theta_end - arc.theta_start_rad) : Wrap2Pi(arc.theta_start_rad - theta_end);
  }
  if (turns != nullptr) {
    const long p = std::lround(turns->value);
    if (p < 1 || std::abs(turns->value - static_cast<double>(p)) > 1e-9) {
      return Fail(line_, "E_SYNTAX", "arc turn count P must be a positive integer", "write P1, P2, ...");
    }
    arc.sweep_rad += kTwoPi * static_cast<double>(p - 1);
  }
  block->has_arc = true;
  return Status::Ok();
}

// ---------------------------------------------------------------------------------------------------

Result<LineSource> LineSource::Open(const std::filesystem::path& path) {
  LineSource source;
  source.path_ = path.string();
  source.file_ = std::fopen(path.c_str(), "rb");
  if (source.file_ == nullptr) {
    std::error_code ec;
    if (!std::filesystem::exists(path, ec)) return Status::NotFound("no file " + path.string());
    return Status::IoError("cannot open " + path.string() + " for reading");
  }
  source.buffer_.resize(1 << 20);
  return source;
}

LineSource LineSource::FromText(std::string_view text) {
  LineSource source;
  source.in_memory_ = true;
  source.text_ = text;
  source.end_ = text.size();
  source.eof_ = true;
  return source;
}

LineSource::LineSource(LineSource&& other) noexcept { *this = std::move(other); }

LineSource& LineSource::operator=(LineSource&& other) noexcept {
  if (this != &other) {
    if (file_ != nullptr) std::fclose(file_);
    file_ = std::exchange(other.file_, nullptr);
    path_ = std::move(other.path_);
    buffer_ = std::move(other.buffer_);
    text_ = other.text_;
    begin_ = other.begin_;
    end_ = other.end_;
    eof_ = other.eof_;
    in_memory_ = other.in_memory_;
    status_ = other.status_;
  }
  return *this;
}

LineSource::~LineSource() {
  if (file_ != nullptr) std::fclose(file_);
}

bool LineSource::Fill() {
  if (eof_ || file_ == nullptr) return false;
  // Keep the unread tail at the front; grow when a single line fills the buffer.
  if (begin_ > 0) {
    std::memmove(buffer_.data(), buffer_.data() + begin_, end_ - begin_);
    end_ -= begin_;
    begin_ = 0;
  }
  if (end_ == buffer_.size()) buffer_.resize(buffer_.size() * 2);
  const std::size_t got = std::fread(buffer_.data() + end_, 1, buffer_.size() - end_, file_);
  end_ += got;
  if (got == 0) {
    if (std::ferror(file_)) status_ = Status::IoError("read error in " + path_);
    eof_ = true;
  }
  return got > 0;
}

bool LineSource::Next(std::string_view* line, std::string_view* eol) {
  while (true) {
    const char* data = in_memory_ ? text_.data() : buffer_.data();
    const void* found = begin_ < end_ ? std::memchr(data + begin_, '\n', end_ - begin_) : nullptr;
    if (found != nullptr) {
      const std::size_t nl = static_cast<std::size_t>(static_cast<const char*>(found) - data);
      std::size_t stop = nl;
      *eol = std::string_view(data + nl, 1);
      if (stop > begin_ && data[stop - 1] == '\r') {
        --stop;
        *eol = std::string_view(data + stop, 2);
      }
      *line = std::string_view(data + begin_, stop - begin_);
      begin_ = nl + 1;
      return true;
    }
    if (!eof_) {
      Fill();
      continue;
    }
    if (begin_ < end_) {
      std::size_t stop = end_;
      *eol = std::string_view();
      if (data[stop - 1] == '\r') {
        --stop;
        *eol = std::string_view(data + stop, 1);
      }
      *line = std::string_view(data + begin_, stop - begin_);
      begin_ = end_;
      return true;
    }
    return false;
  }
}

// ---------------------------------------------------------------------------------------------------

namespace {

constexpr double kPow10[] = {1, 10, 100, 1e3, 1e4, 1e5, 1e6, 1e7, 1e8, 1e9};

// x rounded to an integer, halves away from zero; values within 1e-6 of a half count as halves (they
// are decimal halves blurred by binary arithmetic).
double RoundHalfAway(double x) {
  const double a = std::abs(x);
  const double f = std::floor(a);
  const double d = a - f;
  const double r = d >= 0.5 - 1e-6 ? f + 1 : f;
  return x < 0 ? -r : r;
}

}  // namespace

double RoundCoordinate(double value, int decimals) {
  const int d = std::clamp(decimals, 0, 9);
  return RoundHalfAway(value * kPow10[d]) / kPow10[d];
}

std::string FormatCoordinate(double value, int decimals) {
  const int d = std::clamp(decimals, 0, 9);
  const double scaled = RoundHalfAway(value * kPow10[d]);
  long long n = static_cast<long long>(scaled);
  const bool negative = n < 0;
  if (negative) n = -n;
  const long long unit = static_cast<long long>(kPow10[d]);
  long long whole = n / unit;
  long long frac = n % unit;
  char buffer[48];
  char* p = buffer;
  if (negative && n != 0) *p++ = '-';
  auto [end, ec] = std::to_chars(p, buffer + sizeof(buffer), whole);
  (void)ec;
  p = end;
  *p++ = '.';
  if (frac != 0) {
    int digits = d;
    while (frac % 10 == 0) {
      frac /= 10;
      --digits;
    }
    char tmp[16];
    auto [fend, fec] = std::to_chars(tmp, tmp + sizeof(tmp), frac);
    (void)fec;
    const int len = static_cast<int>(fend - tmp);
    for (int k = len; k < digits; ++k) *p++ = '0';
    std::memcpy(p, tmp, static_cast<std::size_t>(len));
    p += len;
  }
  return std::string(buffer, p);
}

Status ReadProgramPathInto(std::string_view text, const ReaderOptions& options, const std::string& source,
                           ProgramPath* path) {
  FL_RETURN_IF_ERROR(options.Validate());
  GcodeReader reader(options, source);
  LineSource lines = LineSource::FromText(text);
  Block block;
  std::string_view line, eol;
  int percent = 0;
  Status status;
  while (lines.Next(&line, &eol)) {
    status = reader.Read(line, &block);
    if (!status.ok()) break;
    if (block.percent && ++percent == 2) break;
    if (block.motion != Motion::kNone) {
      PathMove m;
      m.line = block.line;
      m.motion = block.motion;
      m.start = block.start;
      m.end = block.end;
      m.start_known = block.start_known;
      m.end_known = block.end_known;
      m.has_arc = block.has_arc;
      m.arc = block.arc;
      m.feed = block.feed;
      m.units = block.units;
      m.rotary = block.rotary;
      m.rotary_known = block.rotary_known;
      m.cutter_comp = block.cutter_comp != 40;
      if (!block.comments.empty()) {
        const auto [b, e] = block.comments.front();
        std::string_view c = block.text.substr(b, e - b);
        if (!c.empty() && (c.front() == '(' || c.front() == ';')) c.remove_prefix(1);
        if (!c.empty() && c.back() == ')') c.remove_suffix(1);
        m.comment = std::string(c);
      }
      path->moves.push_back(std::move(m));
    }
    if (block.program_end) break;
  }
  path->report = reader.report();
  FL_RETURN_IF_ERROR(status);
  return lines.status();
}

Result<ProgramPath> ReadProgramPath(std::string_view text, const ReaderOptions& options, const std::string& source) {
  ProgramPath path;
  FL_RETURN_IF_ERROR(ReadProgramPathInto(text, options, source, &path));
  return path;
}

}  // namespace formloop::nc
