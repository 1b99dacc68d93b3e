#pragma once
// The measurement model of spec/tuning-and-link.md §1: the part's dimensions, the probe points each uses,
// the coefficient matrix K (dimensions × offsets) and the offsets with their bounds, resolution and
// safety limits. A JSON file, validated on load; every message names the dimension, offset or point and
// the fix.
//
//   {
//     "format": "formloop.measurement_model", "version": 1,
//     "part": {"code": "BRKT-22", "drawing_revision": "C"},        // optional: project, machine
//     "machine": {"serial": "M-01"},
//     "processes": [{"id": "OP10", "nc_program": "O1000", "measuring_program": "O9000",
//                    "tools": [3], "wcs": ["G54"]}],
//     "point_uncertainty_mm": 0.0005,      // default u of a probe point on each measured axis
//     "max_point_deviation_mm": 0.5,       // a measured axis this far from its reference: invalid point
//     "points": [{"id": 1, "process": "OP10", "reference_mm": [-118, 0, -5],
//                 "approach": [1, 0, 0], "axes": "X", "u_mm": 0.0005}],
//     "offsets": [{"id": "T3_radius_wear", "kind": "TOOL_RADIUS_WEAR", "tool": 3, "address": "",
//                  "resolution_mm": 0.001, "delta_min_mm": -0.05, "delta_max_mm": 0.05,
//                  "limit_mm": 0.1, "baseline_mm": 0, "step_limit_mm": 0.03, "weight": 1e-4},
//                 {"id": "G54_X", "kind": "WORK_OFFSET", "wcs": "G54", "axis": "X", "baseline_mm": -250.0, ...}],
//     "dimensions": [{"id": "D1", "name": "outer width", "process": "OP10", "type": "LENGTH",
//                     "method": "TWO_POINT", "axis": "X", "nominal_mm": 24.0, "tol_upper_mm": 0.02,
//                     "tol_lower_mm": -0.02, "weight": 1, "mode": "COMPENSATE", "target": "NOMINAL",
//                     "points": [{"id": 1, "role": "WALL_A"}, {"id": 2, "role": "WALL_B"}],
//                     "k_row": {"T3_radius_wear": 2}}],
//     "block": {"mode": "NEAREST", "max_age_min": 30},
//     "solver": {"rho": 1000, "band_shrink": 1.0},
//     "average": {"skip_band_mm": 0.002, "max_mm": 0.020}
//   }
//
// Dimension fields: type and method as in metrology/dimensions.h; sizes and locations give nominal_mm,
// tol_upper_mm, tol_lower_mm (signed, lower < upper); zone types (FLATNESS, ROUNDNESS, PARALLELISM,
// PERPENDICULARITY, COAXIALITY, SYMMETRY, TRUE_POSITION) give tolerance_mm (t > 0) and nothing else, and
// must be TOLERANCE_ONLY (their K row is 0: spec §1.2 — model a location error as signed POSITION
// dimensions instead); ANGLE gives nominal_deg, tol_upper_deg, tol_lower_deg; TRUE_POSITION also gives
// nominal_position_mm [u, v]; POSITION by CIRCLE may give feature_axis (the circle's axis, default Z) when
// `axis` is the measuring direction. mode is COMPENSATE, TOLERANCE_ONLY (alias CHECK_ONLY: judged, never drives
// offsets) or IGNORE (not evaluated); target NOMINAL (default) or BAND_CENTRE. A COMPENSATE dimension
// needs a non-zero k_row. axis is X, Y or Z. Points: reference_mm is the nominal surface point in the
// process WCS; axes lists the axes the probe measures (the others keep their reference value), default
// "XYZ"; approach is the probing direction (into the material).
//
// Offsets: kind TOOL_RADIUS_WEAR | TOOL_LENGTH_WEAR (with tool ≥ 1) | WORK_OFFSET (with wcs and axis);
// delta_min_mm ≤ 0 ≤ delta_max_mm (solver bounds on the change), limit_mm L > 0 with |new − baseline| ≤ L
// (default 0.1), baseline_mm b (0 for wear, the setup value for work offsets), optional step_limit_mm on
// |change|, resolution_mm q > 0 (default 0.001), weight w_c > 0 (default 1e-4; larger = moved less).

#include <filesystem>
#include <map>
#include <optional>
#include <string>
#include <vector>

#include <Eigen/Core>
#include <nlohmann/json.hpp>

#include "core/status.h"
#include "metrology/dimensions.h"
#include "metrology/standard_block.h"
#include "tuning/offset_solve.h"
#include "tuning/wear_average.h"

namespace formloop::tuning {

enum class DimensionMode { kCompensate, kToleranceOnly, kIgnore };
enum class DimensionTarget { kNominal, kBandCentre };
enum class OffsetKind { kToolRadiusWear, kToolLengthWear, kWorkOffset };
const char* DimensionModeName(DimensionMode mode);
const char* OffsetKindName(OffsetKind kind);

struct ModelPoint {
  int id = 0;  // 1..2000 (spec §1.1)
  std::string process;
  Eigen::Vector3d reference_mm = Eigen::Vector3d::Zero();
  Eigen::Vector3d approach = Eigen::Vector3d::Zero();
  std::array<bool, 3> measured = {true, true, true};
  double u_mm = 0;
};

struct PointRef {
  int id = 0;
  std::string role;
};

struct ModelDimension {
  std::string id, name, process;
  metrology::DimensionDefinition definition;  // type, method, axis, nominal position
  metrology::Tolerance tolerance;             // nominal, upper, lower (mm; degrees for ANGLE)
  bool angle = false;                         // values in degrees
  double weight = 1;
  DimensionMode mode = DimensionMode::kCompensate;
  DimensionTarget target = DimensionTarget::kNominal;
  std::vector<PointRef> points;
  std::map<std::string, double> k_row;  // offset id → K_ij
};

struct ModelOffset {
  std::string id;
  OffsetKind kind = OffsetKind::kToolRadiusWear;
  int tool = 0;
  std::string wcs, axis, address;
  double resolution_mm = 0.001;
  double delta_min_mm = -0.05, delta_max_mm = 0.05;
  double limit_mm = 0.1;
  double baseline_mm = 0;
  std::optional<double> step_limit_mm;
  double weight = 1e-4;
};

struct MeasurementModel {
  std::string source;  // file, for messages
  std::string part_code, drawing_revision, machine_serial, project;
  std::vector<ModelPoint> points;
  std::vector<ModelOffset> offsets;
  std::vector<ModelDimension> dimensions;
  double max_point_deviation_mm = 0.5;
  metrology::BlockMode block_mode = metrology::BlockMode::kNearest;
  double block_max_age_s = 1800;
  OffsetSolveOptions solver;
  AverageOptions average;

  const ModelPoint* FindPoint(int id) const;
  int OffsetIndex(const std::string& id) const;  // −1 when unknown
};

Result<MeasurementModel> ParseMeasurementModel(const nlohmann::json& json, const std::string& source);
Result<MeasurementModel> ReadMeasurementModel(const std::filesystem::path& path);

}  // namespace formloop::tuning
