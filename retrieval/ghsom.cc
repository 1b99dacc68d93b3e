#include "retrieval/ghsom.h"

#include <Eigen/Eigenvalues>
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <ctime>
#include <deque>
#include <limits>
#include <set>
#include <utility>

#include "core/json_io.h"
#include "core/number_text.h"
#include "core/random.h"

namespace formloop::retrieval {
namespace {

using nlohmann::json;

// An eigenvalue at or below this fraction of the largest counts as "no spread" for initialisation.
constexpr double kDegenerateEigenFraction = 1e-12;
// The largest eigenvalue at or below this (z-score units squared): the parent's inputs coincide.
constexpr double kNoSpread = 1e-24;
// Offset scale when the parent's inputs have no spread at all (z-score units).
constexpr double kDegenerateOffset = 1e-3;

std::string Num(double x) { return FormatSignificant(x, 6); }

Status Bad(const std::string& field, const std::string& what, const std::string& fix = "") {
  return Status::BadInput(Where{.field = field}, "ghsom: " + what, fix);
}

// ---- SOM primitives ----

// Squared distances n × U between rows of x (with squared norms xx) and rows of w.
Eigen::MatrixXd SquaredDistances(const Eigen::MatrixXd& x, const Eigen::VectorXd& xx, const Eigen::MatrixXd& w) {
  Eigen::MatrixXd d2 = -2.0 * (x * w.transpose());
  d2.colwise() += xx;
  d2.rowwise() += w.rowwise().squaredNorm().transpose();
  return d2;
}

// Best and second-best column of a row; ties go to the lowest index. second = −1 with one column.
void BestTwo(const Eigen::MatrixXd& d2, Eigen::Index row, int* best, int* second) {
  double b1 = std::numeric_limits<double>::infinity(), b2 = b1;
  int i1 = -1, i2 = -1;
  for (Eigen::Index u = 0; u < d2.cols(); ++u) {
    const double v = d2(row, u);
    if (v < b1 || i1 < 0) {
      b2 = b1;
      i2 = i1;
      b1 = v;
      i1 = static_cast<int>(u);
    } else if (v < b2 || i2 < 0) {
      b2 = v;
      i2 = static_cast<int>(u);
    }
  }
  *best = std::max(i1, 0);
  *second = i2;
}

bool GridAdjacent(int a, int b, int cols) {
  const int ra = a / cols, ca = a % cols, rb = b / cols, cb = b % cols;
  return std::abs(ra - rb) + std::abs(ca - cb) == 1;
}

std::vector<int> NeighboursOf(int u, int rows, int cols) {
  std::vector<int> out;
  const int r = u / cols, c = u % cols;
  if (r > 0) out.push_back(u - cols);
  if (c > 0) out.push_back(u - 1);
  if (c + 1 < cols) out.push_back(u + 1);
  if (r + 1 < rows) out.push_back(u + cols);
  return out;
}

// Batch SOM (see the header): `epochs` passes from the current weights.
void TrainSom(const Eigen::MatrixXd& x, const Eigen::VectorXd& xx, int rows, int cols, const GhsomOptions& options,
              Eigen::MatrixXd* w) {
  const int units = rows * cols;
  const Eigen::Index dim = x.cols();
  Eigen::MatrixXd grid2(units, units);  // squared grid distances
  for (int a = 0; a < units; ++a) {
    for (int b = 0; b < units; ++b) {
      const double dr = a / cols - b / cols, dc = a % cols - b % cols;
      grid2(a, b) = dr * dr + dc * dc;
    }
  }
  Eigen::MatrixXd sums(units, dim);
  Eigen::VectorXd counts(units);
  for (int epoch = 0; epoch < options.epochs; ++epoch) {
    const double t = options.epochs == 1 ? 1.0 : static_cast<double>(epoch) / (options.epochs - 1);
    const double sigma = options.sigma_start_units * std::pow(options.sigma_end_units / options.sigma_start_units, t);
    const Eigen::MatrixXd d2 = SquaredDistances(x, xx, *w);
    sums.setZero();
    counts.setZero();
    for (Eigen::Index j = 0; j < x.rows(); ++j) {
      Eigen::Index best = 0;
      d2.row(j).minCoeff(&best);  // first minimum: ties go to the lowest index
      sums.row(best) += x.row(j);
      counts(best) += 1.0;
    }
    const Eigen::MatrixXd h = (-grid2.array() / (2.0 * sigma * sigma)).exp().matrix();
    const Eigen::MatrixXd numerator = h * sums;
    const Eigen::VectorXd denominator = h * counts;
    for (int k = 0; k < units; ++k) {
      if (denominator(k) > 0) w->row(k) = numerator.row(k) / denominator(k);
    }
  }
}

// Fixes an eigenvector's sign: the largest-magnitude component (lowest index on ties) is positive.
Eigen::VectorXd FixSign(Eigen::VectorXd v) {
  Eigen::Index k = 0;
  v.cwiseAbs().maxCoeff(&k);
  if (v(k) < 0) v = -v;
  return v;
}

Eigen::VectorXd RandomUnitOrthogonal(Rng* rng, Eigen::Index dim, const Eigen::VectorXd* against) {
  for (int attempt = 0; attempt < 16; ++attempt) {
    Eigen::VectorXd v(dim);
    for (Eigen::Index k = 0; k < dim; ++k) v(k) = rng->Normal();
    if (against != nullptr) v -= v.dot(*against) * *against;
    const double n = v.norm();
    if (n > 1e-9) return v / n;
  }
  return Eigen::VectorXd::Zero(dim);  // dim 1 and an orthogonal direction was asked for
}

// Initial 2 × 2 weights around the parent weight (see the header).
Eigen::MatrixXd InitialWeights(const Eigen::MatrixXd& x, const Eigen::VectorXd& parent_weight,
                               const GhsomOptions& options, int map_id) {
  const Eigen::Index dim = x.cols();
  const Eigen::RowVectorXd mean = x.colwise().mean();
  const Eigen::MatrixXd centred = x.rowwise() - mean;
  const Eigen::MatrixXd covariance = (centred.transpose() * centred) / static_cast<double>(x.rows());
  Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd> solver(covariance);
  const Eigen::VectorXd& values = solver.eigenvalues();  // ascending
  const double l1 = std::max(0.0, values(dim - 1));
  const double l2 = dim >= 2 ? std::max(0.0, values(dim - 2)) : 0.0;
  Rng rng(options.seed ^ static_cast<std::uint64_t>(map_id));
  Eigen::VectorXd v1, v2;
  double s1 = 0, s2 = 0;
  if (l1 > kNoSpread) {
    v1 = FixSign(solver.eigenvectors().col(dim - 1));
    s1 = std::sqrt(l1);
  } else {
    v1 = RandomUnitOrthogonal(&rng, dim, nullptr);
    s1 = kDegenerateOffset;
  }
  if (dim >= 2 && l1 > kNoSpread && l2 > kDegenerateEigenFraction * l1) {
    v2 = FixSign(solver.eigenvectors().col(dim - 2));
    s2 = std::sqrt(l2);
  } else {
    v2 = RandomUnitOrthogonal(&rng, dim, &v1);
    s2 = s1;
  }
  Eigen::MatrixXd w(4, dim);
  for (int r = 0; r < 2; ++r) {
    for (int c = 0; c < 2; ++c) {
      w.row(r * 2 + c) =
          (parent_weight + options.init_offset * ((2.0 * c - 1.0) * s1 * v1 + (2.0 * r - 1.0) * s2 * v2)).transpose();
    }
  }
  return w;
}

// Assigns x (rows `rows` of the model's inputs) to the map's units and fills the unit and map statistics (everything
// but id, parents, depth, mqe_parent, insertions and child links).
void ComputeStats(const Eigen::MatrixXd& x, const Eigen::VectorXd& xx, const std::vector<int>& rows, GhsomMap* map) {
  const int units = map->unit_count();
  std::vector<GhsomUnit> fresh(static_cast<std::size_t>(units));
  for (int u = 0; u < units && u < static_cast<int>(map->units.size()); ++u) {
    fresh[static_cast<std::size_t>(u)].child_map = map->units[static_cast<std::size_t>(u)].child_map;
  }
  const Eigen::MatrixXd d2 = SquaredDistances(x, xx, map->weights);
  std::vector<double> sum(static_cast<std::size_t>(units), 0.0), peak(static_cast<std::size_t>(units), 0.0);
  double total = 0;
  int errors = 0;
  for (Eigen::Index j = 0; j < x.rows(); ++j) {
    int best = 0, second = -1;
    BestTwo(d2, j, &best, &second);
    const double d = (x.row(j) - map->weights.row(best)).norm();
    auto& unit = fresh[static_cast<std::size_t>(best)];
    unit.inputs.push_back(rows[static_cast<std::size_t>(j)]);
    sum[static_cast<std::size_t>(best)] += d;
    peak[static_cast<std::size_t>(best)] = std::max(peak[static_cast<std::size_t>(best)], d);
    total += d;
    if (second >= 0 && !GridAdjacent(best, second, map->cols)) ++errors;
  }
  double mqe_sum = 0;
  int occupied = 0;
  for (int u = 0; u < units; ++u) {
    auto& unit = fresh[static_cast<std::size_t>(u)];
    const auto n = static_cast<double>(unit.inputs.size());
    unit.mqe = unit.inputs.empty() ? 0.0 : sum[static_cast<std::size_t>(u)] / n;
    unit.radius = std::max(kMinLeafRadius, peak[static_cast<std::size_t>(u)]);
    if (!unit.inputs.empty()) {
      mqe_sum += unit.mqe;
      ++occupied;
    }
  }
  map->units = std::move(fresh);
  map->mqe = occupied > 0 ? mqe_sum / occupied : 0.0;
  map->input_count = static_cast<int>(x.rows());
  map->qe = x.rows() > 0 ? total / static_cast<double>(x.rows()) : 0.0;
  map->topographic_errors = errors;
  map->te = x.rows() > 0 ? static_cast<double>(errors) / static_cast<double>(x.rows()) : 0.0;
}

// Inserts a row or column between units e and d (4-neighbours); new weights are the means across.
void InsertBetween(int e, int d, GhsomMap* map) {
  const int rows = map->rows, cols = map->cols;
  const Eigen::Index dim = map->weights.cols();
  const int re = e / cols, ce = e % cols, rd = d / cols, cd = d % cols;
  Eigen::MatrixXd w;
  if (re == rd) {  // same row: a new column after min(ce, cd)
    const int at = std::min(ce, cd) + 1;
    w.resize(rows * (cols + 1), dim);
    for (int r = 0; r < rows; ++r) {
      for (int c = 0; c <= cols; ++c) {
        const int dst = r * (cols + 1) + c;
        if (c < at) {
          w.row(dst) = map->weights.row(r * cols + c);
        } else if (c == at) {
          w.row(dst) = 0.5 * (map->weights.row(r * cols + at - 1) + map->weights.row(r * cols + at));
        } else {
          w.row(dst) = map->weights.row(r * cols + c - 1);
        }
      }
    }
    map->cols = cols + 1;
  } else {  // same column: a new row after min(re, rd)
    const int at = std::min(re, rd) + 1;
    w.resize((rows + 1) * cols, dim);
    for (int r = 0; r <= rows; ++r) {
      for (int c = 0; c < cols; ++c) {
        const int dst = r * cols + c;
        if (r < at) {
          w.row(dst) = map->weights.row(r * cols + c);
        } else if (r == at) {
          w.row(dst) = 0.5 * (map->weights.row((at - 1) * cols + c) + map->weights.row(at * cols + c));
        } else {
          w.row(dst) = map->weights.row((r - 1) * cols + c);
        }
      }
    }
    map->rows = rows + 1;
  }
  map->weights = std::move(w);
}

Status CheckFiniteRow(const Eigen::VectorXd& x, int expected_dim, const std::string& what) {
  if (x.size() != expected_dim) {
    return Bad(what,
               "the vector has " + std::to_string(x.size()) + " components, the model " + std::to_string(expected_dim),
               "standardise the query with the model's Standardiser");
  }
  for (Eigen::Index k = 0; k < x.size(); ++k) {
    if (!std::isfinite(x(k))) {
      return Bad(what + "[" + std::to_string(k) + "]", "component is not finite (" + Num(x(k)) + ")",
                 "give finite features");
    }
  }
  return Status::Ok();
}

Status CheckMatrix(const Eigen::MatrixXd& x, const std::string& what) {
  if (x.rows() < 2) {
    return Bad(what, "needs at least 2 rows (cases), got " + std::to_string(x.rows()), "pass one case per row, N >= 2");
  }
  if (x.cols() < 1) return Bad(what, "needs at least 1 column (feature), got 0");
  for (Eigen::Index i = 0; i < x.rows(); ++i) {
    for (Eigen::Index k = 0; k < x.cols(); ++k) {
      if (!std::isfinite(x(i, k))) {
        return Bad(what + "[" + std::to_string(i) + "][" + std::to_string(k) + "]",
                   "value is not finite (" + Num(x(i, k)) + ")", "remove or repair the case");
      }
    }
  }
  return Status::Ok();
}

double CpuSeconds() { return static_cast<double>(std::clock()) / CLOCKS_PER_SEC; }

}  // namespace

// ---------------------------------------------------------------------------------------------
// Standardiser

Result<Standardiser> Standardiser::Fit(const Eigen::MatrixXd& x) {
  FL_RETURN_IF_ERROR(CheckMatrix(x, "x").WithContext("standardiser"));
  Standardiser s;
  s.mean = x.colwise().mean().transpose();
  s.std.resize(x.cols());
  for (Eigen::Index k = 0; k < x.cols(); ++k) {
    const double var = (x.col(k).array() - s.mean(k)).square().sum() / static_cast<double>(x.rows() - 1);
    const double sd = std::sqrt(var);
    if (!(sd > 1e-12 * std::max(1.0, std::abs(s.mean(k))))) {
      s.std(k) = 1.0;
      s.constant_components.push_back(static_cast<int>(k));
    } else {
      s.std(k) = sd;
    }
  }
  return s;
}

Result<Eigen::MatrixXd> Standardiser::ApplyRows(const Eigen::MatrixXd& x) const {
  if (x.cols() != mean.size()) {
    return Bad(
        "x",
        "standardiser: " + std::to_string(x.cols()) + " columns, the standardiser has " + std::to_string(mean.size()),
        "pass the same features the standardiser was fitted on");
  }
  Eigen::MatrixXd z = x.rowwise() - mean.transpose();
  z.array().rowwise() /= std.transpose().array();
  return z;
}

Result<Eigen::VectorXd> Standardiser::Apply(const Eigen::VectorXd& x) const {
  if (x.size() != mean.size()) {
    return Bad("x",
               "standardiser: " + std::to_string(x.size()) + " components, the standardiser has " +
                   std::to_string(mean.size()),
               "pass the same features the standardiser was fitted on");
  }
  return Eigen::VectorXd((x - mean).array() / std.array());
}

// ---------------------------------------------------------------------------------------------
// Training

class GhsomBuilder {
 public:
  // Gathers rows of the model's inputs into a matrix.
  static Eigen::MatrixXd Gather(const Ghsom& g, const std::vector<int>& rows) {
    const auto dim = static_cast<Eigen::Index>(g.dimension());
    Eigen::MatrixXd x(static_cast<Eigen::Index>(rows.size()), dim);
    for (std::size_t i = 0; i < rows.size(); ++i) {
      x.row(static_cast<Eigen::Index>(i)) =
          Eigen::Map<const Eigen::RowVectorXd>(g.data_.data() + static_cast<std::size_t>(rows[i]) * dim, dim);
    }
    return x;
  }

