// M57/M58/M59 distribution (nc-gen/path_deviation.h): the acceptance checks of spec/path-deviation.md §8
// (output resolution q = 0.0001 mm, comparisons to ±q/2), the chord tolerance of split arcs against the
// corrected curve computed here, and every refusal of §7 with its code, its line and no output file.

#include <cmath>
#include <filesystem>
#include <fstream>
#include <numbers>
#include <sstream>
#include <string>
#include <vector>

#include <gtest/gtest.h>

#include "core/atomic_file.h"
#include "nc-gen/path_deviation.h"
#include "tests/support/rs274.h"
#include "tests/support/test_dir.h"

namespace formloop::nc {
namespace {

using Eigen::Vector2d;
using Eigen::Vector3d;

DeviationTable Table(const std::vector<std::pair<long, Vector3d>>& entries) {
  DeviationTable table;
  for (const auto& [index, d] : entries) EXPECT_TRUE(table.Add({.index = index, .d_mm = d}).ok());
  return table;
}

DistributeOptions FineOptions() {
  DistributeOptions o;
  o.decimals_mm = 4;  // spec §8: q = 0.0001 mm
  return o;
}

std::vector<std::string> Lines(const std::string& text) {
  std::vector<std::string> lines;
  std::istringstream in(text);
  for (std::string l; std::getline(in, l);) lines.push_back(l);
  return lines;
}

std::string Distribute(const std::string& program, const DeviationTable& table,
                       DistributeOptions options = FineOptions(), DistributeReport* report = nullptr) {
  const auto out = DistributeText(program, table, options, report);
  EXPECT_TRUE(out.ok()) << out.status().message();
  return out.ok() ? *out : std::string();
}

Status Refusal(const std::string& program, const DeviationTable& table, DistributeOptions options = FineOptions()) {
  return DistributeText(program, table, options).status();
}

// Numbers of the word `letter` on a line ("G1 X50.0015 F100" -> X = 50.0015).
double WordValue(const std::string& line, char letter) {
  const auto at = line.find(letter);
  EXPECT_NE(at, std::string::npos) << line << " has no " << letter;
  return at == std::string::npos ? std::nan("") : std::strtod(line.c_str() + at + 1, nullptr);
}

TEST(PathDeviationTest, KeyPointMovesByExactlyItsDeviation) {
  // §8.1: M57 at X0 Y0 Z0; X50, X100, M59 P1 with D1 = (0.003, 0, 0); X200; M58.
  const std::string program = "G21 G90 G17\nG0 X0 Y0 Z0\nM57\nG1 X50. F100\nG1 X100.\nM59 P1\nG1 X200.\nM58\nM30\n";
  const auto out = Lines(Distribute(program, Table({{1, Vector3d(0.003, 0, 0)}})));
  ASSERT_EQ(out.size(), 9u);
  EXPECT_EQ(out[3], "G1 X50.0015 F100");
  EXPECT_EQ(out[4], "G1 X100.003");
  EXPECT_EQ(out[6], "G1 X200.");  // Δ is back to 0 at M58: unchanged
  EXPECT_EQ(out[2], "(M57 COMPENSATED REGION START - APPLIED BY FORMLOOP)");
  EXPECT_EQ(out[5].rfind("(M59 P1 KEY POINT DEVIATION X0.003 Y0. Z0. MM", 0), 0u) << out[5];
  EXPECT_EQ(out[8], "M30");
}

TEST(PathDeviationTest, SeedExampleMidpointGetsTheAverage) {
  // §8.2: D = −1 µm at P1, four straight 25 mm blocks, +3 µm at P2: ends 0, +1, +2, +3 µm; the middle of
  // the path (the end of the second block) +1 µm, the mean of the two key points.
  const std::string program =
      "G21 G90\nG0 X0 Y0 Z0\nM57\nG1 X10. F100\nM59 P1\nG1 X35.\nG1 X60.\nG1 X85.\nG1 X110.\nM59 P2\nG1 X120.\nM58\n";
  DistributeReport report;
  const auto out = Lines(
      Distribute(program, Table({{1, Vector3d(-0.001, 0, 0)}, {2, Vector3d(0.003, 0, 0)}}), FineOptions(), &report));
  EXPECT_NEAR(WordValue(out[3], 'X'), 9.999, 1e-9);
  EXPECT_NEAR(WordValue(out[5], 'X') - 35, 0.000, 1e-9);
  EXPECT_NEAR(WordValue(out[6], 'X') - 60, 0.001, 1e-9);
  EXPECT_NEAR(WordValue(out[7], 'X') - 85, 0.002, 1e-9);
  EXPECT_NEAR(WordValue(out[8], 'X') - 110, 0.003, 1e-9);
  EXPECT_EQ(out[10], "G1 X120.");
  ASSERT_EQ(report.interval_list.size(), 3u);
  EXPECT_NEAR(report.interval_list[1].length_mm, 100, 1e-12);
  EXPECT_NEAR(report.interval_list[1].gradient, 0.004 / 100, 1e-15);
  EXPECT_EQ(report.interval_list[1].corrected, 3u);  // X35 keeps its text: Δ = 0 there
}

// The corrected arc of §5: P'(λ) = P(λ) + Δ_(k−1) + λ·δ_k, computed here for a circle in the XY plane.
Vector3d CorrectedArcPoint(const Vector2d& centre, double r, double theta0, double sweep, double lambda,
                           const Vector3d& delta_prev, const Vector3d& drift) {
  const double t = theta0 + lambda * sweep;
  return Vector3d(centre.x() + r * std::cos(t), centre.y() + r * std::sin(t), 0) + delta_prev + lambda * drift;
}

double DistanceToSegment(const Vector3d& p, const Vector3d& a, const Vector3d& b) {
  const Vector3d ab = b - a;
  const double t = std::clamp((p - a).dot(ab) / ab.squaredNorm(), 0.0, 1.0);
  return (a + t * ab - p).norm();
}

TEST(PathDeviationTest, LengthWeightingOverALineAndASplitArc) {
  // §8.3: from M57 at (0, 0): G1 X10, G3 X20 Y10 I0 J10 (L = 15.70796), M59 P1 with D1 = (0, 0.005, 0).
  const std::string program =
      "G21 G90 G17\nG0 X0 Y0 Z0\nM57\nG1 X10. F300\nG3 X20. Y10. I0 J10.\nM59 P1\nG1 Z5.\nM58\n";
  DistributeReport report;
  const auto out = Lines(Distribute(program, Table({{1, Vector3d(0, 0.005, 0)}}), FineOptions(), &report));
  const double total = 10 + 5 * std::numbers::pi;
  ASSERT_NEAR(report.interval_list[0].length_mm, 25.70796, 1e-5);
  EXPECT_NEAR(0.005 / total, 1.94492e-4, 1e-9);
  EXPECT_NEAR(WordValue(out[3], 'Y'), 0.0019, 1e-12);  // the line's end: 10 × R = 0.00194
  // 56 straight moves replace the arc (ε = 0.001 mm, r = 10: θ_max = 1.6206°).
  EXPECT_EQ(report.arcs_split, 1u);
  EXPECT_EQ(report.segments, 56u);
  std::vector<Vector3d> vertices;
  for (std::size_t i = 4; i < 4 + 56; ++i) {
    vertices.emplace_back(WordValue(out[i], 'X'), WordValue(out[i], 'Y'), WordValue(out[i], 'Z'));
  }
  EXPECT_EQ(out[4].rfind("G1 X", 0), 0u) << out[4];
  EXPECT_EQ(out[4 + 56].rfind("(M59 P1", 0), 0u);
  EXPECT_NEAR((vertices[27] - Vector3d(17.0711, 2.9324, 0)).norm(), 0, 1e-9);  // the middle vertex (λ = 1/2)
  EXPECT_NEAR((vertices[55] - Vector3d(20.0, 10.005, 0)).norm(), 0, 1e-9);
  // Every vertex lies on the corrected curve (radius 10 about the moving centre, to the rounding of the
  // output), and every chord stays within ε of the corrected curve.
  const double q = 1e-4;
  const double rate = 0.005 / total;
  const Vector3d delta_prev(0, 10 * rate, 0);
  const Vector3d drift(0, 5 * std::numbers::pi * rate, 0);
  double worst_vertex = 0, worst_chord = 0;
  Vector3d previous = Vector3d(10, 0, 0) + delta_prev;  // where the controller starts the arc (rounded: 10, 0.0019)
  previous.y() = 0.0019;
  for (int i = 0; i < 56; ++i) {
    const double lambda = (i + 1) / 56.0;
    const Vector3d expected =
        CorrectedArcPoint(Vector2d(10, 10), 10, -std::numbers::pi / 2, std::numbers::pi / 2, lambda, delta_prev, drift);
    const Vector3d centre_now = Vector3d(10, 10, 0) + delta_prev + lambda * drift;
    worst_vertex = std::max(worst_vertex, std::abs((expected - centre_now).norm() - 10));  // exact: 1e-15
    EXPECT_NEAR((vertices[i] - expected).norm(), 0, std::sqrt(2.0) * q / 2 + 1e-12) << "vertex " << i;
    for (int s = 0; s <= 20; ++s) {
      const double mu = (i + s / 20.0) / 56.0;
      const Vector3d curve =
          CorrectedArcPoint(Vector2d(10, 10), 10, -std::numbers::pi / 2, std::numbers::pi / 2, mu, delta_prev, drift);
      worst_chord = std::max(worst_chord, DistanceToSegment(curve, previous, vertices[i]));
    }
    previous = vertices[i];
  }
  EXPECT_LE(worst_vertex, 1e-9);
  EXPECT_LE(worst_chord, 0.001 + std::sqrt(2.0) * q);
  EXPECT_GT(worst_chord, 0.0009);  // the bound is reached (sagitta 0.00098): the check can fail
}

TEST(PathDeviationTest, ArcsStayArcsForAConstantDeviation) {
  // §8.4: between P1 and P2 with the same D = (0.002, −0.001, 0): every end point moves by D, every arc
  // keeps its words, the block count does not change.
  const std::string program =
      "G21 G90 G17\nG0 X0 Y0 Z0\nM57\nG1 X5. F300\nM59 P1\nG1 X10.\nG3 X20. Y10. I0 J10.\nG2 X30. Y0 R10.\n"
      "G3 X30. Y0 I-5. J0\nG18 G2 X40. Z0 I5. K0\nG17 G1 X50.\nM59 P2\nG1 X60.\nM58\n";
  const DeviationTable table = Table({{1, Vector3d(0.002, -0.001, 0)}, {2, Vector3d(0.002, -0.001, 0)}});
  DistributeReport report;
  const auto out = Lines(Distribute(program, table, FineOptions(), &report));
  const auto in = Lines(program);
  ASSERT_EQ(out.size(), in.size());
  EXPECT_EQ(out[5], "G1 X10.002");  // the controller is at Y-0.001 already (block 4 wrote it)
  EXPECT_EQ(out[6], "G3 X20.002 Y9.999 I0 J10.");
  EXPECT_EQ(out[7], "G2 X30.002 Y-0.001 R10.");
  EXPECT_EQ(out[8], "G3 X30.002 Y-0.001 I-5. J0");  // a full circle stays one
  EXPECT_EQ(out[9], "G18 G2 X40.002 Z0 I5. K0");
  EXPECT_EQ(out[10], "G17 G1 X50.002");
  EXPECT_EQ(out[3], "G1 X5.002 F300 Y-0.001");
  EXPECT_EQ(report.interval_list[1].arcs_kept, 4u);
  EXPECT_EQ(report.arcs_split, 0u);
}

TEST(PathDeviationTest, DriftAlongTheNormalMakesAHelix) {
  // §8.5: a quarter arc at Z0, the only motion of an interval going from 0 to (0, 0, 0.004): one G3 with
  // the same I/J and Z0.004.
  const std::string program = "G21 G90 G17\nG0 X10 Y0 Z0\nM57\nG3 X20. Y10. I0 J10. F300\nM59 P1\nG1 Z5.\nM58\n";
  const auto out = Lines(Distribute(program, Table({{1, Vector3d(0, 0, 0.004)}})));
  EXPECT_EQ(out[3], "G3 X20. Y10. I0 J10. F300 Z0.004");
}

TEST(PathDeviationTest, IncrementalStraightMoves) {
  // §8.7: check 1 in G91: X50, X50, M59, X100 give X50.0015, X50.0015, X99.997.
  const std::string program = "G21 G90\nG0 X0 Y0 Z0\nG91\nM57\nG1 X50. F100\nG1 X50.\nM59 P1\nG1 X100.\nM58\nG90\n";
  const auto out = Lines(Distribute(program, Table({{1, Vector3d(0.003, 0, 0)}})));
  EXPECT_EQ(out[4], "G1 X50.0015 F100");
  EXPECT_EQ(out[5], "G1 X50.0015");
  EXPECT_EQ(out[7], "G1 X99.997");
}

TEST(PathDeviationTest, ZeroDeviationsAndLinesOutsideRegionsAreByteIdentical) {
  // §8.8 (CRLF, comments and odd spacing kept): only the marker lines change, into comments.
  const std::string program =
      "%\r\n(shop program)\r\nN10 G21 G90 G17\r\nN20 G0 X0 Y0 Z0 ; start\r\nN30 M57\r\nN40 g1 x 10 y5 f300 (cut)\r\n"
      "N50 G2 X20. Y5. R5.\r\nN60 M59 P1\r\nN70 G1 X30.\r\nN80 M58\r\nN90 G0 Z5\r\n%";
  const std::string out = Distribute(program, Table({{1, Vector3d::Zero()}}));
  const auto a = Lines(program), b = Lines(out);
  ASSERT_EQ(a.size(), b.size());
  for (std::size_t i = 0; i < a.size(); ++i) {
    const bool marker = a[i].find("M57") != std::string::npos || a[i].find("M58") != std::string::npos ||
                        a[i].find("M59") != std::string::npos;
    if (marker) {
      EXPECT_EQ(b[i].rfind(a[i].substr(0, 4) + "(M5", 0), 0u) << b[i];
    } else {
      EXPECT_EQ(a[i], b[i]) << "line " << i + 1;
    }
  }
  EXPECT_EQ(out.back(), '%');
}

TEST(PathDeviationTest, RotaryWordsPassThroughUnderTcpAndAreRefusedWithout) {
  // §8.11.
  const std::string tcp = "G21 G90\nG0 X0 Y0 Z0 A0\nG43.4 H1\nM57\nG1 X50. A30. F100\nM59 P1\nG1 X60.\nM58\nG49\n";
  const auto out = Lines(Distribute(tcp, Table({{1, Vector3d(0.002, 0.001, 0)}})));
  EXPECT_EQ(out[4], "G1 X50.002 A30. F100 Y0.001");
  const Status no_tcp =
      Refusal("G21 G90\nG0 X0 Y0 Z0 A0\nM57\nG1 X50. A30. F100\nM59 P1\nM58\n", Table({{1, Vector3d::Zero()}}));
  EXPECT_NE(no_tcp.message().find("E_ROTARY_NO_TCP"), std::string::npos) << no_tcp.message();
  EXPECT_NE(no_tcp.message().find("program:4:"), std::string::npos) << no_tcp.message();
}

TEST(PathDeviationTest, FanucProgramsKeepTheirNumberFormat) {
  // Least-increment numbers stay as written where nothing changes; corrected words carry a point.
  DistributeOptions o = FineOptions();
  o.reader.dialect = GcodeDialect::kFanuc;
  o.decimals_mm = 3;
  const std::string program =
      "%\nO0001\nG21 G90 G17\nG00 X0 Y0 Z0\nM57\nG01 X50000 F100\nM59 P1\nG01 X60000\nM58\nM30\n%\n";
  const auto out = Lines(Distribute(program, Table({{1, Vector3d(0.004, 0, 0)}}), o));
  EXPECT_EQ(out[5], "G01 X50.004 F100");
  EXPECT_EQ(out[7], "G01 X60000");  // ends at M58, where the deviation is 0: unchanged, no point added
}

struct RefusalCase {
  std::string name, program, code;
  long line = 0;
};

void PrintTo(const RefusalCase& c, std::ostream* os) { *os << c.name; }

class PathDeviationRefusalTest : public ::testing::TestWithParam<RefusalCase> {};

TEST_P(PathDeviationRefusalTest, ClearErrorWithLineAndNothingWritten) {
  const RefusalCase& c = GetParam();
  const DeviationTable table = Table({{1, Vector3d(0.003, 0, 0)}, {2, Vector3d(0.4, 0, 0)}, {3, Vector3d(0.6, 0, 0)}});
  const auto dir = testing::FreshTestDir("formloop-distribute");
  std::ofstream(dir / "in.ngc") << c.program;
  DistributeOptions options = FineOptions();
  options.buffer_max = 3;
  const auto result = DistributeProgram(dir / "in.ngc", dir / "out.ngc", table, options);
  ASSERT_FALSE(result.ok()) << c.name;
  const std::string& m = result.status().message();
  EXPECT_EQ(result.status().code(), StatusCode::kBadInput) << m;
  EXPECT_NE(m.find(c.code), std::string::npos) << m;
  EXPECT_NE(m.find("in.ngc:" + std::to_string(c.line) + ":"), std::string::npos) << m;
  EXPECT_NE(m.find("Fix:"), std::string::npos) << m;
  // Nothing written: no output, no temporary file.
  std::size_t files = 0;
  for (const auto& e : std::filesystem::directory_iterator(dir)) files += e.is_regular_file() ? 1 : 0;
  EXPECT_EQ(files, 1u) << m;
  std::filesystem::remove_all(dir);
}

INSTANTIATE_TEST_SUITE_P(
    Spec, PathDeviationRefusalTest,
    ::testing::Values(
        RefusalCase{"m59_outside", "G21\nG0 X0 Y0 Z0\nG1 X1 F1\nM59 P1\n", "E_M59_OUTSIDE", 4},
        RefusalCase{"nested", "G21\nG0 X0 Y0 Z0\nM57\nG1 X1 F1\nM57\n", "E_NESTED_M57", 5},
        RefusalCase{"missing_m58_at_m30", "G21\nG0 X0 Y0 Z0\nM57\nG1 X1 F1\nM30\n", "E_MISSING_M58", 5},
        RefusalCase{"missing_m58_at_eof", "G21\nG0 X0 Y0 Z0\nM57\nG1 X1 F1\n", "E_MISSING_M58", 3},
        RefusalCase{"m58_outside", "G21\nG0 X0 Y0 Z0\nM58\n", "E_M58_OUTSIDE", 3},
        RefusalCase{"zero_length", "G21\nG0 X0 Y0 Z0\nM57\nM59 P1\nM58\n", "E_ZERO_LENGTH", 4},
        RefusalCase{"index_not_in_table", "G21\nG0 X0 Y0 Z0\nM57\nG1 X1 F1\nM59 P7\nM58\n", "E_NO_DEVIATION", 5},
        RefusalCase{"no_p", "G21\nG0 X0 Y0 Z0\nM57\nG1 X1 F1\nM59\nM58\n", "E_NO_DEVIATION", 5},
        RefusalCase{"deviation_limit", "G21\nG0 X0 Y0 Z0\nM57\nG1 X100 F1\nM59 P3\nG1 X200\nM58\n", "E_DEVIATION_LIMIT",
                    5},
        RefusalCase{"gradient", "G21\nG0 X0 Y0 Z0\nM57\nG1 X1 F1\nM59 P2\nG1 X200\nM58\n", "E_GRADIENT", 5},
        RefusalCase{"unknown_g_word", "G21\nG0 X0 Y0 Z0\nG7.5\nM57\nG1 X1 F1\nM58\n", "E_UNKNOWN_WORD", 3},
        RefusalCase{"unknown_letter", "G21\nG0 X0 Y0 Z0\nM57\nG1 X1 E2 F1\nM58\n", "E_UNKNOWN_WORD", 4},
        RefusalCase{"incremental_arc", "G21\nG0 X0 Y0 Z0\nM57\nG91 G2 X10 Y0 I5 J0 F1\nG90\nM59 P1\nM58\n",
                    "E_INCREMENTAL_ARC", 4},
        RefusalCase{"unit_change", "G21\nG0 X0 Y0 Z0\nM57\nG1 X1 F1\nG20\nG1 X1\nM58\n", "E_UNIT_CHANGE", 5},
        RefusalCase{"reference_return", "G21\nG0 X0 Y0 Z0\nM57\nG28 Z0\nM58\n", "E_UNSUPPORTED_IN_REGION", 4},
        RefusalCase{"canned_cycle", "G21\nG0 X0 Y0 Z0\nM57\nG81 X1 Y1 Z-1 R1 F1\nG80\nM58\n", "E_UNSUPPORTED_IN_REGION",
                    4},
        RefusalCase{"work_system", "G21\nG10 L2 P1 X0 Y0 Z0\nG10 L2 P2 X0 Y0 Z0\nG0 X0 Y0 Z0\nM57\nG55\nM58\n",
                    "E_UNSUPPORTED_IN_REGION", 6},
        RefusalCase{"comp_change", "G21\nG0 X0 Y0 Z0\nM57\nG41 D1 G1 X1 F1\nM58\n", "E_COMP_CHANGE", 4},
        RefusalCase{"inverse_time_split", "G21 G93\nG0 X0 Y0 Z0\nM57\nG1 X10 F1\nG3 X20 Y10 I0 J10 F1\nM59 P1\nM58\n",
                    "E_INVERSE_TIME", 5},
        RefusalCase{"marker_block", "G21\nG0 X0 Y0 Z0\nM57 G1 X5\nM58\n", "E_MARKER_BLOCK", 3},
        RefusalCase{"position_unknown", "G21\nG0 X0 Y0\nM57\nG1 X1 F1\nM58\n", "E_POSITION_UNKNOWN", 3},
        RefusalCase{"buffer", "G21\nG0 X0 Y0 Z0\nM57\nG1 X1 F1\nG1 X2\nG1 X3\nG1 X4\nM58\n", "E_BUFFER_OVERFLOW", 3},
        RefusalCase{"invalid_arc", "G21\nG0 X0 Y0 Z0\nM57\nG2 X10 Y0 I4 J0 F1\nM58\n", "E_ARC_RADIUS", 4}),
    [](const ::testing::TestParamInfo<RefusalCase>& param) { return param.param.name; });

TEST(PathDeviationTest, OutputNeverReplacesTheInput) {
  const auto dir = testing::FreshTestDir("formloop-distribute-same");
  const std::string program = "G21\nG0 X0 Y0 Z0\nM57\nG1 X1 F1\nM59 P1\nM58\n";
  std::ofstream(dir / "p.ngc") << program;
  const auto r = DistributeProgram(dir / "p.ngc", dir / "." / "p.ngc", Table({{1, Vector3d::Zero()}}), FineOptions());
  ASSERT_FALSE(r.ok());
  EXPECT_NE(r.status().message().find("is the input program"), std::string::npos) << r.status().message();
  EXPECT_EQ(*ReadFile(dir / "p.ngc"), program);
  std::filesystem::remove_all(dir);
}

TEST(PathDeviationTest, DeviationTableCsv) {
  const auto table = DeviationTable::Parse(
      "# probing session 7\nindex,dx,dy,dz,unit,session,timestamp\n1,0.003,0,-0.001,mm,s7,2026-01-02T10:00\n"
      "2,0.0001,0,0,inch,s7,2026-01-02T10:01\n",
      "dev.csv");
  ASSERT_TRUE(table.ok()) << table.status().message();
  EXPECT_EQ(table->size(), 2u);
  EXPECT_NEAR(table->Find(2)->d_mm.x(), 0.00254, 1e-15);
  EXPECT_EQ(table->Find(1)->session, "s7");
  const auto repeated = DeviationTable::Parse("index,dx,dy,dz\n1,0,0,0\n1,0,0,0\n", "r.csv");
  EXPECT_NE(repeated.status().message().find("r.csv:3"), std::string::npos) << repeated.status().message();
  const auto nan = DeviationTable::Parse("index,dx,dy,dz\n1,nan,0,0\n", "n.csv");
  EXPECT_NE(nan.status().message().find("E_DEVIATION_LIMIT"), std::string::npos) << nan.status().message();
  const auto header = DeviationTable::Parse("index,dx,dy\n1,0,0\n", "h.csv");
  EXPECT_NE(header.status().message().find("dz"), std::string::npos);
}

TEST(PathDeviationTest, ExplicitDeviationWordsAndImplicitSequence) {
  const std::string explicit_words = "G21 G90\nG0 X0 Y0 Z0\nM57\nG1 X100. F100\nM59 I0.002 J0 K-0.001\nG1 X200.\nM58\n";
  const auto out = Lines(Distribute(explicit_words, DeviationTable()));
  EXPECT_EQ(out[3], "G1 X100.002 F100 Z-0.001");
  DistributeOptions sequential = FineOptions();
  sequential.implicit_sequential = true;
  const std::string program = "G21 G90\nG0 X0 Y0 Z0\nM57\nG1 X100. F100\nM59\nG1 X200.\nM59\nG1 X300.\nM58\n";
  const auto seq =
      Lines(Distribute(program, Table({{1, Vector3d(0.001, 0, 0)}, {2, Vector3d(0.002, 0, 0)}}), sequential));
  EXPECT_EQ(seq[3], "G1 X100.001 F100");
  EXPECT_EQ(seq[5], "G1 X200.002");
}

TEST(PathDeviationTest, ModalArcAfterASplitArcGetsItsMotionCode) {
  // The second block relies on the modal G3; after the first arc is split the written program is in G1,
  // so G3 is written into it.
  const std::string program =
      "G21 G90 G17\nG0 X10 Y0 Z0\nM57\nG3 X20. Y10. I0 J10. F300\nM59 P1\nX10. Y20. I-10. J0\nM59 P2\nG1 Z5.\nM58\n";
  const auto out = Lines(Distribute(program, Table({{1, Vector3d(0.01, 0, 0)}, {2, Vector3d(0.01, 0, 0)}})));
  bool found = false;
  for (const auto& l : out) found |= l.rfind("G3 X10.01 Y20. I-10. J0", 0) == 0;
  std::string all;
  for (const auto& l : out) all += l + "\n";
  EXPECT_TRUE(found) << "no explicit G3 on the modal arc:\n" << all;
}

namespace large {

// A real-sized program (issue 23, "What it must show" 5): 120,000 blocks of a finishing raster (1 mm
// lines, a quarter arc of r = 2 every 10 blocks, a comment every 50), a key point every 1,000 blocks
// and a region every 20 (closed by a 5 mm lift), with deviations of up to 30 µm, so arcs in intervals whose deviation
// changes fast enough are split and the others kept. Every written block is checked against the corrected path computed
// here from the program's own geometry; LinuxCNC's rs274 reads the result (when installed).
struct Nominal {
  bool arc = false;
  Vector3d start = Vector3d::Zero(), end = Vector3d::Zero();
  Vector2d centre = Vector2d::Zero();
  bool ccw = true;
  double length = 0;
  Vector3d At(double lambda) const {
    if (!arc) return start + lambda * (end - start);
    const double t0 = std::atan2(start.y() - centre.y(), start.x() - centre.x());
    const double t = t0 + (ccw ? 1 : -1) * lambda * std::numbers::pi / 2;
    return Vector3d(centre.x() + 2 * std::cos(t), centre.y() + 2 * std::sin(t), 0);
  }
};

TEST(PathDeviationTest, RealSizedProgramIsTransformedCorrectly) {
  std::string program = "%\nG21 G90 G17 G94\nG0 X0 Y0 Z0\nF1200\n";
  std::vector<Nominal> blocks;
  std::vector<std::pair<std::size_t, long>> markers;  // (motion blocks before it, key index; 0 = M57, -1 = M58)
  DeviationTable table;
  double x = 0, y = 0;
  int dir = 1;
  long key = 0;
  char line[128];
  const long kBlocks = 120000;
  long written = 0;
  while (written < kBlocks) {
    program += "M57\n";
    markers.emplace_back(blocks.size(), 0);
    for (int region_key = 0; region_key < 20 && written < kBlocks; ++region_key) {
      for (int k = 0; k < 1000; ++k, ++written) {
        if (k % 50 == 49) {
          program += "(pass)\n";
          continue;
        }
        Nominal b;
        b.start = Vector3d(x, y, 0);
        if (k % 10 == 9) {
          b.arc = true;
          b.ccw = dir > 0;
          b.centre = Vector2d(x, y + 2);
          x += dir * 2;
          y += 2;
          std::snprintf(line, sizeof(line), "%s X%.4f Y%.4f I0 J2.\n", dir > 0 ? "G3" : "G2", x, y);
          b.length = std::numbers::pi;
          if (std::abs(x) > 200) dir = -dir;
        } else {
          x += dir;
          std::snprintf(line, sizeof(line), "G1 X%.4f Y%.4f\n", x, y);
          b.length = 1;
        }
        b.end = Vector3d(x, y, 0);
        program += line;
        blocks.push_back(b);
      }
      ++key;
      EXPECT_TRUE(
          table.Add({.index = key, .d_mm = Vector3d(0.03 * std::sin(1.3 * key), 0.02 * std::cos(0.7 * key), 0)}).ok());
      program += "M59 P" + std::to_string(key) + "\n";
      markers.emplace_back(blocks.size(), key);
    }
    Nominal lift;  // the 5 mm lift that closes the region (the deviation returns to 0 along it)
    lift.start = Vector3d(x, y, 0);
    lift.end = Vector3d(x, y, 5);
    lift.length = 5;
    blocks.push_back(lift);
    program += "G1 Z5.\nM58\nG0 Z0\n";  // (the rapid back down is outside the region)
    markers.emplace_back(blocks.size(), -1);
    Nominal down;
    down.start = lift.end;
    down.end = lift.start;
    blocks.push_back(down);
  }
  program += "M30\n%\n";
  ASSERT_GE(written, 100000);
  // The deviation at the start and end of every motion block, from this test's own lengths.
  std::vector<Vector3d> d_start(blocks.size(), Vector3d::Zero()), d_end(blocks.size(), Vector3d::Zero());
  for (std::size_t m = 0; m + 1 < markers.size(); ++m) {
    const auto [b, k0] = markers[m];
    const auto [e, k1] = markers[m + 1];
    if (k0 == -1) continue;  // from M58 to the next M57: outside every region
    const Vector3d d0 = k0 == 0 ? Vector3d::Zero() : table.Find(k0)->d_mm;
    const Vector3d d1 = k1 <= 0 ? Vector3d::Zero() : table.Find(k1)->d_mm;
    double total = 0;
    for (std::size_t i = b; i < e; ++i) total += blocks[i].length;
    double s = 0;
    for (std::size_t i = b; i < e; ++i) {
      d_start[i] = d0 + (d1 - d0) * (s / total);
      s += blocks[i].length;
      d_end[i] = d0 + (d1 - d0) * (s / total);
    }
  }
  DistributeReport report;
  DistributeOptions options = FineOptions();
  const auto out = DistributeText(program, table, options, &report);
  ASSERT_TRUE(out.ok()) << out.status().message();
  const auto path = ReadProgramPath(*out, {}, "out.ngc");
  ASSERT_TRUE(path.ok()) << path.status().message();
  const double q = 1e-4, tol = std::sqrt(3.0) * q / 2 + 1e-9;
  std::size_t j = 1;  // after the first rapid
  std::size_t kept = 0, split = 0, failures = 0;
  double worst = 0;
  for (std::size_t i = 0; i < blocks.size() && failures < 10; ++i) {
    const Nominal& b = blocks[i];
    const Vector3d target = b.end + d_end[i];
    ASSERT_LT(j, path->moves.size());
    const PathMove& m = path->moves[j];
    if (!b.arc || m.has_arc) {
      const double d = (m.end - target).norm();
      worst = std::max(worst, d);
      if (d > tol) {
        ADD_FAILURE() << "block " << i << " (output line " << m.line << "): " << m.end.transpose() << " vs "
                      << target.transpose();
        ++failures;
      }
      if (b.arc) {
        ++kept;
        for (double lambda : {0.25, 0.5, 0.75}) {
          const Vector3d expected = b.At(lambda) + d_start[i] + lambda * (d_end[i] - d_start[i]);
          EXPECT_LE((m.arc.PointAt(lambda) - expected).norm(), 2 * q) << "kept arc " << i;
        }
      }
      ++j;
      continue;
    }
    ++split;
    const std::size_t first = j;
    while (j < path->moves.size() && (path->moves[j].end - target).norm() > tol) ++j;
    ASSERT_LT(j, path->moves.size()) << "split arc " << i;
    const std::size_t n = j - first + 1;
    for (std::size_t k = 0; k < n; ++k) {
      const double lambda = static_cast<double>(k + 1) / n;
      const Vector3d expected = b.At(lambda) + d_start[i] + lambda * (d_end[i] - d_start[i]);
      EXPECT_LE((path->moves[first + k].end - expected).norm(), tol) << "split arc " << i << " vertex " << k;
    }
    ++j;
  }
  EXPECT_EQ(j, path->moves.size());
  EXPECT_GT(kept, 1000u);
  EXPECT_GT(split, 1000u);
  EXPECT_EQ(report.arcs_kept, kept);
  EXPECT_EQ(report.arcs_split, split);
  std::printf(
      "[large] %ld blocks in, %zu lines out; %zu corrected, %zu arcs kept, %zu split into %zu moves; "
      "max |written - expected| %.3g mm (q = 1e-4)\n",
      written, report.lines_out, report.corrected, kept, split, report.segments, worst);
  if (testing::Rs274Installed()) {  // LinuxCNC reads all of it, to the same number of motions
    const auto folder = testing::FreshTestDir("formloop-distribute-large");
    ASSERT_TRUE(WriteFileAtomic(folder / "out.ngc", *out).ok());
    int code = 0;
    std::string console;
    const testing::Canon canon = testing::ParseCanon(testing::RunRs274(folder / "out.ngc", &code, &console));
    EXPECT_EQ(code, 0) << console.substr(0, 2000);
    EXPECT_EQ(canon.moves.size(), path->moves.size());
    std::filesystem::remove_all(folder);
  }
}

}  // namespace large

}  // namespace
}  // namespace formloop::nc
