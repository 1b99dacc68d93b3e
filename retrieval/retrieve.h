#pragma once
// Case retrieval and routing over a trained case library (spec/case-library.md §2–§4; issue 7).
//
// Training (TrainLibraryGhsom, `formloop kb train`): the library's cases with a descriptor, sorted by uid,
// become rows of X (N × 24); a Standardiser is fitted on X and stored with the map; TrainGhsom runs on the
// z-scores with input ids 0..N−1 (row = position in "case_uids"). The stored GhsomRecord holds:
//   parameters: {"ghsom": GhsomOptions, "standardiser": Standardiser, "case_uids": [...], "descriptor_names"}
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
// GHSOM chains, refined within the query's leaf with r = radius_scale · LeafRadius(leaf) in z-score units),
// ranked (A descending, uid ascending) and the best A routed with the rule-base thresholds:
//   A > high → "direct" (rule route.direct), low ≤ A ≤ high → "simulate" (route.simulate),
//   A < low → "default" (route.default, flagged for an engineer).
// Facet weights are the rule base's "facet.weights" restricted to the index's facets; a facet the rule base
// does not weigh (e.g. "geometry" in a version-1 rule base) gets kDefaultGeometryWeight (geometry) or 1.
// radius_scale comes from the optional rule "retrieval.refinement" {"radius_scale": κ} (default 1).
// Descriptor choice: the GHSOM input is x = w ⊙ z (z the z-scores), w from the optional rule
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

struct RetrieveOptions {
  int breadth = 1;
  int min_candidates = 1;
  int top = 5;                 // candidates listed in the result
  // > 0: of the gathered candidates only the max_scored nearest in the GHSOM input space (||x' − x||) are scored
  // with A (for large leaves of big libraries; an approximation: a farther case with better categorical facets
  // can be missed). 0: every candidate is scored.
  int max_scored = 0;
  std::string exclude_uid;     // leave-one-out: never return this case
  Status Validate() const;
};

struct RetrievedCase {
  std::string uid;
  std::string family;
  CaseSimilarity similarity;
};

struct RetrievalResult {
  std::vector<std::string> query_chain;  // root → ... → leaf unit
  double r_leaf = 0;                     // refinement radius used (z-score units)
  int breadth_used = 0;
  int candidates = 0;
  std::vector<RetrievedCase> ranked;     // best first, at most options.top
  std::string route;                     // "direct", "simulate" or "default"
  double best_similarity = 0;
  nlohmann::json route_rule;             // the rule-base choice of the route
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
  static Result<RetrievalModel> Assemble(const std::vector<kb::CaseRecord>& cases, Standardiser standardiser,
                                         Eigen::VectorXd input_weights, Ghsom ghsom, const std::vector<std::string>& case_uids,
                                         const std::vector<kb::Rule>& rules, const FacetTaxonomies& taxonomies);

  // The GHSOM input of a raw descriptor: w ⊙ z.
  Result<Eigen::VectorXd> Input(const Eigen::VectorXd& descriptor) const;
  // Query from a GHSOM input (Input()) and facet concepts.
  Result<RetrievalResult> RetrieveInput(const Eigen::VectorXd& x, const std::map<std::string, std::string>& concepts,
                                        const RetrieveOptions& options) const;
  // Query from a descriptor (24 raw values) and facet concepts (PartFeatures::Concepts()).
  Result<RetrievalResult> Retrieve(const Eigen::VectorXd& descriptor, const std::map<std::string, std::string>& concepts,
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
  static Result<nlohmann::json> LeaveOneOut(const std::vector<kb::CaseRecord>& cases, const GhsomOptions& ghsom,
                                            const std::vector<kb::Rule>& rules, const FacetTaxonomies& taxonomies,
                                            const RetrieveOptions& options);

  const Ghsom& ghsom() const { return ghsom_; }
  const Standardiser& standardiser() const { return standardiser_; }
  const Eigen::VectorXd& input_weights() const { return input_weights_; }
  const kb::RouteThresholds& thresholds() const { return thresholds_; }
  const std::map<std::string, double>& weights() const { return weights_; }
  double radius_scale() const { return radius_scale_; }
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
  std::map<std::string, nlohmann::json> route_rules_;
  std::shared_ptr<const CaseSimilarityIndex> index_;
};

// The route name for A under thresholds (see the header comment).
std::string RouteOf(double a, const kb::RouteThresholds& thresholds);

}  // namespace formloop::retrieval
