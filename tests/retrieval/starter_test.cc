// The starter-library generator (retrieval/starter.h): deterministic, ≥ 200 cases from ≥ 8 families, valid case
// records, every surface kind builds, bad sources are refused.

#include <set>

#include <gtest/gtest.h>

#include "retrieval/starter.h"

namespace formloop::retrieval {
namespace {

const std::filesystem::path kData = std::filesystem::path(FORMLOOP_SOURCE_DIR) / "data";

TEST(Starter, DrawIsDeterministicAndLargeEnough) {
  auto spec = StarterSpec::Load(kData / "starter" / "families.json");
  ASSERT_TRUE(spec.ok()) << spec.status().ToString();
  const auto a = DrawStarterParts(*spec), b = DrawStarterParts(*spec);
  ASSERT_EQ(a.size(), b.size());
  EXPECT_GE(a.size(), 200u);
  std::set<std::string> families, uids, shapes;
  for (size_t i = 0; i < a.size(); ++i) {
    EXPECT_EQ(a[i].uid, b[i].uid);
    EXPECT_EQ(a[i].params, b[i].params);
    EXPECT_EQ(a[i].simulation.dump(), b[i].simulation.dump());
    EXPECT_EQ(a[i].manufacturing.dump(), b[i].manufacturing.dump());
    families.insert(a[i].family);
    uids.insert(a[i].uid);
    shapes.insert(a[i].description.shape_family);
  }
  EXPECT_GE(families.size(), 8u);
  EXPECT_GE(shapes.size(), 8u);
  EXPECT_EQ(uids.size(), a.size());
}

TEST(Starter, CasesAreValidRecordsWithDescriptorsAndConcepts) {
  auto spec = StarterSpec::Load(kData / "starter" / "families.json");
  ASSERT_TRUE(spec.ok());
  auto tax = FacetTaxonomies::Load(kData / "taxonomies");
  ASSERT_TRUE(tax.ok()) << tax.status().ToString();
  FeatureOptions options;
  options.taxonomies = std::make_shared<const FacetTaxonomies>(*tax);
  const auto parts = DrawStarterParts(*spec);
  // One part of each family (every kind), twice: the same record byte for byte.
  for (size_t i = 0; i < parts.size(); i += static_cast<size_t>(spec->cases_per_family)) {
    auto r1 = MakeStarterCase(parts[i], spec->fit_samples, options);
    ASSERT_TRUE(r1.ok()) << parts[i].uid << ": " << r1.status().ToString();
    auto r2 = MakeStarterCase(parts[i], spec->fit_samples, options);
    ASSERT_TRUE(r2.ok());
    EXPECT_EQ(r1->ToJson().dump(), r2->ToJson().dump());
    ASSERT_TRUE(r1->descriptor.has_value());
    EXPECT_EQ(r1->descriptor->size(), static_cast<size_t>(kDescriptorCount));
    EXPECT_EQ(r1->concepts.size(), 5u);
    EXPECT_EQ(r1->concepts.at("shape"), parts[i].description.shape_family);
    // The record passes the library's own validation.
    auto back = kb::CaseRecord::FromJson(r1->ToJson(), Where{.file = parts[i].uid});
    EXPECT_TRUE(back.ok()) << back.status().ToString();
  }
}

TEST(Starter, PerturbationScalesEveryParameter) {
  auto spec = StarterSpec::Load(kData / "starter" / "families.json");
  ASSERT_TRUE(spec.ok());
  const auto parts = DrawStarterParts(*spec);
  Rng rng(1);
  const StarterPart p = PerturbStarterPart(parts[0], 0.2, rng, "-x");
  EXPECT_EQ(p.uid, parts[0].uid + "-x");
  for (const auto& [name, v] : p.params) {
    const double ratio = v / parts[0].params.at(name);
    EXPECT_TRUE(std::abs(ratio - 0.8) < 1e-12 || std::abs(ratio - 1.2) < 1e-12) << name << " " << ratio;
  }
}

TEST(Starter, BadSourcesAreRefused) {
  EXPECT_FALSE(StarterSpec::FromJson(nlohmann::json::object(), "x").ok());
  // A family file whose families lack a field is refused naming it.
  const auto missing = StarterSpec::FromJson(
      {{"format", "formloop-starter-families"}, {"seed", 1}, {"cases_per_family", 2}, {"families", {{{"name", "x"}}}}},
      "f.json");
  ASSERT_FALSE(missing.ok());
  EXPECT_NE(missing.status().message().find("families[0].shape"), std::string::npos) << missing.status().message();
  EXPECT_FALSE(StarterSpec::Load(kData / "starter" / "missing.json").ok());
}

}  // namespace
}  // namespace formloop::retrieval
