#pragma once
// Case retrieval and routing over a trained case library (spec/case-library.md §2–§4; issue 7).
//
// Training (TrainLibraryGhsom, `formloop kb train`): the library's cases with a descriptor, sorted by uid,
// become rows of D (N × 24); the magnitude transform T (below) and a Standardiser are fitted on them and stored
// with the map; TrainGhsom runs on w ⊙ z(T(D)) with input ids 0..N−1 (row = position in "case_uids"). The stored
// GhsomRecord holds:
//   parameters: {"ghsom": GhsomOptions, "descriptor_transform": T, "standardiser": Standardiser,
//                "case_uids": [...], "input_weights", "descriptor_names"}
//   quality:    GhsomReport (per map QE / TE / MQE, units, leaves, depth, times) + leaf QE
//   map:        Ghsom::ToJson()
//   change_counter: the library's change counter read before the cases (so a concurrent add marks it stale).
//
// Incremental growth (InsertCaseIntoGhsom, used by `formloop kb add`): when the stored GHSOM was current
// before the add, the new case is standardised with the stored scaling and Ghsom::Insert-ed (local subtree
// retraining when its leaf's mqe crosses the depth threshold); the record is stored again with the new change
// counter, so it stays current. Otherwise (no GHSOM, or already stale, or a replaced/removed case) nothing is
// inserted and the GHSOM stays stale until `formloop kb train` (kb check reports it).
//
// Retrieval (RetrievalModel + Retrieve, `formloop retrieve`): the query's descriptor is standardised with the
// stored scaling and descends the GHSOM to its leaf unit. Candidates (breadth): 0 = the leaf's cases;
// 1 = + the cases of its 4-neighbour units on the same map (default); 2 = + every unit of the leaf's map
// (all cases under the parent unit); b ≥ 3 climbs b − 2 more levels. When fewer than min_candidates are
// found, breadth grows by one until enough (or the whole library). Every candidate is scored with A
// (CaseSimilarityIndex: the five categorical facets from data/taxonomies and the geometric facet = the
// GHSOM chains, refined within the query's leaf with r of "Refinement radius" below),
// ranked (A descending, uid ascending) and the best A routed with the rule-base thresholds:
//   A > high → "direct" (rule route.direct), low ≤ A ≤ high → "simulate" (route.simulate),
//   A < low → "default" (route.default, flagged for an engineer).
// Facet weights are the rule base's "facet.weights" restricted to the index's facets; a facet the rule base
// does not weigh (e.g. "geometry" in a version-1 rule base) gets kDefaultGeometryWeight (geometry) or 1.
// Magnitudes on a log scale: the GHSOM input is built from T(d), T_k(d_k) = asinh(d_k / ε_k) for the magnitude
// descriptors (DescriptorIsMagnitude: lengths, area, curvatures, radius, slope, aspect ratios) with ε_k = 1 % of the
// library's median |d_k| (logarithmic for |d_k| ≫ ε_k, continuous through zero for signed curvatures), and
// T_k(d_k) = d_k for the area fractions. So two parts that differ by a given percentage are about the same distance
// apart whatever their size or family; on raw values that distance varied about 4× between the starter families.
// T is fitted when training and stored with the map ("descriptor_transform"); a map stored without it (formloop
// before this) is read with T = identity, as it was trained.
// Refinement radius: the rule "retrieval.refinement" {"radius": r} fixes r in GHSOM input units for every leaf
// (the starter rule base does: a leaf's radius measures how spread its cases are, not how near a part must be to
// reuse a case's plan, and leaves hold one to two families of very different spread); {"radius_scale": κ} gives
// the spec's r = κ · leaf radius (default κ = 1).
// Descriptor choice: the GHSOM input is x = w ⊙ z (z the z-scores of T(d)), w from the optional rule
// "retrieval.descriptors" {"exclude": [descriptor names], "weights": {name: w ≥ 0}} (default all 1), read when
// training and stored with the map ("input_weights"), so queries use the same input space.

#include <filesystem>
#include <map>
#include <string>
#include <vector>

#include <Eigen/Core>
#include <nlohmann/json.hpp>

#include "core/status.h"
#include "kb/library.h"
#include "retrieval/features.h"
#include "retrieval/ghsom.h"
#include "retrieval/ic_similarity.h"

