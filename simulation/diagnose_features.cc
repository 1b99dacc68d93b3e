// Feature positions (`diagnose --features`): nominal and measured positions of holes, bosses or
// datums, each coordinate an observation, screened with the effects that act on positions.

#include <cmath>
#include <fstream>
#include <map>

#include "core/csv.h"
#include "core/number_text.h"
#include "simulation/diagnose.h"
#include "simulation/diagnose_engine.h"

namespace formloop::sim {

Result<std::vector<FeaturePosition>> ReadFeatures(const std::string& path) {
  std::ifstream in(path);
  if (!in) return Status::NotFound("cannot open feature file '" + path + "'");
  std::string line;
  long line_no = 0;
  std::vector<std::string> header;
  std::vector<FeaturePosition> out;
  auto split = [](const std::string& s) {  // core's CSV cell rules, as owned strings
    std::vector<std::string_view> views;
    SplitCsvCells(s, &views);
    return std::vector<std::string>(views.begin(), views.end());
  };
  std::map<std::string, int> col;
  while (std::getline(in, line)) {
    ++line_no;
    if (line.empty() || line[0] == '#') continue;
    const auto cells = split(line);
    if (col.empty()) {
      for (std::size_t i = 0; i < cells.size(); ++i) col[cells[i]] = static_cast<int>(i);
      for (const char* need : {"id", "x_nom", "y_nom", "x", "y"}) {
        if (!col.count(need)) {
          return Status::BadInput(Where{.file = path, .line = line_no, .field = need}, "missing column",
                                  "the header must name id, x_nom, y_nom, [z_nom,] x, y, [z]");
        }
      }
      if (col.count("z_nom") != col.count("z")) {
        return Status::BadInput(Where{.file = path, .line = line_no, .field = col.count("z") ? "z_nom" : "z"},
                                "missing column", "give both z_nom and z, or neither");
      }
      continue;
    }
    if (cells.size() < col.size()) {
      return Status::BadInput(Where{.file = path, .line = line_no},
                              "expected " + std::to_string(col.size()) + " cells");
    }
    FeaturePosition f;
    f.id = cells[col["id"]];
    f.has_z = col.count("z") > 0;
    auto number = [&](const char* name, double* value) -> Status {
      const std::string& s = cells[col[name]];
      if (!ParseDouble(s, value) || !std::isfinite(*value)) {
        return Status::BadInput(Where{.file = path, .line = line_no, .field = name},
                                "'" + s + "' is not a finite number");
      }
      return Status::Ok();
    };
    FL_RETURN_IF_ERROR(number("x_nom", &f.nominal.x()));
    FL_RETURN_IF_ERROR(number("y_nom", &f.nominal.y()));
    FL_RETURN_IF_ERROR(number("x", &f.measured.x()));
    FL_RETURN_IF_ERROR(number("y", &f.measured.y()));
    if (f.has_z) {
      FL_RETURN_IF_ERROR(number("z_nom", &f.nominal.z()));
      FL_RETURN_IF_ERROR(number("z", &f.measured.z()));
    }
    for (const auto& other : out) {
      if (other.id == f.id) {
        return Status::BadInput(Where{.file = path, .line = line_no, .field = "id"}, "duplicated id '" + f.id + "'");
      }
    }
    out.push_back(f);
  }
  if (col.empty()) return Status::BadInput(Where{.file = path}, "empty file", "give a header and one row per feature");
  return out;
}

Result<Diagnosis> DiagnoseFeatures(const std::vector<FeaturePosition>& features, const Model& baseline,
                                   const DiagnoseOptions& options) {
  if (features.size() < 4) return Status::BadInput("feature diagnosis needs at least 4 features");
  if (!options.direct.empty()) {
    return Status::BadInput(Where{.field = "direct measurements"}, "are used with probe data only",
                            "diagnose the probe log (--measured with --run) with them");
  }
  const bool has_z = features.front().has_z;
  const int dims = has_z ? 3 : 2;
  const int m = static_cast<int>(features.size());
  const int n = m * dims;
  detail::Problem prob;
  prob.r.resize(n);
  prob.weight = Eigen::VectorXd::Ones(n);
  prob.part_of.assign(static_cast<std::size_t>(n), 0);
  prob.part_names = {""};
  prob.xy.resize(n, 2);
  Eigen::MatrixXd pos(m, 3);
  for (int i = 0; i < m; ++i) {
    const auto& f = features[i];
    pos.row(i) = f.nominal.transpose();
    Eigen::Vector3d predicted = Eigen::Vector3d::Zero();
    for (const auto& e : baseline.effects) {
      if (e.effect->acts_on_positions()) predicted += e.effect->DisplacementUm(f.nominal, e.values);
    }
    const Eigen::Vector3d d = 1e3 * (f.measured - f.nominal) - predicted;
    for (int k = 0; k < dims; ++k) {
      prob.r[i * dims + k] = d[k];
      prob.xy.row(i * dims + k) = f.nominal.head<2>().transpose();
    }
  }
  // Neighbours: the same coordinate of the k nearest features.
  FL_ASSIGN_OR_RETURN(const auto feature_nn,
                      detail::KnnLists(has_z ? pos : Eigen::MatrixXd(pos.leftCols(2)), std::min(options.knn, m - 1)));
  prob.neighbours.resize(n);
  for (int i = 0; i < m; ++i) {
    for (int k = 0; k < dims; ++k) {
      for (int j : feature_nn[i]) prob.neighbours[i * dims + k].push_back(j * dims + k);
    }
  }
  prob.applicable = [has_z](const Effect* e) {
    if (!e->acts_on_positions()) return false;
    // Without z, effects that only move z or depend on z are not observable.
    if (!has_z) {
      const std::string_view name = e->name();
      if (name == "axis_scale_z" || name == "squareness_yz" || name == "squareness_zx") return false;
    }
    return true;
  };
  prob.jacobian = [&features, dims, n](const Effect* e, const std::vector<double>&) {
    const int p = e->parameter_count();
    Eigen::MatrixXd j(n, p);
    for (int k = 0; k < p; ++k) {
      std::vector<double> unit(p, 0.0);
      unit[k] = 1.0;
      for (std::size_t i = 0; i < features.size(); ++i) {
        const Eigen::Vector3d d = e->DisplacementUm(features[i].nominal, unit);
        for (int c = 0; c < dims; ++c) j(static_cast<Eigen::Index>(i) * dims + c, k) = d[c];
      }
    }
    return j;
  };
  // 2-D data: setup_offset's and setup_rotation's out-of-plane parts have zero columns; they are
  // reported as not observable (null) and kept at 0 in the extended model.
  return detail::RunEngine(prob, baseline, options);
}

}  // namespace formloop::sim
