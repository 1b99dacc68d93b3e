#pragma once
// Shared pieces of the posts (internal to nc-gen): a line writer that numbers blocks, wraps comments and
// enforces the line-length limit, and the read-back of the ISO word-address dialects (LinuxCNC, Fanuc,
// Sinumerik) through the one G-code reader.

#include <algorithm>
#include <cstddef>
#include <memory>
#include <string>
#include <string_view>
#include <vector>

#include "core/parallel.h"
#include "core/status.h"
#include "nc-gen/gcode_reader.h"
#include "nc-gen/post.h"
#include "nc-gen/probe_program.h"

namespace formloop::nc::internal {

enum class Numbering {
  kBlocks,    // "N<n> " on blocks when PostOptions::block_numbers (ISO dialects); comments never numbered
  kAllLines,  // "<n> " on every line from 0 in steps of 1 (Heidenhain: numbers are part of the syntax)
};

class LineBatch;

class ProgramText {
 public:
  // A comment line is comment_open + text + comment_close.
  ProgramText(const PostOptions& options, Numbering numbering, std::string comment_open, std::string comment_close);
  void Raw(std::string_view text);      // never numbered in kBlocks ('%', "O1234", ...)
  void Block(std::string_view text);    // an NC block
  void Comment(std::string_view text);  // sanitised text; wrapped at spaces to fit the line length
  // A continuation line of the block before, never numbered, indented by four spaces (Heidenhain's
  // multi-line cycle blocks).
  void Continuation(std::string_view text);
  // The blocks and comments of a batch, in order, as if written here one by one (numbers, wrapping and the
  // line-length check are done here).
  void Append(const LineBatch& batch);
  // Room for `bytes` more characters, allocated once (a million-line program).
  void Reserve(std::size_t bytes) { out_.reserve(out_.size() + bytes); }
  // The coordinate value with PostOptions::decimals; never "-0.000".
  std::string Num(double value) const;
  // The program (moved out: call once, last), or the first line-length refusal.
  Result<std::string> Finish();

 private:
  std::string NumberPrefix(bool numbered);
  void Emit(std::string_view text, bool numbered);
  const PostOptions& options_;
  Numbering numbering_;
  std::string comment_open_, comment_close_;
  std::string out_;
  long next_number_ = 0;
  long lines_ = 0;
  Status error_ = Status::Ok();
};

// Blocks and comments formatted away from the program (a chunk of moves on a worker thread), without
// their numbers: ProgramText::Append writes them in order.
class LineBatch {
 public:
  void Block(std::string_view text) { Add(text, false); }
  void Comment(std::string_view text) { Add(text, true); }  // sanitised text, wrapped when appended
  void Clear();

