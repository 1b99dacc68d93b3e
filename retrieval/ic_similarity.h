#pragma once
// Information-content similarity between a query part and library cases (spec/case-library.md §3).
//
// Pair similarity of two concepts a, b of one facet, with c = Lca(a, b) their lowest common node
// (the seed's common node B_i−) and IC from retrieval/taxonomy.h (natural log, nats):
//   Resnik(a, b) = IC(c)                                  (Resnik 1995, IJCAI; NLTK res_similarity)
//   Lin(a, b)    = 2·IC(c) / (IC(a) + IC(b)), 1 when IC(a) = IC(b) = 0
//                                                        (Lin 1998, ICML "An information-theoretic
//                                                        definition of similarity"; NLTK lin_similarity)
// In a tree the lowest common node is also the common subsumer of highest IC (IC never decreases
// from parent to child), so both equal NLTK's values computed with the same propagated counts.
// Lin is in [0, 1]: IC(c) ≤ min(IC(a), IC(b)). Lin(a, a) = 1. A pair whose only common node is the
// root has Resnik = Lin = 0 (unless both are the root or carry every case: then Lin = 1 by the spec).
//
// The geometric facet. Its taxonomy is the GHSOM hierarchy: every case carries its concept chain
// root → map units → leaf unit id (node ids as strings) and its standardised feature vector x (the
// GHSOM's input space). The tree is built from all cases' chains (Taxonomy::FromChains); the query's
// chain comes from descending the same GHSOM and may end in nodes no case lies under (IC by the
// zero-count policy). When query and case end in the same leaf unit their Lin similarity is 1 and
// says nothing more, so it is refined continuously with their distance d = ||x' − x|| (spec §3):
//   Sim = 1 − (1 − s_leaf) · min(1, d / r_leaf),
//   s_leaf = IC(parent(leaf)) / IC(leaf)   (0 when IC(leaf) = 0 or the leaf is the root).
// Why that s_leaf: it is the Lin similarity 2·IC(parent) / (IC(leaf) + IC(leaf)) of two different
// units under the same parent map that are as populated as this leaf — what a case just across the
// unit's border would score. So a case at the leaf's radius (d ≥ r_leaf) scores like a neighbour
// unit, an identical part (d = 0) scores 1, and any part with d ≤ 0.05·r_leaf scores ≥ 0.95 whatever
// s_leaf is (Sim ≥ 1 − 0.05·(1 − s_leaf)). When IC(leaf) = 0 (every case sits in this unit) the
// taxonomy tells nothing and geometry alone decides (s_leaf = 0). r_leaf is the refinement radius
// in the units of x, supplied by the caller (retrieval/retrieve.h: the query's leaf radius times a
// scale, or one radius from the rule base); r_leaf = 0 makes the refinement a step: 1 when d = 0,
// s_leaf otherwise.
//
// Overall similarity ("standardised similarity"): A = Σ_i ω_i Sim_i / Σ_i ω_i over the facets, with
// weights ω_i ≥ 0 from the rule base (§5), Σ ω_i > 0. A result carries each facet's concepts, common
// node, ICs and similarity: the explanation of why a case was retrieved.

#include <Eigen/Core>
#include <map>
#include <nlohmann/json.hpp>
#include <optional>
#include <string>
#include <vector>

#include "core/status.h"
#include "retrieval/taxonomy.h"

