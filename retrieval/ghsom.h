#pragma once
// Growing hierarchical self-organising map (GHSOM) over standardised case feature vectors
// (spec/case-library.md §2): the geometric facet taxonomy of the case library.
//
// Sources: M. Dittenbach, D. Merkl, A. Rauber, "The growing hierarchical self-organizing map",
// Proc. IJCNN 2000, vol. 6, pp. 15–19; A. Rauber, D. Merkl, M. Dittenbach, "The growing hierarchical
// self-organizing map: exploratory analysis of high-dimensional data", IEEE Trans. Neural Networks
// 13(6):1331–1341, 2002.
//
// Where it sits: retrieval layer (above kb, reconstruction, core). Inputs are z-scores: fit a
// Standardiser on the case features, apply it to the cases and to every query (the same scaling).
//
// The algorithm, as implemented (every choice below is deterministic; ties go to the lowest index):
//   Layer 0. One unit w_0 = mean of all N inputs; mqe_0 = (1/N) Σ_j ||w_0 − x_j|| (Euclidean).
//   A new map (of a parent unit p with weight w_p and inputs X_p) starts as 2 × 2 units. Let
//     λ_1 ≥ λ_2 and v_1, v_2 be the two largest eigenpairs of the (1/n) covariance of X_p (Eigen
//     SelfAdjointEigenSolver), each eigenvector's sign fixed so that its largest-magnitude component
//     (lowest index on ties) is positive. Unit (r, c), r, c ∈ {0, 1}, starts at
//       w_p + init_offset · ((2c − 1) √λ_1 v_1 + (2r − 1) √λ_2 v_2).
//     Degenerate parents: when λ_1 ≤ 1e-24 (no spread at all) v_1 is a unit vector drawn from
//     Rng(seed ⊕ map id) with scale 1e-3 in place of √λ_1; when λ_2 ≤ 1e-12 λ_1 (or D = 1), v_2 is
//     drawn the same way, orthogonalised against v_1, with the scale of v_1. So four distinct units
//     whenever D ≥ 2.
//   Training: batch SOM (Kohonen 2001, Self-Organizing Maps, §3.14), `epochs` passes. In pass t
//     (0-based) every input is assigned its best-matching unit (BMU, smallest squared distance
//     ||x||² + ||w||² − 2 x·w, computed as one matrix product), then w_k := Σ_u h_ku S_u / Σ_u h_ku n_u,
//     where S_u and n_u are the sum and count of the inputs whose BMU is u and
//     h_ku = exp(−g_ku² / (2σ_t²)) with g_ku the Euclidean distance of the grid positions (row, col).
//     σ_t falls geometrically from sigma_start_units to sigma_end_units:
//     σ_t = σ_s (σ_e / σ_s)^(t / (epochs − 1)). A unit with Σ_u h_ku n_u = 0 keeps its weight.
//   Unit statistics after training (BMUs reassigned with the final weights): n_i inputs,
//     mqe_i = mean ||w_i − x|| over them (0 when n_i = 0), MQE_m = mean of mqe_i over units with n_i > 0.
//   Breadth growth: while MQE_m ≥ tau1 · mqe_parent (mqe_parent = mqe_0 for the layer-1 map, else the
//     parent unit's mqe_i), MQE_m > 0 and the grown map stays within max_units_per_map: the error
//     unit e is the unit with the largest mqe_i (the IJCNN 2000 choice: mean, not summed, error); d is
//     its 4-neighbour with the largest ||w_e − w_d||; a column is inserted between them when they
//     share a row, otherwise a row; each new unit's weight is the mean of its two neighbours across
//     the insertion; the whole map is retrained (same schedule, from the current weights).
//   Depth growth: after a map stops growing, each unit i (in index order) with mqe_i ≥ tau2 · mqe_0,
//     mqe_i > 0 and n_i ≥ min_inputs_for_child gets a child map trained on its inputs, as long as the
//     map's depth < max_depth. Maps are built breadth first; map ids count up in creation order; the
//     layer-1 map is "m0".
//   Map quality: QE = mean over the map's inputs of the distance to their BMU; TE (topographic
//     error) = fraction of the map's inputs whose best and second-best units are not 4-neighbours
//     on the grid.
//
// Concepts. Unit u of map m is the concept "m<m>.u<u>" (u = row · cols + col); the root (layer 0) is
// "root". A map id, once given, is never reused and Insert never reshapes an existing map, so the
// concept ids of a model stay valid as it grows (new subtrees get new ids).
//
// Leaf radius r_leaf of a leaf unit (a unit with no child map) = max over the inputs mapped to it of
// ||x − w||, floored at kMinLeafRadius (an empty or single-point leaf still has a positive radius). It
// is the scale of the within-leaf similarity refinement s = 1 − (1 − s_leaf) · min(1, ||x' − x|| / r_leaf).
//
// Incremental insertion (Insert): the case descends to its leaf unit; every unit on the path takes the
// input (n, mqe, radius and its map's QE, TE and MQE updated for the one new input; weights are not
// moved). When the leaf then has mqe ≥ tau2 · mqe_0 (mqe_0 stays the value of the full training),
// n ≥ min_inputs_for_child and its map is shallower than max_depth, a subtree is trained below it from
// all its inputs by the same rules (new map ids). A full retrain is TrainGhsom on all the inputs.
//
// Cost: each (re)training is O(n · units · D · epochs) (matrix products) for the n inputs of the map;
// a descent is O(units on the path · D).