  static GhsomMap* MutableMap(Ghsom* g, int id) {
    const auto it =
        std::lower_bound(g->maps_.begin(), g->maps_.end(), id, [](const GhsomMap& m, int key) { return m.id < key; });
    return it != g->maps_.end() && it->id == id ? &*it : nullptr;
  }

  // Builds the subtree below (parent_map, parent_unit) on `rows`, breadth first. new_maps receives the ids created;
  // report (optional) one row per map.
  static void BuildSubtree(Ghsom* g, int parent_map, int parent_unit, const std::vector<int>& rows, int depth,
                           double mqe_parent, const Eigen::VectorXd& parent_weight, std::vector<int>* new_maps,
                           GhsomReport* report) {
    struct Job {
      int parent_map, parent_unit, depth;
      std::vector<int> rows;
      double mqe_parent;
      Eigen::VectorXd parent_weight;
    };
    const GhsomOptions& o = g->options_;
    const double depth_threshold = o.tau2 * g->mqe0_;
    std::deque<Job> queue;
    queue.push_back({parent_map, parent_unit, depth, rows, mqe_parent, parent_weight});
    while (!queue.empty()) {
      Job job = std::move(queue.front());
      queue.pop_front();
      const auto start = std::chrono::steady_clock::now();
      GhsomMap map;
      map.id = g->next_map_id_++;
      map.parent_map = job.parent_map;
      map.parent_unit = job.parent_unit;
      map.depth = job.depth;
      map.mqe_parent = job.mqe_parent;
      map.rows = map.cols = 2;
      const Eigen::MatrixXd x = Gather(*g, job.rows);
      const Eigen::VectorXd xx = x.rowwise().squaredNorm();
      map.weights = InitialWeights(x, job.parent_weight, o, map.id);
      TrainSom(x, xx, map.rows, map.cols, o, &map.weights);
      ComputeStats(x, xx, job.rows, &map);
      bool unit_cap_reached = false;
      while (map.mqe >= o.tau1 * map.mqe_parent && map.mqe > 0) {
        int e = 0;
        for (int u = 1; u < map.unit_count(); ++u) {
          if (map.units[static_cast<std::size_t>(u)].mqe > map.units[static_cast<std::size_t>(e)].mqe) e = u;
        }
        int d = -1;
        double far = -1;
        for (int n : NeighboursOf(e, map.rows, map.cols)) {
          const double dist = (map.weights.row(e) - map.weights.row(n)).norm();
          if (dist > far || (dist == far && n < d)) {
            far = dist;
            d = n;
          }
        }
        const bool column = e / map.cols == d / map.cols;
        const int grown = column ? map.rows * (map.cols + 1) : (map.rows + 1) * map.cols;
        if (grown > o.max_units_per_map) {
          unit_cap_reached = true;
          break;
        }
        InsertBetween(e, d, &map);
        ++map.insertions;
        TrainSom(x, xx, map.rows, map.cols, o, &map.weights);
        ComputeStats(x, xx, job.rows, &map);
      }
      if (map.depth < o.max_depth) {
        for (int u = 0; u < map.unit_count(); ++u) {
          const GhsomUnit& unit = map.units[static_cast<std::size_t>(u)];
          if (unit.mqe > 0 && unit.mqe >= depth_threshold &&
              static_cast<int>(unit.inputs.size()) >= o.min_inputs_for_child) {
            queue.push_back({map.id, u, map.depth + 1, unit.inputs, unit.mqe, map.weights.row(u).transpose()});
          }
        }
      }
      if (map.parent_map >= 0) {
        MutableMap(g, map.parent_map)->units[static_cast<std::size_t>(map.parent_unit)].child_map = map.id;
      }
      const double seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
      if (report != nullptr) {
        report->maps.push_back({.id = map.id,
                                .depth = map.depth,
                                .rows = map.rows,
                                .cols = map.cols,
                                .inputs = map.input_count,
                                .insertions = map.insertions,
                                .mqe = map.mqe,
                                .qe = map.qe,
                                .te = map.te,
                                .training_time_s = seconds,
                                .unit_cap_reached = unit_cap_reached});
      }
      if (new_maps != nullptr) new_maps->push_back(map.id);
      g->maps_.push_back(std::move(map));
    }
  }