namespace formloop::retrieval {

// The name of the geometric facet in weights and results.
inline constexpr char kGeometricFacet[] = "geometry";

// Resnik and Lin of one pair of concepts, with the common node and the ICs behind them.
struct ConceptSimilarity {
  std::string a, b;                          // canonical node names (aliases resolved)
  std::string common;                        // lowest common node Lca(a, b)
  double ic_a = 0, ic_b = 0, ic_common = 0;  // nats
  double resnik = 0;                         // = ic_common, nats
  double lin = 0;                            // in [0, 1]
  nlohmann::json ToJson() const;
};

// a, b: names or aliases of nodes of counts.taxonomy(). NotFound naming the unknown concept;
// BadInput under ZeroCountPolicy::kRefuse when an IC is undefined.
Result<ConceptSimilarity> CompareConcepts(const ConceptCounts& counts, const std::string& a, const std::string& b);
Result<double> ResnikSimilarity(const ConceptCounts& counts, const std::string& a, const std::string& b);
Result<double> LinSimilarity(const ConceptCounts& counts, const std::string& a, const std::string& b);
// Lin from the three ICs (1 when ic_a = ic_b = 0; the caller guarantees ic_common ≤ min(ic_a, ic_b)).
double LinFromIc(double ic_common, double ic_a, double ic_b);

// s_leaf of a leaf unit (see the header comment) from the geometric facet's counts.
Result<double> LeafFloorSimilarity(const ConceptCounts& counts, int leaf);
// 1 − (1 − s_leaf)·min(1, distance / r_leaf); r_leaf = 0: 1 when distance = 0, else s_leaf.
// BadInput when s_leaf ∉ [0, 1], distance < 0 or r_leaf < 0 or any is not finite.
Result<double> RefineWithinLeaf(double s_leaf, double distance, double r_leaf);

// The concepts of one part (a library case or the query).
struct CaseConcepts {
  std::string case_id;                             // unique in the library; the ranking tie-break
  std::map<std::string, std::string> categorical;  // facet name → concept (name or alias)
  std::vector<std::string> geometric_chain;        // root → ... → leaf unit id; empty: no geometric facet
  Eigen::VectorXd geometric_x;                     // standardised feature vector (GHSOM input space)
};

struct SimilarityOptions {
  // Facet name → ω ≥ 0 (kGeometricFacet for the geometric facet). Empty: every facet weighs 1.
  // Otherwise it must name exactly the index's facets (a missing or unknown facet is an error, so a
  // typo in the rule base cannot silently drop a facet).
  std::map<std::string, double> facet_weights;
  ZeroCountPolicy zero_count_policy = ZeroCountPolicy::kHalfCount;  // see retrieval/taxonomy.h
  // BadInput naming the facet when a weight is negative or not finite, or when all are zero.
  Status Validate() const;
};

struct FacetSimilarity {
  std::string facet;
  std::string query_concept, case_concept, common_node;  // canonical names / node ids
  double ic_query = 0, ic_case = 0, ic_common = 0;       // nats
  double lin = 0;                                        // Lin of the pair
  bool refined = false;                                  // geometric facet, same leaf unit: refined with the distance
  double s_leaf = 0;                                     // when refined
  double distance = 0;                                   // ||x' − x||, when refined
  double r_leaf = 0;                                     // when refined
  double similarity = 0;                                 // Sim_i: lin, or the refined value
  double weight = 0;                                     // ω_i
  nlohmann::json ToJson() const;
};

struct CaseSimilarity {
  std::string case_id;
  double overall = 0;                   // A in [0, 1]
  std::vector<FacetSimilarity> facets;  // in facet-name order, the geometric facet last
  nlohmann::json ToJson() const;
};

// The library side of retrieval: one ConceptCounts per facet over the library's cases.
class CaseSimilarityIndex {
 public:
  // taxonomies: categorical facet name → its taxonomy; every case must give a concept for every
  // one of them (NotFound naming the case and facet otherwise). The geometric facet is present when
  // the cases carry chains (all of them must, with feature vectors of one length, or none).
  static Result<CaseSimilarityIndex> Build(const std::map<std::string, Taxonomy>& taxonomies,
                                           const std::vector<CaseConcepts>& cases, const SimilarityOptions& options);

  // Facet names, categorical in name order, then kGeometricFacet when present.
  const std::vector<std::string>& facets() const { return facets_; }
  bool has_geometric_facet() const { return geometric_.has_value(); }
  // Counts of a facet; NotFound for an unknown facet.
  Result<const ConceptCounts*> counts(const std::string& facet) const;
  double weight(const std::string& facet) const { return weights_.at(facet); }

  // A between the query and one case (normally a library case; any part whose concepts lie in
  // the taxonomies works). r_leaf: the radius of the query's leaf unit (ignored without the
  // geometric facet). BadInput naming the facet for a missing concept, a chain that contradicts
  // the tree, or feature vectors of different lengths.
  Result<CaseSimilarity> Score(const CaseConcepts& query, double r_leaf, const CaseConcepts& candidate) const;
  // Scores every candidate and sorts by A descending, ties by case_id ascending (then input order).
  Result<std::vector<CaseSimilarity>> Rank(const CaseConcepts& query, double r_leaf,
                                           const std::vector<CaseConcepts>& candidates) const;

 private:
  Result<FacetSimilarity> ScoreGeometric(const CaseConcepts& query, double r_leaf, const CaseConcepts& candidate) const;

  std::vector<std::string> facets_;
  std::map<std::string, ConceptCounts> categorical_;
  std::optional<ConceptCounts> geometric_;
  long x_size_ = 0;
  std::map<std::string, double> weights_;
};

}  // namespace formloop::retrieval
