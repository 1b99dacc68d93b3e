// Fixtures and helpers shared by the point-format tests (point_io_test.cc: numbers, dispatch, CSV,
// XYZ; point_io_binary_test.cc: PLY and PCD).
#ifndef FORMLOOP_TESTS_CORE_POINT_IO_TEST_SUPPORT_H_
#define FORMLOOP_TESTS_CORE_POINT_IO_TEST_SUPPORT_H_

#include <gmock/gmock.h>
#include <gtest/gtest.h>
#include <unistd.h>

#include <algorithm>
#include <bit>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <initializer_list>
#include <string>
#include <vector>

#include "core/atomic_file.h"
#include "core/point_io.h"
#include "core/random.h"
#include "tests/support/locale.h"

namespace formloop::point_io_test {

namespace fs = std::filesystem;
using ::testing::HasSubstr;
using ::testing::IsEmpty;

// ---- Fixtures and helpers ----------------------------------------------------------------------

// A synthetic set with every attribute: positions in a 1 m cube, unit normals, ids, times and two
// scalar columns (in the order deviation_um, intensity).
inline PointSet MakeSample(std::size_t n, std::uint64_t seed) {
  Rng rng(seed);
  PointSet set;
  std::vector<double> deviation_um;
  std::vector<double> intensity;
  for (std::size_t i = 0; i < n; ++i) {
    set.points.emplace_back(rng.Uniform(-500, 500), rng.Uniform(-500, 500), rng.Uniform(-50, 50));
    Eigen::Vector3d normal(rng.Normal(), rng.Normal(), rng.Normal() + 3);
    set.normals.push_back(normal.normalized());
    set.ids.push_back(static_cast<std::int64_t>(i) * 7 - 3);
    set.times_s.push_back(0.001 * static_cast<double>(i) + rng.Uniform(0, 1e-4));
    deviation_um.push_back(rng.Normal(0, 3));
    intensity.push_back(rng.Uniform());
  }
  set.SetScalar("deviation_um", std::move(deviation_um));
  set.SetScalar("intensity", std::move(intensity));
  return set;
}

inline PointSet PositionsOnly(const PointSet& full) {
  PointSet set;
  set.points = full.points;
  return set;
}

// Largest absolute difference over every value; sizes, ids and scalar names must match exactly.
inline void ExpectSame(const PointSet& expected, const PointSet& actual, double tolerance) {
  ASSERT_EQ(expected.size(), actual.size());
  ASSERT_EQ(expected.normals.size(), actual.normals.size());
  ASSERT_EQ(expected.times_s.size(), actual.times_s.size());
  EXPECT_EQ(expected.ids, actual.ids);
  ASSERT_EQ(expected.scalars.size(), actual.scalars.size());
  double worst = 0;
  for (std::size_t i = 0; i < expected.size(); ++i) {
    worst = std::max(worst, (expected.points[i] - actual.points[i]).cwiseAbs().maxCoeff());
    if (expected.has_normals()) {
      worst = std::max(worst, (expected.normals[i] - actual.normals[i]).cwiseAbs().maxCoeff());
    }
    if (expected.has_times()) worst = std::max(worst, std::abs(expected.times_s[i] - actual.times_s[i]));
  }
  for (std::size_t c = 0; c < expected.scalars.size(); ++c) {
    EXPECT_EQ(expected.scalars[c].name, actual.scalars[c].name);
    ASSERT_EQ(expected.scalars[c].values.size(), actual.scalars[c].values.size());
    for (std::size_t i = 0; i < expected.size(); ++i) {
      worst = std::max(worst, std::abs(expected.scalars[c].values[i] - actual.scalars[c].values[i]));
    }
  }
  if (tolerance == 0) {
    EXPECT_EQ(worst, 0.0);
  } else {
    EXPECT_LE(worst, tolerance);
  }
}

inline void ExpectError(const Status& status, StatusCode code, std::initializer_list<std::string> parts) {
  EXPECT_EQ(status.code(), code) << status.ToString();
  for (const auto& part : parts) EXPECT_THAT(status.message(), HasSubstr(part));
}

// Each test gets its own empty folder, removed afterwards.
class PointIoTestBase : public ::testing::Test {
 protected:
  void SetUp() override {
    const auto* info = ::testing::UnitTest::GetInstance()->current_test_info();
    dir_ = fs::temp_directory_path() / ("formloop_point_io_" + std::string(info->test_suite_name()) + "_" +
                                        info->name() + "_" + std::to_string(::getpid()));
    fs::remove_all(dir_);
    fs::create_directories(dir_);
  }
  void TearDown() override {
    std::error_code ignored;
    fs::remove_all(dir_, ignored);
  }

  fs::path Path(const std::string& name) const { return dir_ / name; }

  fs::path WriteBytes(const std::string& name, const std::string& content) const {
    const fs::path path = Path(name);
    std::ofstream out(path, std::ios::binary);
    out.write(content.data(), static_cast<std::streamsize>(content.size()));
    return path;
  }

  std::string ReadBytes(const fs::path& path) const {
    auto content = ReadFile(path);
    EXPECT_TRUE(content.ok()) << content.status().ToString();
    return content.ok() ? *content : std::string();
  }

  std::vector<std::string> Listing() const {
    std::vector<std::string> names;
    for (const auto& entry : fs::directory_iterator(dir_)) names.push_back(entry.path().filename().string());
    std::sort(names.begin(), names.end());
    return names;
  }

  fs::path dir_;
};

class PointIoTest : public PointIoTestBase {};
class CsvTest : public PointIoTestBase {};
class XyzTest : public PointIoTestBase {};
class PlyTest : public PointIoTestBase {};
class PcdTest : public PointIoTestBase {};

using formloop::testing::CommaNumpunct;
using formloop::testing::GlobalLocale;

// Big-endian bytes for hand-made PLY files.
template <typename T>
inline void AppendBigEndian(T value, std::string* out) {
  char bytes[sizeof(T)];
  std::memcpy(bytes, &value, sizeof(T));
  if constexpr (std::endian::native == std::endian::little) std::reverse(bytes, bytes + sizeof(T));
  out->append(bytes, sizeof(T));
}
template <typename T>
inline void AppendLittleEndian(T value, std::string* out) {
  char bytes[sizeof(T)];
  std::memcpy(bytes, &value, sizeof(T));
  if constexpr (std::endian::native == std::endian::big) std::reverse(bytes, bytes + sizeof(T));
  out->append(bytes, sizeof(T));
}

}  // namespace formloop::point_io_test

#endif  // FORMLOOP_TESTS_CORE_POINT_IO_TEST_SUPPORT_H_
