// Probing programs in the four dialects (nc-gen/probe_program.h): golden programs byte for byte, locale
// independence, every point id exactly once, the safety refusal naming the point, and the result-range
// limits of Fanuc macro variables and Sinumerik R parameters.
//
// The golden files were written by this implementation once and checked by eye against the dialect notes in
// nc-gen/probe_program.cc (the LinuxCNC one is PostLinuxCncProbing's output as it was before the other
// dialects were added). To rewrite them after an intended change:
//   FORMLOOP_UPDATE_GOLDEN=1 formloop_nc_gen_tests --gtest_filter='ProbeDialect*'

#include <algorithm>
#include <cctype>
#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <locale>
#include <sstream>

#include <gtest/gtest.h>

#include "core/atomic_file.h"
#include "metrology/probe.h"
#include "nc-gen/post.h"
#include "nc-gen/probe_program.h"
#include "tests/support/golden.h"
#include "tests/support/locale.h"

namespace formloop::nc {
namespace {

using formloop::testing::CommaNumpunct;
using formloop::testing::GlobalLocale;

// Three points with negative, positive and zero coordinates, an axial and two tilted normals, and ids
// 1, 2, 17 (so "point 1" must not be counted inside "point 17").
metrology::ProbingPlan SmallPlan() {
  metrology::ProbingPlan plan;
  auto add = [&plan](std::int64_t id, Eigen::Vector3d p, Eigen::Vector3d n) {
    metrology::ProbePoint point;
    point.id = id;
    point.point = p;
    point.normal = n.normalized();
    plan.points.push_back(point);
  };
  add(1, {-10.0, 5.0, 0.0}, {0, 0, 1});
  add(2, {0.0, -7.5, 2.25}, {0.6, 0, 0.8});
  add(17, {12.5, 3.0, -1.5}, {0, -0.6, 0.8});
  return plan;
}

ProbeProgramOptions GoldenOptions() {
  ProbeProgramOptions o;
  o.post.title = "formloop small probing plan (3 points)";
  o.post.decimals = 3;
  o.safe_z_mm = 20;
  return o;
}

std::filesystem::path GoldenPath(const std::string& dialect) { return testing::GoldenPath("probe_small", dialect); }
using testing::ReadGoldenText;

// Occurrences of the word pair "point <id>", case-insensitive ("point 17" is not "point 1", and the
// Heidenhain parameter text "1ST POINT 1ST AXIS" is not "point 1").
int CountPointId(std::string text, std::int64_t id) {
  std::transform(text.begin(), text.end(), text.begin(),
                 [](unsigned char c) { return static_cast<char>(std::tolower(c)); });
  const std::string needle = "point " + std::to_string(id);
  int count = 0;
  for (std::size_t pos = text.find(needle); pos != std::string::npos; pos = text.find(needle, pos + 1)) {
    const std::size_t after = pos + needle.size();
    if (after >= text.size() || !std::isalnum(static_cast<unsigned char>(text[after]))) ++count;
  }
  return count;
}

TEST(ProbeDialectsTest, NamesMatchThePostRegistryAndUnknownDialectsAreRefused) {
  EXPECT_EQ(ProbingDialectNames(), PostNames());
  const auto r = PostProbing(SmallPlan(), "mazatrol", GoldenOptions());
  ASSERT_FALSE(r.ok());
  EXPECT_NE(r.status().message().find("mazatrol"), std::string::npos) << r.status().message();
}

TEST(ProbeDialectsTest, LinuxCncEntryPointsAgree) {
  const auto a = PostProbing(SmallPlan(), "linuxcnc", GoldenOptions());
  const auto b = PostLinuxCncProbing(SmallPlan(), GoldenOptions());
  ASSERT_TRUE(a.ok() && b.ok());
  EXPECT_EQ(*a, *b);
}

class ProbeDialectTest : public ::testing::TestWithParam<std::string> {};

TEST_P(ProbeDialectTest, MatchesTheGoldenFileByteForByte) {
  const auto text = PostProbing(SmallPlan(), GetParam(), GoldenOptions());
  ASSERT_TRUE(text.ok()) << text.status().message();
  const auto golden = GoldenPath(GetParam());
  if (std::getenv("FORMLOOP_UPDATE_GOLDEN") != nullptr) {
    std::ofstream(golden, std::ios::binary) << *text;
    GTEST_SKIP() << "rewrote " << golden;
  }
  ASSERT_TRUE(std::filesystem::exists(golden)) << golden;
  EXPECT_EQ(*text, ReadGoldenText(golden)) << "output of the " << GetParam() << " probing post changed";
}

TEST_P(ProbeDialectTest, CommaDecimalLocaleGivesTheSameProgram) {
  const auto plain = PostProbing(SmallPlan(), GetParam(), GoldenOptions());
  ASSERT_TRUE(plain.ok()) << plain.status().message();
  GlobalLocale comma(std::locale(std::locale::classic(), new CommaNumpunct));
  const auto under_comma = PostProbing(SmallPlan(), GetParam(), GoldenOptions());
  ASSERT_TRUE(under_comma.ok()) << under_comma.status().message();
  EXPECT_EQ(*plain, *under_comma);
}

TEST_P(ProbeDialectTest, EveryPointIdIsMentionedExactlyOnce) {
  const auto text = PostProbing(SmallPlan(), GetParam(), GoldenOptions());
  ASSERT_TRUE(text.ok()) << text.status().message();
  for (const auto& p : SmallPlan().points) EXPECT_EQ(CountPointId(*text, p.id), 1) << "point " << p.id;
}

TEST_P(ProbeDialectTest, OutOfTravelPointIsRefusedByItsId) {
  // Point 17's search end is at z = -1.5 - 0.8 = -2.3 (ball centre, R = 1, search 2); the others stay above -2.
  ProbeProgramOptions options = GoldenOptions();
  options.post.limits.travel_min_mm.z() = -2.0;
  const auto r = PostProbing(SmallPlan(), GetParam(), options);
  ASSERT_FALSE(r.ok());
  EXPECT_EQ(r.status().code(), StatusCode::kSafetyLimit);
  EXPECT_NE(r.status().message().find("probe point 17"), std::string::npos) << r.status().message();
  // And the safe Z above the travel is refused at the first point.
  options = GoldenOptions();
  options.post.limits.travel_max_mm.z() = 15;
  const auto high = PostProbing(SmallPlan(), GetParam(), options);
  ASSERT_FALSE(high.ok());
  EXPECT_EQ(high.status().code(), StatusCode::kSafetyLimit);
  EXPECT_NE(high.status().message().find("probe point 1"), std::string::npos) << high.status().message();
  // A probe feed over the machine's limit.
  options = GoldenOptions();
  options.probe_feed_mm_per_min = 2 * options.post.limits.max_feed_mm_per_min;
  EXPECT_EQ(PostProbing(SmallPlan(), GetParam(), options).status().code(), StatusCode::kSafetyLimit);
}

INSTANTIATE_TEST_SUITE_P(AllDialects, ProbeDialectTest,
                         ::testing::Values("linuxcnc", "fanuc", "heidenhain", "sinumerik"));

TEST(ProbeDialectsTest, FanucProbesWithG31AndCopiesTheSkipPosition) {
  const auto text = PostProbing(SmallPlan(), "fanuc", GoldenOptions());
  ASSERT_TRUE(text.ok()) << text.status().message();
  std::size_t g31 = 0;
  for (std::size_t pos = text->find("G31 "); pos != std::string::npos; pos = text->find("G31 ", pos + 1)) ++g31;
  EXPECT_EQ(g31, 3u);
  // The third point (k = 2) lands in #506..#508.
  EXPECT_NE(text->find("#506=#5061\n#507=#5062\n#508=#5063\n"), std::string::npos) << *text;
}

TEST(ProbeDialectsTest, FanucResultRangeMustFitTheCommonVariables) {
  ProbeProgramOptions options = GoldenOptions();
  options.fanuc_result_base = 991;  // #991..#999: fits exactly
  ASSERT_TRUE(PostProbing(SmallPlan(), "fanuc", options).ok());
  options.fanuc_result_base = 992;  // #992..#1000: one too many
  const auto over = PostProbing(SmallPlan(), "fanuc", options);
  ASSERT_FALSE(over.ok());
  EXPECT_NE(over.status().message().find("#999"), std::string::npos) << over.status().message();
  options.fanuc_result_base = 195;  // #195..#203 crosses out of the #100..#199 block
  EXPECT_FALSE(PostProbing(SmallPlan(), "fanuc", options).ok());
  options.fanuc_result_base = 300;  // not a common variable
  EXPECT_FALSE(PostProbing(SmallPlan(), "fanuc", options).ok());
  options.fanuc_result_base = 100;
  const auto low = PostProbing(SmallPlan(), "fanuc", options);
  ASSERT_TRUE(low.ok()) << low.status().message();
  EXPECT_NE(low->find("#108=#5063"), std::string::npos);
}

TEST(ProbeDialectsTest, SinumerikResultRangeMustFitTheRParameters) {
  ProbeProgramOptions options = GoldenOptions();
  options.sinumerik_r_base = 91;  // R91..R99
  const auto fits = PostProbing(SmallPlan(), "sinumerik", options);
  ASSERT_TRUE(fits.ok()) << fits.status().message();
  EXPECT_NE(fits->find("R99=$AA_MW[Z]"), std::string::npos);
  options.sinumerik_r_base = 92;
  const auto over = PostProbing(SmallPlan(), "sinumerik", options);
  ASSERT_FALSE(over.ok());
  EXPECT_NE(over.status().message().find("R99"), std::string::npos) << over.status().message();
  options.sinumerik_r_last = 199;  // a control configured with more R parameters
  EXPECT_TRUE(PostProbing(SmallPlan(), "sinumerik", options).ok());
}

TEST(ProbeDialectsTest, HeidenhainNumbersBlocksButNotCycleParameterLines) {
  const auto text = PostProbing(SmallPlan(), "heidenhain", GoldenOptions());
  ASSERT_TRUE(text.ok()) << text.status().message();
  std::istringstream in(*text);
  long expected = 0;
  int parameter_lines = 0;
  for (std::string line; std::getline(in, line);) {
    if (line.starts_with("    Q")) {
      ++parameter_lines;
      continue;
    }
    EXPECT_TRUE(line.starts_with(std::to_string(expected) + " ")) << line;
    ++expected;
  }
  EXPECT_EQ(parameter_lines, 3 * 9);
  EXPECT_NE(text->find("Q294=-1.500 ;1ST POINT 3RD AXIS"), std::string::npos) << *text;
}

// Issue 17 item 7: a plan larger than the controller's result storage is split into programs that each fit
// (400 points: Fanuc #500-#999 holds 166, Sinumerik R10-R99 holds 30), every point in exactly one of them, in
// plan order; a plan that fits and the dialects without a limit give one program equal to PostProbing's.
TEST(ProbeDialectsTest, APlanBeyondTheResultStorageIsSplitIntoBatchesThatFit) {
  metrology::ProbingPlan plan;
  for (int k = 0; k < 400; ++k) {
    metrology::ProbePoint p;
    p.id = k + 1;
    p.point = Eigen::Vector3d(-50.0 + 0.25 * k, 10.0 * std::sin(0.1 * k), 1.0);
    p.normal = Eigen::Vector3d::UnitZ();
    plan.points.push_back(p);
  }
  ProbeProgramOptions o = GoldenOptions();
  EXPECT_FALSE(PostProbing(plan, "fanuc", o).ok()) << "one Fanuc program cannot hold 400 results";
  struct Expect {
    const char* dialect;
    std::size_t capacity, programs;
  } const expectations[] = {{"fanuc", 166, 3}, {"sinumerik", 30, 14}, {"linuxcnc", 0, 1}, {"heidenhain", 0, 1}};
  for (const Expect& e : expectations) {
    EXPECT_EQ(FindPost(e.dialect)->ProbeResultCapacity(o), e.capacity) << e.dialect;
    const auto batches = PostProbingBatches(plan, e.dialect, o);
    ASSERT_TRUE(batches.ok()) << e.dialect << ": " << batches.status().ToString();
    ASSERT_EQ(batches->size(), e.programs) << e.dialect;
    for (int id = 1; id <= 400; ++id) {
      int seen = 0;
      for (const std::string& text : *batches) seen += CountPointId(text, id);
      EXPECT_EQ(seen, 1) << e.dialect << " point " << id;
    }
    if (e.programs == 1) {
      EXPECT_EQ(batches->front(), *PostProbing(plan, e.dialect, o)) << e.dialect;
    }
  }
  const auto fanuc = PostProbingBatches(plan, "fanuc", o);
  EXPECT_NE((*fanuc)[0].find("#997=#5063"), std::string::npos) << "166 points fill #500-#997";
  EXPECT_EQ((*fanuc)[0].find("#998"), std::string::npos);
  EXPECT_NE((*fanuc)[2].find("BATCH 3 OF 3, POINTS 333-400"), std::string::npos) << (*fanuc)[2].substr(0, 300);
  // A lower base: #100-#199 holds 33 points.
  o.fanuc_result_base = 100;
  EXPECT_EQ(PostProbingBatches(plan, "fanuc", o)->size(), 13u);
}

}  // namespace
}  // namespace formloop::nc
