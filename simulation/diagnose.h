#pragma once
// Model discovery (spec/simulation.md §5, issue 20): what the simulation gets wrong, which catalogue
// effects explain it — or, when the data cannot tell several apart, which group of them does — the
// extended model, and the gain on held-out data.
//
//   1. Residuals r = measured − simulated(baseline), µm, both read through the same probe
//      compensation and foot-point projection (so the measurement process cancels), with the
//      residual's Moran's I (k-NN weights).
//   2. Terms: every catalogue effect not in the baseline. Over several parts (DiagnosePooled) an
//      effect of the machine, tool or probe is one term shared by all parts and a set-up effect
//      (Effect::part_specific) one term per part; each part's rows are weighted by 1/σ̂ of its noise.
//   3. Selection: forward steps add the term with the lowest ΔBIC among those significant at α/K
//      (Bonferroni over the K candidates of the step; partial F test, linear least squares by QR,
//      thermal_drift_z's τ by a profile search in log τ inside its plausible range) that also explains
//      at least `min_share` of the systematic part of the current residual (RSS drop over
//      RSS − n σ̂², σ̂² the nugget variance from nearest-neighbour differences). Then, until nothing
//      changes: exchange (a selected term for a candidate, when that lowers BIC), backward elimination
//      (a selected term no longer significant at α given the others) and another forward step. The
//      share guard keeps a localised pattern outside the catalogue from being pinned on an effect that
//      fits a sliver of it.
//   4. Identifiability: a selected term s and a candidate c are aliases when, in the model with both,
//      s is not significant at `alias_alpha` given c and the rest (c can do s's work on this design:
//      this path, this plan, these times). A minor selected term (removing < `pair_alias_share` of
//      the variance given the others) is also aliased with two candidates that together, in its place,
//      fit with plausible values and a BIC less than `alias_bic` worse (Kass & Raftery 1995: not very
//      strong evidence): a z scale on a dome standing in for a tool radius and a deflection. The term
//      that carries the signal is not so tested: one effect against a pair in just the right
//      proportion is parsimony's case. Alias edges joined into connected groups: a group of two
//      or more is reported as one finding — "one or more of: ...; these data cannot tell them apart"
//      — with its combined prediction and gain, and no parameter of its members is printed. A single
//      parameter of a selected effect joins a group when it is significant without a candidate (at
//      `alias_alpha` / the number of parameters so tested: Bonferroni, as a forward step) and not
//      with it ("setup_offset(tz_um)": the effect stays named, that parameter is not printed); one
//      the data do not ask for at that level is printed with its interval, which is joined over its
//      look-alikes (6.), not grouped with everything it resembles.
//      A candidate in no group, asked for beside the selected terms (a column of it significant at
//      `alias_alpha`), whose column is nearly collinear with a selected term of one column already in
//      a group (estimates correlated ≥ 0.95 given the rest) joins that group, its most collinear
//      one: both are there, their split is not determined (a set-up z offset beside a tool radius
//      grouped with the probe radius on an egg box). A named term gains no group so. The parameters
//      of a combination of one term's own that moves nothing the data see form a group too (a part's
//      rotation on a sphere cap about the line through the centre), the model keeping none of it; the
//      finding says the combination ("...(wx_urad)@B : ...(wy_urad)@B : ...(wz_urad)@B = -0.49 : -0.39 :
//      0.78 changes nothing these points see": the turn about that axis).
//      Design correlations between named effects and the candidates they resemble are reported too.
//   5. Plausibility: a named effect whose value lies outside its plausible range (rule base,
//      plausible_ranges.h; for a linear effect of several parameters, the part of its values the data
//      determine) is not named; the finding says which value the data asked for, and the
//      selection runs again without that effect.
//   6. Intervals: 95 % profile likelihood (the values whose profiled RSS stays below
//      RSS_min (1 + F(0.95; 1, ν)/ν); the t interval for a linear parameter when no τ is fitted; τ
//      clipped to its plausible range), joined over the selected model and the model plus each
//      candidate left out: an interval does not assume that a look-alike too weak to be selected is
//      absent (extreme-bounds analysis, Leamer 1983); and over the model with each alias group's
//      selected member replaced by each of the group's candidates: "one or more of" does not say
//      which member is there, so a named interval must not assume it (a z scale grouped with wear
//      took the slow part of a thermal drift, whose τ and amplitude intervals then missed the truth).
//   7. If the residual after the selected terms is still spatially correlated (z > z_critical):
//      "unexplained systematic residual", with where (local Moran HH/LL clusters); a localised region
//      is set aside and the selection repeated outside it (RunEngine).
//   8. Gain: RMS before/after in-sample, and spatial block cross-validation (contiguous blocks in x-y,
//      leave one block out, the selected terms' parameters refitted without it).
//
// The same screening runs on feature positions (DiagnoseFeatures) with the effects that act on
// positions, each coordinate of each feature an observation.
//
// References: Bonferroni-guarded forward selection with exchange and backward steps (Miller, Subset
// Selection in Regression, 2nd ed. 2002, ch. 3); profile-likelihood intervals for a nonlinear
// parameter (Bates & Watts, Nonlinear Regression Analysis, 1988, §6.1; Venzon & Moolgavkar 1988).

