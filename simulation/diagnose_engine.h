#pragma once
// The engine behind diagnose.h (internal to formloop_simulation): the observations as a Problem
// (residuals, where they lie, which part they belong to, and each effect's Jacobian there), terms,
// least-squares fits of sets of terms, and the selection with identifiability analysis. The data
// kinds (probe logs of one or several parts, feature positions) build a Problem and call RunEngine;
// experiment_design.cc reuses the fits to predict what a new measurement would separate.

#include <functional>
#include <string>
#include <vector>

#include <Eigen/Core>

#include "core/status.h"
#include "metrology/spatial_weights.h"
#include "simulation/diagnose.h"

namespace formloop::sim::detail {

// An effect fitted once for all parts (part = kShared), for one part's rows only (part ≥ 0), or with
// its own parameters on each part (part = kEachPart: a set-up when pooling; its columns are one block
// per part, its parameters the parts' in order).
inline constexpr int kShared = -1;
inline constexpr int kEachPart = -2;
struct Term {
  const Effect* effect = nullptr;
  int part = kShared;
  bool operator==(const Term& o) const { return effect == o.effect && part == o.part; }
};

// The observations. Rows are points (probe data) or coordinates (feature positions); several parts are
// stacked, each part's rows contiguous.
struct Problem {
  Eigen::VectorXd r;                         // residual, µm, times the row weight
  Eigen::VectorXd weight;                    // per row: 1 for one part; 1/σ̂ of its part when pooled
  Eigen::MatrixXd xy;                        // n × 2 positions for CV blocks and cluster centroids, mm
  Eigen::MatrixXd pos;                       // n × d positions the k-NN lists were built from (d = 0: none)
  std::vector<int> part_of;                  // per row
  std::vector<std::string> part_names;       // one per part ("" for a single part)
  std::vector<std::vector<int>> neighbours;  // k-NN within each part, for Moran's I
  std::function<bool(const Effect*)> applicable;
  // n × p Jacobian of effect e at θ over every row, unweighted.
  std::function<Eigen::MatrixXd(const Effect*, const std::vector<double>&)> jacobian;
  double time_scale_s = 1;  // for the τ search range when no plausible range is given
  // Rows [0, points) are measured points; rows after them direct measurements of parameters
  // (DirectMeasurement: no position, no neighbours, always in the training set of the block CV).
  // −1: every row is a point.
  int points = -1;
  int n() const { return static_cast<int>(r.size()); }
  int Points() const { return points < 0 ? n() : points; }
  int parts() const { return static_cast<int>(part_names.size()); }
  // Weighted columns of a term at θ (its Width() values; a linear term ignores them): zero outside its
  // part, one block per part for kEachPart.
  Eigen::MatrixXd Columns(const Term& t, const std::vector<double>& theta) const;
  // Parameters of a term: the effect's, times the parts for kEachPart.
  int Width(const Term& t) const;
  // "setup_offset", "setup_offset@B" (one part), "setup_offset@each part".
  std::string Label(const Term& t) const;
};

struct Fit {
  Eigen::VectorXd beta;
  Eigen::VectorXd residual;
  double rss = 0;
  Eigen::MatrixXd cov;  // s² (AᵀA)⁺
  int rank = 0;
};
// covariance = false leaves cov empty (the rest the same numbers): for callers that use the RSS or β only,
// since (AᵀA)⁺ costs a second decomposition as large as the fit's.
Fit LeastSquares(const Eigen::MatrixXd& a, const Eigen::VectorXd& r, bool covariance = true);
// (aᵀa)⁺ through a's unit-norm columns (the same rank decisions as LeastSquares).
Eigen::MatrixXd InverseGram(const Eigen::MatrixXd& a);

// A term fitted together with a fixed design X: its parameters, its linearised columns at them (the
// full Jacobian, so a later fit with these columns can still move τ to first order) and the fit of
// [X, columns]. A nonlinear parameter (τ) is profiled in log τ over [tau_lo, tau_hi].
struct TermFit {
  Term term;
  std::vector<double> theta;
  Eigen::MatrixXd columns;
  Fit fit;
  std::vector<double> std_errors;
};
TermFit FitTerm(const Problem& prob, const Term& term, const Eigen::MatrixXd& x, double tau_lo, double tau_hi);
// The columns of a term's linear parameters at a value τ of its nonlinear one (all its columns when it
// has none).
Eigen::MatrixXd LinearColumnsAt(const Problem& prob, const Term& term, double tau);
// The RSS of [X, the term's linear columns at τ] (the profile of a nonlinear term at one τ).
double ProfileRss(const Problem& prob, const Term& term, const Eigen::MatrixXd& x, double tau);

// Horizontal concatenation.
Eigen::MatrixXd Concat(const Eigen::MatrixXd& a, const Eigen::MatrixXd& b);
// The columns of fitted terms side by side, leaving out term `skip` (−1: none).
Eigen::MatrixXd DesignOf(const std::vector<TermFit>& s, int skip = -1);

// 95 % profile-likelihood intervals of every parameter of the terms `s` ({lower, upper} per term and
// column): the values whose profiled RSS stays below RSS_min (1 + F(0.95; 1, ν)/ν). Without a
// nonlinear term that is the t interval. With one (τ), the linear parameters' conditional intervals at
// each τ of a 64-point log grid over [tau_lo, tau_hi] whose RSS is below the limit are joined (at fixed
// τ the RSS is quadratic in a linear parameter: RSS(b) = RSS(τ) + (b − β̂(τ))² [(XᵀX)⁻¹]_jj⁻¹), and τ's
// own interval is where its profile crosses the limit (bisection), clipped to the range searched.
std::vector<std::vector<std::pair<double, double>>> ProfileIntervals(const Problem& prob, const std::vector<TermFit>& s,
                                                                     double tau_lo, double tau_hi, int nu, double f95);

// Residual Moran's z of `residual` after `design` (plus an intercept), over the first w.n() rows (the
// points; direct-measurement rows after them have no place).
double MoranZ(const Eigen::VectorXd& residual, const Eigen::MatrixXd& design, const metrology::SpatialWeights& w);
double NuggetVariance(const Eigen::VectorXd& r, const std::vector<std::vector<int>>& neighbours);
// The row-standardised k-NN weights of a problem's points (its direct-measurement rows left out).
Result<metrology::SpatialWeights> PointWeights(const Problem& prob);
// k-NN lists of the rows of `points` (n × d), each part on its own when `part_of` is given.
Result<std::vector<std::vector<int>>> KnnLists(const Eigen::MatrixXd& points, int k,
                                               const std::vector<int>* part_of = nullptr);

// The largest canonical correlation between one member's columns and the other members' columns, both
// with the `others` columns projected out: 1 when the design cannot separate the members at all.
double GroupDesignCorrelation(const std::vector<Eigen::MatrixXd>& members, const Eigen::MatrixXd& others);

// Spatial block cross-validation RMS (µm) of the residual after `design`, refitted without each block.
double BlockCvRms(const Problem& prob, const Eigen::MatrixXd& design, int blocks);

// Rows of probe data: contexts, residual, optional measured sensitivities; the part they belong to
// (−1: their index in the list) and their noise σ (0: estimated from the residual's nugget when there
// are several parts; one part alone is not weighted).
struct PartRows {
  const std::vector<PointContext>* contexts = nullptr;
  const Eigen::VectorXd* residual_um = nullptr;
  const MeasurementSensitivity* sensitivity = nullptr;
  int part = -1;
  double sigma_um = 0;
};
// The stacked problem of probe data rows (diagnose.cc). `labels`: one per part.
// `direct`: direct measurements appended as rows after the points (their effects are not in the
// baseline, so a row's residual is the measured value), weighted by 1/σ_m; the points are then weighted
// by 1/σ̂ of their part (its nugget) even when there is one part, so each row counts by its precision.
Result<Problem> BuildProbeProblem(const std::vector<PartRows>& sets, const std::vector<std::string>& labels, int knn,
                                  const std::vector<DirectMeasurement>& direct = {});

// Selection, identifiability, plausibility, intervals and gain (steps 3–6 and 8 of diagnose.h), with
// the terms selected (named and alias-group members in the model) and their parameters.
struct Selection {
  Diagnosis diagnosis;
  std::vector<Term> terms;
  std::vector<std::vector<double>> theta;
};
Result<Selection> SelectCauses(const Problem& prob, const Model& baseline, const DiagnoseOptions& options);
// Exhaustive best-subset search over `units` (at most `max_size` of them) on the Gram matrix of their
// columns, a nonlinear unit's τ on a coarse log grid: the subset of lowest BIC among those whose every
// unit is significant at α/K given the others (K = units.size()), pays for its parameters (ΔBIC < 0)
// and explains at least `min_share` of the systematic variance it is fitted to (as the forward step
// asks), with every fitted value inside its plausible range. Also the best subset that fails only the
// plausibility, when it beats that one. Furnival & Wilson (1974) search the same space by branch and
// bound; at ≤ 4 of ≤ 20 units plain enumeration is cheap.
struct SubsetSearch {
  std::vector<int> best;  // indices into units
  double best_bic = 0;
  std::vector<int> implausible;  // a better-fitting subset with an implausible value (empty: none)
  double implausible_bic = 0;
};
SubsetSearch BestSubset(const Problem& prob, const std::vector<Term>& units, const DiagnoseOptions& options,
                        double nugget, double tau_lo, double tau_hi, int max_size);

// SelectCauses plus the set-aside of a localised pattern outside the catalogue (step 7).
Result<Diagnosis> RunEngine(const Problem& prob, const Model& baseline, const DiagnoseOptions& options);

// What distinguishes an effect's basis: the hint given when effects are aliased or confounded.
std::string SeparateHint(std::string_view effect);

}  // namespace formloop::sim::detail
