// The G-code reader (nc-gen/gcode_reader.h): spec/path-deviation.md §3 geometry and §8 checks 6 and 9,
// number formats of both dialects, modal state, comments, block delete, what is reported with its line,
// and the errors.

#include <cmath>
#include <filesystem>
#include <fstream>
#include <numbers>
#include <string>

#include <gtest/gtest.h>

#include "nc-gen/gcode_reader.h"
#include "tests/support/test_dir.h"

namespace formloop::nc {
namespace {

using Eigen::Vector3d;

ProgramPath Read(const std::string& text, ReaderOptions options = {}) {
  auto path = ReadProgramPath(text, options, "t.ngc");
  EXPECT_TRUE(path.ok()) << path.status().message();
  return path.ok() ? *path : ProgramPath{};
}

Status ReadError(const std::string& text, ReaderOptions options = {}) {
  return ReadProgramPath(text, options, "bad.ngc").status();
}

double LengthOf(const PathMove& m) { return m.has_arc ? m.arc.Length() : (m.end - m.start).norm(); }

TEST(GcodeReaderTest, ArcLengthsOfTheSpec) {
  // §8.9: quarter circle r = 10, full helical turn r = 10 with pitch 2, R-form semicircle.
  const auto p = Read(
      "G21 G90 G17\nG0 X10 Y0 Z0\nG3 X0 Y10 I-10 J0\nG0 X10 Y0 Z0\nG2 X10 Y0 Z2 I-10 J0\nG0 X0 Y0 Z0\n"
      "G2 X20. Y0 R10.\n");
  ASSERT_EQ(p.moves.size(), 6u);
  EXPECT_NEAR(LengthOf(p.moves[1]), 15.70796, 1e-5);
  EXPECT_NEAR(LengthOf(p.moves[3]), 62.86368, 1e-5);
  EXPECT_NEAR(LengthOf(p.moves[5]), 31.41593, 1e-5);
  // The semicircle from (0, 0) to (20, 0) clockwise with R > 0 has its centre at (10, 0) and passes (10, 10).
  EXPECT_NEAR((p.moves[5].arc.PointAt(0.5) - Vector3d(10, 10, 0)).norm(), 0, 1e-12);
  EXPECT_NEAR(p.moves[3].arc.PointAt(0.5).z(), 1.0, 1e-12);
}

TEST(GcodeReaderTest, PlaneOrientationG18) {
  // §8.6: from X0 Z10, G18 G3 X10 Z0 I0 K-10 is a quarter; G2 the other three quarters.
  const auto p = Read("G21 G90\nG0 X0 Y0 Z10\nG18 G3 X10. Z0 I0 K-10.\nG0 X0 Y0 Z10\nG18 G2 X10. Z0 I0 K-10.\n");
  ASSERT_EQ(p.moves.size(), 4u);
  EXPECT_NEAR(LengthOf(p.moves[1]), 15.70796, 1e-5);
  EXPECT_NEAR(LengthOf(p.moves[3]), 47.12389, 1e-5);
  // The quarter passes (X, Z) = (7.07, 7.07); the three-quarter arc passes (X, Z) = (-10, 0).
  EXPECT_NEAR((p.moves[1].arc.PointAt(0.5) - Vector3d(10 / std::sqrt(2.0), 0, 10 / std::sqrt(2.0))).norm(), 0, 1e-12);
  EXPECT_NEAR((p.moves[3].arc.PointAt(1.0 / 3) - Vector3d(-10, 0, 0)).norm(), 0, 1e-12);
}

TEST(GcodeReaderTest, G19ArcAndRSigns) {
  // G19: (u, v) = (Y, Z); G3 from (Y10, Z0) about the origin to (Y0, Z10) is a quarter.
  const auto p = Read("G21\nG0 X0 Y10 Z0\nG19 G3 Y0 Z10 J-10 K0\nG17\nG0 X0 Y0 Z0\nG3 X10 Y0 R-5\n");
  ASSERT_EQ(p.moves.size(), 4u);
  EXPECT_NEAR(p.moves[1].arc.sweep_rad, std::numbers::pi / 2, 1e-12);
  // R < 0 picks the arc of more than half a turn: with a chord of 10 and |R| = 5 both are halves.
  EXPECT_NEAR(p.moves[3].arc.sweep_rad, std::numbers::pi, 1e-6);
  const auto q = Read("G21\nG0 X0 Y0 Z0\nG3 X6 Y0 R5\nG0 X0 Y0\nG3 X6 Y0 R-5\n");
  EXPECT_LT(q.moves[1].arc.sweep_rad, std::numbers::pi);
  EXPECT_GT(q.moves[3].arc.sweep_rad, std::numbers::pi);
  EXPECT_NEAR(q.moves[1].arc.sweep_rad + q.moves[3].arc.sweep_rad, 2 * std::numbers::pi, 1e-12);
}

TEST(GcodeReaderTest, FullCirclesTurnsAndModalArcs) {
  // A full circle with centre words only (no axis words), LinuxCNC's P turn count, and modal G2 blocks.
  const auto p = Read("G21\nG0 X-25 Y100 Z0\nG1 Z-1 F140\nG2 I-45\nG2 X-25 Y100 I-45 P3\nX-70 Y55 I-45 J0\n");
  ASSERT_EQ(p.moves.size(), 5u);
  EXPECT_NEAR(p.moves[2].arc.sweep_rad, 2 * std::numbers::pi, 1e-12);
  EXPECT_NEAR(p.moves[3].arc.sweep_rad, 6 * std::numbers::pi, 1e-12);
  EXPECT_EQ(p.moves[4].motion, Motion::kArcCw);
  EXPECT_NEAR(p.moves[4].arc.sweep_rad, std::numbers::pi / 2, 1e-12);
  EXPECT_NEAR(p.moves[2].feed, 140, 0);
}

TEST(GcodeReaderTest, IncrementalDistanceAndAbsoluteCentres) {
  const auto p = Read("G21 G90\nG0 X10 Y0 Z0\nG91 G3 X-10 Y10 I-10 J0\nG90 G90.1 G3 X-10 Y0 I0 J0\nG91.1 G91 G1 X1\n");
  ASSERT_EQ(p.moves.size(), 4u);
  EXPECT_NEAR((p.moves[1].end - Vector3d(0, 10, 0)).norm(), 0, 1e-12);
  EXPECT_NEAR(p.moves[1].arc.sweep_rad, std::numbers::pi / 2, 1e-12);
  EXPECT_NEAR((p.moves[2].arc.centre - Vector3d(0, 0, 0)).norm(), 0, 1e-12);
  EXPECT_NEAR(p.moves[2].arc.sweep_rad, std::numbers::pi / 2, 1e-12);
  EXPECT_NEAR(p.moves[3].end.x(), -9, 1e-12);
}

TEST(GcodeReaderTest, NumbersWithoutPointFollowTheDialect) {
  const std::string text = "G21 G90\nG0 X50 Y50. Z-5\nG20\nG1 X50 F100\n";
  const auto linuxcnc = Read(text);
  EXPECT_NEAR(linuxcnc.moves[0].end.x(), 50, 0);
  EXPECT_NEAR(linuxcnc.moves[0].end.z(), -5, 0);
  ReaderOptions fanuc;
  fanuc.dialect = GcodeDialect::kFanuc;
  const auto f = Read("%\nO1234\n" + text + "%\n", fanuc);
  ASSERT_EQ(f.moves.size(), 2u);
  EXPECT_NEAR(f.moves[0].end.x(), 0.050, 1e-12);  // least increments, 0.001 mm
  EXPECT_NEAR(f.moves[0].end.y(), 50, 0);
  EXPECT_NEAR(f.moves[0].end.z(), -0.005, 1e-12);
  EXPECT_NEAR(f.moves[1].end.x(), 0.0050, 1e-12);  // inch: 0.0001 in
  EXPECT_EQ(f.moves[1].units, Units::kInch);
  EXPECT_NEAR(f.moves[1].feed, 100, 0);  // feed words are not least increments
  // The unit change keeps the physical position: Y 50 mm is 1.9685 in afterwards.
  EXPECT_NEAR(f.moves[1].end.y(), 50 / 25.4, 1e-12);
}

TEST(GcodeReaderTest, CommentsBlockDeleteLineNumbersAndSpaces) {
  const std::string text =
      "%\n(header; with a semicolon)\nN10 G21 G90 (mm) ; trailing\nn20 g0 x 1 y 2 z 3\n/N30 G1 X5 F100\n"
      "N40 G1 X 7.5 Y2 ; comment (not closed\n%\nG1 X99\n";
  const auto on = Read(text);
  ASSERT_EQ(on.moves.size(), 3u);  // the second '%' ends the program
  EXPECT_EQ(on.moves[0].line, 4);
  EXPECT_EQ(on.moves[1].line, 5);
  EXPECT_EQ(on.moves[2].line, 6);
  EXPECT_NEAR(on.moves[2].end.x(), 7.5, 0);
  ReaderOptions skip;
  skip.block_delete = true;
  const auto off = Read(text, skip);
  ASSERT_EQ(off.moves.size(), 2u);
  EXPECT_EQ(off.report.skipped_blocks, 1u);
  const auto crlf = Read("G21\r\nG0 X1 Y2 Z3\r\nG1 X2 F100");
  ASSERT_EQ(crlf.moves.size(), 2u);
  EXPECT_EQ(crlf.moves[1].line, 3);
  EXPECT_NEAR(crlf.moves[1].end.x(), 2, 0);
}

TEST(GcodeReaderTest, RotaryAxesArePassedThroughAndTracked) {
  const auto p = Read("G21\nG0 X0 Y0 Z0 A0\nG1 X10 A30. F100\nG1 X20\n");
  ASSERT_EQ(p.moves.size(), 3u);
  EXPECT_NEAR(p.moves[1].rotary[0], 30, 0);
  EXPECT_EQ(p.moves[1].rotary_known & 1u, 1u);
  EXPECT_NEAR(p.moves[2].rotary[0], 30, 0);
}

TEST(GcodeReaderTest, WhatIsNotModelledIsReportedWithItsLineAndMakesPositionsUnknown) {
  const auto p = Read(
      "G21\nG0 X0 Y0 Z0\nG28 G91 Z0\nG90\nG0 X1 Y2\nG81 X5 Y5 Z-2 R1 F100\nX6\nG80\nG0 Z5\n#1 = 3\n"
      "G1 X[#1 + 1] F10\nG7.5 X1\nG1 X2 E0.5\n");
  const ReadReport& r = p.report;
  ASSERT_TRUE(r.words.count("G28"));
  EXPECT_EQ(r.words.at("G28").first_lines, std::vector<long>{3});
  ASSERT_TRUE(r.words.count("G81"));
  EXPECT_EQ(r.words.at("G81").first_lines, std::vector<long>{6});
  ASSERT_TRUE(r.words.count("#"));
  EXPECT_EQ(r.words.at("#").first_lines, (std::vector<long>{10, 11}));
  ASSERT_TRUE(r.words.count("G7.5"));
  EXPECT_EQ(r.words.at("G7.5").kind, NoteKind::kUnknown);
  ASSERT_TRUE(r.words.count("E"));
  EXPECT_EQ(r.words.at("E").kind, NoteKind::kUnknown);
  EXPECT_EQ(r.words.at("E").first_lines, std::vector<long>{13});
  // After G28 Z the Z axis is unknown until programmed; the expression leaves X unknown.
  ASSERT_GE(p.moves.size(), 4u);
  EXPECT_EQ(p.moves[0].end_known, 7u);
  EXPECT_EQ(p.moves[1].end_known, 3u);  // G0 X1 Y2: X and Y known, Z not (G28)
  EXPECT_EQ(p.moves[2].end_known, 7u);  // G0 Z5 after the cycle
  EXPECT_EQ(p.moves[3].end_known & 1u, 0u);
}

TEST(GcodeReaderTest, WorkOffsetsSetByTheProgramAreFollowed) {
  // G10 L2 on the active system shifts the current point; G55 with known offsets converts it; G92
  // renames it.
  const auto p = Read(
      "G21\nG10 L2 P1 X0 Y0 Z0\nG10 L2 P2 X0 Y0 Z0\nG54\nG0 X1 Y1 Z1\nG10 L2 P1 Y-100\nG1 X2 F10\n"
      "G10 L2 P2 X10 Y0 Z0\nG55\nG1 X3\nG92 X0 Y0 Z0\nG1 X1\n");
  ASSERT_EQ(p.moves.size(), 4u);
  EXPECT_NEAR((p.moves[1].end - Vector3d(2, 101, 1)).norm(), 0, 1e-12);
  EXPECT_EQ(p.moves[1].end_known, 7u);
  EXPECT_NEAR((p.moves[2].start - Vector3d(2 - 10, 101 + -100, 1)).norm(), 0, 1e-12);
  EXPECT_NEAR((p.moves[3].end - Vector3d(1, 0, 0)).norm(), 0, 1e-12);
  // A work system whose offsets the program never set: position unknown, and said so.
  const auto q = Read("G21\nG0 X1 Y1 Z1\nG56\nG1 X2 F10\n");
  EXPECT_EQ(q.moves[1].end_known, 1u);
  EXPECT_TRUE(q.report.words.count("G56"));
}

// Found by fuzz/fuzz_gcode (UBSan: float-cast-overflow converting a 200-digit N word to long). A word's
// number beyond ±kMaxWordValue is refused naming the line and the word, for every letter and dialect; the
// crashing input is kept in fuzz/corpus/fuzz_gcode/.
TEST(GcodeReaderTest, NumbersBeyondTheWordRangeAreRefusedBeforeAnyConversion) {
  const std::string huge(200, '7');
  for (const char* letter : {"N", "G", "M", "X", "F", "P"}) {
    for (const GcodeDialect dialect : {GcodeDialect::kRs274ngc, GcodeDialect::kFanuc, GcodeDialect::kSinumerik}) {
      ReaderOptions options;
      options.dialect = dialect;
      const Status status = ReadError("G21\n" + std::string(letter) + "0" + huge + " G0 X1\n", options);
      EXPECT_NE(status.message().find("bad.ngc:2"), std::string::npos) << letter << ": " << status.message();
      EXPECT_NE(status.message().find("E_RANGE"), std::string::npos) << letter << ": " << status.message();
    }
  }
  EXPECT_NE(ReadError("G21\nG1 X1000000000 F10\n").message().find("E_RANGE"), std::string::npos);
  const auto largest = Read("G21\nG0 X999999999\n");
  ASSERT_EQ(largest.moves.size(), 1u);
  EXPECT_EQ(largest.moves[0].end.x(), 999999999.0);
}

TEST(GcodeReaderTest, InvalidArcsAreErrorsWithTheirLine) {
  const Status no_centre = ReadError("G21\nG0 X0 Y0 Z0\nG2 X10 Y0\n");
  EXPECT_NE(no_centre.message().find("bad.ngc:3"), std::string::npos) << no_centre.message();
  EXPECT_NE(no_centre.message().find("E_ARC_NO_CENTRE"), std::string::npos);
  const Status radius = ReadError("G21\nG0 X0 Y0 Z0\nG1 X1 F1\nG2 X10 Y0 I4 J0\n");
  EXPECT_NE(radius.message().find("bad.ngc:4"), std::string::npos) << radius.message();
  EXPECT_NE(radius.message().find("E_ARC_RADIUS"), std::string::npos);
  const Status r_far = ReadError("G21\nG0 X0 Y0 Z0\nG2 X30 Y0 R10\n");
  EXPECT_NE(r_far.message().find("E_ARC_R:"), std::string::npos) << r_far.message();
  const Status r_full = ReadError("G21\nG0 X0 Y0 Z0\nG2 X0 Y0 R10\n");
  EXPECT_NE(r_full.message().find("E_ARC_R_FULLCIRCLE"), std::string::npos) << r_full.message();
  const Status two = ReadError("G21\nG0 G1 X1\n");
  EXPECT_NE(two.message().find("E_MODAL_GROUP"), std::string::npos) << two.message();
  const Status syntax = ReadError("G21\nG1 X F100\n");
  EXPECT_NE(syntax.message().find("bad.ngc:2"), std::string::npos) << syntax.message();
  const Status comment = ReadError("G21 (open\n");
  EXPECT_NE(comment.message().find("E_SYNTAX"), std::string::npos) << comment.message();
  // Within the tolerance the arc is read (as the spiral between the two radii).
  ReaderOptions loose;
  loose.arc_radius_tolerance_mm = 0.01;
  const auto ok = Read("G21\nG0 X0 Y0 Z0\nG2 X10.005 Y0 I5 J0\n", loose);
  EXPECT_NEAR((ok.moves[1].arc.PointAt(1) - Vector3d(10.005, 0, 0)).norm(), 0, 1e-12);
}

TEST(GcodeReaderTest, CoordinatesAreFormattedWithAPointAndRoundedHalfAway) {
  EXPECT_EQ(FormatCoordinate(50.0015, 4), "50.0015");
  EXPECT_EQ(FormatCoordinate(100.003, 4), "100.003");
  EXPECT_EQ(FormatCoordinate(200, 4), "200.");
  EXPECT_EQ(FormatCoordinate(-0.00004, 4), "0.");
  EXPECT_EQ(FormatCoordinate(0.00015, 4), "0.0002");
  EXPECT_EQ(FormatCoordinate(-0.00015, 4), "-0.0002");
  EXPECT_EQ(FormatCoordinate(50.0015, 3), "50.002");
  EXPECT_EQ(FormatCoordinate(-12.5, 0), "-13.");
  EXPECT_EQ(FormatCoordinate(0.1, 3), "0.1");
  EXPECT_EQ(FormatCoordinate(-7.05, 4), "-7.05");
  EXPECT_DOUBLE_EQ(RoundCoordinate(50.0015, 3), 50.002);
}

TEST(GcodeReaderTest, LineSourceReadsLongLinesAndChunkBoundaries) {
  const auto dir = testing::FreshTestDir("formloop-reader");
  const auto file = dir / "long.ngc";
  std::string text;
  for (int i = 0; i < 200000; ++i) text += "G1 X" + std::to_string(i) + " Y1 F100\n";
  text += "(" + std::string(3 << 20, 'c') + ")\r\nG1 X-1";  // a line longer than the 1 MiB buffer, no final newline
  std::ofstream(file, std::ios::binary) << text;
  auto source = LineSource::Open(file);
  ASSERT_TRUE(source.ok());
  std::string_view line, eol;
  long count = 0;
  std::string_view last;
  std::size_t longest = 0;
  while (source->Next(&line, &eol)) {
    ++count;
    longest = std::max(longest, line.size());
    if (count == 200001) {
      EXPECT_EQ(eol, "\r\n");
    }
    last = line;
  }
  EXPECT_EQ(count, 200002);
  EXPECT_EQ(longest, (3u << 20) + 2);
  EXPECT_EQ(last, "G1 X-1");
  std::filesystem::remove_all(dir);
  EXPECT_EQ(LineSource::Open(dir / "none.ngc").status().code(), StatusCode::kNotFound);
}

}  // namespace
}  // namespace formloop::nc
