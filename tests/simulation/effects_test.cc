// The effect catalogue against hand computations (physics sanity), models as data, and diagnose on
// feature positions.

#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>

#include <gtest/gtest.h>

#include "core/random.h"
#include "metrology/deviations.h"
#include "simulation/covariates.h"
#include "simulation/diagnose.h"
#include "simulation/effects.h"
#include "simulation/model.h"
#include "simulation/virtual_machine.h"

namespace formloop::sim {
namespace {

TEST(EffectCatalogueTest, EveryEffectOfTheSpecIsRegisteredUnderItsStableName) {
  const std::vector<std::string> spec = {
      "scallop",      "tool_radius",  "tool_wear",      "tool_deflection", "thermal_drift_z", "axis_scale_x",
      "axis_scale_y", "axis_scale_z", "squareness_xy",  "squareness_yz",   "squareness_zx",   "backlash_x",
      "backlash_y",   "setup_offset", "setup_rotation", "probe_radius",    "probe_lobing",    "noise"};
  ASSERT_EQ(EffectCatalogue().size(), spec.size());
  for (std::size_t i = 0; i < spec.size(); ++i) {
    EXPECT_EQ(EffectCatalogue()[i]->name(), spec[i]);
    EXPECT_FALSE(EffectCatalogue()[i]->physics().empty());
    EXPECT_FALSE(EffectCatalogue()[i]->basis().empty());
  }
  EXPECT_EQ(FindEffect("no_such_effect"), nullptr);
}

// Analytic Jacobians against central differences of DeviationUm, at random contexts and parameters.
TEST(EffectCatalogueTest, JacobiansMatchFiniteDifferences) {
  Rng rng(5);
  for (const Effect* e : EffectCatalogue()) {
    for (int trial = 0; trial < 20; ++trial) {
      PointContext c;
      c.point = {rng.Uniform(-50, 50), rng.Uniform(-50, 50), rng.Uniform(-10, 10)};
      c.normal = Eigen::Vector3d(rng.Uniform(-0.5, 0.5), rng.Uniform(-0.5, 0.5), 1).normalized();
      c.approach =
          -Eigen::Vector3d(c.normal + Eigen::Vector3d(rng.Uniform(-0.3, 0.3), rng.Uniform(-0.3, 0.3), 0)).normalized();
      c.path_length_mm = rng.Uniform(0, 5000);
      c.cut_time_s = rng.Uniform(0, 900);
      c.feed = Eigen::Vector3d(rng.Uniform(-1, 1), rng.Uniform(-1, 1), 0).normalized();
      c.engagement = rng.Uniform(0.05, 0.3);
      std::vector<double> theta;
      for (const auto& p : e->parameters()) theta.push_back(p.linear ? rng.Uniform(-5, 5) : rng.Uniform(100, 1000));
      std::vector<double> j(theta.size());
      e->Jacobian(c, theta, j);
      for (std::size_t k = 0; k < theta.size(); ++k) {
        const double h = 1e-4 * std::max(1.0, std::abs(theta[k]));
        auto plus = theta, minus = theta;
        plus[k] += h;
        minus[k] -= h;
        const double fd = (e->DeviationUm(c, plus) - e->DeviationUm(c, minus)) / (2 * h);
        EXPECT_NEAR(j[k], fd, 1e-6 * std::max(1.0, std::abs(fd))) << e->name() << " parameter " << k;
      }
    }
  }
}

// One straight pass along +x over the plane z = 0 and probe points right under it.
struct StraightPass {
  std::vector<CutterLocation> cls;
  std::vector<MeasuredPoint> points;
};
StraightPass MakeStraightPass(double slope_x = 0) {
  StraightPass s;
  const double r = 3.0;
  const Eigen::Vector3d n = Eigen::Vector3d(-slope_x, 0, 1).normalized();
  for (int i = 0; i <= 100; ++i) {
    const double x = i;
    const Eigen::Vector3d cc(x, 0, slope_x * x);
    CutterLocation cl;
    cl.centre = cc + r * n;
    cl.path_length_mm = x;
    cl.time_s = x / 25.0;  // 1500 mm/min
    cl.fed_from_previous = i > 0;
    s.cls.push_back(cl);
  }
  for (int id = 1; id <= 9; ++id) {
    const double x = 10.0 * id;
    s.points.push_back({id, Eigen::Vector3d(x, 0, slope_x * x), n, -n});
  }
  return s;
}

TEST(EffectPhysicsTest, ToolWearGrowsAlongASinglePassAsHandComputed) {
  const StraightPass pass = MakeStraightPass();
  const auto contexts = AssociateWithToolpath(pass.cls, 3.0, pass.points);
  ASSERT_TRUE(contexts.ok()) << contexts.status().message();
  const Effect* wear = FindEffect("tool_wear");
  for (const PointContext& c : *contexts) {
    // k_w = 5 µm/m: at x mm along the pass the ball has cut x mm, so δ = 5 · x/1000 µm.
    EXPECT_NEAR(wear->DeviationUm(c, std::vector<double>{5.0}), 5.0 * c.point.x() / 1000.0, 1e-12);
    EXPECT_NEAR(c.scallop_um, 0.0, 1e-9);  // right under the ball: no cusp
  }
}

TEST(EffectPhysicsTest, ThermalDriftOnAPlaneFollowsTheExponentialInCuttingTime) {
  const StraightPass pass = MakeStraightPass();
  const auto contexts = AssociateWithToolpath(pass.cls, 3.0, pass.points).value();
  const Effect* thermal = FindEffect("thermal_drift_z");
  for (const PointContext& c : contexts) {
    const double t = c.point.x() / 25.0;  // cut time of the location above the point
    EXPECT_NEAR(c.cut_time_s, t, 1e-12);
    // A = 10 µm, τ = 2 s; on a plane n_z = 1, the tool has grown down into the part: δ = −10 (1 − e^(−t/2)).
    EXPECT_NEAR(thermal->DeviationUm(c, std::vector<double>{10.0, 2.0}), -10.0 * (1.0 - std::exp(-t / 2.0)), 1e-12);
  }
}

TEST(EffectPhysicsTest, BacklashFlipsWithTheFeedDirectionOnZigZagPasses) {
  // Two passes on the plane z = 0.5 x (n_x = −0.447): pass 0 fed +x at y = 0, pass 1 fed −x at y = 1.
  const double slope = 0.5, r = 3.0;
  const Eigen::Vector3d n = Eigen::Vector3d(-slope, 0, 1).normalized();
  std::vector<CutterLocation> cls;
  for (int pass = 0; pass < 2; ++pass) {
    for (int i = 0; i <= 40; ++i) {
      const double x = pass == 0 ? i : 40 - i;
      CutterLocation cl;
      cl.centre = Eigen::Vector3d(x, pass * 1.0, slope * x) + r * n;
      cl.fed_from_previous = i > 0;
      cls.push_back(cl);
    }
  }
  std::vector<MeasuredPoint> points = {{1, Eigen::Vector3d(20, 0, 10), n, -n}, {2, Eigen::Vector3d(20, 1, 10), n, -n}};
  const auto contexts = AssociateWithToolpath(cls, r, points).value();
  ASSERT_EQ(contexts.size(), 2u);
  EXPECT_EQ(contexts[0].pass, 0);
  EXPECT_EQ(contexts[1].pass, 1);
  // The feed runs along the slope: ±(1, 0, 0.5)/|·|.
  EXPECT_NEAR(contexts[0].feed.x(), 1.0 / std::sqrt(1.25), 1e-12);
  EXPECT_NEAR(contexts[1].feed.x(), -1.0 / std::sqrt(1.25), 1e-12);
  // b = 8 µm: D_x = −(b/2) sign(f_x), δ = D_x n_x = ∓4 · (−0.4472) = ±1.789 µm.
  const Effect* backlash = FindEffect("backlash_x");
  const double nx = n.x();
  EXPECT_NEAR(backlash->DeviationUm(contexts[0], std::vector<double>{8.0}), -4.0 * nx, 1e-12);
  EXPECT_NEAR(backlash->DeviationUm(contexts[1], std::vector<double>{8.0}), 4.0 * nx, 1e-12);
  EXPECT_NEAR(-4.0 * nx, 1.7889, 1e-4);
}

TEST(EffectPhysicsTest, GeometricEffectsAsHandComputed) {
  PointContext c;
  c.point = {100, 50, 20};
  c.normal = Eigen::Vector3d(1, 2, 2) / 3.0;
  // axis_scale_x, e = 10 µm/m: D_x = 10e-6 · 100 mm = 1 µm; δ = 1 · 1/3.
  EXPECT_NEAR(FindEffect("axis_scale_x")->DeviationUm(c, std::vector<double>{10}), 1.0 / 3.0, 1e-12);
  // squareness_xy, S = 20 µrad: D_x = 20e-6 · 50 mm = 1 µm; δ = 1/3.
  EXPECT_NEAR(FindEffect("squareness_xy")->DeviationUm(c, std::vector<double>{20}), 1.0 / 3.0, 1e-12);
  // setup_offset t = (3, 0, −3) µm: δ = (3 − 6)/3 = −1.
  EXPECT_NEAR(FindEffect("setup_offset")->DeviationUm(c, std::vector<double>{3, 0, -3}), -1.0, 1e-12);
  // setup_rotation ω = (0, 0, 10) µrad: D = ω × p = 10e-6 (−50, 100, 0) mm = (−0.5, 1, 0) µm; δ = (−0.5 + 2)/3.
  EXPECT_NEAR(FindEffect("setup_rotation")->DeviationUm(c, std::vector<double>{0, 0, 10}), 0.5, 1e-12);
  // tool_deflection k_d = 6 µm at a_e = 0.2 r: 6 (1 − 4/9) (0.2/0.1).
  c.engagement = 0.2;
  EXPECT_NEAR(FindEffect("tool_deflection")->DeviationUm(c, std::vector<double>{6}), 6 * (5.0 / 9.0) * 2, 1e-12);
  // probe_lobing: approach along −x (probing direction +x, θ = 0, ρ = 1), normal +x: c_a = 1 → δ = c3.
  c.normal = Eigen::Vector3d::UnitX();
  c.approach = -Eigen::Vector3d::UnitX();
  EXPECT_NEAR(FindEffect("probe_lobing")->DeviationUm(c, std::vector<double>{2.5, 7}), 2.5, 1e-12);
  // Probing direction at θ = 30°: cos 90° = 0, sin 90° = 1 → δ = s3 · c_a.
  c.approach = -Eigen::Vector3d(std::cos(M_PI / 6), std::sin(M_PI / 6), 0);
  EXPECT_NEAR(FindEffect("probe_lobing")->DeviationUm(c, std::vector<double>{2.5, 7}), 7 * std::cos(M_PI / 6), 1e-12);
}

// End to end through the virtual machine and probe compensation: a probe effective radius 3 µm too
// large reads +3 µm along the normal; a ball 3 µm too small leaves +3 µm of material.
TEST(EffectPhysicsTest, ProbeRadiusAndToolRadiusReadAsHandComputedThroughTheProbeLog) {
  const StraightPass pass = MakeStraightPass();
  metrology::ProbingPlan plan;
  for (const auto& p : pass.points) plan.points.push_back({p.id, p.point.x(), p.point.y(), p.point, p.normal});
  for (const char* effect : {"probe_radius", "tool_radius"}) {
    VirtualMachineOptions vm;
    vm.true_probe.ball_radius_mm = 1.0;
    ASSERT_TRUE(vm.model.Set(effect, {3.0}).ok());
    const auto result = MachineAndProbe(pass.cls, plan, vm);
    ASSERT_TRUE(result.ok()) << result.status().message();
    for (std::size_t i = 0; i < plan.points.size(); ++i) {
      // Contact point c + R a with the assumed R = 1 mm, read along n (z here).
      const auto& rec = result->log.records[i];
      const double deviation_um =
          1e3 * (rec.centre + 1.0 * rec.approach - plan.points[i].point).dot(plan.points[i].normal);
      EXPECT_NEAR(deviation_um, 3.0, 1e-9) << effect;
    }
  }
}

TEST(ModelTest, JsonRoundTripAndBadInputNamesTheField) {
  Model m;
  ASSERT_TRUE(m.Set("thermal_drift_z", {6, 900}, {0.5, 40}).ok());
  ASSERT_TRUE(m.Set("setup_offset", {1, 2, 3}).ok());
  const auto back = Model::FromJson(m.ToJson(), "m.json");
  ASSERT_TRUE(back.ok()) << back.status().message();
  EXPECT_EQ(back->ToJson().dump(), m.ToJson().dump());
  auto bad = m.ToJson();
  bad["effects"][0]["parameters"].erase("tau_s");
  EXPECT_NE(Model::FromJson(bad, "m.json").status().message().find("effects[0].parameters.tau_s"), std::string::npos);
  bad = m.ToJson();
  bad["effects"][1]["name"] = "setup_offest";
  EXPECT_NE(Model::FromJson(bad, "m.json").status().message().find("unknown effect 'setup_offest'"), std::string::npos);
  bad = m.ToJson();
  bad["version"] = 7;
  EXPECT_NE(Model::FromJson(bad, "m.json").status().message().find("upgrade formloop"), std::string::npos);
  bad = m.ToJson();
  bad["effects"][0]["parameters"]["tau_s"] = -1;
  EXPECT_FALSE(Model::FromJson(bad, "m.json").ok());
  EXPECT_FALSE(m.Set("tool_radius", {1, 2}).ok());
}

// Feature positions (hole centres) distorted by a similarity transform plus an anisotropic scale and
// a small squareness, with 5 µm noise: the causes are named and their parameters recovered within
// their intervals — simultaneous 95 % intervals over the 7 observable parameters (Bonferroni:
// ±2.69 standard errors each), since 7 separate 95 % intervals all hold only ~70 % of the time.
TEST(FeatureDiagnosisTest, SimilarityTransformPlusAnisotropicScaleAndSquareness) {
  Model truth;
  ASSERT_TRUE(truth.Set("setup_offset", {12, -8, 0}).ok());
  ASSERT_TRUE(truth.Set("setup_rotation", {0, 0, 80}).ok());
  ASSERT_TRUE(truth.Set("axis_scale_x", {60}).ok());  // similarity scale 40 ppm + 20 anisotropic
  ASSERT_TRUE(truth.Set("axis_scale_y", {20}).ok());  // similarity scale 40 ppm − 20
  ASSERT_TRUE(truth.Set("squareness_xy", {50}).ok());
  Rng rng(31);
  std::vector<FeaturePosition> features;
  for (int i = 0; i < 12; ++i) {
    for (int j = 0; j < 9; ++j) {
      FeaturePosition f;
      f.id = "H" + std::to_string(i * 9 + j);
      f.nominal = Eigen::Vector3d(-220 + 40 * i, -160 + 40 * j, 0);
      Eigen::Vector3d d = Eigen::Vector3d::Zero();
      for (const auto& e : truth.effects) d += e.effect->DisplacementUm(f.nominal, e.values);
      f.measured = f.nominal + 1e-3 * (d + Eigen::Vector3d(rng.Normal(0, 5), rng.Normal(0, 5), 0));
      features.push_back(f);
    }
  }
  DiagnoseOptions options;
  options.max_causes = 6;
  const auto d = DiagnoseFeatures(features, Model{}, options);
  ASSERT_TRUE(d.ok()) << d.status().message();
  std::printf("%s", d->Summary().c_str());
  for (const auto& e : truth.effects) {
    const auto& named = d->causes;
    const auto it =
        std::find_if(named.begin(), named.end(), [&](const Cause& c) { return c.effect == e.effect->name(); });
    ASSERT_NE(it, named.end()) << e.effect->name() << " not named";
    for (std::size_t k = 0; k < e.values.size(); ++k) {
      const bool unobservable = (e.effect->name() == "setup_offset" && k == 2) ||  // z, from 2-D positions
                                (e.effect->name() == "setup_rotation" && k < 2);   // tilts, from 2-D positions
      if (unobservable) {
        EXPECT_TRUE(std::isnan(it->parameters[k])) << e.effect->name() << " parameter " << k << " reported";
        continue;
      }
      EXPECT_LE(std::abs(it->parameters[k] - e.values[k]), 2.69 * it->std_errors[k])
          << e.effect->name() << " parameter " << k << ": " << it->parameters[k] << " +- " << it->std_errors[k];
    }
  }
  EXPECT_LT(d->rms_after_um, 6.0);
  EXPECT_GT(d->rms_before_um, 2 * d->rms_after_um);
  std::printf("feature RMS %.2f -> %.2f um, held-out %.2f -> %.2f um\n", d->rms_before_um, d->rms_after_um,
              d->heldout_rms_before_um, d->heldout_rms_after_um);
}

TEST(FeatureDiagnosisTest, BadFeatureFilesNameTheLineAndField) {
  const auto dir = std::filesystem::temp_directory_path() / "formloop_features_test";
  std::filesystem::create_directories(dir);
  auto write = [&](const std::string& name, const std::string& text) {
    std::ofstream(dir / name) << text;
    return (dir / name).string();
  };
  EXPECT_NE(ReadFeatures(write("a.csv", "id,x_nom,y_nom,x\nH1,0,0,0\n")).status().message().find("y"),
            std::string::npos);
  const auto nan = ReadFeatures(write("b.csv", "id,x_nom,y_nom,x,y\nH1,0,0,0,0\nH2,1,1,abc,1\n"));
  EXPECT_NE(nan.status().message().find(":3"), std::string::npos) << nan.status().message();
  EXPECT_NE(ReadFeatures(write("c.csv", "id,x_nom,y_nom,x,y\nH1,0,0,0,0\nH1,1,1,1,1\n"))
                .status()
                .message()
                .find("duplicated"),
            std::string::npos);
  EXPECT_FALSE(ReadFeatures((dir / "missing.csv").string()).ok());
  std::filesystem::remove_all(dir);
}

}  // namespace
}  // namespace formloop::sim
