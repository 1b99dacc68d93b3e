// `formloop nc path` and `formloop nc probe` through the binary: every dialect's program reads back
// with formloop's reader to as many feed moves as the report has CL points, probing programs name
// every point, and limit violations are refused with nothing written.

#include <algorithm>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <string>

#include <unistd.h>

#include <gtest/gtest.h>

#include "core/atomic_file.h"
#include "core/json_io.h"
#include "nc-gen/post.h"
#include "tests/support/run_binary.h"

namespace formloop::app {
namespace {

namespace fs = std::filesystem;

class NcCliTest : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = fs::temp_directory_path() / ("formloop-nc-" + std::to_string(::getpid()) + "-" +
                                        ::testing::UnitTest::GetInstance()->current_test_info()->name());
    fs::remove_all(dir_);
    fs::create_directories(dir_);
    ASSERT_EQ(Run("fit analytic:saddle --out " + Path("Q.step")), 0) << err_;
  }
  void TearDown() override { fs::remove_all(dir_); }
  std::string Path(const std::string& name) const { return (dir_ / name).string(); }
  // Runs the binary; keeps stderr in err_.
  int Run(const std::string& args) {
    std::string out;
    return testing::RunFormloop(args, &out, &err_);
  }
  fs::path dir_;
  std::string err_;
};

TEST_F(NcCliTest, EveryDialectPostsAProgramThatReadsBack) {
  for (const std::string& dialect : nc::PostNames()) {
    const std::string program = Path("p_" + dialect + ".nc"), report = Path("r_" + dialect + ".json");
    ASSERT_EQ(Run("nc path --surface " + Path("Q.step") + " --scallop-um 20 --max-spacing-mm 2 --dialect " + dialect +
                  " --out " + program + " --report " + report),
              0)
        << dialect << ": " << err_;
    const auto json = ReadJsonFile(report);
    ASSERT_TRUE(json.ok());
    const auto text = ReadFile(program);
    ASSERT_TRUE(text.ok());
    const auto moves = nc::ReadProgram(*text, dialect, program);
    ASSERT_TRUE(moves.ok()) << moves.status().ToString();
    long feeds = 0;
    for (const nc::ProgramMove& m : *moves) feeds += m.rapid ? 0 : 1;
    // Every CL point is one feed move (the plunge onto the first point of each pass included).
    EXPECT_EQ(feeds, (*json)["cl_points"].get<long>()) << dialect;
  }
}

TEST_F(NcCliTest, ProbingProgramsNameEveryPoint) {
  for (const std::string& dialect : nc::PostNames()) {
    const std::string program = Path("probe_" + dialect + ".nc");
    ASSERT_EQ(Run("nc probe --surface " + Path("Q.step") + " --grid 4x3 --dialect " + dialect + " --out " + program), 0)
        << dialect << ": " << err_;
    const std::string text = ReadFile(program).value();
    for (int id = 1; id <= 12; ++id) {
      const std::string upper = "POINT " + std::to_string(id), lower = "point " + std::to_string(id);
      EXPECT_TRUE(text.find(upper) != std::string::npos || text.find(lower) != std::string::npos)
          << dialect << " misses point " << id;
    }
  }
  // A curvature-weighted plan of 15 points: every id in the program; a bad weight is refused by name.
  const std::string weighted = Path("weighted.ngc");
  ASSERT_EQ(Run("nc probe --surface " + Path("Q.step") + " --count 15 --curvature-weight 2 --out " + weighted), 0)
      << err_;
  const std::string text = ReadFile(weighted).value();
  for (int id = 1; id <= 15; ++id) {
    EXPECT_NE(text.find("point " + std::to_string(id) + ")"), std::string::npos) << "misses point " << id;
  }
  EXPECT_EQ(Run("nc probe --surface " + Path("Q.step") + " --count 15 --curvature-weight -1 --out " + Path("bad.ngc")),
            2);
  EXPECT_NE(err_.find("curvature_weight"), std::string::npos) << err_;
  EXPECT_FALSE(fs::exists(dir_ / "bad.ngc"));
}

