#pragma once
// Hidden-effect scenarios with several causes at once (issue 20): a machine with 2–4 catalogue effects
// of the size the regression machines have, parts planned and probed as the pipeline does it (a
// zig-zag raster at the part's angle, an inset probing grid approached along −n), the probe log
// written by the virtual machine (MachineAndProbe, the independent generator: it evaluates each
// effect's physics, not diagnose's Jacobians). Several parts of one machine share its machine, tool
// and probe effects and each has its own set-up. The truth is read only to grade.
//
// The draw of one machine:
//   noise σ (combined) uniform in [1, 2] µm (the regression machines: 1–2 µm roughness, 0.5–1 µm probe);
//   k ∈ {2, 3, 4} distinct effects of the catalogue, each with parameters drawn in the catalogue's
//   typical range and scaled so its own RMS on the first part is SNR_e · σ, SNR_e uniform in [3, 20];
//   accepted when the sum of the effects' peak magnitudes on the first part lies in [20, 60] µm and
//   every parameter inside its plausible range (data/starter/rules.json), else drawn again.

#include <algorithm>
#include <cmath>
#include <string>
#include <vector>

#include <gtest/gtest.h>

#include "simulation/plausible_ranges.h"
#include "tests/support/discovery.h"

namespace formloop::testing {

inline const sim::PlausibleRanges& StarterPlausibleRanges() {
  static const sim::PlausibleRanges ranges =
      sim::ReadPlausibleRanges(std::string(FORMLOOP_SOURCE_DIR) + "/data/starter/rules.json").value();
  return ranges;
}

// Diagnose's options as the tests run it: the starter rule base's plausible ranges.
inline sim::DiagnoseOptions StarterDiagnoseOptions() {
  sim::DiagnoseOptions o;
  o.plausible = StarterPlausibleRanges();
  return o;
}

// A machine with these effects and the regression machines' noise (0.8 µm roughness, 0.6 µm probe).
inline sim::Model MachineWithNoise(const std::vector<std::pair<std::string, std::vector<double>>>& effects) {
  sim::Model m;
  for (const auto& [name, values] : effects) EXPECT_TRUE(m.Set(name, values).ok()) << name;
  EXPECT_TRUE(m.Set("noise", {0.8, 0.6}).ok());
  return m;
}

inline bool IsSetupEffect(std::string_view name) { return name == "setup_offset" || name == "setup_rotation"; }

// One part of a machine: its surface, raster angle, probing grid and probing start time.
struct PartLayout {
  std::string surface;
  double raster_angle_deg = 0;
  int grid = 30;  // grid × grid probe points
  double feed_mm_per_min = 1500;
};

struct MultiScenario {
  std::uint64_t seed = 0;
  double sigma_um = 1;
  std::vector<std::string> injected;  // effect names
  std::vector<double> snr;            // per injected effect, on the first part
  double total_peak_um = 0;           // Σ peak |δ_e| on the first part
  sim::Model machine;                 // shared effects (+ noise)
  std::vector<sim::Model> setups;     // per part: its set-up effects
  std::vector<Scenario> parts;        // the probed parts (Scenario of discovery.h)
  // True effects per part: the machine's plus the part's set-up (grading).
  sim::Model TruthOf(std::size_t part) const {
    sim::Model m = machine;
    for (const auto& e : setups[part].effects) (void)m.Set(e.effect->name(), e.values);
    return m;
  }
};

// Probes part `layout` of a machine whose true model is `truth` (noise included).
inline Scenario ProbePart(const PartLayout& layout, const sim::Model& truth, std::uint64_t seed,
                          const std::vector<Eigen::Vector3d>* approaches = nullptr,
                          const metrology::ProbingPlan* plan = nullptr) {
  Scenario s;
  s.surface = layout.surface;
  s.machined = &MachinedWith(layout.surface, layout.raster_angle_deg, layout.feed_mm_per_min);
  s.plan = plan != nullptr ? *plan : metrology::PlanProbingGrid(s.machined->q, layout.grid, layout.grid, 0.05).value();
  s.points = static_cast<int>(s.plan.points.size());
  s.truth = truth;
  for (const auto& e : truth.effects) {
    if (e.effect->kind() != sim::EffectKind::kNoise) s.injected.emplace_back(e.effect->name());
  }
  sim::VirtualMachineOptions vm;
  vm.tool_radius_mm = 3.0;
  vm.true_probe.ball_radius_mm = 1.0;
  vm.model = truth;
  vm.seed = seed;
  if (approaches != nullptr) vm.approaches = *approaches;
  const auto machined = sim::MachineAndProbe(s.machined->cls, s.plan, vm).value();
  s.log = machined.log;
  double sum2 = 0;
  for (std::size_t i = 0; i < machined.truth.size(); ++i) {
    double systematic = machined.truth[i].measurement_um + machined.truth[i].surface_um - machined.truth[i].scallop_um;
    sum2 += systematic * systematic;
  }
  s.effect_rms_um = std::sqrt(sum2 / std::max<std::size_t>(1, machined.truth.size()));
  (void)s.baseline.Set("noise", {truth.surface_sigma_um(), truth.probe_sigma_um()});
  return s;
}

// RMS and peak of one effect over contexts.
inline std::pair<double, double> EffectRmsPeak(const sim::Effect& e, const std::vector<double>& theta,
                                               const std::vector<sim::PointContext>& contexts) {
  double sum2 = 0, peak = 0;
  for (const auto& c : contexts) {
    const double d = e.DeviationUm(c, theta);
    sum2 += d * d;
    peak = std::max(peak, std::abs(d));
  }
  return {std::sqrt(sum2 / std::max<std::size_t>(1, contexts.size())), peak};
}

// Draws a parameter vector of `e` in the catalogue's typical range (τ: 0.2–2 × the first part's cutting
// time), its linear part scaled to RMS `rms_um` on `contexts`.
inline std::vector<double> DrawEffect(Rng& rng, const sim::Effect& e, double rms_um, double cut_time_s,
                                      const std::vector<sim::PointContext>& contexts) {
  std::vector<double> theta;
  for (const auto& p : e.parameters()) {
    theta.push_back(p.linear ? rng.Uniform(p.typical_min, p.typical_max) : cut_time_s * rng.Uniform(0.2, 2.0));
  }
  double rms = EffectRmsPeak(e, theta, contexts).first;
  if (rms < 1e-9) return {};
  for (std::size_t k = 0; k < theta.size(); ++k) {
    if (e.parameters()[k].linear) theta[k] *= rms_um / rms;
  }
  return theta;
}

inline bool Plausible(const sim::Effect& e, const std::vector<double>& theta) {
  for (int k = 0; k < e.parameter_count(); ++k) {
    const sim::ParameterRange* r = StarterPlausibleRanges().Find(e, k);
    if (r != nullptr && !r->Contains(theta[static_cast<std::size_t>(k)])) return false;
  }
  return true;
}

// A machine with 2–4 effects and `layouts.size()` parts (the first fixes the magnitudes). Set-up
// effects are drawn anew for every part (each part is clamped on its own) at the first part's size.
inline MultiScenario DrawMultiScenario(std::uint64_t seed, const std::vector<PartLayout>& layouts,
                                       std::vector<std::string> forced = {}) {
  Rng rng(seed);
  MultiScenario out;
  out.seed = seed;
  const std::vector<std::string> all = InjectableEffects();
  const MachinedSurface& first = MachinedWith(layouts.front().surface, layouts.front().raster_angle_deg);
  const auto plan0 = metrology::PlanProbingGrid(first.q, layouts.front().grid, layouts.front().grid, 0.05).value();
  const auto contexts = sim::AssociateWithToolpath(first.cls, 3.0, sim::MeasuredPointsOf(plan0)).value();
  for (int attempt = 0;; ++attempt) {
    out.sigma_um = rng.Uniform(1.0, 2.0);
    std::vector<std::string> names = forced;
    if (names.empty()) {
      const int k = 2 + static_cast<int>(rng.UniformIndex(3));
      while (static_cast<int>(names.size()) < k) {
        const std::string& pick = all[rng.UniformIndex(all.size())];
        if (std::find(names.begin(), names.end(), pick) == names.end()) names.push_back(pick);
      }
    }
    sim::Model machine, setup;
    std::vector<double> snr;
    double total_peak = 0;
    bool ok = true;
    for (const std::string& name : names) {
      const sim::Effect* e = sim::FindEffect(name);
      const double snr_e = rng.Uniform(3.0, 20.0);
      const std::vector<double> theta = DrawEffect(rng, *e, snr_e * out.sigma_um, first.total_time_s, contexts);
      if (theta.empty() || !Plausible(*e, theta)) {
        ok = false;
        break;
      }
      total_peak += EffectRmsPeak(*e, theta, contexts).second;
      snr.push_back(snr_e);
      (void)(IsSetupEffect(name) ? setup : machine).Set(name, theta);
    }
    if (!ok || total_peak < 20.0 || total_peak > 60.0) {
      if (attempt > 2000) std::abort();  // the draw cannot fail this often; a broken catalogue would
      continue;
    }
    (void)machine.Set("noise", {0.8 * out.sigma_um, 0.6 * out.sigma_um});
    out.injected = names;
    out.snr = snr;
    out.total_peak_um = total_peak;
    out.machine = machine;
    out.setups.push_back(setup);
    break;
  }
  // The other parts' set-ups: the same effects, redrawn at the first part's RMS on their own surfaces.
  for (std::size_t p = 1; p < layouts.size(); ++p) {
    sim::Model setup;
    const MachinedSurface& m = MachinedWith(layouts[p].surface, layouts[p].raster_angle_deg);
    const auto plan = metrology::PlanProbingGrid(m.q, layouts[p].grid, layouts[p].grid, 0.05).value();
    const auto ctx = sim::AssociateWithToolpath(m.cls, 3.0, sim::MeasuredPointsOf(plan)).value();
    for (const auto& e : out.setups.front().effects) {
      const double rms0 = EffectRmsPeak(*e.effect, e.values, contexts).first;
      std::vector<double> theta;
      for (int tries = 0; tries < 50; ++tries) {
        theta = DrawEffect(rng, *e.effect, rms0, 0, ctx);
        if (!theta.empty() && Plausible(*e.effect, theta)) break;
        theta = e.values;
      }
      (void)setup.Set(e.effect->name(), theta);
    }
    out.setups.push_back(setup);
  }
  for (std::size_t p = 0; p < layouts.size(); ++p) {
    out.parts.push_back(ProbePart(layouts[p], out.TruthOf(p), rng.Fork()));
  }
  return out;
}

// The layouts a suite scenario draws: 1–3 parts, distinct surfaces, raster angles from those a part file
// states (0, 45, 90°), grids of 20–36 points per side.
inline std::vector<PartLayout> DrawLayouts(Rng& rng, int parts) {
  std::vector<std::string> surfaces = DiscoverySurfaces();
  std::vector<PartLayout> out;
  for (int p = 0; p < parts; ++p) {
    const std::size_t pick = rng.UniformIndex(surfaces.size());
    PartLayout l;
    l.surface = surfaces[pick];
    surfaces.erase(surfaces.begin() + static_cast<std::ptrdiff_t>(pick));
    l.raster_angle_deg = 45.0 * static_cast<double>(rng.UniformIndex(3));
    l.grid = 20 + static_cast<int>(rng.UniformIndex(17));
    out.push_back(l);
  }
  return out;
}

}  // namespace formloop::testing

