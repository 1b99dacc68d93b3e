#include "retrieval/retrieve.h"

#include <algorithm>
#include <cmath>
#include <optional>
#include <set>
#include <unordered_map>

#include "core/json_io.h"
#include "core/log.h"

namespace formloop::retrieval {
namespace {

using nlohmann::json;

// The schema's version-1 defaults (kb/schema.cc), used when a model is built without a rule base.
std::vector<kb::Rule> DefaultRules() {
  auto rule = [](const std::string& name, json cond, json choice) {
    kb::Rule r;
    r.version = 0;
    r.name = name;
    r.condition = std::move(cond);
    r.choice = std::move(choice);
    r.active = true;
    return r;
  };
  return {rule("route.direct", {{"similarity", {{"gt", 0.95}}}}, {{"route", "direct_nc"}}),
          rule("route.simulate", {{"similarity", {{"ge", 0.8}, {"le", 0.95}}}}, {{"route", "simulation_correction"}}),
          rule("route.default", {{"similarity", {{"lt", 0.8}}}}, {{"route", "default_plan"}, {"flag_engineer", true}}),
          rule("facet.weights", json::object(),
               {{"shape", 3}, {"material", 1}, {"tolerance", 1}, {"finish", 0.5}, {"machine_tool", 1}})};
}

Result<Eigen::MatrixXd> DescriptorMatrix(const std::vector<const kb::CaseRecord*>& cases) {
  Eigen::MatrixXd x(static_cast<Eigen::Index>(cases.size()), kDescriptorCount);
  for (size_t i = 0; i < cases.size(); ++i) {
    const auto& d = *cases[i]->descriptor;
    if (static_cast<int>(d.size()) != kDescriptorCount) {
      return Status::BadInput(
          Where{.field = "cases." + cases[i]->uid + ".descriptor"},
          "has " + std::to_string(d.size()) + " values, expected " + std::to_string(kDescriptorCount));
    }
    for (int k = 0; k < kDescriptorCount; ++k) x(static_cast<Eigen::Index>(i), k) = d[static_cast<size_t>(k)];
  }
  return x;
}

std::vector<const kb::CaseRecord*> WithDescriptor(const std::vector<kb::CaseRecord>& cases) {
  std::vector<const kb::CaseRecord*> out;
  for (const auto& c : cases) {
    if (c.descriptor) out.push_back(&c);
  }
  std::sort(out.begin(), out.end(), [](const auto* a, const auto* b) { return a->uid < b->uid; });
  return out;
}

Result<Eigen::VectorXd> StoredInputWeights(const json& parameters, int dimension) {
  std::vector<double> v(static_cast<std::size_t>(dimension), 1.0);
  const JsonFields f(parameters, "case library", "ghsom.parameters.");
  FL_RETURN_IF_ERROR(f.OptionalNumberArray("input_weights", &v, static_cast<std::size_t>(dimension)));
  return Eigen::Map<const Eigen::VectorXd>(v.data(), dimension).eval();
}

double Quantile(std::vector<double> v, double p) {
  if (v.empty()) return 0;
  std::sort(v.begin(), v.end());
  const double pos = p * static_cast<double>(v.size() - 1);
  const auto lo = static_cast<size_t>(std::floor(pos));
  const size_t hi = std::min(lo + 1, v.size() - 1);
  return v[lo] + (pos - static_cast<double>(lo)) * (v[hi] - v[lo]);
}

}  // namespace

DescriptorTransform DescriptorTransform::Identity(int dimension) {
  return DescriptorTransform{Eigen::VectorXd::Zero(dimension)};
}

DescriptorTransform DescriptorTransform::Fit(const Eigen::MatrixXd& x) {
  DescriptorTransform t = Identity(static_cast<int>(x.cols()));
  for (Eigen::Index k = 0; k < x.cols(); ++k) {
    if (!DescriptorIsMagnitude(static_cast<int>(k))) continue;
    std::vector<double> a(static_cast<size_t>(x.rows()));
    for (Eigen::Index i = 0; i < x.rows(); ++i) a[static_cast<size_t>(i)] = std::abs(x(i, k));
    t.eps(k) = 0.01 * Quantile(std::move(a), 0.5);  // 0 (linear) when most cases have 0 there
  }
  return t;
}

Eigen::VectorXd DescriptorTransform::Apply(const Eigen::VectorXd& d) const {
  Eigen::VectorXd y = d;
  for (Eigen::Index k = 0; k < std::min(d.size(), eps.size()); ++k) {
    if (eps(k) > 0) y(k) = std::asinh(d(k) / eps(k));
  }
  return y;
}

Eigen::MatrixXd DescriptorTransform::ApplyRows(const Eigen::MatrixXd& x) const {
  Eigen::MatrixXd y(x.rows(), x.cols());
  for (Eigen::Index i = 0; i < x.rows(); ++i) y.row(i) = Apply(x.row(i).transpose()).transpose();
  return y;
}

json DescriptorTransform::ToJson() const {
  return {{"kind", "asinh(d / eps) for eps > 0, d otherwise"},
          {"eps", std::vector<double>(eps.data(), eps.data() + eps.size())}};
}

Result<DescriptorTransform> DescriptorTransform::FromJson(const json& j, int dimension) {
  const JsonFields f(j, "case library", "ghsom.parameters.descriptor_transform.");
  FL_RETURN_IF_ERROR(f.CheckKnown({"kind", "eps"}));
  std::vector<double> eps;
  FL_RETURN_IF_ERROR(f.NumberArray("eps", &eps, static_cast<std::size_t>(dimension), {.min = 0}));
  DescriptorTransform t = Identity(dimension);
  for (int k = 0; k < dimension; ++k) t.eps(k) = eps[static_cast<std::size_t>(k)];
  return t;
}

namespace {
// The GHSOM input of the cases (rows sorted by uid): x = w ⊙ z(T(d)), and what made it.
struct GhsomInput {
  DescriptorTransform transform;
  Standardiser standardiser;
  Eigen::VectorXd weights;
  Eigen::MatrixXd x;
  std::vector<std::string> uids;
};

Result<GhsomInput> PrepareInput(const std::vector<const kb::CaseRecord*>& rows, const std::vector<kb::Rule>& rules) {
  GhsomInput in;
  FL_ASSIGN_OR_RETURN(Eigen::MatrixXd raw, DescriptorMatrix(rows));
  in.transform = DescriptorTransform::Fit(raw);
  const Eigen::MatrixXd t = in.transform.ApplyRows(raw);
  FL_ASSIGN_OR_RETURN(in.standardiser, Standardiser::Fit(t));
  FL_ASSIGN_OR_RETURN(Eigen::MatrixXd z, in.standardiser.ApplyRows(t));
  FL_ASSIGN_OR_RETURN(in.weights, InputWeightsFromRules(rules));
  in.x = z * in.weights.asDiagonal();
  for (const auto* r : rows) in.uids.push_back(r->uid);
  return in;
}

// The stored map's T (identity for a map trained before the transform existed).
Result<DescriptorTransform> StoredTransform(const json& parameters, int dimension) {
  if (!parameters.contains("descriptor_transform")) return DescriptorTransform::Identity(dimension);
  return DescriptorTransform::FromJson(parameters["descriptor_transform"], dimension);
}
}  // namespace

// Calibrated on the starter library with a tuning held-out set (seed 1111, bases offset by 2; the test's set,
// seed 4242, was not used for choosing): tau1 = 0.5 gives a layer-1 map of about two units per family; tau2 = 1
// grows no child maps, so every leaf is a layer-1 unit holding one family's cases. With finer trees (the spec's
// defaults tau1 0.3 / tau2 0.03) leaves hold 2-5 cases, their radius is tiny and a 5 % change of a part already
// lands in a sibling leaf, where A is the Lin value of the tree (≈ 0.5 for the geometric facet, A ≈ 0.77):
// near-identical parts then fail the > 0.95 goal (measured 25 %). `kb train --tau1 --tau2` overrides.
GhsomOptions LibraryGhsomDefaults() {
  GhsomOptions o;
  o.tau1 = 0.5;
  o.tau2 = 1.0;
  return o;
}

Result<std::vector<kb::Rule>> RulesFromJson(const json& j, const std::string& source) {
  FL_ASSIGN_OR_RETURN(std::vector<kb::Rule> rules, kb::ParseRules(j, source));
  const auto problems = kb::RuleSetProblems(rules);
  if (!problems.empty()) return Status::BadInput(Where{.file = source}, problems.front());
  return rules;
}

Result<Eigen::VectorXd> InputWeightsFromRules(const std::vector<kb::Rule>& rules) {
  Eigen::VectorXd w = Eigen::VectorXd::Ones(kDescriptorCount);
  const auto& names = DescriptorNames();
  auto index_of = [&](const std::string& name) -> int {
    for (int k = 0; k < kDescriptorCount; ++k) {
      if (names[static_cast<size_t>(k)] == name) return k;
    }
    return -1;
  };
  for (const kb::Rule& r : rules) {
    if (r.name != "retrieval.descriptors") continue;
    const Where where{.field = "rules.retrieval.descriptors"};
    for (const json& e : r.choice.value("exclude", json::array())) {
      const int k = e.is_string() ? index_of(e.get<std::string>()) : -1;
      if (k < 0) return Status::BadInput(where, "unknown descriptor " + e.dump(), "use retrieval::DescriptorNames()");
      w(k) = 0;
    }
    const json weights = r.choice.value("weights", json::object());
    const JsonFields weight_fields(weights, "rules", "retrieval.descriptors.weights.");
    for (const auto& [name, v] : weights.items()) {
      const int k = index_of(name);
      if (k < 0)
        return Status::BadInput(where, "weight of unknown descriptor " + name, "use retrieval::DescriptorNames()");
      FL_RETURN_IF_ERROR(weight_fields.Number(name, &w(k), {.min = 0}));
    }
  }
  if (!(w.sum() > 0))
    return Status::BadInput(Where{.field = "rules.retrieval.descriptors"}, "every descriptor excluded");
  return w;
}

std::string RouteOf(double a, const kb::RouteThresholds& t) {
  if (a > t.high) return "direct";
  if (a >= t.low) return "simulate";
  return "default";
}

Status RetrieveOptions::Validate() const {
  if (breadth < 0 || breadth > 64) return Status::BadInput(Where{.field = "breadth"}, "must be in [0, 64]");
  if (min_candidates < 1) return Status::BadInput(Where{.field = "min_candidates"}, "must be >= 1");
  if (top < 1) return Status::BadInput(Where{.field = "top"}, "must be >= 1");
  if (max_scored < 0) return Status::BadInput(Where{.field = "max_scored"}, "must be >= 0");
  return Status::Ok();
}

json RetrievalResult::ToJson() const {
  json ranked_json = json::array();
  int rank = 1;
  for (const RetrievedCase& c : ranked) {
    json facets = json::array();
    for (const FacetSimilarity& f : c.similarity.facets) facets.push_back(f.ToJson());
    ranked_json.push_back({{"rank", rank++},
                           {"uid", c.uid},
                           {"family", c.family},
                           {"similarity", c.similarity.overall},
                           {"facets", facets}});
  }
  return {
      {"query",
       {{"geometric_chain", query_chain},
        {"leaf", query_chain.empty() ? "" : query_chain.back()},
        {"refinement_radius", r_leaf}}},
      {"breadth_used", breadth_used},
      {"candidates_scored", candidates},
      {"route",
       {{"name", route}, {"similarity", best_similarity}, {"flag_engineer", route == "default"}, {"rule", route_rule}}},
      {"ranked", ranked_json}};
}

Result<RetrievalModel> RetrievalModel::Assemble(const std::vector<kb::CaseRecord>& records,
                                                DescriptorTransform transform, Standardiser standardiser,
                                                Eigen::VectorXd input_weights, Ghsom ghsom,
                                                const std::vector<std::string>& case_uids,
                                                const std::vector<kb::Rule>& rules_in,
                                                const FacetTaxonomies& taxonomies) {
  RetrievalModel m;
  const std::vector<kb::Rule> rules = rules_in.empty() ? DefaultRules() : rules_in;
  FL_ASSIGN_OR_RETURN(m.thresholds_, kb::ThresholdsOf(rules));
  const auto by_facet = taxonomies.ByFacet();
  json weights_rule = json::object();
  for (const kb::Rule& r : rules) {
    if (r.name == "facet.weights") weights_rule = r.choice;
    if (r.name == "retrieval.refinement") {
      const JsonFields f(r.choice, "rules", "retrieval.refinement.");
      FL_RETURN_IF_ERROR(f.OptionalNumber("radius_scale", &m.radius_scale_, {.min = 0, .exclusive_min = true}));
      if (f.Has("radius")) {
        double radius = 0;
        FL_RETURN_IF_ERROR(f.Number("radius", &radius, {.min = 0, .exclusive_min = true}));
        m.fixed_radius_ = radius;
      }
    }
    if (r.name == "route.direct") m.route_rules_["direct"] = r.choice;
    if (r.name == "route.simulate") m.route_rules_["simulate"] = r.choice;
    if (r.name == "route.default") m.route_rules_["default"] = r.choice;
  }
  if (!(m.radius_scale_ > 0) || !std::isfinite(m.radius_scale_)) {
    return Status::BadInput(Where{.field = "rules.retrieval.refinement.radius_scale"}, "must be a number > 0");
  }
  const JsonFields weights(weights_rule, "rules", "facet.weights.");
  for (const auto& [facet, tax] : by_facet) {
    m.weights_[facet] = 1.0;
    FL_RETURN_IF_ERROR(weights.OptionalNumber(facet, &m.weights_[facet], {.min = 0}));
  }
  m.weights_[kGeometricFacet] = kDefaultGeometryWeight;
  FL_RETURN_IF_ERROR(weights.OptionalNumber(kGeometricFacet, &m.weights_[kGeometricFacet], {.min = 0}));

  std::unordered_map<std::string, const kb::CaseRecord*> by_uid;
  for (const auto& r : records) by_uid[r.uid] = &r;
  std::set<std::string> trained(case_uids.begin(), case_uids.end());
  for (const auto& r : records) {
    if (r.descriptor && !trained.count(r.uid)) m.untrained_.push_back(r.uid);
  }
  m.cases_.resize(case_uids.size());
  m.families_.resize(case_uids.size());
  std::vector<CaseConcepts> present;
  present.reserve(case_uids.size());
  for (int row = 0; row < ghsom.input_count(); ++row) {
    const std::int64_t id = ghsom.input_id(row);
    if (id < 0 || id >= static_cast<std::int64_t>(case_uids.size())) {
      return Status::BadInput(Where{.field = "ghsom.ids"}, "input id " + std::to_string(id) + " has no case uid");
    }
    const std::string& uid = case_uids[static_cast<size_t>(id)];
    CaseConcepts& c = m.cases_[static_cast<size_t>(id)];
    auto it = by_uid.find(uid);
    if (it == by_uid.end()) continue;  // removed since training: never a candidate
    c.case_id = uid;
    for (const auto& [facet, tax] : by_facet) {
      auto f = it->second->concepts.find(facet);
      if (f == it->second->concepts.end()) {
        return Status::BadInput(Where{.field = "cases." + uid + ".concepts." + facet}, "missing facet concept");
      }
      c.categorical[facet] = f->second;
    }
    c.geometric_x = ghsom.input(row);
    c.geometric_chain = ghsom.ConceptPath(c.geometric_x);
    m.families_[static_cast<size_t>(id)] = it->second->family;
    present.push_back(c);
  }
  if (present.empty()) return Status::Failed("no case of the library is in its GHSOM; run `formloop kb train`");
  SimilarityOptions so;
  so.facet_weights = m.weights_;
  FL_ASSIGN_OR_RETURN(CaseSimilarityIndex index, CaseSimilarityIndex::Build(by_facet, present, so));
  m.index_ = std::make_shared<const CaseSimilarityIndex>(std::move(index));
  if (input_weights.size() != standardiser.dimension() || transform.eps.size() != standardiser.dimension()) {
    return Status::BadInput(Where{.field = "ghsom.parameters"},
                            "input_weights, descriptor_transform and standardiser differ in size");
  }
  m.transform_ = std::move(transform);
  m.standardiser_ = std::move(standardiser);
  m.input_weights_ = std::move(input_weights);
  m.ghsom_ = std::move(ghsom);
  return m;
}

Result<RetrievalModel> RetrievalModel::Train(const std::vector<kb::CaseRecord>& cases, const GhsomOptions& options,
                                             const std::vector<kb::Rule>& rules, const FacetTaxonomies& taxonomies,
                                             const std::string& exclude_uid) {
  auto rows = WithDescriptor(cases);
  std::erase_if(rows, [&](const kb::CaseRecord* r) { return !exclude_uid.empty() && r->uid == exclude_uid; });
  if (rows.size() < 2) return Status::BadInput("need at least 2 cases with a descriptor to train");
  FL_ASSIGN_OR_RETURN(GhsomInput in, PrepareInput(rows, rules));
  FL_ASSIGN_OR_RETURN(Ghsom g, TrainGhsom(in.x, options));
  FL_ASSIGN_OR_RETURN(RetrievalModel m, Assemble(cases, std::move(in.transform), std::move(in.standardiser),
                                                 std::move(in.weights), std::move(g), in.uids, rules, taxonomies));
  std::erase(m.untrained_, exclude_uid);  // left out on purpose, not awaiting training
  return m;
}

Result<RetrievalModel> RetrievalModel::Load(kb::Library& library, const FacetTaxonomies& taxonomies) {
  FL_ASSIGN_OR_RETURN(std::optional<kb::GhsomRecord> rec, library.LoadGhsom());
  if (!rec) {
    return Status::Failed("case library '" + library.path().string() +
                          "' has no trained GHSOM; run `formloop kb train " + library.path().string() + "`");
  }
  const json& p = rec->parameters;
  if (!p.contains("standardiser") || !p.contains("case_uids")) {
    return Status::BadInput(Where{.field = "ghsom.parameters"},
                            "the stored GHSOM has no standardiser or case list (not trained by `kb train`)");
  }
  FL_ASSIGN_OR_RETURN(Standardiser st, Standardiser::FromJson(p["standardiser"]));
  FL_ASSIGN_OR_RETURN(Ghsom g, Ghsom::FromJson(rec->map));
  FL_ASSIGN_OR_RETURN(auto cases, library.ListCases());
  FL_ASSIGN_OR_RETURN(kb::RuleSet rules, library.GetRules());
  FL_ASSIGN_OR_RETURN(Eigen::VectorXd w, StoredInputWeights(p, st.dimension()));
  FL_ASSIGN_OR_RETURN(DescriptorTransform t, StoredTransform(p, st.dimension()));
  return Assemble(cases, std::move(t), std::move(st), std::move(w), std::move(g),
                  p["case_uids"].get<std::vector<std::string>>(), rules.rules, taxonomies);
}

Result<CaseConcepts> RetrievalModel::Query(const Eigen::VectorXd& x,
                                           const std::map<std::string, std::string>& concepts) const {
  CaseConcepts query;
  query.case_id = "query";
  for (const auto& [facet, w] : weights_) {
    if (facet == kGeometricFacet) continue;
    auto it = concepts.find(facet);
    if (it == concepts.end()) {
      return Status::BadInput(Where{.field = "query.concepts." + facet}, "missing facet concept");
    }
    query.categorical[facet] = it->second;
  }
  query.geometric_chain = ghsom_.ConceptPath(x);
  if (query.geometric_chain.empty())
    return Status::BadInput(Where{.field = "query.descriptor"}, "non-finite descriptor");
  query.geometric_x = x;
  return query;
}

Result<CaseSimilarity> RetrievalModel::Score(const Eigen::VectorXd& descriptor,
                                             const std::map<std::string, std::string>& concepts,
                                             const std::string& uid) const {
  FL_ASSIGN_OR_RETURN(Eigen::VectorXd x, Input(descriptor));
  FL_ASSIGN_OR_RETURN(CaseConcepts query, Query(x, concepts));
  const std::vector<GhsomUnitRef> refs = ghsom_.Descend(x);
  const double r = RefinementRadius(refs.back());
  for (const CaseConcepts& c : cases_) {
    if (c.case_id == uid) return index_->Score(query, r, c);
  }
  return Status::NotFound("case '" + uid + "' is not in the retrieval model");
}

double RetrievalModel::RefinementRadius(const GhsomUnitRef& leaf) const {
  return fixed_radius_ > 0 ? fixed_radius_ : radius_scale_ * ghsom_.LeafRadius(leaf);
}

Result<Eigen::VectorXd> RetrievalModel::Input(const Eigen::VectorXd& descriptor) const {
  if (descriptor.size() != transform_.eps.size()) {
    return Status::BadInput(Where{.field = "query.descriptor"}, "has " + std::to_string(descriptor.size()) +
                                                                    " values, the library's have " +
                                                                    std::to_string(transform_.eps.size()));
  }
  FL_ASSIGN_OR_RETURN(Eigen::VectorXd z, standardiser_.Apply(transform_.Apply(descriptor)));
  return z.cwiseProduct(input_weights_).eval();
}

Result<RetrievalResult> RetrievalModel::RetrieveInput(const Eigen::VectorXd& x,
                                                      const std::map<std::string, std::string>& concepts,
                                                      const RetrieveOptions& options) const {
  FL_RETURN_IF_ERROR(options.Validate());
  const std::vector<GhsomUnitRef> refs = ghsom_.Descend(x);
  if (refs.empty()) return Status::BadInput(Where{.field = "query.descriptor"}, "non-finite descriptor");
  RetrievalResult out;
  out.query_chain = ghsom_.ConceptPath(x);
  const GhsomUnitRef leaf = refs.back();
  out.r_leaf = RefinementRadius(leaf);

  FL_ASSIGN_OR_RETURN(CaseConcepts query, Query(x, concepts));

  // Candidate rows by breadth, widened until min_candidates are found.
  std::vector<std::int64_t> ids;
  const int n_refs = static_cast<int>(refs.size());
  int breadth = options.breadth;
  for (;; ++breadth) {
    std::vector<std::int64_t> gathered;
    auto add = [&](const GhsomUnitRef& u) {
      const std::vector<std::int64_t> unit_ids = ghsom_.InputIds(u);
      gathered.insert(gathered.end(), unit_ids.begin(), unit_ids.end());
    };
    bool everything = false;
    if (breadth >= 2) {
      const int k = n_refs - breadth;  // refs[k]: the unit whose inputs are taken
      if (k < 0) {
        everything = true;
      } else {
        add(refs[static_cast<size_t>(k)]);
      }
    } else {
      add(leaf);
      if (breadth >= 1) {
        for (int n : ghsom_.GridNeighbours(leaf)) add({leaf.map, n});
      }
    }
    if (everything) {
      gathered.resize(cases_.size());
      for (size_t i = 0; i < cases_.size(); ++i) gathered[i] = static_cast<std::int64_t>(i);
    }
    std::sort(gathered.begin(), gathered.end());
    gathered.erase(std::unique(gathered.begin(), gathered.end()), gathered.end());
    ids.clear();
    for (std::int64_t id : gathered) {
      const CaseConcepts& c = cases_[static_cast<size_t>(id)];
      if (c.case_id.empty() || c.case_id == options.exclude_uid) continue;
      ids.push_back(id);
    }
    if (static_cast<int>(ids.size()) >= options.min_candidates || everything) break;
  }
  out.breadth_used = breadth;
  if (options.max_scored > 0 && static_cast<int>(ids.size()) > options.max_scored) {
    std::vector<std::pair<double, std::int64_t>> by_distance;
    by_distance.reserve(ids.size());
    for (std::int64_t id : ids) {
      by_distance.emplace_back((cases_[static_cast<size_t>(id)].geometric_x - x).squaredNorm(), id);
    }
    std::nth_element(by_distance.begin(), by_distance.begin() + options.max_scored, by_distance.end());
    by_distance.resize(static_cast<size_t>(options.max_scored));
    ids.clear();
    for (const auto& [d2, id] : by_distance) ids.push_back(id);
  }
  out.candidates = static_cast<int>(ids.size());
  std::vector<RetrievedCase> scored;
  scored.reserve(ids.size());
  for (std::int64_t id : ids) {
    FL_ASSIGN_OR_RETURN(CaseSimilarity s, index_->Score(query, out.r_leaf, cases_[static_cast<size_t>(id)]));
    scored.push_back({cases_[static_cast<size_t>(id)].case_id, families_[static_cast<size_t>(id)], std::move(s)});
  }
  const size_t keep = std::min(scored.size(), static_cast<size_t>(options.top));
  auto better = [](const RetrievedCase& a, const RetrievedCase& b) {
    if (a.similarity.overall != b.similarity.overall) return a.similarity.overall > b.similarity.overall;
    return a.uid < b.uid;
  };
  std::partial_sort(scored.begin(), scored.begin() + static_cast<std::ptrdiff_t>(keep), scored.end(), better);
  scored.resize(keep);
  out.ranked = std::move(scored);
  out.best_similarity = out.ranked.empty() ? 0.0 : out.ranked.front().similarity.overall;
  out.route = RouteOf(out.best_similarity, thresholds_);
  auto rr = route_rules_.find(out.route);
  out.route_rule = rr == route_rules_.end() ? json::object() : rr->second;
  return out;
}

Result<json> RetrievalModel::LeaveOneOut(const std::vector<kb::CaseRecord>& records, const GhsomOptions& ghsom,
                                         const std::vector<kb::Rule>& rules, const FacetTaxonomies& taxonomies,
                                         const RetrieveOptions& options_in, int max_cases) {
  FL_RETURN_IF_ERROR(options_in.Validate());
  if (max_cases < 0) return Status::BadInput(Where{.field = "max_cases"}, "must be >= 0 (0: every case)");
  struct RouteCount {
    int count = 0, same = 0;
  };
  std::map<std::string, RouteCount> routes{{"direct", {}}, {"simulate", {}}, {"default", {}}};
  std::map<std::string, std::map<std::string, int>> confusion;
  std::vector<double> a_values, a_same, a_other;
  json rows = json::array();
  int correct = 0, total = 0;
  const std::vector<const kb::CaseRecord*> all = WithDescriptor(records);
  std::vector<const kb::CaseRecord*> left_out = all;
  if (max_cases > 0 && static_cast<int>(all.size()) > max_cases) {
    left_out.clear();
    for (int i = 0; i < max_cases; ++i) left_out.push_back(all[static_cast<size_t>(i) * all.size() / max_cases]);
  }
  for (const kb::CaseRecord* c : left_out) {
    FL_ASSIGN_OR_RETURN(RetrievalModel model, Train(records, ghsom, rules, taxonomies, c->uid));
    RetrieveOptions options = options_in;
    options.top = 1;
    const Eigen::VectorXd descriptor =
        Eigen::Map<const Eigen::VectorXd>(c->descriptor->data(), static_cast<Eigen::Index>(c->descriptor->size()));
    auto r = model.Retrieve(descriptor, c->concepts, options);
    if (!r.ok()) return r.status().WithContext("leave-one-out of case " + c->uid);
    if (r->ranked.empty()) continue;
    ++total;
    const RetrievedCase& best = r->ranked.front();
    const bool same = best.family == c->family;
    correct += same ? 1 : 0;
    RouteCount& rc = routes[r->route];
    ++rc.count;
    rc.same += same ? 1 : 0;
    confusion[c->family][best.family] += 1;
    a_values.push_back(r->best_similarity);
    (same ? a_same : a_other).push_back(r->best_similarity);
    rows.push_back({{"uid", c->uid},
                    {"family", c->family},
                    {"route", r->route},
                    {"similarity", r->best_similarity},
                    {"case", best.uid},
                    {"case_family", best.family}});
  }
  json routes_json = json::object();
  for (const auto& [name, rc] : routes) {
    routes_json[name] = {{"count", rc.count},
                         {"share", total ? static_cast<double>(rc.count) / total : 0.0},
                         {"same_family", rc.same},
                         {"same_family_rate", rc.count ? static_cast<double>(rc.same) / rc.count : 0.0}};
  }
  auto dist = [](const std::vector<double>& v) {
    json hist = json::array();
    for (int b = 0; b < 20; ++b) {
      const double lo = 0.05 * b, hi = 0.05 * (b + 1);
      hist.push_back(std::count_if(v.begin(), v.end(), [&](double a) { return a >= lo && (a < hi || b == 19); }));
    }
    return json{{"n", v.size()},
                {"min", v.empty() ? 0.0 : *std::min_element(v.begin(), v.end())},
                {"p05", Quantile(v, 0.05)},
                {"p25", Quantile(v, 0.25)},
                {"median", Quantile(v, 0.5)},
                {"p75", Quantile(v, 0.75)},
                {"p95", Quantile(v, 0.95)},
                {"max", v.empty() ? 0.0 : *std::max_element(v.begin(), v.end())},
                {"histogram_0.05", hist}};
  };
  FL_ASSIGN_OR_RETURN(kb::RouteThresholds thresholds, kb::ThresholdsOf(rules.empty() ? DefaultRules() : rules));
  return json{{"method",
               "leave-one-out: each case is taken out, the standardiser, GHSOM and IC counts are trained on the "
               "others, and the case is retrieved as a new part"},
              {"ghsom", ghsom.ToJson()},
              {"cases", total},
              {"library_cases", all.size()},
              {"breadth", options_in.breadth},
              {"thresholds", {{"low", thresholds.low}, {"high", thresholds.high}}},
              {"top1_same_family_rate", total ? static_cast<double>(correct) / total : 0.0},
              {"routes", routes_json},
              {"similarity", dist(a_values)},
              {"similarity_same_family", dist(a_same)},
              {"similarity_other_family", dist(a_other)},
              {"confusion", confusion},
              {"per_case", rows}};
}

Result<GhsomOptions> StoredGhsomOptions(kb::Library& library) {
  FL_ASSIGN_OR_RETURN(std::optional<kb::GhsomRecord> rec, library.LoadGhsom());
  if (!rec || !rec->parameters.contains("ghsom")) return LibraryGhsomDefaults();
  auto options = GhsomOptions::FromJson(rec->parameters["ghsom"]);
  if (!options.ok()) return options.status().WithContext("the stored GHSOM's parameters.ghsom");
  return options;
}

Result<json> TrainLibraryGhsom(kb::Library& library, const GhsomOptions& options) {
  FL_RETURN_IF_ERROR(options.Validate());
  FL_ASSIGN_OR_RETURN(long long changes, library.ChangeCounter());
  FL_ASSIGN_OR_RETURN(auto cases, library.ListCases());
  const auto rows = WithDescriptor(cases);
  if (rows.size() < 2) {
    return Status::BadInput("case library '" + library.path().string() + "' has " + std::to_string(rows.size()) +
                            " case(s) with a descriptor; training needs at least 2");
  }
  FL_ASSIGN_OR_RETURN(kb::RuleSet rules, library.GetRules());
  FL_ASSIGN_OR_RETURN(GhsomInput in, PrepareInput(rows, rules.rules));
  GhsomReport report;
  FL_ASSIGN_OR_RETURN(Ghsom g, TrainGhsom(in.x, options, &report));
  const std::vector<std::string>& uids = in.uids;
  const Standardiser& st = in.standardiser;
  const Eigen::VectorXd& w = in.weights;
  json names = json::array();
  for (auto n : DescriptorNames()) names.push_back(std::string(n));
  kb::GhsomRecord rec;
  rec.seed = static_cast<long long>(options.seed);
  rec.parameters = {{"ghsom", options.ToJson()},
                    {"descriptor_transform", in.transform.ToJson()},
                    {"standardiser", st.ToJson()},
                    {"case_uids", uids},
                    {"input_weights", std::vector<double>(w.data(), w.data() + w.size())},
                    {"descriptor_names", names}};
  rec.quality = report.ToJson();
  rec.quality["leaf_qe"] = g.LeafQe();
  rec.quality["mqe0"] = g.mqe0();
  rec.map = g.ToJson();
  rec.case_count = static_cast<long long>(uids.size());
  rec.change_counter = changes;
  FL_ASSIGN_OR_RETURN(long long id, library.StoreGhsom(rec));
  return json{{"ghsom_id", id},
              {"cases", uids.size()},
              {"cases_without_descriptor", cases.size() - rows.size()},
              {"change_counter", changes},
              {"parameters", options.ToJson()},
              {"constant_components", st.constant_components},
              {"input_weights", std::vector<double>(w.data(), w.data() + w.size())},
              {"quality", rec.quality}};
}

Result<json> InsertCaseIntoGhsom(kb::Library& library, const kb::CaseRecord& record, long long changes_before_add) {
  FL_ASSIGN_OR_RETURN(kb::GhsomStatus status, library.Ghsom());
  if (!status.present) return json{{"inserted", false}, {"reason", "no GHSOM trained yet"}};
  if (status.trained_at_changes != changes_before_add) {
    return json{{"inserted", false}, {"reason", "the GHSOM was already stale; run `formloop kb train`"}};
  }
  if (!record.descriptor) return json{{"inserted", false}, {"reason", "the case has no descriptor"}};
  FL_ASSIGN_OR_RETURN(std::optional<kb::GhsomRecord> rec, library.LoadGhsom());
  if (!rec || !rec->parameters.contains("case_uids") || !rec->parameters.contains("standardiser")) {
    return json{{"inserted", false}, {"reason", "the stored GHSOM was not trained by `kb train`"}};
  }
  auto uids = rec->parameters["case_uids"].get<std::vector<std::string>>();
  if (std::find(uids.begin(), uids.end(), record.uid) != uids.end()) {
    return json{{"inserted", false}, {"reason", "the case replaced a trained case; run `formloop kb train`"}};
  }
  FL_ASSIGN_OR_RETURN(Standardiser st, Standardiser::FromJson(rec->parameters["standardiser"]));
  FL_ASSIGN_OR_RETURN(Ghsom g, Ghsom::FromJson(rec->map));
  const Eigen::VectorXd raw = Eigen::Map<const Eigen::VectorXd>(record.descriptor->data(),
                                                                static_cast<Eigen::Index>(record.descriptor->size()));
  FL_ASSIGN_OR_RETURN(DescriptorTransform t, StoredTransform(rec->parameters, st.dimension()));
  if (raw.size() != t.eps.size()) {
    return Status::BadInput(Where{.field = "cases." + record.uid + ".descriptor"},
                            "size differs from the library's descriptors");
  }
  FL_ASSIGN_OR_RETURN(Eigen::VectorXd z, st.Apply(t.Apply(raw)));
  FL_ASSIGN_OR_RETURN(Eigen::VectorXd w, StoredInputWeights(rec->parameters, st.dimension()));
  const Eigen::VectorXd x = z.cwiseProduct(w);
  GhsomInsertReport ins;
  FL_RETURN_IF_ERROR(g.Insert(x, static_cast<std::int64_t>(uids.size()), &ins));
  uids.push_back(record.uid);
  rec->parameters["case_uids"] = uids;
  rec->map = g.ToJson();
  rec->case_count = static_cast<long long>(uids.size());
  // Only this add may lie between training and now; if another writer added too, the record stays stale.
  rec->change_counter = changes_before_add + 1;
  FL_ASSIGN_OR_RETURN(long long id, library.StoreGhsom(*rec));
  json path = json::array();
  for (const auto& u : ins.path) path.push_back(Ghsom::ConceptId(u));
  return json{{"inserted", true},
              {"ghsom_id", id},
              {"path", path},
              {"subtree_retrained", ins.retrained},
              {"new_maps", ins.new_maps},
              {"leaf_mqe", ins.leaf_mqe},
              {"depth_threshold", ins.threshold}};
}

Status CheckCaseForRetrieval(const kb::CaseRecord& record, const FacetTaxonomies& taxonomies) {
  const std::string what = "case '" + record.uid + "'";
  const std::map<std::string, Taxonomy> by_facet = taxonomies.ByFacet();
  for (const auto& [facet, value] : record.concepts) {
    if (by_facet.count(facet) == 0) {
      std::string names;
      for (const auto& [name, tax] : by_facet) names += (names.empty() ? "" : ", ") + name;
      return Status::BadInput(Where{.file = what, .field = "concepts." + facet}, "is not a facet",
                              "use the facets " + names);
    }
  }
  for (const auto& [facet, taxonomy] : by_facet) {
    const auto it = record.concepts.find(facet);
    if (it == record.concepts.end()) {
      return Status::BadInput(Where{.file = what, .field = "concepts." + facet}, "is missing",
                              "give the " + facet + " concept of the case (retrieval compares every facet)");
    }
    if (taxonomy.Find(it->second)) continue;
    const std::optional<std::string> near = taxonomy.Suggest(it->second);
    return Status::BadInput(Where{.file = what, .field = "concepts." + facet},
                            "'" + it->second + "' is not a concept of the " + facet + " taxonomy",
                            near ? "did you mean '" + *near + "'?"
                                 : "use a node or alias of data/taxonomies/" +
                                       std::string(facet == kMachineToolFacet ? "machine_tool" : facet) + ".txt");
  }
  if (record.descriptor) {
    const std::vector<double>& d = *record.descriptor;
    if (d.size() != static_cast<std::size_t>(kDescriptorCount)) {
      return Status::BadInput(Where{.file = what, .field = "descriptor"},
                              "has " + std::to_string(d.size()) + " values; the library's descriptors have " +
                                  std::to_string(kDescriptorCount),
                              "compute it with formloop (retrieve --part/--surface prints it) or leave it out");
    }
    for (std::size_t i = 0; i < d.size(); ++i) {
      if (!std::isfinite(d[i])) {
        return Status::BadInput(Where{.file = what, .field = "descriptor[" + std::to_string(i) + "]"},
                                "is not a finite number (" + std::string(DescriptorNames()[i]) + ")");
      }
    }
  }
  return Status::Ok();
}

Result<std::vector<std::string>> RetrievalProblems(kb::Library& library, const FacetTaxonomies& taxonomies) {
  std::vector<std::string> problems;
  FL_ASSIGN_OR_RETURN(const std::vector<kb::CaseRecord> records, library.ListCases());
  for (const kb::CaseRecord& r : records) {
    const Status s = CheckCaseForRetrieval(r, taxonomies);
    if (!s.ok()) problems.push_back(s.message());
  }
  FL_ASSIGN_OR_RETURN(const kb::GhsomStatus ghsom, library.Ghsom());
  if (ghsom.present) {
    const auto model = RetrievalModel::Load(library, taxonomies);
    if (!model.ok()) problems.push_back("retrieval model: " + model.status().message());
  }
  return problems;
}

Result<json> AddCaseAndGrowGhsom(kb::Library& library, const kb::CaseRecord& record, bool replace) {
  // One transaction: the add and the GHSOM read-modify-write commit together, so concurrent `kb add`s
  // and `formloop run` retain steps (other processes, other hosts on one PostgreSQL library) cannot
  // interleave between reading the map and storing it. On a serialization failure it all reruns.
  json out;
  const Status written = library.RunInTransaction([&]() -> Status {
    FL_ASSIGN_OR_RETURN(long long changes_before, library.ChangeCounter());
    FL_RETURN_IF_ERROR(library.AddCase(record, replace));
    auto inserted = InsertCaseIntoGhsom(library, record, changes_before);
    if (inserted.ok()) {
      out = std::move(inserted).value();
      return Status::Ok();
    }
    // A storage failure aborts the whole transaction (and may be retried); a case the map cannot take
    // is added without it, the map staying stale until `kb train`.
    if (inserted.status().code() == StatusCode::kIoError) return inserted.status();
    log::Warn("case {} not inserted into the GHSOM: {}", record.uid, inserted.status().ToString());
    out = json{{"inserted", false}, {"reason", inserted.status().ToString()}};
    return Status::Ok();
  });
  FL_RETURN_IF_ERROR(written);
  return out;
}

}  // namespace formloop::retrieval
