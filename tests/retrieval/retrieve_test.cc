// Retrieval calibration on a labelled held-out set built from the starter families (issue 7, "What it must
// show" 1), routing, breadth and leave-one-out.
//
// The library: the starter cases of data/starter/families.json, GHSOM with LibraryGhsomDefaults(), the rule
// base of data/starter/rules.json. The held-out set (seeded): every library part (252) is a base; from it
//   identical  the base part itself                                     → A(query, base) ≥ 0.99
//   near       every surface parameter × (1 ± δ), δ ~ U[0.01, 0.05]      → A(query, base) > 0.95 in ≥ 95 %
//   far        every surface parameter × (1 ± δ), δ ~ U[0.10, 0.30]      → 0.80 ≤ A(query, base) ≤ 0.95 in ≥ 80 %
//   other      A(near or far query, every library case of another family) < 0.80 in ≥ 95 % of the pairs
//   top-1      the family of the best retrieved case (near and far queries) = the query's family in ≥ 95 %
// (signs ±1 drawn per parameter; the part's material, tolerance, finish and tool stay the base's: "parameters"
// are the shape parameters). The confusion table and the measured rates are printed.

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <functional>
#include <map>
#include <memory>
#include <set>
#include <string>
#include <vector>

#include <unistd.h>

#include <gtest/gtest.h>

#include "core/json_io.h"
#include "kb/schema.h"
#include "reconstruction/surface_family.h"
#include "retrieval/retrieve.h"
#include "retrieval/starter.h"

