#pragma once
// The experiment that separates an alias group (issue 20): when a diagnosis reports effects the data
// cannot tell apart, which cheapest change to the measurement or to the next part would — chosen on the
// joint Fisher information of the group's members, with the design correlation predicted after it.
//
// Candidate changes (each with a cost in machine seconds):
//   - re-probe: K more points of the same part (K = 8, 16, 32, 64), chosen from a grid of locations ×
//     approach directions (along −n and tilted by `tilt_deg` toward four azimuths) by sequential
//     D-optimal design: each point the one that most increases log det of the group's information
//     (Fedorov 1972; Atkinson, Donev & Tobias, Optimum Experimental Designs, 2007, ch. 11–12). Cost:
//     K × the probing time per point. Splits what differs in where or how a point is probed (a probe
//     radius against a tool radius: the tilt; effects that differ on steep or far regions).
//   - a direct measurement on the machine (DirectKind): the tool setter, a reference sphere, the
//     fixture's datum faces — alone or together. Splits what it measures from what it does not (a
//     tool radius from a probe radius, a set-up shift from a rotation), whatever the part's shape.
//   - the next part cut another way: the raster turned by 45° or 90°, the cutting order reversed
//     (180°), or the feed halved, probed with the same plan and diagnosed together with this part.
//     Cost: the new path's cutting time plus probing. Splits effects of cutting time from those of path
//     length or position (thermal drift, wear, a rotation).
// The group's information: F = Gᵀ(I − P_O)G, G the members' columns scaled to unit norm on the current
// data and O the other effects' columns (the rest of the extended model; a part-specific effect has
// its own columns on a new part). The design correlation is the largest canonical correlation between
// one member's columns and the others' after O is projected out (1: inseparable). The separation
// predicted: for each member m, the part of what m alone would predict for the group's combined
// prediction that the other members cannot reproduce, λ_m = ‖(I − P_{O,G∖m}) G_m θ_m‖² / σ² (θ_m m's
// least-squares fit of the combined prediction, scaled up to a tenth of the combined prediction when it
// is smaller: a minor member, a probe radius beside a set-up shift, must still be told from its
// look-alikes, or the two stay grouped after the change); the change is predicted to split the group
// when every member's λ_m reaches `required_noncentrality` (≈ 90 % power of a 1-df test at α = 0.01: 15).
// Among the changes predicted to split, the cheapest is proposed; when none is, the one with the
// largest λ per second, marked as not enough on its own.

#include <functional>
#include <string>
#include <vector>

#include <Eigen/Core>
#include <nlohmann/json.hpp>

#include "core/status.h"
#include "metrology/probe.h"
#include "simulation/covariates.h"
#include "simulation/diagnose.h"

