// Level 1 on shop programs (issue 24, Level 1: "the optimum written into the program's F and S words
// through the G-code reader"): RS274NGC programs with G2/G3 arcs, a helix, a G91 section, a G20 inch
// program and the public LinuxCNC sample linuxcnc_cds.ngc get their F and S rewritten; every other line
// stays byte-identical, arc and helix lengths are the reader's exact ones, the edited program reads back
// (formloop's reader and LinuxCNC's rs274 when installed) with the same path and the new feeds, and what
// cannot be edited safely is refused with its line.

#include <gtest/gtest.h>
#include <unistd.h>

#include <cctype>
#include <cmath>
#include <filesystem>
#include <numbers>
#include <set>
#include <string>
#include <vector>

#include "core/atomic_file.h"
#include "core/json_io.h"
#include "core/number_text.h"
#include "nc-gen/gcode_reader.h"
#include "planning/cutting_program.h"
#include "planning/program_edit.h"
#include "tests/support/rs274.h"

namespace formloop::planning {
namespace {

constexpr double kPi = std::numbers::pi;

CuttingCoefficients S1() {
  return CuttingCoefficientsFromJson(ReadJsonFile(std::string(FORMLOOP_SOURCE_DIR) + "/data/cutting/s1.json").value(),
                                     "s1.json")
      .value();
}

std::vector<std::string> Lines(const std::string& text) {
  std::vector<std::string> out;
  std::size_t start = 0;
  while (start < text.size()) {
    const std::size_t end = std::min(text.find('\n', start), text.size());
    out.push_back(text.substr(start, end - start));
    start = end + 1;
  }
  return out;
}

// The 1-based lines of `before` whose text differs in `after` (the two header comments removed).
std::set<std::size_t> ChangedLines(const std::string& before, const std::string& after) {
  std::vector<std::string> a = Lines(before), b;
  for (const std::string& l : Lines(after)) {
    std::string lower = l;  // Fanuc comments are upper case
    for (char& c : lower) c = static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
    if (lower.find("formloop optimise cutting: parent sha256") == std::string::npos &&
        lower.find("(coefficient set ") == std::string::npos) {
      b.push_back(l);
    }
  }
  EXPECT_EQ(a.size(), b.size());
  std::set<std::size_t> out;
  for (std::size_t i = 0; i < std::min(a.size(), b.size()); ++i) {
    if (a[i] != b[i]) out.insert(i + 1);
  }
  return out;
}

// Engagement a_p, a_e for the feed blocks with N words in [first, last].
std::vector<BlockEngagement> EngageBlocks(const std::string& text, long first, long last, double a_p, double a_e) {
  const EditableProgram p = EditableProgram::Parse(text, "linuxcnc", "t", ProgramReading::kShopProgram).value();
  std::vector<BlockEngagement> out;
  for (const ProgramLine& l : p.lines()) {
    if (l.move < 0 || p.moves()[static_cast<std::size_t>(l.move)].rapid) continue;
    if (l.number >= first && l.number <= last) out.push_back({l.number, a_p, a_e});
  }
  return out;
}

// Same motions, ends and arcs; feeds (mm/min) returned for comparison.
void ExpectSamePath(const std::string& a_text, const std::string& b_text, std::vector<double>* feeds_a,
                    std::vector<double>* feeds_b) {
  const auto a = nc::ReadProgramPath(a_text, {}, "a");
  const auto b = nc::ReadProgramPath(b_text, {}, "b");
  ASSERT_TRUE(a.ok() && b.ok());
  ASSERT_EQ(a->moves.size(), b->moves.size());
  for (std::size_t i = 0; i < a->moves.size(); ++i) {
    const nc::PathMove &p = a->moves[i], &q = b->moves[i];
    EXPECT_EQ(p.motion, q.motion) << i;
    EXPECT_EQ(p.end_known, q.end_known) << i;
    for (int k = 0; k < 3; ++k) {
      if (p.end_known >> k & 1u) {
        EXPECT_EQ(p.end[k], q.end[k]) << i;
      }
    }
    EXPECT_EQ(p.has_arc, q.has_arc);
    if (p.has_arc && q.has_arc) {
      EXPECT_EQ(p.arc.centre, q.arc.centre);
      EXPECT_EQ(p.arc.sweep_rad, q.arc.sweep_rad);
      EXPECT_EQ(p.arc.rise, q.arc.rise);
    }
    const double mpu_a = p.units == nc::Units::kInch ? nc::kMmPerInch : 1.0;
    const double mpu_b = q.units == nc::Units::kInch ? nc::kMmPerInch : 1.0;
    feeds_a->push_back(p.motion == nc::Motion::kRapid ? 0 : p.feed * mpu_a);
    feeds_b->push_back(q.motion == nc::Motion::kRapid ? 0 : q.feed * mpu_b);
  }
}

// rs274's canonical path of both programs: same moves (kind, ends, arc centres and turns); returns the
// feeds of the edited one, and its SET_SPINDLE_SPEED values.
void ExpectRs274SamePath(const std::string& before, const std::string& after, const std::string& name,
                         std::vector<double>* feeds_after, std::string* canon_after) {
  const std::filesystem::path dir =
      std::filesystem::temp_directory_path() / ("formloop-shop-" + std::to_string(::getpid()) + "-" + name);
  std::filesystem::create_directories(dir);
  ASSERT_TRUE(WriteFileAtomic(dir / "before.ngc", before).ok());
  ASSERT_TRUE(WriteFileAtomic(dir / "after.ngc", after).ok());
  int code_a = 0, code_b = 0;
  std::string console;
  const testing::Canon a = testing::ParseCanon(testing::RunRs274(dir / "before.ngc", &code_a, &console));
  ASSERT_EQ(code_a, 0) << console;
  *canon_after = testing::RunRs274(dir / "after.ngc", &code_b, &console);
  ASSERT_EQ(code_b, 0) << console;
  const testing::Canon b = testing::ParseCanon(*canon_after);
  std::filesystem::remove_all(dir);
  EXPECT_EQ(a.unparsed_motion, 0);
  ASSERT_EQ(a.moves.size(), b.moves.size());
  ASSERT_GT(a.moves.size(), 0u);
  for (std::size_t i = 0; i < a.moves.size(); ++i) {
    EXPECT_EQ(a.moves[i].kind, b.moves[i].kind) << i;
    EXPECT_EQ(a.moves[i].p, b.moves[i].p) << i;
    EXPECT_EQ(a.moves[i].centre, b.moves[i].centre) << i;
    EXPECT_EQ(a.moves[i].rotation, b.moves[i].rotation) << i;
    feeds_after->push_back(b.moves[i].feed);
  }
}

std::string WordOf(const std::string& line, char letter) {
  const std::size_t at = line.find(letter);
  if (at == std::string::npos) return "";
  std::size_t end = at + 1;
  while (end < line.size() && (std::isdigit(static_cast<unsigned char>(line[end])) || line[end] == '.')) ++end;
  return line.substr(at + 1, end - at - 1);
}

// mm, G17 arcs in both centre forms, a helix (a full turn down 2 mm), a G91 section, words without blanks.
const char* const kShopMm =
    "%\n"
    "(shop program: arcs, a helix, G91)\n"
    "G21 G90 G17 G94\n"
    "G0X0Y0Z5S3000M3\n"
    "G1Z-2F200\n"
    "N100 G1 X20 F500\n"
    "N110 G3 X30 Y10 I0 J10\n"
    "N120 G3 X20 Y20 R10\n"
    "N130 G2 X20 Y20 Z-4 I0 J-5 (helix)\n"
    "N140 G91 G1 X-10\n"
    "N150 Y-10\n"
    "N160 G90 G1 X0 Y0\n"
    "G0 Z5\n"
    "M5\n"
    "M30\n"
    "%\n";

TEST(ShopProgram, ArcsHelixAndG91GetTheOptimumInFAndSAndNothingElseChanges) {
  const std::string text = kShopMm;
  const EditableProgram p = EditableProgram::Parse(text, "linuxcnc", "shop.ngc", ProgramReading::kShopProgram).value();
  // The reader's exact lengths: quarter arcs of radius 10, the helix sqrt((2π·5)² + 2²), the G91 lines.
  const std::vector<double> want = {20, 5 * kPi, 5 * kPi, std::hypot(10 * kPi, 2.0), 10, 10, std::hypot(10.0, 10.0)};
  std::vector<double> got;
  for (const ProgramLine& l : p.lines()) {
    if (l.number >= 100) got.push_back(p.MoveLengthMm(static_cast<std::size_t>(l.move)));
  }
  ASSERT_EQ(got.size(), want.size());
  for (std::size_t i = 0; i < want.size(); ++i) EXPECT_NEAR(got[i], want[i], 1e-9) << i;

  const std::vector<BlockEngagement> e = EngageBlocks(text, 100, 160, 5, 1);
  ASSERT_EQ(e.size(), 7u);
  auto r = OptimiseCuttingProgram(text, "linuxcnc", "shop.ngc", e, S1(), {.seed = 3});
  ASSERT_TRUE(r.ok()) << r.status().ToString();
  ASSERT_EQ(r->groups.size(), 1u);
  double volume = 0;
  for (double l : want) volume += l * 5 * 1;
  EXPECT_NEAR(r->groups[0].volume_mm3, volume, 1e-9 * volume);
  // Only the spindle line (S, words without blanks kept so) and N100 (the one F of the cut) change.
  EXPECT_EQ(ChangedLines(text, r->program), (std::set<std::size_t>{4, 6}));
  const std::vector<std::string> out = Lines(r->program);
  const double feed = std::floor(r->groups[0].state.v_f_mm_per_min + 1e-9);
  EXPECT_EQ(out[5], "G0X0Y0Z5S" + FeedWord(r->spindle_rpm) + "M3");
  EXPECT_EQ(out[7], "N100 G1 X20 F" + FeedWord(feed));
  EXPECT_LE(feed, r->groups[0].model.state.v_f_mm_per_min * (1 + 1e-9));

  std::vector<double> fa, fb;
  ExpectSamePath(text, r->program, &fa, &fb);
  for (std::size_t i = 0; i < fa.size(); ++i) {
    if (i >= 2 && i <= 8) {
      EXPECT_EQ(fb[i], feed) << i;  // the seven engaged blocks
    } else {
      EXPECT_EQ(fb[i], fa[i]) << i;  // rapids and the plunge keep theirs
    }
  }
  if (!testing::Rs274Installed()) GTEST_SKIP() << "rs274 not found (Debian linuxcnc-uspace)";
  std::vector<double> canon_feeds;
  std::string canon;
  ExpectRs274SamePath(text, r->program, "mm", &canon_feeds, &canon);
  ASSERT_EQ(canon_feeds.size(), fb.size());
  for (std::size_t i = 2; i <= 8; ++i) EXPECT_EQ(canon_feeds[i], feed) << i;
  EXPECT_NE(canon.find("SET_SPINDLE_SPEED(0, " + FeedWord(r->spindle_rpm) + ".0000)"), std::string::npos) << canon;
}

TEST(ShopProgram, InchProgramGetsItsFeedInInchPerMinuteRoundedDown) {
  const std::string text =
      "G20 G90 G17 G94\n"
      "G0 X0 Y0 Z0.2 S2000 M3\n"
      "G1 Z-0.1 F8\n"
      "N10 G1 X2.\n"
      "N20 G3 X3. Y1. I0 J1.\n"
      "N30 G1 Y2. F12.5\n"
      "N40 X0\n"
      "N50 G1 Y0\n"
      "G0 Z0.2\n"
      "M30\n";
  const EditableProgram p = EditableProgram::Parse(text, "linuxcnc", "inch.ngc", ProgramReading::kShopProgram).value();
  EXPECT_NEAR(p.MoveLengthMm(static_cast<std::size_t>(p.lines()[4].move)), 25.4 * kPi / 2, 1e-9);
  const std::vector<BlockEngagement> e = EngageBlocks(text, 10, 40, 5, 1);  // N50 not engaged
  auto r = OptimiseCuttingProgram(text, "linuxcnc", "inch.ngc", e, S1(), {.seed = 3});
  ASSERT_TRUE(r.ok()) << r.status().ToString();
  const double feed_mm = std::floor(r->groups[0].state.v_f_mm_per_min + 1e-9);
  const double feed_in = std::floor(feed_mm / 25.4 * 100 + 1e-9) / 100;
  // N10 gets the feed in inch/min, N30's own F word is rewritten, N50 gets its original 12.5 back.
  EXPECT_EQ(ChangedLines(text, r->program), (std::set<std::size_t>{2, 4, 6, 8}));
  const std::vector<std::string> out = Lines(r->program);
  EXPECT_EQ(out[5], "N10 G1 X2. F" + FormatFixed(feed_in, 2));
  EXPECT_EQ(WordOf(out[7], 'F'), FormatFixed(feed_in, 2));
  EXPECT_EQ(out[9], "N50 G1 Y0 F12.5");
  EXPECT_EQ(out[3], "G0 X0 Y0 Z0.2 S" + FeedWord(r->spindle_rpm) + " M3");
  EXPECT_GT(feed_in * 25.4, feed_mm - 0.254);
  EXPECT_LE(feed_in * 25.4, feed_mm);
  std::vector<double> fa, fb;
  ExpectSamePath(text, r->program, &fa, &fb);
  ASSERT_EQ(fb.size(), 8u);
  for (std::size_t i = 2; i <= 5; ++i) EXPECT_NEAR(fb[i], feed_in * 25.4, 1e-9) << i;
  EXPECT_NEAR(fb[6], 12.5 * 25.4, 1e-9);
  if (!testing::Rs274Installed()) GTEST_SKIP() << "rs274 not found (Debian linuxcnc-uspace)";
  std::vector<double> canon_feeds;
  std::string canon;
  ExpectRs274SamePath(text, r->program, "inch", &canon_feeds, &canon);
  ASSERT_EQ(canon_feeds.size(), 8u);
  for (std::size_t i = 2; i <= 5; ++i) EXPECT_NEAR(canon_feeds[i], feed_in, 1e-9) << i;  // rs274 prints inch/min
  EXPECT_NEAR(canon_feeds[6], 12.5, 1e-9);
}

// LinuxCNC's sample program (Kramer 1994, inch, R-form arcs, lower-case n words): the pocket's cuts
// n0180..n0500 engaged, the rest keeps F16.0 (restored where the modal feed changed).
TEST(ShopProgram, PublicLinuxCncProgramKeepsRs274sCanonicalPath) {
  const std::string file = std::string(FORMLOOP_SOURCE_DIR) + "/data/nc-programs/linuxcnc_cds.ngc";
  const std::string text = ReadFile(file).value();
  const std::vector<BlockEngagement> e = EngageBlocks(text, 180, 500, 5, 1);
  ASSERT_GT(e.size(), 20u);
  auto r = OptimiseCuttingProgram(text, "linuxcnc", file, e, S1(), {.seed = 3});
  ASSERT_TRUE(r.ok()) << r.status().ToString();
  const double feed_in = std::floor(std::floor(r->groups[0].state.v_f_mm_per_min + 1e-9) / 25.4 * 100 + 1e-9) / 100;
  const std::set<std::size_t> changed = ChangedLines(text, r->program);
  // The S line, the first engaged block (n0180) and the first feed block after n0500.
  ASSERT_EQ(changed.size(), 3u);
  const std::vector<std::string> in = Lines(text);
  for (std::size_t line : changed) {
    const std::string& l = in[line - 1];
    EXPECT_TRUE(l.rfind("n0140", 0) == 0 || l.rfind("n0180", 0) == 0 || l.rfind("n0510", 0) == 0) << l;
  }
  std::vector<double> fa, fb;
  ExpectSamePath(text, r->program, &fa, &fb);
  if (!testing::Rs274Installed()) GTEST_SKIP() << "rs274 not found (Debian linuxcnc-uspace)";
  std::vector<double> canon_feeds;
  std::string canon;
  ExpectRs274SamePath(text, r->program, "cds", &canon_feeds, &canon);
  std::size_t at_new = 0, at_old = 0;
  for (double f : canon_feeds) {
    at_new += f == feed_in;
    at_old += f == 16.0;
  }
  EXPECT_EQ(at_new, e.size());
  EXPECT_GT(at_old, 0u);
  EXPECT_NE(canon.find("SET_SPINDLE_SPEED(0, " + FeedWord(r->spindle_rpm) + ".0000)"), std::string::npos);
  std::printf("[shop] linuxcnc_cds.ngc: %zu canonical moves unchanged, %zu at F%s in/min, %zu at F16.0, S%s\n",
              canon_feeds.size(), at_new, FormatFixed(feed_in, 2).c_str(), at_old, FeedWord(r->spindle_rpm).c_str());
}

// A Fanuc shop program: O number, '%' lines, numbers without a decimal point in least increments
// (Y10000 = 10 mm on IS-B) inside a G91 section, an R-form arc. The edit keeps its spelling.
TEST(ShopProgram, FanucProgramWithLeastIncrementsIsEditedInItsOwnSpelling) {
  const std::string text =
      "%\n"
      "O1000 (SHOP)\n"
      "G21 G90 G17 G94\n"
      "G0 X0. Y0. Z5. S3000 M3\n"
      "G1 Z-2. F200.\n"
      "N100 G1 X20. F500.\n"
      "N110 G3 X30. Y10. R10.\n"
      "N120 G91 G1 Y10000\n"
      "N130 G90 G1 X0. Y0.\n"
      "G0 Z5.\n"
      "M30\n"
      "%\n";
  const EditableProgram p = EditableProgram::Parse(text, "fanuc", "shop.nc", ProgramReading::kShopProgram).value();
  std::vector<double> lengths;
  for (const ProgramLine& l : p.lines()) {
    if (l.number >= 100) lengths.push_back(p.MoveLengthMm(static_cast<std::size_t>(l.move)));
  }
  ASSERT_EQ(lengths.size(), 4u);
  EXPECT_NEAR(lengths[1], 5 * kPi, 1e-9);
  EXPECT_NEAR(lengths[2], 10, 1e-12);  // Y10000 in least increments of 0.001 mm
  EXPECT_NEAR(lengths[3], std::hypot(30.0, 20.0), 1e-9);
  std::vector<BlockEngagement> e;
  for (long n : {100, 110, 120, 130}) e.push_back({n, 5, 1});
  auto r = OptimiseCuttingProgram(text, "fanuc", "shop.nc", e, S1(), {.seed = 3});
  ASSERT_TRUE(r.ok()) << r.status().ToString();
  EXPECT_EQ(ChangedLines(text, r->program), (std::set<std::size_t>{4, 6}));
  const double feed = std::floor(r->groups[0].state.v_f_mm_per_min + 1e-9);
  const std::vector<std::string> out = Lines(r->program);
  EXPECT_EQ(out[7], "N100 G1 X20. F" + FeedWord(feed)) << r->program;  // line 6 after 2 header comments
  nc::ReaderOptions fanuc;
  fanuc.dialect = nc::GcodeDialect::kFanuc;
  const auto read = nc::ReadProgramPath(r->program, fanuc, "out.nc");
  ASSERT_TRUE(read.ok()) << read.status().ToString();
  int cuts = 0;
  for (const nc::PathMove& m : read->moves) {
    if (m.motion != nc::Motion::kRapid && m.end.z() == -2 && m.start.z() == -2) {
      EXPECT_EQ(m.feed, feed);
      ++cuts;
    }
  }
  EXPECT_EQ(cuts, 4);
}

TEST(ShopProgram, WhatCannotBeEditedSafelyIsRefusedWithItsLine) {
  struct Case {
    std::string text, says;
  };
  const std::vector<Case> cases = {
      {"G21 G90\n#1=500\nN10 G1 X10 F#1\nM30\n", "line 2"},
      {"G21 G90\nN10 G93 G1 X10 F2\nM30\n", "N10 (line 2): feed move in G93"},
      {"G21 G90\nN10 G1 X10 F300\nN20 G81 X5 Y5 Z-2 R1\nM30\n", "N20 (line 3): G81"},
      {"G21 G90\nN10 G96 S200 M3\nN20 G1 X10 F300\nM30\n", "N10 (line 2): G96"},
      {"G21 G90\nN10 G1 X10 F300\nN20 M98 P100\nM30\n", "N20 (line 3): M98"},
      {"G21 G90\nT1 M6\nS3000 M3\nG0 X0 Y0 Z0\nN10 G1 X10 F300\nT2 M6\nS800 M3\nN20 G1 X0\nM30\n",
       "line 6 selects tool T2"},
  };
  for (const Case& c : cases) {
    const auto r = OptimiseCuttingProgram(c.text, "linuxcnc", "bad.ngc", {{10, 5, 1}}, S1(), {.seed = 1});
    ASSERT_FALSE(r.ok()) << c.text;
    EXPECT_EQ(r.status().code(), StatusCode::kBadInput) << r.status().ToString();
    EXPECT_NE(r.status().ToString().find(c.says), std::string::npos) << r.status().ToString();
  }
  // An engaged block after G28 (position unknown): its length is not known, so it is refused, not skipped.
  const std::string g28 = "G21 G90\nG28\nN10 G1 X10 F300\nM30\n";
  const auto r = OptimiseCuttingProgram(g28, "linuxcnc", "g28.ngc", {{10, 5, 1}}, S1(), {.seed = 1});
  ASSERT_FALSE(r.ok());
  EXPECT_NE(r.status().ToString().find("N10 of g28.ngc starts or ends where the program's position is not known"),
            std::string::npos)
      << r.status().ToString();
}

}  // namespace
}  // namespace formloop::planning
