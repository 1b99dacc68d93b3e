// The probe's clearance from the part on a probing program's moves (nc-gen/probe_clearance.h,
// ProbeProgramOptions::part_surface): a point at the bottom of a steep valley probed with a 45° tilt
// starts clearance × sin 45° to the side, under the valley's wall. On a wide valley the clearance is
// shortened until the moves clear the wall (checked here against the exact surface, sample by sample);
// on a narrow one the point is refused naming it and the gap; points that are clear are programmed byte
// for byte as without the check, in all four dialects.

#include <cmath>
#include <cstdio>
#include <numbers>
#include <string>
#include <vector>

#include <gtest/gtest.h>

#include "metrology/probe.h"
#include "nc-gen/probe_program.h"
#include "nc-gen/probe_reach.h"
#include "reconstruction/analytic_surface.h"
#include "reconstruction/foot_point.h"

namespace formloop::nc {
namespace {

// z = x⁴ / L³: a valley along y with a flat bottom and walls that steepen to 76° at |x| = L.
class Valley : public recon::AnalyticSurface {
 public:
  // Over |x| ≤ half_width_mm, |y| ≤ 6.
  Valley(double l_mm, double half_width_mm) : k_(1.0 / (l_mm * l_mm * l_mm)), w_(half_width_mm) {}
  std::string name() const override { return "valley"; }
  std::string description() const override { return "z = x^4 / L^3"; }
  recon::ParamDomain domain() const override { return {-w_, w_, -6, 6}; }
  bool is_graph() const override { return true; }
  recon::SurfaceDerivatives Derivatives(double u, double v) const override {
    recon::SurfaceDerivatives d;
    d.p = Eigen::Vector3d(u, v, k_ * u * u * u * u);
    d.su = Eigen::Vector3d(1, 0, 4 * k_ * u * u * u);
    d.sv = Eigen::Vector3d(0, 1, 0);
    d.suu = Eigen::Vector3d(0, 0, 12 * k_ * u * u);
    d.suv = d.svv = Eigen::Vector3d::Zero();
    return d;
  }

