#include "nc-gen/gcode_reader.h"

#include <algorithm>
#include <cctype>
#include <charconv>
#include <cmath>
#include <cstring>

#include "core/point_io.h"

namespace formloop::nc {
namespace {

constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();

bool IsSpace(char c) { return c == ' ' || c == '\t' || c == '\r' || c == '\f' || c == '\v'; }
bool IsDigit(char c) { return c >= '0' && c <= '9'; }
bool IsAlpha(char c) { return (c >= 'A' && c <= 'Z') || (c >= 'a' && c <= 'z'); }
char Upper(char c) { return (c >= 'a' && c <= 'z') ? static_cast<char>(c - 'a' + 'A') : c; }

}  // namespace

int GTenths(double g) { return static_cast<int>(std::lround(g * 10)); }

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
    if (GTenths(g) == GTenths(code)) return true;
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
  block->tcp = GTenths(length_comp_) == 434 || GTenths(length_comp_) == 435;
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
