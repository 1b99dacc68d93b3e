// `formloop tune` through the binary (app/cmd_tune.cc): exit codes, stdout JSON, nothing written on bad input.

#include <filesystem>
#include <string>

#include <gtest/gtest.h>

#include "core/atomic_file.h"
#include "core/json_io.h"
#include "tests/support/run_binary.h"
#include "tests/support/test_dir.h"

namespace formloop::app {
namespace {

namespace fs = std::filesystem;

TEST(TuneCli, BracketExitCodesAndOutputs) {
  const fs::path dir = testing::FreshTestDir("tune-cli");
  const std::string data = std::string(FORMLOOP_SOURCE_DIR) + "/data/tuning/bracket/";
  const std::string inputs = "--model " + data + "model.json --points " + data + "points.csv --block " + data +
                             "block.csv --offsets " + data + "offsets.json";
  std::string out, err;
  // SAFE and confirmed: exit 0, the summary on stdout.
  int code = testing::RunFormloop("tune " + inputs + " --confirm --out " + (dir / "ok").string(), &out, &err);
  EXPECT_EQ(code, 0) << err;
  auto summary = ParseJson(out, "stdout");
  ASSERT_TRUE(summary.ok()) << out;
  EXPECT_EQ((*summary)["status"], "SAFE");
  EXPECT_TRUE((*summary)["confirmed"].get<bool>());
  EXPECT_EQ((*summary)["ng"], 4);
  auto plan = ReadJsonFile(dir / "ok/offsets.json");
  ASSERT_TRUE(plan.ok());
  EXPECT_EQ((*plan)["writes"].size(), 3u);
  // The average strategy on the same part: D8 hangs on a work offset alone, D1/D4/D5 on T3, D6 on T5.
  code = testing::RunFormloop("tune " + inputs + " --strategy average --out " + (dir / "avg").string(), &out, &err);
  EXPECT_TRUE(code == 0 || code == 1) << err;
  EXPECT_TRUE(fs::exists(dir / "avg/offsets.json"));
  // Without the current offsets nothing can be written: exit 1, the reason on stderr.
  code = testing::RunFormloop(
      "tune --model " + data + "model.json --points " + data + "points.csv --out " + (dir / "blocked").string(), &out,
      &err);
  EXPECT_EQ(code, 1);
  EXPECT_NE(err.find("current offsets unknown"), std::string::npos) << err;
  // A bad model: exit 2, the message names the dimension, nothing written.
  Json model = *ReadJsonFile(data + "model.json");
  model["dimensions"][3]["tol_lower_mm"] = 0.5;
  ASSERT_TRUE(WriteJsonFile(dir / "bad.json", model).ok());
  code = testing::RunFormloop("tune --model " + (dir / "bad.json").string() + " --points " + data +
                                  "points.csv --out " + (dir / "bad").string(),
                              &out, &err);
  EXPECT_EQ(code, 2);
  EXPECT_NE(err.find("dimensions[D4].tol_lower_mm"), std::string::npos) << err;
  EXPECT_FALSE(fs::exists(dir / "bad"));
  EXPECT_FALSE(fs::exists(dir / "bad.partial"));
  fs::remove_all(dir);
}

}  // namespace
}  // namespace formloop::app