  // The model before any map: options, w_0, mqe_0, inputs and ids.
  static Ghsom Start(const Eigen::MatrixXd& x_standardised, const std::vector<std::int64_t>& input_ids,
                     const GhsomOptions& options) {
    Ghsom g;
    g.options_ = options;
    const Eigen::Index n = x_standardised.rows(), dim = x_standardised.cols();
    g.mean0_ = x_standardised.colwise().mean().transpose();
    g.mqe0_ = (x_standardised.rowwise() - g.mean0_.transpose()).rowwise().norm().mean();
    g.data_.resize(static_cast<std::size_t>(n * dim));
    for (Eigen::Index i = 0; i < n; ++i) {
      for (Eigen::Index k = 0; k < dim; ++k) g.data_[static_cast<std::size_t>(i * dim + k)] = x_standardised(i, k);
    }
    g.ids_ = input_ids;
    return g;
  }

  static void Summarise(const Ghsom& g, GhsomReport* report) {
    report->unit_count = 0;
    report->max_depth = 0;
    for (const auto& m : g.maps_) {
      report->unit_count += m.unit_count();
      report->max_depth = std::max(report->max_depth, m.depth);
    }
    report->leaf_count = static_cast<int>(g.Leaves().size());
    report->leaf_qe = g.LeafQe();
  }
};

Result<Ghsom> TrainGhsom(const Eigen::MatrixXd& x_standardised, const GhsomOptions& options, GhsomReport* report) {
  std::vector<std::int64_t> ids(static_cast<std::size_t>(std::max<Eigen::Index>(0, x_standardised.rows())));
  for (std::size_t i = 0; i < ids.size(); ++i) ids[i] = static_cast<std::int64_t>(i);
  return TrainGhsom(x_standardised, ids, options, report);
}

Result<Ghsom> TrainGhsom(const Eigen::MatrixXd& x_standardised, const std::vector<std::int64_t>& input_ids,
                         const GhsomOptions& options, GhsomReport* report) {
  const auto wall_start = std::chrono::steady_clock::now();
  const double cpu_start = CpuSeconds();
  FL_RETURN_IF_ERROR(options.Validate());
  FL_RETURN_IF_ERROR(CheckMatrix(x_standardised, "x_standardised"));
  if (input_ids.size() != static_cast<std::size_t>(x_standardised.rows())) {
    return Bad("input_ids",
               std::to_string(input_ids.size()) + " ids for " + std::to_string(x_standardised.rows()) + " rows",
               "give one id per row");
  }
  {
    std::set<std::int64_t> seen;
    for (std::size_t i = 0; i < input_ids.size(); ++i) {
      if (!seen.insert(input_ids[i]).second) {
        return Bad("input_ids[" + std::to_string(i) + "]", "id " + std::to_string(input_ids[i]) + " repeats",
                   "give each case its own id");
      }
    }
  }
  Ghsom g = GhsomBuilder::Start(x_standardised, input_ids, options);
  std::vector<int> rows(static_cast<std::size_t>(x_standardised.rows()));
  for (std::size_t i = 0; i < rows.size(); ++i) rows[i] = static_cast<int>(i);
  GhsomReport local;
  GhsomBuilder::BuildSubtree(&g, -1, -1, rows, 1, g.mqe0(), g.root_weight(), nullptr, &local);
  if (report != nullptr) {
    GhsomBuilder::Summarise(g, &local);
    local.wall_time_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - wall_start).count();
    local.cpu_time_s = CpuSeconds() - cpu_start;
    *report = std::move(local);
  }
  return g;
}