#include <Eigen/Core>
#include <cstdint>
#include <nlohmann/json.hpp>
#include <string>
#include <vector>

#include "core/status.h"

namespace formloop::retrieval {

// Smallest leaf radius, in z-score units: far below any spread a case feature has, but positive so
// the within-leaf refinement never divides by zero.
inline constexpr double kMinLeafRadius = 1e-6;

// Per-component z-scores: z_k = (x_k − mean_k) / std_k. std_k is the sample standard deviation
// (divisor N − 1). A component whose std is ≤ 1e-12 · max(1, |mean|) has no spread: its std is set to
// 1 (so it standardises to x_k − mean_k, 0 for the cases) and its index is listed in
// constant_components.
struct Standardiser {
  Eigen::VectorXd mean;                  // D
  Eigen::VectorXd std;                   // D, all > 0
  std::vector<int> constant_components;  // ascending

  // x: N × D, one case per row, N ≥ 2, all finite. Errors name the row and column.
  static Result<Standardiser> Fit(const Eigen::MatrixXd& x);
  int dimension() const { return static_cast<int>(mean.size()); }
  // Rows of x (N × D) standardised (a separate name: an Eigen expression would fit both overloads).
  // BadInput when the column count differs from D.
  Result<Eigen::MatrixXd> ApplyRows(const Eigen::MatrixXd& x) const;
  // One vector (D) standardised. BadInput when the size differs from D.
  Result<Eigen::VectorXd> Apply(const Eigen::VectorXd& x) const;

