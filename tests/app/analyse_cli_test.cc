// `formloop analyse moran` through the binary: the PySAL St Louis case, the weight kinds, the LISA
// table, residual Moran, and bad input (missing column, non-numeric cell, GAL id not in the data).

#include <cmath>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <sstream>
#include <string>
#include <vector>

#include <unistd.h>

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include "core/random.h"
#include "tests/support/run_binary.h"

namespace formloop::app {
namespace {

namespace fs = std::filesystem;
const std::string kData = std::string(FORMLOOP_REFERENCE_DIR) + "/moran-pysal/";

class AnalyseCliTest : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = fs::temp_directory_path() / ("formloop-analyse-" + std::to_string(::getpid()) + "-" +
                                        ::testing::UnitTest::GetInstance()->current_test_info()->name());
    fs::remove_all(dir_);
    fs::create_directories(dir_);
  }
  void TearDown() override { fs::remove_all(dir_); }

  std::string Write(const std::string& name, const std::string& text) const {
    const fs::path path = dir_ / name;
    std::ofstream(path) << text;
    return path.string();
  }
  // stl_hom.txt (GeoDa text: a "78,4" line, then a quoted header) as a plain CSV with a row number id
  // (stl.gal numbers the units 1..78 in file order) and made-up planar coordinates.
  std::string StLouisCsv() const {
    std::ifstream in(kData + "stl_hom.txt");
    std::string line;
    std::getline(in, line);
    std::getline(in, line);
    std::ostringstream out;
    out << "# St Louis homicides (libpysal stl_hom.txt)\nrow,FIPSNO,HR8488,HR8893,HC8488,u,v\n";
    Rng rng(3);
    for (int row = 1; std::getline(in, line); ++row) {
      if (line.empty()) continue;
      out << row << "," << line << "," << rng.Uniform(0, 10) << "," << rng.Uniform(0, 10) << "\n";
    }
    return Write("stl.csv", out.str());
  }
  fs::path dir_;
};

nlohmann::json Analyse(const std::string& args, int expected_code = 0, std::string* err_out = nullptr) {
  std::string out, err;
  const int code = testing::RunFormloop(args, &out, &err);
  EXPECT_EQ(code, expected_code) << args << "\n" << err;
  if (err_out != nullptr) *err_out = err;
  if (code != 0) return nullptr;
  return nlohmann::json::parse(out);
}

TEST_F(AnalyseCliTest, StLouisThroughTheCliMatchesPysal) {
  const std::string csv = StLouisCsv();
  const auto j = Analyse("analyse moran --points " + csv + " --value HR8893 --weights " + kData +
                         "stl.gal --style W --permutations 999 --seed 7");
  ASSERT_FALSE(j.is_null());
  EXPECT_EQ(j["n"], 78);
  EXPECT_NEAR(j["I"].get<double>(), 0.24365582621771659, 1e-12 * 0.2437);
  EXPECT_NEAR(j["p_normality"].get<double>(), 0.00013573931385468807, 1e-9 * 0.000136);
  EXPECT_NEAR(j["expected"].get<double>(), -1.0 / 77, 1e-16);
  EXPECT_EQ(j["weights"]["kind"], "gal");
  EXPECT_EQ(j["islands"]["policy"], "refuse");
  EXPECT_LE(j["permutation"]["p_sim"].get<double>(), 0.005);
  // The same seed gives the same permutation result.
  const auto again = Analyse("analyse moran --points " + csv + " --value HR8893 --weights " + kData +
                             "stl.gal --style W --permutations 999 --seed 7");
  EXPECT_EQ(j["permutation"], again["permutation"]);
}

TEST_F(AnalyseCliTest, Sids2WithAnIdColumnMatchesPysal) {
  const auto j = Analyse("analyse moran --points " + kData + "sids2_sidr74.csv --value SIDR74 --weights " + kData +
                         "sids2.gal --id FIPSNO --style W");
  ASSERT_FALSE(j.is_null());
  EXPECT_NEAR(j["I"].get<double>(), 0.24772519320480135, 1e-12 * 0.2477);
}