namespace formloop::retrieval {

inline constexpr double kDefaultGeometryWeight = 3.0;

// T of the header comment. eps_k = 0: linear.
struct DescriptorTransform {
  Eigen::VectorXd eps;
  static DescriptorTransform Identity(int dimension);
  // x: N × kDescriptorCount, the library's raw descriptors.
  static DescriptorTransform Fit(const Eigen::MatrixXd& x);
  Eigen::VectorXd Apply(const Eigen::VectorXd& d) const;
  Eigen::MatrixXd ApplyRows(const Eigen::MatrixXd& x) const;
  nlohmann::json ToJson() const;
  static Result<DescriptorTransform> FromJson(const nlohmann::json& j, int dimension);
};

// GHSOM options `kb train` and `kb init --starter` use unless told otherwise (calibrated on the starter
// library, see the .cc).
GhsomOptions LibraryGhsomDefaults();

// The input weights w of the header comment from a rule base (all 1 without the rule). BadInput for an unknown
// descriptor name or a negative weight.
Result<Eigen::VectorXd> InputWeightsFromRules(const std::vector<kb::Rule>& rules);

// Rules in the `kb rules --set` file format ({"rules": [{"name", "condition", "choice"}]} or the array), as
// active rules of version 0 (for in-memory models).
Result<std::vector<kb::Rule>> RulesFromJson(const nlohmann::json& j, const std::string& source);

// The options the library's stored GHSOM was trained with (LibraryGhsomDefaults when none is stored).
Result<GhsomOptions> StoredGhsomOptions(kb::Library& library);

// Trains the library's GHSOM and stores it. Returns the JSON report printed by `kb train`.
Result<nlohmann::json> TrainLibraryGhsom(kb::Library& library, const GhsomOptions& options);

// See the header comment. Returns {"inserted": bool, "reason"/"report": ...}.
Result<nlohmann::json> InsertCaseIntoGhsom(kb::Library& library, const kb::CaseRecord& record,
                                           long long changes_before_add);

// Adds (or, with `replace`, replaces) a case in its own transaction, then grows the GHSOM with it
// (InsertCaseIntoGhsom). The case stays committed whatever the insertion does: a failed insertion only
// leaves the GHSOM stale (kb check reports it); it is logged and returned as {"inserted": false, "reason"}.
// `formloop kb add` and the retain step of `formloop run` both store cases this way.
Result<nlohmann::json> AddCaseAndGrowGhsom(kb::Library& library, const kb::CaseRecord& record, bool replace);

// A case as retrieval uses it (issue 17): the five facet concepts (kShapeFacet ...) present, each a node
// or alias of its facet's taxonomy (the message offers the node that matches but for case and blanks,
// "h13 " -> "H13"), no other facet, and the descriptor, when present, kDescriptorCount finite values.
// BadInput naming the case uid and the field. `formloop kb add` and `kb import` refuse such a case before
// writing anything; `kb check` reports it (RetrievalProblems).
Status CheckCaseForRetrieval(const kb::CaseRecord& record, const FacetTaxonomies& taxonomies);

// What `formloop retrieve` and `run --kb` would trip on in a library: every case through
// CheckCaseForRetrieval, and, when a GHSOM is stored, the retrieval model loaded as retrieval loads it
// (RetrievalModel::Load). One message per problem, empty when retrieval works.
Result<std::vector<std::string>> RetrievalProblems(kb::Library& library, const FacetTaxonomies& taxonomies);

struct RetrieveOptions {
  int breadth = 1;
  int min_candidates = 1;
  int top = 5;  // candidates listed in the result
  // > 0: of the gathered candidates only the max_scored nearest in the GHSOM input space (||x' − x||) are scored
  // with A (for large leaves of big libraries; an approximation: a farther case with better categorical facets
  // can be missed). 0: every candidate is scored.
  int max_scored = 0;
  std::string exclude_uid;  // leave-one-out: never return this case
  Status Validate() const;
};

struct RetrievedCase {
  std::string uid;
  std::string family;
  CaseSimilarity similarity;
};

struct RetrievalResult {
  std::vector<std::string> query_chain;  // root → ... → leaf unit
  double r_leaf = 0;                     // refinement radius used (GHSOM input units)
  int breadth_used = 0;
  int candidates = 0;
  std::vector<RetrievedCase> ranked;  // best first, at most options.top
  std::string route;                  // "direct", "simulate" or "default"
  double best_similarity = 0;
  nlohmann::json route_rule;  // the rule-base choice of the route
  nlohmann::json ToJson() const;
};

class RetrievalModel {
 public:
  // From an open library: its active rule base, newest GHSOM and the cases it was trained on.
  // FailedPrecondition-like Failed when no GHSOM is stored ("run formloop kb train").
  static Result<RetrievalModel> Load(kb::Library& library, const FacetTaxonomies& taxonomies);
  // In memory (tests, bench): standardise `cases`' descriptors, train, index. rules: the rule base (as
  // Library::GetRules gives; empty → the schema's defaults with kDefaultGeometryWeight).
  // exclude_uid: train as if that case were not in `cases` (leave-one-out).
  static Result<RetrievalModel> Train(const std::vector<kb::CaseRecord>& cases, const GhsomOptions& options,
                                      const std::vector<kb::Rule>& rules, const FacetTaxonomies& taxonomies,
                                      const std::string& exclude_uid = "");
  // From parts already computed (a stored GHSOM record's contents).
  static Result<RetrievalModel> Assemble(const std::vector<kb::CaseRecord>& cases, DescriptorTransform transform,
                                         Standardiser standardiser, Eigen::VectorXd input_weights, Ghsom ghsom,
                                         const std::vector<std::string>& case_uids, const std::vector<kb::Rule>& rules,
                                         const FacetTaxonomies& taxonomies);

