// The distributed program as LinuxCNC reads it (issue 23, "What it must show" 2). A program with lines,
// kept and split arcs in G17, G18 and G19, a helix and a rapid, three key points and both kinds of
// interval (constant and changing deviation), is distributed by formloop and read by LinuxCNC's
// `rs274 -g`:
//   - the input with its markers turned into comments gives rs274's uncorrected path, which is the
//     path written in the program (the input with the markers as they are is refused by rs274: M57 is
//     no LinuxCNC code);
//   - rs274 accepts the output (the markers are comments there), and every one of its canonical moves
//     matches the corrected path computed here from rs274's own uncorrected moves (lengths of lines,
//     arcs and helices by this test's own polyline integration, the deviation interpolated linearly in
//     path length between the markers): straight end points within q/2 + rs274's printing (1e-4 mm),
//     kept arcs at λ = 0, 1/4, 1/2, 3/4, 1 within 2e-4 mm, split arcs with every vertex on the corrected
//     curve and every chord within the chord tolerance ε = 0.001 mm (+ rounding) of it.

#include <cmath>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <string>
#include <vector>

#include <gtest/gtest.h>

#include "nc-gen/path_deviation.h"
#include "tests/support/rs274.h"
#include "tests/support/test_dir.h"

namespace formloop::nc {
namespace {

using Eigen::Vector3d;
using testing::Canon;
using testing::CanonKind;
using testing::CanonMove;

const char* kProgram =
    "%\n"
    "(formloop distribution check)\n"
    "G21 G90 G17 G94\n"
    "G0 X0 Y0 Z5\n"
    "G0 X0 Y0 Z0\n"
    "M57\n"
    "G1 X10. F600\n"
    "G3 X20. Y10. I0 J10.\n"
    "G1 X25. Y12.\n"
    "M59 P1\n"
    "G1 X35. Y12.\n"
    "G2 X45. Y12. R5.\n"
    "G3 X45. Y12. I-3. J0\n"
    "G18 G2 X55. Z0 I5. K0\n"
    "G17 G1 X60. Y12.\n"
    "M59 P2\n"
    "G2 X60. Y2. Z-1. I0 J-5.\n"
    "G1 X70. Y2. Z-1.\n"
    "G19 G3 Y12. Z-1. J5. K0\n"
    "G17\n"
    "M59 P3\n"
    "G1 X80. Y12. Z0\n"
    "G0 Z5.\n"
    "M58\n"
    "G0 X0 Y0\n"
    "M30\n"
    "%\n";

// End points of the program's motions as written (the uncorrected path).
const std::vector<Vector3d> kNominalEnds = {
    {0, 0, 5},   {0, 0, 0},   {10, 0, 0},  {20, 10, 0}, {25, 12, 0},  {35, 12, 0}, {45, 12, 0}, {45, 12, 0},
    {55, 12, 0}, {60, 12, 0}, {60, 2, -1}, {70, 2, -1}, {70, 12, -1}, {80, 12, 0}, {80, 12, 5}, {0, 0, 5}};

DeviationTable Table() {
  DeviationTable t;
  EXPECT_TRUE(t.Add({.index = 1, .d_mm = Vector3d(0.004, -0.002, 0.001)}).ok());
  EXPECT_TRUE(t.Add({.index = 2, .d_mm = Vector3d(0.004, -0.002, 0.001)}).ok());
  EXPECT_TRUE(t.Add({.index = 3, .d_mm = Vector3d(-0.003, 0.005, 0.002)}).ok());
  return t;
}

// The test's own length of a canonical move (arcs by a fine polyline).
double LengthOf(const CanonMove& m) {
  if (m.kind != CanonKind::kArc) return (m.p - m.start).norm();
  double length = 0;
  Vector3d previous = m.ArcPoint(0);
  for (int i = 1; i <= 20000; ++i) {
    const Vector3d p = m.ArcPoint(i / 20000.0);
    length += (p - previous).norm();
    previous = p;
  }
  return length;
}

Vector3d PointOf(const CanonMove& m, double lambda) {
  return m.kind == CanonKind::kArc ? m.ArcPoint(lambda) : Vector3d(m.start + lambda * (m.p - m.start));
}

double DistanceToSegment(const Vector3d& p, const Vector3d& a, const Vector3d& b) {
  const Vector3d ab = b - a;
  const double t = ab.squaredNorm() > 0 ? std::clamp((p - a).dot(ab) / ab.squaredNorm(), 0.0, 1.0) : 0.0;
  return (a + t * ab - p).norm();
}

class DistributeRs274Test : public ::testing::Test {
 protected:
  void SetUp() override {
    if (!testing::Rs274Installed()) GTEST_SKIP() << "rs274 not found (Debian linuxcnc-uspace): skipped";
    dir_ = testing::FreshTestDir("formloop-distribute-rs274");
  }
  void TearDown() override {
    if (!dir_.empty()) std::filesystem::remove_all(dir_);
  }
  Canon Run(const std::string& name, const std::string& text, int* code, std::string* console) {
    std::ofstream(dir_ / name) << text;
    return testing::ParseCanon(testing::RunRs274(dir_ / name, code, console));
  }
  std::filesystem::path dir_;
};

TEST_F(DistributeRs274Test, Rs274AcceptsTheOutputAndItsMovesAreTheCorrectedPath) {
  int code = 0;
  std::string console;
  // The markers are not LinuxCNC codes.
  Run("raw.ngc", kProgram, &code, &console);
  EXPECT_NE(code, 0);
  EXPECT_NE(console.find("M57"), std::string::npos) << console;
  // Markers as comments: the uncorrected path, as written.
  std::string stripped;
  {
    std::istringstream in(kProgram);
    for (std::string line; std::getline(in, line);) {
      stripped += (line.rfind("M5", 0) == 0 ? "(" + line + ")" : line) + "\n";
    }
  }
  const Canon nominal = Run("stripped.ngc", stripped, &code, &console);
  ASSERT_EQ(code, 0) << console;
  ASSERT_EQ(nominal.moves.size(), kNominalEnds.size());
  for (std::size_t i = 0; i < kNominalEnds.size(); ++i) {
    EXPECT_LE((nominal.moves[i].p - kNominalEnds[i]).norm(), 1e-9) << "nominal move " << i;
  }
  // Distribute.
  DistributeOptions options;
  options.decimals_mm = 4;
  const DeviationTable table = Table();
  DistributeReport report;
  const auto out = DistributeText(kProgram, table, options, &report);
  ASSERT_TRUE(out.ok()) << out.status().message();
  const Canon corrected = Run("out.ngc", *out, &code, &console);
  ASSERT_EQ(code, 0) << console << "\n" << *out;
  int applied = 0;
  for (const auto& c : corrected.comment_texts) applied += c.find("APPLIED BY FORMLOOP") != std::string::npos;
  EXPECT_EQ(applied, 5);

  // The deviation at every motion's start and end, from the marker positions in rs274's nominal output.
  const std::size_t n = nominal.moves.size();
  std::vector<Vector3d> delta_start(n, Vector3d::Zero()), delta_end(n, Vector3d::Zero());
  std::vector<std::pair<std::size_t, Vector3d>> keys;  // (motion index where the marker stands, D)
  for (const auto& [at, text] : nominal.comments_at) {
    if (text == "M57" || text == "M58") keys.emplace_back(at, Vector3d::Zero());
    if (text.rfind("M59 P", 0) == 0) keys.emplace_back(at, table.Find(std::stol(text.substr(5)))->d_mm);
  }
  ASSERT_EQ(keys.size(), 5u);
  for (std::size_t k = 0; k + 1 < keys.size(); ++k) {
    const auto [b, d0] = keys[k];
    const auto [e, d1] = keys[k + 1];
    double total = 0;
    for (std::size_t i = b; i < e; ++i) total += LengthOf(nominal.moves[i]);
    double s = 0;
    for (std::size_t i = b; i < e; ++i) {
      delta_start[i] = d0 + (d1 - d0) * (s / total);
      s += LengthOf(nominal.moves[i]);
      delta_end[i] = d0 + (d1 - d0) * (s / total);
    }
  }
  // Walk rs274's corrected moves against the nominal ones.
  const double q = 1e-4, eps = 0.001;
  std::size_t j = 0, kept = 0, split = 0, segments = 0;
  double worst_end = 0, worst_arc = 0, worst_vertex = 0, worst_chord = 0;
  for (std::size_t i = 0; i < n && j < corrected.moves.size(); ++i) {
    const CanonMove& m = nominal.moves[i];
    const Vector3d target = m.p + delta_end[i];
    // Returns a Vector3d, not `auto`: an Eigen expression returned from the lambda would refer to PointOf's
    // temporary after it is gone (ASan: stack-use-after-return; the sanitizer run found it).
    auto corrected_at = [&](double lambda) -> Vector3d {
      return PointOf(m, lambda) + delta_start[i] + lambda * (delta_end[i] - delta_start[i]);
    };
    const CanonMove& c = corrected.moves[j];
    if (m.kind != CanonKind::kArc || c.kind == CanonKind::kArc) {
      ASSERT_EQ(c.kind, m.kind) << "nominal move " << i << ", corrected move " << j;
      worst_end = std::max(worst_end, (c.p - target).norm());
      EXPECT_LE((c.p - target).norm(), std::sqrt(3.0) * q + 1e-9) << "move " << i;
      if (m.kind == CanonKind::kArc) {
        ++kept;
        for (double lambda : {0.0, 0.25, 0.5, 0.75, 1.0}) {
          const double d = (c.ArcPoint(lambda) - corrected_at(lambda)).norm();
          worst_arc = std::max(worst_arc, d);
          EXPECT_LE(d, 2e-4) << "kept arc " << i << " at " << lambda;
        }
      }
      ++j;
      continue;
    }
    // Split arc: straight feeds up to the corrected end point.
    ++split;
    const std::size_t first = j;
    while (j < corrected.moves.size() && (corrected.moves[j].p - target).norm() > std::sqrt(3.0) * q + 1e-9) ++j;
    ASSERT_LT(j, corrected.moves.size()) << "split arc " << i << " never reaches its corrected end";
    const std::size_t count = j - first + 1;
    segments += count;
    for (std::size_t k = 0; k < count; ++k) {
      const CanonMove& seg = corrected.moves[first + k];
      ASSERT_EQ(seg.kind, CanonKind::kFeed);
      const double l0 = static_cast<double>(k) / count, l1 = static_cast<double>(k + 1) / count;
      const double vertex = (seg.p - corrected_at(l1)).norm();
      worst_vertex = std::max(worst_vertex, vertex);
      EXPECT_LE(vertex, std::sqrt(3.0) * q) << "split arc " << i << " vertex " << k;
      for (int s = 0; s <= 16; ++s) {
        const double d = DistanceToSegment(corrected_at(l0 + (l1 - l0) * s / 16.0), seg.start, seg.p);
        worst_chord = std::max(worst_chord, d);
      }
    }
    ++j;
  }
  EXPECT_EQ(j, corrected.moves.size());
  EXPECT_LE(worst_chord, eps + 2 * q);
  EXPECT_EQ(kept, 3u);   // R-form semicircle, full circle, G18 semicircle (constant deviation)
  EXPECT_EQ(split, 3u);  // the quarter, the helix, the G19 arc (changing deviation)
  EXPECT_EQ(report.arcs_kept, kept);
  EXPECT_EQ(report.arcs_split, split);
  std::printf(
      "[rs274] distributed program: %zu nominal moves, %zu corrected moves; %zu arcs kept, %zu split into "
      "%zu segments; max |end - expected| %.2g mm, kept arcs %.2g mm, split vertices %.2g mm, chords %.2g mm "
      "(eps %.3g)\n",
      n, corrected.moves.size(), kept, split, segments, worst_end, worst_arc, worst_vertex, worst_chord, eps);
}

}  // namespace
}  // namespace formloop::nc
