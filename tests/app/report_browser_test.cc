// The run report (app/report.h) in a real browser: headless Chromium (WebGL through SwiftShader) opens
// report.html from disk and the report's own script records what rendered. Every SVG chart has a size and
// its rasters decode, the 3-D canvas is drawn (not blank), no element is wider than a 900 px window and no
// script error occurs; a screenshot of the fixture's report matches the stored reference within a
// tolerance; the demo part and a regression part are run, rendered and photographed at 900 and 1400 px
// into build/report-screenshots/ (for the issue and for people).

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <iterator>
#include <regex>
#include <string>
#include <vector>

#include <png.h>

#include <gtest/gtest.h>

#include "app/report.h"
#include "core/log.h"
#include "tests/support/run_binary.h"
#include "tests/support/run_fixture.h"
#include "tests/support/test_dir.h"

namespace formloop::app {
namespace {

namespace fs = std::filesystem;

const fs::path kChromium = "/usr/bin/chromium";

// Where the tests leave their screenshots: build/report-screenshots/.
fs::path ScreenshotDir() {
  const fs::path dir = fs::path(FORMLOOP_BINARY).parent_path().parent_path() / "report-screenshots";
  fs::create_directories(dir);
  return dir;
}

std::string Slurp(const fs::path& path) {
  std::ifstream in(path, std::ios::binary);
  return {std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>()};
}

std::string Shell(const std::string& command) {
  std::string out;
  FILE* pipe = ::popen(command.c_str(), "r");
  if (pipe == nullptr) return out;
  char buffer[4096];
  std::size_t n;
  while ((n = std::fread(buffer, 1, sizeof buffer, pipe)) > 0) out.append(buffer, n);
  ::pclose(pipe);
  return out;
}

// Chromium headless with WebGL on SwiftShader (the software GPU: same pixels on every machine), a fixed
// window and device scale, no network services, its own profile; the page gets 10 s of virtual time.
std::string Chromium(const fs::path& profile, int width, int height, const std::string& action, const fs::path& html) {
  return "timeout 90 " + kChromium.string() +
         " --headless --no-sandbox --use-angle=swiftshader --enable-unsafe-swiftshader --no-first-run "
         "--disable-background-networking --disable-component-update --disable-sync --disable-quic "
         "--hide-scrollbars --force-device-scale-factor=1 --font-render-hinting=none --user-data-dir=" +
         profile.string() + " --window-size=" + std::to_string(width) + "," + std::to_string(height) +
         " --virtual-time-budget=10000 " + action + " 'file://" + fs::absolute(html).string() + "' 2>/dev/null";
}

// The body's data-NAME attribute in a dumped DOM ("" when absent).
std::string Data(const std::string& dom, const std::string& name) {
  const std::string key = "data-" + name + "=\"";
  const std::size_t at = dom.find(key);
  if (at == std::string::npos) return "";
  const std::size_t begin = at + key.size();
  return dom.substr(begin, dom.find('"', begin) - begin);
}

struct Rgb8 {
  std::vector<unsigned char> pixels;  // RGB
  unsigned width = 0, height = 0;
};

Rgb8 ReadPng(const fs::path& path) {
  Rgb8 out;
  png_image image{};
  image.version = PNG_IMAGE_VERSION;
  if (!png_image_begin_read_from_file(&image, path.c_str())) return out;
  image.format = PNG_FORMAT_RGB;
  out.pixels.resize(PNG_IMAGE_SIZE(image));
  if (!png_image_finish_read(&image, nullptr, out.pixels.data(), 0, nullptr)) return {};
  out.width = image.width, out.height = image.height;
  return out;
}

class ReportBrowserTest : public ::testing::Test {
 protected:
  void SetUp() override {
    if (!fs::exists(kChromium)) {
      if (std::getenv("CI") != nullptr) FAIL() << "/usr/bin/chromium is missing; scripts/setup.sh installs it";
      GTEST_SKIP() << "/usr/bin/chromium is not installed (scripts/setup.sh deps installs it)";
    }
    log::SetLevel(log::Level::kWarn);
    dir_ = testing::FreshTestDir("formloop-report-browser");
    fs::create_directories(dir_ / "profile");
  }
  void TearDown() override { fs::remove_all(dir_); }

