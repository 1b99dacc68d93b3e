// The run report (app/report.h): every section, every picture a valid PNG of the size the HTML
// states, byte-identical output, no network references, clear refusal without summary.json, the
// CLI, and a headless Chromium that loads every picture.

#include <array>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <string>
#include <vector>

#include <unistd.h>

#include <gtest/gtest.h>

#include "app/report.h"
#include "app/report_charts.h"
#include "app/report_image.h"
#include "core/log.h"
#include "tests/support/run_binary.h"
#include "tests/support/run_fixture.h"
#include "tests/support/test_dir.h"

namespace formloop::app {
namespace {

namespace fs = std::filesystem;

std::string Slurp(const fs::path& path) {
  std::ifstream in(path, std::ios::binary);
  return {std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>()};
}

// The test's own base64 decoder (independent of app::Base64); empty on a bad character.
std::string DecodeBase64(const std::string& text) {
  static const std::string kAlphabet = "ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
  std::string out;
  unsigned buffer = 0;
  int bits = 0;
  for (char c : text) {
    if (c == '=') break;
    const std::size_t v = kAlphabet.find(c);
    if (v == std::string::npos) return {};
    buffer = (buffer << 6) | static_cast<unsigned>(v);
    bits += 6;
    if (bits >= 8) {
      bits -= 8;
      out.push_back(static_cast<char>((buffer >> bits) & 0xFF));
    }
  }
  return out;
}

std::uint32_t BigEndian32(const std::string& bytes, std::size_t at) {
  std::uint32_t v = 0;
  for (std::size_t k = 0; k < 4; ++k) v = (v << 8) | static_cast<unsigned char>(bytes[at + k]);
  return v;
}

std::size_t CountOf(const std::string& text, const std::string& what) {
  std::size_t n = 0;
  for (std::size_t at = text.find(what); at != std::string::npos; at = text.find(what, at + 1)) ++n;
  return n;
}

// One <img src="data:image/png;base64,..." width="W" height="H" alt="..."> of the report.
struct EmbeddedImage {
  std::string base64;
  std::uint32_t width = 0;
  std::uint32_t height = 0;
  std::string alt;
};

// The value of attribute `name` in the tag starting at `from` (std::regex overflows the stack on
// hundreds of kilobytes of base64, so this scans by hand).
std::string Attribute(const std::string& html, std::size_t from, const std::string& name) {
  const std::size_t tag_end = html.find('>', from);
  const std::size_t at = html.find(" " + name + "=\"", from);
  if (at == std::string::npos || at > tag_end) return {};
  const std::size_t begin = at + name.size() + 3;
  return html.substr(begin, html.find('"', begin) - begin);
}

std::vector<EmbeddedImage> EmbeddedImages(const std::string& html) {
  static const std::string kPrefix = "data:image/png;base64,";
  std::vector<EmbeddedImage> images;
  for (std::size_t at = html.find("<img "); at != std::string::npos; at = html.find("<img ", at + 1)) {
    EmbeddedImage image;
    const std::string src = Attribute(html, at, "src");
    if (src.rfind(kPrefix, 0) == 0) image.base64 = src.substr(kPrefix.size());
    const std::string w = Attribute(html, at, "width"), h = Attribute(html, at, "height");
    image.width = w.empty() ? 0 : static_cast<std::uint32_t>(std::stoul(w));
    image.height = h.empty() ? 0 : static_cast<std::uint32_t>(std::stoul(h));
    image.alt = Attribute(html, at, "alt");
    images.push_back(std::move(image));
  }
  return images;
}

class ReportTest : public ::testing::Test {
 protected:
  void SetUp() override {
    log::SetLevel(log::Level::kWarn);
    dir_ = testing::FreshTestDir("formloop-report");
    run_ = dir_ / "run";
  }
  void TearDown() override { fs::remove_all(dir_); }
  fs::path dir_;
  fs::path run_;
};

TEST_F(ReportTest, HasEverySectionAndValidEmbeddedPngs) {
  formloop::testing::WriteRunFixture(run_);
  const fs::path html_path = dir_ / "report.html";
  ASSERT_TRUE(WriteRunReport(run_, html_path).ok());
  const std::string html = Slurp(html_path);

  EXPECT_NE(html.find("<h1>Run report: fixture saddle</h1>"), std::string::npos);
  EXPECT_NE(html.find("Within tolerance after 2 loops"), std::string::npos);
  for (const char* heading : {"Retrieval", "Plan", "Simulation correction", "Loop history",
                              "Deviations before and after", "Spatial analysis", "Diagnosis", "Retain"}) {
    EXPECT_NE(html.find(std::string("<h2>") + heading + "</h2>"), std::string::npos) << heading;
  }
  // Every optional file of the fixture is present, so no section may fall back.
  EXPECT_EQ(html.find("not available"), std::string::npos);
  EXPECT_NE(html.find("case-0002"), std::string::npos);  // second ranked candidate
  EXPECT_NE(html.find("tool_wear"), std::string::npos);  // diagnosis cause
  EXPECT_NE(html.find("k_w_um_per_m = 1.9 ± 0.1"), std::string::npos);
  EXPECT_NE(html.find("0.1.0-test"), std::string::npos);  // footer version

  const std::vector<EmbeddedImage> images = EmbeddedImages(html);
  for (std::size_t k = 0; k < images.size(); ++k) {
    const std::string png = DecodeBase64(images[k].base64);
    ASSERT_GE(png.size(), 33u) << "image " << k;
    EXPECT_EQ(png.substr(0, 8), std::string("\x89PNG\r\n\x1a\n", 8)) << "image " << k;
    EXPECT_EQ(png.substr(12, 4), "IHDR") << "image " << k;
    EXPECT_EQ(BigEndian32(png, 16), images[k].width) << "image " << k;
    EXPECT_EQ(BigEndian32(png, 20), images[k].height) << "image " << k;
    EXPECT_GE(images[k].width, 400u);
    EXPECT_GE(images[k].height, 300u);
    EXPECT_FALSE(images[k].alt.empty()) << "image " << k;
  }
  EXPECT_GE(images.size(), 7u);
  EXPECT_EQ(images.size(), CountOf(html, "<img "));  // every <img> is an embedded PNG
  EXPECT_EQ(CountOf(html, "<figcaption>"), images.size());
  EXPECT_EQ(html.find("http://"), std::string::npos);
  EXPECT_EQ(html.find("https://"), std::string::npos);
}

TEST_F(ReportTest, WritingTwiceIsByteIdentical) {
  formloop::testing::WriteRunFixture(run_);
  ASSERT_TRUE(WriteRunReport(run_, dir_ / "a.html").ok());
  ASSERT_TRUE(WriteRunReport(run_, dir_ / "b.html").ok());
  const std::string a = Slurp(dir_ / "a.html");
  EXPECT_GT(a.size(), 10000u);
  EXPECT_EQ(a, Slurp(dir_ / "b.html"));
}

TEST_F(ReportTest, MissingSummaryIsRefusedNamingTheFile) {
  formloop::testing::WriteRunFixture(run_);
  fs::remove(run_ / "summary.json");
  const Status status = WriteRunReport(run_, dir_ / "report.html");
  ASSERT_FALSE(status.ok());
  EXPECT_EQ(status.code(), StatusCode::kBadInput);
  EXPECT_NE(status.message().find("summary.json"), std::string::npos) << status.message();
  EXPECT_FALSE(fs::exists(dir_ / "report.html"));
}

TEST_F(ReportTest, MalformedSummaryIsRefusedNamingTheFile) {
  formloop::testing::WriteRunFixture(run_);
  std::ofstream(run_ / "summary.json") << "{\"part\": \"x\", \"tolerance_um\": 20, \"loops\": 3}\n";
  const Status status = WriteRunReport(run_, dir_ / "report.html");
  ASSERT_FALSE(status.ok());
  EXPECT_EQ(status.code(), StatusCode::kBadInput);
  EXPECT_NE(status.message().find("summary.json"), std::string::npos) << status.message();
  EXPECT_NE(status.message().find("loops"), std::string::npos) << status.message();
  EXPECT_FALSE(fs::exists(dir_ / "report.html"));
}

TEST_F(ReportTest, MissingOptionalFilesSayNotAvailable) {
  formloop::testing::WriteRunFixture(run_, {.loops = 1, .with_optional_files = false});
  fs::remove(run_ / "loop-0" / "analysis.json");
  Result<std::string> html = RenderRunReport(run_);
  ASSERT_TRUE(html.ok()) << html.status().ToString();
  EXPECT_NE(html->find("NOT within tolerance"), std::string::npos);
  for (const char* what : {"Ranked candidates (retrieval.json): not available", "Plan (plan.json): not available",
                           "Diagnosis (loop-0/diagnosis/diagnosis.json): not available",
                           "Retain (retain.json): not available", "Moran scatter plot: not available"}) {
    EXPECT_NE(html->find(what), std::string::npos) << what;
  }
  // Loop 0 maps, histogram, LISA map and form-error bars remain.
  EXPECT_EQ(CountOf(*html, "<img "), 5u);
}

TEST_F(ReportTest, CommandWritesReportHtmlInTheRunFolder) {
  formloop::testing::WriteRunFixture(run_);
  std::string out;
  EXPECT_EQ(formloop::testing::RunFormloop("report " + run_.string() + " --quiet", &out), 0);
  EXPECT_NE(out.find("report.html"), std::string::npos);
  EXPECT_TRUE(fs::exists(run_ / "report.html"));
  EXPECT_EQ(formloop::testing::RunFormloop("report " + (dir_ / "no-such-run").string() + " --quiet", &out), 2);
}

TEST(ReportImageTest, Base64AndColourMaps) {
  EXPECT_EQ(Base64(""), "");
  EXPECT_EQ(Base64("f"), "Zg==");
  EXPECT_EQ(Base64("fo"), "Zm8=");
  EXPECT_EQ(Base64("foobar"), "Zm9vYmFy");
  const Rgb zero = DivergingColour(0, 10), plus = DivergingColour(10, 10), minus = DivergingColour(-10, 10);
  EXPECT_GT(plus.r, plus.b);                 // positive: red
  EXPECT_GT(minus.b, minus.r);               // negative: blue
  EXPECT_EQ(zero.r, zero.b);                 // zero: neutral
  EXPECT_EQ(DivergingColour(99, 10), plus);  // clamped
  EXPECT_EQ(LisaColour(1), HexColour(0xd7191c));
  EXPECT_EQ(LisaColour(3), HexColour(0x2c7bb6));
  EXPECT_EQ(NiceTicks(-10, 10, 4), (std::vector<double>{-10, -5, 0, 5, 10}));
  EXPECT_EQ(TickLabel(2.5, 0.5), "2.5");
}

TEST(ReportImageTest, TextDrawsGlyphPixels) {
  Canvas c(40, 10);
  c.Text(1, 1, "1", HexColour(0x000000));
  // The digit 1's stem is font column 2: pixels (3, 1..7) are ink, (1, 1) is not.
  EXPECT_EQ(c.Get(3, 4), HexColour(0x000000));
  EXPECT_EQ(c.Get(1, 1), HexColour(0xffffff));
  EXPECT_EQ(Canvas::TextWidth("µm", 2), 22);
}

// Runs Chromium headless on the report and returns the dumped DOM.
std::string DumpDom(const fs::path& html, const fs::path& profile) {
  const std::string command =
      "timeout 120 /usr/bin/chromium --headless --no-sandbox --disable-gpu --disable-quic --no-first-run "
      "--disable-background-networking --disable-component-update --disable-sync --user-data-dir=" +
      profile.string() + " --virtual-time-budget=5000 --dump-dom 'file://" + fs::absolute(html).string() +
      "' 2>/dev/null";
  std::string out;
  FILE* pipe = ::popen(command.c_str(), "r");
  if (pipe == nullptr) return out;
  std::array<char, 4096> buffer{};
  std::size_t n;
  while ((n = std::fread(buffer.data(), 1, buffer.size(), pipe)) > 0) out.append(buffer.data(), n);
  ::pclose(pipe);
  return out;
}

TEST_F(ReportTest, HeadlessChromiumLoadsEveryImage) {
  if (!fs::exists("/usr/bin/chromium")) {
    if (std::getenv("CI") != nullptr) FAIL() << "/usr/bin/chromium is missing; scripts/setup.sh installs it";
    GTEST_SKIP() << "/usr/bin/chromium is not installed (scripts/setup.sh deps installs it)";
  }
  formloop::testing::WriteRunFixture(run_);
  const fs::path html_path = dir_ / "report.html";
  ASSERT_TRUE(WriteRunReport(run_, html_path).ok());
  const std::size_t images = CountOf(Slurp(html_path), "<img ");
  ASSERT_GE(images, 7u);
  fs::create_directories(dir_ / "chromium-profile");
  const std::string dom = DumpDom(html_path, dir_ / "chromium-profile");
  ASSERT_FALSE(dom.empty()) << "chromium printed nothing";
  const std::string expected = "data-images-loaded=\"" + std::to_string(images) + "/" + std::to_string(images) + "\"";
  EXPECT_NE(dom.find(expected), std::string::npos) << "expected " << expected << " in the dumped DOM";
}

}  // namespace
}  // namespace formloop::app
