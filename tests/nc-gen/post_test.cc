// Tool path, LinuxCNC post and its reader, safety limits, probing program, mirror compensation.

#include <array>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>

#include <sys/wait.h>
#include <unistd.h>

#include <gtest/gtest.h>

#include "metrology/probe.h"
#include "nc-gen/compensation.h"
#include "nc-gen/post.h"
#include "nc-gen/probe_program.h"
#include "nc-gen/toolpath.h"
#include "reconstruction/analytic_surface.h"
#include "reconstruction/bspline_surface.h"
#include "tests/support/rs274.h"

namespace formloop::nc {
namespace {

recon::BSplineSurface Saddle() {
  auto s = recon::MakeReferenceSurface("saddle");
  recon::FitReport report;
  auto q = recon::FitAnalytic(*s.value(), 30, 30, {}, 0, 1, &report);
  EXPECT_TRUE(q.ok());
  return q.value();
}

ToolpathOptions CoarseOptions() {
  ToolpathOptions o;
  o.tool.radius_mm = 3.0;
  o.scallop_um = 5.0;
  o.max_point_spacing_mm = 2.0;
  return o;
}

TEST(ToolpathTest, StepOverMeetsTheScallopFormulaAndCentresAreOffsetAlongTheNormal) {
  const auto q = Saddle();
  const auto path = PlanRaster(q, CoarseOptions());
  ASSERT_TRUE(path.ok()) << path.status().message();
  // Flat-surface bound: h = s²/(8 r) → s = sqrt(8 r h) = sqrt(8 · 3 · 0.005) = 0.3464 mm; the saddle's
  // curvature across the passes (|κ| ≤ 1/150) changes it by well under 5 %.
  EXPECT_NEAR(path->max_step_over_mm, std::sqrt(8 * 3 * 0.005), 0.05 * 0.3464);
  EXPECT_EQ(path->gouge_risk_points, 0);
  for (std::size_t k = 0; k < path->points.size(); k += 97) {
    const ClPoint& cl = path->points[k];
    if (cl.kind != ClKind::kCut) continue;  // leads are off Q
    EXPECT_NEAR((cl.centre - cl.cc).norm(), 3.0, 1e-12);
    EXPECT_NEAR((cl.centre - cl.cc).normalized().dot(q.Normal(cl.u, cl.v)), 1.0, 1e-12);
    EXPECT_NEAR((cl.tip - (cl.centre - Eigen::Vector3d(0, 0, 3))).norm(), 0.0, 1e-12);
  }
  // Zig-zag: pass 1 runs against pass 0.
  const auto first_of = [&](int pass) {
    for (const auto& cl : path->points) {
      if (cl.pass == pass) return cl.u;
    }
    return 0.0;
  };
  EXPECT_LT(first_of(0), first_of(1));
}

TEST(PostTest, LinuxCncProgramReadsBackToTheToolpath) {
  const auto path = PlanRaster(Saddle(), CoarseOptions());
  ASSERT_TRUE(path.ok());
  PostOptions post;
  post.title = "test";
  const auto text = PostLinuxCnc(*path, post);
  ASSERT_TRUE(text.ok()) << text.status().message();
  EXPECT_NE(text->find("G21 G90 G17"), std::string::npos);
  EXPECT_NE(text->find("M30"), std::string::npos);
  EXPECT_EQ(text->find(','), std::string::npos) << "numbers must not depend on the locale";
  const auto moves = ReadLinuxCncMoves(*text, "test.ngc");
  ASSERT_TRUE(moves.ok()) << moves.status().message();
  std::vector<Eigen::Vector3d> feeds;
  for (const auto& m : *moves) {
    if (!m.rapid) feeds.push_back(m.tip);
  }
  ASSERT_EQ(feeds.size(), path->points.size());
  double worst = 0;
  for (std::size_t k = 0; k < feeds.size(); ++k)
    worst = std::max(worst, (feeds[k] - path->points[k].tip).cwiseAbs().maxCoeff());
  EXPECT_LE(worst, 0.5e-4 + 1e-12);  // 4 decimals: half a unit in the last place
  // Block numbers do not disturb the reader.
  post.block_numbers = true;
  const auto numbered = PostLinuxCnc(*path, post);
  ASSERT_TRUE(numbered.ok());
  EXPECT_NE(numbered->find("N10 G21"), std::string::npos);
  EXPECT_EQ(ReadLinuxCncMoves(*numbered, "n.ngc")->size(), moves->size());
}

TEST(PostTest, RefusesToPostBeyondTheMachineLimits) {
  const auto path = PlanRaster(Saddle(), CoarseOptions());
  ASSERT_TRUE(path.ok());
  PostOptions post;
  post.limits.travel_max_mm = Eigen::Vector3d(40, 300, 200);  // the saddle reaches X = 50 (+ tool)
  const auto text = PostLinuxCnc(*path, post);
  ASSERT_FALSE(text.ok());
  EXPECT_EQ(text.status().code(), StatusCode::kSafetyLimit);
  EXPECT_NE(text.status().message().find("X "), std::string::npos) << text.status().message();
  EXPECT_NE(text.status().message().find("no program was written"), std::string::npos);
  PostOptions fast;
  fast.limits.max_feed_mm_per_min = 1000;  // below the 1500 mm/min feed
  EXPECT_EQ(PostLinuxCnc(*path, fast).status().code(), StatusCode::kSafetyLimit);
  PostOptions spindle;
  spindle.limits.max_spindle_rpm = 6000;
  EXPECT_EQ(PostLinuxCnc(*path, spindle).status().code(), StatusCode::kSafetyLimit);
}

TEST(PostTest, ReaderRejectsWhatItCannotReadWithTheLine) {
  const auto r = ReadLinuxCncMoves("G21 G90\nG1 X1 Y2 Z3 F100\nG2 X1 Y1 I0.5 J0\n", "hand.ngc");
  ASSERT_FALSE(r.ok());
  EXPECT_NE(r.status().message().find("hand.ngc:3"), std::string::npos) << r.status().message();
  const auto inch = ReadLinuxCncMoves("G20\nG1 X1\n", "inch.ngc");
  EXPECT_NE(inch.status().message().find("inch.ngc:1"), std::string::npos);
}

TEST(ProbeProgramTest, EveryPointProbesAlongMinusTheNormal) {
  const auto q = Saddle();
  const auto plan = metrology::PlanProbingGrid(q, 5, 4, 0.05);
  ASSERT_TRUE(plan.ok());
  ProbeProgramOptions options;
  options.ball_radius_mm = 1.0;
  options.safe_z_mm = 40;
  const auto text = PostLinuxCncProbing(*plan, options);
  ASSERT_TRUE(text.ok()) << text.status().message();
  EXPECT_NE(text->find("(PROBEOPEN probe_results.txt)"), std::string::npos);
  EXPECT_NE(text->find("(PROBECLOSE)"), std::string::npos);
  std::size_t count = 0, pos = 0;
  while ((pos = text->find("G38.2", pos)) != std::string::npos) {
    ++count;
    ++pos;
  }
  EXPECT_EQ(count, 20u);
  EXPECT_NE(text->find("(point 20)"), std::string::npos);
  options.post.limits.travel_max_mm.z() = 30;  // safe Z 40 is above the travel
  EXPECT_EQ(PostLinuxCncProbing(*plan, options).status().code(), StatusCode::kSafetyLimit);
}

TEST(CompensationTest, MirrorOffsetIsMinusDsAlongTheNormalAndVerifiesFromThePrograms) {
  const auto q = Saddle();
  const auto path = PlanRaster(q, CoarseOptions());
  ASSERT_TRUE(path.ok());
  // d_s = 10 µm + 5 µm · u/50: material left everywhere, more at +u.
  const SystematicField field = [](double u, double) { return 0.010 + 0.005 * u / 50.0; };
  const auto comp = CompensateToolpath(*path, field, "test field", {});
  ASSERT_TRUE(comp.ok());
  for (std::size_t k = 0; k < path->points.size(); k += 53) {
    const ClPoint& a = path->points[k];
    const ClPoint& b = comp->path.points[k];
    // Leads are off Q and keep their place; cut points move by −d_s·n.
    const Eigen::Vector3d expected =
        a.kind == ClKind::kCut ? Eigen::Vector3d(-field(a.u, a.v) * a.normal) : Eigen::Vector3d::Zero();
    EXPECT_NEAR((b.cc - a.cc - expected).norm(), 0.0, 1e-12);
    EXPECT_NEAR((b.tip - a.tip - expected).norm(), 0.0, 1e-12);
  }
  PostOptions post;
  const auto nominal_text = PostLinuxCnc(*path, post);
  const auto comp_text = PostLinuxCnc(comp->path, post);
  ASSERT_TRUE(nominal_text.ok() && comp_text.ok());
  const auto a = ReadLinuxCncMoves(*nominal_text, "a");
  const auto b = ReadLinuxCncMoves(*comp_text, "b");
  auto copy = comp.value();
  ASSERT_TRUE(AssignProgramLines(*a, *b, &copy).ok());
  const auto disagreement = VerifyCompensation(*a, *b, copy);
  ASSERT_TRUE(disagreement.ok());
  EXPECT_LE(*disagreement, 0.1 * std::sqrt(3.0) + 1e-9);  // two roundings of 0.05 µm per axis
  // A tampered program is caught.
  auto moves = *b;
  for (auto& m : moves) {
    if (!m.rapid) {
      m.tip.z() += 0.002;
      break;
    }
  }
  EXPECT_GT(*VerifyCompensation(*a, moves, copy), 1.9);
  // Offsets beyond the limit are refused.
  const SystematicField huge = [](double, double) { return 0.5; };
  EXPECT_EQ(CompensateToolpath(*path, huge, "x", {}).status().code(), StatusCode::kSafetyLimit);
}

TEST(PostTest, CommentsNeverNestParentheses) {
  EXPECT_EQ(CommentText("part a (loop 0) \n"), "part a [loop 0]  ");
  PostOptions post;
  post.title = "title (with parentheses)";
  const auto text = PostLinuxCnc(PlanRaster(Saddle(), CoarseOptions()).value(), post);
  ASSERT_TRUE(text.ok());
  EXPECT_NE(text->find("(title [with parentheses])"), std::string::npos);
}

// LinuxCNC's own interpreter (Debian linuxcnc-uspace, installed by scripts/setup.sh) must accept the
// cutting and the probing program and turn them into exactly our moves.
std::string RunRs274(const std::filesystem::path& program, int* exit_code) {
  std::string console;
  const std::string canon_text = testing::RunRs274(program, exit_code, &console);
  return canon_text + "\n--- rs274 output ---\n" + console;
}

std::size_t Count(const std::string& text, const std::string& word) {
  std::size_t count = 0;
  for (std::size_t pos = text.find(word); pos != std::string::npos; pos = text.find(word, pos + 1)) ++count;
  return count;
}

TEST(PostTest, LinuxCncInterpreterAcceptsProgramsAndProbing) {
  if (!testing::Rs274Installed()) {
    GTEST_SKIP() << "rs274 not found: install Debian's linuxcnc-uspace (scripts/setup.sh does)";
  }
  const auto q = Saddle();
  const auto path = PlanRaster(q, CoarseOptions());
  ASSERT_TRUE(path.ok());
  PostOptions post;
  post.title = "formloop test (nested) program";
  const auto text = PostLinuxCnc(*path, post);
  const auto plan = metrology::PlanProbingGrid(q, 6, 5, 0.05);
  ProbeProgramOptions probe_options;
  probe_options.safe_z_mm = 40;
  probe_options.post.title = "probing (test)";
  const auto probe_text = PostLinuxCncProbing(*plan, probe_options);
  ASSERT_TRUE(text.ok() && probe_text.ok());
  const auto dir = std::filesystem::temp_directory_path() / ("formloop-rs274-" + std::to_string(::getpid()));
  std::filesystem::create_directories(dir);
  std::ofstream(dir / "p.ngc") << *text;
  std::ofstream(dir / "probe.ngc") << *probe_text;
  int code = 0;
  const std::string canon = RunRs274(dir / "p.ngc", &code);
  EXPECT_EQ(code, 0) << canon.substr(canon.size() > 2000 ? canon.size() - 2000 : 0);
  EXPECT_EQ(Count(canon, "STRAIGHT_FEED"), path->points.size());
  EXPECT_GE(Count(canon, "USE_LENGTH_UNITS(CANON_UNITS_MM)"), 1u);  // at start-up and for our G21
  EXPECT_EQ(Count(canon, "CANON_UNITS_INCHES"), 0u);
  const std::string probe_canon = RunRs274(dir / "probe.ngc", &code);
  EXPECT_EQ(code, 0) << probe_canon.substr(probe_canon.size() > 2000 ? probe_canon.size() - 2000 : 0);
  EXPECT_EQ(Count(probe_canon, "STRAIGHT_PROBE"), 30u);
  std::filesystem::remove_all(dir);
}

}  // namespace
}  // namespace formloop::nc