  nlohmann::json ToJson() const;
  static Result<Standardiser> FromJson(const nlohmann::json& j);
};

struct GhsomOptions {
  double tau1 = 0.3;               // breadth (λ): a map grows until MQE_m < 0.3 · mqe_parent, i.e. it must
                                   // explain 70 % of its parent's error — moderate maps; smaller = wider
  double tau2 = 0.03;              // depth (γ): a unit whose mqe is ≥ 3 % of the whole library's mqe_0 is
                                   // expanded — a fine taxonomy; larger = shallower
  int min_inputs_for_child = 16;   // 4 per unit of the child's initial 2 × 2 map: fewer cannot be organised
  int max_depth = 5;               // depth of the deepest map (layer-1 map = 1); caps degenerate chains
  int max_units_per_map = 64;      // an 8 × 8 map: wider maps at one level defeat the hierarchy
  int epochs = 20;                 // batch-SOM passes per (re)training: batch SOM settles in tens of passes
  double sigma_start_units = 1.0;  // Gaussian neighbourhood width at the first pass, in grid cells:
                                   // a unit pulls its 4-neighbours at weight e^-0.5 (orders the map)
  double sigma_end_units = 0.25;   // at the last pass: neighbour weight e^-8 ≈ 3e-4, close to k-means (low QE)
  double init_offset = 0.5;        // initial 2 × 2 units at ± half a principal standard deviation
  std::uint64_t seed = 20000724;   // only for degenerate initial directions (see above); fixed
  Status Validate() const;         // BadInput naming the field
  nlohmann::json ToJson() const;
  static Result<GhsomOptions> FromJson(const nlohmann::json& j);
};

// A unit of a map: the concept "m<map>.u<index>".
struct GhsomUnit {
  std::vector<int> inputs;         // rows of the stored inputs (Ghsom::input) mapped here, ascending
  double mqe = 0;                  // mean ||w − x|| over inputs (0 when none), z-score units
  double radius = kMinLeafRadius;  // max ||w − x|| over inputs, floored at kMinLeafRadius
  int child_map = -1;              // id of the child map, −1 for a leaf
};

struct GhsomMap {
  int id = 0;
  int parent_map = -1;   // −1: the layer-1 map, whose parent is the root unit
  int parent_unit = -1;  // unit index in parent_map (−1 for the root)
  int depth = 1;         // layer-1 map = 1
  int rows = 2, cols = 2;
  Eigen::MatrixXd weights;  // (rows · cols) × D, unit u = row · cols + col
  std::vector<GhsomUnit> units;
  double mqe_parent = 0;       // the breadth threshold's basis: mqe of the parent unit (mqe_0 for layer 1)
  double mqe = 0;              // MQE_m
  double qe = 0;               // mean distance of the map's inputs to their BMU
  double te = 0;               // topographic error, in [0, 1]
  int input_count = 0;         // inputs trained on (plus inserted)
  int insertions = 0;          // rows/columns inserted by breadth growth
  int topographic_errors = 0;  // te · input_count, kept exact for Insert

  int unit_count() const { return rows * cols; }
};

// (map id, unit index) of a concept.
struct GhsomUnitRef {
  int map = -1;
  int unit = -1;
  bool operator==(const GhsomUnitRef&) const = default;
};

// Timing and shape of a training run. Kept out of Ghsom::ToJson so that the model serialises
// byte-identically run to run.
struct GhsomReport {
  struct MapRow {
    int id = 0, depth = 0, rows = 0, cols = 0, inputs = 0, insertions = 0;
    double mqe = 0, qe = 0, te = 0;
    double training_time_s = 0;     // wall time of this map's training and breadth growth
    bool unit_cap_reached = false;  // breadth growth stopped by max_units_per_map, not by tau1
  };
  std::vector<MapRow> maps;
  int unit_count = 0;  // units over all maps
  int leaf_count = 0;
  int max_depth = 0;   // deepest map
  double leaf_qe = 0;  // mean over inputs of the distance to the leaf unit they are stored under
  double wall_time_s = 0;
  double cpu_time_s = 0;
  nlohmann::json ToJson() const;
};

// What Insert did.
struct GhsomInsertReport {
  std::vector<GhsomUnitRef> path;  // maps and units the input descended through
  bool retrained = false;          // a subtree was trained below the leaf
  std::vector<int> new_maps;       // ids of the maps of that subtree
  double leaf_mqe = 0;             // the leaf's mqe after taking the input
  double threshold = 0;            // tau2 · mqe_0
};

class Ghsom {
 public:
  Ghsom() = default;