// ---------------------------------------------------------------------------------------------
// Queries

const GhsomMap* Ghsom::map(int id) const {
  const auto it =
      std::lower_bound(maps_.begin(), maps_.end(), id, [](const GhsomMap& m, int key) { return m.id < key; });
  return it != maps_.end() && it->id == id ? &*it : nullptr;
}

Eigen::VectorXd Ghsom::input(int row) const {
  const auto dim = static_cast<Eigen::Index>(dimension());
  return Eigen::Map<const Eigen::VectorXd>(data_.data() + static_cast<std::size_t>(row) * dim, dim);
}

std::string Ghsom::ConceptId(const GhsomUnitRef& ref) {
  if (ref.map < 0) return "root";
  return "m" + std::to_string(ref.map) + ".u" + std::to_string(ref.unit);
}

Result<GhsomUnitRef> Ghsom::ParseConceptId(const std::string& id) const {
  if (id == "root") return GhsomUnitRef{};
  int m = -1, u = -1;
  char tail = 0;
  if (std::sscanf(id.c_str(), "m%d.u%d%c", &m, &u, &tail) != 2 || ConceptId({m, u}) != id) {
    return Bad("concept", "'" + id + "' is not a concept id", "write m<map>.u<unit> such as m3.u5, or root");
  }
  const GhsomMap* found = map(m);
  if (found == nullptr || u < 0 || u >= found->unit_count()) {
    return Status::NotFound("ghsom: concept '" + id + "' is not in this model");
  }
  return GhsomUnitRef{m, u};
}

