// Level 1 on a program (spec/process-optimization.md §1.2, §1.8; checks 5.1.1 and the bad-input cases of
// issue 24): the depth-of-cut alarm naming exactly the failing blocks, the optimum written into F and S
// with every other line byte-identical, fusion with recorded cutting data, and errors that name the
// parameter or the block.

#include "planning/cutting_program.h"

#include <gtest/gtest.h>

#include <string>
#include <vector>

#include "core/file_hash.h"
#include "core/json_io.h"
#include "nc-gen/moves.h"
#include "nc-gen/post.h"
#include "planning/program_edit.h"

namespace formloop::planning {
namespace {

// Three side-milling passes along x, each of ten 10 mm feed blocks (a_p 5; a_e 1, 1, 3), posted by
// formloop with block numbers N10, N20, ...
std::string SideMillingProgram(const std::string& dialect) {
  nc::MoveList list;
  list.header.tool_number = 1;
  list.header.tool_radius_mm = 5;
  list.header.spindle_rpm = 3000;
  list.header.passes = 3;
  list.safe_z_mm = 10;
  auto add = [&](nc::MoveType type, Eigen::Vector3d tip, double feed, int pass, const std::string& source) {
    nc::Move m;
    m.type = type;
    m.tip = tip;
    m.feed_mm_per_min = feed;
    m.pass = pass;
    m.source = source;
    list.moves.push_back(m);
  };
  for (int p = 0; p < 3; ++p) {
    nc::Move c;
    c.type = nc::MoveType::kComment;
    c.text = "pass " + std::to_string(p);
    list.moves.push_back(c);
    const double y = 4.0 * p;
    add(nc::MoveType::kRapid, {0, y, 10}, 0, p, "rapid");
    add(nc::MoveType::kFeed, {0, y, -5}, 300, p, "plunge");
    add(nc::MoveType::kSetFeed, {0, y, -5}, 600, p, "feed");
    for (int k = 1; k <= 10; ++k) add(nc::MoveType::kFeed, {10.0 * k, y, -5}, 600, p, "cut");
    add(nc::MoveType::kRapid, {100, y, 10}, 0, p, "retract");
    list.moves.back().axes = nc::kAxisZ;
  }
  nc::PostOptions options;
  options.title = "side milling test";
  options.block_numbers = true;
  options.decimals = 3;
  return nc::Post(list, dialect, options).value();
}

// Engagement of every cut block: the N numbers of the G1 moves along x.
std::vector<BlockEngagement> Engagement(const std::string& text, const std::string& dialect) {
  EditableProgram p = EditableProgram::Parse(text, dialect, "test").value();
  std::vector<BlockEngagement> out;
  int cut = 0;
  for (std::size_t i = 0; i < p.moves().size(); ++i) {
    const nc::ProgramMove& m = p.moves()[i];
    if (m.rapid || i == 0 || m.tip.z() != -5 || p.MoveStart(i).z() != -5) continue;
    const double a_e = cut < 20 ? 1.0 : 3.0;
    out.push_back({p.lines()[p.LineOfMove(i)].number, 5.0, a_e});
    ++cut;
  }
  return out;
}

CuttingCoefficients S1() {
  return CuttingCoefficientsFromJson(ReadJsonFile(std::string(FORMLOOP_SOURCE_DIR) + "/data/cutting/s1.json").value(),
                                     "s1.json")
      .value();
}

TEST(CuttingProgram, UnsafeDepthOfCutStopsWithAnAlarmNamingExactlyThatBlock) {
  const std::string text = SideMillingProgram("linuxcnc");
  std::vector<BlockEngagement> e = Engagement(text, "linuxcnc");
  ASSERT_EQ(e.size(), 30u);
  e[13].a_p_mm = 15;  // a_p,max = min(0.9 * 22, 1.0 * 10) = 10
  const std::string n = "N" + std::to_string(e[13].block);
  auto r = OptimiseCuttingProgram(text, "linuxcnc", "side.ngc", e, S1(), {});
  ASSERT_FALSE(r.ok());
  EXPECT_EQ(r.status().code(), StatusCode::kSafetyLimit);
  const std::string& msg = r.status().message();
  EXPECT_NE(msg.find("L1-DOC-RANGE: 1 block"), std::string::npos) << msg;
  EXPECT_NE(msg.find(n + " (tool T1, side_milling): a_p = 15.000 mm (limit 0 < a_p <= 10.000)"), std::string::npos)
      << msg;
  // Every other block is named nowhere.
  for (std::size_t k = 0; k < e.size(); ++k) {
    if (k != 13) {
      EXPECT_EQ(msg.find("N" + std::to_string(e[k].block) + " "), std::string::npos) << k;
    }
  }
  // Two failures (a_e beyond d as well): both listed.
  e[20].a_e_mm = 12;
  const Status both = CheckDepthOfCut(text, "linuxcnc", "side.ngc", e, S1());
  EXPECT_NE(both.message().find("2 block(s)"), std::string::npos) << both.message();
  EXPECT_NE(both.message().find("N" + std::to_string(e[20].block) + " (tool T1, slotting)"), std::string::npos);
}

TEST(CuttingProgram, OptimumIsWrittenIntoFAndSAndNothingElseChanges) {
  const std::string text = SideMillingProgram("linuxcnc");
  const std::vector<BlockEngagement> e = Engagement(text, "linuxcnc");
  const CuttingCoefficients k = S1();
  auto r = OptimiseCuttingProgram(text, "linuxcnc", "side.ngc", e, k, {.seed = 3});
  ASSERT_TRUE(r.ok()) << r.status().ToString();
  ASSERT_EQ(r->groups.size(), 2u);
  // Group a_e = 3 removes 1500 mm³ against 1000: it sets the spindle speed.
  EXPECT_TRUE(r->groups[1].sets_spindle);
  EXPECT_NEAR(r->groups[1].model.state.n_rpm, 6350.36, 0.005 * 6350.36);  // case D of §1.9 (T_c instead of 48.8)
  EXPECT_EQ(r->spindle_rpm, std::round(r->groups[1].model.state.n_rpm));
  for (const CuttingGroup& g : r->groups) {
    CuttingCase c = k.base;
    c.a_p_mm = g.a_p_mm;
    c.a_e_mm = g.a_e_mm;
    EXPECT_TRUE(SatisfiesConstraints(c, g.state, 1e-9));
    EXPECT_EQ(g.state.n_rpm, r->spindle_rpm);
  }
  EXPECT_LT(r->cutting_time_after_min, 0.5 * r->cutting_time_before_min);
  EXPECT_NE(r->program.find("parent sha256 " + Sha256Hex(text)), std::string::npos);

  // Line by line: only the S line and the first cut block of each pass (new F) and the block after the
  // cut (restoring nothing: retract is a rapid) differ; the plunge keeps F300.
  const EditableProgram before = EditableProgram::Parse(text, "linuxcnc", "a").value();
  const EditableProgram after = EditableProgram::Parse(r->program, "linuxcnc", "b").value();
  ASSERT_EQ(after.lines().size(), before.lines().size() + 2);  // two header comments
  ASSERT_EQ(after.moves().size(), before.moves().size());
  int changed = 0;
  std::size_t j = 0;
  for (std::size_t i = 0; i < before.lines().size(); ++i, ++j) {
    while (after.lines()[j].text.find("optimise cutting") != std::string::npos ||
           after.lines()[j].text.find("coefficient set S1") != std::string::npos) {
      ++j;
    }
    if (before.lines()[i].text != after.lines()[j].text) ++changed;
  }
  EXPECT_EQ(changed, r->lines_changed);
  EXPECT_EQ(changed, 1 + 3);  // S, and the first cut block of each pass
  // Every move goes where it went; cut blocks at their group's feed, plunges as before.
  std::size_t cut = 0;
  for (std::size_t i = 0; i < before.moves().size(); ++i) {
    EXPECT_EQ(after.moves()[i].tip, before.moves()[i].tip);
    const bool is_cut =
        !before.moves()[i].rapid && i > 0 && before.moves()[i].tip.z() == -5 && before.MoveStart(i).z() == -5;
    if (is_cut) {
      const CuttingGroup& g = r->groups[cut < 20 ? 0 : 1];
      EXPECT_DOUBLE_EQ(after.moves()[i].feed_mm_per_min, g.state.v_f_mm_per_min);
      ++cut;
    } else if (!before.moves()[i].rapid) {
      EXPECT_EQ(after.moves()[i].feed_mm_per_min, before.moves()[i].feed_mm_per_min);
    }
  }
  EXPECT_EQ(cut, 30u);
  // Same seed, same program.
  EXPECT_EQ(OptimiseCuttingProgram(text, "linuxcnc", "side.ngc", e, k, {.seed = 3})->program, r->program);
}

TEST(CuttingProgram, FanucProgramsAreEditedInTheirOwnSpelling) {
  const std::string text = SideMillingProgram("fanuc");
  auto r = OptimiseCuttingProgram(text, "fanuc", "side.nc", Engagement(text, "fanuc"), S1(), {});
  ASSERT_TRUE(r.ok()) << r.status().ToString();
  EXPECT_NE(r->program.find("(FORMLOOP OPTIMISE CUTTING: PARENT SHA256 "), std::string::npos);
  EXPECT_NE(r->program.find("S" + FeedWord(r->spindle_rpm) + " M03"), std::string::npos) << r->program;
}

TEST(CuttingProgram, DatabaseRecordIsFusedWithTheModelOptimum) {
  const std::string text = SideMillingProgram("linuxcnc");
  CuttingProgramOptions options;
  options.cutting_data = CuttingDataFromJson(nlohmann::json::parse(R"([
      {"tool_family": "solid-carbide-end-mill", "grade": "K20F", "material": "C45", "iso_group": "P",
       "operation": "side_milling", "d_min_mm": 8, "d_max_mm": 12, "hardness_hb": 200,
       "v_c_nom_m_per_min": 160, "f_z_nom_mm": 0.04, "source": "case side-001"}])"),
                                             "cases")
                             .value();
  options.model_credibility = 0.5;
  auto r = OptimiseCuttingProgram(text, "linuxcnc", "side.ngc", Engagement(text, "linuxcnc"), S1(), options);
  ASSERT_TRUE(r.ok()) << r.status().ToString();
  EXPECT_TRUE(r->fusion.database_used);
  EXPECT_EQ(r->fusion.match->level, "exact");
  EXPECT_DOUBLE_EQ(r->fusion.w_m, 0.3);
  // n between the database point and the model, nearer the database (w_m = 0.3).
  const double n_model = r->groups[1].model.state.n_rpm, n_db = r->fusion.n_db_rpm;
  EXPECT_NEAR(std::log(r->spindle_rpm), 0.7 * std::log(n_db) + 0.3 * std::log(n_model), 1e-3);
  EXPECT_NE(r->program.find("w_m 0.300"), std::string::npos);
}

TEST(CuttingProgram, BadInputNamesTheParameterOrTheBlock) {
  const std::string text = SideMillingProgram("linuxcnc");
  // A missing coefficient.
  Json k = ReadJsonFile(std::string(FORMLOOP_SOURCE_DIR) + "/data/cutting/s1.json").value();
  k["tool_life"].erase("m");
  auto missing = CuttingCoefficientsFromJson(k, "s1.json");
  ASSERT_FALSE(missing.ok());
  EXPECT_NE(missing.status().message().find("s1.json: field 'tool_life.m'"), std::string::npos)
      << missing.status().message();
  // A Taylor exponent out of range.
  k = ReadJsonFile(std::string(FORMLOOP_SOURCE_DIR) + "/data/cutting/s1.json").value();
  k["tool_life"]["m"] = 1.2;
  EXPECT_NE(CuttingCoefficientsFromJson(k, "s1.json").status().message().find("tool_life.m"), std::string::npos);
  // Infeasible limits name the constraint.
  k = ReadJsonFile(std::string(FORMLOOP_SOURCE_DIR) + "/data/cutting/s1.json").value();
  k["limits"]["max_force_n"] = 5;
  auto weak = CuttingCoefficientsFromJson(k, "s1.json");
  ASSERT_TRUE(weak.ok());
  auto r = OptimiseCuttingProgram(text, "linuxcnc", "side.ngc", Engagement(text, "linuxcnc"), *weak, {});
  ASSERT_FALSE(r.ok());
  EXPECT_NE(r.status().message().find("L1-INFEASIBLE"), std::string::npos);
  EXPECT_NE(r.status().message().find("g4 cutting force"), std::string::npos) << r.status().message();
  // A block that does not exist, and one that is a rapid.
  std::vector<BlockEngagement> e = Engagement(text, "linuxcnc");
  e.push_back({99990, 5, 1});
  auto unknown = OptimiseCuttingProgram(text, "linuxcnc", "side.ngc", e, S1(), {});
  EXPECT_NE(unknown.status().message().find("N99990 is not a block of side.ngc"), std::string::npos)
      << unknown.status().message();
  // Heidenhain is not word-address G-code.
  EXPECT_EQ(EditableProgram::Parse("0 BEGIN PGM X MM\n", "heidenhain", "p.h").status().code(), StatusCode::kBadInput);
}

TEST(ProgramEdit, WordsAreReplacedOrAddedAndTheRestKeepsItsBytes) {
  const std::string text = "%\n(title)\nN10 G1 X1.000 Y2.000 Z3.000 F300\nN20 G1 X2.000\n%\n";
  EditableProgram p = EditableProgram::Parse(text, "linuxcnc", "t.ngc").value();
  EXPECT_EQ(p.Decimals(), 3);
  EXPECT_EQ(p.BlockName(2), "N10");
  p.SetWord(2, 'F', "450");
  p.SetWord(3, 'Y', "2.500");
  EXPECT_EQ(p.Text(), "%\n(title)\nN10 G1 X1.000 Y2.000 Z3.000 F450\nN20 G1 X2.000 Y2.500\n%\n");
  EXPECT_TRUE(p.Verified("t.ngc").ok());
}

}  // namespace
}  // namespace formloop::planning
