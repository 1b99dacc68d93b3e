#pragma once
// Test support: a synthetic run folder in the layout app/report.h reads, with known truth.
//
// Probe points on a grid × grid lattice over 100 × 80 mm; the systematic field is a smooth bump
// d_s = amplitude · sin(π x / 100) · cos(π y / 80) whose amplitude shrinks by `compensation_gain` each
// loop (what compensation would do), plus seeded Gaussian noise (formloop::Rng). Loop 0 also carries
// the spatial lag (rook neighbours, row-standardised) and LISA clusters by quadrant, and analysis.json
// holds the Moran's I those imply, so the Moran scatter's line matches its points.

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <filesystem>
#include <fstream>
#include <numbers>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "core/number_text.h"
#include "core/random.h"

namespace formloop::testing {

struct RunFixtureOptions {
  int grid = 20;                    // points per side
  int loops = 2;                    // loop-0 .. loop-(loops-1)
  double amplitude_um = 30;         // systematic bump of loop 0
  double compensation_gain = 0.15;  // amplitude factor from one loop to the next
  double noise_sigma_um = 2;
  double tolerance_um = 20;
  std::uint64_t seed = 7;
  bool with_optional_files = true;  // retrieval.json, plan.json, sim_correction.json, diagnosis.json, retain.json
};

namespace run_fixture_detail {

inline void WriteText(const std::filesystem::path& path, const std::string& text) {
  std::filesystem::create_directories(path.parent_path());
  std::ofstream(path, std::ios::binary) << text;
}

inline void WriteJson(const std::filesystem::path& path, const nlohmann::json& json) {
  WriteText(path, json.dump(2) + "\n");
}

// Row-standardised rook-neighbour lag of the centred values on a g × g lattice (index = j * g + i).
inline std::vector<double> RookLag(const std::vector<double>& d, int g, double mean) {
  std::vector<double> lag(d.size(), 0);
  for (int j = 0; j < g; ++j) {
    for (int i = 0; i < g; ++i) {
      double sum = 0;
      int n = 0;
      const int di[] = {1, -1, 0, 0}, dj[] = {0, 0, 1, -1};
      for (int k = 0; k < 4; ++k) {
        const int a = i + di[k], b = j + dj[k];
        if (a < 0 || b < 0 || a >= g || b >= g) continue;
        sum += d[static_cast<std::size_t>(b * g + a)] - mean;
        ++n;
      }
      lag[static_cast<std::size_t>(j * g + i)] = n > 0 ? sum / n : 0;
    }
  }
  return lag;
}

// 1 HH, 2 LH, 3 LL, 4 HL by quadrant where |z · lag_z| is large, else 0 (not significant).
inline int Quadrant(double z, double lag_z) {
  if (std::abs(z * lag_z) < 0.5) return 0;
  if (z >= 0) return lag_z >= 0 ? 1 : 4;
  return lag_z >= 0 ? 2 : 3;
}

}  // namespace run_fixture_detail

// Writes loop-K/deviations.csv and loop-K/analysis.json; returns the form error of that loop (µm).
inline double WriteFixtureLoop(const std::filesystem::path& dir, int loop, const RunFixtureOptions& o, Rng& rng,
                               double* moran_z) {
  using namespace run_fixture_detail;
  const int g = o.grid;
  const double amplitude = o.amplitude_um * std::pow(o.compensation_gain, loop);
  std::vector<double> x, y, ds, du, d;
  for (int j = 0; j < g; ++j) {
    for (int i = 0; i < g; ++i) {
      x.push_back(100.0 * i / (g - 1));
      y.push_back(80.0 * j / (g - 1));
      ds.push_back(amplitude * std::sin(std::numbers::pi * x.back() / 100) *
                   std::cos(std::numbers::pi * y.back() / 80));
      du.push_back(rng.Normal(0, o.noise_sigma_um));
      d.push_back(ds.back() + du.back());
    }
  }
  double mean = 0, var = 0, cross = 0, peak = 0, var_u = 0;
  for (std::size_t k = 0; k < d.size(); ++k) mean += d[k] / d.size();
  const std::vector<double> lag = RookLag(d, g, mean);
  for (std::size_t k = 0; k < d.size(); ++k) {
    var += (d[k] - mean) * (d[k] - mean);
    cross += (d[k] - mean) * lag[k];
    peak = std::max(peak, std::abs(ds[k]));
    var_u += du[k] * du[k] / d.size();
  }
  const double sd = std::sqrt(var / d.size()), moran_i = cross / var;
  *moran_z = (moran_i + 1.0 / (d.size() - 1)) / 0.035;  // rough, only shown in the report
  std::string csv = "x,y,z,nx,ny,nz,id,u,v,deviation_um,systematic_um,random_um,lag_um,lisa_cluster\n";
  for (std::size_t k = 0; k < d.size(); ++k) {
    const int lisa = loop == 0 ? Quadrant((d[k] - mean) / sd, lag[k] / sd) : 0;
    csv += FormatExact(x[k]) + "," + FormatExact(y[k]) + ",0,0,0,1," + std::to_string(k) + "," +
           FormatExact(x[k] / 100) + "," + FormatExact(y[k] / 80) + "," + FormatExact(d[k]) + "," + FormatExact(ds[k]) +
           "," + FormatExact(du[k]) + "," + FormatExact(lag[k]) + "," + std::to_string(k == 0 ? 5 : lisa) + "\n";
  }
  const std::filesystem::path loop_dir = dir / ("loop-" + std::to_string(loop));
  WriteText(loop_dir / "deviations.csv", csv);
  WriteJson(loop_dir / "analysis.json",
            {{"raw_moran", {{"I", moran_i}, {"expected", -1.0 / (d.size() - 1)}, {"z_normality", *moran_z}}},
             {"chosen_model", "bicubic"},
             {"tolerance_um", o.tolerance_um},
             {"decision", loop + 1 < o.loops ? "compensate" : "stop"}});
  return peak + 2 * std::sqrt(var_u);
}

inline void WriteFixtureOptionalFiles(const std::filesystem::path& dir) {
  using run_fixture_detail::WriteJson;
  nlohmann::json facets = nlohmann::json::array();
  for (const char* f : {"shape", "material", "tolerance"}) {
    facets.push_back({{"facet", f},
                      {"query_concept", std::string(f) + "-q"},
                      {"case_concept", std::string(f) + "-c"},
                      {"common_node", std::string(f) + "-root"},
                      {"ic_query", 2.1},
                      {"ic_case", 2.3},
                      {"ic_common", 1.4},
                      {"lin", 0.636}});
  }
  WriteJson(
      dir / "retrieval.json",
      {{"route", {{"name", "simulate"}, {"similarity", 0.71}, {"flag_engineer", false}, {"rule", "A >= 0.6"}}},
       {"ranked",
        {{{"rank", 1}, {"uid", "case-0001"}, {"family", "saddle"}, {"similarity", 0.71}, {"facets", facets}},
         {{"rank", 2}, {"uid", "case-0002"}, {"family", "sphere_cap"}, {"similarity", 0.52}, {"facets", facets}}}},
       {"query", {{"shape_family", "saddle"}}}});
  WriteJson(dir / "plan.json", {{"tool_radius_mm", 3},
                                {"stepover_mm", 0.4},
                                {"feed_mm_per_min", 1200},
                                {"strategy", "raster"},
                                {"raster_angle_deg", 0}});
  WriteJson(dir / "sim_correction.json",
            {{"chosen", "corrected"},
             {"why", "predicted form error falls below tolerance"},
             {"defects_before", {{{"defect", "gouge"}, {"peak_um", 12.5}}, {{"defect", "scallop"}, {"peak_um", 3.1}}}},
             {"defects_after", {{{"defect", "scallop"}, {"peak_um", 2.9}}}}});
  WriteJson(dir / "loop-0" / "diagnosis" / "diagnosis.json", {{"causes",
                                                               {{{"effect", "tool_wear"},
                                                                 {"parameters", {{"k_w_um_per_m", 1.9}}},
                                                                 {"std_errors", {{"k_w_um_per_m", 0.1}}},
                                                                 {"variance_explained", 0.82},
                                                                 {"z_before", 14.2},
                                                                 {"z_after", 0.9}},
                                                                {{"effect", "thermal_drift"},
                                                                 {"parameters", {2.5, 600}},
                                                                 {"std_errors", {0.3, 40}},
                                                                 {"variance_explained", 0.11},
                                                                 {"z_before", 4.0},
                                                                 {"z_after", 0.5}}}},
                                                              {"unexplained", nullptr},
                                                              {"gain",
                                                               {{"rms_before_um", 11.0},
                                                                {"rms_after_um", 2.1},
                                                                {"heldout_rms_before_um", 11.4},
                                                                {"heldout_rms_after_um", 2.3}}}});
  WriteJson(dir / "retain.json", {{"case_uid", "case-0042"}, {"stored", true}});
}

// Writes the whole run folder into dir (created if needed).
inline void WriteRunFixture(const std::filesystem::path& dir, const RunFixtureOptions& o = {}) {
  Rng rng(o.seed);
  nlohmann::json loops = nlohmann::json::array();
  bool within = false;
  int loops_to_tolerance = 0;
  for (int k = 0; k < o.loops; ++k) {
    double moran_z = 0;
    const double form_error_um = WriteFixtureLoop(dir, k, o, rng, &moran_z);
    within = form_error_um <= o.tolerance_um;
    if (within && loops_to_tolerance == 0) loops_to_tolerance = k + 1;
    loops.push_back({{"loop", k},
                     {"form_error_um", form_error_um},
                     {"systematic_peak_um", o.amplitude_um * std::pow(o.compensation_gain, k)},
                     {"random_sigma_um", o.noise_sigma_um},
                     {"raw_moran_z", moran_z},
                     {"chosen_model", "bicubic"},
                     {"residual_moran_z", 0.4},
                     {"within_tolerance", within},
                     {"compensated_after", k + 1 < o.loops},
                     {"decision", k + 1 < o.loops ? "compensate" : "stop"}});
  }
  run_fixture_detail::WriteJson(
      dir / "summary.json",
      {{"formloop_version", "0.1.0-test"},
       {"part", "fixture saddle"},
       {"surface", "saddle"},
       {"tolerance_um", o.tolerance_um},
       {"fit_check_max_um", 0.8},
       {"route", {{"name", "simulate"}, {"similarity", 0.71}, {"case_uid", "case-0001"}, {"flag_engineer", false}}},
       {"loops", loops},
       {"within_tolerance", within},
       {"loops_to_tolerance", within ? nlohmann::json(loops_to_tolerance) : nlohmann::json(nullptr)},
       {"causes", {"tool_wear"}}});
  if (o.with_optional_files) WriteFixtureOptionalFiles(dir);
}

}  // namespace formloop::testing
