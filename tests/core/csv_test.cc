// The one CSV reader (core/csv.h) and the locale-free number text (core/number_text.h): line numbers
// count blank and comment lines, cells are trimmed and unquoted, a trailing comma is an empty cell,
// comments reach a reader that asks for them, a table refuses ragged rows and names the file, line and
// column of a bad number; FormatSignificant is printf's %g to the character.

#include "core/csv.h"

#include <cstdio>
#include <string>
#include <vector>

#include <gtest/gtest.h>

#include "core/number_text.h"

namespace formloop {
namespace {

TEST(CsvReaderTest, RowsCellsLineNumbersAndComments) {
  const std::string text = "# a comment\r\n\n x , \"y\",z,\n1,2,3,\n   \n# options: {\"a\": 1, \"b\": 2}\n4,5,6,7";
  CsvReader plain(text);
  ASSERT_TRUE(plain.Next());
  EXPECT_EQ(plain.line_number(), 3);
  EXPECT_EQ(plain.cells(), (std::vector<std::string_view>{"x", "y", "z", ""}));
  ASSERT_TRUE(plain.Next());
  EXPECT_EQ(plain.line_number(), 4);
  ASSERT_TRUE(plain.Next());
  EXPECT_EQ(plain.line_number(), 7);
  EXPECT_EQ(plain.cells().size(), 4u);
  EXPECT_FALSE(plain.Next());

  CsvReader with_comments(text, /*comments=*/true);
  std::vector<std::string> comments;
  while (with_comments.Next()) {
    if (with_comments.is_comment()) comments.emplace_back(with_comments.line());
  }
  EXPECT_EQ(comments, (std::vector<std::string>{"# a comment", "# options: {\"a\": 1, \"b\": 2}"}));
}

TEST(CsvTableTest, ColumnsNumbersAndErrorsNameTheFileLineAndColumn) {
  auto table = ParseCsvTable("id,value\n# note\n1, 2.5\n2,abc\n", "t.csv");
  ASSERT_TRUE(table.ok()) << table.status().ToString();
  EXPECT_EQ(table->header_line, 1);
  EXPECT_EQ(table->lines, (std::vector<long>{3, 4}));
  EXPECT_EQ(table->comments.size(), 1u);
  const auto c = table->Column("value", "--value");
  ASSERT_TRUE(c.ok());
  double v = 0;
  ASSERT_TRUE(table->Number(0, *c, &v).ok());
  EXPECT_EQ(v, 2.5);
  const Status bad = table->Number(1, *c, &v);
  EXPECT_EQ(bad.code(), StatusCode::kBadInput);
  for (const char* want : {"t.csv", "4", "value", "'abc' is not a finite number"}) {
    EXPECT_NE(bad.message().find(want), std::string::npos) << want << " in " << bad.message();
  }
  const auto missing = table->Column("z", "--coords");
  ASSERT_FALSE(missing.ok());
  EXPECT_NE(missing.status().message().find("columns: id, value"), std::string::npos) << missing.status().message();

  const auto ragged = ParseCsvTable("a,b\n1,2,3\n", "r.csv");
  ASSERT_FALSE(ragged.ok());
  EXPECT_NE(ragged.status().message().find("row has 3 cells, the header 2"), std::string::npos);
  EXPECT_FALSE(ParseCsvTable("# only a comment\n", "e.csv").ok());
  EXPECT_TRUE(ParseCsvTable("# only a comment\n", "e.csv", /*require_rows=*/false).ok());
}

TEST(NumberTextTest, SignificantIsPrintfG) {
  char buffer[64];
  for (double x : {0.0, -0.0, 1.0, 0.1, 123456789.0, 1.5e-7, -2.345678e12, 0.000012345, 99999.95, 1e300}) {
    for (int digits : {1, 2, 4, 6, 12, 17}) {
      std::snprintf(buffer, sizeof buffer, "%.*g", digits, x);
      EXPECT_EQ(FormatSignificant(x, digits), buffer) << x << " " << digits;
    }
  }
  EXPECT_EQ(FormatSignificant(0.000012345, 3), "1.23e-05");
  EXPECT_EQ(FormatFixed(-0.0004, 3), "0.000");
  double parsed = 0;
  EXPECT_TRUE(ParseDouble("+1.25", &parsed));
  EXPECT_EQ(parsed, 1.25);
  EXPECT_FALSE(ParseDouble(" 1", &parsed));
}

}  // namespace
}  // namespace formloop