std::vector<GhsomUnitRef> Ghsom::Descend(const Eigen::VectorXd& x_std) const {
  std::vector<GhsomUnitRef> path;
  if (maps_.empty() || x_std.size() != mean0_.size() || !x_std.allFinite()) return path;
  const GhsomMap* m = &maps_.front();
  while (m != nullptr) {
    int best = 0;
    double best_d2 = std::numeric_limits<double>::infinity();
    for (int u = 0; u < m->unit_count(); ++u) {
      const double d2 = (m->weights.row(u).transpose() - x_std).squaredNorm();
      if (d2 < best_d2) {
        best_d2 = d2;
        best = u;
      }
    }
    path.push_back({m->id, best});
    const int child = m->units[static_cast<std::size_t>(best)].child_map;
    m = child >= 0 ? map(child) : nullptr;
  }
  return path;
}

std::vector<std::string> Ghsom::ConceptPath(const Eigen::VectorXd& x_std) const {
  const std::vector<GhsomUnitRef> path = Descend(x_std);
  std::vector<std::string> out;
  if (path.empty()) return out;
  out.reserve(path.size() + 1);
  out.emplace_back("root");
  for (const auto& ref : path) out.push_back(ConceptId(ref));
  return out;
}

std::vector<int> Ghsom::GridNeighbours(const GhsomUnitRef& ref) const {
  const GhsomMap* m = map(ref.map);
  if (m == nullptr || ref.unit < 0 || ref.unit >= m->unit_count()) return {};
  return NeighboursOf(ref.unit, m->rows, m->cols);
}

