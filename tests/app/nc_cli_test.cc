// `formloop nc path` and `formloop nc probe` through the binary: every dialect's program reads back
// with formloop's reader to as many feed moves as the report has CL points, probing programs name
// every point, and limit violations are refused with nothing written.

#include <array>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <string>

#include <unistd.h>
#include <sys/wait.h>

#include <gtest/gtest.h>

#include "core/atomic_file.h"
#include "core/json_io.h"
#include "nc-gen/post.h"

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
    const std::string command = std::string(FORMLOOP_BINARY) + " " + args + " 2>" + Path("stderr.txt");
    FILE* pipe = ::popen(command.c_str(), "r");
    if (pipe == nullptr) return -1;
    std::array<char, 4096> buffer{};
    while (std::fread(buffer.data(), 1, buffer.size(), pipe) > 0) {
    }
    const int status = ::pclose(pipe);
    const auto err = ReadFile(Path("stderr.txt"));
    err_ = err.ok() ? *err : "";
    return WIFEXITED(status) ? WEXITSTATUS(status) : -1;
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
}

TEST_F(NcCliTest, LimitsAndBadOptionsAreRefusedWithNothingWritten) {
  const std::string out = Path("bad.nc");
  EXPECT_EQ(Run("nc path --surface " + Path("Q.step") + " --out " + out + " --max-feed 100"), 1);
  EXPECT_NE(err_.find("feed 300 mm/min"), std::string::npos) << err_;
  EXPECT_EQ(Run("nc path --surface " + Path("Q.step") + " --out " + out + " --travel-mm 20"), 1);
  EXPECT_NE(err_.find("outside the travel"), std::string::npos) << err_;
  EXPECT_EQ(Run("nc probe --surface " + Path("Q.step") + " --out " + out + " --travel-z-mm 1"), 1);
  EXPECT_EQ(Run("nc path --surface " + Path("Q.step") + " --out " + out + " --dialect haas"), 2);
  EXPECT_NE(err_.find("haas"), std::string::npos) << err_;
  EXPECT_EQ(Run("nc probe --surface " + Path("Q.step") + " --out " + out + " --grid 4by3"), 2);
  EXPECT_EQ(Run("nc path --surface " + Path("missing.step") + " --out " + out), 2);
  EXPECT_FALSE(fs::exists(out));
}

}  // namespace
}  // namespace formloop::app
