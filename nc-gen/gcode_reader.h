#pragma once
// One reader for word-address NC programs: RS274NGC as LinuxCNC reads it (LinuxCNC G-code reference,
// "Overview", "G Codes", "M Codes"; NIST RS274NGC version 3, Kramer et al. 2000) and Fanuc-style ISO
// programs (Fanuc Series 0i-MF / 30i-B operator's manuals, "Program configuration", "Decimal point
// programming"). Every program formloop reads is read here: the shop's own finishing programs, the
// programs formloop's posts write (ReadProgram in post.h), and the input of `nc distribute` and
// `nc compensate --program` (spec/path-deviation.md §1, §3).
//
// What is modelled (the tool-tip path in work coordinates, program units):
//   motion     G0 G1 G2 G3 (centre I/J/K or R form, full circles, helices along the plane's normal,
//              LinuxCNC's P turn count), modal motion (a block with only coordinates repeats it);
//   modes      G17/G18/G19 planes, G20/G21 units, G90/G91 distance, G90.1/G91.1 arc centre mode,
//              G93/G94/G95 feed modes, F/S/T/M/N/O words, G40-G42 and G43/G44/G49 state (the
//              programmed contour is the path: compensation is not applied), G43.4/G43.5 tool centre
//              point control, G54-G59.3 selection, G61/G64 path control, G4 dwell, G80, G98/G99;
//   numbers    with or without a decimal point; without one, Fanuc reads axis and centre words in least
//              input increments (X50 = 0.050 mm on IS-B) and LinuxCNC in units (NoPointUnit);
//   text       ( ) and ';' comments, block delete '/', '%' lines, N line numbers, rotary axes A/B/C
//              (passed through, their value tracked).
// What is recognised but not modelled is reported, never dropped: each such word becomes a Note with
// its line (ReadReport), and the axes whose value it makes unknown are marked unknown until the program
// states them again (reference returns G28/G30, machine coordinates G53, frame changes G10/G52/G92 and
// a change of work coordinate system, canned cycles G73-G89, probing G38.x, splines, polar
// coordinates, scaling, mirroring, rotation, macro variables '#', expressions '[...]', O-word control
// flow and sub-programs M98/M99/G65/G66, Fanuc ',R'/',C' corner words, extra axes U/V/W). A word the
// reader does not know at all (an unknown G-code or letter) is a Note of kind kUnknown; a caller that
// writes a program from this one refuses those (ReaderOptions::unknown_is_error).
//
// Invalid geometry is an error, as in the controller (spec §3): an arc without centre words
// (E_ARC_NO_CENTRE), start and end radii differing by more than arc_radius_tolerance (E_ARC_RADIUS), an
// R-form chord longer than 2R (E_ARC_R), an R-form full circle (E_ARC_R_FULLCIRCLE), two motion codes in
// one block (E_MODAL_GROUP), a word without a number (E_SYNTAX), a word's number beyond ±kMaxWordValue
// (E_RANGE).
//
// Streaming: GcodeReader::Read takes one line at a time and keeps only the modal state, so a program of
// any length is read in constant memory (LineSource reads a file in chunks).

#include <array>
#include <cstdint>
#include <cstdio>
#include <filesystem>
#include <limits>
#include <map>
#include <string>
#include <string_view>
#include <vector>

#include <Eigen/Core>
#include <nlohmann/json.hpp>

#include "core/status.h"

