#include "retrieval/ic_similarity.h"

#include <gtest/gtest.h>

#include <cmath>
#include <limits>
#include <string>
#include <vector>

namespace formloop::retrieval {
namespace {

// The toy taxonomy and library of the reference values.
//
//   entity ─┬─ metal ─┬─ steel ─┬─ H13        case concepts (N = 10):
//           │         │         └─ P20          H13 ×3, P20 ×2, steel ×1 (an inner concept),
//           │         └─ aluminium ─┬─ 6061     6061 ×1, 7075 ×1, PEEK ×2, POM ×0
//           │                       └─ 7075
//           └─ polymer ─┬─ PEEK
//                       └─ POM
//
// Counts propagated to every ancestor, as NLTK does when it builds an IC dictionary
// (nltk.corpus.reader.wordnet: ic[pos][synset.offset] += count for the synset and each hypernym,
// ic[pos][0] = total): entity 10, metal 8, steel 6, H13 3, P20 2, aluminium 2, 6061 1, 7075 1,
// polymer 2, PEEK 2, POM 0. NLTK's information_content = −log(count / ic[pos][0]); its
// res_similarity(a, b, ic) = IC(lcs) and lin_similarity(a, b, ic) = 2·IC(lcs) / (IC(a) + IC(b)), with
// lcs the common hypernym of largest IC — in a tree the lowest common node. With these counts NLTK
// gives (natural logs):
//   res(H13, P20)  = log(10/6)                               = 0.5108256237659907
//   lin(H13, P20)  = 2 log(10/6) / (log(10/3) + log(10/2))   = 0.36313618962414757
//   res(H13, 6061) = log(10/8)                               = 0.22314355131420976
//   lin(H13, 6061) = 2 log(10/8) / (log(10/3) + log(10))     = 0.12727213287124423
//   res(H13, PEEK) = lin(H13, PEEK) = 0 (only the root in common, IC(entity) = 0)
//   lin(steel, H13) = 2 log(10/6) / (log(10/6) + log(10/3))  = 0.5957850385183656
// POM has count 0: NLTK returns IC = 1e300 there (so lin → 0); formloop's default half-count policy
// gives IC(POM) = log(20) and lin(POM, PEEK) = 2 log 5 / (log 20 + log 5) = log 5 / log 10
// = 0.6989700043360189 (a documented departure, only for zero counts).
// The expected values below are written from the formulas with the literal counts, not computed by
// the code under test.
Taxonomy Toy() {
  Taxonomy t("entity");
  EXPECT_TRUE(t.AddNode("metal", "entity").ok());
  EXPECT_TRUE(t.AddNode("steel", "metal").ok());
  EXPECT_TRUE(t.AddNode("H13", "steel", {"1.2344"}).ok());
  EXPECT_TRUE(t.AddNode("P20", "steel").ok());
  EXPECT_TRUE(t.AddNode("aluminium", "metal").ok());
  EXPECT_TRUE(t.AddNode("6061", "aluminium").ok());
  EXPECT_TRUE(t.AddNode("7075", "aluminium").ok());
  EXPECT_TRUE(t.AddNode("polymer", "entity").ok());
  EXPECT_TRUE(t.AddNode("PEEK", "polymer").ok());
  EXPECT_TRUE(t.AddNode("POM", "polymer").ok());
  return t;
}

const std::vector<std::string> kToyCases = {"H13",   "H13",  "1.2344", "P20",  "P20",
                                            "steel", "6061", "7075",   "PEEK", "PEEK"};

ConceptCounts ToyCounts(ZeroCountPolicy policy = ZeroCountPolicy::kHalfCount) {
  auto c = ConceptCounts::Count(Toy(), kToyCases, policy);
  EXPECT_TRUE(c.ok()) << c.status().ToString();
  return *c;
}

constexpr double kExact = 1e-12;

TEST(IcSimilarity, ResnikAndLinEqualNltkOnTheToyTaxonomy) {
  const ConceptCounts c = ToyCounts();
  EXPECT_NEAR(*ResnikSimilarity(c, "H13", "P20"), std::log(10.0 / 6.0), kExact);
  EXPECT_NEAR(*ResnikSimilarity(c, "H13", "P20"), 0.5108256237659907, kExact);
  EXPECT_NEAR(*LinSimilarity(c, "H13", "P20"), 2 * std::log(10.0 / 6.0) / (std::log(10.0 / 3.0) + std::log(10.0 / 2.0)),
              kExact);
  EXPECT_NEAR(*LinSimilarity(c, "H13", "P20"), 0.36313618962414757, kExact);
  EXPECT_NEAR(*ResnikSimilarity(c, "H13", "6061"), std::log(10.0 / 8.0), kExact);
  EXPECT_NEAR(*ResnikSimilarity(c, "H13", "6061"), 0.22314355131420976, kExact);
  EXPECT_NEAR(*LinSimilarity(c, "H13", "6061"), 2 * std::log(10.0 / 8.0) / (std::log(10.0 / 3.0) + std::log(10.0)),
              kExact);
  EXPECT_NEAR(*LinSimilarity(c, "H13", "6061"), 0.12727213287124423, kExact);
  EXPECT_NEAR(*LinSimilarity(c, "steel", "H13"), 0.5957850385183656, kExact);
  EXPECT_NEAR(*LinSimilarity(c, "POM", "PEEK"), 0.6989700043360189, kExact);

  const auto s = CompareConcepts(c, "1.2344", "P20");  // alias resolved
  ASSERT_TRUE(s.ok());
  EXPECT_EQ(s->a, "H13");
  EXPECT_EQ(s->common, "steel");
  EXPECT_NEAR(s->ic_a, std::log(10.0 / 3.0), kExact);
  EXPECT_NEAR(s->ic_b, std::log(5.0), kExact);
  EXPECT_EQ(s->ToJson().at("common"), "steel");
}

TEST(IcSimilarity, RootOnlyLcaIdentitySymmetryRange) {
  const ConceptCounts c = ToyCounts();
  EXPECT_EQ(*ResnikSimilarity(c, "H13", "PEEK"), 0.0);
  EXPECT_EQ(*LinSimilarity(c, "H13", "PEEK"), 0.0);
  EXPECT_EQ(CompareConcepts(c, "H13", "PEEK")->common, "entity");
  // Identity → 1, including both-IC-zero (the root) by the spec's definition.
  EXPECT_EQ(*LinSimilarity(c, "entity", "entity"), 1.0);
  const std::vector<std::string> all = {"entity", "metal", "steel",   "H13",  "P20", "aluminium",
                                        "6061",   "7075",  "polymer", "PEEK", "POM"};
  for (const std::string& a : all) {
    EXPECT_NEAR(*LinSimilarity(c, a, a), 1.0, kExact) << a;
    for (const std::string& b : all) {
      const double lin = *LinSimilarity(c, a, b), res = *ResnikSimilarity(c, a, b);
      EXPECT_EQ(lin, *LinSimilarity(c, b, a)) << a << " " << b;
      EXPECT_EQ(res, *ResnikSimilarity(c, b, a)) << a << " " << b;
      EXPECT_GE(lin, 0.0);
      EXPECT_LE(lin, 1.0);
      EXPECT_GE(res, 0.0);
    }
  }
}

TEST(IcSimilarity, UnknownConceptAndRefusedZeroCount) {
  const ConceptCounts c = ToyCounts();
  auto unknown = LinSimilarity(c, "H13", "unobtainium");
  ASSERT_FALSE(unknown.ok());
  EXPECT_EQ(unknown.status().code(), StatusCode::kNotFound);
  EXPECT_NE(unknown.status().message().find("'unobtainium'"), std::string::npos);
  const ConceptCounts refuse = ToyCounts(ZeroCountPolicy::kRefuse);
  EXPECT_TRUE(LinSimilarity(refuse, "H13", "P20").ok());
  auto zero = LinSimilarity(refuse, "POM", "PEEK");
  ASSERT_FALSE(zero.ok());
  EXPECT_NE(zero.status().message().find("'POM'"), std::string::npos);
}

TEST(IcSimilarity, RefineWithinLeaf) {
  EXPECT_EQ(*RefineWithinLeaf(0.4, 0.0, 2.0), 1.0);
  EXPECT_NEAR(*RefineWithinLeaf(0.4, 1.0, 2.0), 1 - 0.6 * 0.5, kExact);
  EXPECT_NEAR(*RefineWithinLeaf(0.4, 5.0, 2.0), 0.4, kExact);  // beyond the radius: the floor
  EXPECT_NEAR(*RefineWithinLeaf(0.0, 0.1, 2.0), 0.95, 1e-15);  // d = 0.05 r: 0.95 even when s_leaf = 0
  EXPECT_GT(*RefineWithinLeaf(0.0, 0.099, 2.0), 0.95);
  EXPECT_EQ(*RefineWithinLeaf(0.4, 0.0, 0.0), 1.0);  // r = 0: a step
  EXPECT_EQ(*RefineWithinLeaf(0.4, 1e-9, 0.0), 0.4);
  EXPECT_FALSE(RefineWithinLeaf(1.5, 0, 1).ok());
  EXPECT_FALSE(RefineWithinLeaf(0.5, -1, 1).ok());
  auto bad_r = RefineWithinLeaf(0.5, 1, std::numeric_limits<double>::quiet_NaN());
  ASSERT_FALSE(bad_r.ok());
  EXPECT_NE(bad_r.status().message().find("r_leaf"), std::string::npos);
}

// A library of 4 cases with a material facet (the toy taxonomy) and the geometric facet. GHSOM
// chains: c1, c2 in unit u1 of map m1; c3 in u2 of m1; c4 in u3 of the root map. Geometric counts:
// root 4, m1 3, u1 2, u2 1, u3 1.
CaseConcepts Case(const std::string& id, const std::string& material, std::vector<std::string> chain,
                  std::vector<double> x) {
  CaseConcepts c;
  c.case_id = id;
  c.categorical["material"] = material;
  c.geometric_chain = std::move(chain);
  c.geometric_x = Eigen::Map<Eigen::VectorXd>(x.data(), static_cast<long>(x.size()));
  return c;
}

std::vector<CaseConcepts> Library() {
  return {Case("c1", "H13", {"root", "m1", "u1"}, {0, 0}), Case("c2", "P20", {"root", "m1", "u1"}, {1, 0}),
          Case("c3", "6061", {"root", "m1", "u2"}, {3, 3}), Case("c4", "PEEK", {"root", "u3"}, {-5, 2})};
}

CaseSimilarityIndex Index(const SimilarityOptions& options = {}) {
  auto index = CaseSimilarityIndex::Build({{"material", Toy()}}, Library(), options);
  EXPECT_TRUE(index.ok()) << index.status().ToString();
  return *index;
}

TEST(IcSimilarity, OverallIsTheWeightedMeanOfFacets) {
  SimilarityOptions options;
  options.facet_weights = {{"material", 1.0}, {kGeometricFacet, 3.0}};
  const CaseSimilarityIndex index = Index(options);
  ASSERT_EQ(index.facets(), (std::vector<std::string>{"material", kGeometricFacet}));
  // Query: P20, in unit u2 (as c3), at distance 0.5 from c3 with r_leaf = 2.
  const CaseConcepts query = Case("q", "P20", {"root", "m1", "u2"}, {3, 3.5});
  auto s = index.Score(query, 2.0, Library()[2]);
  ASSERT_TRUE(s.ok()) << s.status().ToString();
  // Material: N = 4 cases H13, P20, 6061, PEEK: lin(P20, 6061) = 2 log(4/3) / (log 4 + log 4).
  const double material = 2 * std::log(4.0 / 3.0) / (2 * std::log(4.0));
  // Geometry, same leaf u2: s_leaf = IC(m1)/IC(u2) = log(4/3)/log(4); Sim = 1 − (1 − s_leaf)·0.5/2.
  const double s_leaf = std::log(4.0 / 3.0) / std::log(4.0);
  const double geometry = 1 - (1 - s_leaf) * 0.25;
  ASSERT_EQ(s->facets.size(), 2u);
  EXPECT_NEAR(s->facets[0].similarity, material, kExact);
  EXPECT_EQ(s->facets[0].common_node, "metal");
  EXPECT_TRUE(s->facets[1].refined);
  EXPECT_NEAR(s->facets[1].s_leaf, s_leaf, kExact);
  EXPECT_NEAR(s->facets[1].similarity, geometry, kExact);
  EXPECT_EQ(s->facets[1].common_node, "u2");
  EXPECT_NEAR(s->overall, (1 * material + 3 * geometry) / 4, kExact);

  // Scaling every weight leaves A unchanged.
  options.facet_weights = {{"material", 7.0}, {kGeometricFacet, 21.0}};
  EXPECT_NEAR(Index(options).Score(query, 2.0, Library()[2])->overall, s->overall, kExact);
  // A zero weight switches a facet off.
  options.facet_weights = {{"material", 0.0}, {kGeometricFacet, 1.0}};
  EXPECT_NEAR(Index(options).Score(query, 2.0, Library()[2])->overall, geometry, kExact);

  const nlohmann::json j = s->ToJson();
  EXPECT_EQ(j.at("case_id"), "c3");
  EXPECT_EQ(j.at("facets").at(1).at("common_node"), "u2");
  EXPECT_NEAR(j.at("facets").at(1).at("refinement").at("r_leaf").get<double>(), 2.0, 0);
}

TEST(IcSimilarity, GeometricFacetAcrossUnitsAndNewLeaves) {
  const CaseSimilarityIndex index = Index();
  // Query in u1 vs c3 (u2): Lin via m1: 2 log(4/3) / (log 2 + log 4); no refinement.
  const CaseConcepts query = Case("q", "H13", {"root", "m1", "u1"}, {0, 0});
  auto s = index.Score(query, 1.0, Library()[2]);
  ASSERT_TRUE(s.ok()) << s.status().ToString();
  EXPECT_FALSE(s->facets[1].refined);
  EXPECT_EQ(s->facets[1].common_node, "m1");
  EXPECT_NEAR(s->facets[1].similarity, 2 * std::log(4.0 / 3.0) / (std::log(2.0) + std::log(4.0)), kExact);
  // vs c4 (u3 under the root): only the root in common → 0.
  EXPECT_EQ(index.Score(query, 1.0, Library()[3])->facets[1].similarity, 0.0);
  // A query ending in a unit no case lies under: IC = log(2N) = log 8 (half-count policy).
  const CaseConcepts fresh = Case("q", "H13", {"root", "m1", "u9"}, {0, 0});
  auto f = index.Score(fresh, 1.0, Library()[0]);
  ASSERT_TRUE(f.ok()) << f.status().ToString();
  EXPECT_NEAR(f->facets[1].ic_query, std::log(8.0), kExact);
  EXPECT_EQ(f->facets[1].common_node, "m1");
  EXPECT_NEAR(f->facets[1].similarity, 2 * std::log(4.0 / 3.0) / (std::log(8.0) + std::log(2.0)), kExact);
  // A chain that contradicts the library's tree.
  auto wrong = index.Score(Case("q", "H13", {"root", "u3", "u1"}, {0, 0}), 1.0, Library()[0]);
  ASSERT_FALSE(wrong.ok());
  EXPECT_NE(wrong.status().message().find("query.geometry"), std::string::npos) << wrong.status().message();
  auto short_x = index.Score(Case("q", "H13", {"root", "m1", "u1"}, {0}), 1.0, Library()[0]);
  EXPECT_EQ(short_x.status().code(), StatusCode::kBadInput);
}

TEST(IcSimilarity, IdenticalPartsScoreOneAndNearIdenticalAbove095) {
  const CaseSimilarityIndex index = Index();
  for (const CaseConcepts& c : Library()) {
    auto s = index.Score(c, 1.0, c);
    ASSERT_TRUE(s.ok());
    EXPECT_EQ(s->overall, 1.0) << c.case_id;
  }
  CaseConcepts near = Library()[0];
  near.case_id = "near";
  near.geometric_x[0] += 0.04;  // 4 % of r_leaf = 1
  EXPECT_GT(index.Score(near, 1.0, Library()[0])->overall, 0.95);
  EXPECT_LT(index.Score(near, 1.0, Library()[0])->overall, 1.0);
}

TEST(IcSimilarity, SymmetricAndInRangeOverTheLibrary) {
  const CaseSimilarityIndex index = Index();
  for (const CaseConcepts& a : Library()) {
    for (const CaseConcepts& b : Library()) {
      const double ab = index.Score(a, 1.5, b)->overall, ba = index.Score(b, 1.5, a)->overall;
      EXPECT_NEAR(ab, ba, kExact) << a.case_id << " " << b.case_id;
      EXPECT_GE(ab, 0.0);
      EXPECT_LE(ab, 1.0);
    }
  }
}

TEST(IcSimilarity, RankSortsByScoreThenCaseId) {
  const CaseSimilarityIndex index = Index();
  std::vector<CaseConcepts> candidates = Library();
  CaseConcepts twin = candidates[0];
  twin.case_id = "a0";  // same concepts and vector as c1: ties with it, and sorts first by id
  candidates.insert(candidates.begin() + 2, twin);
  const CaseConcepts query = Case("q", "H13", {"root", "m1", "u1"}, {0.1, 0});
  auto ranked = index.Rank(query, 1.0, candidates);
  ASSERT_TRUE(ranked.ok()) << ranked.status().ToString();
  ASSERT_EQ(ranked->size(), 5u);
  std::vector<std::string> order;
  for (const CaseSimilarity& s : *ranked) order.push_back(s.case_id);
  EXPECT_EQ(order, (std::vector<std::string>{"a0", "c1", "c2", "c3", "c4"}));
  EXPECT_EQ((*ranked)[0].overall, (*ranked)[1].overall);
  for (size_t i = 1; i < ranked->size(); ++i) EXPECT_GE((*ranked)[i - 1].overall, (*ranked)[i].overall);
}

TEST(IcSimilarity, BadWeightsAndConceptsAreClearErrors) {
  SimilarityOptions negative;
  negative.facet_weights = {{"material", -1.0}, {kGeometricFacet, 1.0}};
  auto n = CaseSimilarityIndex::Build({{"material", Toy()}}, Library(), negative);
  ASSERT_FALSE(n.ok());
  EXPECT_EQ(n.status().code(), StatusCode::kBadInput);
  EXPECT_NE(n.status().message().find("facet_weights.material"), std::string::npos) << n.status().message();

  SimilarityOptions zero;
  zero.facet_weights = {{"material", 0.0}, {kGeometricFacet, 0.0}};
  auto z = CaseSimilarityIndex::Build({{"material", Toy()}}, Library(), zero);
  ASSERT_FALSE(z.ok());
  EXPECT_NE(z.status().message().find("all facet weights are zero"), std::string::npos);

  SimilarityOptions typo;
  typo.facet_weights = {{"materail", 1.0}, {"material", 1.0}, {kGeometricFacet, 1.0}};
  EXPECT_NE(CaseSimilarityIndex::Build({{"material", Toy()}}, Library(), typo).status().message().find("materail"),
            std::string::npos);
  SimilarityOptions missing;
  missing.facet_weights = {{"material", 1.0}};
  EXPECT_NE(CaseSimilarityIndex::Build({{"material", Toy()}}, Library(), missing)
                .status()
                .message()
                .find("facet_weights.geometry"),
            std::string::npos);

  std::vector<CaseConcepts> bad_library = Library();
  bad_library[1].categorical["material"] = "unobtainium";
  auto b = CaseSimilarityIndex::Build({{"material", Toy()}}, bad_library, {});
  ASSERT_FALSE(b.ok());
  EXPECT_NE(b.status().message().find("unobtainium"), std::string::npos);
  EXPECT_NE(b.status().message().find("material"), std::string::npos);

  const CaseSimilarityIndex index = Index();
  auto q = index.Score(Case("q", "unobtainium", {"root", "m1", "u1"}, {0, 0}), 1.0, Library()[0]);
  ASSERT_FALSE(q.ok());
  EXPECT_EQ(q.status().code(), StatusCode::kNotFound);
  EXPECT_NE(q.status().message().find("'unobtainium'"), std::string::npos);
  CaseConcepts no_material = Library()[0];
  no_material.categorical.clear();
  EXPECT_NE(index.Score(no_material, 1.0, Library()[0]).status().message().find("query.material"), std::string::npos);
  // Same leaf but an invalid leaf radius.
  EXPECT_FALSE(index.Score(Library()[0], -1.0, Library()[1]).ok());
  EXPECT_EQ(CaseSimilarityIndex::Build({{"material", Toy()}}, {}, {}).status().code(), StatusCode::kBadInput);
}

}  // namespace
}  // namespace formloop::retrieval
