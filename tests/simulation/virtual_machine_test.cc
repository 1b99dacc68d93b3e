// The virtual machine: the swept-ball envelope gives the scallop the planner aimed for, effects add
// up as documented, probe logs follow the probe model, and seeds make runs repeatable.

#include <cmath>

#include <gtest/gtest.h>

#include "metrology/deviations.h"
#include "nc-gen/toolpath.h"
#include "reconstruction/analytic_surface.h"
#include "reconstruction/bspline_surface.h"
#include "simulation/virtual_machine.h"

namespace formloop::sim {
namespace {

struct Scene {
  recon::BSplineSurface q;
  nc::Toolpath path;
  std::vector<CutterLocation> cls;
  metrology::ProbingPlan plan;
};

Scene MakeScene(const std::string& surface, double scallop_um) {
  Scene s;
  auto analytic = recon::MakeReferenceSurface(surface);
  recon::FitReport report;
  s.q = recon::FitAnalytic(*analytic.value(), 40, 40, {}, 0, 1, &report).value();
  nc::ToolpathOptions o;
  o.tool.radius_mm = 3.0;
  o.scallop_um = scallop_um;
  o.max_point_spacing_mm = 0.5;
  s.path = nc::PlanRaster(s.q, o).value();
  for (std::size_t k = 0; k < s.path.points.size(); ++k) {
    const auto& p = s.path.points[k];
    CutterLocation cl;
    cl.centre = p.centre;
    cl.path_length_mm = p.path_length_mm;
    cl.time_s = p.time_s;
    cl.fed_from_previous = k > 0 && s.path.points[k - 1].pass == p.pass;
    s.cls.push_back(cl);
  }
  s.plan = metrology::PlanProbingGrid(s.q, 15, 15, 0.05).value();
  return s;
}

TEST(VirtualMachineTest, ScallopStaysBelowTheTargetAndNeverGouges) {
  for (const char* surface : {"plane", "sphere_cap", "egg_box"}) {
    const Scene s = MakeScene(surface, 4.0);
    VirtualMachineOptions vm;
    const auto r = MachineAndProbe(s.cls, s.plan, vm);
    ASSERT_TRUE(r.ok()) << r.status().message();
    double max_scallop = -1e9, min_scallop = 1e9;
    for (const auto& t : r->truth) {
      max_scallop = std::max(max_scallop, t.scallop_um);
      min_scallop = std::min(min_scallop, t.scallop_um);
    }
    // Target 4 µm plus the chord tolerance (1 µm); the CC points lie on Q, so nothing is cut below it
    // beyond the 1 µm chord error of the straight feed segments.
    EXPECT_LE(max_scallop, 4.0 + 1.0) << surface;
    EXPECT_GE(min_scallop, -1.0) << surface;
    EXPECT_GT(max_scallop, 1.0) << surface << ": some probe points must fall between passes";
  }
}

TEST(VirtualMachineTest, EffectsAddUpAndTheProbeModelInvertsTheLog) {
  const Scene s = MakeScene("saddle", 3.0);
  VirtualMachineOptions vm;
  vm.effects.tool_radius_error_um = 8;
  vm.effects.deflection_um = 20;
  vm.effects.thermal_amplitude_um = 6;
  vm.effects.thermal_tau_s = 900;
  vm.true_probe.ball_radius_mm = 1.0;
  vm.true_probe.pretravel_mm = 0.002;
  const auto r = MachineAndProbe(s.cls, s.plan, vm);
  ASSERT_TRUE(r.ok());
  metrology::ProbeModel probe = vm.true_probe;  // analysis with the right probe model
  const auto dev = metrology::ComputeDeviations(s.q, s.plan, r->log, probe);
  ASSERT_TRUE(dev.ok());
  for (std::size_t i = 0; i < dev->size(); ++i) {
    const InjectedTruth& t = r->truth[i];
    const Eigen::Vector3d n = s.plan.points[i].normal;
    const double engagement = r->contexts[i].engagement;
    EXPECT_GT(engagement, 0.0);
    EXPECT_NEAR(r->EffectUm(i, "tool_deflection"), 20 * (1 - n.z() * n.z()) * engagement / 0.1, 1e-9);
    EXPECT_EQ(r->EffectUm(i, "tool_radius"), 8.0);
    EXPECT_LE(r->EffectUm(i, "thermal_drift_z"), 0.0);
    EXPECT_GE(r->EffectUm(i, "thermal_drift_z"), -6.0);
    // Without noise the measured deviation is the injected total (the surface is locally flat over
    // microns, the B-spline fit of the saddle is exact).
    EXPECT_NEAR((*dev)[i].deviation_mm * 1e3, t.total_um(), 1e-3) << "point " << i;
  }
  // Analysing with the wrong pretravel shifts every deviation by it.
  metrology::ProbeModel nominal;
  nominal.ball_radius_mm = 1.0;
  const auto shifted = metrology::ComputeDeviations(s.q, s.plan, r->log, nominal);
  EXPECT_NEAR((*shifted)[0].deviation_mm - (*dev)[0].deviation_mm, -0.002, 1e-9);
}

TEST(VirtualMachineTest, SameSeedSameLogOtherSeedOtherNoise) {
  const Scene s = MakeScene("plane", 5.0);
  VirtualMachineOptions vm;
  vm.effects.surface_noise_um = 1.0;
  vm.effects.probe_noise_um = 0.5;
  vm.seed = 99;
  const auto a = MachineAndProbe(s.cls, s.plan, vm);
  const auto b = MachineAndProbe(s.cls, s.plan, vm);
  vm.seed = 100;
  const auto c = MachineAndProbe(s.cls, s.plan, vm);
  ASSERT_TRUE(a.ok() && b.ok() && c.ok());
  double same = 0, differ = 0;
  for (std::size_t i = 0; i < a->log.records.size(); ++i) {
    same = std::max(same, (a->log.records[i].centre - b->log.records[i].centre).norm());
    differ = std::max(differ, (a->log.records[i].centre - c->log.records[i].centre).norm());
  }
  EXPECT_EQ(same, 0.0);
  EXPECT_GT(differ, 1e-4);
}

TEST(VirtualMachineTest, ProbingOutsideTheMachinedAreaIsAnError) {
  Scene s = MakeScene("plane", 5.0);
  s.plan.points[3].point += Eigen::Vector3d(0, 500, 0);
  const auto r = MachineAndProbe(s.cls, s.plan, {});
  EXPECT_EQ(r.status().code(), StatusCode::kBadInput);
  EXPECT_NE(r.status().message().find("point 4 "), std::string::npos) << r.status().message();
}

}  // namespace
}  // namespace formloop::sim
