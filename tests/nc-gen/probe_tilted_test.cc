// Probing programs with tilted approaches (a separating experiment, issue 20; nc-gen/probe_program.h
// ProbeProgramOptions::approaches): the controlled point is the stylus-ball centre, which starts the
// clearance back along the approach from its contact position (nominal point + R·n) and probes along the
// approach to the search end. LinuxCNC's program is run through its own interpreter (rs274) and the
// probing motions compared with that geometry; Fanuc and Sinumerik probe to the same search end;
// Heidenhain's cycle 444 cannot carry a tilt and refuses, like an approach that does not come down
// onto the part.

#include <array>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <numbers>
#include <sstream>
#include <string>
#include <vector>

#include <gtest/gtest.h>

#include "metrology/probe.h"
#include "nc-gen/probe_program.h"
#include "tests/support/rs274.h"

namespace formloop::nc {
namespace {

// Three points: on a flat top, on a slope facing +x, on one facing −y (ids 1..3).
metrology::ProbingPlan Plan() {
  const std::array<std::array<double, 6>, 3> rows = {
      {{-8.0, 4.0, 1.0, 0, 0, 1}, {2.0, -6.0, 3.5, 0.6, 0, 0.8}, {10.0, 2.0, -0.5, 0, -0.6, 0.8}}};
  metrology::ProbingPlan plan;
  for (std::size_t k = 0; k < rows.size(); ++k) {
    metrology::ProbePoint p;
    p.id = static_cast<std::int64_t>(k + 1);
    p.point = Eigen::Vector3d(rows[k][0], rows[k][1], rows[k][2]);
    p.normal = Eigen::Vector3d(rows[k][3], rows[k][4], rows[k][5]).normalized();
    plan.points.push_back(p);
  }
  return plan;
}

// Point 1 along −n; points 2 and 3 tilted by 30° toward +y and −x.
std::vector<Eigen::Vector3d> Approaches(const metrology::ProbingPlan& plan) {
  const double tilt = 30.0 * std::numbers::pi / 180.0;
  std::vector<Eigen::Vector3d> out = {-plan.points[0].normal};
  for (const auto& [k, toward] : std::vector<std::pair<int, Eigen::Vector3d>>{{1, {0, 1, 0}}, {2, {-1, 0, 0}}}) {
    const Eigen::Vector3d& n = plan.points[static_cast<std::size_t>(k)].normal;
    const Eigen::Vector3d d = (toward - toward.dot(n) * n).normalized();
    out.push_back((-std::cos(tilt) * n + std::sin(tilt) * d).normalized());
  }
  return out;
}

ProbeProgramOptions Options() {
  ProbeProgramOptions o;
  o.post.title = "formloop tilted probing";
  o.post.decimals = 4;
  o.safe_z_mm = 20;
  o.linuxcnc_log_file = "probe.log";
  return o;
}

TEST(ProbeTiltedTest, LinuxCncProbesAlongTheApproachAsItsInterpreterRunsIt) {
  if (!testing::Rs274Installed()) GTEST_SKIP() << "rs274 (Debian linuxcnc-uspace) not installed";
  const metrology::ProbingPlan plan = Plan();
  ProbeProgramOptions o = Options();
  o.approaches = Approaches(plan);
  const auto text = PostProbing(plan, "linuxcnc", o);
  ASSERT_TRUE(text.ok()) << text.status().message();
  // The LOG line names each point's approach.
  for (std::size_t i = 0; i < plan.points.size(); ++i) {
    const Eigen::Vector3d& a = o.approaches[i];
    char expected[160];
    std::snprintf(expected, sizeof expected, "(LOG,point %lld #5061 #5062 #5063 #5070 %.9f %.9f %.9f)",
                  static_cast<long long>(plan.points[i].id), a.x() + 0.0, a.y() + 0.0, a.z() + 0.0);  // no "-0"
    EXPECT_NE(text->find(expected), std::string::npos) << expected << "\n" << *text;
  }
  const auto dir = std::filesystem::temp_directory_path() / ("formloop-tilted-" + std::to_string(::getpid()));
  std::filesystem::create_directories(dir);
  std::ofstream(dir / "probe.ngc") << *text;
  int code = 0;
  std::string console;
  const testing::Canon canon = testing::ParseCanon(testing::RunRs274(dir / "probe.ngc", &code, &console));
  std::filesystem::remove_all(dir);
  ASSERT_EQ(code, 0) << console;
  std::vector<const testing::CanonMove*> probes;
  for (const auto& m : canon.moves) {
    if (m.kind == testing::CanonKind::kProbe) probes.push_back(&m);
  }
  ASSERT_EQ(probes.size(), plan.points.size());
  for (std::size_t i = 0; i < plan.points.size(); ++i) {
    const auto& p = plan.points[i];
    const Eigen::Vector3d& a = o.approaches[i];
    const Eigen::Vector3d centre = p.point + o.ball_radius_mm * p.normal;
    const Eigen::Vector3d start = centre - o.clearance_mm * a, end = centre + o.search_mm * a;
    // 4 decimals in the program: half a unit of the last one per axis.
    EXPECT_LT((probes[i]->start - start).cwiseAbs().maxCoeff(), 0.6e-4) << "point " << p.id << " probe start";
    EXPECT_LT((probes[i]->p - end).cwiseAbs().maxCoeff(), 0.6e-4) << "point " << p.id << " probe end";
    // The probing motion runs along a (from the start through the contact position to the search end).
    const Eigen::Vector3d along = (probes[i]->p - probes[i]->start).normalized();
    EXPECT_GT(along.dot(a), 1 - 1e-6) << "point " << p.id;
  }
  // The tilted points really are tilted: 30° between the probing motion and −n.
  const Eigen::Vector3d along = (probes[1]->p - probes[1]->start).normalized();
  EXPECT_NEAR(std::acos(along.dot(-plan.points[1].normal)) * 180.0 / std::numbers::pi, 30.0, 0.01);
}

TEST(ProbeTiltedTest, FanucAndSinumerikProbeToTheSameSearchEnd) {
  const metrology::ProbingPlan plan = Plan();
  ProbeProgramOptions o = Options();
  o.approaches = Approaches(plan);
  const Eigen::Vector3d end =
      plan.points[1].point + o.ball_radius_mm * plan.points[1].normal + o.search_mm * o.approaches[1];
  char x[32];
  std::snprintf(x, sizeof x, "X%.4f", end.x());
  for (const char* dialect : {"fanuc", "sinumerik"}) {
    const auto text = PostProbing(plan, dialect, o);
    ASSERT_TRUE(text.ok()) << dialect << ": " << text.status().message();
    const std::string probe_word = std::string(dialect) == "fanuc" ? "G31 " : "MEAS=1 G1 ";
    const auto at = text->find(probe_word + x);
    EXPECT_NE(at, std::string::npos) << dialect << ": no probing move to " << x << "\n" << *text;
  }
}

TEST(ProbeTiltedTest, HeidenhainAndBadApproachesAreRefused) {
  const metrology::ProbingPlan plan = Plan();
  ProbeProgramOptions o = Options();
  o.approaches = Approaches(plan);
  const auto heidenhain = PostProbing(plan, "heidenhain", o);
  ASSERT_FALSE(heidenhain.ok());
  EXPECT_NE(heidenhain.status().message().find("probe point 2"), std::string::npos) << heidenhain.status().message();
  EXPECT_NE(heidenhain.status().message().find("cycle 444"), std::string::npos) << heidenhain.status().message();
  // Along −n everywhere (the approaches given, none tilted): Heidenhain writes its program.
  o.approaches = {-plan.points[0].normal, -plan.points[1].normal, -plan.points[2].normal};
  EXPECT_TRUE(PostProbing(plan, "heidenhain", o).ok());
  // An approach from below, one too steep, a wrong count: refused naming the point, nothing written.
  o.approaches = Approaches(plan);
  o.approaches[2] = Eigen::Vector3d(0, 0, 1);
  auto refused = PostProbing(plan, "linuxcnc", o);
  ASSERT_FALSE(refused.ok());
  EXPECT_NE(refused.status().message().find("probe point 3"), std::string::npos) << refused.status().message();
  const double steep = 70.0 * std::numbers::pi / 180.0;
  o.approaches[2] =
      (-std::cos(steep) * plan.points[2].normal + std::sin(steep) * Eigen::Vector3d(1, 0, 0)).normalized();
  EXPECT_FALSE(PostProbing(plan, "linuxcnc", o).ok());
  o.approaches.pop_back();
  EXPECT_FALSE(PostProbing(plan, "linuxcnc", o).ok());
}

}  // namespace
}  // namespace formloop::nc