#include <string>
#include <vector>

#include <Eigen/Core>
#include <nlohmann/json.hpp>

#include "core/status.h"
#include "metrology/probe.h"
#include "reconstruction/bspline_surface.h"
#include "simulation/covariates.h"
#include "simulation/model.h"
#include "simulation/plausible_ranges.h"

namespace formloop::sim {

// A direct measurement of a catalogue effect's parameter on the machine, outside the part's probe log:
// the tool setter (tool_radius.delta_r_um: the cutting tool's radius error), a reference sphere
// (probe_radius.delta_r_eff_um: the probe's effective radius error), a datum of the fixture
// (setup_offset.tx_um/ty_um/tz_um: the part's set-up shift). It enters the fit as one more observation,
// value = parameter + ε, ε ~ N(0, σ²) (a row of the least squares with weight 1/σ beside the points'),
// so it splits effects the probe data alone cannot tell apart — by what it measures, never by fiat:
// a parameter the data and the measurement disagree on still shows in the fit. docs/diagnose.md
// describes the file (ReadDirectMeasurements).
struct DirectMeasurement {
  std::string effect;     // catalogue name
  std::string parameter;  // one of its parameters (name as the catalogue gives it)
  double value = 0;       // the parameter's measured value, in its unit (the catalogue's sign)
  double sigma = 1;       // standard uncertainty of `value`, same unit
  std::string part;       // a set-up's part label when several parts are diagnosed (empty: the first)
  std::string by;         // the instrument, in words ("tool setter", "reference sphere", "datum bore")
  Status Validate() const;
  nlohmann::json ToJson() const;
};
// {"direct_measurements": [{"effect": "tool_radius", "parameter": "delta_r_um", "value": 6.1,
//   "sigma": 1.0, "by": "tool setter"}, ...]} — errors name the file, the entry and the field.
Result<std::vector<DirectMeasurement>> ReadDirectMeasurements(const std::string& path);
// The same list given inline (the part file's "direct_measurements"): errors name `source` and
// `field`[i].<key>.
Result<std::vector<DirectMeasurement>> DirectMeasurementsFromJson(const nlohmann::json& list, const std::string& source,
                                                                  const std::string& field);

struct DiagnoseOptions {
  double alpha = 0.01;        // family-wise level of the F test per step (spec: 0.01)
  double alias_alpha = 0.01;  // a selected term not significant at this level given a candidate is its alias
  // ... and aliased with two candidates whose model in its place is worse by less than this BIC (0: no
  // pair test).
  double alias_bic = 10.0;
  double pair_alias_share = 0.1;  // ... for a selected term that removes less than this share of the variance
  double z_critical = 2.326;      // residual Moran's z above which the residual is "systematic" (α = 0.01)
  double min_share = 0.3;         // of the systematic variance an effect must explain to be named (see above)
  double confounded_correlation = 0.95;
  int knn = 8;                          // Moran's I weights
  int max_causes = 8;                   // selected terms (a pooled set-up counts once per part)
  int cv_blocks = 4;                    // block CV: cv_blocks × cv_blocks contiguous blocks over x-y
  std::vector<std::string> candidates;  // empty = the whole catalogue (minus the baseline's effects)
  bool toolpath_known = true;           // false: effects that need the tool path are not screened (reported)
  // Plausible parameter ranges (the rule base's "diagnose.plausible_ranges"); empty: none, and τ is
  // searched over [T/100, 100 T], T the longest cutting time.
  PlausibleRanges plausible;
  // Direct measurements of parameters (probe data only; their effects must not be in the baseline).
  std::vector<DirectMeasurement> direct;
  Status Validate() const;
};

struct ScreenedEffect {
  std::string effect;  // a term: the effect, "@part" for a part's own set-up when pooling
  std::vector<double> parameters, std_errors;
  double rss_drop = 0;  // µm² (pooled: in units of each part's σ̂²)
  double f = 0, p_value = 1;
  double delta_bic = 0;
  double share = 0;    // of the systematic variance of the residual it was fitted to
  double z_after = 0;  // residual Moran's z with it added
  bool significant = false;
};

struct Cause {
  std::string effect;
  std::string part;  // empty: shared by every part; else the part whose set-up it is
  std::vector<std::string> parameter_names;
  std::vector<double> parameters, std_errors;
  std::vector<double> lower, upper;  // 95 % interval per parameter (profile likelihood for τ)
  // Per parameter: inside an alias group (another effect can do its work); its value, error and
  // interval are then NaN (reported as null) — the group carries it.
  std::vector<bool> aliased;
  double variance_explained = 0;     // fraction of the baseline residual's variance it removes (given the others)
  double z_before = 0, z_after = 0;  // residual Moran's z without it and with it (the others fitted)
  std::string Label() const { return part.empty() ? effect : effect + "@" + part; }
};

// Effects the data cannot tell apart: one finding, named by its members, with what they predict together.
struct AliasGroup {
  std::vector<std::string> members;   // term labels, every effect that can do the group's work
  std::vector<std::string> in_model;  // the members whose columns carry the combined prediction
  double variance_explained = 0;      // fraction of the baseline residual's variance the group removes
  double combined_rms_um = 0;         // RMS of the combined prediction over the points
  double max_correlation = 0;         // largest correlation between two members' best fits of the group's prediction
  std::string separate_by;            // what would tell them apart (the members' hints)
  // Combinations of a member's own parameters that change nothing the points see (a sphere cap's turn
  // about the line through its centre), each a unit vector in the parameters' own units.
  struct Undetermined {
    std::vector<std::string> parameters;  // column labels: "setup_rotation(wx_urad)@2"
    std::vector<double> coefficients;     // unit norm; components below 5 % of the largest left out
    std::string Text() const;             // "a : b : c = -0.49 : -0.39 : 0.78 changes nothing these points see"
  };
  std::vector<Undetermined> undetermined;
  std::string Message() const;        // "one or more of: a, b, c; these data cannot tell them apart"
};

// An effect the data fit best with a value outside its plausible range: not named.
struct Implausible {
  std::string effect, part;
  std::vector<std::string> parameter_names;
  std::vector<double> parameters;
  std::vector<std::string> violations;  // "tau_s = 34700 outside [60, 14400]"
};

struct Confounding {
  std::string named, other;
  double correlation = 0;
  std::string separate_by;
};

struct Diagnosis {
  int n = 0;
  std::vector<std::string> parts;  // part labels (one empty label for a single part)
  double rms_before_um = 0, rms_after_um = 0;
  double heldout_rms_before_um = 0, heldout_rms_after_um = 0;
  double z_before = 0, z_after = 0;
  double noise_sigma_um = 0;  // nugget estimate
  bool explained_by_baseline = false;
  std::vector<Cause> causes;             // named: significant, identifiable, plausible; by variance explained
  std::vector<AliasGroup> alias_groups;  // findings the data cannot split
  std::vector<Implausible> implausible;
  std::vector<std::vector<ScreenedEffect>> screening;  // per forward-selection step
  std::vector<Confounding> confounded;                 // named effects with a look-alike the data still separate
  std::vector<std::string> not_screened;  // effects the data cannot test (e.g. no tool path), with the reason in ToJson
  // The direct measurements used, each with the value the fit gives its parameter (NaN: its effect not
  // named on its own) — a measurement the fit disagrees with by many σ is visible here.
  std::vector<DirectMeasurement> direct;
  std::vector<double> direct_fitted;
  bool unexplained = false;
  nlohmann::json unexplained_where = nlohmann::json::array();  // clusters of the remaining residual
  std::vector<double> residual_um, residual_after_um;
  Model extended;  // baseline + named causes + alias groups' combined predictions (pooled: the first part's set-up)
  // True when `effect` is among the members of a reported alias group (any part).
  bool InAliasGroup(std::string_view effect) const;
  nlohmann::json ToJson() const;  // diagnosis.json (fixed schema: causes, alias_groups, unexplained, gain, ...)
  std::string Summary() const;    // the readable summary for stderr
};

// How the measured deviation at each point responds to the surface moving along n (per µm) and to
// the probe's effective radius (per µm). The catalogue's bases are first order for an approach along
// −n (1 and c_a); with a tilted approach on a curved surface the compensation and foot-point
// projection bend them by up to ~1 %, which at high SNR is many standard errors. ProbeResiduals
// measures both through the same chain the data went through.
struct MeasurementSensitivity {
  Eigen::VectorXd surface;  // ∂(measured deviation)/∂(surface offset)
  Eigen::VectorXd radius;   // ∂(measured deviation)/∂(effective radius)
};

struct ProbeResidualData {
  std::vector<PointContext> contexts;  // in log order
  Eigen::VectorXd residual_um;         // measured − simulated(baseline)
  MeasurementSensitivity sensitivity;
};

// Residual-level entry: r (µm) at points with contexts; the engine used by both data kinds. Without
// `sensitivity` the catalogue's first-order bases are used as they are.
Result<Diagnosis> DiagnoseResiduals(const std::vector<PointContext>& contexts, const Eigen::VectorXd& residual_um,
                                    const Model& baseline, const DiagnoseOptions& options,
                                    const MeasurementSensitivity* sensitivity = nullptr);

// Probe data: measured log vs the baseline's simulation of the same plan on the same tool path.
struct ProbeDataInput {
  const recon::BSplineSurface* surface = nullptr;
  const std::vector<CutterLocation>* cutter_locations = nullptr;
  double tool_radius_mm = 3.0;
  const metrology::ProbingPlan* plan = nullptr;
  const metrology::ProbeLog* measured = nullptr;
  metrology::ProbeModel probe;  // the probe model analysis assumes
};
Result<ProbeResidualData> ProbeResiduals(const ProbeDataInput& input, const Model& baseline);
Result<Diagnosis> Diagnose(const ProbeDataInput& input, const Model& baseline, const DiagnoseOptions& options);

// Several parts of one machine, tool and material (different shapes, raster angles, cutting orders,
// probing plans): the shared effects fitted jointly, each part's set-up on its own (see above).
// `labels` name the parts in the output (default "1", "2", ...). One part gives Diagnose's result.
Result<Diagnosis> DiagnosePooled(const std::vector<ProbeDataInput>& inputs, const Model& baseline,
                                 const DiagnoseOptions& options, const std::vector<std::string>& labels = {});
// The residual-level form of DiagnosePooled.
Result<Diagnosis> DiagnosePooledResiduals(const std::vector<ProbeResidualData>& parts, const Model& baseline,
                                          const DiagnoseOptions& options, const std::vector<std::string>& labels = {});

// Held-out RMS (µm) of `model` against measured data (e.g. a second part): r = measured − simulated(model).
Result<double> PredictionRms(const ProbeDataInput& input, const Model& model);

// A probing plan and a log without the run that made the part: deviations read along the planned
// normals from the compensated contact points, r = that − the baseline's prediction. Only the
// effects that do not need the tool path are screened (DiagnoseOptions::toolpath_known = false).
Result<Diagnosis> DiagnosePlanOnly(const metrology::ProbingPlan& plan, const metrology::ProbeLog& measured,
                                   const metrology::ProbeModel& probe, const Model& baseline, DiagnoseOptions options);

// Feature positions: nominal and measured (mm); 2-D features leave z out.
struct FeaturePosition {
  std::string id;
  Eigen::Vector3d nominal = Eigen::Vector3d::Zero();
  Eigen::Vector3d measured = Eigen::Vector3d::Zero();
  bool has_z = false;
};
Result<std::vector<FeaturePosition>> ReadFeatures(const std::string& path);
Result<Diagnosis> DiagnoseFeatures(const std::vector<FeaturePosition>& features, const Model& baseline,
                                   const DiagnoseOptions& options);

}  // namespace formloop::sim