namespace formloop::nc {

// The largest magnitude of a word's number (nine digits: 1,000 m in 0.001 mm increments; block numbers, codes
// and parameters are far smaller). Larger numbers are refused (E_RANGE) before any is converted to an integer.
inline constexpr double kMaxWordValue = 999999999;

enum class GcodeDialect {
  kRs274ngc,   // LinuxCNC: numbers without a point are units; ';' comments; O-words are control flow
  kFanuc,      // Fanuc 0i/30i: numbers without a point are least increments; O<n> / :<n> program numbers
  kSinumerik,  // Siemens 840D ISO words as formloop's post writes them: G70/G71 inch/mm, ';' comments
};
// "linuxcnc" (also "rs274ngc"), "fanuc" or "sinumerik".
Result<GcodeDialect> ParseGcodeDialect(std::string_view name);
const char* GcodeDialectName(GcodeDialect dialect);

// How a number without a decimal point is read in axis and centre words (spec table: no_point_unit).
enum class NoPointUnit {
  kDialect,         // kLeastIncrement for Fanuc, kUnit for RS274NGC
  kUnit,            // X50 = 50 mm (or inch)
  kLeastIncrement,  // X50 = 50 least increments (0.001 mm / 0.0001 inch on IS-B controls)
};

enum class Plane { kXY, kZX, kYZ };  // G17, G18, G19: (u, v, w) = (X, Y, Z), (Z, X, Y), (Y, Z, X)
enum class Units { kMm, kInch };
enum class Motion { kNone, kRapid, kLinear, kArcCw, kArcCcw };
enum class FeedMode { kUnitsPerMinute, kInverseTime, kUnitsPerRevolution };  // G94, G93, G95

// Axis indices of the plane's (u, v, w) in (X, Y, Z), and of the centre words (I, J, K).
struct PlaneAxes {
  int u, v, w;
};
PlaneAxes AxesOf(Plane plane);
const char* PlaneCode(Plane plane);  // "G17", "G18", "G19"

constexpr double kMmPerInch = 25.4;

struct ReaderOptions {
  GcodeDialect dialect = GcodeDialect::kRs274ngc;
  NoPointUnit no_point = NoPointUnit::kDialect;
  // Least input increment for numbers without a point (kLeastIncrement): IS-B is 0.001 mm, 0.0001 inch.
  double least_increment_mm = 0.001;
  double least_increment_inch = 0.0001;
  // Largest |r_start − r_end| of a centre-form arc, mm (spec tol_r). Where start and end radii differ
  // within it the arc is the spiral from one radius to the other (as LinuxCNC runs it), so both ends stay
  // exact. Programs printed with 3 decimals in inches need about 0.02 mm.
  double arc_radius_tolerance_mm = 0.002;
  // Block delete switch: true skips blocks starting with '/', false (the default, switch off) reads them.
  bool block_delete = false;
  // M-codes that a caller gives a meaning (the deviation markers M57/M58/M59 of `nc distribute`): they
  // are not reported as unknown.
  std::vector<int> caller_m_codes;
  Status Validate() const;
};

// One word as it stands in the line.
struct Word {
  char letter = 0;                   // upper case
  double value = 0;                  // as written (before unit or least-increment scaling)
  std::uint32_t begin = 0, end = 0;  // byte span of the whole word (letter .. last digit) in the line
  bool has_point = false;            // the number has a decimal point
  bool expression = false;           // '#..' or '[..]': value unknown
};

// What a note says about a word.
enum class NoteKind {
  kUnmodelled,  // recognised; its effect on the path is not computed (named in `what`)
  kUnknown,     // not a word this reader knows
  // Cutter radius compensation G41/G42: the programmed contour is read; the controller offsets it by the
  // tool radius, so the tool-centre path differs from the path read here.
  kCompensation,
};

struct Note {
  long line = 0;
  NoteKind kind = NoteKind::kUnmodelled;
  std::string word;  // "G28", "#", "O", "M98", ",R", "U"
  std::string what;  // "reference return: position after it unknown"
};

// Every note of a program, counted per word, with the first lines of each (memory bounded).
struct ReadReport {
  static constexpr std::size_t kLinesPerWord = 20;
  struct Entry {
    NoteKind kind = NoteKind::kUnmodelled;
    std::string what;
    std::size_t count = 0;
    std::vector<long> first_lines;
  };
  std::map<std::string, Entry> words;  // by word
  std::size_t lines = 0, blocks = 0, motion_blocks = 0, arcs = 0, skipped_blocks = 0;
  std::size_t notes() const;
  std::size_t unknown() const;
  void Add(const Note& note);
  nlohmann::json ToJson() const;
};

// An arc or helix in absolute work coordinates, program units. At λ ∈ [0, 1] of its length the point
// is at angle θ_s ± λφ about the centre, radius r_s + λ(r_e − r_s), height w_s + λh.
struct ArcGeometry {
  Plane plane = Plane::kXY;
  bool ccw = true;                                  // G3
  Eigen::Vector3d start = Eigen::Vector3d::Zero();  // X, Y, Z
  Eigen::Vector3d end = Eigen::Vector3d::Zero();
  Eigen::Vector3d centre = Eigen::Vector3d::Zero();  // u, v of the centre; w = start's w
  double radius_start = 0, radius_end = 0;
  double sweep_rad = 0;  // φ > 0, full turns included
  double theta_start_rad = 0;
  double rise = 0;  // h = E_w − S_w
  double radius() const { return 0.5 * (radius_start + radius_end); }
  // spec §3: L = sqrt((r φ)² + h²), r the mean radius.
  double Length() const;
  Eigen::Vector3d PointAt(double lambda) const;
  // Unit tangent at λ (direction of travel).
  Eigen::Vector3d TangentAt(double lambda) const;
};

// A G number in tenths, the form G-codes are compared in: G90.1 -> 901, G1 -> 10.
int GTenths(double g);

// One block as read, with the modal state after it.
struct Block {
  long line = 0;               // 1-based line number
  std::string_view text;       // the line without its terminator (valid until the next Read)
  bool skipped = false;        // block delete on and the line starts with '/'
  bool slash = false;          // the line starts with '/' (an optional block)
  bool percent = false;        // a '%' line
  long n_word = -1;            // N number, -1 when none
  std::uint32_t head_end = 0;  // end of the block's head: leading blanks, '/' and the N word
  std::vector<Word> words;     // in order (comments excluded)
  std::vector<std::pair<std::uint32_t, std::uint32_t>> comments;  // byte spans including delimiters
  std::vector<int> m_codes;                                       // M numbers in the block
  std::vector<double> g_codes;                                    // G numbers in the block
  std::vector<Note> notes;                                        // what this block reports

