#include "simulation/part_record.h"

#include <cmath>
#include <functional>

#include "simulation/virtual_machine.h"

namespace formloop::sim {
namespace {

using Json = nlohmann::json;

// The record's columns: name and how to read / write it on one point. Vectors are three columns.
struct Column {
  const char* name;
  std::function<double(const PartRecord&, std::size_t)> get;
  std::function<void(PartRecord&, std::size_t, double)> set;
  bool integer = false;
};

std::vector<Column> Columns() {
  std::vector<Column> c;
  c.push_back({"id", [](const PartRecord& r, std::size_t i) { return static_cast<double>(r.contexts[i].id); },
               [](PartRecord& r, std::size_t i, double x) { r.contexts[i].id = static_cast<std::int64_t>(x); }, true});
  auto vector3 = [&c](const char* x, const char* y, const char* z, Eigen::Vector3d PointContext::*m) {
    const char* names[3] = {x, y, z};
    for (int k = 0; k < 3; ++k) {
      c.push_back({names[k], [m, k](const PartRecord& r, std::size_t i) { return (r.contexts[i].*m)[k]; },
                   [m, k](PartRecord& r, std::size_t i, double v) { (r.contexts[i].*m)[k] = v; }});
    }
  };
  vector3("x_mm", "y_mm", "z_mm", &PointContext::point);
  vector3("nx", "ny", "nz", &PointContext::normal);
  vector3("ax", "ay", "az", &PointContext::approach);
  auto scalar = [&c](const char* name, double PointContext::*m) {
    c.push_back({name, [m](const PartRecord& r, std::size_t i) { return r.contexts[i].*m; },
                 [m](PartRecord& r, std::size_t i, double v) { r.contexts[i].*m = v; }});
  };
  scalar("path_length_mm", &PointContext::path_length_mm);
  scalar("cut_time_s", &PointContext::cut_time_s);
  c.push_back({"pass", [](const PartRecord& r, std::size_t i) { return static_cast<double>(r.contexts[i].pass); },
               [](PartRecord& r, std::size_t i, double x) { r.contexts[i].pass = static_cast<int>(x); }, true});
  vector3("fx", "fy", "fz", &PointContext::feed);
  scalar("engagement", &PointContext::engagement);
  scalar("scallop_um", &PointContext::scallop_um);
  auto vec = [&c](const char* name, Eigen::VectorXd PartRecord::*m) {
    c.push_back({name, [m](const PartRecord& r, std::size_t i) { return (r.*m)[static_cast<Eigen::Index>(i)]; },
                 [m](PartRecord& r, std::size_t i, double v) { (r.*m)[static_cast<Eigen::Index>(i)] = v; }});
  };
  vec("residual_um", &PartRecord::residual_um);
  c.push_back(
      {"d_surface",
       [](const PartRecord& r, std::size_t i) { return r.sensitivity.surface[static_cast<Eigen::Index>(i)]; },
       [](PartRecord& r, std::size_t i, double v) { r.sensitivity.surface[static_cast<Eigen::Index>(i)] = v; }});
  c.push_back({"d_radius",
               [](const PartRecord& r, std::size_t i) { return r.sensitivity.radius[static_cast<Eigen::Index>(i)]; },
               [](PartRecord& r, std::size_t i, double v) { r.sensitivity.radius[static_cast<Eigen::Index>(i)] = v; }});
  return c;
}

}  // namespace

Result<PartRecord> PartRecord::Of(const ProbeDataInput& input) {
  FL_ASSIGN_OR_RETURN(ProbeResidualData data, ProbeResiduals(input, Model{}));
  PartRecord r;
  r.contexts = std::move(data.contexts);
  r.residual_um = std::move(data.residual_um);
  r.sensitivity = std::move(data.sensitivity);
  return r;
}

ProbeResidualData PartRecord::Against(const Model& baseline) const {
  ProbeResidualData out;
  out.contexts = contexts;
  out.sensitivity = sensitivity;
  out.residual_um = residual_um;
  const Model none;
  for (std::size_t i = 0; i < contexts.size(); ++i) {
    const PointContext& c = contexts[i];
    const auto k = static_cast<Eigen::Index>(i);
    const double surface_um = baseline.SurfaceDeviationUm(c) - none.SurfaceDeviationUm(c);
    const double radius_um = 1e3 * MeasurementEffectsMm(c, baseline);
    out.residual_um[k] -= surface_um * sensitivity.surface[k] + radius_um * sensitivity.radius[k];
  }
  return out;
}

Json PartRecord::ToJson() const {
  Json j = {{"format", kPartRecordFormat}, {"version", kPartRecordVersion}, {"points", contexts.size()}};
  for (const Column& c : Columns()) {
    Json column = Json::array();
    for (std::size_t i = 0; i < contexts.size(); ++i) {
      const double x = c.get(*this, i);
      if (c.integer) {
        column.push_back(static_cast<long long>(x));
      } else {
        column.push_back(x);
      }
    }
    j[c.name] = std::move(column);
  }
  return j;
}

Result<PartRecord> PartRecord::FromJson(const Json& j, const std::string& source) {
  if (!j.is_object() || j.value("format", "") != kPartRecordFormat) {
    return Status::BadInput(Where{.file = source, .field = "format"},
                            std::string("is not a ") + kPartRecordFormat + " record");
  }
  if (!j.contains("version") || !j["version"].is_number_integer() || j["version"].get<int>() > kPartRecordVersion ||
      j["version"].get<int>() < 1) {
    return Status::BadInput(
        Where{.file = source, .field = "version"},
        "missing or not a version this formloop reads (1.." + std::to_string(kPartRecordVersion) + ")",
        "upgrade formloop");
  }
  if (!j.contains("points") || !j["points"].is_number_unsigned() || j["points"].get<std::size_t>() == 0) {
    return Status::BadInput(Where{.file = source, .field = "points"}, "missing or not a positive count");
  }
  const std::size_t n = j["points"].get<std::size_t>();
  PartRecord r;
  r.contexts.resize(n);
  r.residual_um.resize(static_cast<Eigen::Index>(n));
  r.sensitivity.surface.resize(static_cast<Eigen::Index>(n));
  r.sensitivity.radius.resize(static_cast<Eigen::Index>(n));
  for (const Column& c : Columns()) {
    if (!j.contains(c.name) || !j[c.name].is_array() || j[c.name].size() != n) {
      return Status::BadInput(Where{.file = source, .field = c.name},
                              "missing or not an array of " + std::to_string(n) + " numbers");
    }
    const Json& column = j[c.name];
    for (std::size_t i = 0; i < n; ++i) {
      const Json& x = column[i];
      if (!(c.integer ? x.is_number_integer() : x.is_number()) || !std::isfinite(x.get<double>())) {
        return Status::BadInput(Where{.file = source, .field = std::string(c.name) + "[" + std::to_string(i) + "]"},
                                c.integer ? "not an integer" : "not a finite number");
      }
      c.set(r, i, x.get<double>());
    }
  }
  for (std::size_t i = 0; i < n; ++i) {
    const PointContext& c = r.contexts[i];
    for (const char* name : {"n", "a"}) {
      const Eigen::Vector3d& v = name[0] == 'n' ? c.normal : c.approach;
      if (std::abs(v.norm() - 1.0) > 1e-6) {
        return Status::BadInput(
            Where{.file = source, .field = std::string(name) + "x.." + name + "z[" + std::to_string(i) + "]"},
            "is not a unit vector");
      }
    }
  }
  return r;
}

}  // namespace formloop::sim