 private:
  double k_, w_;
};

metrology::ProbePoint PointAt(const Valley& q, std::int64_t id, double x, double y) {
  metrology::ProbePoint p;
  p.id = id;
  p.u = x;
  p.v = y;
  p.point = q.Point(x, y);
  p.normal = q.Normal(x, y);
  return p;
}

// Tilted by `deg` from −n towards +x.
Eigen::Vector3d Tilted(const Eigen::Vector3d& n, double deg) {
  const double t = deg * std::numbers::pi / 180;
  const Eigen::Vector3d d = (Eigen::Vector3d::UnitX() - n.x() * n).normalized();
  return (-std::cos(t) * n + std::sin(t) * d).normalized();
}

ProbeProgramOptions Options(const recon::FootPointProjector* part) {
  ProbeProgramOptions o;
  o.post.title = "formloop probing clear of the part";
  o.post.decimals = 4;
  o.safe_z_mm = 30;
  o.clearance_mm = 3;
  o.linuxcnc_log_file = "probe.log";
  if (part != nullptr) o.part_surface = *part;
  return o;
}

// The least gap − requirement over densely sampled positions of the ball (every 10 µm: the gap between
// samples is within 5 µm of theirs), measured on the exact surface: the check's own samples are sparser.
double LeastMargin(const recon::FootPointProjector& part, const Eigen::Vector3d& from, const Eigen::Vector3d& to,
                   double req_from, double req_to, double radius) {
  double least = 1e9;
  const int n = std::max(1, static_cast<int>((to - from).norm() / 0.01));
  for (int i = 0; i <= n; ++i) {
    const double f = static_cast<double>(i) / n;
    const auto foot = part.Project(from + f * (to - from));
    EXPECT_TRUE(foot.ok());
    const double gap = (foot->deviation_mm < 0 ? -foot->distance_mm : foot->distance_mm) - radius;
    least = std::min(least, gap - (req_from + f * (req_to - req_from)));
  }
  return least;
}

// The G0 Z of the descent to `id`'s start in a LinuxCNC program.
double StartZ(const std::string& text, std::int64_t id) {
  const auto at = text.find("(point " + std::to_string(id) + ")");
  EXPECT_NE(at, std::string::npos);
  const auto z = text.find("G0 Z", text.find('\n', text.find('\n', at) + 1));
  return std::stod(text.substr(z + 4));
}

TEST(ProbeClearanceTest, ATiltedPointUnderAWallGetsAShorterClearanceThatClearsIt) {
  const Valley q(4.0, 6.0);  // walls up to z = 20
  const auto part = recon::FootPointProjector::Build(q);
  ASSERT_TRUE(part.ok()) << part.status().message();
  metrology::ProbingPlan plan;
  plan.points = {PointAt(q, 1, 1.0, -3.0), PointAt(q, 2, 0.0, 0.0), PointAt(q, 3, 1.5, 3.0)};
  ProbeProgramOptions o = Options(&*part);
  o.approaches = {-plan.points[0].normal, Tilted(plan.points[1].normal, -45), Tilted(plan.points[2].normal, 20)};
  // Point 2: at the full 3 mm the start (2.12 mm to the side, 2.12 mm up) is within 0.6 mm of the −x wall.
  const Eigen::Vector3d contact = plan.points[1].point + o.ball_radius_mm * plan.points[1].normal;
  const Eigen::Vector3d& a = o.approaches[1];
  const double g_full = std::min(o.min_gap_mm, 0.5 * 3.0 * -a.dot(plan.points[1].normal));
  EXPECT_LT(LeastMargin(*part, contact - 3.0 * a, contact - 0.3 * a, g_full, 0.1 * g_full, 1.0), 0)
      << "the full clearance must collide for this test to mean anything";
  const auto text = PostProbing(plan, "linuxcnc", o);
  ASSERT_TRUE(text.ok()) << text.status().message();
  // Halved: the start 1.5 mm back along the approach; every move clear of the wall (dense samples).
  const Eigen::Vector3d start = contact - 1.5 * a;
  EXPECT_NEAR(StartZ(*text, 2), start.z(), 0.6e-4) << *text;
  const double g = std::min(o.min_gap_mm, 0.5 * 1.5 * -a.dot(plan.points[1].normal));
  const Eigen::Vector3d above(start.x(), start.y(), o.safe_z_mm);
  const double descent = LeastMargin(*part, above, start, g, g, 1.0);
  const double probing = LeastMargin(*part, start, contact - 0.15 * a, g, 0.1 * g, 1.0);
  std::printf(
      "[clearance] valley L = 4 mm, 45 deg tilt at the bottom: clearance 3 -> 1.5 mm; least margin over "
      "the required gap %.4f mm on the descent, %.4f mm on the probing move\n",
      descent, probing);
  EXPECT_GE(descent, -0.006);
  EXPECT_GE(probing, -0.006);
  // Fanuc and Sinumerik start from the same shortened start; Heidenhain refuses the tilt as before.
  char start_words[64];
  std::snprintf(start_words, sizeof start_words, "X%.4f Y%.4f Z%.4f", start.x(), start.y(), start.z());
  for (const char* dialect : {"linuxcnc", "fanuc", "sinumerik"}) {
    const auto other = PostProbing(plan, dialect, o);
    ASSERT_TRUE(other.ok()) << dialect << ": " << other.status().message();
    EXPECT_NE(other->find(start_words), std::string::npos) << dialect << ": no return to " << start_words;
  }
  EXPECT_FALSE(PostProbing(plan, "heidenhain", o).ok());
  // The clear points (1 along −n, 3 tilted 20° on the gentle slope) are programmed as without the check.
  ProbeProgramOptions unchecked = Options(nullptr);
  unchecked.approaches = o.approaches;
  const auto plain = PostProbing(plan, "linuxcnc", unchecked);
  ASSERT_TRUE(plain.ok());
  for (const std::int64_t id : {1, 3}) {
    const std::string mark = "(point " + std::to_string(id) + ")";
    const std::string next = "(point " + std::to_string(id + 1) + ")";
    auto block = [&](const std::string& t) {
      const auto from = t.find(mark);
      return t.substr(from, t.find(id == 3 ? "(PROBECLOSE)" : next.c_str()) - from);
    };
    EXPECT_EQ(block(*text), block(*plain)) << "point " << id;
  }
}

TEST(ProbeClearanceTest, ClearPointsAreProgrammedByteForByteInEveryDialect) {
  const Valley q(4.0, 6.0);  // walls up to z = 20
  const auto part = recon::FootPointProjector::Build(q);
  ASSERT_TRUE(part.ok());
  metrology::ProbingPlan plan;
  for (int i = 0; i < 9; ++i) plan.points.push_back(PointAt(q, i + 1, -2.0 + 0.5 * i, -4.0 + i));
  for (const std::string& dialect : ProbingDialectNames()) {
    const auto checked = PostProbing(plan, dialect, Options(&*part));
    const auto plain = PostProbing(plan, dialect, Options(nullptr));
    ASSERT_TRUE(checked.ok()) << dialect << ": " << checked.status().message();
    ASSERT_TRUE(plain.ok()) << dialect;
    EXPECT_EQ(*checked, *plain) << dialect;
  }
  // Tilted by 30° along the valley (clear of the walls): the same bytes as without the check.
  ProbeProgramOptions o = Options(&*part), unchecked = Options(nullptr);
  for (const auto& p : plan.points) {
    const Eigen::Vector3d along_y = (Eigen::Vector3d::UnitY() - p.normal.y() * p.normal).normalized();
    o.approaches.push_back((-std::cos(std::numbers::pi / 6) * p.normal + 0.5 * along_y).normalized());
  }
  unchecked.approaches = o.approaches;
  for (const char* dialect : {"linuxcnc", "fanuc", "sinumerik"}) {
    const auto checked = PostProbing(plan, dialect, o);
    ASSERT_TRUE(checked.ok()) << dialect << ": " << checked.status().message();
    EXPECT_EQ(*checked, *PostProbing(plan, dialect, unchecked)) << dialect;
  }
}

TEST(ProbeClearanceTest, APointThatCannotBeClearedIsRefusedNamingItAndTheGap) {
  // A narrow valley: the walls stand 4 mm high 1.62 mm from the bottom's axis (z = 9.3 at the edges).
  const Valley q(1.2, 2.0);
  const auto part = recon::FootPointProjector::Build(q);
  ASSERT_TRUE(part.ok());
  metrology::ProbingPlan plan;
  plan.points = {PointAt(q, 7, 0.0, -2.0), PointAt(q, 8, 0.0, 2.0)};
  ProbeProgramOptions o = Options(&*part);
  o.approaches = {-plan.points[0].normal, Tilted(plan.points[1].normal, -45)};
  // Even along −n the ball descends between the valley's rims, 2 mm from its centre, and walls about
  // 1.6 mm from it at z = 4: a gap near 0.6 mm against the 1 mm required, with the clearance halved or
  // quartered too. Every dialect refuses, naming the point and the least gap coming down (0.613 mm, at
  // z = 4).
  for (const std::string& dialect : ProbingDialectNames()) {
    ProbeProgramOptions untilted = Options(&*part);
    metrology::ProbingPlan first;
    first.points = {plan.points[0]};
    const auto refused = PostProbing(first, dialect, untilted);
    ASSERT_FALSE(refused.ok()) << dialect;
    EXPECT_EQ(refused.status().code(), StatusCode::kSafetyLimit) << dialect;
    const std::string& m = refused.status().message();
    EXPECT_NE(m.find("probe point 7: the stylus ball would come within 0.613 mm of the part (1.000 mm required)"),
              std::string::npos)
        << m;
    EXPECT_NE(m.find("mm required) on the descent from safe Z"), std::string::npos) << m;
  }
  // A 0.5 mm gap is enough for point 7; point 8, tilted 45° under the wall, is refused even with the
  // clearance quartered: its start lies inside the wall.
  o.min_gap_mm = 0.5;
  for (const char* dialect : {"linuxcnc", "fanuc", "sinumerik"}) {
    const auto refused = PostProbing(plan, dialect, o);
    ASSERT_FALSE(refused.ok()) << dialect;
    const std::string& m = refused.status().message();
    EXPECT_NE(m.find("probe point 8: the stylus ball would enter the part by "), std::string::npos) << m;
    std::printf("[clearance] %s: %s\n", dialect, m.c_str());
  }
  // Without the tilt point 8 is fine.
  o.approaches[1] = -plan.points[1].normal;
  EXPECT_TRUE(PostProbing(plan, "linuxcnc", o).ok());
}

// `formloop run`'s grid plans: a point no clearance clears is left out of the plan (ReachableProbePoints)
// instead of refusing the program, the rest is programmed with the same checks; too few left: refused.
TEST(ProbeClearanceTest, UnreachablePointsAreLeftOutOfThePlanAndTheRestIsProgrammedClear) {
  const Valley q(1.2, 2.0);  // the narrow valley above: along −n only with a 0.5 mm gap, tilted 45° never
  const auto part = recon::FootPointProjector::Build(q);
  ASSERT_TRUE(part.ok());
  metrology::ProbingPlan plan;
  plan.points = {PointAt(q, 1, 0.0, -4.0), PointAt(q, 2, 0.0, -2.0), PointAt(q, 3, 0.0, 0.0), PointAt(q, 4, 0.0, 2.0),
                 PointAt(q, 5, 0.0, 4.0)};
  ProbeProgramOptions o = Options(&*part);
  o.min_gap_mm = 0.5;
  for (const auto& p : plan.points) o.approaches.push_back(-p.normal);
  o.approaches[1] = Tilted(plan.points[1].normal, -45);
  o.approaches[3] = Tilted(plan.points[3].normal, 45);
  ASSERT_FALSE(PostProbing(plan, "linuxcnc", o).ok())
      << "the whole plan must be refused for this test to mean anything";
  const auto reachable = ReachableProbePoints(plan, o);
  ASSERT_TRUE(reachable.ok()) << reachable.status().message();
  ASSERT_EQ(reachable->left_out.size(), 2u);
  EXPECT_EQ(reachable->left_out[0].id, 2);
  EXPECT_EQ(reachable->left_out[0].index, 1u);
  EXPECT_EQ(reachable->left_out[1].id, 4);
  for (const auto& u : reachable->left_out) {
    EXPECT_EQ(u.reason.rfind("the stylus ball would enter the part by ", 0), 0u) << u.reason;
    EXPECT_EQ(u.reason.find("Fix"), std::string::npos) << u.reason;
    std::printf("[clearance] left out: point %lld: %s\n", static_cast<long long>(u.id), u.reason.c_str());
  }
  ASSERT_EQ(reachable->plan.points.size(), 3u);
  ASSERT_EQ(reachable->approaches.size(), 3u);
  const std::int64_t kept_ids[] = {1, 3, 5};
  for (std::size_t k = 0; k < 3; ++k) {
    EXPECT_EQ(reachable->plan.points[k].id, kept_ids[k]);
    EXPECT_EQ(reachable->approaches[k], o.approaches[2 * k]);
  }
  // The rest is programmed in every dialect with the check on (each traverse from above the last point
  // kept), and every move of the program keeps the gap (dense samples on the exact surface).
  ProbeProgramOptions kept = o;
  kept.approaches = reachable->approaches;
  for (const char* dialect : {"linuxcnc", "fanuc", "sinumerik"}) {
    EXPECT_TRUE(PostProbing(reachable->plan, dialect, kept).ok()) << dialect;
  }
  const auto text = PostProbing(reachable->plan, "linuxcnc", kept);
  ASSERT_TRUE(text.ok());
  EXPECT_EQ(text->find("(point 2)"), std::string::npos);
  EXPECT_EQ(text->find("(point 4)"), std::string::npos);
  for (const auto& p : reachable->plan.points) {
    const Eigen::Vector3d contact = p.point + o.ball_radius_mm * p.normal;
    const Eigen::Vector3d start = contact + o.clearance_mm * p.normal;
    EXPECT_NEAR(StartZ(*text, p.id), start.z(), 0.6e-4) << p.id;
    const Eigen::Vector3d above(start.x(), start.y(), o.safe_z_mm);
    EXPECT_GE(LeastMargin(*part, above, start, 0.5, 0.5, 1.0), -0.006) << p.id;
  }
  // Nothing is left out of a plan whose points all clear, nor without the part's surface.
  ProbeProgramOptions unchecked = Options(nullptr);
  unchecked.approaches = o.approaches;
  const auto all = ReachableProbePoints(plan, unchecked);
  ASSERT_TRUE(all.ok());
  EXPECT_TRUE(all->left_out.empty());
  EXPECT_EQ(all->plan.points.size(), plan.points.size());
  // With the default 1 mm gap no point of the valley's bottom clears: fewer than half remain, refused.
  const auto refused = ReachableProbePoints(plan, Options(&*part));
  ASSERT_FALSE(refused.ok());
  EXPECT_EQ(refused.status().code(), StatusCode::kSafetyLimit);
  const std::string& m = refused.status().message();
  EXPECT_NE(m.find("the probe reaches only 0 of the plan's 5 points clear of the part (at least 50 % needed"),
            std::string::npos)
      << m;
  EXPECT_NE(m.find("e.g. probe point 1: the stylus ball would come within 0.61"), std::string::npos) << m;
  EXPECT_NE(m.find("Fix: "), std::string::npos) << m;
  std::printf("[clearance] %s\n", m.c_str());
}

TEST(ProbeClearanceTest, AConfiguredShankIsKeptClearOfTheWalls) {
  const Valley q(4.0, 6.0);  // walls up to z = 20
  const auto part = recon::FootPointProjector::Build(q);
  ASSERT_TRUE(part.ok());
  metrology::ProbingPlan plan;
  plan.points = {PointAt(q, 4, 0.0, 0.0)};
  ProbeProgramOptions o = Options(&*part);
  EXPECT_TRUE(PostProbing(plan, "linuxcnc", o).ok()) << "the ball alone clears the walls 4 mm away";
  o.shank_radius_mm = 3.5;  // a probe body: the walls at z = 4 are 4 mm from its axis
  const auto refused = PostProbing(plan, "linuxcnc", o);
  ASSERT_FALSE(refused.ok());
  EXPECT_NE(refused.status().message().find("probe point 4: the stylus shank would come within"), std::string::npos)
      << refused.status().message();
  o.shank_radius_mm = 0.5;
  EXPECT_TRUE(PostProbing(plan, "linuxcnc", o).ok());
}

}  // namespace
}  // namespace formloop::nc