  // The motion of this block (kNone when it moves nothing).
  Motion motion = Motion::kNone;
  bool explicit_motion = false;                                                    // the block has a G0/G1/G2/G3 word
  Eigen::Vector3d start = Eigen::Vector3d::Zero(), end = Eigen::Vector3d::Zero();  // X, Y, Z
  unsigned start_known = 0, end_known = 0;                                         // axis masks (bit a = axis a known)
  unsigned xyz_words = 0;  // which of X, Y, Z the block programs
  ArcGeometry arc;         // when motion is an arc and its start is known
  bool has_arc = false;
  std::array<double, 3> rotary{};  // A, B, C after the block
  unsigned rotary_known = 0, rotary_words = 0;
  bool rotary_moved = false;  // an A/B/C word changed a rotary value

  // Modal state after the block.
  Motion modal_motion = Motion::kNone;
  Plane plane = Plane::kXY;
  Units units = Units::kMm;
  bool incremental = false;   // G91
  bool arc_absolute = false;  // G90.1
  FeedMode feed_mode = FeedMode::kUnitsPerMinute;
  double feed = 0;  // program units per minute (or as the feed mode says)
  bool has_feed_word = false;
  int cutter_comp = 40;      // 40, 41, 42
  double length_comp = 49;   // 43, 43.1, 43.4, 43.5, 44, 49
  bool tcp = false;          // G43.4 / G43.5 active
  int work_system = 54;      // 54..59 (59.1..59.3 as 591..593), Fanuc G54.1 Pn as 5410 + n
  bool program_end = false;  // M2 / M30 (or a closing '%')
  // Transforms that make the frame unknown while active (polar, scaling, mirroring, rotation).
  bool transform_active = false;
  bool cycle_active = false;  // a canned cycle is modal (G73-G89 until G80)

  // Length units to mm (1 or 25.4).
  double mm_per_unit() const { return units == Units::kInch ? kMmPerInch : 1.0; }
  const Word* Find(char letter) const;
  bool HasM(int code) const;
  bool HasG(double code) const;
  // The path length of the motion, mm (0 when it moves nothing or its ends are unknown): line
  // ||E − S|| over X, Y, Z; arc ArcGeometry::Length.
  double LengthMm() const;
  bool ends_known() const { return start_known == 7u && end_known == 7u; }
};

// Reads one line at a time; keeps the modal state between lines.
class GcodeReader {
 public:
  explicit GcodeReader(ReaderOptions options = {}, std::string source = "program");

  // Reads `line` (without its terminator) as the next block. On error (invalid geometry or syntax,
  // codes E_*), the Status names the source and line; the reader should not be used further.
  Status Read(std::string_view line, Block* block);