TEST_F(NcCliTest, LimitsAndBadOptionsAreRefusedWithNothingWritten) {
  const std::string out = Path("bad.nc");
  // A feed above the machine's maximum is refused with the options, before any planning (issue 17).
  EXPECT_EQ(Run("nc path --surface " + Path("Q.step") + " --out " + out + " --max-feed 100"), 2);
  EXPECT_NE(err_.find("'--feed': 1500 mm/min is above the machine's --max-feed 100"), std::string::npos) << err_;
  EXPECT_EQ(Run("nc path --surface " + Path("Q.step") + " --out " + out + " --travel-mm 20"), 1);
  EXPECT_NE(err_.find("outside the travel"), std::string::npos) << err_;
  EXPECT_EQ(Run("nc probe --surface " + Path("Q.step") + " --out " + out + " --travel-z-mm 1"), 1);
  EXPECT_EQ(Run("nc path --surface " + Path("Q.step") + " --out " + out + " --dialect haas"), 2);
  EXPECT_NE(err_.find("haas"), std::string::npos) << err_;
  EXPECT_EQ(Run("nc probe --surface " + Path("Q.step") + " --out " + out + " --grid 4by3"), 2);
  // The probe's moves are checked clear of Q: a least gap of 50 mm, which the traverse at safe Z 50 cannot
  // keep above the saddle, is refused naming the point, the move and the gap.
  EXPECT_EQ(Run("nc probe --surface " + Path("Q.step") + " --out " + out + " --grid 4x4 --min-gap-mm 50"), 1);
  EXPECT_NE(err_.find("probe point 2: the stylus ball would come within 44.574 mm of the part (50.000 mm required) "
                      "on the traverse at safe Z from point 1"),
            std::string::npos)
      << err_;
  EXPECT_EQ(Run("nc probe --surface " + Path("Q.step") + " --out " + out + " --min-gap-mm 0"), 2);
  EXPECT_NE(err_.find("--min-gap-mm"), std::string::npos) << err_;
  EXPECT_EQ(Run("nc probe --surface " + Path("Q.step") + " --out " + out + " --shank-radius-mm -1"), 2);
  EXPECT_NE(err_.find("--shank-radius-mm"), std::string::npos) << err_;
  EXPECT_EQ(Run("nc path --surface " + Path("missing.step") + " --out " + out), 2);
  EXPECT_FALSE(fs::exists(out));
}

TEST_F(NcCliTest, CheckFindsACorruptedCompensatedBlock) {
  // The demo run writes a nominal program, a compensated one and the side file.
  const fs::path run = dir_ / "demo";
  ASSERT_EQ(Run("run " + std::string(FORMLOOP_SOURCE_DIR) + "/data/parts/demo-saddle.json --out " + run.string()), 0)
      << err_;
  const std::string nominal = (run / "toolpath" / "program.ngc").string();
  const std::string side = (run / "loop-0" / "compensation_side.bin").string();
  std::string compensated = (run / "loop-0" / "program_compensated.ngc").string();
  const std::string check = "nc check --nominal " + nominal + " --side " + side + " --compensated ";
  ASSERT_EQ(Run(check + compensated), 0) << err_;

  // Raise the Z word of one feed block deep in the program by 10 µm.
  std::string text = ReadFile(compensated).value();
  std::size_t at = text.find("G1 X", text.size() / 2);
  ASSERT_NE(at, std::string::npos);
  const std::size_t z = text.find(" Z", at) + 2, end = text.find_first_of(" \n", z);
  const double value = std::stod(text.substr(z, end - z)) + 0.010;
  char buffer[32];
  std::snprintf(buffer, sizeof buffer, "%.4f", value);
  text.replace(z, end - z, buffer);
  const fs::path corrupted = dir_ / "corrupted.ngc";
  ASSERT_TRUE(WriteFileAtomic(corrupted, text).ok());
  EXPECT_EQ(Run(check + corrupted.string()), 1);
  EXPECT_NE(err_.find("1 of "), std::string::npos) << err_;
  const long line = static_cast<long>(std::count(text.begin(), text.begin() + static_cast<long>(at), '\n')) + 1;
  EXPECT_NE(err_.find("compensated line " + std::to_string(line)), std::string::npos) << err_;
}

