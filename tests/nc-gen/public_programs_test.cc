// The reader on programs nobody here wrote (issue 23, "What it must show" 3): public NC programs with
// arcs from public repositories, kept with their sources and licences in data/nc-programs/
// (README.md). For each program:
//   - formloop's reader reads it, and every word it does not model is in its report with its lines:
//     the test lists, per program, exactly which words those are (nothing else may appear, nothing
//     listed may be missing), and checks independently (its own scan of the text) that every letter
//     word of the program is one the reader handles or one it reported;
//   - where LinuxCNC's rs274 accepts the program, both paths agree move by move: the same motion kinds
//     in the same order, end points within half a unit of rs274's printed last decimal, and arcs at
//     λ = 1/4, 1/2, 3/4 within 2·10^-4 program units (rs274 prints centres with 4 decimals); moves under
//     cutter compensation are not compared (rs274 prints the offset path), axes the reader does not
//     know (before they are first programmed) neither;
//   - where rs274 refuses the program, the reader refuses it at the same block, or reads it and reports
//     what rs274 stopped at.

#include <algorithm>
#include <cctype>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <map>
#include <set>
#include <string>
#include <vector>

#include <gtest/gtest.h>

#include "core/atomic_file.h"
#include "nc-gen/gcode_reader.h"
#include "tests/support/rs274.h"