namespace formloop::retrieval {
namespace {

const std::filesystem::path kData = std::filesystem::path(FORMLOOP_SOURCE_DIR) / "data";

struct Query {
  std::string kind;  // identical, near, far
  std::string family, base_uid;
  PartFeatures features;
};

struct Fixture {
  StarterSpec spec;
  FeatureOptions options;
  std::vector<StarterPart> parts;
  std::vector<kb::CaseRecord> cases;
  std::unique_ptr<RetrievalModel> model;
  std::vector<Query> queries;
};

const Fixture& Shared() {
  static Fixture* f = [] {
    auto* fx = new Fixture;
    auto spec = StarterSpec::Load(kData / "starter" / "families.json");
    EXPECT_TRUE(spec.ok()) << spec.status().ToString();
    fx->spec = *spec;
    auto tax = FacetTaxonomies::Load(kData / "taxonomies");
    EXPECT_TRUE(tax.ok()) << tax.status().ToString();
    fx->options.taxonomies = std::make_shared<const FacetTaxonomies>(*tax);
    fx->parts = DrawStarterParts(fx->spec);
    auto cases = GenerateStarterCases(fx->spec, fx->options);
    EXPECT_TRUE(cases.ok()) << cases.status().ToString();
    fx->cases = *cases;
    auto rules_json = ReadJsonFile(kData / "starter" / "rules.json");
    EXPECT_TRUE(rules_json.ok());
    auto rules = RulesFromJson(*rules_json, "rules.json");
    EXPECT_TRUE(rules.ok()) << rules.status().ToString();
    auto model = RetrievalModel::Train(fx->cases, LibraryGhsomDefaults(), *rules, *tax);
    EXPECT_TRUE(model.ok()) << model.status().ToString();
    fx->model = std::make_unique<RetrievalModel>(std::move(model).value());

    // The refinement radius of data/starter/rules.json was chosen on another draw of the perturbations (seed 1111,
    // same bases); this set (seed 4242) was measured once with it. Measured with other seeds (same radius):
    // far 10-30 % in band 94.0 % (777), 91.7 % (9001); near > 0.95 99.6 %, 99.2 %. Before the logarithmic
    // magnitudes and the fixed radius (leaf radius × 2.6 on raw z-scores) the far band held 70-72 % of these
    // 252-base sets: the 81 % once measured on 63 bases was a lucky draw.
    Rng rng(4242);
    auto features_of = [&](const StarterPart& p) {
      auto surface = recon::FitParametric(p.kind, p.params, fx->spec.fit_samples);
      EXPECT_TRUE(surface.ok()) << p.uid << ": " << surface.status().ToString();
      auto feat = ExtractFeatures(p.description, *surface, fx->options);
      EXPECT_TRUE(feat.ok()) << p.uid << ": " << feat.status().ToString();
      return *feat;
    };
    for (size_t i = 0; i < fx->parts.size(); ++i) {
      const StarterPart& base = fx->parts[i];
      fx->queries.push_back({"identical", base.family, base.uid, features_of(base)});
      const double d_near = rng.Uniform(0.01, 0.05);
      fx->queries.push_back({"near", base.family, base.uid, features_of(PerturbStarterPart(base, d_near, rng, "-n"))});
      const double d_far = rng.Uniform(0.10, 0.30);
      fx->queries.push_back({"far", base.family, base.uid, features_of(PerturbStarterPart(base, d_far, rng, "-f"))});
    }
    return fx;
  }();
  return *f;
}

TEST(StarterRetrieval, LibraryIsBigEnoughAndTrained) {
  const Fixture& f = Shared();
  std::set<std::string> families;
  for (const auto& c : f.cases) families.insert(c.family);
  EXPECT_GE(f.cases.size(), 200u);
  EXPECT_GE(families.size(), 8u);
  EXPECT_EQ(f.model->case_count(), static_cast<int>(f.cases.size()));
  EXPECT_GT(f.model->ghsom().maps().size(), 0u);
}

TEST(StarterRetrieval, HeldOutCalibration) {
  const Fixture& f = Shared();
  const RetrievalModel& m = *f.model;
  std::map<std::string, std::string> family_of;
  for (const auto& c : f.cases) family_of[c.uid] = c.family;

  int n_ident = 0, ident_ok = 0, ident_top_ok = 0;
  int n_near = 0, near_ok = 0, n_far = 0, far_ok = 0, far_above = 0, far_below = 0;
  long n_other = 0, other_ok = 0;
  int n_max_other = 0, max_other_ok = 0;
  int n_top = 0, top_ok = 0;
  std::vector<double> a_near, a_far;
  std::map<std::string, std::map<std::string, int>> confusion;
  for (const Query& q : f.queries) {
    const auto concepts = q.features.Concepts();
    auto base = m.Score(q.features.descriptors, concepts, q.base_uid);
    ASSERT_TRUE(base.ok()) << base.status().ToString();
    const double a = base->overall;
    auto r = m.Retrieve(q.features, {});
    ASSERT_TRUE(r.ok()) << r.status().ToString();
    ASSERT_FALSE(r->ranked.empty());
    if (q.kind == "identical") {
      ++n_ident;
      ident_ok += a >= 0.99 ? 1 : 0;
      ident_top_ok += r->best_similarity >= 0.99 ? 1 : 0;
      continue;
    }
    if (q.kind == "near") {
      ++n_near;
      near_ok += a > 0.95 ? 1 : 0;
      a_near.push_back(a);
    } else {
      ++n_far;
      far_ok += (a >= 0.80 && a <= 0.95) ? 1 : 0;
      far_above += a > 0.95 ? 1 : 0;
      far_below += a < 0.80 ? 1 : 0;
      a_far.push_back(a);
    }
    ++n_top;
    top_ok += r->ranked.front().family == q.family ? 1 : 0;
    confusion[q.family][r->ranked.front().family] += 1;
    double max_other = 0;
    for (const auto& c : f.cases) {
      if (c.family == q.family) continue;
      auto s = m.Score(q.features.descriptors, concepts, c.uid);
      ASSERT_TRUE(s.ok()) << s.status().ToString();
      ++n_other;
      other_ok += s->overall < 0.80 ? 1 : 0;
      max_other = std::max(max_other, s->overall);
    }
    ++n_max_other;
    max_other_ok += max_other < 0.80 ? 1 : 0;
  }
  auto rate = [](long ok, long n) { return n ? static_cast<double>(ok) / static_cast<double>(n) : 0.0; };
  auto quart = [](std::vector<double> v) {
    std::sort(v.begin(), v.end());
    if (v.empty()) return std::string("-");
    char buf[128];
    std::snprintf(buf, sizeof buf, "min %.3f  q25 %.3f  median %.3f  q75 %.3f  max %.3f", v.front(), v[v.size() / 4],
                  v[v.size() / 2], v[3 * v.size() / 4], v.back());
    return std::string(buf);
  };
  std::printf("\nHeld-out calibration (%zu library cases, %zu queries)\n", f.cases.size(), f.queries.size());
  std::printf("  identical  A(q, base) >= 0.99        %3d / %3d = %.3f (goal 1.00); top-1 A >= 0.99: %d\n", ident_ok,
              n_ident, rate(ident_ok, n_ident), ident_top_ok);
  std::printf("  near <=5%%  A(q, base) > 0.95         %3d / %3d = %.3f (goal >= 0.95)  A: %s\n", near_ok, n_near,
              rate(near_ok, n_near), quart(a_near).c_str());
  std::printf("  far 10-30%% 0.80 <= A(q, base) <= 0.95 %3d / %3d = %.3f (goal >= 0.80)  above %d, below %d  A: %s\n",
              far_ok, n_far, rate(far_ok, n_far), far_above, far_below, quart(a_far).c_str());
  std::printf("  other family, all pairs A < 0.80     %ld / %ld = %.4f (goal >= 0.95)\n", other_ok, n_other,
              rate(other_ok, n_other));
  std::printf("  other family, best pair A < 0.80     %d / %d = %.3f (stricter; reported)\n", max_other_ok, n_max_other,
              rate(max_other_ok, n_max_other));
  std::printf("  top-1 family accuracy                %3d / %3d = %.3f (goal >= 0.95)\n", top_ok, n_top,
              rate(top_ok, n_top));
  std::printf("Confusion (rows: query family, columns: top-1 family)\n%-16s", "");
  std::vector<std::string> fams;
  for (const auto& fam : f.spec.families) fams.push_back(fam.name);
  for (const auto& c : fams) std::printf(" %5.5s", c.c_str());
  std::printf("\n");
  for (const auto& r : fams) {
    std::printf("%-16s", r.c_str());
    for (const auto& c : fams) std::printf(" %5d", confusion[r][c]);
    std::printf("\n");
  }
  EXPECT_EQ(ident_ok, n_ident);
  EXPECT_GE(rate(near_ok, n_near), 0.95);
  EXPECT_GE(rate(far_ok, n_far), 0.80);
  EXPECT_GE(rate(other_ok, n_other), 0.95);
  EXPECT_GE(rate(top_ok, n_top), 0.95);
}

TEST(StarterRetrieval, RoutesFollowThresholdsAndExplain) {
  const Fixture& f = Shared();
  const RetrievalModel& m = *f.model;
  for (const Query& q : f.queries) {
    auto r = m.Retrieve(q.features, {.breadth = 1, .min_candidates = 1, .top = 3});
    ASSERT_TRUE(r.ok());
    EXPECT_EQ(r->route, RouteOf(r->best_similarity, m.thresholds()));
    EXPECT_LE(r->ranked.size(), 3u);
    for (size_t i = 1; i < r->ranked.size(); ++i) {
      EXPECT_GE(r->ranked[i - 1].similarity.overall, r->ranked[i].similarity.overall);
    }
    const auto j = r->ToJson();
    EXPECT_TRUE(j["ranked"][0]["facets"].is_array());
    EXPECT_FALSE(j["ranked"][0]["facets"][0]["common_node"].get<std::string>().empty());
  }
  EXPECT_EQ(RouteOf(0.96, {0.8, 0.95}), "direct");
  EXPECT_EQ(RouteOf(0.95, {0.8, 0.95}), "simulate");
  EXPECT_EQ(RouteOf(0.80, {0.8, 0.95}), "simulate");
  EXPECT_EQ(RouteOf(0.7999, {0.8, 0.95}), "default");
}

TEST(StarterRetrieval, BreadthWidensTheCandidateSet) {
  const Fixture& f = Shared();
  const Query& q = f.queries[1];
  int last = 0;
  for (int b = 0; b <= 4; ++b) {
    auto r = f.model->Retrieve(q.features, {.breadth = b, .min_candidates = 1, .top = 1000});
    ASSERT_TRUE(r.ok());
    EXPECT_GE(r->candidates, last) << "breadth " << b;
    last = r->candidates;
  }
  auto all = f.model->Retrieve(q.features, {.breadth = 64, .min_candidates = 1, .top = 1});
  ASSERT_TRUE(all.ok());
  EXPECT_EQ(all->candidates, f.model->case_count());
  // min_candidates widens automatically.
  auto widened = f.model->Retrieve(q.features, {.breadth = 0, .min_candidates = f.model->case_count(), .top = 1});
  ASSERT_TRUE(widened.ok());
  EXPECT_EQ(widened->candidates, f.model->case_count());
}

// Leave-one-out retrains without each case: its rows equal a model trained on the library without that
// case, retrieving it as a query (checked for a few cases), and differ from retrieval by the full model
// with the case merely excluded from the candidates where the left-out case shaped the map or the counts.
TEST(StarterRetrieval, LeaveOneOutRetrainsWithoutEachCase) {
  const Fixture& f = Shared();
  auto rules_json = ReadJsonFile(kData / "starter" / "rules.json");
  ASSERT_TRUE(rules_json.ok());
  auto rules = RulesFromJson(*rules_json, "rules.json");
  ASSERT_TRUE(rules.ok());
  auto loo = RetrievalModel::LeaveOneOut(f.cases, LibraryGhsomDefaults(), *rules, *f.options.taxonomies, {});
  ASSERT_TRUE(loo.ok()) << loo.status().ToString();
  const auto& j = *loo;
  std::printf("Leave-one-out: top-1 family %.4f; routes direct %d, simulate %d, default %d; A median %.4f\n",
              j["top1_same_family_rate"].get<double>(), j["routes"]["direct"]["count"].get<int>(),
              j["routes"]["simulate"]["count"].get<int>(), j["routes"]["default"]["count"].get<int>(),
              j["similarity"]["median"].get<double>());
  ASSERT_EQ(j["cases"].get<int>(), static_cast<int>(f.cases.size()));
  const int routed = j["routes"]["direct"]["count"].get<int>() + j["routes"]["simulate"]["count"].get<int>() +
                     j["routes"]["default"]["count"].get<int>();
  EXPECT_EQ(routed, static_cast<int>(f.cases.size()));
  EXPECT_GE(j["top1_same_family_rate"].get<double>(), 0.95);
  ASSERT_EQ(j["per_case"].size(), f.cases.size());

  int differs_from_exclusion = 0;
  for (const auto& row : j["per_case"]) {
    const std::string uid = row["uid"].get<std::string>();
    const auto it = std::find_if(f.cases.begin(), f.cases.end(), [&](const auto& c) { return c.uid == uid; });
    ASSERT_NE(it, f.cases.end());
    const Eigen::VectorXd d = Eigen::Map<const Eigen::VectorXd>(it->descriptor->data(), kDescriptorCount);
    auto excluded = f.model->Retrieve(d, it->concepts, {.top = 1, .exclude_uid = uid});
    ASSERT_TRUE(excluded.ok());
    if (std::abs(excluded->best_similarity - row["similarity"].get<double>()) > 1e-12) ++differs_from_exclusion;
  }
  std::printf("Leave-one-out: A differs from the full model's (case only excluded) for %d of %zu cases\n",
              differs_from_exclusion, f.cases.size());
  EXPECT_GT(differs_from_exclusion, 0) << "the left-out case must not shape the model it is retrieved from";

  for (const int k : {0, 57, 131, 251}) {
    const auto& row = j["per_case"][static_cast<size_t>(k)];
    const std::string uid = row["uid"].get<std::string>();
    const auto it = std::find_if(f.cases.begin(), f.cases.end(), [&](const auto& c) { return c.uid == uid; });
    auto without = RetrievalModel::Train(f.cases, LibraryGhsomDefaults(), *rules, *f.options.taxonomies, uid);
    ASSERT_TRUE(without.ok());
    EXPECT_EQ(without->case_count(), static_cast<int>(f.cases.size()) - 1);
    EXPECT_TRUE(without->untrained().empty());
    const Eigen::VectorXd d = Eigen::Map<const Eigen::VectorXd>(it->descriptor->data(), kDescriptorCount);
    auto r = without->Retrieve(d, it->concepts, {.top = 1});
    ASSERT_TRUE(r.ok());
    EXPECT_EQ(r->ranked.front().uid, row["case"].get<std::string>()) << uid;
    EXPECT_EQ(r->best_similarity, row["similarity"].get<double>()) << uid;
    EXPECT_EQ(r->route, row["route"].get<std::string>()) << uid;
  }
}

// Magnitudes on a log scale: the same relative change is the same step whatever the size; fractions stay linear.
TEST(DescriptorTransform, MagnitudesLogarithmicFractionsLinearAndStoredExactly) {
  Eigen::MatrixXd d(3, kDescriptorCount);
  for (int k = 0; k < kDescriptorCount; ++k) d.col(k) << 10.0 * (k + 1), 20.0 * (k + 1), 40.0 * (k + 1);
  const DescriptorTransform t = DescriptorTransform::Fit(d);
  for (int k = 0; k < kDescriptorCount; ++k) {
    if (DescriptorIsMagnitude(k)) {
      EXPECT_DOUBLE_EQ(t.eps(k), 0.01 * 20.0 * (k + 1)) << DescriptorNames()[static_cast<size_t>(k)];
    } else {
      EXPECT_EQ(t.eps(k), 0.0) << DescriptorNames()[static_cast<size_t>(k)];
    }
  }
  const int extent = 0, fraction = 13;  // extent_x_mm, h_frac_flat
  ASSERT_TRUE(DescriptorIsMagnitude(extent));
  ASSERT_FALSE(DescriptorIsMagnitude(fraction));
  Eigen::VectorXd small = d.row(0).transpose(), big = 50 * small;
  Eigen::VectorXd small_up = small, big_up = big;
  small_up(extent) *= 1.1;
  big_up(extent) *= 1.1;
  const double step_small = t.Apply(small_up)(extent) - t.Apply(small)(extent);
  const double step_big = t.Apply(big_up)(extent) - t.Apply(big)(extent);
  EXPECT_NEAR(step_small, std::log(1.1), 2e-4);
  EXPECT_NEAR(step_big, step_small, 1e-4);
  EXPECT_EQ(t.Apply(small)(fraction), small(fraction));
  // Signed magnitudes pass through zero continuously (asinh).
  Eigen::VectorXd signed_curv = small;
  signed_curv(extent) = -small(extent);
  EXPECT_DOUBLE_EQ(t.Apply(signed_curv)(extent), -t.Apply(small)(extent));

  auto back = DescriptorTransform::FromJson(t.ToJson(), kDescriptorCount);
  ASSERT_TRUE(back.ok()) << back.status().ToString();
  EXPECT_EQ(back->eps, t.eps);
  nlohmann::json bad = t.ToJson();
  bad["eps"][3] = -1.0;
  const auto refused = DescriptorTransform::FromJson(bad, kDescriptorCount);
  ASSERT_FALSE(refused.ok());
  EXPECT_NE(refused.status().ToString().find("descriptor_transform.eps"), std::string::npos);
  EXPECT_FALSE(DescriptorTransform::FromJson(t.ToJson(), kDescriptorCount - 1).ok());
}

}  // namespace
}  // namespace formloop::retrieval

