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
// least-squares fit of the combined prediction); the change is predicted to split the group when every
// member's λ_m reaches `required_noncentrality` (≈ 90 % power of a 1-df test at α = 0.01: 15).
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

struct ExperimentOptions {
  std::vector<int> reprobe_counts = {8, 16, 32, 64};
  double tilt_deg = 30;                  // of a tilted approach from −n
  int candidate_grid = 24;               // re-probe candidates: grid × grid locations (inset 5 %) × 5 approaches
  double probe_seconds_per_point = 4.0;  // the virtual machine's default
  std::vector<double> raster_turns_deg = {45, 90, 180};
  std::vector<double> feed_scales = {0.5};
  double required_noncentrality = 15;
  PlausibleRanges plausible;  // the τ search range of a thermal member not in the model
  // The part's path cut with the raster turned by `turn_deg` and the feed scaled: cutter locations (in
  // cutting order, with path length and time). Without it no next-part change is considered (the
  // simulation layer cannot plan tool paths; nc-gen can).
  std::function<Result<std::vector<CutterLocation>>(double turn_deg, double feed_scale)> replan;
  Status Validate() const;
};

struct ExperimentProposal {
  std::vector<std::string> members;  // the alias group
  std::string kind;                  // "reprobe", "raster_turn", "feed"
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
  nlohmann::json ToJson() const;
};

// One proposal per alias group of `diagnosis` (made from `parts` with `baseline`; the first part is the
// one a re-probe or the next part's plan refer to). `parts` must carry the surface.
Result<std::vector<ExperimentProposal>> ProposeExperiments(const std::vector<ProbeDataInput>& parts,
                                                           const Diagnosis& diagnosis, const Model& baseline,
                                                           const ExperimentOptions& options);

// The design correlation of `members` (labels as an AliasGroup lists them) against the other effects
// of `diagnosis`' extended model, on the data of `parts`: what ProposeExperiments predicts, measured on
// the data actually taken.
Result<double> GroupCorrelation(const std::vector<ProbeDataInput>& parts, const Diagnosis& diagnosis,
                                const Model& baseline, const std::vector<std::string>& members);

}  // namespace formloop::sim
