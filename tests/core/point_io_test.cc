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
#include "tests/core/point_io_test_support.h"
#include "tests/support/locale.h"

namespace formloop {
namespace {

namespace fs = std::filesystem;
using ::testing::HasSubstr;
using ::testing::IsEmpty;

using namespace point_io_test;  // NOLINT: the shared fixtures and helpers

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
  // A number a double cannot hold is told apart from text that is no number (the readers say which).
  for (const char* huge : {"1e400", "-1e400", "+1e400", "1e-400"}) EXPECT_TRUE(NumberBeyondDoubleRange(huge)) << huge;
  for (const char* other : {"1.5", "1e300", "abc", "1e400x", "", "+-1e400"}) {
    EXPECT_FALSE(NumberBeyondDoubleRange(other)) << other;
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
  // formloop's marker (core/output_file.h), then the header.
  EXPECT_EQ(text.rfind(kPointFileMarker, 0), 0u);
  const std::size_t header = std::string(kPointFileMarker).size();
  EXPECT_EQ(text.substr(header, text.find('\n', header) - header), "x,y,z,nx,ny,nz,id,t,deviation_um,intensity");
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

}  // namespace
}  // namespace formloop