namespace formloop::sim {

// A direct measurement a shop can make beside the probe log: which catalogue parameters it observes,
// how precisely (σ, in the parameter's unit) and at what cost. Modelled as one more observation of each
// parameter (a row of weight 1/σ in the group's Fisher information); applied, it is given to diagnose
// as DiagnoseOptions::direct (`formloop diagnose --direct FILE.json`).
struct DirectKind {
  std::string kind;        // "tool_setter"
  std::string instrument;  // "tool setter"
  std::string effect;      // catalogue effect
  std::vector<std::string> parameters;
  double sigma = 1;
  double cost_s = 60;
  std::string action;  // what to do, in words
  // σ is of a radius difference (µm) over the first part's cutting path: the parameter's σ is σ / the
  // path length in m (the tool setter before and after the cut for a wear rate in µm/m).
  bool per_path_length = false;
};
// The tool setter (tool_radius, σ 1 µm, 60 s), a reference sphere (probe_radius, σ 0.5 µm, 120 s), the
// fixture's datum faces (setup_offset tx, ty, tz, σ 1 µm each, 90 s) and its datum plane and edge probed
// at points ~100 mm apart (setup_rotation wx, wy, wz, σ 5 µrad each: 0.5 µm over 100 mm, 120 s); a
// calibrated step gauge or length bar along X, Y (~500 mm: axis_scale, σ 1 µm/m, 600 s) and Z (~200 mm:
// σ 2.5 µm/m); a ball-bar test per plane (ISO 230-4: squareness_xy/yz/zx, σ 5 µrad, 900 s); a test cut
// of a wall at two radial engagements in a spare block, both walls probed (tool_deflection, σ 1 µm,
// 600 s); the reference sphere probed in many directions (probe_lobing c3, s3, σ 0.3 µm, 180 s); the
// tool setter before and after the cut (tool_wear: σ 1.4 µm of the radius loss over the path length,
// 120 s). Every σ and cost is our assumption for a typical shop, not a figure measured in one; they are
// options (ExperimentOptions::direct_kinds).
std::vector<DirectKind> DefaultDirectKinds();

struct ExperimentOptions {
  std::vector<int> reprobe_counts = {8, 16, 32, 64};
  double tilt_deg = 30;                  // of a tilted approach from −n
  int candidate_grid = 24;               // re-probe candidates: grid × grid locations (inset 5 %) × 5 approaches
  double probe_seconds_per_point = 4.0;  // the virtual machine's default
  std::vector<double> raster_turns_deg = {45, 90, 180};
  std::vector<double> feed_scales = {0.5};
  double required_noncentrality = 15;
  // Direct measurements considered, alone and together (every combination of those that measure a
  // member of the group); empty: none.
  std::vector<DirectKind> direct_kinds = DefaultDirectKinds();
  PlausibleRanges plausible;  // the τ search range of a thermal member not in the model
  // The part's path cut with the raster turned by `turn_deg` and the feed scaled: cutter locations (in
  // cutting order, with path length and time). Without it no next-part change is considered (the
  // simulation layer cannot plan tool paths; nc-gen can).
  std::function<Result<std::vector<CutterLocation>>(double turn_deg, double feed_scale)> replan;
  Status Validate() const;
};

struct ExperimentProposal {
  std::vector<std::string> members;  // the alias group
  std::string kind;                  // "reprobe", "raster_turn", "feed", or direct kinds joined by '+'
  std::string change;                // what to do, in words
  double cost_s = 0;
  double correlation_before = 0, correlation_after = 0;  // design correlation of the group
  double log_det_gain = 0;                               // increase of log det of the group's information
  double separation = 0;                                 // min over members of λ_m after the change (see above)
  bool predicted_to_split = false;
  // The change itself: re-probe points (ids after the part's largest) and their approaches; or the
  // next part's raster turn and feed scale.
  metrology::ProbingPlan plan;
  std::vector<Eigen::Vector3d> approaches;
  double raster_turn_deg = 0, feed_scale = 1;
  // Or the direct measurements to make (their value is what the shop measures; 0 here).
  std::vector<DirectMeasurement> direct;
  nlohmann::json ToJson() const;
};

// One proposal per alias group of `diagnosis` (made from `parts` with `baseline`; the first part is the
// one a re-probe or the next part's plan refer to). `parts` must carry the surface. The readings the
// diagnosis used (its `direct`) are counted as made: a change is judged by what it adds to them, and a
// reading proposed again says so.
Result<std::vector<ExperimentProposal>> ProposeExperiments(const std::vector<ProbeDataInput>& parts,
                                                           const Diagnosis& diagnosis, const Model& baseline,
                                                           const ExperimentOptions& options);
// The same from the residuals the diagnosis was made from, in its order (DiagnosePooledResiduals's: a
// pooled diagnosis whose earlier parts are known by their case-library records only); `part` is the
// first, whose surface, plan and path a re-probe or the next part's plan refer to.
Result<std::vector<ExperimentProposal>> ProposeExperiments(const ProbeDataInput& part,
                                                           const std::vector<ProbeResidualData>& residuals,
                                                           const Diagnosis& diagnosis,
                                                           const ExperimentOptions& options);

// The design correlation of `members` (labels as an AliasGroup lists them) against the other effects
// of `diagnosis`' extended model, on the data of `parts`: what ProposeExperiments predicts, measured on
// the data actually taken (with the direct measurements that were made, if any).
Result<double> GroupCorrelation(const std::vector<ProbeDataInput>& parts, const Diagnosis& diagnosis,
                                const Model& baseline, const std::vector<std::string>& members,
                                const std::vector<DirectMeasurement>& direct = {});

// The separation (λ, see above) the readings `direct` would give the alias group of `diagnosis` that lists
// `members`, on the data of `parts`, the readings the diagnosis used counted as made: what a proposal of
// those readings predicts. A pooled diagnosis's group is predicted with each part's own set-up, so the
// figure does not depend on the order of the parts.
Result<double> GroupSeparation(const std::vector<ProbeDataInput>& parts, const Diagnosis& diagnosis,
                               const Model& baseline, const std::vector<std::string>& members,
                               const std::vector<DirectMeasurement>& direct);

}  // namespace formloop::sim