namespace formloop::nc {
namespace {

using testing::CanonKind;

const std::filesystem::path kData = std::filesystem::path(FORMLOOP_SOURCE_DIR) / "data" / "nc-programs";

struct Reading {
  std::vector<PathMove> moves;
  ReadReport report;
  Status status;
};

// Reads until the end or the first error, keeping the moves read so far.
Reading ReadUntilError(const std::string& text, const ReaderOptions& options, const std::string& source) {
  ProgramPath path;
  Reading r;
  r.status = ReadProgramPathInto(text, options, source, &path);
  r.moves = std::move(path.moves);
  r.report = std::move(path.report);
  return r;
}

// The test's own scan: every letter that starts a word outside comments, per line.
std::map<char, long> LettersOf(const std::string& text) {
  std::map<char, long> letters;
  bool comment = false;
  for (std::size_t i = 0; i < text.size(); ++i) {
    const char c = text[i];
    if (c == '\n') {
      comment = false;
      continue;
    }
    if (comment) {
      if (c == ')') comment = false;
      continue;
    }
    if (c == '(') {
      comment = true;
      continue;
    }
    if (c == ';') {
      while (i < text.size() && text[i] != '\n') ++i;
      --i;
      continue;
    }
    if (std::isalpha(static_cast<unsigned char>(c))) {
      ++letters[static_cast<char>(std::toupper(static_cast<unsigned char>(c)))];
    }
  }
  return letters;
}

// Every letter of the program is one the reader handles, or it was reported.
void ExpectEveryLetterHandledOrReported(const std::string& text, const std::set<std::string>& reported,
                                        const std::string& name) {
  static const std::string kHandled = "GMNXYZABCIJKRFSTPLHDO";
  for (const auto& [letter, count] : LettersOf(text)) {
    if (kHandled.find(letter) != std::string::npos) continue;
    EXPECT_TRUE(reported.count(std::string(1, letter)))
        << name << ": letter " << letter << " (" << count << " times) is neither handled nor reported";
  }
}

struct Agreement {
  std::size_t compared = 0, arcs = 0, skipped_compensation = 0;
  double max_end_difference = 0, max_arc_difference = 0;
};

Agreement CompareWithRs274(const std::vector<PathMove>& ours, const testing::Canon& canon, const std::string& name) {
  Agreement a;
  EXPECT_EQ(canon.unparsed_motion, 0) << name;
  EXPECT_EQ(ours.size(), canon.moves.size()) << name << ": formloop moves vs rs274 motions";
  int failures = 0;
  for (std::size_t k = 0; k < std::min(ours.size(), canon.moves.size()) && failures < 10; ++k) {
    const PathMove& m = ours[k];
    const testing::CanonMove& c = canon.moves[k];
    const std::string where = name + " line " + std::to_string(m.line) + " (canon line " + std::to_string(c.line) + ")";
    const CanonKind expected = m.motion == Motion::kRapid    ? CanonKind::kTraverse
                               : m.motion == Motion::kLinear ? CanonKind::kFeed
                                                             : CanonKind::kArc;
    if (c.kind != expected) {
      ADD_FAILURE() << where << ": rs274 " << testing::CanonKindName(c.kind) << ", formloop "
                    << testing::CanonKindName(expected);
      ++failures;
      continue;
    }
    if (m.cutter_comp) {
      ++a.skipped_compensation;
      continue;
    }
    ++a.compared;
    const double tol = 0.5 * std::pow(10.0, -c.decimals) + 1e-9;
    for (int axis = 0; axis < 3; ++axis) {
      if ((m.end_known & (1u << axis)) == 0) continue;
      const double d = std::abs(m.end[axis] - c.p[axis]);
      a.max_end_difference = std::max(a.max_end_difference, d);
      if (d > tol) {
        ADD_FAILURE() << where << " axis "
                      << "XYZ"[axis] << ": formloop " << m.end[axis] << ", rs274 " << c.p[axis];
        ++failures;
      }
    }
    if (c.kind == CanonKind::kArc) {
      EXPECT_TRUE(m.has_arc) << where << ": formloop did not model the arc";
      if (!m.has_arc || m.start_known != 7u) continue;
      ++a.arcs;
      for (double lambda : {0.25, 0.5, 0.75}) {
        const double d = (m.arc.PointAt(lambda) - c.ArcPoint(lambda)).norm();
        a.max_arc_difference = std::max(a.max_arc_difference, d);
        if (d > 2e-4) {
          ADD_FAILURE() << where << " at lambda " << lambda << ": formloop " << m.arc.PointAt(lambda).transpose()
                        << ", rs274 " << c.ArcPoint(lambda).transpose();
          ++failures;
        }
      }
    }
  }
  return a;
}

struct PublicProgram {
  std::string file;
  GcodeDialect dialect = GcodeDialect::kRs274ngc;
  std::set<std::string> reported;  // exactly the words the reader must report
  bool rs274_accepts = true;
  std::string reader_error;  // "" or the code the reader stops with
  long error_line = 0;
  std::string rs274_says;  // a phrase of rs274's refusal
};

void PrintTo(const PublicProgram& p, std::ostream* os) { *os << p.file; }

class PublicProgramTest : public ::testing::TestWithParam<PublicProgram> {};

TEST_P(PublicProgramTest, ReadReportedAndAgreesWithRs274) {
  const PublicProgram& p = GetParam();
  const auto text = ReadFile(kData / p.file);
  ASSERT_TRUE(text.ok()) << text.status().message();
  ReaderOptions options;
  options.dialect = p.dialect;
  const Reading r = ReadUntilError(*text, options, p.file);
  if (p.reader_error.empty()) {
    ASSERT_TRUE(r.status.ok()) << r.status.message();
  } else {
    ASSERT_FALSE(r.status.ok());
    EXPECT_NE(r.status.message().find(p.reader_error), std::string::npos) << r.status.message();
    EXPECT_NE(r.status.message().find(p.file + ":" + std::to_string(p.error_line) + ":"), std::string::npos)
        << r.status.message();
  }
  // What is reported: exactly the expected words.
  std::set<std::string> reported;
  for (const auto& [word, entry] : r.report.words) {
    reported.insert(word);
    EXPECT_FALSE(entry.first_lines.empty()) << word;
  }
  EXPECT_EQ(reported, p.reported) << p.file;
  ExpectEveryLetterHandledOrReported(*text, reported, p.file);
  std::printf("[public] %-36s %6zu lines %6zu motion blocks %5zu arcs, %zu words reported\n", p.file.c_str(),
              r.report.lines, r.report.motion_blocks, r.report.arcs, r.report.notes());
  if (!testing::Rs274Installed()) {
    GTEST_SKIP() << "rs274 not found (Debian linuxcnc-uspace): the comparison with LinuxCNC is skipped";
  }
  int code = 0;
  std::string console;
  const std::string canon_text = testing::RunRs274(kData / p.file, &code, &console);
  const testing::Canon canon = testing::ParseCanon(canon_text);
  if (p.rs274_accepts) {
    ASSERT_EQ(code, 0) << console;
  } else {
    EXPECT_NE(code, 0) << p.file << ": rs274 was expected to refuse it";
    EXPECT_NE(console.find(p.rs274_says), std::string::npos) << console;
  }
  if (!p.reader_error.empty() || p.rs274_accepts) {
    // Up to where both stop, the paths agree.
    const Agreement a = CompareWithRs274(r.moves, canon, p.file);
    std::printf(
        "[public] %-36s %zu moves compared with rs274 (%zu arcs, %zu under cutter compensation not compared): "
        "max end difference %.2g, max arc difference %.2g program units\n",
        p.file.c_str(), a.compared, a.arcs, a.skipped_compensation, a.max_end_difference, a.max_arc_difference);
    EXPECT_GT(a.compared, 0u);
  }
}

INSTANTIATE_TEST_SUITE_P(Programs, PublicProgramTest,
                         ::testing::Values(PublicProgram{.file = "linuxcnc_cds.ngc", .reported = {}},
                                           PublicProgram{.file = "linuxcnc_tort.ngc", .reported = {}},
                                           PublicProgram{.file = "camotics_botomata_bottom.nc", .reported = {}},
                                           PublicProgram{.file = "cncjs_circle_diamond_square.gcode",
                                                         .reported = {},
                                                         .rs274_accepts = false,
                                                         .reader_error = "E_ARC_RADIUS",
                                                         .error_line = 624,
                                                         .rs274_says = "N624"},
                                           PublicProgram{.file = "cncjs_helical_thread_milling.gcode",
                                                         .reported = {"G42", "G3"},
                                                         .rs274_accepts = false,
                                                         .rs274_says = "tool 8"}),
                         [](const ::testing::TestParamInfo<PublicProgram>& param) {
                           std::string name = param.param.file.substr(0, param.param.file.find('.'));
                           for (char& c : name) {
                             if (!std::isalnum(static_cast<unsigned char>(c))) c = '_';
                           }
                           return name;
                         });

// The link's machine-side LinuxCNC program (cnc/machine_program.h; golden in tests/cnc/golden/, written
// by formloop's link, not by its posts) is macro code: O-word subroutines and loops, # parameters,
// G38.2 probing. The G-code reader does not execute macros; it reads the program without an error and
// reports exactly those three words with their lines, so nothing in it is silently taken for a path.
TEST(LinkProgramTest, MacroWordsOfTheLinksLinuxCncProgramAreReportedNotDropped) {
  const std::string file = "measure.ngc";
  const auto text = ReadFile(std::filesystem::path(FORMLOOP_SOURCE_DIR) / "tests" / "cnc" / "golden" / file);
  ASSERT_TRUE(text.ok()) << text.status().message();
  const Reading r = ReadUntilError(*text, ReaderOptions{}, file);
  ASSERT_TRUE(r.status.ok()) << r.status.message();
  std::set<std::string> reported;
  for (const auto& [word, entry] : r.report.words) {
    reported.insert(word);
    EXPECT_FALSE(entry.first_lines.empty()) << word;
  }
  EXPECT_EQ(reported, (std::set<std::string>{"#", "O", "G38.2"}));
  EXPECT_EQ(r.report.unknown(), 0u);
  // The test's own count, comments removed: O-word lines (the rest of the line is theirs), parameter
  // statements (a line starting with '#'), words whose value is #n or [expression], G38.2 blocks.
  std::size_t o_lines = 0, hash_words = 0, probes = 0;
  std::size_t start = 0;
  while (start < text->size()) {
    const std::size_t end = std::min(text->find('\n', start), text->size());
    std::string l;
    for (std::size_t i = start, depth = 0; i < end; ++i) {
      const char c = (*text)[i];
      if (c == '(') ++depth;
      if (depth == 0) l += c;
      if (c == ')' && depth > 0) --depth;
    }
    start = end + 1;
    if (l.empty()) continue;
    if (l[0] == 'o' || l[0] == 'O') {
      ++o_lines;
    } else if (l[0] == '#') {
      ++hash_words;
    } else {
      for (std::size_t i = 1; i < l.size(); ++i) {
        hash_words += (l[i] == '#' || l[i] == '[') && std::isalpha(static_cast<unsigned char>(l[i - 1])) ? 1 : 0;
      }
      probes += l.find("G38.2") != std::string::npos ? 1 : 0;
    }
  }
  EXPECT_GT(o_lines, 0u);
  EXPECT_EQ(r.report.words.at("O").count, o_lines);
  EXPECT_EQ(r.report.words.at("#").count, hash_words);
  EXPECT_EQ(r.report.words.at("G38.2").count, probes);
  std::printf("[link] %s: %zu O-word lines, %zu parameter words, %zu probing moves reported; %zu motion blocks\n",
              file.c_str(), o_lines, hash_words, probes, r.report.motion_blocks);
}

}  // namespace
}  // namespace formloop::nc
