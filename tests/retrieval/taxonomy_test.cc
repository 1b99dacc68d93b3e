#include "retrieval/taxonomy.h"

#include <gtest/gtest.h>

#include <cmath>
#include <filesystem>
#include <limits>
#include <string>
#include <vector>

#include "reconstruction/analytic_surface.h"

namespace formloop::retrieval {
namespace {

const std::filesystem::path kTaxonomyDir = std::filesystem::path(FORMLOOP_SOURCE_DIR) / "data" / "taxonomies";

constexpr char kToy[] = R"(# toy material taxonomy
material
  metal
    steel   # an inline comment
      H13 | aka=1.2344, X40CrMoV5-1
      P20
    aluminium
      6061
      7075
  polymer | note=not a metal
    PEEK
)";

Taxonomy Toy() {
  auto t = Taxonomy::Parse(kToy, "toy.txt");
  EXPECT_TRUE(t.ok()) << t.status().ToString();
  return *t;
}

int Id(const Taxonomy& t, const std::string& name) {
  const auto id = t.Find(name);
  EXPECT_TRUE(id.has_value()) << name;
  return id.value_or(-1);
}

TEST(Taxonomy, ParsesTreeAliasesAndAttributes) {
  const Taxonomy t = Toy();
  ASSERT_EQ(t.size(), 10);
  EXPECT_EQ(t.root_name(), "material");
  EXPECT_EQ(t.name(t.parent(Id(t, "H13"))), "steel");
  EXPECT_EQ(t.depth(Id(t, "H13")), 3);
  EXPECT_EQ(t.depth(Taxonomy::kRoot), 0);
  EXPECT_EQ(Id(t, "1.2344"), Id(t, "H13"));
  EXPECT_EQ(Id(t, "X40CrMoV5-1"), Id(t, "H13"));
  EXPECT_EQ(t.aliases(Id(t, "H13")), (std::vector<std::string>{"1.2344", "X40CrMoV5-1"}));
  EXPECT_EQ(t.attributes(Id(t, "polymer")).at("note"), "not a metal");
  EXPECT_FALSE(t.Find("h13").has_value());  // names are case-sensitive
  EXPECT_EQ(t.children(Id(t, "metal")).size(), 2u);
}

TEST(Taxonomy, AncestorsLcaLeaves) {
  const Taxonomy t = Toy();
  const int h13 = Id(t, "H13"), p20 = Id(t, "P20"), a6061 = Id(t, "6061"), peek = Id(t, "PEEK");
  const std::vector<int> chain = t.Ancestors(h13);
  ASSERT_EQ(chain.size(), 4u);
  EXPECT_EQ(t.name(chain[0]), "H13");
  EXPECT_EQ(t.name(chain[1]), "steel");
  EXPECT_EQ(t.name(chain[2]), "metal");
  EXPECT_EQ(chain[3], Taxonomy::kRoot);
  EXPECT_EQ(t.name(t.Lca(h13, p20)), "steel");
  EXPECT_EQ(t.name(t.Lca(h13, a6061)), "metal");
  EXPECT_EQ(t.Lca(h13, peek), Taxonomy::kRoot);
  EXPECT_EQ(t.Lca(h13, h13), h13);
  EXPECT_EQ(t.Lca(Id(t, "steel"), h13), Id(t, "steel"));  // ancestor-or-self
  EXPECT_EQ(t.Lca(p20, h13), t.Lca(h13, p20));
  EXPECT_TRUE(t.IsLeaf(h13));
  EXPECT_FALSE(t.IsLeaf(Id(t, "metal")));
  EXPECT_TRUE(t.IsUnder(h13, Id(t, "metal")));
  EXPECT_FALSE(t.IsUnder(peek, Id(t, "metal")));
  std::vector<std::string> leaves;
  for (int id : t.LeavesUnder(Id(t, "metal"))) leaves.push_back(t.name(id));
  EXPECT_EQ(leaves, (std::vector<std::string>{"H13", "P20", "6061", "7075"}));
  EXPECT_EQ(t.LeavesUnder(peek), std::vector<int>{peek});
  EXPECT_EQ(t.LeavesUnder(Taxonomy::kRoot).size(), 5u);
}

TEST(Taxonomy, TextRoundTrip) {
  const Taxonomy t = Toy();
  auto again = Taxonomy::Parse(t.ToText(), "round-trip");
  ASSERT_TRUE(again.ok()) << again.status().ToString();
  EXPECT_EQ(again->ToText(), t.ToText());
  EXPECT_EQ(again->size(), t.size());
  EXPECT_EQ(Id(*again, "1.2344"), Id(*again, "H13"));
}

void ExpectParseError(const std::string& text, const std::string& needle) {
  auto t = Taxonomy::Parse(text, "bad.txt");
  ASSERT_FALSE(t.ok()) << "parsed: " << text;
  EXPECT_EQ(t.status().code(), StatusCode::kBadInput);
  EXPECT_NE(t.status().message().find(needle), std::string::npos) << t.status().message();
}

TEST(Taxonomy, ParseErrorsNameFileAndLine) {
  ExpectParseError("root\n  a\n   b\n", "bad.txt:3:");  // odd indent
  ExpectParseError("root\n  a\n   b\n", "not a multiple of two");
  ExpectParseError("root\n  a\n      b\n", "bad.txt:3:");     // jumps two levels
  ExpectParseError("root\n\ta\n", "bad.txt:2:");              // tab
  ExpectParseError("root\n  a\n  b\n    a\n", "bad.txt:4:");  // duplicate name
  ExpectParseError("root\n  a\n  b\n    a\n", "first defined on line 2");
  ExpectParseError("root\n  a | aka=x\n  x\n", "bad.txt:3:");  // alias clash
  ExpectParseError("root\n  a\nother\n", "bad.txt:3:");        // second root
  ExpectParseError("  root\n", "bad.txt:1:");                  // indented root
  ExpectParseError("root\n  a | max_mm\n", "bad.txt:2:");      // attribute without '='
  ExpectParseError("root\n  | aka=x\n", "empty concept name");
  ExpectParseError("# only a comment\n\n   \n", "bad.txt: the taxonomy is empty");
  ExpectParseError("", "empty");
}

TEST(Taxonomy, ProgrammaticConstruction) {
  Taxonomy t("shape");
  ASSERT_TRUE(t.AddNode("free-form", "shape").ok());
  auto dome = t.AddNode("dome", "free-form", {"sphere cap"});
  ASSERT_TRUE(dome.ok());
  EXPECT_EQ(t.Find("sphere cap").value_or(-1), *dome);
  EXPECT_EQ(t.AddNode("dome", "shape").status().code(), StatusCode::kBadInput);
  EXPECT_EQ(t.AddNode("x", "shape", {"dome"}).status().code(), StatusCode::kBadInput);
  EXPECT_EQ(t.AddNode("x", "no such parent").status().code(), StatusCode::kNotFound);
  EXPECT_EQ(t.AddNode("", "shape").status().code(), StatusCode::kBadInput);
  EXPECT_EQ(t.AddNode("a|b", "shape").status().code(), StatusCode::kBadInput);
  EXPECT_EQ(t.size(), 3);
}

TEST(Taxonomy, FromChainsBuildsTheGhsomTree) {
  auto t = Taxonomy::FromChains({{"root", "m1", "u1"}, {"root", "m1", "u2"}, {"root", "u3"}, {"root", "m1", "u1"}});
  ASSERT_TRUE(t.ok()) << t.status().ToString();
  EXPECT_EQ(t->size(), 5);
  EXPECT_EQ(t->name(t->Lca(Id(*t, "u1"), Id(*t, "u2"))), "m1");
  EXPECT_EQ(t->Lca(Id(*t, "u1"), Id(*t, "u3")), Taxonomy::kRoot);

  auto other_parent = Taxonomy::FromChains({{"root", "m1", "u1"}, {"root", "m2", "u1"}});
  ASSERT_FALSE(other_parent.ok());
  EXPECT_NE(other_parent.status().message().find("chains[1]"), std::string::npos) << other_parent.status().message();
  auto other_root = Taxonomy::FromChains({{"root", "u1"}, {"top", "u2"}});
  ASSERT_FALSE(other_root.ok());
  EXPECT_NE(other_root.status().message().find("chains[1]"), std::string::npos);
  EXPECT_FALSE(Taxonomy::FromChains({}).ok());
  EXPECT_FALSE(Taxonomy::FromChains({{"root"}, {}}).ok());
  EXPECT_FALSE(Taxonomy::FromChains({{"root", "a", "root"}}).ok());
}

TEST(TaxonomyCounts, CountsCasesUnderEachNodeAndIc) {
  const Taxonomy t = Toy();
  // 6 cases: H13 ×2 (one by alias), P20, steel (an inner concept), 6061, PEEK.
  auto c = ConceptCounts::Count(t, {"H13", "1.2344", "P20", "steel", "6061", "PEEK"});
  ASSERT_TRUE(c.ok()) << c.status().ToString();
  EXPECT_EQ(c->cases(), 6);
  EXPECT_EQ(c->count(Taxonomy::kRoot), 6);
  EXPECT_EQ(c->count(Id(t, "H13")), 2);
  EXPECT_EQ(c->count(Id(t, "steel")), 4);
  EXPECT_EQ(c->count(Id(t, "metal")), 5);
  EXPECT_EQ(c->count(Id(t, "aluminium")), 1);
  EXPECT_EQ(c->count(Id(t, "7075")), 0);
  EXPECT_EQ(*c->Ic("material"), 0.0);
  EXPECT_NEAR(*c->Ic("H13"), std::log(6.0 / 2.0), 1e-15);
  EXPECT_NEAR(*c->Ic("steel"), std::log(6.0 / 4.0), 1e-15);
  EXPECT_NEAR(*c->Ic("6061"), std::log(6.0), 1e-15);  // one case of N: log N
  // Zero count, default policy: half a case, IC = log(2N) — above every observed leaf.
  EXPECT_NEAR(*c->Ic("7075"), std::log(12.0), 1e-15);
  EXPECT_GT(*c->Ic("7075"), *c->Ic("6061"));
}

TEST(TaxonomyCounts, ZeroCountPolicyRefuseAndBadInput) {
  const Taxonomy t = Toy();
  auto c = ConceptCounts::Count(t, {"H13", "PEEK"}, ZeroCountPolicy::kRefuse);
  ASSERT_TRUE(c.ok());
  EXPECT_TRUE(c->Ic("H13").ok());
  auto undefined = c->Ic("7075");
  ASSERT_FALSE(undefined.ok());
  EXPECT_EQ(undefined.status().code(), StatusCode::kBadInput);
  EXPECT_NE(undefined.status().message().find("'7075'"), std::string::npos);

  EXPECT_EQ(ConceptCounts::Count(t, {}).status().code(), StatusCode::kBadInput);
  auto unknown = ConceptCounts::Count(t, {"H13", "unobtainium"});
  ASSERT_FALSE(unknown.ok());
  EXPECT_EQ(unknown.status().code(), StatusCode::kNotFound);
  EXPECT_NE(unknown.status().message().find("case 1"), std::string::npos);
  EXPECT_NE(unknown.status().message().find("unobtainium"), std::string::npos);
  EXPECT_FALSE(InformationContent(3, 2, ZeroCountPolicy::kHalfCount, "x").ok());
  EXPECT_FALSE(InformationContent(1, 0, ZeroCountPolicy::kHalfCount, "x").ok());
}

TEST(TaxonomyBands, InclusiveUpperBoundsAndErrors) {
  auto t = Taxonomy::Load(kTaxonomyDir / "tolerance.txt");
  ASSERT_TRUE(t.ok()) << t.status().ToString();
  auto leaf = [&](double value) {
    auto id = ClassifyByBand(*t, t->root_name(), "max_mm", value, "form_tolerance_mm");
    EXPECT_TRUE(id.ok()) << id.status().ToString();
    return id.ok() ? t->name(*id) : std::string("?");
  };
  EXPECT_EQ(leaf(0.001), "ultra");
  EXPECT_EQ(leaf(0.005), "ultra");  // bounds are inclusive
  EXPECT_EQ(leaf(0.0051), "fine");
  EXPECT_EQ(leaf(0.02), "fine");
  EXPECT_EQ(leaf(0.05), "medium");
  EXPECT_EQ(leaf(0.3), "coarse");
  auto nan =
      ClassifyByBand(*t, t->root_name(), "max_mm", std::numeric_limits<double>::quiet_NaN(), "form_tolerance_mm");
  ASSERT_FALSE(nan.ok());
  EXPECT_NE(nan.status().message().find("form_tolerance_mm"), std::string::npos);
  EXPECT_FALSE(ClassifyByBand(*t, t->root_name(), "max_mm", -0.01, "form_tolerance_mm").ok());
  EXPECT_EQ(ClassifyByBand(*t, t->root_name(), "max_um", 0.01, "x").status().code(), StatusCode::kNotFound);

  auto closed = Taxonomy::Parse("t\n  a | max_mm=1\n  b | max_mm=2\n", "closed");
  ASSERT_TRUE(closed.ok());
  EXPECT_EQ(closed->name(*ClassifyByBand(*closed, "t", "max_mm", 1.5, "v")), "b");
  auto above = ClassifyByBand(*closed, "t", "max_mm", 2.5, "v");
  ASSERT_FALSE(above.ok());
  EXPECT_NE(above.status().message().find("above the largest band bound 2"), std::string::npos);
  auto broken = Taxonomy::Parse("t\n  a | max_mm=one\n", "broken");
  ASSERT_TRUE(broken.ok());
  EXPECT_EQ(ClassifyByBand(*broken, "t", "max_mm", 0.5, "v").status().code(), StatusCode::kBadInput);
}

TEST(TaxonomyShipped, LoadAndCoverTheSpec) {
  for (const char* file : {"material.txt", "tolerance.txt", "finish.txt", "machine_tool.txt", "shape.txt"}) {
    auto t = Taxonomy::Load(kTaxonomyDir / file);
    ASSERT_TRUE(t.ok()) << file << ": " << t.status().ToString();
    EXPECT_GE(t->LeavesUnder(Taxonomy::kRoot).size(), 4u) << file;
  }
  auto material = Taxonomy::Load(kTaxonomyDir / "material.txt");
  ASSERT_TRUE(material.ok());
  const int h13 = Id(*material, "H13");
  std::vector<std::string> path;
  for (int id : material->Ancestors(h13)) path.push_back(material->name(id));
  EXPECT_EQ(path, (std::vector<std::string>{"H13", "hot-work tool steel", "tool steel", "steel", "metal", "material"}));
  EXPECT_EQ(Id(*material, "1.2344"), h13);
  EXPECT_EQ(material->name(Id(*material, "1.2343")), "H11");
  for (const char* name : {"P20", "6061", "7075", "Ti-6Al-4V", "Inconel 718", "PEEK", "316L"}) {
    const int id = Id(*material, name);
    EXPECT_TRUE(material->IsLeaf(id)) << name;
  }
  EXPECT_EQ(material->name(material->parent(Id(*material, "Ti-6Al-4V"))), "titanium");

  // Every analytic reference surface has a shape-family leaf of the same name, plus the other
  // families the spec names.
  auto shape = Taxonomy::Load(kTaxonomyDir / "shape.txt");
  ASSERT_TRUE(shape.ok());
  for (const std::string& name : recon::ReferenceSurfaceNames()) {
    const auto id = shape->Find(name);
    ASSERT_TRUE(id.has_value()) << name;
    EXPECT_TRUE(shape->IsLeaf(*id)) << name;
  }
  for (const char* name : {"dome", "bowl", "turbine-like freeform", "egg box"})
    EXPECT_TRUE(shape->Find(name).has_value()) << name;
  EXPECT_NE(shape->Lca(Id(*shape, "sphere_cap"), Id(*shape, "saddle")), Taxonomy::kRoot);
  EXPECT_EQ(shape->Lca(Id(*shape, "plane"), Id(*shape, "saddle")), Taxonomy::kRoot);

  auto load_missing = Taxonomy::Load(kTaxonomyDir / "no_such_file.txt");
  EXPECT_EQ(load_missing.status().code(), StatusCode::kNotFound);
}

}  // namespace
}  // namespace formloop::retrieval