 private:
  friend class ProgramText;
  void Add(std::string_view text, bool comment);
  std::string text_;               // the lines one after another
  std::vector<std::size_t> ends_;  // end of each line in text_
  std::vector<bool> comment_;      // each line a comment (else a block)
};

// Moves per chunk of the parallel posts: fixed, so the chunks and the bytes never depend on the threads.
inline constexpr long kPostChunk = 4096;
// Moves held at a time: this many chunks (a few MB; the program text itself is the big buffer).
inline constexpr long kPostBatchChunks = 8;

// Formats the moves on every core (core/parallel.h), the same bytes as one move after the other: the moves
// are collected in order into batches of kPostBatchChunks fixed chunks; the modal state before each chunk
// comes from the moves before it (advance, a walk over the batch), then the chunks are formatted in
// parallel into LineBatches and appended to `w` in order. format(move, index, state before the move, out)
// writes the move's lines; advance(&state, move) is the modal state after it.
template <typename State, typename FormatMove, typename Advance>
Status FormatMovesInChunks(const MoveSequence& moves, State state, const FormatMove& format, const Advance& advance,
                           ProgramText* w) {
  const std::size_t chunk = static_cast<std::size_t>(kPostChunk);
  const std::size_t batch_size = chunk * static_cast<std::size_t>(kPostBatchChunks);
  std::vector<Move> batch;
  batch.reserve(std::min(batch_size, moves.Size()));
  std::vector<LineBatch> lines(static_cast<std::size_t>(kPostBatchChunks));
  std::vector<State> before(static_cast<std::size_t>(kPostBatchChunks), state);
  std::size_t first_index = 0;  // the sequence index of batch[0]
  const auto flush = [&] {
    for (std::size_t i = 0; i < batch.size(); ++i) {
      if (i % chunk == 0) before[i / chunk] = state;
      advance(&state, batch[i]);
    }
    ParallelFor(static_cast<long>(batch.size()), kPostChunk, [&](long begin, long end) {
      const std::size_t c = static_cast<std::size_t>(begin) / chunk;
      State s = before[c];
      for (long i = begin; i < end; ++i) {
        const Move& m = batch[static_cast<std::size_t>(i)];
        format(m, first_index + static_cast<std::size_t>(i), s, &lines[c]);
        advance(&s, m);
      }
    });
    for (std::size_t c = 0; c * chunk < batch.size(); ++c) {
      w->Append(lines[c]);
      lines[c].Clear();
    }
    first_index += batch.size();
    batch.clear();
  };
  FL_RETURN_IF_ERROR(moves.ForEach([&](std::size_t, const Move& m) {
    batch.push_back(m);
    if (batch.size() == batch_size) flush();
    return Status::Ok();
  }));
  flush();
  return Status::Ok();
}

// Lines of a program text (the last without a newline counts): a bound on its moves.
std::size_t LineCount(const std::string& text);

// Axis words of a motion block: "X1.000 Y2.000" for the axes in `axes`.
std::string AxisWords(const ProgramText& w, const Move& move, const std::string& separator = "");

// Comment text for ';'-comment dialects (Heidenhain, Sinumerik): control characters become spaces.
std::string PlainComment(const std::string& text);
// Comment text for Fanuc: upper case, only characters safe inside ( ), one space per run (post_fanuc.cc).
std::string FanucComment(const std::string& text);

// The body of a word-address program (LinuxCNC, Fanuc, Sinumerik): comment lines through `comment`
// (the dialect's sanitiser), rapids as `rapid` + axis words, feed moves as `feed` + axis words with F
// written only when it changes (modal), feed-only blocks as "F..". `length_offset` ("G43 H2"; empty for
// none) goes into the first rapid, the retract to safe Z, so the offset takes effect with a Z move away
// from the part, as Fanuc wants it ("G00 G43 H2 Z10.000"; LinuxCNC applies G43 before the motion of its block).
Status WriteWordAddressBody(const MoveSequence& moves, const std::string& rapid, const std::string& feed,
                            std::string (*comment)(const std::string&), ProgramText* w,
                            const std::string& length_offset = "");

// The words that activate tool length compensation for tool `tool` on LinuxCNC and Fanuc: "G43 H<tool>"
// (the length offset register numbered like the tool, the usual shop convention).
std::string LengthOffsetWords(int tool);

// The word-address reader's view of a dialect.
struct WordDialect {
  std::string name;  // "LinuxCNC", used in messages
  GcodeDialect gcode = GcodeDialect::kRs274ngc;
};

// formloop's own output read back through the one G-code reader (gcode_reader.h), held to what formloop
// writes: millimetres, absolute coordinates, straight moves, nothing the reader reports. Anything else is
// refused with its line, so a hand-edited program is never misread as formloop's.
Result<std::vector<ProgramMove>> ReadWordAddress(const std::string& text, const std::string& source,
                                                 const WordDialect& dialect);

// One probe point's positions (ball centre) for the probing posts (nc-gen/probe_program.h): above it at
// safe Z, the clearance start along +n, the search end along −n.
struct ProbeStation {
  std::int64_t id = 0;
  Eigen::Vector3d surface, normal, above, start, target;
  Eigen::Vector3d approach = -Eigen::Vector3d::UnitZ();  // unit, into the surface (−n unless tilted)
  bool tilted = false;
  double clearance_mm = 0;  // start − contact position along the approach (options.clearance_mm unless shortened)
};
// Every station of the plan, each position checked against the limits (SafetyLimit names the point id),
// after the options and the probe feed; with options.part_surface, each point's moves against the part
// (nc-gen/probe_clearance.h), a point's clearance shortened when that clears it.
Result<std::vector<ProbeStation>> ProbeStations(const metrology::ProbingPlan& plan, const ProbeProgramOptions& options);
// "stylus ball radius R mm; programmed point = ball centre; N points".
std::string ProbeHeader(const ProbeProgramOptions& options, std::size_t points);
// "X.. Y.. Z.." with the program's decimals.
std::string XyzWords(const ProgramText& w, const Eigen::Vector3d& p);

// Registry entries (one per dialect file).
std::unique_ptr<PostDialect> MakeLinuxCncPost();
std::unique_ptr<PostDialect> MakeFanucPost();
std::unique_ptr<PostDialect> MakeHeidenhainPost();
std::unique_ptr<PostDialect> MakeSinumerikPost();

}  // namespace formloop::nc::internal