namespace formloop::testing {

// How a diagnosis of a scenario's parts compares with the truth.
struct Grade {
  int true_effects = 0;  // effect instances: shared ones once, a set-up once per part
  int found = 0;         // named or inside a reported alias group
  int false_named = 0;   // named outside any alias group, not in the truth
  int parameters = 0;    // of named true effects
  int inside = 0;        // ... inside their 95 % interval
  bool gain_ok = false;  // held-out RMS fell by ≥ 50 % of the systematic RMS
  int alias_groups = 0;
  std::vector<std::string> missed, false_names;
  nlohmann::json outside = nlohmann::json::array();  // named parameters whose interval misses the truth
  nlohmann::json ToJson() const {
    return {{"true_effects", true_effects},
            {"found", found},
            {"false_named", false_named},
            {"parameters", parameters},
            {"inside", inside},
            {"gain_ok", gain_ok},
            {"alias_groups", alias_groups},
            {"missed", missed},
            {"false_names", false_names},
            {"outside", outside}};
  }
};

// `labels`: the diagnosis' part labels (one "" for a single part); `parts` the scenario's parts in the
// same order (the truth of part p is scenario.TruthOf(p)).
inline Grade GradeDiagnosis(const sim::Diagnosis& d, const MultiScenario& scenario, std::size_t parts) {
  Grade g;
  g.alias_groups = static_cast<int>(d.alias_groups.size());
  auto label = [&](const std::string& effect, std::size_t part) {
    return parts > 1 && IsSetupEffect(effect) ? effect + "@" + d.parts[part] : effect;
  };
  auto grouped = [&](const std::string& l) {
    const std::string every = l.substr(0, l.find('@')) + "@each part";
    for (const auto& grp : d.alias_groups) {
      if (std::count(grp.members.begin(), grp.members.end(), l) +
              std::count(grp.members.begin(), grp.members.end(), every) >
          0) {
        return true;
      }
    }
    return false;
  };
  auto truth_of = [&](const std::string& effect, std::size_t part) -> const sim::EffectInstance* {
    return IsSetupEffect(effect) ? scenario.setups[part].Find(effect) : scenario.machine.Find(effect);
  };
  for (std::size_t p = 0; p < parts; ++p) {
    for (const std::string& effect : scenario.injected) {
      if (!IsSetupEffect(effect) && p > 0) continue;
      ++g.true_effects;
      const std::string l = label(effect, p);
      bool named = false;
      for (const auto& c : d.causes) named = named || c.Label() == l;
      if (named || grouped(l)) {
        ++g.found;
      } else {
        g.missed.push_back(l);
      }
    }
  }
  for (const auto& c : d.causes) {
    std::size_t part = 0;
    for (std::size_t p = 0; p < d.parts.size(); ++p) {
      if (d.parts[p] == c.part) part = p;
    }
    const sim::EffectInstance* truth = truth_of(c.effect, part);
    if (truth == nullptr) {
      ++g.false_named;
      g.false_names.push_back(c.Label());
      continue;
    }
    for (std::size_t j = 0; j < truth->values.size(); ++j) {
      if (std::isnan(c.lower[j])) continue;
      ++g.parameters;
      if (truth->values[j] >= c.lower[j] && truth->values[j] <= c.upper[j]) {
        ++g.inside;
      } else {
        g.outside.push_back({{"effect", c.Label()},
                             {"parameter", c.parameter_names[j]},
                             {"truth", truth->values[j]},
                             {"estimate", c.parameters[j]},
                             {"interval", {c.lower[j], c.upper[j]}}});
      }
    }
  }
  double sum2 = 0;
  int n = 0;
  for (std::size_t p = 0; p < parts; ++p) {
    sum2 += std::pow(scenario.parts[p].effect_rms_um, 2) * scenario.parts[p].points;
    n += scenario.parts[p].points;
  }
  const double systematic_rms = std::sqrt(sum2 / std::max(1, n));
  g.gain_ok = d.heldout_rms_before_um - d.heldout_rms_after_um >= 0.5 * systematic_rms;
  return g;
}

// The inputs of a scenario's first `parts` parts.
inline std::vector<sim::ProbeDataInput> InputsOf(const MultiScenario& s, std::size_t parts) {
  std::vector<sim::ProbeDataInput> out;
  for (std::size_t p = 0; p < parts; ++p) out.push_back(InputOf(s.parts[p]));
  return out;
}

}  // namespace formloop::testing

