#pragma once
// Level 3 of the self-optimising NC (spec/process-optimization.md §3): from on-machine inspection, the
// out-of-tolerance regions of a surface are traced back to the NC blocks that cut them and those blocks
// are adjusted — normal offsets of their cutter locations for a geometric or thermal error, a feed
// reduction (then offsets for the rest) where the error follows the cutting load — with the inspection
// log of §3.5.
//
// Evaluation (§3.2): deviations e_k = (p_k − q_k)·n_k; the small rigid displacement (τ, ω) by least
// squares on e_k ≈ (τ + ω × q_k)·n_k solved by SVD (singular values below 1e-9 σ_max dropped: free
// DOF), form error FE = max r − min r of its residuals, PE = 2 max|e|; the systematic field ê(x) =
// Σ w_k e_k / Σ w_k, w_k = exp(−|x − q_k|²/2h²) over neighbours within 3h (Nadaraya–Watson); Moran's I
// of e with w_ij = 1/d_ij for 0 < d_ij ≤ 2h and its normality z (Cliff & Ord 1981, through
// metrology/morans_i.h): z > 2.33 (α = 0.01) is systematic and may be compensated, else report only.
//
// Regions and blocks (§3.3): points with |ê(q_k)| > t_p/2 of one sign, connected within 1.5h. Every
// cutting block (feed move) carries CC samples at ≤ min(0.5, h/4) mm: the foot point on the nominal
// surface of the ball centre (programmed tip + r ẑ) and its normal. A block belongs to a region when one
// of its samples lies within 1.5h of a region point with |ê| > t_p/2 there; ranges are reported per
// pass (a pass = a run of feed moves). Each out-of-tolerance point is also mapped back to the nearest
// block ("unmapped" beyond max(pass spacing, h)).
//
// Adjustment (§3.4): the region's blocks, dilated by 2 passes, are "deflection" when the Pearson ρ
// between ê at their CC samples and the block load (a Level-2 log or the predicted F_c) is ≥ 0.7 with a
// positive slope and ê > 0, else "offset". Offset: on the region's blocks and a taper band (blocks
// within 2h) split so CL points are ≤ min(h/2, 1) mm apart (new blocks take free N numbers between
// neighbours), CL' = CL − γ ê(CC) n wherever |ê| > 0.1 t_p; any |γ ê| > δ_max = 0.2 mm is L3-COMP-LIMIT
// and nothing is edited. Deflection: the feed of the region's blocks is scaled by φ = clamp((0.5 (t_p/2)
// / ê_peak)^(1/y_F), 0.3, 1), tapered back to 1 over 2 passes, and the remaining φ^y_F ê is offset as
// above. An overcut region (ê < −t_p/2) cannot be repaired: the part is non-conforming and the
// compensation goes only into the program for the next parts. After editing, the shifted CL points are
// checked against the nominal surface (no point of it cut deeper than the intended shift plus t_p/2) and
// the program is read back; unedited lines stay byte-identical and the header names the parent's
// SHA-256 and the inspection id.
//
// Departures: the Level-1 depth re-check of edited blocks needs a stock model and is not run on
// finishing programs; renumbering when no free N number is left is refused (BadInput naming the blocks)
// rather than done.

#include <Eigen/Core>
#include <cstdint>
#include <filesystem>
#include <map>
#include <nlohmann/json.hpp>
#include <string>
#include <vector>

#include "core/point_set.h"
#include "core/status.h"
#include "metrology/deviations.h"
#include "planning/program_edit.h"
#include "reconstruction/foot_point.h"

