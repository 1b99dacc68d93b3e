// The bad-input suite of issue 17 (cases.h): every case must be refused with its exit code, a message that
// names the file, line or field, and nothing written or deleted in its folder or the fixtures. One ctest
// test per case.

#include <set>

#include <gtest/gtest.h>

#include "cases.h"
#include "harness.h"

namespace formloop::bad_input {
namespace {

const std::vector<Case>& Cases() {
  static const std::vector<Case> cases = AllCases();
  return cases;
}

class BadInputTest : public ::testing::TestWithParam<std::size_t> {};

TEST_P(BadInputTest, RefusedClearlyWithNothingWrittenOrDeleted) {
  const Case& c = Cases()[GetParam()];
  std::string error;
  const fs::path fixtures = EnsureFixtures(FORMLOOP_BINARY, FixtureRoot(), &error);
  ASSERT_FALSE(fixtures.empty()) << error;
  const fs::path work = fs::temp_directory_path() / ("formloop-bad-input-" + std::to_string(::getpid()));
  const Result r = RunCase(c, FORMLOOP_BINARY, fixtures, work, fs::path(FORMLOOP_SOURCE_DIR) / "data");
  EXPECT_EQ(r.outcome, Outcome::kClear) << c.reader << " | formloop " << c.args << "\n" << r.Describe();
  EXPECT_EQ(r.exit_code, c.exit_code) << r.err;
  EXPECT_TRUE(r.missing.empty()) << r.err;
  EXPECT_TRUE(r.changes.empty());
  std::error_code ec;
  if (!HasFailure()) fs::remove_all(work, ec);
}

TEST(BadInputCatalogueTest, HasAtLeast120UniquelyNamedCasesOverEveryReader) {
  std::set<std::string> names, readers;
  for (const Case& c : Cases()) {
    EXPECT_TRUE(names.insert(c.name).second) << "repeated case name " << c.name;
    readers.insert(c.reader);
    EXPECT_FALSE(c.mentions.empty()) << c.name << " asserts nothing about its message";
  }
  EXPECT_GE(Cases().size(), 120u);
  for (const char* reader : {"point file", "STEP/IGES", "part JSON", "model JSON", "probe profile", "case JSON",
                             "probe log", "probing plan", "G-code", "tool-path file", "side file", "field CSV",
                             "case library", "output folder", "output path", "options", "machine profile"}) {
    EXPECT_TRUE(readers.count(reader)) << "no case for " << reader;
  }
}

INSTANTIATE_TEST_SUITE_P(Cases, BadInputTest, ::testing::Range<std::size_t>(0, Cases().size()),
                         [](const ::testing::TestParamInfo<std::size_t>& param) { return Cases()[param.param].name; });

}  // namespace
}  // namespace formloop::bad_input