namespace formloop::retrieval {
namespace {

// Issue 17 item 4: a case retrieval cannot use is refused at `kb add`/`kb import` and found by `kb check`,
// naming the case uid and the field.
TEST(CaseCheck, StarterAndExampleCasesPassBadConceptsAndDescriptorsAreRefusedNamingTheCase) {
  const auto tax = FacetTaxonomies::Load(kData / "taxonomies");
  ASSERT_TRUE(tax.ok()) << tax.status().ToString();
  for (const kb::CaseRecord& c : Shared().cases) ASSERT_TRUE(CheckCaseForRetrieval(c, *tax).ok()) << c.uid;
  const auto example = kb::ReadCaseFile(kData / "kb" / "example_case.json");
  ASSERT_TRUE(example.ok()) << example.status().ToString();
  ASSERT_TRUE(CheckCaseForRetrieval(*example, *tax).ok()) << CheckCaseForRetrieval(*example, *tax).message();

  auto refused = [&](const std::function<void(kb::CaseRecord*)>& change, std::vector<std::string> mentions) {
    kb::CaseRecord c = *example;
    change(&c);
    const Status s = CheckCaseForRetrieval(c, *tax);
    EXPECT_EQ(s.code(), StatusCode::kBadInput) << mentions.front();
    mentions.push_back("example-blade-001");
    for (const std::string& m : mentions) EXPECT_NE(s.message().find(m), std::string::npos) << m << ": " << s.message();
  };
  refused([](kb::CaseRecord* c) { c->concepts["material"] = "h13 "; },
          {"concepts.material", "'h13 '", "did you mean 'H13'"});
  refused([](kb::CaseRecord* c) { c->concepts["shape"] = "teapot"; }, {"concepts.shape", "teapot", "shape.txt"});
  refused([](kb::CaseRecord* c) { c->concepts.erase("machine_tool"); }, {"concepts.machine_tool", "missing"});
  refused([](kb::CaseRecord* c) { c->concepts["colour"] = "red"; }, {"concepts.colour", "not a facet"});
  refused([](kb::CaseRecord* c) { c->descriptor = std::vector<double>(10, 1.0); }, {"descriptor", "10 values", "24"});
  refused([](kb::CaseRecord* c) { (*c->descriptor)[3] = std::nan(""); }, {"descriptor[3]", "finite"});
}

TEST(CaseCheck, RetrievalProblemsFindsACaseStoredBeforeTheCheck) {
  const auto tax = FacetTaxonomies::Load(kData / "taxonomies");
  ASSERT_TRUE(tax.ok());
  const auto dir = std::filesystem::temp_directory_path() / ("formloop-casecheck-" + std::to_string(::getpid()));
  std::filesystem::create_directories(dir);
  {
    ASSERT_TRUE(kb::InitLibrary(dir / "cases.db").ok());
    auto library = kb::Library::Open(dir / "cases.db");
    ASSERT_TRUE(library.ok()) << library.status().ToString();
    for (int i = 0; i < 3; ++i) ASSERT_TRUE((*library)->AddCase(Shared().cases[static_cast<std::size_t>(i)]).ok());
    auto clean = RetrievalProblems(**library, *tax);
    ASSERT_TRUE(clean.ok()) << clean.status().ToString();
    EXPECT_TRUE(clean->empty()) << clean->front();
    kb::CaseRecord bad = Shared().cases[3];
    bad.concepts["material"] = "h13 ";  // as an older formloop stored it without the check
    ASSERT_TRUE((*library)->AddCase(bad).ok());
    auto found = RetrievalProblems(**library, *tax);
    ASSERT_TRUE(found.ok()) << found.status().ToString();
    ASSERT_EQ(found->size(), 1u);
    EXPECT_NE(found->front().find("case '" + bad.uid + "'"), std::string::npos) << found->front();
    EXPECT_NE(found->front().find("did you mean 'H13'"), std::string::npos) << found->front();
  }
  std::filesystem::remove_all(dir);
}

}  // namespace
}  // namespace formloop::retrieval