std::vector<std::int64_t> Ghsom::InputIds(const GhsomUnitRef& ref) const {
  std::vector<std::int64_t> out;
  const GhsomMap* m = map(ref.map);
  if (m == nullptr || ref.unit < 0 || ref.unit >= m->unit_count()) return out;
  for (int row : m->units[static_cast<std::size_t>(ref.unit)].inputs)
    out.push_back(ids_[static_cast<std::size_t>(row)]);
  return out;
}

double Ghsom::LeafRadius(const GhsomUnitRef& ref) const {
  const GhsomMap* m = map(ref.map);
  if (m == nullptr || ref.unit < 0 || ref.unit >= m->unit_count()) return kMinLeafRadius;
  return m->units[static_cast<std::size_t>(ref.unit)].radius;
}

std::vector<GhsomUnitRef> Ghsom::Leaves() const {
  std::vector<GhsomUnitRef> out;
  for (const auto& m : maps_) {
    for (int u = 0; u < m.unit_count(); ++u) {
      if (m.units[static_cast<std::size_t>(u)].child_map < 0) out.push_back({m.id, u});
    }
  }
  return out;
}

double Ghsom::LeafQe() const {
  double total = 0;
  long count = 0;
  for (const auto& m : maps_) {
    for (int u = 0; u < m.unit_count(); ++u) {
      const GhsomUnit& unit = m.units[static_cast<std::size_t>(u)];
      if (unit.child_map >= 0) continue;
      total += unit.mqe * static_cast<double>(unit.inputs.size());
      count += static_cast<long>(unit.inputs.size());
    }
  }
  return count > 0 ? total / static_cast<double>(count) : 0.0;
}