#include "simulation/experiment_design.h"
#include "simulation/proposal_plan.h"

namespace formloop::testing {

// The part `s` probed again at a re-probe proposal's points (the same machined part: the machine's
// effects are deterministic, the noise new), the new records appended to its log and plan.
inline Scenario Reprobed(const Scenario& s, const sim::ExperimentProposal& p, std::uint64_t seed) {
  Scenario out = s;
  sim::VirtualMachineOptions vm;
  vm.tool_radius_mm = 3.0;
  vm.true_probe.ball_radius_mm = 1.0;
  vm.model = s.truth;
  vm.seed = seed;
  vm.approaches = p.approaches;
  const auto extra = sim::MachineAndProbe(s.machined->cls, p.plan, vm).value();
  const double t0 = s.log.records.empty() ? 0.0 : s.log.records.back().t_s;
  for (auto record : extra.log.records) {
    record.t_s += t0;
    out.log.records.push_back(record);
  }
  for (const auto& point : p.plan.points) out.plan.points.push_back(point);
  out.points = static_cast<int>(out.plan.points.size());
  return out;
}

// A direct-measurement proposal applied on the virtual machine: each parameter it measures read from
// the part's TRUE model (0 when the machine lacks the effect) plus N(0, σ²) noise of the instrument —
// never from what the diagnosis said.
inline std::vector<sim::DirectMeasurement> Measured(const Scenario& s, const sim::ExperimentProposal& p,
                                                    std::uint64_t seed) {
  Rng rng(seed);
  std::vector<sim::DirectMeasurement> out = p.direct;
  for (auto& d : out) {
    double truth = 0;
    if (const sim::EffectInstance* e = s.truth.Find(d.effect)) {
      for (int j = 0; j < e->effect->parameter_count(); ++j) {
        if (e->effect->parameters()[j].name == d.parameter) truth = e->values[static_cast<std::size_t>(j)];
      }
    }
    d.value = rng.Normal(truth, d.sigma);
  }
  return out;
}

// The options a test proposes experiments with: the starter plausible ranges, and the part's path
// re-planned by nc-gen (MachinedWith) for a raster turn or a feed scale.
inline sim::ExperimentOptions ExperimentOptionsFor(const Scenario& s) {
  sim::ExperimentOptions o;
  o.plausible = StarterPlausibleRanges();
  const std::string surface = s.surface;
  const double angle = s.machined->raster_angle_deg, feed = s.machined->feed_mm_per_min;
  o.replan = [surface, angle, feed](double turn, double scale) -> Result<std::vector<sim::CutterLocation>> {
    return MachinedWith(surface, std::fmod(angle + turn, 360.0), feed * scale).cls;
  };
  return o;
}

// The next part of the machine cut as `p` says (raster turned or feed scaled), probed with the first
// part's plan, with the set-up `setup` of its own.
inline Scenario NextPart(const Scenario& s, const sim::ExperimentProposal& p, const sim::Model& machine,
                         const sim::Model& setup, std::uint64_t seed) {
  sim::Model truth = machine;
  for (const auto& e : setup.effects) (void)truth.Set(e.effect->name(), e.values);
  const PartLayout layout{s.surface, std::fmod(s.machined->raster_angle_deg + p.raster_turn_deg, 360.0), 0,
                          s.machined->feed_mm_per_min * p.feed_scale};
  return ProbePart(layout, truth, seed, nullptr, &s.plan);
}

// Part `p` of scenario `s` as `formloop run` plans it when the case library holds `planned` for its
// machine: its own plan with the proposals' tilted re-probe points (sim::ApplyProposals), its path
// with the raster turned and the feed scaled as they say; the same machine and set-up, new noise.
inline Scenario PartAsPipelinePlansIt(const MultiScenario& s, std::size_t p,
                                      const std::vector<sim::PlannedProposal>& planned, std::uint64_t seed) {
  const Scenario& plain = s.parts[p];
  const sim::PlanWithProposals applied = sim::ApplyProposals(plain.plan, plain.machined->q, planned);
  const PartLayout layout{plain.surface, std::fmod(plain.machined->raster_angle_deg + applied.raster_turn_deg, 360.0),
                          0, plain.machined->feed_mm_per_min * applied.feed_scale};
  return ProbePart(layout, s.TruthOf(p), seed, &applied.approaches, &applied.plan);
}

}  // namespace formloop::testing
