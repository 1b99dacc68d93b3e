// `formloop nc distribute` and `formloop nc compensate --program` / `nc check` through the binary (issue
// 23): a distributed program with its report, a refusal that writes nothing, and a program the test
// wrote on the reference cylinder (fitted to STEP) compensated, checked and found out when corrupted.

#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <string>
#include <vector>

#include <gtest/gtest.h>

#include "core/atomic_file.h"
#include "core/json_io.h"
#include "nc-gen/gcode_reader.h"
#include "tests/support/run_binary.h"
#include "tests/support/test_dir.h"

namespace formloop::app {
namespace {

namespace fs = std::filesystem;

class NcProgramCliTest : public ::testing::Test {
 protected:
  void SetUp() override { dir_ = testing::FreshTestDir("formloop-nc-program"); }
  void TearDown() override { fs::remove_all(dir_); }
  std::string Path(const std::string& name) const { return (dir_ / name).string(); }
  int Run(const std::string& args) { return testing::RunFormloop(args, &out_, &err_); }
  void Write(const std::string& name, const std::string& text) { ASSERT_TRUE(WriteFileAtomic(dir_ / name, text).ok()); }
  fs::path dir_;
  std::string out_, err_;
};

TEST_F(NcProgramCliTest, DistributeWritesProgramAndReportOrNothing) {
  Write("p.ngc", "%\nG21 G90 G17\nG0 X0 Y0 Z0\nM57\nG1 X50. F300\nG1 X100.\nM59 P1\nG1 X200.\nM58\nM30\n%\n");
  Write("d.csv", "index,dx,dy,dz\n1,0.003,0,0\n");
  ASSERT_EQ(Run("nc distribute " + Path("p.ngc") + " --deviations " + Path("d.csv") + " --out " + Path("o.ngc") +
                " --decimals 4 --report " + Path("r.json")),
            0)
      << err_;
  const std::string out = ReadFile(dir_ / "o.ngc").value();
  EXPECT_NE(out.find("G1 X50.0015 F300\n"), std::string::npos) << out;
  EXPECT_NE(out.find("G1 X100.003\n"), std::string::npos) << out;
  EXPECT_NE(out.find("G1 X200.\n"), std::string::npos) << out;
  const auto summary = nlohmann::json::parse(out_);
  EXPECT_EQ(summary["corrected_blocks"], 2);
  const auto report = ReadJsonFile(dir_ / "r.json");
  ASSERT_TRUE(report.ok());
  EXPECT_EQ((*report)["interval_list"].size(), 2u);
  // An index not in the table: exit 2, the line, nothing written (not the program, not the report).
  Write("d2.csv", "index,dx,dy,dz\n2,0.003,0,0\n");
  EXPECT_EQ(Run("nc distribute " + Path("p.ngc") + " --deviations " + Path("d2.csv") + " --out " + Path("o2.ngc") +
                " --report " + Path("r2.json")),
            2);
  EXPECT_NE(err_.find("p.ngc:7: E_NO_DEVIATION"), std::string::npos) << err_;
  EXPECT_FALSE(fs::exists(dir_ / "o2.ngc"));
  EXPECT_FALSE(fs::exists(dir_ / "r2.json"));
  for (const auto& e : fs::directory_iterator(dir_)) {
    EXPECT_EQ(e.path().string().find(".tmp-"), std::string::npos) << e.path();
  }
}

std::string Num(double v) { return nc::FormatCoordinate(v, 6); }

TEST_F(NcProgramCliTest, CompensateAShopProgramAndCheckIt) {
  ASSERT_EQ(Run("fit analytic:cylinder --out " + Path("Q.step")), 0) << err_;
  // Ball-centre circles about the cylinder's axis (X50 Z-70, radius 80 + 3): G18 arcs and a helix.
  auto tip = [](double phi_deg, double y) {
    const double p = phi_deg * std::acos(-1.0) / 180;
    return std::array<double, 3>{50 + 83 * std::sin(p), y, -73 + 83 * std::cos(p)};
  };
  const auto a = tip(-30, 5), b = tip(30, 5), c = tip(-20, 65);
  std::string shop = "G21 G90 G94 G18\nG0 X" + Num(a[0]) + " Y5. Z" + Num(a[2] + 10) + "\nG1 Z" + Num(a[2]) + " F800\n";
  shop += "G3 X" + Num(b[0]) + " Y5. Z" + Num(b[2]) + " I" + Num(50 - a[0]) + " K" + Num(-73 - a[2]) + "\n";
  shop += "G1 Y45.\nG2 X" + Num(c[0]) + " Y65. Z" + Num(c[2]) + " I" + Num(50 - b[0]) + " K" + Num(-73 - b[2]) + "\n";
  shop += "G1 Y85.\nG0 Z30.\nM30\n";
  Write("shop.ngc", shop);
  std::string field = "u,v,ds_um\n";
  for (int u = 0; u <= 100; u += 25) {
    for (int v = 0; v <= 90; v += 30)
      field += std::to_string(u) + "," + std::to_string(v) + "," + Num(15 + 0.2 * u - 0.1 * v) + "\n";
  }
  Write("ds.csv", field);
  ASSERT_EQ(Run("nc compensate --program " + Path("shop.ngc") + " --surface " + Path("Q.step") +
                " --ball-radius-mm 3 --field " + Path("ds.csv") + " --out " + Path("comp.ngc") + " --side " +
                Path("side.csv")),
            0)
      << err_;
  const auto summary = nlohmann::json::parse(out_);
  EXPECT_EQ(summary["arcs_split"], 2);
  EXPECT_GT(summary["points_on_q"].get<int>(), 100);
  EXPECT_GT(summary["max_offset_um"].get<double>(), 20);
  const std::string check = "nc check --nominal " + Path("shop.ngc") + " --compensated " + Path("comp.ngc") +
                            " --side " + Path("side.csv") + " --field " + Path("ds.csv");
  ASSERT_EQ(Run(check), 0) << err_ << out_;
  EXPECT_TRUE(nlohmann::json::parse(out_)["field_checked"].get<bool>());
  // Corrupt one split vertex by 1 µm in Z: exit 1, the block named.
  std::vector<std::string> lines;
  std::istringstream in(ReadFile(dir_ / "comp.ngc").value());
  for (std::string l; std::getline(in, l);) lines.push_back(l);
  const std::size_t target = lines.size() / 2;
  ASSERT_EQ(lines[target][0], 'X') << lines[target];
  const auto z = lines[target].find('Z');
  lines[target] = lines[target].substr(0, z + 1) + Num(std::strtod(lines[target].c_str() + z + 1, nullptr) + 0.001);
  std::string corrupted;
  for (const auto& l : lines) corrupted += l + "\n";
  Write("comp.ngc", corrupted);
  EXPECT_EQ(Run(check), 1);
  EXPECT_NE(err_.find("compensated line " + std::to_string(target + 1)), std::string::npos) << err_;
  const auto report = nlohmann::json::parse(out_);
  ASSERT_EQ(report["disagreeing_blocks"].size(), 1u) << out_;
  // Fanuc: the dialect's limit on decimals (4 in mm) holds for a shop program too, before anything is read.
  EXPECT_EQ(Run("nc compensate --program " + Path("shop.ngc") + " --surface " + Path("Q.step") +
                " --ball-radius-mm 3 --field " + Path("ds.csv") + " --out " + Path("f.nc") + " --side " +
                Path("f.csv") + " --dialect fanuc --decimals 5"),
            2);
  EXPECT_NE(err_.find("--decimals"), std::string::npos) << err_;
  EXPECT_FALSE(fs::exists(dir_ / "f.nc"));
  // Neither --toolpath nor --program: refused by name.
  EXPECT_EQ(Run("nc compensate --field " + Path("ds.csv") + " --out " + Path("x.ngc") + " --side " + Path("x.csv")), 2);
  EXPECT_NE(err_.find("--program"), std::string::npos) << err_;
}

}  // namespace
}  // namespace formloop::app
