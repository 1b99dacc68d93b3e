#pragma once
// Model discovery (spec/simulation.md §5): what the simulation gets wrong, which catalogue effect
// explains it, the extended model, and the gain on held-out data.
//
//   1. Residuals r = measured − simulated(baseline), µm, both read through the same probe
//      compensation and foot-point projection (so the measurement process cancels), with the
//      residual's Moran's I (k-NN weights).
//   2. Screening: every catalogue effect not in the baseline is fitted to r together with the effects
//      already named (linear least squares by QR; thermal_drift_z's τ by a profile search in log τ and
//      golden-section refinement), scored by its drop in RSS, the partial F test, ΔBIC and the
//      residual Moran's z after adding it.
//   3. Forward selection: the effect with the lowest ΔBIC among those significant at α/K (Bonferroni
//      over the K candidates of the step) that also explains at least `min_share` of the systematic
//      part of the current residual (RSS drop over RSS − n σ̂², σ̂² the nugget variance from
//      nearest-neighbour differences) is named; repeated while one qualifies. The share guard keeps a
//      localised pattern outside the catalogue from being pinned on an effect that fits a sliver of it.
//   4. Confounding: a candidate whose fitted column predicts the named effect's contribution with
//      correlation ≥ `confounded_correlation` is reported with what data would separate the two.
//   5. If the residual after the named effects is still spatially correlated (z > z_critical):
//      "unexplained systematic residual", with where (local Moran HH/LL clusters).
//   6. Gain: RMS before/after in-sample, and spatial block cross-validation (contiguous blocks in x-y,
//      leave one block out, the named effects' parameters refitted without it).
//
// The same screening runs on feature positions (DiagnoseFeatures) with the effects that act on
// positions, each coordinate of each feature an observation.

#include <string>
#include <vector>

#include <Eigen/Core>
#include <nlohmann/json.hpp>

#include "core/status.h"
#include "metrology/probe.h"
#include "reconstruction/bspline_surface.h"
#include "simulation/covariates.h"
#include "simulation/model.h"

namespace formloop::sim {

struct DiagnoseOptions {
  double alpha = 0.01;        // family-wise level of the F test per step (spec: 0.01)
  double z_critical = 2.326;  // residual Moran's z above which the residual is "systematic" (α = 0.01)
  double min_share = 0.3;     // of the systematic variance an effect must explain to be named (see above)
  double confounded_correlation = 0.95;
  int knn = 8;  // Moran's I weights
  int max_causes = 4;
  int cv_blocks = 4;                    // block CV: cv_blocks × cv_blocks contiguous blocks over x-y
  std::vector<std::string> candidates;  // empty = the whole catalogue (minus the baseline's effects)
  bool toolpath_known = true;           // false: effects that need the tool path are not screened (reported)
  Status Validate() const;
};

struct ScreenedEffect {
  std::string effect;
  std::vector<double> parameters, std_errors;
  double rss_drop = 0;  // µm²
  double f = 0, p_value = 1;
  double delta_bic = 0;
  double share = 0;    // of the systematic variance of the residual it was fitted to
  double z_after = 0;  // residual Moran's z with it added
  bool significant = false;
};

struct Cause {
  std::string effect;
  std::vector<std::string> parameter_names;
  std::vector<double> parameters, std_errors;
  double variance_explained = 0;  // fraction of the baseline residual's variance it removes
  double z_before = 0, z_after = 0;
};

struct Confounding {
  std::string named, other;
  double correlation = 0;
  std::string separate_by;
};

struct Diagnosis {
  int n = 0;
  double rms_before_um = 0, rms_after_um = 0;
  double heldout_rms_before_um = 0, heldout_rms_after_um = 0;
  double z_before = 0, z_after = 0;
  double noise_sigma_um = 0;  // nugget estimate
  bool explained_by_baseline = false;
  std::vector<Cause> causes;
  std::vector<std::vector<ScreenedEffect>> screening;  // per forward-selection step
  std::vector<Confounding> confounded;
  std::vector<std::string> not_screened;  // effects the data cannot test (e.g. no tool path), with the reason in ToJson
  bool unexplained = false;
  nlohmann::json unexplained_where = nlohmann::json::array();  // clusters of the remaining residual
  std::vector<double> residual_um, residual_after_um;
  Model extended;
  nlohmann::json ToJson() const;  // diagnosis.json (fixed schema: causes, unexplained, gain, ...)
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