namespace formloop::planning {

struct InspectionOptions {
  double tolerance_mm = 0.050;  // t_p: the profile conforms when |e| ≤ t_p/2
  double grid_spacing_mm = 0;   // h; 0 = the median nearest-neighbour distance of the points
  double z_threshold = 2.33;    // one-sided α = 0.01
  double gamma = 1.0;           // compensation gain (0.5-1.0)
  double max_offset_mm = 0.2;   // δ_max
  double deflection_rho = 0.7;
  double force_exponent = 0.75;  // y_F of the force law
  // The record of §3.5.
  std::string inspection_id = "inspection-1", part_id, operation_id, probe_calibration_id, time;
  Status Validate() const;
};

// (τ, ω) with e ≈ (τ + ω × q)·n.
struct RigidFit {
  Eigen::Vector3d tau = Eigen::Vector3d::Zero(), omega = Eigen::Vector3d::Zero();
  std::vector<double> residual_mm;
  double form_error_mm = 0;
  int rank = 0;  // DOF determined by the points
};
RigidFit FitRigidDisplacement(const std::vector<metrology::Deviation>& points);

struct InspectionEvaluation {
  double h_mm = 0;
  std::vector<double> e_hat_mm;  // ê(q_k)
  double profile_error_mm = 0;   // PE
  RigidFit fit;
  double moran_i = 0, moran_z = 0;
  double sigma_random_mm = 0;
  bool systematic = false;  // z > threshold
  nlohmann::json ToJson() const;
};
Result<InspectionEvaluation> EvaluateInspection(const std::vector<metrology::Deviation>& points,
                                                const InspectionOptions& options);

struct CcSample {
  Eigen::Vector3d cc = Eigen::Vector3d::Zero(), normal = Eigen::Vector3d::UnitZ();
  double fraction = 0;  // along the block, 0 start .. 1 end
};
struct CutBlock {
  std::size_t move = 0, line = 0;
  int pass = 0;
  Eigen::Vector3d tip_start = Eigen::Vector3d::Zero(), tip_end = Eigen::Vector3d::Zero();
  std::vector<CcSample> samples;  // ends included
};
struct ProgramGeometry {
  double ball_radius_mm = 0, sample_mm = 0;
  std::vector<CutBlock> blocks;
  double pass_spacing_mm = 0;  // median distance from a pass's start to the previous pass
};
// The feed moves of the program with their CC samples on the nominal surface.
Result<ProgramGeometry> BuildProgramGeometry(const EditableProgram& program, const recon::FootPointProjector& nominal,
                                             double ball_radius_mm, double sample_mm);

struct ErrorRegion {
  int sign = 1;
  Eigen::Vector3d centroid = Eigen::Vector3d::Zero();
  double area_mm2 = 0, peak_mm = 0;
  std::vector<int> points;
  std::vector<int> blocks;                // indices into ProgramGeometry::blocks, ascending
  std::vector<std::string> block_ranges;  // per pass: "N1230-N1290" (or lines)
  std::string type;                       // "offset", "deflection" or "overcut"
  double rho = 0;                         // load correlation over the dilated blocks (NaN: no load)
  nlohmann::json ToJson() const;
};

struct InspectionAdjustment {
  InspectionEvaluation evaluation;
  std::vector<ErrorRegion> regions;
  std::vector<std::pair<std::int64_t, std::string>> out_of_tolerance;  // point id -> block or "unmapped"
  // The adjusted program ("" when nothing is edited); kind "recut", "next_part" or "none".
  std::string program, kind = "none";
  bool non_conforming = false;
  int blocks_split = 0, cl_points_shifted = 0, feeds_changed = 0;
  double max_shift_mm = 0;
  // The re-cut model's prediction at every point: e − D (offset) or φ^y_F e − D (deflection), D the
  // normal shift of the edited tool path at the point's nearest CC sample (linear along the block).
  std::vector<double> predicted_e_mm;
  std::vector<std::string> alarms, notes;
  nlohmann::json log_record;  // §3.5
  nlohmann::json ToJson() const;
};

// block_load: load per block name ("N120" or "line 57"), e.g. mean I − I_0 from a Level-2 log; may be empty.
Result<InspectionAdjustment> AdjustProgramFromInspection(const EditableProgram& program,
                                                         const ProgramGeometry& geometry,
                                                         const recon::FootPointProjector& nominal,
                                                         const std::vector<metrology::Deviation>& points,
                                                         const std::map<std::string, double>& block_load,
                                                         const InspectionOptions& options, const std::string& source);

// The inspection table of `formloop analyse` / a run's loop-K/deviations.csv (x, y, z = contact point,
// nx, ny, nz, id, foot_x, foot_y, foot_z, deviation_um) as deviations.
Result<std::vector<metrology::Deviation>> DeviationsFromTable(const PointSet& table, const std::string& source);

// The inspection log (§3.5): JSON Lines, one record per inspection, appended (fsync'd); the reader checks
// every record against the schema (ValidateInspectionRecord) and names the line that fails.
Status ValidateInspectionRecord(const nlohmann::json& record);
Status AppendInspectionLog(const std::filesystem::path& path, const nlohmann::json& record);
Result<std::vector<nlohmann::json>> ReadInspectionLog(const std::filesystem::path& path);

}  // namespace formloop::planning