  // The dumped DOM at width × 1200 px, with every check of the report's own script asserted; returned
  // with Chromium's wall time for RenderAndPhotograph.
  struct Dump {
    std::string dom;
    double wall_s = 0;
  };
  Dump ExpectRendered(const fs::path& html, int width) {
    const std::string report = Slurp(html);
    std::size_t charts = 0;
    for (std::size_t at = report.find("<svg class=\"chart\""); at != std::string::npos;
         at = report.find("<svg class=\"chart\"", at + 1)) {
      ++charts;
    }
    const auto start = std::chrono::steady_clock::now();
    Dump out;
    out.dom = Shell(Chromium(dir_ / "profile", width, 1200, "--dump-dom", html));
    out.wall_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
    const std::string& dom = out.dom;
    EXPECT_FALSE(dom.empty()) << "chromium printed nothing";
    EXPECT_GE(charts, 5u);
    // The print-only projection is hidden on screen, so it has no size there: every other chart does.
    EXPECT_EQ(Data(dom, "charts-drawn"), std::to_string(charts - 1) + "/" + std::to_string(charts)) << html;
    const std::string rasters = Data(dom, "rasters-decoded");
    EXPECT_NE(rasters.find('/'), std::string::npos) << "no data-rasters-decoded: the page's script did not finish";
    EXPECT_EQ(rasters.substr(0, rasters.find('/')), rasters.substr(rasters.find('/') + 1)) << rasters;
    std::smatch m;
    const std::string view = Data(dom, "view3d");
    EXPECT_TRUE(std::regex_match(view, m, std::regex("drawn ([0-9]+)%"))) << view;
    if (!m.empty()) {
      EXPECT_GE(std::stoi(m[1]), 10) << "the 3-D canvas is (nearly) blank: " << view;
    }
    EXPECT_EQ(Data(dom, "too-wide"), "none") << "at " << width << " px";
    EXPECT_EQ(Data(dom, "errors"), "none");
    return out;
  }

  // At 900 and 1400 px: the page rendered (ExpectRendered) and a screenshot into
  // build/report-screenshots/<name>-<width>.png, the whole page up to 8,000 px high (SwiftShader's largest
  // surface is 8,192 px; a taller window renders nothing) as the dump measured it.
  void RenderAndPhotograph(const fs::path& html, const std::string& name) {
    for (int width : {900, 1400}) {
      const Dump dump = ExpectRendered(html, width);
      const std::string height = Data(dump.dom, "page-height");
      ASSERT_FALSE(height.empty());
      const fs::path shot = ScreenshotDir() / (name + "-" + std::to_string(width) + ".png");
      fs::remove(shot);
      const int shot_height = std::min(std::stoi(height), 8000);
      Shell(Chromium(dir_ / "profile", width, shot_height, "--screenshot=" + shot.string(), html));
      const Rgb8 image = ReadPng(shot);
      EXPECT_EQ(image.width, static_cast<unsigned>(width)) << shot;
      EXPECT_EQ(image.height, static_cast<unsigned>(shot_height)) << shot;
      std::cout << "[report] " << name << " at " << width << " px: " << fs::file_size(html) << " bytes, page " << height
                << " px high, load finished at " << Data(dump.dom, "render-ms") << " ms (page clock), chromium wall "
                << dump.wall_s << " s; screenshot " << shot.string() << "\n";
    }
  }

