// `formloop optimise cutting|feed|program` end to end through the binary: the Level-1 optimum of one
// cut against the exact optimum and the same answer for the same seed; a program re-optimised from
// its stock; the Level-2 closed loop with its plot and report; a planted local error on a run's part
// traced to the blocks that cut it and the program adjusted, with the inspection log; and bad input
// (unsafe depth of cut, infeasible limits, a missing coefficient, an occupied --out) refused with the
// block or parameter named and nothing written.

#include <cmath>
#include <filesystem>
#include <fstream>
#include <regex>
#include <sstream>
#include <string>

#include <gtest/gtest.h>

#include "app/part.h"
#include "core/json_io.h"
#include "core/number_text.h"
#include "core/random.h"
#include "metrology/probe.h"
#include "nc-gen/moves.h"
#include "nc-gen/post.h"
#include "nc-gen/toolpath.h"
#include "nc-gen/toolpath_io.h"
#include "planning/inspection_adjustment.h"
#include "reconstruction/analytic_surface.h"
#include "reconstruction/bspline_surface.h"
#include "tests/support/run_binary.h"
#include "tests/support/test_dir.h"

namespace formloop::app {
namespace {
namespace fs = std::filesystem;
using nlohmann::json;
using testing::RunFormloop;

const fs::path kSource = FORMLOOP_SOURCE_DIR;
const std::string kS1 = (kSource / "data" / "cutting" / "s1.json").string();

std::string ReadText(const fs::path& path) {
  std::ifstream in(path, std::ios::binary);
  std::stringstream s;
  s << in.rdbuf();
  return s.str();
}

class OptimiseCliTest : public ::testing::Test {
 protected:
  void SetUp() override { dir_ = testing::FreshTestDir("formloop_optimise_cli"); }
  void TearDown() override { fs::remove_all(dir_); }

  // S1 with one member changed (a JSON pointer) or removed (value null).
  fs::path Coefficients(const std::string& pointer, const json& value) {
    json c = json::parse(ReadText(kS1));
    if (value.is_null()) {
      const json::json_pointer p(pointer);
      c[p.parent_pointer()].erase(p.back());
    } else {
      c[json::json_pointer(pointer)] = value;
    }
    const fs::path path = dir_ / "coefficients.json";
    std::ofstream(path) << c.dump(2);
    return path;
  }

