#include "core/point_io.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>
#include <pcl/io/pcd_io.h>
#include <pcl/point_cloud.h>
#include <pcl/point_types.h>
#include <unistd.h>

#include <algorithm>
#include <bit>
#include <clocale>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <initializer_list>
#include <limits>
#include <locale>
#include <string>
#include <vector>

#include "core/atomic_file.h"
#include "core/random.h"
#include "tests/support/locale.h"

namespace formloop {
namespace {

namespace fs = std::filesystem;
using ::testing::HasSubstr;
using ::testing::IsEmpty;

// ---- Fixtures and helpers ----------------------------------------------------------------------

// A synthetic set with every attribute: positions in a 1 m cube, unit normals, ids, times and two
// scalar columns (in the order deviation_um, intensity).
PointSet MakeSample(std::size_t n, std::uint64_t seed) {
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

PointSet PositionsOnly(const PointSet& full) {
  PointSet set;
  set.points = full.points;
  return set;
}

// Largest absolute difference over every value; sizes, ids and scalar names must match exactly.
void ExpectSame(const PointSet& expected, const PointSet& actual, double tolerance) {
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

void ExpectError(const Status& status, StatusCode code, std::initializer_list<std::string> parts) {
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
void AppendBigEndian(T value, std::string* out) {
  char bytes[sizeof(T)];
  std::memcpy(bytes, &value, sizeof(T));
  if constexpr (std::endian::native == std::endian::little) std::reverse(bytes, bytes + sizeof(T));
  out->append(bytes, sizeof(T));
}
template <typename T>
void AppendLittleEndian(T value, std::string* out) {
  char bytes[sizeof(T)];
  std::memcpy(bytes, &value, sizeof(T));
  if constexpr (std::endian::native == std::endian::big) std::reverse(bytes, bytes + sizeof(T));
  out->append(bytes, sizeof(T));
}

// ---- Numbers and dispatch ---------------------------------------------------------------------

TEST(PointIoFormatTest, FormatFixed) {
  EXPECT_EQ(FormatFixed(1.5, 3), "1.500");
  EXPECT_EQ(FormatFixed(-2.25, 1), "-2.2");  // the binary value is exactly -2.25: round half to even
  EXPECT_EQ(FormatFixed(2.0, 0), "2");
  EXPECT_EQ(FormatFixed(123456789.125, 3), "123456789.125");
  EXPECT_EQ(FormatFixed(-0.0, 3), "0.000");
  EXPECT_EQ(FormatFixed(-0.0004, 3), "0.000");
  EXPECT_EQ(FormatFixed(-0.0006, 3), "-0.001");
  EXPECT_EQ(FormatFixed(1e-10, 9), "0.000000000");
  EXPECT_EQ(FormatFixed(0.5, -2), "0");  // negative decimals count as 0; 0.5 rounds to even
  EXPECT_EQ(FormatFixed(1e300, 2).size(), 304u);
}

TEST(PointIoFormatTest, FormatExactRoundTrips) {
  EXPECT_EQ(FormatExact(0.1), "0.1");
  EXPECT_EQ(FormatExact(-3.0), "-3");
  Rng rng(7);
  for (int i = 0; i < 1000; ++i) {
    const double value = rng.Normal(0, 1000) * std::pow(10.0, rng.Uniform(-20, 20));
    double back = 0;
    ASSERT_TRUE(ParseDouble(FormatExact(value), &back)) << FormatExact(value);
    EXPECT_EQ(back, value);
  }
}

TEST(PointIoFormatTest, ParseDouble) {
  double value = 0;
  EXPECT_TRUE(ParseDouble("1", &value));
  EXPECT_EQ(value, 1.0);
  EXPECT_TRUE(ParseDouble("-12.375", &value));
  EXPECT_EQ(value, -12.375);
  EXPECT_TRUE(ParseDouble("+2.5", &value));
  EXPECT_EQ(value, 2.5);
  EXPECT_TRUE(ParseDouble("1e-3", &value));
  EXPECT_EQ(value, 1e-3);
  EXPECT_TRUE(ParseDouble("nan", &value));
  EXPECT_TRUE(std::isnan(value));
  EXPECT_TRUE(ParseDouble("-inf", &value));
  EXPECT_TRUE(std::isinf(value));
  for (const char* bad : {"", " 1", "1 ", "1x", "1,5", "+", "-", "+-1", "++1", "0x10", "1e400"}) {
    EXPECT_FALSE(ParseDouble(bad, &value)) << "'" << bad << "'";
  }
}

TEST(PointIoFormatTest, FormatFixedIgnoresGermanLocale) {
  std::locale german;
  try {
    german = std::locale("de_DE.UTF-8");
  } catch (const std::runtime_error&) {
    GTEST_SKIP() << "locale de_DE.UTF-8 is not installed (the comma-numpunct test covers the same ground)";
  }
  GlobalLocale scope(german);
  EXPECT_EQ(FormatFixed(1.5, 3), "1.500");
  double value = 0;
  EXPECT_TRUE(ParseDouble("1.5", &value));
  EXPECT_EQ(value, 1.5);
}

TEST_F(PointIoTest, CommaDecimalGlobalLocaleChangesNothing) {
  GlobalLocale scope(std::locale(std::locale::classic(), new CommaNumpunct));
  EXPECT_EQ(FormatFixed(1.5, 3), "1.500");
  EXPECT_EQ(FormatFixed(1234567.25, 2), "1234567.25");
  const PointSet sample = MakeSample(1500, 11);
  PointSet xyz_expected = PositionsOnly(sample);
  xyz_expected.normals = sample.normals;
  for (const std::string name : {"a.csv", "a.xyz", "a.ply", "a.pcd"}) {
    for (const bool binary : {true, false}) {
      ASSERT_TRUE(WritePoints(Path(name), sample, {.binary = binary, .precision = -1}).ok()) << name;
      const std::string text = ReadBytes(Path(name));
      if (name == "a.ply") {
        EXPECT_THAT(text, HasSubstr("\nelement vertex 1500\n"));
      }
      if (name == "a.pcd") {
        EXPECT_THAT(text, HasSubstr("\nWIDTH 1500\n"));
      }
      auto back = ReadPoints(Path(name));
      ASSERT_TRUE(back.ok()) << back.status().ToString();
      ExpectSame(name == "a.xyz" ? xyz_expected : sample, *back, 0);
    }
  }
}

TEST_F(PointIoTest, FormatFromPath) {
  EXPECT_EQ(*PointFormatFromPath("a/b.CSV"), PointFormat::kCsv);
  EXPECT_EQ(*PointFormatFromPath("b.xyz"), PointFormat::kXyz);
  EXPECT_EQ(*PointFormatFromPath("b.txt"), PointFormat::kXyz);
  EXPECT_EQ(*PointFormatFromPath("b.Ply"), PointFormat::kPly);
  EXPECT_EQ(*PointFormatFromPath("b.pcd"), PointFormat::kPcd);
  ExpectError(PointFormatFromPath("scan.las").status(), StatusCode::kBadInput, {"scan.las", "'.las'", "Fix:"});
  ExpectError(PointFormatFromPath("scan").status(), StatusCode::kBadInput, {"scan", "no extension"});
}

TEST_F(PointIoTest, UnknownExtensionWritesNothing) {
  ExpectError(WritePoints(Path("out.las"), MakeSample(3, 1)), StatusCode::kBadInput, {"out.las"});
  ExpectError(ReadPoints(Path("out.las")).status(), StatusCode::kBadInput, {"out.las"});
  EXPECT_THAT(Listing(), IsEmpty());
}

TEST_F(PointIoTest, NonexistentFileIsNotFound) {
  for (const char* name : {"missing.csv", "missing.xyz", "missing.ply", "missing.pcd"}) {
    ExpectError(ReadPoints(Path(name)).status(), StatusCode::kNotFound, {name});
  }
}

TEST_F(PointIoTest, DispatchRoundTripsEveryFormat) {
  const PointSet sample = MakeSample(50, 2);
  for (const char* name : {"p.csv", "p.ply", "p.pcd"}) {
    ASSERT_TRUE(WritePoints(Path(name), sample).ok()) << name;
    auto back = ReadPoints(Path(name));
    ASSERT_TRUE(back.ok()) << back.status().ToString();
    ExpectSame(sample, *back, 1e-9);
  }
  ASSERT_TRUE(WritePoints(Path("p.txt"), PositionsOnly(sample)).ok());
  auto back = ReadPoints(Path("p.txt"));
  ASSERT_TRUE(back.ok()) << back.status().ToString();
  ExpectSame(PositionsOnly(sample), *back, 1e-9);
}

// ---- CSV ----------------------------------------------------------------------------------------

TEST_F(CsvTest, RoundTripExactWithShortestText) {
  const PointSet sample = MakeSample(200, 3);
  ASSERT_TRUE(WriteCsv(Path("a.csv"), sample, {.precision = -1}).ok());
  auto back = ReadCsv(Path("a.csv"));
  ASSERT_TRUE(back.ok()) << back.status().ToString();
  ExpectSame(sample, *back, 0);
}

TEST_F(CsvTest, RoundTripWithNineDecimals) {
  const PointSet sample = MakeSample(200, 4);
  ASSERT_TRUE(WriteCsv(Path("a.csv"), sample).ok());
  const std::string text = ReadBytes(Path("a.csv"));
  EXPECT_EQ(text.substr(0, text.find('\n')), "x,y,z,nx,ny,nz,id,t,deviation_um,intensity");
  auto back = ReadCsv(Path("a.csv"));
  ASSERT_TRUE(back.ok()) << back.status().ToString();
  ExpectSame(sample, *back, 1e-9);
}

TEST_F(CsvTest, CommentsBlankLinesSpacesAndCrlf) {
  const fs::path path = WriteBytes("a.csv",
                                   "# exported by a probe\r\n\r\n x , y ,z, deviation_um ,id\r\n1, 2, 3, 4.5, 7\r\n"
                                   "# a comment between rows\r\n\r\n5,6,7,-8,+9\r\n");
  auto points = ReadCsv(path);
  ASSERT_TRUE(points.ok()) << points.status().ToString();
  ASSERT_EQ(points->size(), 2u);
  EXPECT_EQ(points->points[1], Eigen::Vector3d(5, 6, 7));
  EXPECT_EQ(points->ids, (std::vector<std::int64_t>{7, 9}));
  ASSERT_NE(points->FindScalar("deviation_um"), nullptr);
  EXPECT_EQ(*points->FindScalar("deviation_um"), (std::vector<double>{4.5, -8}));
  EXPECT_FALSE(points->has_normals());
  EXPECT_FALSE(points->has_times());
}

TEST_F(CsvTest, ScalarColumnsKeepFileOrder) {
  const fs::path path = WriteBytes("a.csv", "b,x,a,y,t,z,c\n1,2,3,4,5,6,7\n");
  auto points = ReadCsv(path);
  ASSERT_TRUE(points.ok()) << points.status().ToString();
  ASSERT_EQ(points->scalars.size(), 3u);
  EXPECT_EQ(points->scalars[0].name, "b");
  EXPECT_EQ(points->scalars[1].name, "a");
  EXPECT_EQ(points->scalars[2].name, "c");
  EXPECT_EQ(points->points[0], Eigen::Vector3d(2, 4, 6));
  EXPECT_EQ(points->times_s, std::vector<double>{5});
}

TEST_F(CsvTest, MissingZColumn) {
  const fs::path path = WriteBytes("noz.csv", "# scan\nx,y,dev\n1,2,3\n");
  ExpectError(ReadCsv(path).status(), StatusCode::kBadInput, {"noz.csv:2", "field 'z'", "Fix:"});
}

TEST_F(CsvTest, NanAndInfAreRejected) {
  ExpectError(ReadCsv(WriteBytes("nan.csv", "x,y,z\n1,2,3\n1,2,nan\n")).status(), StatusCode::kBadInput,
              {"nan.csv:3", "field 'z'", "not finite", "Fix:"});
  ExpectError(ReadCsv(WriteBytes("inf.csv", "x,y,z,dev\n1,2,3,-inf\n")).status(), StatusCode::kBadInput,
              {"inf.csv:2", "field 'dev'", "not finite"});
}

TEST_F(CsvTest, EmptyFile) {
  ExpectError(ReadCsv(WriteBytes("empty.csv", "")).status(), StatusCode::kBadInput, {"empty.csv", "no points"});
  ExpectError(ReadCsv(WriteBytes("comments.csv", "# nothing\n\n")).status(), StatusCode::kBadInput,
              {"comments.csv", "no points"});
}

TEST_F(CsvTest, HeaderOnly) {
  ExpectError(ReadCsv(WriteBytes("header.csv", "x,y,z\n\n")).status(), StatusCode::kBadInput,
              {"header.csv:1", "no points", "no data rows"});
}

TEST_F(CsvTest, LettersInNumericColumn) {
  ExpectError(ReadCsv(WriteBytes("letters.csv", "x,y,z\n1,2,3\n1,2,abc\n")).status(), StatusCode::kBadInput,
              {"letters.csv:3", "field 'z'", "'abc' is not a number", "Fix:"});
  ExpectError(ReadCsv(WriteBytes("comma.csv", "x,y,z\n1,2,\n")).status(), StatusCode::kBadInput,
              {"comma.csv:2", "field 'z'", "empty"});
}

TEST_F(CsvTest, NonIntegerId) {
  ExpectError(ReadCsv(WriteBytes("id.csv", "x,y,z,id\n1,2,3,4\n1,2,3,4.5\n")).status(), StatusCode::kBadInput,
              {"id.csv:3", "field 'id'", "'4.5' is not an integer", "Fix:"});
  ExpectError(ReadCsv(WriteBytes("id2.csv", "x,y,z,id\n1,2,3,+-4\n")).status(), StatusCode::kBadInput,
              {"id2.csv:2", "field 'id'"});
}

TEST_F(CsvTest, PartialNormals) {
  ExpectError(ReadCsv(WriteBytes("normals.csv", "x,y,z,nx,ny\n1,2,3,0,0\n")).status(), StatusCode::kBadInput,
              {"normals.csv:1", "field 'nz'", "nx, ny and nz together"});
}

TEST_F(CsvTest, WrongFieldCount) {
  ExpectError(ReadCsv(WriteBytes("count.csv", "x,y,z\n1,2,3\n4,5\n")).status(), StatusCode::kBadInput,
              {"count.csv:3", "2 fields", "3 columns"});
  ExpectError(ReadCsv(WriteBytes("count2.csv", "x,y,z\n1,2,3,\n")).status(), StatusCode::kBadInput,
              {"count2.csv:2", "4 fields"});
}

TEST_F(CsvTest, DuplicateColumn) {
  ExpectError(ReadCsv(WriteBytes("dup.csv", "x,y,z,dev,dev\n1,2,3,4,5\n")).status(), StatusCode::kBadInput,
              {"dup.csv:1", "field 'dev'", "twice"});
}

TEST_F(CsvTest, WritingNanLeavesNoFile) {
  PointSet sample = MakeSample(10, 5);
  sample.scalars[1].values[4] = std::numeric_limits<double>::quiet_NaN();
  ExpectError(WriteCsv(Path("out.csv"), sample), StatusCode::kBadInput, {"out.csv", "intensity"});
  EXPECT_THAT(Listing(), IsEmpty());
  sample = MakeSample(10, 5);
  sample.ids.pop_back();  // size mismatch
  EXPECT_FALSE(WriteCsv(Path("out.csv"), sample).ok());
  EXPECT_THAT(Listing(), IsEmpty());
}

TEST_F(CsvTest, WritingIntoMissingFolderLeavesNoFile) {
  ExpectError(WriteCsv(Path("nope") / "out.csv", MakeSample(3, 6)), StatusCode::kIoError, {"out.csv"});
  EXPECT_THAT(Listing(), IsEmpty());
}

TEST_F(CsvTest, FailedWriteKeepsTheOldFile) {
  const fs::path path = WriteBytes("keep.csv", "x,y,z\n1,2,3\n");
  PointSet sample = MakeSample(3, 7);
  sample.points[1].y() = std::numeric_limits<double>::infinity();
  EXPECT_FALSE(WriteCsv(path, sample).ok());
  EXPECT_EQ(ReadBytes(path), "x,y,z\n1,2,3\n");
  EXPECT_EQ(Listing(), std::vector<std::string>{"keep.csv"});
}

// ---- XYZ ----------------------------------------------------------------------------------------

TEST_F(XyzTest, RoundTripWithAndWithoutNormals) {
  const PointSet full = MakeSample(100, 8);
  PointSet with_normals = PositionsOnly(full);
  with_normals.normals = full.normals;
  ASSERT_TRUE(WriteXyz(Path("n.xyz"), with_normals, {.precision = -1}).ok());
  auto back = ReadXyz(Path("n.xyz"));
  ASSERT_TRUE(back.ok()) << back.status().ToString();
  ExpectSame(with_normals, *back, 0);

  ASSERT_TRUE(WriteXyz(Path("p.xyz"), full).ok());  // ids, times and scalars are not part of XYZ
  back = ReadXyz(Path("p.xyz"));
  ASSERT_TRUE(back.ok()) << back.status().ToString();
  ExpectSame(with_normals, *back, 1e-9);

  ASSERT_TRUE(WriteXyz(Path("q.xyz"), PositionsOnly(full), {.precision = 9}).ok());
  back = ReadXyz(Path("q.xyz"));
  ASSERT_TRUE(back.ok()) << back.status().ToString();
  ExpectSame(PositionsOnly(full), *back, 1e-9);
}

TEST_F(XyzTest, CommentsTabsAndCrlf) {
  auto points = ReadXyz(WriteBytes("a.xyz", "# x y z\r\n1\t2  3\r\n\r\n  4 5 6  \r\n# end\r\n"));
  ASSERT_TRUE(points.ok()) << points.status().ToString();
  ASSERT_EQ(points->size(), 2u);
  EXPECT_EQ(points->points[1], Eigen::Vector3d(4, 5, 6));
}

TEST_F(XyzTest, InconsistentColumnCount) {
  ExpectError(ReadXyz(WriteBytes("mixed.xyz", "1 2 3\n# c\n4 5 6 0 0 1\n")).status(), StatusCode::kBadInput,
              {"mixed.xyz:3", "6 values", "line 1 has 3"});
  ExpectError(ReadXyz(WriteBytes("four.xyz", "1 2 3 4\n")).status(), StatusCode::kBadInput, {"four.xyz:1", "4 values"});
}

TEST_F(XyzTest, BadValues) {
  ExpectError(ReadXyz(WriteBytes("nan.xyz", "1 2 3\n1 NaN 3\n")).status(), StatusCode::kBadInput,
              {"nan.xyz:2", "field 'y'"});
  ExpectError(ReadXyz(WriteBytes("nan2.xyz", "1 2 3\n1 nan 3\n")).status(), StatusCode::kBadInput,
              {"nan2.xyz:2", "field 'y'", "not finite"});
  ExpectError(ReadXyz(WriteBytes("abc.xyz", "1 2 3 0 0 x1\n")).status(), StatusCode::kBadInput,
              {"abc.xyz:1", "field 'nz'", "not a number"});
  ExpectError(ReadXyz(WriteBytes("empty.xyz", "\n# only comments\n")).status(), StatusCode::kBadInput,
              {"empty.xyz", "no points"});
}

TEST_F(XyzTest, WritingNanLeavesNoFile) {
  PointSet sample = PositionsOnly(MakeSample(5, 9));
  sample.points[2].z() = std::numeric_limits<double>::quiet_NaN();
  ExpectError(WriteXyz(Path("out.xyz"), sample), StatusCode::kBadInput, {"out.xyz", "point 2"});
  EXPECT_THAT(Listing(), IsEmpty());
}

// ---- PLY ----------------------------------------------------------------------------------------

TEST_F(PlyTest, BinaryRoundTripIsExact) {
  const PointSet sample = MakeSample(300, 10);
  ASSERT_TRUE(WritePly(Path("a.ply"), sample).ok());
  auto back = ReadPly(Path("a.ply"));
  ASSERT_TRUE(back.ok()) << back.status().ToString();
  ExpectSame(sample, *back, 0);
}

TEST_F(PlyTest, HeaderUsesLfAndNamesFormloop) {
  ASSERT_TRUE(WritePly(Path("a.ply"), MakeSample(2, 11)).ok());
  const std::string text = ReadBytes(Path("a.ply"));
  const std::string header = text.substr(0, text.find("end_header\n") + 11);
  EXPECT_EQ(header,
            "ply\nformat binary_little_endian 1.0\ncomment generated by formloop\nelement vertex 2\n"
            "property double x\nproperty double y\nproperty double z\n"
            "property double nx\nproperty double ny\nproperty double nz\nproperty int id\nproperty double t\n"
            "property double deviation_um\nproperty double intensity\nend_header\n");
  EXPECT_EQ(text.size(), header.size() + 2 * (9 * 8 + 4));
}

TEST_F(PlyTest, AsciiRoundTrip) {
  const PointSet sample = MakeSample(120, 12);
  ASSERT_TRUE(WritePly(Path("exact.ply"), sample, {.binary = false, .precision = -1}).ok());
  auto back = ReadPly(Path("exact.ply"));
  ASSERT_TRUE(back.ok()) << back.status().ToString();
  ExpectSame(sample, *back, 0);

  ASSERT_TRUE(WritePly(Path("nine.ply"), sample, {.binary = false}).ok());
  EXPECT_THAT(ReadBytes(Path("nine.ply")), HasSubstr("format ascii 1.0\ncomment generated by formloop\n"));
  back = ReadPly(Path("nine.ply"));
  ASSERT_TRUE(back.ok()) << back.status().ToString();
  ExpectSame(sample, *back, 1e-9);
}

TEST_F(PlyTest, IdsBeyondInt32RoundTrip) {
  PointSet sample = MakeSample(3, 13);
  sample.ids = {-(std::int64_t{1} << 40), 0, (std::int64_t{1} << 52) + 1};
  for (const bool binary : {true, false}) {
    ASSERT_TRUE(WritePly(Path("big.ply"), sample, {.binary = binary}).ok());
    auto back = ReadPly(Path("big.ply"));
    ASSERT_TRUE(back.ok()) << back.status().ToString();
    EXPECT_EQ(back->ids, sample.ids);
  }
  sample.ids[0] = std::int64_t{1} << 60;
  ExpectError(WritePly(Path("huge.ply"), sample), StatusCode::kBadInput, {"huge.ply", "'id'"});
  EXPECT_EQ(Listing(), std::vector<std::string>{"big.ply"});
}

TEST_F(PlyTest, ReadsBigEndianMixedTypesAndSkipsFaces) {
  std::string text =
      "ply\r\nformat binary_big_endian 1.0\r\ncomment made by hand\r\nobj_info test\r\n"
      "element vertex 2\r\nproperty float32 x\r\nproperty float y\r\nproperty float z\r\n"
      "property uchar red\r\nproperty short s\r\nproperty int32 id\r\nproperty double t\r\n"
      "element face 1\r\nproperty list uchar int vertex_indices\r\nend_header\r\n";
  for (int i = 0; i < 2; ++i) {
    AppendBigEndian<float>(1.5f + static_cast<float>(i), &text);
    AppendBigEndian<float>(-2.25f, &text);
    AppendBigEndian<float>(4.0f, &text);
    AppendBigEndian<std::uint8_t>(200, &text);
    AppendBigEndian<std::int16_t>(-300, &text);
    AppendBigEndian<std::int32_t>(70000 + i, &text);
    AppendBigEndian<double>(0.125, &text);
  }
  AppendBigEndian<std::uint8_t>(3, &text);
  for (int k = 0; k < 3; ++k) AppendBigEndian<std::int32_t>(k, &text);
  auto points = ReadPly(WriteBytes("be.ply", text));
  ASSERT_TRUE(points.ok()) << points.status().ToString();
  ASSERT_EQ(points->size(), 2u);
  EXPECT_EQ(points->points[1], Eigen::Vector3d(2.5, -2.25, 4));
  EXPECT_EQ(points->ids, (std::vector<std::int64_t>{70000, 70001}));
  EXPECT_EQ(points->times_s, (std::vector<double>{0.125, 0.125}));
  ASSERT_EQ(points->scalars.size(), 2u);
  EXPECT_EQ(points->scalars[0].name, "red");
  EXPECT_EQ(points->scalars[0].values[0], 200);
  EXPECT_EQ(points->scalars[1].name, "s");
  EXPECT_EQ(points->scalars[1].values[1], -300);
}

TEST_F(PlyTest, SkipsElementsBeforeVertex) {
  std::string text =
      "ply\nformat binary_little_endian 1.0\nelement camera 1\nproperty list uint8 float32 pose\n"
      "property uint16 flags\nelement vertex 1\nproperty double x\nproperty double y\nproperty double z\n"
      "property float normal_x\nproperty float normal_y\nproperty float normal_z\nend_header\n";
  AppendLittleEndian<std::uint8_t>(2, &text);
  AppendLittleEndian<float>(9, &text);
  AppendLittleEndian<float>(9, &text);
  AppendLittleEndian<std::uint16_t>(1, &text);
  for (const double v : {1.0, 2.0, 3.0}) AppendLittleEndian<double>(v, &text);
  for (const float v : {0.0f, 0.0f, 1.0f}) AppendLittleEndian<float>(v, &text);
  auto points = ReadPly(WriteBytes("le.ply", text));
  ASSERT_TRUE(points.ok()) << points.status().ToString();
  EXPECT_EQ(points->points[0], Eigen::Vector3d(1, 2, 3));
  ASSERT_TRUE(points->has_normals());
  EXPECT_EQ(points->normals[0], Eigen::Vector3d(0, 0, 1));
}

TEST_F(PlyTest, AsciiWithFacesAfterVertices) {
  auto points = ReadPly(WriteBytes("faces.ply",
                                   "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
                                   "property float z\nelement face 1\nproperty list uchar int vertex_indices\n"
                                   "end_header\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n"));
  ASSERT_TRUE(points.ok()) << points.status().ToString();
  EXPECT_EQ(points->size(), 3u);
  EXPECT_EQ(points->points[2], Eigen::Vector3d(0, 1, 0));
}

TEST_F(PlyTest, TruncatedBinary) {
  ASSERT_TRUE(WritePly(Path("cut.ply"), PositionsOnly(MakeSample(10, 14))).ok());
  std::string text = ReadBytes(Path("cut.ply"));
  text.resize(text.size() - 20);  // 10 vertices of 24 bytes: 220 of 240 bytes are left
  const fs::path path = WriteBytes("cut.ply", text);
  ExpectError(ReadPly(path).status(), StatusCode::kBadInput,
              {"cut.ply", "vertex 9", "expected 240 bytes", "only 220 bytes", "Fix:"});
}

TEST_F(PlyTest, ListPropertyOnVertex) {
  ExpectError(ReadPly(WriteBytes("list.ply",
                                 "ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\n"
                                 "property float z\nproperty list uchar float extra\nend_header\n1 2 3 1 4\n"))
                  .status(),
              StatusCode::kBadInput, {"list.ply:7", "field 'extra'", "list"});
}

TEST_F(PlyTest, AsciiErrorsNameTheLine) {
  const std::string header =
      "ply\nformat ascii 1.0\nelement vertex 2\nproperty double x\nproperty double y\nproperty double z\n"
      "property int id\nend_header\n";
  ExpectError(ReadPly(WriteBytes("tokens.ply", header + "1 2 3 4\n1 2 3\n")).status(), StatusCode::kBadInput,
              {"tokens.ply:10", "vertex 1", "3 values", "4 properties"});
  ExpectError(ReadPly(WriteBytes("word.ply", header + "1 2 3 4\n1 two 3 4\n")).status(), StatusCode::kBadInput,
              {"word.ply:10", "field 'y'", "'two' is not a number"});
  ExpectError(ReadPly(WriteBytes("nan.ply", header + "1 2 nan 4\n1 2 3 4\n")).status(), StatusCode::kBadInput,
              {"nan.ply:9", "field 'z'", "not finite"});
  ExpectError(ReadPly(WriteBytes("id.ply", header + "1 2 3 4\n1 2 3 4.5\n")).status(), StatusCode::kBadInput,
              {"id.ply:10", "field 'id'", "not an integer"});
  ExpectError(ReadPly(WriteBytes("short.ply", header + "1 2 3 4\n")).status(), StatusCode::kBadInput,
              {"short.ply:10", "1 of 2 vertices"});
}

TEST_F(PlyTest, BinaryNanNamesVertexAndField) {
  std::string text =
      "ply\nformat binary_little_endian 1.0\nelement vertex 2\nproperty double x\nproperty double y\n"
      "property double z\nend_header\n";
  const std::size_t header_size = text.size();
  for (const double v : {1.0, 2.0, 3.0, 4.0, std::numeric_limits<double>::quiet_NaN(), 6.0}) {
    AppendLittleEndian<double>(v, &text);
  }
  ExpectError(ReadPly(WriteBytes("nan.ply", text)).status(), StatusCode::kBadInput,
              {"nan.ply", "field 'y'", "vertex 1", "byte offset " + std::to_string(header_size + 32), "Fix:"});
}

TEST_F(PlyTest, HeaderErrors) {
  ExpectError(ReadPly(WriteBytes("empty.ply", "")).status(), StatusCode::kBadInput, {"empty.ply", "no points"});
  ExpectError(ReadPly(WriteBytes("nope.ply", "solid cube\n")).status(), StatusCode::kBadInput,
              {"nope.ply:1", "not a PLY file"});
  ExpectError(ReadPly(WriteBytes("type.ply",
                                 "ply\nformat ascii 1.0\nelement vertex 1\nproperty int128 x\n"
                                 "end_header\n1\n"))
                  .status(),
              StatusCode::kBadInput, {"type.ply:4", "field 'x'", "Fix:"});
  ExpectError(ReadPly(WriteBytes("noz.ply",
                                 "ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\n"
                                 "property float y\nend_header\n1 2\n"))
                  .status(),
              StatusCode::kBadInput, {"noz.ply:3", "field 'z'"});
  ExpectError(ReadPly(WriteBytes("zero.ply",
                                 "ply\nformat ascii 1.0\nelement vertex 0\nproperty float x\n"
                                 "property float y\nproperty float z\nend_header\n"))
                  .status(),
              StatusCode::kBadInput, {"zero.ply:3", "no points"});
  ExpectError(ReadPly(WriteBytes("normals.ply",
                                 "ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\n"
                                 "property float y\nproperty float z\nproperty float nx\n"
                                 "end_header\n1 2 3 0\n"))
                  .status(),
              StatusCode::kBadInput, {"normals.ply:3", "field 'ny'"});
  ExpectError(ReadPly(WriteBytes("open.ply", "ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\n")).status(),
              StatusCode::kBadInput, {"open.ply", "end_header"});
  ExpectError(ReadPly(WriteBytes("fmt.ply", "ply\nformat binary_middle_endian 1.0\nend_header\n")).status(),
              StatusCode::kBadInput, {"fmt.ply:2", "binary_middle_endian"});
}

TEST_F(PlyTest, WritingNanLeavesNoFile) {
  PointSet sample = MakeSample(10, 15);
  sample.normals[3].x() = std::numeric_limits<double>::quiet_NaN();
  ExpectError(WritePly(Path("out.ply"), sample), StatusCode::kBadInput, {"out.ply", "normal 3"});
  ExpectError(WritePly(Path("missing") / "out.ply", MakeSample(3, 15)), StatusCode::kIoError, {"out.ply"});
  sample = MakeSample(3, 15);
  sample.SetScalar("two words", {1, 2, 3});
  ExpectError(WritePly(Path("out.ply"), sample), StatusCode::kBadInput, {"out.ply", "'two words'"});
  EXPECT_THAT(Listing(), IsEmpty());
}

// ---- PCD ----------------------------------------------------------------------------------------

TEST_F(PcdTest, BinaryRoundTripIsExact) {
  const PointSet sample = MakeSample(300, 16);
  ASSERT_TRUE(WritePcd(Path("a.pcd"), sample).ok());
  const std::string text = ReadBytes(Path("a.pcd"));
  EXPECT_THAT(text, HasSubstr("\nFIELDS x y z normal_x normal_y normal_z id t deviation_um intensity\n"));
  EXPECT_THAT(text, HasSubstr("\nSIZE 8 8 8 8 8 8 4 8 8 8\nTYPE F F F F F F I F F F\n"));
  EXPECT_THAT(text, HasSubstr("\nWIDTH 300\n"));
  EXPECT_THAT(text, HasSubstr("\nDATA binary\n"));
  auto back = ReadPcd(Path("a.pcd"));
  ASSERT_TRUE(back.ok()) << back.status().ToString();
  ExpectSame(sample, *back, 0);
}

TEST_F(PcdTest, AsciiRoundTrip) {
  const PointSet sample = MakeSample(100, 17);
  ASSERT_TRUE(WritePcd(Path("nine.pcd"), sample, {.binary = false}).ok());
  EXPECT_THAT(ReadBytes(Path("nine.pcd")), HasSubstr("\nDATA ascii\n"));
  auto back = ReadPcd(Path("nine.pcd"));
  ASSERT_TRUE(back.ok()) << back.status().ToString();
  ExpectSame(sample, *back, 1e-9);

  ASSERT_TRUE(WritePcd(Path("exact.pcd"), sample, {.binary = false, .precision = -1}).ok());
  back = ReadPcd(Path("exact.pcd"));
  ASSERT_TRUE(back.ok()) << back.status().ToString();
  ExpectSame(sample, *back, 0);
}

TEST_F(PcdTest, PclReadsOurFileAndWeReadPcls) {
  const PointSet sample = MakeSample(20, 18);
  ASSERT_TRUE(WritePcd(Path("ours.pcd"), sample).ok());
  pcl::PCLPointCloud2 cloud;
  ASSERT_EQ(pcl::io::loadPCDFile(Path("ours.pcd").string(), cloud), 0);
  EXPECT_EQ(cloud.width * cloud.height, 20u);
  ASSERT_EQ(cloud.fields.size(), 10u);
  EXPECT_EQ(cloud.fields[3].name, "normal_x");

  pcl::PointCloud<pcl::PointNormal> theirs;
  for (std::size_t i = 0; i < sample.size(); ++i) {
    pcl::PointNormal p;
    p.x = 0.5f * static_cast<float>(i);
    p.y = 1.0f;
    p.z = -2.0f;
    p.normal_x = 0;
    p.normal_y = 0;
    p.normal_z = 1;
    p.curvature = 0.25f;
    theirs.push_back(p);
  }
  ASSERT_EQ(pcl::io::savePCDFileBinary(Path("theirs.pcd").string(), theirs), 0);
  auto back = ReadPcd(Path("theirs.pcd"));
  ASSERT_TRUE(back.ok()) << back.status().ToString();
  ASSERT_EQ(back->size(), 20u);
  EXPECT_EQ(back->points[3], Eigen::Vector3d(1.5, 1, -2));
  ASSERT_TRUE(back->has_normals());
  EXPECT_EQ(back->normals[3], Eigen::Vector3d(0, 0, 1));
  ASSERT_NE(back->FindScalar("curvature"), nullptr);
  EXPECT_EQ(back->FindScalar("curvature")->at(7), 0.25);
}

TEST_F(PcdTest, NanPointIsRejected) {
  pcl::PointCloud<pcl::PointXYZ> cloud;
  cloud.push_back({1, 2, 3});
  cloud.push_back({std::numeric_limits<float>::quiet_NaN(), 0, 0});
  cloud.is_dense = false;
  ASSERT_EQ(pcl::io::savePCDFileBinary(Path("nan.pcd").string(), cloud), 0);
  ExpectError(ReadPcd(Path("nan.pcd")).status(), StatusCode::kBadInput,
              {"nan.pcd", "field 'x'", "point 1", "not finite", "Fix:"});
  ASSERT_EQ(pcl::io::savePCDFileASCII(Path("nan_ascii.pcd").string(), cloud), 0);
  ExpectError(ReadPcd(Path("nan_ascii.pcd")).status(), StatusCode::kBadInput, {"nan_ascii.pcd", "point 1"});
}

TEST_F(PcdTest, TruncatedBinary) {
  ASSERT_TRUE(WritePcd(Path("cut.pcd"), PositionsOnly(MakeSample(10, 19))).ok());
  std::string text = ReadBytes(Path("cut.pcd"));
  text.resize(text.size() - 20);
  ExpectError(ReadPcd(WriteBytes("cut.pcd", text)).status(), StatusCode::kBadInput,
              {"cut.pcd", "point 9", "expected 240 bytes", "only 220 bytes"});
}

TEST_F(PcdTest, BadFilesAreReportedQuietly) {
  ::testing::internal::CaptureStderr();
  ExpectError(ReadPcd(WriteBytes("junk.pcd", "this is not a point cloud\n")).status(), StatusCode::kBadInput,
              {"junk.pcd", "Fix:"});
  ExpectError(ReadPcd(WriteBytes("empty.pcd", "")).status(), StatusCode::kBadInput, {"empty.pcd", "no points"});
  ExpectError(ReadPcd(Path("missing.pcd")).status(), StatusCode::kNotFound, {"missing.pcd"});
  const std::string header_xy =
      "VERSION .7\nFIELDS x y\nSIZE 4 4\nTYPE F F\nCOUNT 1 1\nWIDTH 1\nHEIGHT 1\nPOINTS 1\nDATA ascii\n1 2\n";
  ExpectError(ReadPcd(WriteBytes("noz.pcd", header_xy)).status(), StatusCode::kBadInput, {"noz.pcd", "field 'z'"});
  const std::string partial =
      "VERSION .7\nFIELDS x y z normal_x\nSIZE 4 4 4 4\nTYPE F F F F\nCOUNT 1 1 1 1\nWIDTH 1\nHEIGHT 1\n"
      "POINTS 1\nDATA ascii\n1 2 3 0\n";
  ExpectError(ReadPcd(WriteBytes("normals.pcd", partial)).status(), StatusCode::kBadInput,
              {"normals.pcd", "field 'normal_y'"});
  const std::string id =
      "VERSION .7\nFIELDS x y z id\nSIZE 4 4 4 4\nTYPE F F F F\nCOUNT 1 1 1 1\nWIDTH 1\nHEIGHT 1\n"
      "POINTS 1\nDATA ascii\n1 2 3 0.5\n";
  ExpectError(ReadPcd(WriteBytes("id.pcd", id)).status(), StatusCode::kBadInput, {"id.pcd", "field 'id'"});
  EXPECT_EQ(::testing::internal::GetCapturedStderr(), "");
}

TEST_F(PcdTest, WritingNanLeavesNoFile) {
  PointSet sample = MakeSample(10, 20);
  sample.times_s[9] = std::numeric_limits<double>::infinity();
  ExpectError(WritePcd(Path("out.pcd"), sample), StatusCode::kBadInput, {"out.pcd", "time 9"});
  ExpectError(WritePcd(Path("missing") / "out.pcd", MakeSample(3, 20)), StatusCode::kIoError, {"out.pcd"});
  EXPECT_THAT(Listing(), IsEmpty());
}

}  // namespace
}  // namespace formloop