  const GhsomOptions& options() const { return options_; }
  int dimension() const { return static_cast<int>(mean0_.size()); }
  const Eigen::VectorXd& root_weight() const { return mean0_; }  // w_0
  double mqe0() const { return mqe0_; }
  // Maps in ascending id order.
  const std::vector<GhsomMap>& maps() const { return maps_; }
  // Map by id, nullptr when no such map.
  const GhsomMap* map(int id) const;
  // Stored inputs (standardised), one per row, and their caller ids (row index for TrainGhsom
  // without ids).
  int input_count() const { return static_cast<int>(ids_.size()); }
  Eigen::VectorXd input(int row) const;
  std::int64_t input_id(int row) const { return ids_[static_cast<std::size_t>(row)]; }

  // "m<map>.u<unit>"; "root" for {−1, −1}.
  static std::string ConceptId(const GhsomUnitRef& ref);
  // Inverse of ConceptId for a unit that exists in this model; BadInput / NotFound otherwise.
  Result<GhsomUnitRef> ParseConceptId(const std::string& id) const;

  // The chain of BMUs from the layer-1 map down to a leaf unit. Empty when x_std has the wrong size
  // or a non-finite component (or the model is empty).
  std::vector<GhsomUnitRef> Descend(const Eigen::VectorXd& x_std) const;
  // {"root", "m0.u3", "m2.u1", ...}: the concept ids of Descend, preceded by "root". Empty when
  // Descend is.
  std::vector<std::string> ConceptPath(const Eigen::VectorXd& x_std) const;

  // 4-neighbours of a unit on its map's grid (ascending unit index), for gathering candidate cases
  // from neighbouring concepts; empty for an unknown unit.
  std::vector<int> GridNeighbours(const GhsomUnitRef& ref) const;
  // Caller ids of the inputs mapped to a unit (for a leaf: its cases), in row order.
  std::vector<std::int64_t> InputIds(const GhsomUnitRef& ref) const;
  // r_leaf of a unit (see the header); kMinLeafRadius for an unknown unit.
  double LeafRadius(const GhsomUnitRef& ref) const;
  // Every leaf unit (unit without a child map), by ascending map id then unit.
  std::vector<GhsomUnitRef> Leaves() const;
  // Mean over all inputs of the distance to the leaf unit they are stored under.
  double LeafQe() const;

  // Adds one standardised input under caller id input_id (must not be in use) and grows the tree
  // locally as described above. BadInput for a wrong size, non-finite values or a used id.
  Status Insert(const Eigen::VectorXd& x_std, std::int64_t input_id, GhsomInsertReport* report = nullptr);

  // The whole model: options, w_0, mqe_0, the inputs and ids, every map. Doubles are written in
  // nlohmann's shortest round-trip form, so FromJson(ToJson()) reproduces every value exactly.
  nlohmann::json ToJson() const;
  // Validates structure and consistency (errors name the JSON path, e.g. "maps[2].units[5].inputs").
  static Result<Ghsom> FromJson(const nlohmann::json& j);

 private:
  friend class GhsomBuilder;
  GhsomOptions options_;
  Eigen::VectorXd mean0_;
  double mqe0_ = 0;
  std::vector<double> data_;  // input_count × D, row-major
  std::vector<std::int64_t> ids_;
  std::vector<GhsomMap> maps_;  // ascending id
  int next_map_id_ = 0;
};

// Trains a GHSOM on x_standardised (N × D, one case per row, N ≥ 2, D ≥ 1, all finite) with input ids
// 0..N−1, or the given ids (N of them, distinct). report (optional) receives timings and shape.
Result<Ghsom> TrainGhsom(const Eigen::MatrixXd& x_standardised, const GhsomOptions& options,
                         GhsomReport* report = nullptr);
Result<Ghsom> TrainGhsom(const Eigen::MatrixXd& x_standardised, const std::vector<std::int64_t>& input_ids,
                         const GhsomOptions& options, GhsomReport* report = nullptr);

}  // namespace formloop::retrieval
