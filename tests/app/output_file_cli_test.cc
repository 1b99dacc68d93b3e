// Single-file outputs through the binary (core/output_file.h): a file that exists is refused (exit 2, the
// file byte for byte as it was, the message naming it and the option) unless --force is given, and with
// --force only a file formloop wrote is replaced; no temporary file is left behind.

#include <chrono>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <string>
#include <vector>

#include <gtest/gtest.h>

#include "tests/support/run_binary.h"
#include "tests/support/run_fixture.h"
#include "tests/support/test_dir.h"

namespace formloop::app {
namespace {

namespace fs = std::filesystem;
using testing::RunFormloop;

std::string Slurp(const fs::path& path) {
  std::ifstream in(path, std::ios::binary);
  return std::string(std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>());
}

// A coarse path: a few thousand blocks on the saddle.
const std::string kFastPath = " --scallop-um 50 --chord-um 20 --max-spacing-mm 5";

class OutputFileCliTest : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    suite_dir_ = fs::temp_directory_path() / ("formloop-output-file-cli-" + std::to_string(::getpid()));
    fs::remove_all(suite_dir_);
    fs::create_directories(suite_dir_);
    std::string out, err;
    surface_ok_ = RunFormloop("-q surfaces export saddle --out " + (suite_dir_ / "Q.step").string(), &out, &err) == 0;
  }
  static void TearDownTestSuite() { fs::remove_all(suite_dir_); }
  void SetUp() override {
    ASSERT_TRUE(surface_ok_);
    dir_ = testing::FreshTestDir("formloop-output-file");
  }
  void TearDown() override { fs::remove_all(dir_); }

  std::string P(const std::string& name) const { return (dir_ / name).string(); }
  static std::string Q() { return (suite_dir_ / "Q.step").string(); }
  fs::path Write(const std::string& name, const std::string& content) const {
    std::ofstream(dir_ / name, std::ios::binary) << content;
    return dir_ / name;
  }
  int Run(const std::string& args) { return RunFormloop("-q " + args, &out_, &err_); }
  // Nothing but the named files: no temporary file ("<target>.tmp-<pid>-<n>") is left.
  void ExpectNoTempFiles() const {
    for (const auto& entry : fs::recursive_directory_iterator(dir_)) {
      EXPECT_EQ(entry.path().filename().string().find(".tmp-"), std::string::npos) << entry.path();
    }
  }
  // `command` (with {OUT} for the user's file) refused without and with --force; the file unchanged.
  void ExpectUserFileKept(const std::string& command, const std::string& name, const std::string& option) {
    const std::string content = Slurp(dir_ / name);
    std::string args = command;
    args.replace(args.find("{OUT}"), 5, P(name));
    EXPECT_EQ(Run(args), 2) << args << "\n" << err_;
    EXPECT_NE(err_.find(P(name) + ": field '" + option + "': already exists"), std::string::npos) << err_;
    EXPECT_NE(err_.find("--force"), std::string::npos) << err_;
    EXPECT_EQ(Slurp(dir_ / name), content);
    EXPECT_EQ(Run(args + " --force"), 2) << args << "\n" << err_;
    EXPECT_NE(err_.find(P(name) + ": field '" + option + "': already exists and formloop did not write it"),
              std::string::npos)
        << err_;
    EXPECT_EQ(Slurp(dir_ / name), content);
    ExpectNoTempFiles();
  }
  // `command` writes {OUT} afresh, is refused the second time, and replaces it with --force.
  void ExpectOwnFileReplaced(const std::string& command, const std::string& name) {
    std::string args = command;
    args.replace(args.find("{OUT}"), 5, P(name));
    fs::remove(dir_ / name);
    ASSERT_EQ(Run(args), 0) << args << "\n" << err_;
    const std::string first = Slurp(dir_ / name);
    ASSERT_FALSE(first.empty());
    EXPECT_EQ(Run(args), 2) << args;
    EXPECT_NE(err_.find("already exists"), std::string::npos) << err_;
    EXPECT_EQ(Slurp(dir_ / name), first);
    fs::last_write_time(dir_ / name, fs::file_time_type::clock::now() - std::chrono::hours(1));
    const auto before = fs::last_write_time(dir_ / name);
    EXPECT_EQ(Run(args + " --force"), 0) << args << "\n" << err_;
    EXPECT_GT(fs::last_write_time(dir_ / name), before) << name << " was not rewritten";
    ExpectNoTempFiles();
  }

  // `command` writes {MAIN} and {REPORT}; with only the report left, it is refused (the main output not written
  // either: both or neither), and with --force the report is replaced.
  void ExpectReportReplaced(std::string command, const std::string& main, const std::string& report) {
    command.replace(command.find("{MAIN}"), 6, P(main));
    command.replace(command.find("{REPORT}"), 8, P(report));
    ASSERT_EQ(Run(command), 0) << command << "\n" << err_;
    fs::remove(dir_ / main);
    EXPECT_EQ(Run(command), 2);
    EXPECT_NE(err_.find(P(report) + ": field '--report': already exists"), std::string::npos) << err_;
    EXPECT_FALSE(fs::exists(dir_ / main));
    EXPECT_EQ(Run(command + " --force"), 0) << err_;
    ExpectNoTempFiles();
  }

  static inline fs::path suite_dir_;
  static inline bool surface_ok_ = false;
  fs::path dir_;
  std::string out_, err_;
};