TEST_F(AnalyseCliTest, ResidualMoranAndLisaTable) {
  const std::string csv = StLouisCsv();
  const std::string lisa = (dir_ / "lisa.csv").string();
  const auto j = Analyse("analyse moran --points " + csv + " --value HR8893 --regressors HR8488 --weights " + kData +
                         "stl.gal --style W --lisa " + lisa + " --lisa-permutations 99 --alpha 0.05");
  ASSERT_FALSE(j.is_null());
  EXPECT_EQ(j["residual"]["p"], 2);
  EXPECT_EQ(j["residual"]["regressors"].size(), 2u);
  EXPECT_LT(j["residual"]["expected"].get<double>(), 0);
  EXPECT_EQ(j["lisa"]["n"], 78);
  std::ifstream in(lisa);
  std::string line;
  std::getline(in, line);
  EXPECT_EQ(line.rfind("# formloop", 0), 0u) << line;  // the marker (core/output_file.h)
  std::getline(in, line);
  EXPECT_EQ(line, "id,value,I_i,lag,expected,variance,z,p_analytical,p_sim,quadrant,cluster");
  int rows = 0, significant = 0;
  while (std::getline(in, line)) {
    ++rows;
    significant += line.find("not significant") == std::string::npos;
  }
  EXPECT_EQ(rows, 78);
  int counted = 0;
  for (const char* c : {"HH", "LL", "HL", "LH"}) counted += j["lisa"]["clusters"][c].get<int>();
  EXPECT_EQ(significant, counted);
}

TEST_F(AnalyseCliTest, KnnDelaunayAndBandWeights) {
  const std::string csv = StLouisCsv();
  const auto knn = Analyse("analyse moran --points " + csv + " --value HR8893 --knn 5 --style B");
  const auto delaunay = Analyse("analyse moran --points " + csv + " --value HR8893 --delaunay --coords u,v --style W");
  const auto band = Analyse("analyse moran --points " + csv + " --value HR8893 --band 0.6 --style W --islands zero");
  ASSERT_FALSE(knn.is_null() || delaunay.is_null() || band.is_null());
  EXPECT_EQ(knn["weights"]["nonzero"], 78 * 5);
  EXPECT_EQ(knn["S0"], 78 * 5);
  EXPECT_EQ(delaunay["weights"]["kind"], "delaunay");
  EXPECT_EQ(band["n"], 78);
  EXPECT_EQ(band["islands"]["policy"], "zero");
  EXPECT_EQ(band["islands"]["islands"], band["weights"]["islands"]);
  if (band["islands"]["islands"].get<int>() > 0) {
    // Refused by default, with the fix named.
    std::string err;
    Analyse("analyse moran --points " + csv + " --value HR8893 --band 0.6 --style W", 2, &err);
    EXPECT_NE(err.find("islands"), std::string::npos) << err;
    const auto dropped =
        Analyse("analyse moran --points " + csv + " --value HR8893 --band 0.6 --style W --islands drop");
    EXPECT_LT(dropped["n"].get<int>(), 78);
    EXPECT_EQ(dropped["islands"]["dropped_ids"].size(), static_cast<std::size_t>(78 - dropped["n"].get<int>()));
  }
}

// The global --threads: k-NN weights, Moran's I and the LISA table of 20,000 points (several parallel
// chunks) are the same bytes on one thread and on two; a negative count is a usage error.
TEST_F(AnalyseCliTest, OneAndTwoThreadsGiveTheSameBytes) {
  std::ostringstream text;
  text << "id,u,v,z\n";
  Rng rng(26);
  for (int i = 0; i < 20000; ++i) {
    const double u = rng.Uniform(0, 100), v = rng.Uniform(0, 100);
    text << i << "," << u << "," << v << "," << std::sin(u / 9) * std::cos(v / 7) + rng.Normal(0, 0.3) << "\n";
  }
  const std::string csv = Write("points.csv", text.str());
  std::string outputs[2], tables[2];
  for (int threads : {1, 2}) {
    const std::string lisa = (dir_ / "lisa.csv").string();  // one name: stdout names it; --force replaces the first
    std::string err;
    const int code = testing::RunFormloop("--threads " + std::to_string(threads) + " analyse moran --points " + csv +
                                              " --value z --coords u,v --knn 8 --style W --lisa " + lisa +
                                              " --lisa-permutations 0 --force",
                                          &outputs[threads - 1], &err);
    ASSERT_EQ(code, 0) << err;
    std::ifstream in(lisa);
    tables[threads - 1] = std::string(std::istreambuf_iterator<char>(in), {});
  }
  EXPECT_EQ(outputs[0], outputs[1]);
  EXPECT_EQ(tables[0], tables[1]);
  EXPECT_GT(tables[0].size(), 20000u);
  EXPECT_EQ(nlohmann::json::parse(outputs[0])["weights"]["nonzero"], 20000 * 8);
  std::string out, err;
  EXPECT_EQ(testing::RunFormloop("--threads -1 analyse moran --points " + csv + " --value z --knn 8", &out, &err), 2);
}

