#include "metrology/spatial_weights.h"

#include <algorithm>
#include <fstream>
#include <map>
#include <sstream>

#include <pcl/kdtree/kdtree_flann.h>
#include <pcl/point_types.h>

namespace formloop::metrology {

Result<SpatialWeights> WeightsFromNeighbours(const std::vector<std::vector<int>>& neighbours, WeightStyle style) {
  const int n = static_cast<int>(neighbours.size());
  std::vector<Eigen::Triplet<double>> triplets;
  SpatialWeights result;
  result.style = style;
  for (int i = 0; i < n; ++i) {
    std::vector<int> row = neighbours[static_cast<std::size_t>(i)];
    std::sort(row.begin(), row.end());
    row.erase(std::unique(row.begin(), row.end()), row.end());
    row.erase(std::remove(row.begin(), row.end(), i), row.end());
    if (row.empty()) {
      ++result.islands;
      continue;
    }
    const double value = style == WeightStyle::kBinary ? 1.0 : 1.0 / static_cast<double>(row.size());
    for (int j : row) {
      if (j < 0 || j >= n) return Status::Internal("neighbour index " + std::to_string(j) + " out of range");
      triplets.emplace_back(i, j, value);
    }
  }
  result.w.resize(n, n);
  result.w.setFromTriplets(triplets.begin(), triplets.end());
  result.w.makeCompressed();
  return result;
}

Result<SpatialWeights> KnnWeights(const Eigen::MatrixXd& points, int k, WeightStyle style) {
  const int n = static_cast<int>(points.cols());
  if (points.rows() != 2 && points.rows() != 3) return Status::Internal("KnnWeights: points must be 2 × n or 3 × n");
  if (k < 1) return Status::BadInput(Where{.field = "k"}, "needs at least one neighbour", "use k >= 1 (default 8)");
  if (n <= k) {
    return Status::BadInput(Where{.field = "k"},
                            std::to_string(n) + " points cannot each have " + std::to_string(k) + " neighbours",
                            "use fewer neighbours or more points");
  }
  // Centre the coordinates: FLANN works in float.
  const Eigen::VectorXd centre = points.rowwise().mean();
  pcl::PointCloud<pcl::PointXYZ>::Ptr cloud(new pcl::PointCloud<pcl::PointXYZ>);
  cloud->resize(static_cast<std::size_t>(n));
  for (int i = 0; i < n; ++i) {
    const Eigen::VectorXd p = points.col(i) - centre;
    (*cloud)[static_cast<std::size_t>(i)] =
        pcl::PointXYZ(static_cast<float>(p[0]), static_cast<float>(p[1]), points.rows() == 3 ? static_cast<float>(p[2]) : 0.f);
  }
  pcl::KdTreeFLANN<pcl::PointXYZ> tree;
  tree.setSortedResults(true);
  tree.setInputCloud(cloud);
  std::vector<std::vector<int>> neighbours(static_cast<std::size_t>(n));
  const int query = std::min(n, k + 4);  // a few spare for self and ties
  pcl::Indices found;
  std::vector<float> unused;
  for (int i = 0; i < n; ++i) {
    tree.nearestKSearch(static_cast<pcl::index_t>(i), query, found, unused);
    // Exact double distances, ties broken by index: deterministic whatever FLANN returned first.
    std::vector<std::pair<double, int>> candidates;
    for (const auto j : found) {
      if (j == i) continue;
      candidates.emplace_back((points.col(j) - points.col(i)).squaredNorm(), static_cast<int>(j));
    }
    std::sort(candidates.begin(), candidates.end());
    for (int m = 0; m < k && m < static_cast<int>(candidates.size()); ++m) {
      neighbours[static_cast<std::size_t>(i)].push_back(candidates[static_cast<std::size_t>(m)].second);
    }
  }
  return WeightsFromNeighbours(neighbours, style);
}

Result<SpatialWeights> ReadGal(const std::filesystem::path& path, const std::vector<std::string>& ids,
                               WeightStyle style) {
  std::ifstream in(path);
  const std::string file = path.string();
  if (!in) return Status::NotFound("GAL file '" + file + "' cannot be opened. Check the path");
  std::map<std::string, int> index;
  for (std::size_t i = 0; i < ids.size(); ++i) index[ids[i]] = static_cast<int>(i);
  std::string line;
  long line_no = 0;
  auto next_line = [&](std::vector<std::string>* tokens) {
    while (std::getline(in, line)) {
      ++line_no;
      std::istringstream ss(line);
      tokens->clear();
      std::string t;
      while (ss >> t) tokens->push_back(t);
      if (!tokens->empty()) return true;
    }
    return false;
  };
  std::vector<std::string> tokens;
  if (!next_line(&tokens)) return Status::BadInput(Where{.file = file}, "the file is empty", "write a GAL file");
  const std::string count_text = tokens.size() >= 2 ? tokens[1] : tokens[0];
  long n = 0;
  try {
    n = std::stol(count_text);
  } catch (...) {
    return Status::BadInput(Where{.file = file, .line = line_no}, "first line does not give the number of units");
  }
  if (n != static_cast<long>(ids.size())) {
    return Status::BadInput(Where{.file = file, .line = line_no},
                            "GAL has " + std::to_string(n) + " units, the data " + std::to_string(ids.size()),
                            "pair data and weights from the same source");
  }
  std::vector<std::vector<int>> neighbours(ids.size());
  for (long unit = 0; unit < n; ++unit) {
    if (!next_line(&tokens) || tokens.size() != 2) {
      return Status::BadInput(Where{.file = file, .line = line_no}, "expected 'id count'", "check the GAL file");
    }
    auto it = index.find(tokens[0]);
    if (it == index.end()) {
      return Status::BadInput(Where{.file = file, .line = line_no}, "id '" + tokens[0] + "' is not in the data");
    }
    const int count = std::stoi(tokens[1]);
    std::vector<std::string> list;
    if (count > 0 && !next_line(&list)) {
      return Status::BadInput(Where{.file = file, .line = line_no}, "neighbour list missing");
    }
    if (static_cast<int>(list.size()) != count) {
      return Status::BadInput(Where{.file = file, .line = line_no},
                              "expected " + std::to_string(count) + " neighbour ids, found " + std::to_string(list.size()));
    }
    for (const auto& id : list) {
      auto jt = index.find(id);
      if (jt == index.end()) {
        return Status::BadInput(Where{.file = file, .line = line_no}, "neighbour id '" + id + "' is not in the data");
      }
      neighbours[static_cast<std::size_t>(it->second)].push_back(jt->second);
    }
  }
  return WeightsFromNeighbours(neighbours, style);
}

}  // namespace formloop::metrology