  // The GHSOM input of a raw descriptor: w ⊙ z(T(d)).
  Result<Eigen::VectorXd> Input(const Eigen::VectorXd& descriptor) const;
  // Query from a GHSOM input (Input()) and facet concepts.
  Result<RetrievalResult> RetrieveInput(const Eigen::VectorXd& x, const std::map<std::string, std::string>& concepts,
                                        const RetrieveOptions& options) const;
  // Query from a descriptor (24 raw values) and facet concepts (PartFeatures::Concepts()).
  Result<RetrievalResult> Retrieve(const Eigen::VectorXd& descriptor,
                                   const std::map<std::string, std::string>& concepts,
                                   const RetrieveOptions& options) const {
    FL_ASSIGN_OR_RETURN(Eigen::VectorXd x, Input(descriptor));
    return RetrieveInput(x, concepts, options);
  }
  Result<RetrievalResult> Retrieve(const PartFeatures& query, const RetrieveOptions& options) const {
    return Retrieve(query.descriptors, query.Concepts(), options);
  }

  // A between a query and one case of the model (all facets), NotFound for a uid not in the model.
  Result<CaseSimilarity> Score(const Eigen::VectorXd& descriptor, const std::map<std::string, std::string>& concepts,
                               const std::string& uid) const;

  // Leave-one-out over a library's cases (spec §4): every case with a descriptor is taken out, a model is
  // trained on the others exactly as Train does (standardiser, GHSOM with `ghsom`, IC counts), and the case is
  // retrieved from it as a new part would be. Reports per route the count and the share whose best case is of
  // the same family, A's distribution, the family confusion of the top-1 case, and one row per case (uid,
  // family, route, A, best case and its family). Whether a route leads to an in-tolerance part needs the part
  // machined again: app/loo_outcomes.h.
  // Every case costs one training, so a big library is sampled: max_cases > 0 leaves out at most that many
  // cases, evenly spaced in uid order (the report says how many of how many).
  static Result<nlohmann::json> LeaveOneOut(const std::vector<kb::CaseRecord>& cases, const GhsomOptions& ghsom,
                                            const std::vector<kb::Rule>& rules, const FacetTaxonomies& taxonomies,
                                            const RetrieveOptions& options, int max_cases = 0);

  const Ghsom& ghsom() const { return ghsom_; }
  const Standardiser& standardiser() const { return standardiser_; }
  const Eigen::VectorXd& input_weights() const { return input_weights_; }
  const kb::RouteThresholds& thresholds() const { return thresholds_; }
  const std::map<std::string, double>& weights() const { return weights_; }
  double radius_scale() const { return radius_scale_; }
  double fixed_radius() const { return fixed_radius_; }  // 0: radius_scale · leaf radius
  const DescriptorTransform& transform() const { return transform_; }
  int case_count() const { return static_cast<int>(cases_.size()); }
  const std::string& family(int row) const { return families_[static_cast<size_t>(row)]; }
  const CaseConcepts& case_concepts(int row) const { return cases_[static_cast<size_t>(row)]; }
  // Cases of the library not in the GHSOM (added after training and not inserted).
  const std::vector<std::string>& untrained() const { return untrained_; }
  const CaseSimilarityIndex& index() const { return *index_; }

 private:
  Result<CaseConcepts> Query(const Eigen::VectorXd& x, const std::map<std::string, std::string>& concepts) const;
  Standardiser standardiser_;
  Eigen::VectorXd input_weights_;
  Ghsom ghsom_;
  std::vector<CaseConcepts> cases_;  // row = GHSOM input id
  std::vector<std::string> families_;
  std::vector<std::string> untrained_;
  std::map<std::string, double> weights_;
  kb::RouteThresholds thresholds_;
  double radius_scale_ = 1.0;
  double fixed_radius_ = 0.0;
  DescriptorTransform transform_;
  double RefinementRadius(const GhsomUnitRef& leaf) const;
  std::map<std::string, nlohmann::json> route_rules_;
  std::shared_ptr<const CaseSimilarityIndex> index_;
};

// The route name for A under thresholds (see the header comment).
std::string RouteOf(double a, const kb::RouteThresholds& thresholds);

}  // namespace formloop::retrieval
