#include "retrieval/ghsom.h"

#include <gtest/gtest.h>

#include <Eigen/QR>
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <limits>
#include <map>
#include <set>

#include "core/random.h"

namespace formloop::retrieval {
namespace {

// Two-level synthetic case library in 6-D: kTop top clusters at the vertices of a regular tetrahedron of edge 28 (10
// · (±1, ±1, ±1) rotated into 6-D by a seeded orthonormal basis, so every component carries the top structure and
// z-scoring keeps it), each with kSub sub-clusters at the vertices of an equilateral triangle of edge 5.2 (radius 3,
// in a seeded plane), points N(0, 0.2²) per component around the sub-centres. Labels: top = label / kSub, sub =
// label.
constexpr int kTop = 4, kSub = 3, kPerSub = 100, kDim = 6;

// Orthonormal kDim × cols basis from a seeded Gaussian matrix.
Eigen::MatrixXd RandomBasis(Rng* rng, int cols) {
  Eigen::MatrixXd g(kDim, cols);
  for (Eigen::Index i = 0; i < g.size(); ++i) g(i) = rng->Normal();
  return Eigen::HouseholderQR<Eigen::MatrixXd>(g).householderQ() * Eigen::MatrixXd::Identity(kDim, cols);
}

struct Clustered {
  Eigen::MatrixXd x;                         // raw features, N × kDim
  std::vector<int> label;                    // top * kSub + sub
  std::vector<Eigen::VectorXd> sub_centres;  // kTop * kSub
};

Clustered MakeClustered(std::uint64_t seed) {
  Rng rng(seed);
  Clustered c;
  const Eigen::MatrixXd rotation = RandomBasis(&rng, 3);
  const double tetrahedron[kTop][3] = {{1, 1, 1}, {1, -1, -1}, {-1, 1, -1}, {-1, -1, 1}};
  for (int t = 0; t < kTop; ++t) {
    const Eigen::VectorXd top =
        10.0 * rotation * Eigen::Vector3d(tetrahedron[t][0], tetrahedron[t][1], tetrahedron[t][2]);
    const Eigen::MatrixXd plane = RandomBasis(&rng, 2);
    for (int s = 0; s < kSub; ++s) {
      const double angle = 2.0 * M_PI * s / kSub;
      c.sub_centres.push_back(top + 3.0 * (std::cos(angle) * plane.col(0) + std::sin(angle) * plane.col(1)));
    }
  }
  c.x.resize(kTop * kSub * kPerSub, kDim);
  int row = 0;
  for (int l = 0; l < kTop * kSub; ++l) {
    for (int i = 0; i < kPerSub; ++i, ++row) {
      for (int k = 0; k < kDim; ++k) c.x(row, k) = c.sub_centres[static_cast<std::size_t>(l)](k) + rng.Normal(0, 0.2);
      c.label.push_back(l);
    }
  }
  return c;
}

// Options for the two-level test: tau2 = 0.08 expands the layer-1 units (which hold whole top clusters, mqe ≈
// 12–30 % of mqe_0) and stops at the sub-cluster units (mqe ≈ 5 % of mqe_0).
GhsomOptions ClusterOptions() {
  GhsomOptions o;
  o.tau1 = 0.3;
  o.tau2 = 0.08;
  return o;
}

struct Trained {
  Clustered data;
  Standardiser standardiser;
  Eigen::MatrixXd z;
  Ghsom model;
};

Trained TrainClustered(std::uint64_t seed, const GhsomOptions& options) {
  Trained t;
  t.data = MakeClustered(seed);
  auto s = Standardiser::Fit(t.data.x);
  EXPECT_TRUE(s.ok()) << s.status().ToString();
  t.standardiser = *s;
  t.z = *t.standardiser.ApplyRows(t.data.x);
  auto g = TrainGhsom(t.z, options);
  EXPECT_TRUE(g.ok()) << g.status().ToString();
  t.model = std::move(*g);
  return t;
}

// Label counts of a unit's inputs (ids are rows of the training matrix).
std::map<int, int> LabelCounts(const Ghsom& g, const GhsomUnitRef& ref, const std::vector<int>& labels) {
  std::map<int, int> counts;
  for (std::int64_t id : g.InputIds(ref)) ++counts[labels[static_cast<std::size_t>(id)]];
  return counts;
}

std::pair<int, double> Dominant(const std::map<int, int>& counts) {
  int best = -1, total = 0, best_count = 0;
  for (const auto& [label, n] : counts) {
    total += n;
    if (n > best_count) {
      best_count = n;
      best = label;
    }
  }
  return {best, total > 0 ? static_cast<double>(best_count) / total : 0.0};
}

TEST(GhsomStandardiser, ZScoresAndConstantComponent) {
  Eigen::MatrixXd x(4, 3);
  x << 1, 5, 7, 2, 5, 8, 3, 5, 9, 4, 5, 10;
  auto s = Standardiser::Fit(x);
  ASSERT_TRUE(s.ok()) << s.status().ToString();
  EXPECT_DOUBLE_EQ(s->mean(0), 2.5);
  EXPECT_NEAR(s->std(0), std::sqrt(5.0 / 3.0), 1e-15);
  ASSERT_EQ(s->constant_components, std::vector<int>{1});
  EXPECT_EQ(s->std(1), 1.0);
  const Eigen::MatrixXd z = *s->ApplyRows(x);
  EXPECT_NEAR(z.col(0).mean(), 0.0, 1e-15);
  EXPECT_NEAR(z.col(2).squaredNorm() / 3.0, 1.0, 1e-14);
  EXPECT_EQ(z.col(1).cwiseAbs().maxCoeff(), 0.0);
  auto back = Standardiser::FromJson(nlohmann::json::parse(s->ToJson().dump()));
  ASSERT_TRUE(back.ok()) << back.status().ToString();
  EXPECT_EQ(back->ToJson().dump(), s->ToJson().dump());
  EXPECT_FALSE(s->Apply(Eigen::VectorXd(Eigen::VectorXd::Zero(2))).ok());
  nlohmann::json broken = s->ToJson();
  broken["std"][0] = -1.0;
  auto bad = Standardiser::FromJson(broken);
  ASSERT_FALSE(bad.ok());
  EXPECT_NE(bad.status().message().find("standardiser.std[0]"), std::string::npos) << bad.status().message();
}

// (a) The hierarchy recovers both levels: the layer-1 map separates the top clusters and each child map separates the
// sub-clusters of its top cluster.
TEST(GhsomHierarchy, RecoversTopAndSubClusters) {
  const Trained t = TrainClustered(11, ClusterOptions());
  const Ghsom& g = t.model;
  ASSERT_FALSE(g.maps().empty());
  const GhsomMap& top = g.maps().front();
  EXPECT_EQ(top.depth, 1);
  std::vector<int> top_label(t.data.label.size());
  for (std::size_t i = 0; i < top_label.size(); ++i) top_label[i] = t.data.label[i] / kSub;

  std::set<int> top_dominant;
  int children = 0;
  for (int u = 0; u < top.unit_count(); ++u) {
    const auto counts = LabelCounts(g, {top.id, u}, top_label);
    if (counts.empty()) continue;
    const auto [label, purity] = Dominant(counts);
    EXPECT_GE(purity, 0.95) << "layer-1 unit " << u << " mixes top clusters";
    top_dominant.insert(label);

    const int child = top.units[static_cast<std::size_t>(u)].child_map;
    if (child < 0) continue;
    ++children;
    const GhsomMap* cm = g.map(child);
    ASSERT_NE(cm, nullptr);
    EXPECT_EQ(cm->depth, 2);
    EXPECT_EQ(cm->parent_map, top.id);
    EXPECT_EQ(cm->parent_unit, u);
    std::set<int> sub_dominant;
    for (int v = 0; v < cm->unit_count(); ++v) {
      const auto sub_counts = LabelCounts(g, {cm->id, v}, t.data.label);
      if (sub_counts.empty()) continue;
      const auto [sub, sub_purity] = Dominant(sub_counts);
      EXPECT_GE(sub_purity, 0.90) << "child map " << cm->id << " unit " << v << " mixes sub-clusters";
      sub_dominant.insert(sub);
    }
    // Every sub-cluster of this top cluster is dominant in some unit of the child map.
    for (int s = 0; s < kSub; ++s) {
      EXPECT_TRUE(sub_dominant.count(label * kSub + s)) << "sub-cluster " << s << " of top " << label << " lost";
    }
  }
  EXPECT_EQ(top_dominant.size(), static_cast<std::size_t>(kTop));
  EXPECT_EQ(children, kTop) << "every top cluster should be expanded into its sub-clusters";
  // The sub-cluster units are tight: no third level.
  for (const auto& m : g.maps()) EXPECT_LE(m.depth, 2);
}

// (b) Layer-1 QE (mean distance of all inputs to their BMU on the layer-1 map) falls strictly as tau1 falls: a
// smaller breadth threshold grows a wider map.
TEST(GhsomBreadth, LayerOneQeFallsWithTau1) {
  Rng rng(5);
  Eigen::MatrixXd x(600, 3);
  for (Eigen::Index i = 0; i < x.rows(); ++i) {
    for (Eigen::Index k = 0; k < x.cols(); ++k) x(i, k) = rng.Uniform(-1, 1);
  }
  const Eigen::MatrixXd z = *(*Standardiser::Fit(x)).ApplyRows(x);
  double previous_qe = std::numeric_limits<double>::infinity();
  int previous_units = 0;
  for (double tau1 : {0.8, 0.5, 0.3, 0.15}) {
    GhsomOptions o;
    o.tau1 = tau1;
    o.max_depth = 1;  // the breadth threshold alone
    GhsomReport report;
    auto g = TrainGhsom(z, o, &report);
    ASSERT_TRUE(g.ok()) << g.status().ToString();
    const GhsomMap& top = g->maps().front();
    std::printf("tau1 %.2f: layer-1 map %d x %d, QE %.4f, TE %.4f, MQE %.4f (mqe0 %.4f)\n", tau1, top.rows, top.cols,
                top.qe, top.te, top.mqe, g->mqe0());
    EXPECT_LT(top.qe, previous_qe) << "tau1 = " << tau1;
    EXPECT_GT(top.unit_count(), previous_units) << "tau1 = " << tau1;
    // The stopping rule held: MQE_m < tau1 · mqe_0 (or the unit cap was reached).
    EXPECT_TRUE(top.mqe < tau1 * g->mqe0() || report.maps.front().unit_cap_reached);
    previous_qe = top.qe;
    previous_units = top.unit_count();
  }
}

// (c) TE is reported for every map, in [0, 1], and matches its definition on the layer-1 map.
TEST(GhsomQuality, TopographicErrorInUnitInterval) {
  GhsomReport report;
  const Clustered data = MakeClustered(3);
  const Eigen::MatrixXd z = *(*Standardiser::Fit(data.x)).ApplyRows(data.x);
  auto g = TrainGhsom(z, ClusterOptions(), &report);
  ASSERT_TRUE(g.ok());
  ASSERT_EQ(report.maps.size(), g->maps().size());
  for (const auto& row : report.maps) {
    EXPECT_GE(row.te, 0.0);
    EXPECT_LE(row.te, 1.0);
    EXPECT_GE(row.training_time_s, 0.0);
  }
  // Recompute TE of the layer-1 map from its weights.
  const GhsomMap& top = g->maps().front();
  int errors = 0;
  for (Eigen::Index i = 0; i < z.rows(); ++i) {
    std::vector<std::pair<double, int>> d;
    for (int u = 0; u < top.unit_count(); ++u) d.push_back({(top.weights.row(u) - z.row(i)).squaredNorm(), u});
    std::stable_sort(d.begin(), d.end(), [](const auto& a, const auto& b) { return a.first < b.first; });
    const int a = d[0].second, b = d[1].second;
    if (std::abs(a / top.cols - b / top.cols) + std::abs(a % top.cols - b % top.cols) != 1) ++errors;
  }
  EXPECT_NEAR(top.te, static_cast<double>(errors) / static_cast<double>(z.rows()), 1e-12);
  EXPECT_EQ(report.unit_count > 0, true);
  EXPECT_GT(report.leaf_qe, 0.0);
  EXPECT_LT(report.leaf_qe,
            top.qe);  // the hierarchy refines the layer-1 quantisation
}

// (d) Same seed ⇒ byte-identical JSON; FromJson(ToJson()) reproduces the model exactly.
TEST(GhsomSerialisation, DeterministicAndExactRoundTrip) {
  const Trained a = TrainClustered(7, ClusterOptions());
  const Trained b = TrainClustered(7, ClusterOptions());
  const std::string dump = a.model.ToJson().dump();
  EXPECT_EQ(dump, b.model.ToJson().dump());
  auto back = Ghsom::FromJson(nlohmann::json::parse(dump));
  ASSERT_TRUE(back.ok()) << back.status().ToString();
  EXPECT_EQ(back->ToJson().dump(), dump);
  ASSERT_EQ(back->maps().size(), a.model.maps().size());
  for (std::size_t m = 0; m < a.model.maps().size(); ++m) {
    EXPECT_TRUE(back->maps()[m].weights == a.model.maps()[m].weights) << "weights of map " << m << " not exact";
    EXPECT_EQ(back->maps()[m].qe, a.model.maps()[m].qe);
  }
  EXPECT_EQ(back->mqe0(), a.model.mqe0());
  for (Eigen::Index i = 0; i < a.z.rows(); i += 37) {
    EXPECT_EQ(back->ConceptPath(a.z.row(i).transpose()), a.model.ConceptPath(a.z.row(i).transpose()));
  }
  // nlohmann writes doubles in shortest round-trip form: awkward values survive dump/parse exactly.
  Rng rng(1);
  for (int i = 0; i < 2000; ++i) {
    const double v = std::ldexp(rng.Uniform(-1, 1), static_cast<int>(rng.UniformIndex(200)) - 100);
    const nlohmann::json j = v;
    EXPECT_EQ(nlohmann::json::parse(j.dump()).get<double>(), v);
  }
  // A different seed changes nothing here (the seed only breaks degenerate initialisations) but is recorded.
  GhsomOptions other = ClusterOptions();
  other.seed = 99;
  auto c = TrainGhsom(a.z, other);
  ASSERT_TRUE(c.ok());
  EXPECT_EQ(c->ToJson()["options"]["seed"], 99);
}

// Concept paths, neighbours, leaf inputs and radii.
TEST(GhsomConcepts, PathsNeighboursAndLeaves) {
  const Trained t = TrainClustered(11, ClusterOptions());
  const Ghsom& g = t.model;
  const Eigen::VectorXd x = t.z.row(5).transpose();
  const auto path = g.ConceptPath(x);
  const auto refs = g.Descend(x);
  ASSERT_EQ(path.size(), refs.size() + 1);
  EXPECT_EQ(path[0], "root");
  EXPECT_EQ(path[1].rfind("m0.u", 0), 0u) << path[1];
  for (std::size_t i = 0; i < refs.size(); ++i) {
    EXPECT_EQ(path[i + 1], Ghsom::ConceptId(refs[i]));
    auto parsed = g.ParseConceptId(path[i + 1]);
    ASSERT_TRUE(parsed.ok());
    EXPECT_EQ(*parsed, refs[i]);
  }
  const GhsomUnitRef leaf = refs.back();
  EXPECT_LT(g.map(leaf.map)->units[static_cast<std::size_t>(leaf.unit)].child_map, 0);
  // The training input descends to the leaf that holds it (batch assignment with the final weights).
  const auto ids = g.InputIds(leaf);
  EXPECT_TRUE(std::find(ids.begin(), ids.end(), 5) != ids.end());
  // Leaf radius: max distance of its inputs to the weight.
  double radius = 0;
  for (std::int64_t id : ids) {
    radius = std::max(radius, (t.z.row(id) - g.map(leaf.map)->weights.row(leaf.unit)).norm());
  }
  EXPECT_DOUBLE_EQ(g.LeafRadius(leaf), std::max(radius, kMinLeafRadius));
  // Every input sits under exactly one leaf.
  std::vector<int> seen(static_cast<std::size_t>(g.input_count()), 0);
  for (const auto& l : g.Leaves()) {
    for (std::int64_t id : g.InputIds(l)) ++seen[static_cast<std::size_t>(id)];
  }
  EXPECT_EQ(std::count(seen.begin(), seen.end(), 1), g.input_count());
  // Grid neighbours on a 2 × 2 map: unit 0 touches 1 and 2, not 3.
  EXPECT_EQ(g.GridNeighbours({0, 0}), (std::vector<int>{1, 2}));
  EXPECT_TRUE(g.GridNeighbours({12345, 0}).empty());
  EXPECT_FALSE(g.ParseConceptId("m999.u0").ok());
  EXPECT_FALSE(g.ParseConceptId("m0.u1x").ok());
  EXPECT_TRUE(g.ConceptPath(Eigen::VectorXd::Zero(kDim + 1)).empty());
}

// (e) A new case lands in its sub-cluster's leaf; a leaf fed past tau2 · mqe_0 gets a new child map.
TEST(GhsomInsert, LandsInRightLeafAndRetrainsLocally) {
  Trained t = TrainClustered(11, ClusterOptions());
  Ghsom& g = t.model;
  // A fresh case at sub-cluster 7's centre: its leaf is dominated by sub-cluster 7.
  const Eigen::VectorXd fresh = *t.standardiser.Apply(t.data.sub_centres[7]);
  GhsomInsertReport report;
  ASSERT_TRUE(g.Insert(fresh, 100000, &report).ok());
  EXPECT_FALSE(report.retrained);
  const GhsomUnitRef leaf = report.path.back();
  const auto ids = g.InputIds(leaf);
  ASSERT_FALSE(ids.empty());
  EXPECT_EQ(ids.back(), 100000);
  std::map<int, int> counts;
  for (std::int64_t id : ids) {
    if (id < static_cast<std::int64_t>(t.data.label.size())) ++counts[t.data.label[static_cast<std::size_t>(id)]];
  }
  EXPECT_EQ(Dominant(counts).first, 7);

  // Feed the leaf points on a shell of radius r around its weight, r below half the distance to any other unit on its
  // path (so they stay in this leaf) but above the depth threshold.
  double nearest_other = std::numeric_limits<double>::infinity();
  for (const auto& ref : report.path) {
    const GhsomMap* m = g.map(ref.map);
    for (int u = 0; u < m->unit_count(); ++u) {
      if (u != ref.unit) nearest_other = std::min(nearest_other, (m->weights.row(u) - m->weights.row(ref.unit)).norm());
    }
  }
  const double r = 0.45 * nearest_other;
  const double threshold = g.options().tau2 * g.mqe0();
  ASSERT_GT(r, 1.2 * threshold) << "the fixture cannot push the leaf past the threshold";
  const Eigen::VectorXd w = g.map(leaf.map)->weights.row(leaf.unit).transpose();
  const int maps_before = static_cast<int>(g.maps().size());
  Rng rng(17);
  bool retrained = false;
  int inserted = 0;
  for (; inserted < 3000 && !retrained; ++inserted) {
    Eigen::VectorXd v(kDim);
    for (int k = 0; k < kDim; ++k) v(k) = rng.Normal();
    const Eigen::VectorXd x = w + r * v.normalized();
    ASSERT_TRUE(g.Insert(x, 200000 + inserted, &report).ok());
    ASSERT_EQ(report.path.back(), leaf) << "shell point left the leaf";
    const auto n = g.InputIds(leaf).size();
    const bool due = report.leaf_mqe >= threshold && n >= static_cast<std::size_t>(g.options().min_inputs_for_child);
    EXPECT_EQ(report.retrained, due) << "insert " << inserted;
    retrained = report.retrained;
  }
  ASSERT_TRUE(retrained) << "leaf mqe never reached tau2 * mqe0";
  ASSERT_FALSE(report.new_maps.empty());
  const GhsomMap* child = g.map(report.new_maps.front());
  ASSERT_NE(child, nullptr);
  EXPECT_EQ(child->parent_map, leaf.map);
  EXPECT_EQ(child->parent_unit, leaf.unit);
  EXPECT_EQ(g.map(leaf.map)->units[static_cast<std::size_t>(leaf.unit)].child_map, child->id);
  EXPECT_EQ(child->input_count, static_cast<int>(g.InputIds(leaf).size()));
  EXPECT_EQ(static_cast<int>(g.maps().size()), maps_before + static_cast<int>(report.new_maps.size()));
  // The leaf is now an inner concept: the fresh case descends one level further, and existing map ids kept.
  EXPECT_GT(g.Descend(fresh).size(), report.path.size());
  EXPECT_EQ(g.maps().front().id, 0);
  // The grown model still serialises and reloads exactly.
  const std::string dump = g.ToJson().dump();
  auto back = Ghsom::FromJson(nlohmann::json::parse(dump));
  ASSERT_TRUE(back.ok()) << back.status().ToString();
  EXPECT_EQ(back->ToJson().dump(), dump);
}

// (f) Bad options and bad input give errors that name the field.
TEST(GhsomErrors, BadOptionsAndInput) {
  auto expect_field = [](const Status& s, const std::string& field) {
    EXPECT_FALSE(s.ok());
    EXPECT_EQ(s.code(), StatusCode::kBadInput);
    EXPECT_NE(s.message().find(field), std::string::npos) << s.message();
  };
  GhsomOptions o;
  o.tau1 = 0;
  expect_field(o.Validate(), "tau1");
  o = {};
  o.tau2 = 1.5;
  expect_field(o.Validate(), "tau2");
  o = {};
  o.min_inputs_for_child = 2;
  expect_field(o.Validate(), "min_inputs_for_child");
  o = {};
  o.max_depth = 0;
  expect_field(o.Validate(), "max_depth");
  o = {};
  o.max_units_per_map = 3;
  expect_field(o.Validate(), "max_units_per_map");
  o = {};
  o.epochs = 0;
  expect_field(o.Validate(), "epochs");
  o = {};
  o.sigma_end_units = 2.0;
  expect_field(o.Validate(), "sigma_end_units");
  o = {};
  o.sigma_start_units = std::nan("");
  expect_field(o.Validate(), "sigma_start_units");
  o = {};
  EXPECT_TRUE(o.Validate().ok());

  expect_field(TrainGhsom(Eigen::MatrixXd::Zero(1, 3), o).status(), "x_standardised");
  Rng rng(2);
  Eigen::MatrixXd x(10, 3);
  for (Eigen::Index i = 0; i < x.size(); ++i) x(i) = rng.Uniform(-1, 1);
  x(4, 2) = std::nan("");
  expect_field(TrainGhsom(x, o).status(), "x_standardised[4][2]");
  x(4, 2) = 0;
  expect_field(TrainGhsom(x, std::vector<std::int64_t>(9, 0), o).status(), "input_ids");
  std::vector<std::int64_t> ids(10);
  for (int i = 0; i < 10; ++i) ids[static_cast<std::size_t>(i)] = i % 9;
  expect_field(TrainGhsom(x, ids, o).status(), "input_ids[9]");
  o.epochs = -1;
  expect_field(TrainGhsom(x, o).status(), "epochs");

  auto g = TrainGhsom(x, GhsomOptions{});
  ASSERT_TRUE(g.ok());
  expect_field(g->Insert(Eigen::VectorXd::Zero(4), 50), "x_std");
  Eigen::VectorXd nan_row = Eigen::VectorXd::Zero(3);
  nan_row(1) = std::numeric_limits<double>::infinity();
  expect_field(g->Insert(nan_row, 50), "x_std[1]");
  expect_field(g->Insert(Eigen::VectorXd::Zero(3), 3), "input_id");
  EXPECT_TRUE(g->Descend(nan_row).empty());

  // FromJson names the broken field.
  const nlohmann::json good = g->ToJson();
  nlohmann::json j = good;
  j["options"].erase("tau2");
  expect_field(Ghsom::FromJson(j).status(), "options.tau2");
  j = good;
  j["maps"][0]["units"][1]["inputs"] = {999};
  expect_field(Ghsom::FromJson(j).status(), "maps[0].units[1].inputs[0]");
  j = good;
  j["maps"][0]["units"][0]["weight"] = {1.0, 2.0};
  expect_field(Ghsom::FromJson(j).status(), "maps[0].units[0].weight");
  j = good;
  j["maps"][0]["units"][0]["child_map"] = 7;
  expect_field(Ghsom::FromJson(j).status(), "child_map");
  j = good;
  j["inputs"][2][0] = "x";
  expect_field(Ghsom::FromJson(j).status(), "inputs[2][0]");
  j = good;
  j["format"] = "other";
  expect_field(Ghsom::FromJson(j).status(), "format");
  EXPECT_TRUE(Ghsom::FromJson(good).ok());
}

// A degenerate input (all rows equal but one) still trains to a valid, finite model.
TEST(GhsomEdgeCases, DegenerateAndOneDimensional) {
  Eigen::MatrixXd x = Eigen::MatrixXd::Zero(30, 4);
  x(0, 0) = 1.0;
  auto g = TrainGhsom(x, GhsomOptions{});
  ASSERT_TRUE(g.ok()) << g.status().ToString();
  for (const auto& m : g->maps()) EXPECT_TRUE(m.weights.allFinite());
  Eigen::MatrixXd line(50, 1);
  for (int i = 0; i < 50; ++i) line(i, 0) = i;
  auto h = TrainGhsom(line, GhsomOptions{});
  ASSERT_TRUE(h.ok()) << h.status().ToString();
  EXPECT_EQ(h->ConceptPath(Eigen::VectorXd::Constant(1, 3.0)).front(), "root");
}

}  // namespace
}  // namespace formloop::retrieval
