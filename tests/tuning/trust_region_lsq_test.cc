// The trust-region reflective bounded least-squares solver (tuning/trust_region_lsq.h) against SciPy's
// lsq_linear trf/bvls fixtures (tests/tuning/make_lsq_fixtures.py), our own independent BVLS and brute
// force (tests/support/bounded_lsq_check.h) and the KKT certificate (spec/tuning-and-link.md §4.4, §9.9).

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <limits>
#include <string>
#include <vector>

#include <gtest/gtest.h>
#include <Eigen/Dense>
#include <Eigen/SparseCore>

#include "core/json_io.h"
#include "core/random.h"
#include "tests/support/bounded_lsq_check.h"
#include "tests/support/tuning_scenarios.h"
#include "tuning/offset_solve.h"
#include "tuning/trust_region_lsq.h"

namespace formloop::tuning {
namespace {

using Eigen::MatrixXd;
using Eigen::VectorXd;

struct Fixture {
  std::string name;
  Eigen::SparseMatrix<double> a;
  VectorXd b, lb, ub;
  VectorXd x_trf, x_bvls;
  double cost_trf = 0, cost_bvls = 0;
  int status_trf = 0, status_bvls = 0;
};

VectorXd ToVector(const Json& j) {
  VectorXd v(j.size());
  for (std::size_t i = 0; i < j.size(); ++i) v(i) = j[i].get<double>();
  return v;
}

std::vector<Fixture> LoadFixtures() {
  auto json = ReadJsonFile(std::string(FORMLOOP_SOURCE_DIR) + "/tests/tuning/fixtures/lsq_scipy.json");
  EXPECT_TRUE(json.ok()) << json.status().ToString();
  std::vector<Fixture> out;
  if (!json.ok()) return out;
  for (const auto& c : (*json)["cases"]) {
    Fixture f;
    f.name = c["name"];
    std::vector<Eigen::Triplet<double>> t;
    for (const auto& e : c["a_triplets"]) t.emplace_back(e[0].get<int>(), e[1].get<int>(), e[2].get<double>());
    f.a.resize(c["shape"][0].get<int>(), c["shape"][1].get<int>());
    f.a.setFromTriplets(t.begin(), t.end());
    f.b = ToVector(c["b"]);
    f.lb = ToVector(c["lb"]);
    f.ub = ToVector(c["ub"]);
    f.x_trf = ToVector(c["trf"]["x"]);
    f.x_bvls = ToVector(c["bvls"]["x"]);
    f.cost_trf = c["trf"]["cost"];
    f.cost_bvls = c["bvls"]["cost"];
    f.status_trf = c["trf"]["status"];
    f.status_bvls = c["bvls"]["status"];
    out.push_back(std::move(f));
  }
  return out;
}

double RelativeCostError(double f, double f_ref) { return std::abs(f - f_ref) / std::max(1.0, f_ref); }

// Same active set as the reference, apart from components within `slack` of a bound in either solution.
bool SameActiveSet(const VectorXd& x, const VectorXd& ref, const VectorXd& lb, const VectorXd& ub, double slack) {
  for (int i = 0; i < x.size(); ++i) {
    auto state = [&](double v) { return v - lb(i) <= slack ? -1 : (ub(i) - v <= slack ? 1 : 0); };
    auto near = [&](double v) { return std::min(v - lb(i), ub(i) - v) <= 1e-6; };
    if (state(x(i)) != state(ref(i)) && !(near(x(i)) && near(ref(i)))) return false;
  }
  return true;
}

TEST(TrustRegionLsq, MatchesScipyFixturesAndPassesKkt) {
  const auto fixtures = LoadFixtures();
  ASSERT_EQ(fixtures.size(), 104u);
  double worst_cost = 0, worst_x_um = 0, worst_cost_trf = 0;
  int polished = 0, max_iterations = 0;
  for (const auto& f : fixtures) {
    SCOPED_TRACE(f.name);
    auto r = SolveBoundedLsq(f.a, f.b, f.lb, f.ub);
    ASSERT_TRUE(r.ok()) << r.status().ToString();
    EXPECT_NE(r->status, BoundedLsqStatus::kMaxIter);
    // spec §4.4.3: |f − f_ref| ≤ 1e-8·max(1, f_ref); ‖x − x_ref‖∞ ≤ 1e-3 µm; same active set.
    const double cost_err = RelativeCostError(r->cost, f.cost_bvls);
    EXPECT_LE(cost_err, 1e-9) << "cost " << r->cost << " vs bvls " << f.cost_bvls;
    const double x_err = (r->x - f.x_bvls).lpNorm<Eigen::Infinity>();
    EXPECT_LE(x_err, 1e-3) << "µm";
    EXPECT_TRUE(SameActiveSet(r->x, f.x_bvls, f.lb, f.ub, 1e-6));
    // Never worse than SciPy's trf by more than the criterion (it is sometimes less accurate than bvls).
    EXPECT_LE(r->cost, f.cost_trf + 1e-8 * std::max(1.0, f.cost_trf));
    const MatrixXd a = MatrixXd(f.a);
    const auto kkt = testing::KktCertificate(a, f.b, f.lb, f.ub, r->x);
    EXPECT_TRUE(kkt.ok) << "KKT violation " << kkt.worst_violation << " > " << kkt.eps_g;
    worst_cost = std::max(worst_cost, cost_err);
    worst_cost_trf = std::max(worst_cost_trf, RelativeCostError(f.cost_trf, f.cost_bvls));
    worst_x_um = std::max(worst_x_um, x_err);
    polished += r->polished;
    max_iterations = std::max(max_iterations, r->iterations);
  }
  std::printf(
      "104 fixtures: worst |f - f_bvls|/max(1,f) = %.2e (scipy trf vs bvls: %.2e), worst |x - x_bvls| = %.2e um, "
      "polished %d, max iterations %d\n",
      worst_cost, worst_cost_trf, worst_x_um, polished, max_iterations);
}

TEST(TrustRegionLsq, IndependentBvlsAgreesWithScipyBvls) {
  // The test-side BVLS is the cross-check for the random scenarios; check it first against SciPy.
  for (const auto& f : LoadFixtures()) {
    SCOPED_TRACE(f.name);
    const auto r = testing::Bvls(MatrixXd(f.a), f.b, f.lb, f.ub);
    ASSERT_TRUE(r.converged);
    EXPECT_LE(RelativeCostError(r.cost, f.cost_bvls), 1e-9);
  }
}

// Random dense problems with box bounds (no separable structure): the plain dense-Cholesky path.
TEST(TrustRegionLsq, DenseProblemsAgreeWithBruteForce) {
  Rng rng(7);
  for (int trial = 0; trial < 60; ++trial) {
    const int n = 1 + static_cast<int>(rng.UniformIndex(8)), m = n + static_cast<int>(rng.UniformIndex(6));
    MatrixXd a(m, n);
    for (int i = 0; i < m; ++i) {
      for (int j = 0; j < n; ++j) a(i, j) = rng.Normal();
    }
    VectorXd b(m), lb(n), ub(n);
    for (int i = 0; i < m; ++i) b(i) = 3 * rng.Normal();
    for (int j = 0; j < n; ++j) {
      lb(j) = rng.Uniform(-1, 0);
      ub(j) = lb(j) + rng.Uniform(0.1, 1.5);
    }
    SCOPED_TRACE(trial);
    auto r = SolveBoundedLsq(a.sparseView(), b, lb, ub);
    ASSERT_TRUE(r.ok()) << r.status().ToString();
    EXPECT_EQ(r->separable_columns, 1);  // dense: only the last column is (trivially) separable
    const auto brute = testing::BruteForce(a, b, lb, ub);
    EXPECT_LE(RelativeCostError(r->cost, brute.cost), 1e-10) << r->cost << " vs " << brute.cost;
    EXPECT_LE((r->x - brute.x).lpNorm<Eigen::Infinity>(), 1e-7);
    EXPECT_TRUE(testing::KktCertificate(a, b, lb, ub, r->x).ok);
  }
}

// A rank-deficient A (two equal columns, no regularisation): Ĥ is singular on the free set, so the
// Newton directions come from conjugate gradients. f is still unique.
TEST(TrustRegionLsq, RankDeficientUsesConjugateGradientsAndReachesTheOptimum) {
  Rng rng(11);
  const int m = 12, n = 5;
  MatrixXd a(m, n);
  for (int i = 0; i < m; ++i) {
    for (int j = 0; j < n; ++j) a(i, j) = rng.Normal();
  }
  a.col(3) = a.col(1);
  VectorXd b(m);
  for (int i = 0; i < m; ++i) b(i) = 4 * rng.Normal();
  VectorXd lb = VectorXd::Constant(n, -0.5), ub = VectorXd::Constant(n, 0.5);
  auto r = SolveBoundedLsq(a.sparseView(), b, lb, ub);
  ASSERT_TRUE(r.ok());
  EXPECT_GT(r->cg_directions, 0);
  const auto brute = testing::BruteForce(a, b, lb, ub);
  EXPECT_LE(RelativeCostError(r->cost, brute.cost), 1e-9) << r->cost << " vs " << brute.cost;
}

// The 200 × 60 bench problem: 60 bounds become active, one component is driven by the Newton step towards
// a bound its gradient points away from. Without the polish tried on stalling the iteration crawled (255 steps).
TEST(TrustRegionLsq, ManyActiveBoundsWithoutCrawling) {
  const auto sc = testing::MakeTuningScenario(20211102 + 200, 200, 60, {.t_spread = 1.1, .tight_offset_share = 0.2});
  auto form = BuildPenaltyForm(sc.problem);
  ASSERT_TRUE(form.ok());
  auto r = SolveBoundedLsq(form->a, form->b, form->lb, form->ub);
  ASSERT_TRUE(r.ok());
  EXPECT_LE(r->iterations, 40);
  int active = 0;
  for (int a : r->active) active += a != 0;
  EXPECT_EQ(active, 60);
  EXPECT_TRUE(testing::KktCertificate(MatrixXd(form->a), form->b, form->lb, form->ub, r->x).ok);
}

TEST(TrustRegionLsq, InfiniteBoundsAndUnconstrainedStart) {
  // Interior optimum: returned from the start, exactly the least-squares solution.
  MatrixXd a(3, 2);
  a << 1, 0, 0, 1, 1, 1;
  VectorXd b(3);
  b << 1, 2, 3;
  const double inf = std::numeric_limits<double>::infinity();
  VectorXd lb = VectorXd::Constant(2, -inf), ub = VectorXd::Constant(2, inf);
  auto r = SolveBoundedLsq(a.sparseView(), b, lb, ub);
  ASSERT_TRUE(r.ok());
  EXPECT_EQ(r->status, BoundedLsqStatus::kUnconstrained);
  EXPECT_NEAR(r->x(0), 1, 1e-14);
  EXPECT_NEAR(r->x(1), 2, 1e-14);
  // One-sided bound that binds: x1 ≤ 1.5 → x1 = 1.5 exactly (polished), x0 = (1 + 3 − 1.5)/2 = 1.25.
  ub(1) = 1.5;
  r = SolveBoundedLsq(a.sparseView(), b, lb, ub);
  ASSERT_TRUE(r.ok());
  EXPECT_TRUE(r->polished);
  EXPECT_EQ(r->x(1), 1.5);
  EXPECT_NEAR(r->x(0), 1.25, 1e-12);
  EXPECT_EQ(r->active[1], 1);
}

TEST(TrustRegionLsq, BadInputsAreRefused) {
  MatrixXd a = MatrixXd::Identity(2, 2);
  VectorXd b = VectorXd::Ones(2), lb = VectorXd::Zero(2), ub = VectorXd::Ones(2);
  ub(1) = 0;  // lb = ub
  auto r = SolveBoundedLsq(a.sparseView(), b, lb, ub);
  ASSERT_FALSE(r.ok());
  EXPECT_NE(r.status().message().find("lb < ub"), std::string::npos);
  ub(1) = 1;
  b(0) = std::nan("");
  EXPECT_FALSE(SolveBoundedLsq(a.sparseView(), b, lb, ub).ok());
  b(0) = 1;
  BoundedLsqOptions o;
  o.gtol = 0;
  EXPECT_FALSE(SolveBoundedLsq(a.sparseView(), b, lb, ub, o).ok());
}

// Without the polish the bare method still meets the spec's GTOL and lands within o/g of the bounds.
TEST(TrustRegionLsq, BareMethodConvergesWithoutPolish) {
  BoundedLsqOptions o;
  o.polish = false;
  int checked = 0;
  double worst = 0, worst_x = 0;
  for (const auto& f : LoadFixtures()) {
    auto r = SolveBoundedLsq(f.a, f.b, f.lb, f.ub, o);
    ASSERT_TRUE(r.ok());
    EXPECT_FALSE(r->polished);
    EXPECT_NE(r->status, BoundedLsqStatus::kMaxIter) << f.name;
    EXPECT_LE(RelativeCostError(r->cost, f.cost_bvls), 1e-6) << f.name;
    worst = std::max(worst, RelativeCostError(r->cost, f.cost_bvls));
    worst_x = std::max(worst_x, (r->x - f.x_bvls).lpNorm<Eigen::Infinity>());
    ++checked;
  }
  EXPECT_EQ(checked, 104);
  std::printf("without the polish: worst |f - f_bvls|/max(1,f) = %.2e, worst |x - x_bvls| = %.2e um\n", worst, worst_x);
}

}  // namespace
}  // namespace formloop::tuning
