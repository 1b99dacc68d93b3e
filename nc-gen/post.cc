#include "nc-gen/post.h"

#include <algorithm>
#include <cctype>
#include <cmath>
#include <utility>

#include "core/number_text.h"
#include "nc-gen/post_text.h"

namespace formloop::nc {

Status MachineLimits::Validate() const {
  for (int a = 0; a < 3; ++a) {
    if (!(travel_min_mm[a] < travel_max_mm[a])) {
      return Status::BadInput(Where{.field = "machine.travel"}, "travel_min must be below travel_max on every axis");
    }
  }
  if (!(max_feed_mm_per_min > 0)) return Status::BadInput(Where{.field = "machine.max_feed_mm_per_min"}, "must be > 0");
  if (!(max_spindle_rpm > 0)) return Status::BadInput(Where{.field = "machine.max_spindle_rpm"}, "must be > 0");
  return Status::Ok();
}

nlohmann::json MachineLimits::ToJson() const {
  return {{"travel_min_mm", {travel_min_mm.x(), travel_min_mm.y(), travel_min_mm.z()}},
          {"travel_max_mm", {travel_max_mm.x(), travel_max_mm.y(), travel_max_mm.z()}},
          {"max_feed_mm_per_min", max_feed_mm_per_min},
          {"max_spindle_rpm", max_spindle_rpm}};
}

bool WithinTravel(const MachineLimits& limits, const Eigen::Vector3d& tip) {
  for (int a = 0; a < 3; ++a) {
    if (tip[a] < limits.travel_min_mm[a] || tip[a] > limits.travel_max_mm[a]) return false;
  }
  return true;
}

Status CheckTravel(const MachineLimits& limits, const Eigen::Vector3d& tip, const std::string& what) {
  static const char* kAxis[] = {"X", "Y", "Z"};
  for (int a = 0; a < 3; ++a) {
    if (tip[a] < limits.travel_min_mm[a] || tip[a] > limits.travel_max_mm[a]) {
      return Status::SafetyLimit(what + ": " + kAxis[a] + " " + FormatFixed(tip[a], 4) + " mm is outside the travel " +
                                 FormatFixed(limits.travel_min_mm[a], 3) + " .. " +
                                 FormatFixed(limits.travel_max_mm[a], 3) +
                                 " mm; no program was written. Fix: the program is in Q's coordinates (the CAD "
                                 "file's frame): place the part within the travel (the face in the machine's set-up "
                                 "frame), or give the machine's real travel (machine.travel_min_mm/travel_max_mm, "
                                 "--travel-mm) if these limits are not the machine's");
    }
  }
  return Status::Ok();
}

Status PostOptions::Validate() const {
  // Beyond 6 decimals (1 nm) no controller resolves; 0 decimals would make Fanuc read X10 as 10 µm.
  if (decimals < 1 || decimals > 6) return Status::BadInput(Where{.field = "post.decimals"}, "must be 1..6");
  if (block_start < 0 || block_increment < 1) {
    return Status::BadInput(Where{.field = "post.block_start"}, "block numbers need start >= 0 and increment >= 1");
  }
  if (max_line_length != 0 && max_line_length < 16) {
    return Status::BadInput(Where{.field = "post.max_line_length"}, "must be 0 (no limit) or at least 16");
  }
  if (program_number < 1 || program_number > 9999) {
    return Status::BadInput(Where{.field = "post.program_number"}, "must be 1..9999 (Fanuc O-number)");
  }
  if (program_name.empty()) return Status::BadInput(Where{.field = "post.program_name"}, "must not be empty");
  for (char c : program_name) {
    if (!std::isalnum(static_cast<unsigned char>(c)) && c != '_') {
      return Status::BadInput(Where{.field = "post.program_name"},
                              "'" + program_name + "' has a character other than letters, digits and '_'",
                              "Heidenhain program names are file names");
    }
  }
  return limits.Validate();
}

namespace {

const std::vector<std::unique_ptr<PostDialect>>& Registry() {
  // The registry: one line per dialect. Order is the order PostNames reports.
  static const auto* registry = [] {
    auto* r = new std::vector<std::unique_ptr<PostDialect>>;
    r->push_back(internal::MakeLinuxCncPost());
    r->push_back(internal::MakeFanucPost());
    r->push_back(internal::MakeHeidenhainPost());
    r->push_back(internal::MakeSinumerikPost());
    return r;
  }();
  return *registry;
}

Status UnknownDialect(std::string_view name) {
  std::string known;
  for (const auto& n : PostNames()) known += (known.empty() ? "" : ", ") + n;
  return Status::BadInput(Where{.field = "post.dialect"}, "unknown post dialect '" + std::string(name) + "'",
                          "use one of " + known);
}

}  // namespace

std::vector<std::string> PostNames() {
  std::vector<std::string> names;
  for (const auto& d : Registry()) names.emplace_back(d->Name());
  return names;
}

const PostDialect* FindPost(std::string_view name) {
  for (const auto& d : Registry()) {
    if (d->Name() == name) return d.get();
  }
  return nullptr;
}

Status PostDialect::CheckDecimals(int decimals, const std::string& field) const {
  if (decimals <= MaxDecimals()) return Status::Ok();
  return Status::BadInput(Where{.field = field},
                          std::string(Name()) + " takes at most " + std::to_string(MaxDecimals()) +
                              " coordinate decimals, got " + std::to_string(decimals),
                          "use " + std::to_string(DefaultDecimals()) + " (the dialect's default)");
}

Result<std::string> Post(const MoveSequence& moves, std::string_view dialect, const PostOptions& options) {
  const PostDialect* post = FindPost(dialect);
  if (post == nullptr) return UnknownDialect(dialect);
  FL_RETURN_IF_ERROR(options.Validate());
  FL_RETURN_IF_ERROR(post->CheckDecimals(options.decimals, "post.decimals"));
  // Safety first, once for every dialect: nothing is formatted unless every position and rate is within limits.
  FL_RETURN_IF_ERROR(CheckMoveList(moves, options.limits));
  return post->Format(moves, options);
}

Result<std::string> Post(const MoveList& list, std::string_view dialect, const PostOptions& options) {
  return Post(HeldMoves(list), dialect, options);
}

Result<std::vector<ProgramMove>> ReadProgram(const std::string& text, std::string_view dialect,
                                             const std::string& source) {
  const PostDialect* post = FindPost(dialect);
  if (post == nullptr) return UnknownDialect(dialect);
  return post->Read(text, source);
}

Result<std::string> PostLinuxCnc(const Toolpath& path, const PostOptions& options) {
  FL_ASSIGN_OR_RETURN(const ToolpathMoves moves, ToolpathMoves::Of(path));
  return Post(moves, "linuxcnc", options);
}

Result<std::vector<ProgramMove>> ReadLinuxCncMoves(const std::string& text, const std::string& source) {
  return ReadProgram(text, "linuxcnc", source);
}

namespace internal {

ProgramText::ProgramText(const PostOptions& options, Numbering numbering, std::string comment_open,
                         std::string comment_close)
    : options_(options),
      numbering_(numbering),
      comment_open_(std::move(comment_open)),
      comment_close_(std::move(comment_close)),
      next_number_(numbering == Numbering::kAllLines ? 0 : options.block_start) {}

std::string ProgramText::NumberPrefix(bool numbered) {
  if (numbering_ == Numbering::kAllLines) return std::to_string(next_number_++) + " ";
  if (!numbered || !options_.block_numbers) return "";
  const long n = next_number_;
  next_number_ += options_.block_increment;
  return "N" + std::to_string(n) + " ";
}

void ProgramText::Emit(std::string_view text, bool numbered) {
  const std::string prefix = NumberPrefix(numbered);
  ++lines_;
  const std::size_t limit = static_cast<std::size_t>(options_.max_line_length);
  const std::size_t size = prefix.size() + text.size();
  if (limit > 0 && size > limit && error_.ok()) {
    const std::string line = prefix + std::string(text);
    error_ =
        Status::BadInput(Where{.line = lines_, .field = "post.max_line_length"},
                         "program line '" + line + "' is " + std::to_string(size) + " characters, over the limit of " +
                             std::to_string(limit) + "; no program was written",
                         "raise max_line_length or use fewer decimals or no block numbers");
  }
  out_ += prefix;
  out_ += text;
  out_ += '\n';
}

void ProgramText::Raw(std::string_view text) { Emit(text, false); }
void ProgramText::Continuation(std::string_view text) {
  const Numbering numbering = numbering_;
  numbering_ = Numbering::kBlocks;  // unnumbered in either scheme: Emit(.., false) adds no number for kBlocks
  Emit("    " + std::string(text), false);
  numbering_ = numbering;
}
void ProgramText::Block(std::string_view text) { Emit(text, true); }

void ProgramText::Append(const LineBatch& batch) {
  std::size_t begin = 0;
  for (std::size_t i = 0; i < batch.ends_.size(); ++i) {
    const std::string_view line(batch.text_.data() + begin, batch.ends_[i] - begin);
    if (batch.comment_[i]) {
      Comment(line);
    } else {
      Block(line);
    }
    begin = batch.ends_[i];
  }
}

void LineBatch::Add(std::string_view text, bool comment) {
  text_ += text;
  ends_.push_back(text_.size());
  comment_.push_back(comment);
}

void LineBatch::Clear() {
  text_.clear();
  ends_.clear();
  comment_.clear();
}

void ProgramText::Comment(std::string_view text) {
  const bool numbered = numbering_ == Numbering::kAllLines;
  const std::size_t limit = static_cast<std::size_t>(options_.max_line_length);
  // Room for the text on one line: the limit less the delimiters and the widest number the line can get.
  const std::size_t number_width =
      numbered ? std::to_string(next_number_ + 1000).size() + 1 : 0;  // generous: numbers grow while wrapping
  const std::size_t frame = comment_open_.size() + comment_close_.size() + number_width;
  if (limit == 0 || text.size() + frame <= limit || limit <= frame + 8) {
    Emit(comment_open_ + std::string(text) + comment_close_, numbered);
    return;
  }
  const std::size_t room = limit - frame;
  std::string rest(text);
  while (!rest.empty()) {
    std::size_t cut = rest.size();
    if (cut > room) {
      cut = rest.rfind(' ', room);
      if (cut == std::string::npos || cut == 0) cut = room;  // one long word: split it
    }
    Emit(comment_open_ + rest.substr(0, cut) + comment_close_, numbered);
    rest = rest.substr(cut);
    while (!rest.empty() && rest.front() == ' ') rest.erase(rest.begin());
  }
}

std::string ProgramText::Num(double value) const { return FormatFixed(value, options_.decimals); }

Result<std::string> ProgramText::Finish() {
  if (!error_.ok()) return error_;
  return std::move(out_);
}

std::string PlainComment(const std::string& text) {
  std::string out = text;
  for (char& c : out) {
    if (static_cast<unsigned char>(c) < 0x20) c = ' ';
  }
  return out;
}

namespace {

// The modal state of a word-address body before a move.
struct WordAddressState {
  double feed = -1;             // the feed in effect (-1: none yet)
  bool offset_written = false;  // the length offset has been programmed
};

}  // namespace

Status WriteWordAddressBody(const MoveSequence& moves, const std::string& rapid, const std::string& feed,
                            std::string (*comment)(const std::string&), ProgramText* w,
                            const std::string& length_offset) {
  w->Reserve(32 * moves.Size());  // "G1 X-123.4567 Y-123.4567 Z-12.3456" and a newline is about 32
  const auto format = [&](const Move& m, std::size_t, const WordAddressState& s, LineBatch* out) {
    switch (m.type) {
      case MoveType::kComment:
        out->Comment(comment(m.text));
        break;
      case MoveType::kRapid:
        out->Block(rapid + " " + (s.offset_written ? "" : length_offset + " ") + AxisWords(*w, m));
        break;
      case MoveType::kSetFeed:
        out->Block("F" + FormatFixed(m.feed_mm_per_min, 0));
        break;
      case MoveType::kFeed: {
        std::string block = feed + " " + AxisWords(*w, m);
        if (m.feed_mm_per_min != s.feed) block += " F" + FormatFixed(m.feed_mm_per_min, 0);
        out->Block(block);
        break;
      }
    }
  };
  const auto advance = [](WordAddressState* s, const Move& m) {
    if (m.type == MoveType::kRapid) s->offset_written = true;
    if (m.type == MoveType::kSetFeed || m.type == MoveType::kFeed) s->feed = m.feed_mm_per_min;
  };
  return FormatMovesInChunks(moves, WordAddressState{.offset_written = length_offset.empty()}, format, advance, w);
}

std::size_t LineCount(const std::string& text) {
  const auto newlines = static_cast<std::size_t>(std::count(text.begin(), text.end(), '\n'));
  return newlines + (!text.empty() && text.back() != '\n');
}

std::string LengthOffsetWords(int tool) { return "G43 H" + std::to_string(tool); }

std::string AxisWords(const ProgramText& w, const Move& move, const std::string& separator) {
  static const char kAxis[] = {'X', 'Y', 'Z'};
  std::string out;
  for (int a = 0; a < 3; ++a) {
    if ((move.axes & (1u << a)) == 0) continue;
    if (!out.empty()) out += ' ';
    out += kAxis[a] + separator + w.Num(move.tip[a]);
  }
  return out;
}

Result<std::vector<ProgramMove>> ReadWordAddress(const std::string& text, const std::string& source,
                                                 const WordDialect& dialect) {
  const std::string fix = "only formloop's own " + dialect.name + " output can be read back";
  ReaderOptions options;
  options.dialect = dialect.gcode;
  GcodeReader reader(options, source);
  LineSource lines = LineSource::FromText(text);
  Block block;
  std::string_view line, eol;
  std::vector<ProgramMove> moves;
  moves.reserve(LineCount(text));  // at most a move per line: allocated once, not grown by doubling
  int percent = 0;
  while (lines.Next(&line, &eol)) {
    FL_RETURN_IF_ERROR(reader.Read(line, &block));
    if (block.percent && ++percent == 2) break;
    const Where where{.file = source, .line = block.line};
    if (!block.notes.empty()) {
      return Status::BadInput(
          where, "unsupported word '" + block.notes.front().word + "' (" + block.notes.front().what + ")", fix);
    }
    if (block.units != Units::kMm || block.incremental) {
      return Status::BadInput(where, "inch or incremental programming is not supported",
                              "program in millimetres and absolute coordinates");
    }
    if (block.motion == Motion::kArcCw || block.motion == Motion::kArcCcw) {
      return Status::BadInput(where, "arc: formloop's own programs are straight moves",
                              fix + " (programs with arcs: nc compensate --program, nc distribute)");
    }
    if (block.motion == Motion::kNone) continue;
    ProgramMove m{
        .rapid = block.motion == Motion::kRapid, .tip = block.end, .line = block.line, .feed_mm_per_min = block.feed};
    moves.push_back(m);
  }
  return moves;
}

}  // namespace internal
}  // namespace formloop::nc