  fs::path dir_;
};

TEST_F(OptimiseCliTest, OneCutGaMatchesTheExactOptimumAndRepeatsByteForByte) {
  std::string out, err;
  const std::string args = "optimise cutting --coefficients " + kS1 + " --a-p-mm 5 --a-e-mm 1 --seed 3 --out ";
  ASSERT_EQ(RunFormloop(args + (dir_ / "a").string(), &out, &err), 0) << err;
  const json r = json::parse(out);
  EXPECT_LT(std::abs(r["cut"]["ga_shortfall_percent"].get<double>()), 0.5);
  for (const json& g : r["cut"]["constraints_at_ga"]) EXPECT_TRUE(g["satisfied"].get<bool>()) << g.dump();
  EXPECT_GT(r["cut"]["taylor"]["T_c_min"].get<double>(), r["cut"]["taylor"]["T_p_min"].get<double>());
  EXPECT_TRUE(r["cut"]["exact"]["kkt"]["passed"].get<bool>());
  ASSERT_EQ(RunFormloop(args + (dir_ / "b").string(), &out, &err), 0) << err;
  EXPECT_EQ(ReadText(dir_ / "a" / "optimise.json"), ReadText(dir_ / "b" / "optimise.json"));
  // An occupied --out is refused; --force replaces only an optimise folder.
  EXPECT_NE(RunFormloop(args + (dir_ / "a").string(), &out, &err), 0);
  EXPECT_NE(err.find("--force"), std::string::npos) << err;
  EXPECT_EQ(RunFormloop(args + (dir_ / "a").string() + " --force", &out, &err), 0) << err;
  fs::create_directories(dir_ / "mine");
  std::ofstream(dir_ / "mine" / "notes.txt") << "keep me";
  EXPECT_NE(RunFormloop(args + (dir_ / "mine").string() + " --force", &out, &err), 0);
  EXPECT_EQ(ReadText(dir_ / "mine" / "notes.txt"), "keep me");
}

TEST_F(OptimiseCliTest, BadInputNamesTheParameterAndWritesNothing) {
  std::string out, err;
  const fs::path target = dir_ / "out";
  // a_p beyond min(0.9 L_c, k_ap d) = 10 mm for side milling with S1.
  EXPECT_NE(RunFormloop("optimise cutting --coefficients " + kS1 + " --a-p-mm 12 --a-e-mm 1 --out " + target.string(),
                        &out, &err),
            0);
  EXPECT_NE(err.find("L1-DOC-RANGE"), std::string::npos) << err;
  EXPECT_NE(err.find("--a-p-mm"), std::string::npos) << err;
  // F_max of 5 N: no speed and feed of the box can hold it.
  const fs::path weak = Coefficients("/limits/max_force_n", 5);
  EXPECT_NE(RunFormloop(
                "optimise cutting --coefficients " + weak.string() + " --a-p-mm 5 --a-e-mm 1 --out " + target.string(),
                &out, &err),
            0);
  EXPECT_NE(err.find("L1-INFEASIBLE"), std::string::npos) << err;
  EXPECT_NE(err.find("F_max"), std::string::npos) << err;
  const fs::path missing = Coefficients("/tool_life/m", nullptr);
  EXPECT_NE(RunFormloop("optimise cutting --coefficients " + missing.string() + " --a-p-mm 5 --a-e-mm 1 --out " +
                            target.string(),
                        &out, &err),
            0);
  EXPECT_NE(err.find("tool_life.m"), std::string::npos) << err;
  EXPECT_FALSE(fs::exists(target));
  EXPECT_FALSE(fs::exists(target.string() + ".partial"));
}

// The recommended cutting data a case keeps (manufacturing.cutting_data) are fused with the model optimum.
TEST_F(OptimiseCliTest, CaseLibraryCuttingDataAreFusedWithTheModelOptimum) {
  std::string out, err;
  const fs::path kb = dir_ / "kb.sqlite";
  ASSERT_EQ(RunFormloop("kb init " + kb.string(), &out, &err), 0) << err;
  json record = json::parse(ReadText(kSource / "data" / "kb" / "example_case.json"));
  record["manufacturing"]["cutting_data"] = json::parse(R"([
      {"tool_family": "solid-carbide-end-mill", "grade": "K20F", "material": "C45", "iso_group": "P",
       "operation": "side_milling", "d_min_mm": 8, "d_max_mm": 12, "hardness_hb": 200,
       "v_c_nom_m_per_min": 160, "f_z_nom_mm": 0.04}])");
  const fs::path case_file = dir_ / "case.json";
  std::ofstream(case_file) << record.dump(2);
  ASSERT_EQ(RunFormloop("kb add " + kb.string() + " " + case_file.string(), &out, &err), 0) << err;
  const std::string uid = record["uid"].get<std::string>();
  ASSERT_EQ(RunFormloop("optimise cutting --coefficients " + kS1 + " --a-p-mm 5 --a-e-mm 1 --library " + kb.string() +
                            " --case " + uid + " --model-credibility 0.5",
                        &out, &err),
            0)
      << err;
  const json fusion = json::parse(out)["cut"]["fusion"];
  EXPECT_TRUE(fusion["database_used"].get<bool>()) << fusion.dump(2);
  EXPECT_EQ(fusion["database"]["level"], "exact") << fusion.dump(2);
  EXPECT_DOUBLE_EQ(fusion["w_m"].get<double>(), 0.3);  // c_model 0.5 (M), c_db 1 (H)
  EXPECT_NE(fusion.dump().find("case " + uid), std::string::npos) << fusion.dump(2);
  // --library without --case is refused.
  EXPECT_NE(RunFormloop("optimise cutting --coefficients " + kS1 + " --a-p-mm 5 --a-e-mm 1 --library " + kb.string(),
                        &out, &err),
            0);
  EXPECT_NE(err.find("--case"), std::string::npos) << err;
}

// Level 2 on formloop's raster over the stepped wall, then Level 1 on the same program and stock.
TEST_F(OptimiseCliTest, FeedControlMeetsTheCriteriaAndTheProgramIsReoptimisedFromItsStock) {
  std::string out, err;
  const fs::path feed = dir_ / "feed";
  ASSERT_EQ(RunFormloop("optimise feed --scenario wall-step --seed 2 --out " + feed.string(), &out, &err), 0) << err;
  const json r = json::parse(out);
  EXPECT_TRUE(r["all_criteria_met"].get<bool>()) << r["criteria"].dump(2);
  EXPECT_LE(r["time_ratio"].get<double>(), 0.8);
  EXPECT_EQ(r["fuzzy"]["above_overload_s"].get<double>(), 0.0);
  EXPECT_EQ(r["constant"]["above_overload_s"].get<double>(), 0.0);
  const std::string png = ReadText(feed / "feed.png");
  ASSERT_GT(png.size(), 1000u);
  EXPECT_EQ(png.substr(1, 3), "PNG");
  EXPECT_NE(ReadText(feed / "report.html").find("data:image/png;base64,"), std::string::npos);
  const std::string csv = ReadText(feed / "feed.csv");
  EXPECT_NE(csv.find("\nfuzzy,"), std::string::npos);
  EXPECT_NE(csv.find("\nconstant,"), std::string::npos);

  const fs::path program = feed / "inputs" / "program.ngc", stock = feed / "inputs" / "stock.json";
  const fs::path cut = dir_ / "cut";
  ASSERT_EQ(RunFormloop("optimise cutting --coefficients " + kS1 + " --program " + program.string() + " --stock " +
                            stock.string() + " --seed 1 --out " + cut.string(),
                        &out, &err),
            0)
      << err;
  const json c = json::parse(out);
  EXPECT_GT(c["program"]["lines_changed"].get<int>(), 0);
  // The raster's 2942 mm/min overloads the tool where a_e = 3 mm: every group is written at n_op within
  // the force limit and above the minimum-cost tool life, so this program gets slower, not faster.
  const double n_op = c["program"]["spindle_rpm"].get<double>();
  ASSERT_GT(c["program"]["groups"].size(), 1u);
  for (const json& g : c["program"]["groups"]) {
    EXPECT_EQ(g["written"]["n_rpm"].get<double>(), n_op);
    EXPECT_LE(g["written"]["force_n"].get<double>(), 300 * (1 + 1e-9)) << g.dump();
    EXPECT_GE(g["written"]["tool_life_min"].get<double>(), 48.8108 * (1 - 1e-6)) << g.dump();
  }
  const std::string written = ReadText(cut / "program.ngc");
  EXPECT_NE(written.find("parent sha256"), std::string::npos);
  EXPECT_NE(written, ReadText(program));

  // The same program over a 30 mm wall: the 22 mm flutes cannot take it; the blocks are named.
  json deep = json::parse(ReadText(stock));
  for (json& prism : deep["prisms"]) prism["top_z_mm"] = 30;
  const fs::path deep_stock = dir_ / "deep_stock.json";
  std::ofstream(deep_stock) << deep.dump();
  EXPECT_NE(RunFormloop("optimise cutting --coefficients " + kS1 + " --program " + program.string() + " --stock " +
                            deep_stock.string() + " --out " + (dir_ / "deep").string(),
                        &out, &err),
            0);
  EXPECT_NE(err.find("L1-DOC-RANGE"), std::string::npos) << err;
  EXPECT_TRUE(std::regex_search(err, std::regex("N[0-9]+"))) << err;
  EXPECT_FALSE(fs::exists(dir_ / "deep"));
}

// A shop program through the binary: LinuxCNC's public sample (inch, R-form arcs) with a per-block
// engagement; the file gets its S and the F of the engaged cut in inch/min, nothing else changes, and
// the input is left as it was.
TEST_F(OptimiseCliTest, ShopProgramWithArcsInInchGetsItsFeedAndSpeedThroughTheReader) {
  const fs::path program = kSource / "data" / "nc-programs" / "linuxcnc_cds.ngc";
  const std::string before = ReadText(program);
  json blocks = json::array();
  for (int n = 180; n <= 500; n += 10) blocks.push_back({{"block", n}, {"a_p_mm", 5}, {"a_e_mm", 1}});
  const fs::path engagement = dir_ / "engagement.json";
  std::ofstream(engagement) << json{{"blocks", blocks}}.dump();
  std::string out, err;
  const fs::path cut = dir_ / "cut";
  ASSERT_EQ(
      RunFormloop("optimise cutting --coefficients " + kS1 + " --program " + program.string() +
                      " --dialect linuxcnc --engagement " + engagement.string() + " --seed 1 --out " + cut.string(),
                  &out, &err),
      0)
      << err;
  const json c = json::parse(out);
  EXPECT_EQ(c["program"]["cutting_blocks"].get<int>(), 33);
  EXPECT_EQ(c["program"]["lines_changed"].get<int>(), 3);  // S on n0140, F on n0180, F16. back on n0510
  const double feed_mm = std::floor(c["program"]["groups"][0]["written"]["v_f_mm_per_min"].get<double>() + 1e-9);
  const std::string written = ReadText(cut / "program.ngc");
  EXPECT_NE(written.find("n0180 G1 Z+1.6875 F" + FormatFixed(std::floor(feed_mm / 25.4 * 100 + 1e-9) / 100, 2) +
                         " (start left circle zigzag)"),
            std::string::npos)
      << written;
  EXPECT_NE(written.find("n0510 G1 Y+0.875 F16."), std::string::npos);
  EXPECT_EQ(ReadText(program), before);
}

// A run folder of the demo part (saddle) as `formloop run` leaves it, with the nominal program, and an
// inspection whose deviations carry a planted local error: +40 µm (material left) in a disc of radius
// 12 mm around (15, 10), N(0, 1 µm) elsewhere.
TEST_F(OptimiseCliTest, PlantedLocalErrorIsTracedToTheBlocksThatCutItAndTheProgramAdjusted) {
  const fs::path run = dir_ / "run";
  fs::create_directories(run / "inputs");
  fs::create_directories(run / "surface");
  fs::create_directories(run / "toolpath");
  fs::create_directories(run / "loop-0");
  auto part = ReadPart(kSource / "data" / "parts" / "demo-saddle.json");
  ASSERT_TRUE(part.ok()) << part.status().message();
  part->toolpath.scallop_um = 8;
  part->toolpath.max_point_spacing_mm = 1.0;
  ASSERT_TRUE(WriteJsonFile(run / "inputs" / "part.json", part->ToJson()).ok());
  auto analytic = recon::MakeReferenceSurface("saddle");
  const recon::BSplineSurface q = recon::FitAnalytic(*analytic.value(), 30, 30, {}, 0, 1, nullptr).value();
  ASSERT_TRUE(recon::WriteStep(run / "surface" / "Q.step", q, "saddle").ok());
  const nc::Toolpath path = nc::PlanRaster(q, part->toolpath).value();
  ASSERT_TRUE(nc::WriteToolpathFile(run / "toolpath" / "toolpath.csv", path).ok());
  const metrology::ProbingPlan plan = metrology::PlanProbingGrid(q, 30, 30, 0.05).value();
  ASSERT_TRUE(WriteJsonFile(run / "toolpath" / "probing_plan.json", plan.ToJson()).ok());
  nc::PostOptions post;
  post.limits = part->limits;
  post.block_numbers = true;
  const std::string program = nc::Post(nc::BuildMoveList(path).value(), part->dialect, post).value();
  std::ofstream(run / "toolpath" / "program.ngc") << program;
  std::string csv = "id,x,y,z,nx,ny,nz,foot_x,foot_y,foot_z,deviation_um\n";
  Rng rng(11);
  for (std::size_t i = 0; i < plan.points.size(); ++i) {
    const Eigen::Vector3d& f = plan.points[i].point;
    const Eigen::Vector3d& n = plan.points[i].normal;
    const bool inside = std::hypot(f.x() - 15, f.y() - 10) < 12;
    const double e_um = (inside ? 40.0 : 0.0) + rng.Normal(0, 1);
    const Eigen::Vector3d p = f + e_um / 1000 * n;
    csv += std::to_string(i + 1);
    for (double v : {p.x(), p.y(), p.z(), n.x(), n.y(), n.z(), f.x(), f.y(), f.z(), e_um})
      csv += "," + FormatFixed(v, 6);
    csv += "\n";
  }
  std::ofstream(run / "loop-0" / "deviations.csv") << csv;

  std::string out, err;
  const fs::path result = dir_ / "adjusted", log = dir_ / "inspection.jsonl";
  ASSERT_EQ(RunFormloop("optimise program --run " + run.string() + " --out " + result.string() + " --log " +
                            log.string() + " --inspection-id insp-7",
                        &out, &err),
            0)
      << err;
  const json r = json::parse(out);
  const json& a = r["adjustment"];
  EXPECT_TRUE(a["evaluation"]["systematic"].get<bool>()) << a["evaluation"].dump();
  ASSERT_EQ(a["regions"].size(), 1u) << a["regions"].dump();
  const json& region = a["regions"][0];
  EXPECT_EQ(region["type"], "offset");
  EXPECT_NEAR(region["centroid_mm"][0].get<double>(), 15, 3);
  EXPECT_NEAR(region["centroid_mm"][1].get<double>(), 10, 3);
  EXPECT_EQ(a["program_kind"], "recut");
  EXPECT_GT(a["cl_points_shifted"].get<int>(), 0);
  // Every block the region names was cut over the disc: its programmed X, Y lie within the disc
  // widened by the ball radius (3 mm) and the 1.5 h neighbourhood.
  std::map<long, Eigen::Vector2d> xy;  // block number -> programmed X, Y (modal)
  {
    std::istringstream lines(program);
    std::string line;
    double x = 0, y = 0;
    const std::regex number("^N([0-9]+)"), word_x("X(-?[0-9.]+)"), word_y("Y(-?[0-9.]+)");
    std::smatch m;
    while (std::getline(lines, line)) {
      if (std::regex_search(line, m, word_x)) x = std::stod(m[1]);
      if (std::regex_search(line, m, word_y)) y = std::stod(m[1]);
      if (std::regex_search(line, m, number)) xy[std::stol(m[1])] = {x, y};
    }
  }
  int named = 0;
  const std::regex range("N([0-9]+)-N([0-9]+)");
  for (const json& text : region["block_ranges"]) {
    std::smatch m;
    const std::string s = text.get<std::string>();
    ASSERT_TRUE(std::regex_search(s, m, range)) << s;
    for (long n = std::stol(m[1]); n <= std::stol(m[2]); ++n) {
      auto it = xy.find(n);
      if (it == xy.end()) continue;
      ++named;
      EXPECT_LT(std::hypot(it->second.x() - 15, it->second.y() - 10), 12 + 3 + 6) << "N" << n;
    }
  }
  EXPECT_GT(named, 10);
  const std::string adjusted = ReadText(result / "program.ngc");
  EXPECT_NE(adjusted, program);
  EXPECT_NE(adjusted.find("insp-7"), std::string::npos);
  // The same from the files alone (a `formloop analyse` folder has no run): the same adjustment.
  const std::string files = " --surface " + (run / "surface" / "Q.step").string() + " --program " +
                            (run / "toolpath" / "program.ngc").string() + " --inspection " +
                            (run / "loop-0" / "deviations.csv").string() + " --tolerance-mm " +
                            FormatFixed(part->tolerance_mm, 4) + " --inspection-id insp-7";
  EXPECT_NE(RunFormloop("optimise program" + files + " --out " + (dir_ / "files").string(), &out, &err), 0);
  EXPECT_NE(err.find("--ball-radius-mm"), std::string::npos) << err;
  ASSERT_EQ(RunFormloop("optimise program" + files + " --ball-radius-mm " + FormatExact(path.options.tool.radius_mm) +
                            " --out " + (dir_ / "files").string(),
                        &out, &err),
            0)
      << err;
  EXPECT_EQ(ReadText(dir_ / "files" / "adjustment.json"), ReadText(result / "adjustment.json"));
  EXPECT_EQ(ReadText(dir_ / "files" / "program.ngc"), adjusted);

  auto records = planning::ReadInspectionLog(log);
  ASSERT_TRUE(records.ok()) << records.status().message();
  ASSERT_EQ(records->size(), 1u);
  EXPECT_EQ((*records)[0]["inspection_id"], "insp-7");
  EXPECT_EQ((*records)[0]["points"].size(), plan.points.size());
}

}  // namespace
}  // namespace formloop::app