  fs::path dir_;
};

TEST_F(ReportBrowserTest, FixtureRendersEveryChartAndThe3dViewAt900px) {
  formloop::testing::WriteRunFixture(dir_ / "run");
  ASSERT_TRUE(WriteRunReport(dir_ / "run", dir_ / "report.html").ok());
  ExpectRendered(dir_ / "report.html", 900);
}

// The top of the fixture's report at 900 × 1400 px against tests/app/data/report_fixture_900.png: at most
// 2 % of the pixels may differ by more than 48 in a channel (font hinting, antialiasing). Set
// FORMLOOP_UPDATE_REFERENCE=1 to rewrite the reference after a deliberate change of the report's look.
TEST_F(ReportBrowserTest, FixtureScreenshotMatchesTheReference) {
  formloop::testing::WriteRunFixture(dir_ / "run");
  ASSERT_TRUE(WriteRunReport(dir_ / "run", dir_ / "report.html").ok());
  const fs::path shot = ScreenshotDir() / "fixture-900.png";
  fs::remove(shot);
  Shell(Chromium(dir_ / "profile", 900, 1400, "--screenshot=" + shot.string(), dir_ / "report.html"));
  const Rgb8 actual = ReadPng(shot);
  ASSERT_EQ(actual.width, 900u) << shot;
  ASSERT_EQ(actual.height, 1400u) << shot;
  const fs::path reference = fs::path(FORMLOOP_SOURCE_DIR) / "tests" / "app" / "data" / "report_fixture_900.png";
  if (std::getenv("FORMLOOP_UPDATE_REFERENCE") != nullptr) {
    fs::create_directories(reference.parent_path());
    fs::copy_file(shot, reference, fs::copy_options::overwrite_existing);
    GTEST_SKIP() << "reference rewritten: " << reference;
  }
  const Rgb8 expected = ReadPng(reference);
  ASSERT_EQ(expected.width, actual.width) << reference;
  ASSERT_EQ(expected.height, actual.height) << reference;
  std::size_t differing = 0, blank_canvas = 0;
  for (std::size_t p = 0; p < actual.pixels.size(); p += 3) {
    int worst = 0;
    for (int c = 0; c < 3; ++c) worst = std::max(worst, std::abs(actual.pixels[p + c] - expected.pixels[p + c]));
    differing += worst > 48;
  }
  const double share = static_cast<double>(differing) / (actual.width * actual.height);
  EXPECT_LT(share, 0.02) << differing << " pixels differ; see " << shot << " against " << reference;
  // And the screenshot is no blank page: the reference itself must hold the drawn part.
  for (std::size_t p = 0; p < expected.pixels.size(); p += 3) {
    blank_canvas += expected.pixels[p] > 240 && expected.pixels[p + 1] > 240 && expected.pixels[p + 2] > 240;
  }
  EXPECT_LT(static_cast<double>(blank_canvas) / (expected.width * expected.height), 0.9);
}

// A real run: the demo part (data/parts/demo-saddle.json) on a fresh starter library.
TEST_F(ReportBrowserTest, DemoPartRendersAt900And1400px) {
  std::string out;
  const fs::path kb = dir_ / "kb.sqlite";
  ASSERT_EQ(testing::RunFormloop("--quiet kb init " + kb.string() + " --starter", &out), 0);
  const fs::path run = dir_ / "demo";
  ASSERT_EQ(
      testing::RunFormloop("--quiet run " + std::string(FORMLOOP_SOURCE_DIR) + "/data/parts/demo-saddle.json --kb " +
                               kb.string() + " --no-retain --out " + run.string(),
                           &out),
      0);
  RenderAndPhotograph(run / "report.html", "demo");
}

// A regression part: the blade of data/regress/parts (the part whose tolerance label the PNG charts clipped).
TEST_F(ReportBrowserTest, RegressionPartRendersAt900And1400px) {
  std::string out;
  const fs::path kb = dir_ / "kb.sqlite";
  ASSERT_EQ(testing::RunFormloop("--quiet kb init " + kb.string() + " --starter", &out), 0);
  const fs::path run = dir_ / "reg-blade-a";
  ASSERT_EQ(testing::RunFormloop("--quiet run " + std::string(FORMLOOP_SOURCE_DIR) +
                                     "/data/regress/parts/reg-blade-a.json --kb " + kb.string() +
                                     " --no-retain --out " + run.string(),
                                 &out),
            0);
  RenderAndPhotograph(run / "report.html", "reg-blade-a");
}

}  // namespace
}  // namespace formloop::app