  const ReadReport& report() const { return report_; }
  const std::string& source() const { return source_; }
  const ReaderOptions& options() const { return options_; }
  // The position after the last block (program units) and which axes are known.
  const Eigen::Vector3d& position() const { return position_; }
  unsigned position_known() const { return known_; }

 private:
  Status Fail(long line, const std::string& code, const std::string& what, const std::string& fix) const;
  double Scale(const Word& word, bool distance) const;
  void Note(Block* block, NoteKind kind, std::string word, std::string what);
  Status Lex(std::string_view line, Block* block);
  Status Interpret(Block* block);
  Status Arc(Block* block, const Eigen::Vector3d& target, unsigned target_known);
  void SetUnits(Units units);

  ReaderOptions options_;
  std::string source_;
  ReadReport report_;
  long line_ = 0;
  // Modal state.
  Eigen::Vector3d position_ = Eigen::Vector3d::Zero();
  unsigned known_ = 0;
  std::array<double, 3> rotary_{};
  unsigned rotary_known_ = 0;
  Motion modal_motion_ = Motion::kNone;
  Plane plane_ = Plane::kXY;
  Units units_ = Units::kMm;
  bool incremental_ = false, arc_absolute_ = false;
  FeedMode feed_mode_ = FeedMode::kUnitsPerMinute;
  double feed_ = 0;
  int cutter_comp_ = 40;
  double length_comp_ = 49;
  int work_system_ = 54;
  // Work offsets G54..G59.3 as far as the program sets them (G10 L2); bit a of offset_known_ = axis a.
  std::array<Eigen::Vector3d, 9> offsets_{};
  std::array<unsigned, 9> offset_known_{};
  bool polar_ = false, scaling_ = false, mirror_ = false, rotation_ = false;
  bool cycle_ = false;
};

// A file read in chunks, one line at a time (terminators "\n", "\r\n" or none at the end of the file).
class LineSource {
 public:
  static Result<LineSource> Open(const std::filesystem::path& path);
  // A text in memory (tests, ReadProgram).
  static LineSource FromText(std::string_view text);
  LineSource(LineSource&&) noexcept;
  LineSource& operator=(LineSource&&) noexcept;
  ~LineSource();
  // The next line without its terminator; `eol` receives the terminator. False at the end.
  bool Next(std::string_view* line, std::string_view* eol);
  // Non-ok after a read error.
  const Status& status() const { return status_; }

 private:
  LineSource() = default;
  bool Fill();
  std::FILE* file_ = nullptr;
  std::string path_;
  std::string buffer_;
  std::string_view text_;  // FromText
  std::size_t begin_ = 0, end_ = 0;
  bool eof_ = false, in_memory_ = false;
  Status status_;
};

// Shortest decimal text of `value` rounded to `decimals` places, halves away from zero, always with a
// decimal point and no trailing zeros: 50.0015, 200., 0., -0.5 (spec §2 "Number format", §5 "Rounding").
std::string FormatCoordinate(double value, int decimals);
// The value FormatCoordinate prints, as a double.
double RoundCoordinate(double value, int decimals);

// Reads a whole program text and returns every block's motion (tests and small programs; large files go
// through LineSource + GcodeReader).
struct PathMove {
  long line = 0;
  Motion motion = Motion::kNone;
  Eigen::Vector3d start = Eigen::Vector3d::Zero(), end = Eigen::Vector3d::Zero();
  unsigned start_known = 0, end_known = 0;
  bool has_arc = false;
  ArcGeometry arc;
  double feed = 0;
  Units units = Units::kMm;
  std::array<double, 3> rotary{};
  unsigned rotary_known = 0;
  bool cutter_comp = false;  // G41/G42 active: the controller's path is offset from this one
  std::string comment;       // the first comment of the block, without delimiters
};
struct ProgramPath {
  std::vector<PathMove> moves;
  ReadReport report;
};
Result<ProgramPath> ReadProgramPath(std::string_view text, const ReaderOptions& options, const std::string& source);
// The same, keeping what was read before an error in *path (its moves and report).
Status ReadProgramPathInto(std::string_view text, const ReaderOptions& options, const std::string& source,
                           ProgramPath* path);

}  // namespace formloop::nc
