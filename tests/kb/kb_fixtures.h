#pragma once
// Test support for the case library: a scratch folder per test and deterministic synthetic cases.

#include <filesystem>
#include <fstream>
#include <iterator>
#include <random>
#include <string>

#include <unistd.h>

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include "kb/library.h"
#include "tests/support/test_dir.h"

namespace formloop::kb::testing {

namespace fs = std::filesystem;

class KbLibraryTest : public ::testing::Test {
 protected:
  void SetUp() override { dir_ = formloop::testing::FreshTestDir("formloop-kblib"); }
  void TearDown() override { fs::remove_all(dir_); }

  // A fresh library at the current schema.
  std::unique_ptr<Library> NewLibrary(const std::string& name) {
    const fs::path path = dir_ / name;
    auto init = InitLibrary(path);
    EXPECT_TRUE(init.ok()) << init.status().message();
    auto lib = Library::Open(path);
    EXPECT_TRUE(lib.ok()) << lib.status().message();
    return lib.ok() ? std::move(lib).value() : nullptr;
  }
  fs::path dir_;
};

// Case `index` of a synthetic library; the same index and seed give the same case. `prefix` keeps uids of
// different writers apart.
inline CaseRecord SyntheticCase(int index, unsigned seed = 7, const std::string& prefix = "case") {
  std::mt19937_64 rng(seed * 100003ULL + static_cast<unsigned>(index));
  std::uniform_real_distribution<double> unit(0.0, 1.0);
  static const char* kFamilies[] = {"freeform", "turbine_blade", "mould_cavity"};
  static const char* kMaterials[] = {"H13", "Ti-6Al-4V", "Al 6061"};
  CaseRecord r;
  char uid[64];
  std::snprintf(uid, sizeof uid, "%s-%05d", prefix.c_str(), index);
  r.uid = uid;
  r.name = "synthetic part " + std::to_string(index);
  r.family = kFamilies[index % 3];
  const std::string material = kMaterials[(index / 3) % 3];
  r.part = {{"tolerance_mm", 0.01 + 0.05 * unit(rng)},
            {"finish_ra_um", 0.2 + unit(rng)},
            {"batch_size", 1 + index % 20},
            {"material", material},
            {"bounding_box_mm", {100.0 * unit(rng), 80.0 * unit(rng), 30.0 * unit(rng)}}};
  r.simulation = {{"model_format", "step"},
                  {"material_properties", {{"youngs_modulus_gpa", 110 + 100 * unit(rng)}}},
                  {"effect_models",
                   {{{"machine", "dmu50"},
                     {"effects",
                      {{{"name", "tool_deflection"}, {"estimate", 0.003 * unit(rng)}, {"standard_error", 0.0004}},
                       {{"name", "thermal_z"}, {"estimate", -0.002 * unit(rng)}, {"standard_error", 0.0002}}}}}}}};
  r.manufacturing = {{"machine", "dmu50"},
                     {"tools", {{{"type", "ball_end"}, {"radius_mm", 3.0}, {"flutes", 2}, {"stickout_mm", 30.0}}}},
                     {"strategy", {{"raster_angle_deg", 45.0 * (index % 4)}, {"step_over_mm", 0.1 + 0.3 * unit(rng)}}},
                     {"reconstruction", {{"algorithm", "B-spline"}, {"degree", 3}, {"control_net", {12, 12}}}},
                     {"compensation", {{"loops", {{{"form_error_mm", 0.05}}, {{"form_error_mm", 0.012}}}}}}};
  std::vector<double> d;
  for (int k = 0; k < 8; ++k) d.push_back(unit(rng) * 10.0 - 5.0);
  r.descriptor = d;
  r.concepts = {{"shape", r.family}, {"material", material}, {"tolerance", index % 2 ? "fine" : "medium"}};
  return r;
}

inline std::string ReadBytes(const fs::path& path) {
  std::ifstream in(path, std::ios::binary);
  return std::string(std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>());
}

inline void WriteBytes(const fs::path& path, const std::string& bytes) {
  std::ofstream out(path, std::ios::binary);
  out << bytes;
}

}  // namespace formloop::kb::testing