// ---------------------------------------------------------------------------------------------
// Insertion

Status Ghsom::Insert(const Eigen::VectorXd& x_std, std::int64_t input_id, GhsomInsertReport* report) {
  if (maps_.empty()) return Status::BadInput("ghsom: insert into an empty model; train it first");
  FL_RETURN_IF_ERROR(CheckFiniteRow(x_std, dimension(), "x_std").WithContext("insert"));
  if (std::find(ids_.begin(), ids_.end(), input_id) != ids_.end()) {
    return Bad("input_id", "insert: id " + std::to_string(input_id) + " is already in the model",
               "give the new case its own id");
  }
  const std::vector<GhsomUnitRef> path = Descend(x_std);
  const int row = input_count();
  data_.insert(data_.end(), x_std.data(), x_std.data() + x_std.size());
  ids_.push_back(input_id);
  for (const auto& ref : path) {
    GhsomMap& m = *GhsomBuilder::MutableMap(this, ref.map);
    GhsomUnit& unit = m.units[static_cast<std::size_t>(ref.unit)];
    const double d = (m.weights.row(ref.unit).transpose() - x_std).norm();
    const auto n = static_cast<double>(unit.inputs.size());
    unit.mqe = (unit.mqe * n + d) / (n + 1.0);
    unit.radius = std::max(unit.radius, d);
    unit.inputs.push_back(row);
    // Second-best unit for the topographic error of this input.
    int second = -1;
    double second_d2 = std::numeric_limits<double>::infinity();
    for (int u = 0; u < m.unit_count(); ++u) {
      if (u == ref.unit) continue;
      const double d2 = (m.weights.row(u).transpose() - x_std).squaredNorm();
      if (d2 < second_d2) {
        second_d2 = d2;
        second = u;
      }
    }
    if (second >= 0 && !GridAdjacent(ref.unit, second, m.cols)) ++m.topographic_errors;
    m.qe = (m.qe * m.input_count + d) / (m.input_count + 1.0);
    ++m.input_count;
    m.te = static_cast<double>(m.topographic_errors) / m.input_count;
    double mqe_sum = 0;
    int occupied = 0;
    for (const auto& other : m.units) {
      if (other.inputs.empty()) continue;
      mqe_sum += other.mqe;
      ++occupied;
    }
    m.mqe = occupied > 0 ? mqe_sum / occupied : 0.0;
  }
  const GhsomUnitRef leaf = path.back();
  const GhsomMap& leaf_map = *map(leaf.map);
  const GhsomUnit& leaf_unit = leaf_map.units[static_cast<std::size_t>(leaf.unit)];
  const double threshold = options_.tau2 * mqe0_;
  GhsomInsertReport local{.path = path, .leaf_mqe = leaf_unit.mqe, .threshold = threshold};
  if (leaf_map.depth < options_.max_depth && leaf_unit.mqe > 0 && leaf_unit.mqe >= threshold &&
      static_cast<int>(leaf_unit.inputs.size()) >= options_.min_inputs_for_child) {
    const std::vector<int> rows = leaf_unit.inputs;
    const Eigen::VectorXd weight = leaf_map.weights.row(leaf.unit).transpose();
    const double mqe = leaf_unit.mqe;
    const int depth = leaf_map.depth + 1;
    GhsomBuilder::BuildSubtree(this, leaf.map, leaf.unit, rows, depth, mqe, weight, &local.new_maps, nullptr);
    local.retrained = true;
  }
  if (report != nullptr) *report = std::move(local);
  return Status::Ok();
}

}  // namespace formloop::retrieval
