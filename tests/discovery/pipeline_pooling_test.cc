// Pooling as the pipeline does it (issue 20): the separating experiment proposed on one part carried to
// the next part of the same machine (simulation/proposal_plan.h), and the pooled diagnosis of the parts.
// Probe logs come from the virtual machine (tests/support/multi_effect.h); the truth is read only to grade.

#include <cmath>
#include <cstdio>
#include <functional>
#include <numbers>
#include <string>
#include <vector>

#include <gtest/gtest.h>

#include "simulation/part_record.h"
#include "tests/support/multi_effect.h"

namespace formloop::testing {
namespace {

double AngleDeg(const Eigen::Vector3d& a, const Eigen::Vector3d& b) {
  return std::acos(std::clamp(a.normalized().dot(b.normalized()), -1.0, 1.0)) * 180.0 / std::numbers::pi;
}

// A proposal made on one surface lands on another at the same fractions of Q's domain, with the same tilt
// from −n, after the plan's own points and their −n approaches.
TEST(ProposalPlanTest, ATiltedReprobeKeepsItsPlaceAndTiltOnAnotherShape) {
  const MachinedSurface& from = MachinedWith("egg_box", 0);
  const MachinedSurface& to = MachinedWith("sphere_cap", 45);
  sim::ExperimentProposal proposal;
  proposal.kind = "reprobe";
  proposal.members = {"probe_radius", "tool_radius"};
  const recon::ParamDomain d0 = from.q.domain();
  for (const auto& [s, t, azimuth_deg] : std::vector<std::array<double, 3>>{{0.25, 0.5, 0}, {0.7, 0.3, 120}}) {
    metrology::ProbePoint p;
    p.id = 1000;
    p.u = d0.u_min + s * d0.u_span();
    p.v = d0.v_min + t * d0.v_span();
    p.point = from.q.Point(p.u, p.v);
    p.normal = from.q.Normal(p.u, p.v);
    const double az = azimuth_deg * std::numbers::pi / 180.0;
    Eigen::Vector3d e(std::cos(az), std::sin(az), 0.0);
    e = (e - e.dot(p.normal) * p.normal).normalized();
    const double tilt = 30.0 * std::numbers::pi / 180.0;
    proposal.plan.points.push_back(p);
    proposal.approaches.push_back(-std::cos(tilt) * p.normal + std::sin(tilt) * e);
  }
  const sim::PlannedProposal planned = sim::PlannedProposal::Of(proposal, d0);
  ASSERT_EQ(planned.points.size(), 2u);
  EXPECT_NEAR(planned.points[0].s, 0.25, 1e-12);
  EXPECT_NEAR(planned.points[1].t, 0.3, 1e-12);
  EXPECT_NEAR(planned.points[0].tilt_deg, 30.0, 1e-9);
  EXPECT_NEAR(planned.points[1].tilt_deg, 30.0, 1e-9);

  // Through JSON as the case library stores it.
  const auto back = sim::PlannedProposal::FromJson(planned.ToJson(), "case", "");
  ASSERT_TRUE(back.ok()) << back.status().message();
  const metrology::ProbingPlan plan = metrology::PlanProbingGrid(to.q, 12, 12, 0.05).value();
  const sim::PlanWithProposals applied = sim::ApplyProposals(plan, to.q, {*back});
  ASSERT_EQ(applied.added, 2);
  EXPECT_EQ(applied.dropped, 0);
  ASSERT_EQ(applied.plan.points.size(), plan.points.size() + 2);
  ASSERT_EQ(applied.approaches.size(), applied.plan.points.size());
  for (std::size_t i = 0; i < plan.points.size(); ++i) {
    EXPECT_NEAR((applied.approaches[i] + plan.points[i].normal).norm(), 0.0, 1e-12);
  }
  const recon::ParamDomain d1 = to.q.domain();
  for (std::size_t k = 0; k < 2; ++k) {
    const auto& p = applied.plan.points[plan.points.size() + k];
    EXPECT_EQ(p.id, plan.points.back().id + 1 + static_cast<std::int64_t>(k));
    EXPECT_NEAR((p.u - d1.u_min) / d1.u_span(), planned.points[k].s, 1e-12);
    EXPECT_NEAR((p.v - d1.v_min) / d1.v_span(), planned.points[k].t, 1e-12);
    const Eigen::Vector3d& a = applied.approaches[plan.points.size() + k];
    EXPECT_NEAR(a.norm(), 1.0, 1e-12);
    EXPECT_NEAR(AngleDeg(a, -p.normal), 30.0, 1e-9);
    EXPECT_LT(a.z(), 0.0);
  }
  EXPECT_EQ(applied.raster_turn_deg, 0.0);
}

TEST(ProposalPlanTest, BadProposalsAreRefusedNamingTheField) {
  const nlohmann::json steep = {{"alias_group", {"probe_radius", "tool_radius"}},
                                {"kind", "reprobe"},
                                {"points", {{{"s", 0.5}, {"t", 0.5}, {"tilt_deg", 75}, {"azimuth_deg", 0}}}}};
  const auto a = sim::PlannedProposal::FromJson(steep, "d.json", "proposals[0].next_part.");
  ASSERT_FALSE(a.ok());
  EXPECT_NE(a.status().message().find("proposals[0].next_part.points[0].tilt_deg"), std::string::npos)
      << a.status().message();
  const nlohmann::json unknown = {{"alias_group", {"a", "b"}}, {"kind", "tool_setter"}};
  const auto b = sim::PlannedProposal::FromJson(unknown, "d.json", "");
  ASSERT_FALSE(b.ok());
  EXPECT_NE(b.status().message().find("tool_setter"), std::string::npos) << b.status().message();
  const nlohmann::json turn = {{"alias_group", {"a", "b"}}, {"kind", "raster_turn"}, {"raster_turn_deg", 90}};
  EXPECT_FALSE(sim::PlannedProposal::FromJson(turn, "d.json", "").ok()) << "feed_scale is required";
}

// A tool radius and a probe radius probed along −n have identical columns on every part: pooling a second
// part probed the same way cannot split them. The second part probed as the pipeline plans it (the first
// part's proposal applied: tilted points) splits them, and both are named with their true values inside
// their intervals.
TEST(PipelinePoolingTest, TheProposalAppliedOnTheNextPartSplitsWhatPlainPoolingCannot) {
  const std::vector<PartLayout> layouts = {{"egg_box", 0, 24}, {"sphere_cap", 90, 24}};
  const MultiScenario s = DrawMultiScenario(4242, layouts, {"tool_radius", "probe_radius"});
  std::printf("truth: %s\n", s.TruthOf(0).ToJson()["effects"].dump().c_str());
  const auto one = sim::Diagnose(InputOf(s.parts[0]), s.parts[0].baseline, StarterDiagnoseOptions());
  ASSERT_TRUE(one.ok()) << one.status().message();
  std::printf("part 1:\n%s", one->Summary().c_str());
  ASSERT_TRUE(one->InAliasGroup("tool_radius") && one->InAliasGroup("probe_radius")) << one->Summary();

  const auto plain = sim::DiagnosePooled(InputsOf(s, 2), s.parts[0].baseline, StarterDiagnoseOptions());
  ASSERT_TRUE(plain.ok()) << plain.status().message();
  std::printf("pooled, plain plans:\n%s", plain->Summary().c_str());
  EXPECT_TRUE(plain->InAliasGroup("tool_radius") && plain->InAliasGroup("probe_radius")) << plain->Summary();

  const auto proposals =
      sim::ProposeExperiments({InputOf(s.parts[0])}, *one, s.parts[0].baseline, ExperimentOptionsFor(s.parts[0]));
  ASSERT_TRUE(proposals.ok()) << proposals.status().message();
  std::vector<sim::PlannedProposal> planned;
  for (const auto& p : *proposals) planned.push_back(sim::PlannedProposal::Of(p, s.parts[0].machined->q.domain()));
  ASSERT_FALSE(planned.empty());
  const Scenario second = PartAsPipelinePlansIt(s, 1, planned, 777);
  ASSERT_GT(second.plan.points.size(), s.parts[1].plan.points.size()) << "tilted points added";
  const auto pooled = sim::DiagnosePooled({InputOf(s.parts[0]), InputOf(second)}, s.parts[0].baseline,
                                          StarterDiagnoseOptions(), {"1", "2"});
  ASSERT_TRUE(pooled.ok()) << pooled.status().message();
  std::printf("pooled, the second part with the proposal:\n%s", pooled->Summary().c_str());
  EXPECT_FALSE(pooled->InAliasGroup("tool_radius") && pooled->InAliasGroup("probe_radius")) << pooled->Summary();
  for (const char* effect : {"tool_radius", "probe_radius"}) {
    const sim::Cause* cause = nullptr;
    for (const auto& c : pooled->causes) cause = c.effect == effect ? &c : cause;
    ASSERT_NE(cause, nullptr) << effect << " not named\n" << pooled->Summary();
    const double truth = s.machine.Find(effect)->values[0];
    EXPECT_TRUE(truth >= cause->lower[0] && truth <= cause->upper[0])
        << effect << " = " << truth << " outside [" << cause->lower[0] << ", " << cause->upper[0] << "]";
  }
  for (const auto& c : pooled->causes) EXPECT_NE(s.machine.Find(c.effect), nullptr) << c.effect << " named falsely";
}

// A part record (simulation/part_record.h), what the case library keeps of a part for the later parts of
// the same machine: through its JSON (the same bytes back), against a baseline with surface and measurement
// effects it gives the residuals the probe chain gives (the linearised chain: within 0.01 µm), and a pooled
// diagnosis over a record is the one over the probe data, byte for byte.
TEST(PartRecordTest, TheRecordGivesTheChainsResidualsAgainstAnyBaselineAndPoolsAsTheProbeDataDo) {
  const sim::Model truth =
      MachineWithNoise({{"thermal_drift_z", {12.0, 900.0}}, {"tool_wear", {2.5}}, {"probe_radius", {1.5}}});
  const Scenario a = ProbePart({"egg_box", 0, 16}, truth, 11);
  const Scenario b = ProbePart({"sphere_cap", 45, 16, 3000}, truth, 12);
  const auto record = sim::PartRecord::Of(InputOf(a));
  ASSERT_TRUE(record.ok()) << record.status().message();
  ASSERT_EQ(record->points(), 256);
  const std::string bytes = record->ToJson().dump();
  const auto back = sim::PartRecord::FromJson(nlohmann::json::parse(bytes), "record");
  ASSERT_TRUE(back.ok()) << back.status().message();
  EXPECT_EQ(back->ToJson().dump(), bytes);

  sim::Model baseline;
  ASSERT_TRUE(baseline.Set("thermal_drift_z", {8.0, 600.0}).ok());
  ASSERT_TRUE(baseline.Set("tool_radius", {-3.0}).ok());
  ASSERT_TRUE(baseline.Set("probe_radius", {2.0}).ok());
  const auto direct = sim::ProbeResiduals(InputOf(a), baseline);
  ASSERT_TRUE(direct.ok()) << direct.status().message();
  const sim::ProbeResidualData stored = back->Against(baseline);
  ASSERT_EQ(stored.residual_um.size(), direct->residual_um.size());
  const double moved_um = (stored.residual_um - back->residual_um).cwiseAbs().maxCoeff();
  EXPECT_GT(moved_um, 5.0) << "the baseline moves the residuals";
  const double linearised_um = (stored.residual_um - direct->residual_um).cwiseAbs().maxCoeff();
  std::printf("baseline moves the residuals by up to %.2f um; the record's linearised chain differs by %.2e um\n",
              moved_um, linearised_um);
  EXPECT_LT(linearised_um, 0.01);
  for (std::size_t i = 0; i < stored.contexts.size(); ++i) {
    ASSERT_EQ(stored.contexts[i].id, direct->contexts[i].id);
    EXPECT_EQ(stored.contexts[i].cut_time_s, direct->contexts[i].cut_time_s);
    EXPECT_EQ(stored.contexts[i].scallop_um, direct->contexts[i].scallop_um);
  }

  const auto over_data =
      sim::DiagnosePooled({InputOf(b), InputOf(a)}, sim::Model{}, StarterDiagnoseOptions(), {"b", "a"});
  ASSERT_TRUE(over_data.ok()) << over_data.status().message();
  const auto b_residuals = sim::ProbeResiduals(InputOf(b), sim::Model{});
  ASSERT_TRUE(b_residuals.ok());
  const auto over_record = sim::DiagnosePooledResiduals({*b_residuals, back->Against(sim::Model{})}, sim::Model{},
                                                        StarterDiagnoseOptions(), {"b", "a"});
  ASSERT_TRUE(over_record.ok()) << over_record.status().message();
  EXPECT_EQ(over_record->ToJson().dump(), over_data->ToJson().dump());

  // A damaged record is refused naming the field.
  for (const auto& [field, damage] : std::vector<std::pair<std::string, std::function<void(nlohmann::json&)>>>{
           {"d_radius", [](nlohmann::json& j) { j.erase("d_radius"); }},
           {"residual_um[3]", [](nlohmann::json& j) { j["residual_um"][3] = "x"; }},
           {"nx..nz[0]", [](nlohmann::json& j) { j["nx"][0] = 0.5; }},
           {"points", [](nlohmann::json& j) { j["points"] = 0; }},
           {"version", [](nlohmann::json& j) { j["version"] = 2; }}}) {
    nlohmann::json j = nlohmann::json::parse(bytes);
    damage(j);
    const auto refused = sim::PartRecord::FromJson(j, "case 7's record");
    ASSERT_FALSE(refused.ok()) << field;
    EXPECT_NE(refused.status().message().find("case 7's record"), std::string::npos) << refused.status().message();
    EXPECT_NE(refused.status().message().find(field), std::string::npos) << refused.status().message();
  }
}

}  // namespace
}  // namespace formloop::testing
