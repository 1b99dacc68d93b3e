// core/golden_section.h: the minimum of a smooth function inside the bracket is found to the tolerance
// asked, a minimum on either end of the bracket drives the bracket to that end, the bracket shrinks by
// φ per step with one evaluation each, f is never called on the bracket's ends, and ties go the side
// the options say.

#include "core/golden_section.h"

#include <cmath>
#include <vector>

#include <gtest/gtest.h>

namespace formloop {
namespace {

const double kPhi = (std::sqrt(5.0) - 1) / 2;

TEST(GoldenSectionTest, FindsAKnownMinimumToTheTolerance) {
  // f(x) = (x - 1.3)^2 + 0.5 cosh(x - 1.3): one minimum at 1.3, not symmetric about the bracket's centre.
  auto f = [](double x) { return (x - 1.3) * (x - 1.3) + 0.5 * std::cosh(x - 1.3); };
  const GoldenSectionResult r = GoldenSectionMinimise(f, 0.0, 5.0, {.tolerance = 1e-6});
  EXPECT_LE(r.hi - r.lo, 1e-6);
  EXPECT_LE(r.lo, 1.3);
  EXPECT_GE(r.hi, 1.3);
  EXPECT_NEAR(r.Mid(), 1.3, 1e-6);
  // Steps: the first n with 5 φ^n <= 1e-6 (n = 33: 5 φ^32 = 1.03e-6, 5 φ^33 = 6.3e-7).
  EXPECT_EQ(r.iterations, 33);
  EXPECT_EQ(r.evaluations, r.iterations + 2);
}

TEST(GoldenSectionTest, MinimumOnABracketEndDrivesTheBracketThere) {
  std::vector<double> calls;
  auto rising = [&](double x) {
    calls.push_back(x);
    return 2 * x + 1;
  };
  const GoldenSectionResult left = GoldenSectionMinimise(rising, -1.0, 3.0, {.tolerance = 1e-8});
  EXPECT_EQ(left.lo, -1.0);  // the end itself never moves ...
  EXPECT_LE(left.hi - left.lo, 1e-8);
  for (double x : calls) {  // ... and is never evaluated
    EXPECT_GT(x, -1.0);
    EXPECT_LT(x, 3.0);
  }
  const GoldenSectionResult right = GoldenSectionMinimise([](double x) { return -x; }, -1.0, 3.0, {.tolerance = 1e-8});
  EXPECT_EQ(right.hi, 3.0);
  EXPECT_LE(right.hi - right.lo, 1e-8);
}

TEST(GoldenSectionTest, ShrinksByPhiPerStepAndHonoursTheIterationCap) {
  auto f = [](double x) { return std::abs(x - 0.2); };
  for (int n : {0, 1, 5, 12}) {
    const GoldenSectionResult r = GoldenSectionMinimise(f, 0.0, 1.0, {.tolerance = 0.0, .max_iterations = n});
    EXPECT_EQ(r.iterations, n);
    EXPECT_NEAR(r.hi - r.lo, std::pow(kPhi, n), 1e-12) << n;
    EXPECT_LE(r.lo, 0.2);
    EXPECT_GE(r.hi, 0.2);
  }
  // A coarse tolerance stops early: the first width <= 0.1 is φ^5 = 0.090.
  const GoldenSectionResult coarse = GoldenSectionMinimise(f, 0.0, 1.0, {.tolerance = 0.1});
  EXPECT_EQ(coarse.iterations, 5);
  EXPECT_LE(coarse.hi - coarse.lo, 0.1);
  EXPECT_GT((coarse.hi - coarse.lo) / kPhi, 0.1);  // one step fewer would not have met it
  // An empty bracket is returned as it came, after the two interior evaluations.
  const GoldenSectionResult point = GoldenSectionMinimise(f, 0.7, 0.7);
  EXPECT_EQ(point.lo, 0.7);
  EXPECT_EQ(point.hi, 0.7);
  EXPECT_EQ(point.iterations, 0);
}

TEST(GoldenSectionTest, TiesGoTheSideTheOptionsSay) {
  auto flat = [](double) { return 1.0; };
  const GoldenSectionResult right = GoldenSectionMinimise(flat, 0.0, 1.0, {.tolerance = 1e-3});
  EXPECT_EQ(right.hi, 1.0);
  EXPECT_LE(right.hi - right.lo, 1e-3);
  const GoldenSectionResult left = GoldenSectionMinimise(flat, 0.0, 1.0, {.tolerance = 1e-3, .ties_keep_left = true});
  EXPECT_EQ(left.lo, 0.0);
  EXPECT_LE(left.hi - left.lo, 1e-3);
}

}  // namespace
}  // namespace formloop
