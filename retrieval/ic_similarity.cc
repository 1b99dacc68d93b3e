#include "retrieval/ic_similarity.h"

#include <algorithm>
#include <cmath>

#include "core/number_text.h"

namespace formloop::retrieval {
namespace {

std::string Quoted(const std::string& s) { return "'" + s + "'"; }

}  // namespace

nlohmann::json ConceptSimilarity::ToJson() const {
  return {{"a", a},           {"b", b},    {"common", common}, {"ic_a", ic_a}, {"ic_b", ic_b}, {"ic_common", ic_common},
          {"resnik", resnik}, {"lin", lin}};
}

double LinFromIc(double ic_common, double ic_a, double ic_b) {
  const double sum = ic_a + ic_b;
  if (sum <= 0) return 1.0;  // both ICs 0: the spec defines 1
  return std::clamp(2.0 * ic_common / sum, 0.0, 1.0);
}

Result<ConceptSimilarity> CompareConcepts(const ConceptCounts& counts, const std::string& a, const std::string& b) {
  const Taxonomy& tree = counts.taxonomy();
  FL_ASSIGN_OR_RETURN(const int ia, tree.Require(a, "concept"));
  FL_ASSIGN_OR_RETURN(const int ib, tree.Require(b, "concept"));
  const int ic = tree.Lca(ia, ib);
  ConceptSimilarity s;
  s.a = tree.name(ia);
  s.b = tree.name(ib);
  s.common = tree.name(ic);
  FL_ASSIGN_OR_RETURN(s.ic_a, counts.Ic(ia));
  FL_ASSIGN_OR_RETURN(s.ic_b, counts.Ic(ib));
  FL_ASSIGN_OR_RETURN(s.ic_common, counts.Ic(ic));
  s.resnik = s.ic_common;
  s.lin = LinFromIc(s.ic_common, s.ic_a, s.ic_b);
  return s;
}

Result<double> ResnikSimilarity(const ConceptCounts& counts, const std::string& a, const std::string& b) {
  FL_ASSIGN_OR_RETURN(const ConceptSimilarity s, CompareConcepts(counts, a, b));
  return s.resnik;
}

Result<double> LinSimilarity(const ConceptCounts& counts, const std::string& a, const std::string& b) {
  FL_ASSIGN_OR_RETURN(const ConceptSimilarity s, CompareConcepts(counts, a, b));
  return s.lin;
}

Result<double> LeafFloorSimilarity(const ConceptCounts& counts, int leaf) {
  const Taxonomy& tree = counts.taxonomy();
  if (leaf < 0 || leaf >= tree.size()) return Status::Internal("leaf id outside the geometric taxonomy");
  if (leaf == Taxonomy::kRoot) return 0.0;
  FL_ASSIGN_OR_RETURN(const double ic_leaf, counts.Ic(leaf));
  FL_ASSIGN_OR_RETURN(const double ic_parent, counts.Ic(tree.parent(leaf)));
  if (ic_leaf <= 0) return 0.0;
  return std::clamp(ic_parent / ic_leaf, 0.0, 1.0);
}

Result<double> RefineWithinLeaf(double s_leaf, double distance, double r_leaf) {
  if (!std::isfinite(s_leaf) || s_leaf < 0 || s_leaf > 1) {
    return Status::BadInput(Where{.field = "s_leaf"}, "leaf similarity " + FormatExact(s_leaf) + " is not in [0, 1]");
  }
  if (!std::isfinite(distance) || distance < 0) {
    return Status::BadInput(Where{.field = "distance"},
                            "feature distance " + FormatExact(distance) + " is not a finite number ≥ 0");
  }
  if (!std::isfinite(r_leaf) || r_leaf < 0) {
    return Status::BadInput(Where{.field = "r_leaf"},
                            "leaf radius " + FormatExact(r_leaf) + " is not a finite number ≥ 0",
                            "pass the radius of the query's GHSOM leaf unit");
  }
  double t = 0;
  if (r_leaf == 0) {
    t = distance == 0 ? 0.0 : 1.0;
  } else {
    t = std::min(1.0, distance / r_leaf);
  }
  return 1.0 - (1.0 - s_leaf) * t;
}

Status SimilarityOptions::Validate() const {
  bool any_positive = false;
  for (const auto& [facet, weight] : facet_weights) {
    if (!std::isfinite(weight) || weight < 0) {
      return Status::BadInput(Where{.field = "facet_weights." + facet},
                              "weight " + FormatExact(weight) + " is not a finite number ≥ 0",
                              "give every facet a weight ≥ 0");
    }
    any_positive = any_positive || weight > 0;
  }
  if (!facet_weights.empty() && !any_positive) {
    return Status::BadInput(Where{.field = "facet_weights"}, "all facet weights are zero",
                            "give at least one facet a positive weight");
  }
  return Status::Ok();
}

nlohmann::json FacetSimilarity::ToJson() const {
  nlohmann::json j = {{"facet", facet},
                      {"query_concept", query_concept},
                      {"case_concept", case_concept},
                      {"common_node", common_node},
                      {"ic_query", ic_query},
                      {"ic_case", ic_case},
                      {"ic_common", ic_common},
                      {"lin", lin},
                      {"similarity", similarity},
                      {"weight", weight}};
  if (refined) {
    j["refinement"] = {{"s_leaf", s_leaf}, {"distance", distance}, {"r_leaf", r_leaf}};
  }
  return j;
}

nlohmann::json CaseSimilarity::ToJson() const {
  nlohmann::json j = {{"case_id", case_id}, {"overall", overall}, {"facets", nlohmann::json::array()}};
  for (const FacetSimilarity& f : facets) j["facets"].push_back(f.ToJson());
  return j;
}

Result<CaseSimilarityIndex> CaseSimilarityIndex::Build(const std::map<std::string, Taxonomy>& taxonomies,
                                                       const std::vector<CaseConcepts>& cases,
                                                       const SimilarityOptions& options) {
  FL_RETURN_IF_ERROR(options.Validate());
  if (cases.empty()) return Status::BadInput(Where{.field = "cases"}, "the case library is empty");
  CaseSimilarityIndex index;
  for (const auto& [facet, taxonomy] : taxonomies) {
    if (facet == kGeometricFacet) {
      return Status::BadInput(Where{.field = "taxonomies"},
                              "categorical facet named " + Quoted(facet) + ", the name of the geometric facet",
                              "rename the categorical facet");
    }
    std::vector<std::string> concepts;
    for (size_t j = 0; j < cases.size(); ++j) {
      const auto it = cases[j].categorical.find(facet);
      if (it == cases[j].categorical.end()) {
        return Status::NotFound("case " + Quoted(cases[j].case_id) + " has no concept for facet " + Quoted(facet));
      }
      concepts.push_back(it->second);
    }
    auto counts = ConceptCounts::Count(taxonomy, concepts, options.zero_count_policy);
    if (!counts.ok()) return counts.status().WithContext("facet " + Quoted(facet));
    index.categorical_.emplace(facet, std::move(counts).value());
    index.facets_.push_back(facet);
  }
  const bool geometric = !cases.front().geometric_chain.empty();
  if (geometric) {
    std::vector<std::vector<std::string>> chains;
    index.x_size_ = cases.front().geometric_x.size();
    for (const CaseConcepts& c : cases) {
      if (c.geometric_chain.empty() || c.geometric_x.size() != index.x_size_ || index.x_size_ == 0 ||
          !c.geometric_x.allFinite()) {
        return Status::BadInput(Where{.field = "cases." + c.case_id + ".geometry"},
                                "the geometric facet needs a chain and a finite feature vector of length " +
                                    std::to_string(index.x_size_) + " on every case (this one has a chain of " +
                                    std::to_string(c.geometric_chain.size()) + " nodes and a vector of " +
                                    std::to_string(c.geometric_x.size()) + ")",
                                "give every case its GHSOM chain and standardised vector, or none");
      }
      chains.push_back(c.geometric_chain);
    }
    auto tree = Taxonomy::FromChains(chains);
    if (!tree.ok()) return tree.status().WithContext("facet " + Quoted(kGeometricFacet));
    std::vector<std::string> leaves;
    for (const CaseConcepts& c : cases) leaves.push_back(c.geometric_chain.back());
    FL_ASSIGN_OR_RETURN(ConceptCounts counts, ConceptCounts::Count(*tree, leaves, options.zero_count_policy));
    index.geometric_ = std::move(counts);
    index.facets_.push_back(kGeometricFacet);
  } else {
    for (const CaseConcepts& c : cases) {
      if (!c.geometric_chain.empty()) {
        return Status::BadInput(Where{.field = "cases." + c.case_id + ".geometry"},
                                "this case has a geometric chain but the first case has none",
                                "give every case its GHSOM chain, or none");
      }
    }
  }
  if (index.facets_.empty()) return Status::BadInput(Where{.field = "taxonomies"}, "no facet to compare");
  if (options.facet_weights.empty()) {
    for (const std::string& f : index.facets_) index.weights_[f] = 1.0;
  } else {
    for (const auto& [facet, weight] : options.facet_weights) {
      if (std::find(index.facets_.begin(), index.facets_.end(), facet) == index.facets_.end()) {
        return Status::BadInput(Where{.field = "facet_weights." + facet}, "weight for unknown facet " + Quoted(facet),
                                "weight only the facets of the library");
      }
    }
    for (const std::string& f : index.facets_) {
      const auto it = options.facet_weights.find(f);
      if (it == options.facet_weights.end()) {
        return Status::BadInput(Where{.field = "facet_weights." + f}, "no weight for facet " + Quoted(f),
                                "weight every facet (0 switches one off)");
      }
      index.weights_[f] = it->second;
    }
  }
  return index;
}

Result<const ConceptCounts*> CaseSimilarityIndex::counts(const std::string& facet) const {
  if (facet == kGeometricFacet && geometric_) return &*geometric_;
  const auto it = categorical_.find(facet);
  if (it == categorical_.end()) return Status::NotFound("no facet " + Quoted(facet) + " in the similarity index");
  return &it->second;
}

Result<FacetSimilarity> CaseSimilarityIndex::ScoreGeometric(const CaseConcepts& query, double r_leaf,
                                                            const CaseConcepts& candidate) const {
  const ConceptCounts& counts = *geometric_;
  const Taxonomy& tree = counts.taxonomy();
  const Where where_q{.field = "query.geometry"};
  if (query.geometric_chain.empty() || query.geometric_chain.front() != tree.root_name()) {
    return Status::BadInput(where_q, "the query's chain must start at the GHSOM root " + Quoted(tree.root_name()),
                            "pass the chain of node ids from descending the library's GHSOM");
  }
  if (query.geometric_x.size() != x_size_ || !query.geometric_x.allFinite()) {
    return Status::BadInput(where_q, "the query's feature vector has " + std::to_string(query.geometric_x.size()) +
                                         " entries or a non-finite one; the library's have " + std::to_string(x_size_));
  }
  // The deepest node of the query chain that is in the tree; the nodes after it are new.
  int last_known = Taxonomy::kRoot;
  bool left_tree = false;
  for (size_t k = 1; k < query.geometric_chain.size(); ++k) {
    const auto id = tree.Find(query.geometric_chain[k]);
    if (id && (left_tree || *id == Taxonomy::kRoot || tree.parent(*id) != last_known)) {
      return Status::BadInput(where_q,
                              "node " + Quoted(query.geometric_chain[k]) + " of the query's chain follows " +
                                  Quoted(query.geometric_chain[k - 1]) + ", not its parent in the library",
                              "pass the chain from the same GHSOM the library's chains come from");
    }
    if (id) {
      last_known = *id;
    } else {
      left_tree = true;
    }
  }
  const Where where_c{.field = "cases." + candidate.case_id + ".geometry"};
  if (candidate.geometric_chain.empty()) return Status::BadInput(where_c, "the case has no geometric chain");
  const auto case_leaf = tree.Find(candidate.geometric_chain.back());
  if (!case_leaf || candidate.geometric_x.size() != x_size_ || !candidate.geometric_x.allFinite()) {
    return Status::BadInput(where_c, "the case's leaf unit " + Quoted(candidate.geometric_chain.back()) +
                                         " is not in the library's GHSOM tree, or its feature vector has " +
                                         std::to_string(candidate.geometric_x.size()) +
                                         " entries (library: " + std::to_string(x_size_) + ") or a non-finite one");
  }
  FacetSimilarity f;
  f.facet = kGeometricFacet;
  f.query_concept = query.geometric_chain.back();
  f.case_concept = tree.name(*case_leaf);
  const int common = tree.Lca(last_known, *case_leaf);
  f.common_node = tree.name(common);
  if (left_tree) {
    FL_ASSIGN_OR_RETURN(f.ic_query, InformationContent(0, counts.cases(), counts.policy(), f.query_concept));
  } else {
    FL_ASSIGN_OR_RETURN(f.ic_query, counts.Ic(last_known));
  }
  FL_ASSIGN_OR_RETURN(f.ic_case, counts.Ic(*case_leaf));
  FL_ASSIGN_OR_RETURN(f.ic_common, counts.Ic(common));
  f.lin = LinFromIc(f.ic_common, f.ic_query, f.ic_case);
  f.similarity = f.lin;
  if (!left_tree && last_known == *case_leaf) {
    f.refined = true;
    FL_ASSIGN_OR_RETURN(f.s_leaf, LeafFloorSimilarity(counts, *case_leaf));
    f.distance = (query.geometric_x - candidate.geometric_x).norm();
    f.r_leaf = r_leaf;
    FL_ASSIGN_OR_RETURN(f.similarity, RefineWithinLeaf(f.s_leaf, f.distance, r_leaf));
  }
  return f;
}

Result<CaseSimilarity> CaseSimilarityIndex::Score(const CaseConcepts& query, double r_leaf,
                                                  const CaseConcepts& candidate) const {
  CaseSimilarity result;
  result.case_id = candidate.case_id;
  double sum_w = 0, sum = 0;
  for (const auto& [facet, counts] : categorical_) {
    const auto q = query.categorical.find(facet);
    if (q == query.categorical.end()) {
      return Status::BadInput(Where{.field = "query." + facet}, "the query has no concept for facet " + Quoted(facet));
    }
    const auto c = candidate.categorical.find(facet);
    if (c == candidate.categorical.end()) {
      return Status::BadInput(Where{.field = "cases." + candidate.case_id + "." + facet},
                              "the case has no concept for facet " + Quoted(facet));
    }
    auto pair = CompareConcepts(counts, q->second, c->second);
    if (!pair.ok()) return pair.status().WithContext("facet " + Quoted(facet));
    FacetSimilarity f;
    f.facet = facet;
    f.query_concept = pair->a;
    f.case_concept = pair->b;
    f.common_node = pair->common;
    f.ic_query = pair->ic_a;
    f.ic_case = pair->ic_b;
    f.ic_common = pair->ic_common;
    f.lin = pair->lin;
    f.similarity = pair->lin;
    f.weight = weights_.at(facet);
    result.facets.push_back(f);
  }
  if (geometric_) {
    FL_ASSIGN_OR_RETURN(FacetSimilarity f, ScoreGeometric(query, r_leaf, candidate));
    f.weight = weights_.at(kGeometricFacet);
    result.facets.push_back(f);
  }
  for (const FacetSimilarity& f : result.facets) {
    sum_w += f.weight;
    sum += f.weight * f.similarity;
  }
  if (!(sum_w > 0)) return Status::Internal("facet weights sum to zero after validation");
  result.overall = std::clamp(sum / sum_w, 0.0, 1.0);
  return result;
}

Result<std::vector<CaseSimilarity>> CaseSimilarityIndex::Rank(const CaseConcepts& query, double r_leaf,
                                                              const std::vector<CaseConcepts>& candidates) const {
  std::vector<CaseSimilarity> ranked;
  ranked.reserve(candidates.size());
  for (const CaseConcepts& c : candidates) {
    FL_ASSIGN_OR_RETURN(CaseSimilarity s, Score(query, r_leaf, c));
    ranked.push_back(std::move(s));
  }
  std::stable_sort(ranked.begin(), ranked.end(), [](const CaseSimilarity& a, const CaseSimilarity& b) {
    if (a.overall != b.overall) return a.overall > b.overall;
    return a.case_id < b.case_id;
  });
  return ranked;
}

}  // namespace formloop::retrieval