// Plan once, post and compensate later: the tool-path file posts to the same program as planning did
// (only the title comment names the other command), posts in another dialect, and compensates to a
// program that `nc check` accepts against the field; an offset above the limit writes nothing.
TEST_F(NcCliTest, ToolpathFilePostsAndCompensatesInSeparateSteps) {
  const std::string toolpath = Path("t.csv"), direct = Path("direct.ngc"), posted = Path("posted.ngc");
  ASSERT_EQ(Run("nc path --surface " + Path("Q.step") +
                " --scallop-um 20 --max-spacing-mm 2 --raster-angle 30 "
                "--one-way --toolpath " +
                toolpath + " --out " + direct),
            0)
      << err_;
  ASSERT_EQ(Run("nc post --toolpath " + toolpath + " --out " + posted), 0) << err_;
  std::string a = ReadFile(direct).value(), b = ReadFile(posted).value();
  const auto drop_title = [](std::string* text) {
    const std::size_t first = text->find('\n'), second = text->find('\n', first + 1);
    text->erase(first, second - first);
  };
  drop_title(&a);
  drop_title(&b);
  EXPECT_EQ(a, b) << "a tool path read back posts to the same program";
  const std::string fanuc = Path("posted.nc");
  ASSERT_EQ(Run("nc post --toolpath " + toolpath + " --dialect fanuc --decimals 3 --out " + fanuc), 0) << err_;
  EXPECT_TRUE(nc::ReadProgram(ReadFile(fanuc).value(), "fanuc", fanuc).ok());

  // A field d_s = 8 µm + 0.05 µm/mm · u on scattered (u, v) samples.
  std::string field = "u,v,ds_um\n";
  for (int i = 0; i < 7; ++i) {
    for (int j = 0; j < 7; ++j) {
      const double u = -50 + 100.0 * i / 6, v = -40 + 80.0 * j / 6;
      field += std::to_string(u) + "," + std::to_string(v) + "," + std::to_string(8 + 0.05 * u) + "\n";
    }
  }
  ASSERT_TRUE(WriteFileAtomic(dir_ / "ds.csv", field).ok());
  const std::string compensated = Path("c.ngc"), side = Path("side.csv");
  ASSERT_EQ(Run("nc compensate --toolpath " + toolpath + " --field " + Path("ds.csv") + " --out " + compensated +
                " --side " + side),
            0)
      << err_;
  EXPECT_EQ(Run("nc check --nominal " + direct + " --compensated " + compensated + " --side " + side + " --field " +
                Path("ds.csv")),
            0)
      << err_;
  // The limit: 5 µm is below the field's offsets; nothing is written.
  EXPECT_EQ(Run("nc compensate --toolpath " + toolpath + " --field " + Path("ds.csv") + " --max-offset-um 5 --out " +
                Path("c2.ngc") + " --side " + Path("side2.csv")),
            1);
  EXPECT_NE(err_.find("exceeds the limit"), std::string::npos) << err_;
  EXPECT_FALSE(fs::exists(dir_ / "c2.ngc"));
  EXPECT_FALSE(fs::exists(dir_ / "side2.csv"));

  // A corrupted tool-path file is refused naming the line and field.
  std::string text = ReadFile(toolpath).value();
  const std::size_t row = text.find("\n0,cut,");
  ASSERT_NE(row, std::string::npos);
  const long line = static_cast<long>(std::count(text.begin(), text.begin() + static_cast<long>(row), '\n')) + 2;
  text.replace(row + 1, 6, "0,cat,");
  ASSERT_TRUE(WriteFileAtomic(dir_ / "bad.csv", text).ok());
  EXPECT_EQ(Run("nc post --toolpath " + Path("bad.csv") + " --out " + Path("bad.ngc")), 2);
  EXPECT_NE(err_.find("bad.csv:" + std::to_string(line) + ": field 'kind'"), std::string::npos) << err_;
  EXPECT_FALSE(fs::exists(dir_ / "bad.ngc"));
}

// The pipeline in another controller's dialect at another raster angle: programs carry the dialect's
// extension, the compensated program passes `nc check` in that dialect, and an unknown dialect is
// refused naming the field.
TEST_F(NcCliTest, RunPostsInThePartsDialectAndRasterAngle) {
  auto part = ReadJsonFile(std::string(FORMLOOP_SOURCE_DIR) + "/data/parts/demo-saddle.json");
  ASSERT_TRUE(part.ok());
  (*part)["machine"]["dialect"] = "heidenhain";
  (*part)["toolpath"]["raster_angle_deg"] = 45;
  ASSERT_TRUE(WriteJsonFile(dir_ / "part.json", *part).ok());
  const fs::path run = dir_ / "run";
  ASSERT_EQ(Run("run " + Path("part.json") + " --out " + run.string()), 0) << err_;
  EXPECT_TRUE(fs::exists(run / "toolpath" / "program.h"));
  EXPECT_TRUE(fs::exists(run / "toolpath" / "probe.h"));
  EXPECT_TRUE(fs::exists(run / "toolpath" / "toolpath.csv"));
  const auto toolpath = ReadJsonFile(run / "toolpath" / "toolpath.json");
  ASSERT_TRUE(toolpath.ok());
  EXPECT_EQ((*toolpath)["raster_angle_deg"].get<double>(), 45.0);
  ASSERT_TRUE(fs::exists(run / "loop-0" / "program_compensated.h")) << "the demo compensates after loop 0";
  EXPECT_EQ(Run("nc check --dialect heidenhain --nominal " + (run / "toolpath" / "program.h").string() +
                " --compensated " + (run / "loop-0" / "program_compensated.h").string() + " --side " +
                (run / "loop-0" / "compensation_side.bin").string()),
            0)
      << err_;

  (*part)["machine"]["dialect"] = "haas";
  ASSERT_TRUE(WriteJsonFile(dir_ / "bad.json", *part).ok());
  EXPECT_EQ(Run("run " + Path("bad.json") + " --out " + (dir_ / "bad").string()), 2);
  EXPECT_NE(err_.find("machine.dialect"), std::string::npos) << err_;
}

}  // namespace
}  // namespace formloop::app