TEST_F(AnalyseCliTest, BadInputNamesFileLineColumnAndFix) {
  const std::string csv = StLouisCsv();
  std::string err;
  Analyse("analyse moran --points " + csv + " --value HR9999 --knn 4 --style W", 2, &err);
  EXPECT_NE(err.find("stl.csv"), std::string::npos) << err;
  EXPECT_NE(err.find("no column 'HR9999'"), std::string::npos) << err;
  EXPECT_NE(err.find("Fix:"), std::string::npos) << err;

  const std::string bad = Write("bad.csv", "id,x,y,z\n1,0,0,1\n2,1,0,2\n3,0,1,abc\n4,1,1,3\n5,2,2,1\n");
  Analyse("analyse moran --points " + bad + " --value z --knn 2 --style W", 2, &err);
  EXPECT_NE(err.find("bad.csv:4"), std::string::npos) << err;
  EXPECT_NE(err.find("'z'"), std::string::npos) << err;
  EXPECT_NE(err.find("'abc' is not a finite number"), std::string::npos) << err;
  EXPECT_NE(err.find("Fix:"), std::string::npos) << err;

  const std::string ragged = Write("ragged.csv", "id,x,y,z\n1,0,0,1\n2,1,0\n");
  Analyse("analyse moran --points " + ragged + " --value z --knn 1 --style W", 2, &err);
  EXPECT_NE(err.find("ragged.csv:3"), std::string::npos) << err;

  // A GAL id the data do not have.
  const std::string data = Write("five.csv", "id,x,y,z\nA,0,0,1\nB,1,0,2\nC,0,1,5\nD,1,1,3\nE,2,2,1\n");
  const std::string gal = Write("five.gal", "5\nA 1\nB\nB 1\nA\nC 1\nD\nD 1\nC\nF 1\nA\n");
  Analyse("analyse moran --points " + data + " --value z --weights " + gal + " --id id --style W", 2, &err);
  EXPECT_NE(err.find("five.gal:10"), std::string::npos) << err;
  EXPECT_NE(err.find("id 'F' is not in the data"), std::string::npos) << err;

  Analyse("analyse moran --points " + data + " --value z --knn 2 --delaunay --style W", 2, &err);
  EXPECT_NE(err.find("exactly one of"), std::string::npos) << err;
  Analyse("analyse moran --points " + data + " --value z --band 0 --style W", 2, &err);
  EXPECT_NE(err.find("'--band': must be a positive distance"), std::string::npos) << err;
  Analyse("analyse moran --points " + data + " --value z --knn 0 --style W", 2, &err);
  EXPECT_NE(err.find("'--knn': must be at least 1"), std::string::npos) << err;
  Analyse("analyse moran --points " + data + " --value z --knn 2 --style Q", 2, &err);
  EXPECT_NE(err.find("--style"), std::string::npos) << err;
  Analyse("analyse moran --points " + data + " --value z --knn 2 --style W --islands keep", 2, &err);
  EXPECT_NE(err.find("refuse, drop or zero"), std::string::npos) << err;
  std::string out;
  EXPECT_EQ(testing::RunFormloop("analyse", &out), 2);  // the bare command needs a subcommand for now
  EXPECT_TRUE(out.empty());
}

}  // namespace
}  // namespace formloop::app
