// The simulated machine's probe surface (cnc/linuxcnc_probe_surface.h) without LinuxCNC: the quadric
// through each reference surface, the HAL net's trip distance against the exact surface, the set-up
// pose, and the HAL text it emits. tests/linuxcnc runs the same nets inside LinuxCNC.

#include "cnc/linuxcnc_probe_surface.h"

#include <gtest/gtest.h>

#include <charconv>
#include <cmath>
#include <regex>
#include <set>
#include <sstream>

#include "core/random.h"

namespace formloop::cnc {
namespace {

using Eigen::Vector3d;

const std::vector<std::string> kQuadrics = {"plane",         "sphere_cap", "cylinder",
                                            "ellipsoid_cap", "saddle",     "tilted_paraboloid"};

TEST(LinuxCncProbeSurfaceTest, QuadricThroughEachQuadricReferenceSurfaceVanishesOnIt) {
  Rng rng(25);
  for (const std::string& name : kQuadrics) {
    const auto surface = recon::MakeReferenceSurface(name);
    ASSERT_TRUE(surface.ok());
    const auto f = QuadricThrough(**surface);
    ASSERT_TRUE(f.ok()) << name << ": " << f.status().message();
    EXPECT_EQ(f->IsPlane(), name == "plane") << name;
    const recon::ParamDomain d = (*surface)->domain();
    double worst_mm = 0;
    for (int k = 0; k < 200; ++k) {
      const double u = rng.Uniform(d.u_min, d.u_max), v = rng.Uniform(d.v_min, d.v_max);
      const Vector3d p = (*surface)->Point(u, v), n = (*surface)->Normal(u, v);
      const Vector3d g = f->Gradient(p);
      worst_mm = std::max(worst_mm, std::abs(f->Evaluate(p)) / g.norm());
      EXPECT_GT(g.dot(n), 0) << name << ": F must grow towards the probe";
      EXPECT_NEAR(g.normalized().dot(n), 1.0, 1e-9) << name;
      EXPECT_GT(f->Evaluate(p + 0.01 * n), 0) << name;
      EXPECT_LT(f->Evaluate(p - 0.01 * n), 0) << name;
    }
    EXPECT_LT(worst_mm, 1e-9) << name;
  }
}

TEST(LinuxCncProbeSurfaceTest, SurfacesThatAreNotQuadricsAreRefusedNamingThoseThatAre) {
  for (const char* name : {"egg_box", "franke", "blade"}) {
    const auto surface = recon::MakeReferenceSurface(name);
    ASSERT_TRUE(surface.ok());
    const auto f = QuadricThrough(**surface);
    ASSERT_FALSE(f.ok()) << name;
    EXPECT_EQ(f.status().code(), StatusCode::kBadInput);
    EXPECT_NE(f.status().message().find("not a plane or a quadric"), std::string::npos) << f.status().message();
    for (const std::string& q : kQuadrics) EXPECT_NE(f.status().message().find(q), std::string::npos) << q;
  }
}

// The net trips where the ball centre is the ball radius from the surface, to a nanometre, for every
// quadric; planes and spheres need one fixed-point step.
TEST(LinuxCncProbeSurfaceTest, NetTripsAtTheBallRadiusWithinANanometre) {
  for (const std::string& name : kQuadrics) {
    ProbeSurfaceOptions o;
    o.surface = name;
    o.ball_radius_mm = 1.0;
    const auto built = BuildProbeSurface(o);
    ASSERT_TRUE(built.ok()) << name << ": " << built.status().message();
    const ProbeSurfaceReport& r = built->report;
    std::printf("[probe surface] %-18s %d step(s), %3d HAL components, max trip error %.4f nm over %d points\n",
                name.c_str(), r.iterations, r.components, r.max_trigger_error_nm, r.checked_points);
    EXPECT_LE(r.max_trigger_error_nm, 1.0) << name;
    EXPECT_EQ(r.checked_points, 21 * 21);
    if (name == "plane" || name == "sphere_cap" || name == "cylinder") {
      EXPECT_EQ(r.iterations, 1) << name;
    }
    if (name == "plane") {
      EXPECT_EQ(r.components, 2) << "a plane is two sums";
    }
  }
}

// An independent check of one net: along the normal of random points (not the build's grid) the gap
// changes sign at r, and far above the surface it is positive (no early trip).
TEST(LinuxCncProbeSurfaceTest, GapChangesSignAtTheBallRadiusAtRandomPoints) {
  ProbeSurfaceOptions o;
  o.surface = "saddle";
  o.ball_radius_mm = 2.0;
  const auto built = BuildProbeSurface(o);
  ASSERT_TRUE(built.ok()) << built.status().message();
  const auto surface = recon::MakeReferenceSurface("saddle");
  Rng rng(7);
  for (int k = 0; k < 100; ++k) {
    const double u = rng.Uniform(-50, 50), v = rng.Uniform(-40, 40);
    const Vector3d p = (*surface)->Point(u, v), n = (*surface)->Normal(u, v);
    EXPECT_GT(built->net.Evaluate(p + (2.0 + 2e-6) * n), 0) << u << " " << v;
    EXPECT_LT(built->net.Evaluate(p + (2.0 - 2e-6) * n), 0) << u << " " << v;
    EXPECT_GT(built->net.Evaluate(p + 30.0 * n), 0);
    EXPECT_GT(built->net.Evaluate(p + Vector3d(0, 0, 2.5)), 0) << "straight above, 2.5 mm: no contact yet";
  }
}

// Shifted by s and rotated by ω about the part origin, the surface is where R(ω)p + s says: the net
// trips at r from the placed surface and about s·n + (ω × p)·n away from the nominal one.
TEST(LinuxCncProbeSurfaceTest, PlacedSurfaceIsShiftedAndRotatedAboutThePartOrigin) {
  ProbeSurfaceOptions o;
  o.surface = "saddle";
  o.pose.shift_um = Vector3d(0, 0, 20);
  o.pose.rotation_urad = Vector3d(0.01 * M_PI / 180 * 1e6, 0, 0);  // 0.01° about x
  const auto built = BuildProbeSurface(o);
  ASSERT_TRUE(built.ok()) << built.status().message();
  EXPECT_LE(built->report.max_trigger_error_nm, 1.0);
  const auto surface = recon::MakeReferenceSurface("saddle");
  for (const auto& [u, v] : std::vector<std::pair<double, double>>{{0, 0}, {40, 30}, {-45, -35}, {10, -20}}) {
    const Vector3d p = (*surface)->Point(u, v), n = (*surface)->Normal(u, v);
    const Vector3d w = o.pose.rotation_urad * 1e-6;
    const double expected_mm = (o.pose.shift_um * 1e-3 + w.cross(p)).dot(n);
    // Bisection along the nominal normal for the trip distance minus r.
    double lo = 1.0 + expected_mm - 1e-3, hi = 1.0 + expected_mm + 1e-3;
    ASSERT_LT(built->net.Evaluate(p + lo * n), 0);
    ASSERT_GT(built->net.Evaluate(p + hi * n), 0);
    for (int i = 0; i < 60; ++i) {
      const double mid = 0.5 * (lo + hi);
      (built->net.Evaluate(p + mid * n) < 0 ? lo : hi) = mid;
    }
    // First order in ω and in the tilt of the normal: within 2 nm here.
    EXPECT_NEAR(0.5 * (lo + hi) - 1.0, expected_mm, 2e-6) << u << " " << v;
  }
}

// The HAL text: one loadrt per component type, every component added to the thread once, every
// constant written so that it reads back to the same double.
TEST(LinuxCncProbeSurfaceTest, HalTextLoadsAddsAndSetsEveryComponentExactly) {
  ProbeSurfaceOptions o;
  o.surface = "ellipsoid_cap";
  o.pose.shift_um = Vector3d(3, -4, 5);
  const auto built = BuildProbeSurface(o);
  ASSERT_TRUE(built.ok()) << built.status().message();
  const std::string hal = built->net.Hal("psurf", "servo-thread", {"pos-x", "pos-y", "pos-z"}, "probe-gap");
  std::istringstream in(hal);
  int loaded = 0, added = 0, set = 0;
  std::set<std::string> names, outputs;
  for (std::string line; std::getline(in, line);) {
    std::istringstream w(line);
    std::string verb;
    w >> verb;
    if (verb == "loadrt") {
      std::string type, list;
      w >> type >> list;
      ASSERT_EQ(list.rfind("names=", 0), 0u) << line;
      std::stringstream items(list.substr(6));
      for (std::string name; std::getline(items, name, ',');) {
        EXPECT_TRUE(names.insert(name).second) << name;
        ++loaded;
      }
    } else if (verb == "addf") {
      std::string name, thread;
      w >> name >> thread;
      EXPECT_TRUE(names.count(name)) << "addf before loadrt: " << name;
      EXPECT_EQ(thread, "servo-thread");
      ++added;
    } else if (verb == "setp") {
      std::string pin, value;
      w >> pin >> value;
      double x = 0;
      const auto r = std::from_chars(value.data(), value.data() + value.size(), x);
      EXPECT_TRUE(r.ec == std::errc() && r.ptr == value.data() + value.size()) << line;
      ++set;
    } else if (verb == "net") {
      std::string signal, arrow, pin;
      w >> signal >> arrow >> pin;
      if (arrow == "<=") {
        EXPECT_TRUE(outputs.insert(signal).second) << "one writer per signal: " << signal;
      }
    }
  }
  EXPECT_EQ(loaded, built->report.components);
  EXPECT_EQ(added, built->report.components);
  EXPECT_GT(set, 0);
  EXPECT_TRUE(outputs.count("probe-gap")) << hal;
}

TEST(LinuxCncProbeSurfaceTest, BadOptionsAreRefusedNamingTheField) {
  ProbeSurfaceOptions o;
  o.ball_radius_mm = 0;
  EXPECT_NE(BuildProbeSurface(o).status().message().find("ball_radius_mm"), std::string::npos);
  o = {};
  o.pose.shift_um = Vector3d(0, 0, 5000);
  EXPECT_NE(BuildProbeSurface(o).status().message().find("pose"), std::string::npos);
  o = {};
  o.surface = "no_such_surface";
  EXPECT_EQ(BuildProbeSurface(o).status().code(), StatusCode::kNotFound);
}

}  // namespace
}  // namespace formloop::cnc