TEST_F(OutputFileCliTest, NcPathKeepsAUsersFileAndReplacesItsOwnProgramInEveryDialect) {
  Write("notes.txt", "my notes\nline two\n");
  ExpectUserFileKept("nc path --surface " + Q() + " --out {OUT}" + kFastPath, "notes.txt", "--out");
  ExpectUserFileKept("nc path --surface " + Q() + " --toolpath {OUT}" + kFastPath, "notes.txt", "--toolpath");
  ExpectUserFileKept("nc path --surface " + Q() + " --out " + P("p.ngc") + " --report {OUT}" + kFastPath, "notes.txt",
                     "--report");
  EXPECT_FALSE(fs::exists(dir_ / "p.ngc"));  // all or nothing: the program was not written either
  for (const char* dialect : {"linuxcnc", "fanuc", "heidenhain", "sinumerik"}) {
    ExpectOwnFileReplaced("nc path --surface " + Q() + " --dialect " + dialect + " --out {OUT}" + kFastPath,
                          std::string("p.") + dialect);
  }
  ExpectOwnFileReplaced("nc path --surface " + Q() + " --toolpath {OUT}" + kFastPath, "tp.csv");
  // The report (JSON, "generator": "formloop").
  ExpectReportReplaced("nc path --surface " + Q() + " --toolpath {MAIN} --report {REPORT}" + kFastPath, "t2.csv",
                       "report.json");
  // nc post of the tool path formloop wrote: its own program is replaced, the user's is not.
  ExpectOwnFileReplaced("nc post --toolpath " + P("tp.csv") + " --out {OUT}", "post.ngc");
  ExpectUserFileKept("nc post --toolpath " + P("tp.csv") + " --out {OUT}", "notes.txt", "--out");
}

TEST_F(OutputFileCliTest, NcProbeKeepsAUsersPartFile) {
  Write("p.json", "{\"name\": \"my part\", \"tolerance_mm\": 0.01}\n");
  ExpectUserFileKept("nc probe --surface " + Q() + " --grid 3x3 --out {OUT}", "p.json", "--out");
  for (const char* dialect : {"linuxcnc", "fanuc", "heidenhain"}) {
    ExpectOwnFileReplaced("nc probe --surface " + Q() + " --grid 3x3 --dialect " + dialect + " --out {OUT}",
                          std::string("probe.") + dialect);
  }
}

TEST_F(OutputFileCliTest, FitAndSurfacesKeepAUsersStepFile) {
  Write("user.step",
        "ISO-10303-21;\nHEADER;\nFILE_NAME('user.step','2024-01-01',(''),(''),'','OtherCAD','');\nENDSEC;\n");
  ExpectUserFileKept("fit analytic:saddle --grid 20x20 --check 100 --out {OUT}", "user.step", "--out");
  ExpectUserFileKept("surfaces export saddle --out {OUT}", "user.step", "--out");
  ExpectOwnFileReplaced("fit analytic:saddle --grid 20x20 --check 100 --out {OUT}", "q.step");
  ExpectReportReplaced("fit analytic:saddle --grid 20x20 --check 100 --out {MAIN} --report {REPORT}", "q2.step",
                       "fit.json");
  // Point files of every format carry the marker and still read back.
  for (const char* ext : {"csv", "xyz", "ply", "pcd"}) {
    const std::string name = std::string("s.") + ext;
    ExpectOwnFileReplaced("surfaces sample saddle --nu 6 --nv 6 --out {OUT}", name);
    EXPECT_EQ(Run("project --surface " + Q() + " --points " + P(name) + " --out " + P(std::string("d-") + name)), 0)
        << err_;
  }
}

TEST_F(OutputFileCliTest, ProjectKeepsAUsersCsv) {
  ASSERT_EQ(Run("surfaces sample saddle --nu 6 --nv 6 --out " + P("scan.csv")), 0) << err_;
  Write("user.csv", "a,b\n1,2\n");
  ExpectUserFileKept("project --surface " + Q() + " --points " + P("scan.csv") + " --out {OUT}", "user.csv", "--out");
  ExpectOwnFileReplaced("project --surface " + Q() + " --points " + P("scan.csv") + " --out {OUT}", "dev.csv");
  ExpectOwnFileReplaced("project --surface " + Q() + " --points " + P("scan.csv") + " --out {OUT}", "dev.ply");
}

TEST_F(OutputFileCliTest, CalibrateKeepsAUsersJsonAndReplacesItsProfile) {
  ExpectOwnFileReplaced("calibrate synth-sphere --points 30 --out {OUT}", "log.csv");
  Write("p3.json", "{\"name\": \"part 3\", \"surface\": {\"reference\": \"saddle\"}}\n");
  const std::string sphere = "calibrate sphere " + P("log.csv") + " --radius 12.5 --ball 1 --out {OUT}";
  ExpectUserFileKept(sphere, "p3.json", "--out");
  ExpectOwnFileReplaced(sphere, "profile.json");
}

TEST_F(OutputFileCliTest, ReportKeepsAUsersHtml) {
  formloop::testing::WriteRunFixture(dir_ / "run", {.grid = 8, .loops = 1});
  Write("mine.html", "<!DOCTYPE html>\n<html><head><title>mine</title></head><body>keep</body></html>\n");
  ExpectUserFileKept("report " + P("run") + " --out {OUT}", "mine.html", "--out");
  ExpectOwnFileReplaced("report " + P("run") + " --out {OUT}", "r.html");
}

TEST_F(OutputFileCliTest, KbExportKeepsAUsersFile) {
  ASSERT_EQ(Run("kb init " + P("kb.sqlite")), 0) << err_;
  Write("user.jsonl", "{\"type\": \"my line\"}\n");
  ExpectUserFileKept("kb export " + P("kb.sqlite") + " --out {OUT}", "user.jsonl", "--out");
  ExpectOwnFileReplaced("kb export " + P("kb.sqlite") + " --out {OUT}", "cases.jsonl");
}

}  // namespace
}  // namespace formloop::app
