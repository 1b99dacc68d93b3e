// The run report (app/report.h): every section, every chart an inline SVG (its rasters valid PNGs),
// readable numbers and no raw JSON, byte-identical output, no network references, clear refusal without
// summary.json, the CLI, the diagnosis with and without the several-causes fields, the next-cycle note,
// the plant overview. tests/app/report_browser_test.cc renders the reports in headless Chromium.

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
#include "app/report_html.h"
#include "app/report_image.h"
#include "app/report_svg.h"
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

// The base64 of every PNG raster embedded in the report's SVG charts (<image href="data:image/png;base64,...">;
// std::regex overflows the stack on hundreds of kilobytes of base64, so this scans by hand).
std::vector<std::string> EmbeddedRasters(const std::string& html) {
  static const std::string kPrefix = "href=\"data:image/png;base64,";
  std::vector<std::string> rasters;
  for (std::size_t at = html.find(kPrefix); at != std::string::npos; at = html.find(kPrefix, at + 1)) {
    const std::size_t begin = at + kPrefix.size();
    rasters.push_back(html.substr(begin, html.find('"', begin) - begin));
  }
  return rasters;
}

// The report without its <script> elements: what a reader sees, not the inlined three.js.
std::string WithoutScripts(const std::string& html) {
  std::string out;
  std::size_t at = 0;
  for (std::size_t open = html.find("<script"); open != std::string::npos; open = html.find("<script", at)) {
    out += html.substr(at, open - at);
    const std::size_t close = html.find("</script>", open);
    if (close == std::string::npos) return out;
    at = close + 9;
  }
  return out + html.substr(at);
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

TEST_F(ReportTest, HasEverySectionAndInlineSvgCharts) {
  formloop::testing::WriteRunFixture(run_);
  const fs::path html_path = dir_ / "report.html";
  ASSERT_TRUE(WriteRunReport(run_, html_path).ok());
  const std::string html = Slurp(html_path);

  EXPECT_NE(html.find("<h1>Run report: fixture saddle</h1>"), std::string::npos);
  // The fixture's loop 1 is within tolerance: one compensation loop, two machined cycles.
  EXPECT_NE(html.find("Within tolerance after 1 compensation loop (2 machined cycles)"), std::string::npos);
  for (const char* heading : {"The part in 3-D", "Retrieval", "Plan", "Simulation correction", "Loop history",
                              "Deviations before and after", "Spatial analysis", "Diagnosis", "Retain"}) {
    EXPECT_NE(html.find(std::string("<h2>") + heading + "</h2>"), std::string::npos) << heading;
  }
  // Every optional file of the fixture is present, so no section may fall back.
  EXPECT_EQ(html.find("not available"), std::string::npos);
  EXPECT_NE(html.find("case-0002"), std::string::npos);  // second ranked candidate
  EXPECT_NE(html.find("tool_wear"), std::string::npos);  // diagnosis cause
  EXPECT_NE(html.find("k_w = 1.9 ± 0.1 µm/m"), std::string::npos);
  EXPECT_NE(html.find("0.1.0-test"), std::string::npos);  // footer version

  // Charts: bars, two maps, histogram, Moran scatter, LISA map, the 3-D view's static projection; no <img>.
  EXPECT_EQ(CountOf(html, "<svg class=\"chart\""), 7u);
  EXPECT_EQ(CountOf(html, "<img "), 0u);
  EXPECT_EQ(CountOf(html, "<figcaption>"), 7u);
  EXPECT_NE(html.find("<title>Systematic field of loop 0</title>"), std::string::npos);
  EXPECT_NE(html.find("−α = −20 µm"), std::string::npos);  // the histogram's tolerance line, as text
  const std::vector<std::string> rasters = EmbeddedRasters(html);
  EXPECT_EQ(rasters.size(), 2u);  // the two maps' interpolated fields
  for (std::size_t k = 0; k < rasters.size(); ++k) {
    const std::string png = DecodeBase64(rasters[k]);
    ASSERT_GE(png.size(), 33u) << "raster " << k;
    EXPECT_EQ(png.substr(0, 8), std::string("\x89PNG\r\n\x1a\n", 8)) << "raster " << k;
    EXPECT_GE(BigEndian32(png, 16), 100u) << "raster " << k;  // 160 cells along the longer side
  }
  // The 3-D view: three.js and its controls inlined, its data, and nothing fetched from anywhere.
  EXPECT_NE(html.find("three.js r111, Debian libjs-three"), std::string::npos);
  EXPECT_NE(html.find("<script type=\"application/json\" id=\"view3d-data\">"), std::string::npos);
  EXPECT_EQ(html.find("<script src"), std::string::npos);
  EXPECT_EQ(html.find("src=\"http"), std::string::npos);
  EXPECT_EQ(html.find("href=\"http"), std::string::npos);
  EXPECT_EQ(html.find("url(http"), std::string::npos);
  // What a reader sees: no exponent numbers, no raw JSON, no dotted-key dumps.
  const std::string text = WithoutScripts(html);
  EXPECT_EQ(text.find("e+0"), std::string::npos);
  EXPECT_EQ(text.find("{\""), std::string::npos);
  EXPECT_EQ(text.find("<code>case_plan."), std::string::npos);
}

TEST_F(ReportTest, NumbersAndKeysReadAsAReaderWantsThem) {
  EXPECT_EQ(report::Readable(21208.4), "21208");
  EXPECT_EQ(report::Readable(1.2e4), "12000");
  EXPECT_EQ(report::Readable(813.31), "813");
  EXPECT_EQ(report::Readable(3.40321), "3.4");
  EXPECT_EQ(report::Readable(0.020281028975), "0.0203");
  EXPECT_EQ(report::Readable(-29.63036), "-29.6");
  EXPECT_EQ(report::Readable(2.9e-11), "0");
  const report::KeyLabel feed = report::LabelOf("feed_mm_per_min");
  EXPECT_EQ(feed.name, "Feed");
  EXPECT_EQ(feed.unit, "mm/min");
  EXPECT_EQ(report::LabelOf("spindle_rpm").Header(), "Spindle (rpm)");
  EXPECT_EQ(report::LabelOf("raster_angle_deg").Header(), "Raster angle (°)");
  EXPECT_EQ(report::LabelOf("tz_um").symbol, "tz");
  EXPECT_EQ(report::LabelOf("tau_s").symbol, "τ");
  // Objects never print as JSON.
  EXPECT_EQ(report::Scalar(Json{{"flag_engineer", true}, {"scallop_um", 3.4}}), "Flag engineer: yes; Scallop: 3.4 µm");
}

TEST_F(ReportTest, InterpolatedFieldFollowsASmoothFieldAndLeavesHolesBlank) {
  // A 21 × 21 lattice over 100 × 100 mm without the points inside a 30 mm square hole; field 0.2 x − 0.1 y µm.
  std::vector<double> x, y, v;
  for (int j = 0; j <= 20; ++j) {
    for (int i = 0; i <= 20; ++i) {
      const double px = 5.0 * i, py = 5.0 * j;
      if (px > 35 && px < 65 && py > 35 && py < 65) continue;
      x.push_back(px), y.push_back(py), v.push_back(0.2 * px - 0.1 * py);
    }
  }
  const report::FieldGrid g = report::InterpolateField(x, y, v, 50, {});
  ASSERT_EQ(g.nx, 50);
  ASSERT_EQ(g.ny, 50);
  int checked = 0;
  for (int j = 0; j < g.ny; ++j) {
    for (int i = 0; i < g.nx; ++i) {
      const double cx = g.x0 + (i + 0.5) * g.dx, cy = g.y0 + (j + 0.5) * g.dy;
      const bool interior = cx > 10 && cx < 90 && cy > 10 && cy < 90;
      const bool hole = cx > 48 && cx < 52 && cy > 48 && cy < 52;  // > 1.5 spacings from every point
      if (hole) {
        EXPECT_TRUE(std::isnan(g.At(i, j))) << cx << ", " << cy;
      }
      if (interior && !(cx > 30 && cx < 70 && cy > 30 && cy < 70)) {
        ASSERT_FALSE(std::isnan(g.At(i, j))) << cx << ", " << cy;
        // A linear field is reproduced where the kernel sees points on every side (range 30 µm).
        EXPECT_NEAR(g.At(i, j), 0.2 * cx - 0.1 * cy, 0.3) << cx << ", " << cy;
        ++checked;
      }
    }
  }
  EXPECT_GT(checked, 1000);
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
  for (const char* what : {"Ranked candidates: not available", "Plan: not available", "Diagnosis: not available",
                           "Retain: not available", "Moran scatter plot: not available"}) {
    EXPECT_NE(html->find(what), std::string::npos) << what;
  }
  // No internal file is named to the reader.
  for (const char* file : {"retrieval.json", "plan.json", "diagnosis.json", "retain.json", "analysis.json"}) {
    EXPECT_EQ(WithoutScripts(*html).find(file), std::string::npos) << file;
  }
  // Form-error bars, the loop 0 map, histogram, LISA map and the 3-D view's projection remain.
  EXPECT_EQ(CountOf(*html, "<svg class=\"chart\""), 5u);
}

TEST_F(ReportTest, CommandWritesReportHtmlInTheRunFolder) {
  formloop::testing::WriteRunFixture(run_);
  std::string out;
  EXPECT_EQ(formloop::testing::RunFormloop("report " + run_.string() + " --quiet", &out), 0);
  EXPECT_NE(out.find("report.html"), std::string::npos);
  EXPECT_TRUE(fs::exists(run_ / "report.html"));
  EXPECT_EQ(formloop::testing::RunFormloop("report " + (dir_ / "no-such-run").string() + " --quiet", &out), 2);
}

TEST_F(ReportTest, DiagnosisWithAliasGroupsSaysWhatTheDataCannotSeparate) {
  formloop::testing::WriteRunFixture(run_);
  // diagnosis.json as the several-causes diagnosis writes it (issue 20): intervals, an aliased parameter,
  // an alias group with its separating experiment, an implausible fit, and an unexplained residual.
  const Json diagnosis = {
      {"causes",
       {{{"effect", "setup_offset"},
         {"parameters", {{"tz_um", -29.6}, {"tx_um", nullptr}}},
         {"std_errors", {{"tz_um", 4.5}, {"tx_um", nullptr}}},
         {"interval_95", {{"tz_um", {-38.5, -20.7}}, {"tx_um", {nullptr, nullptr}}}},
         {"aliased_parameters", {"tx_um"}},
         {"variance_explained", 0.96},
         {"z_before", 24.7},
         {"z_after", 3.5}},
        {{"effect", "tool_radius"},
         {"parameters", {{"delta_r_um", 48.3}}},
         {"std_errors", {{"delta_r_um", 4.0}}},
         {"variance_explained", 0.01},
         {"z_before", 3.5},
         {"z_after", 3.3}}}},
      {"alias_groups",
       {{{"finding", "one or more of: thermal_drift_z, tool_wear; these data cannot tell them apart"},
         {"members", {"thermal_drift_z", "tool_wear"}},
         {"carried_by", {"thermal_drift_z"}},
         {"variance_explained", 0.02},
         {"combined_rms_um", 1.4},
         {"design_correlation", 0.997},
         {"separate_by", "probe regions cut early and late"}}}},
      {"proposals",
       {{{"alias_group", {"thermal_drift_z", "tool_wear"}},
         {"kind", "raster_turn"},
         {"change", "turn the next part's raster by 90°"},
         {"cost_s", 0},
         {"design_correlation_before", 0.997},
         {"design_correlation_predicted", 0.41},
         {"predicted_to_split", true}}}},
      {"implausible",
       {{{"effect", "spindle_growth"},
         {"fitted", {{"tau_s", 34700}}},
         {"outside_plausible_range", {"tau_s = 34700 outside [60, 14400]"}}}}},
      {"unexplained", {{"message", "unexplained systematic residual"}, {"z", 3.3}, {"where", Json::array()}}},
      {"residual", {{"rms_um", 15.2}, {"noise_sigma_um", 1.4}}},
      {"gain",
       {{"rms_before_um", 15.2},
        {"rms_after_um", 1.1},
        {"heldout_rms_before_um", 15.2},
        {"heldout_rms_after_um", 1.2}}}};
  std::ofstream(run_ / "loop-0" / "diagnosis" / "diagnosis.json") << diagnosis.dump();
  Result<std::string> html = RenderRunReport(run_);
  ASSERT_TRUE(html.ok()) << html.status().ToString();
  for (const char* what :
       {"tz = -29.6 ± 4.5 µm, 95 % interval [-38.5, -20.7]", "tx = in an alias group (see below)", "96.0 %",
        "1.0 %<br><small>minor beside the leading cause</small>", "<h3>Alias groups</h3>", "thermal_drift_z, tool_wear",
        "probe regions cut early and late", "turn the next part's raster by 90°", "0.997 → 0.410",
        "tau_s = 34700 outside [60, 14400]", "An unexplained systematic residual remains", "Moran z = 3.30",
        "lowers the RMS by 92.1 %"}) {
    EXPECT_NE(html->find(what), std::string::npos) << what;
  }
  EXPECT_EQ(html->find("None: the causes above account"), std::string::npos);
  // Nothing named on its own: the alias groups carry the explanation, and the report says so.
  Json only_groups = diagnosis;
  only_groups["causes"] = Json::array();
  std::ofstream(run_ / "loop-0" / "diagnosis" / "diagnosis.json") << only_groups.dump();
  html = RenderRunReport(run_);
  ASSERT_TRUE(html.ok());
  EXPECT_NE(html->find("on its own (the alias groups below do, together)."), std::string::npos);
}

TEST_F(ReportTest, DiagnosisWithoutUnexplainedResidualIsNotAVerdict) {
  formloop::testing::WriteRunFixture(run_);
  Result<std::string> html = RenderRunReport(run_);
  ASSERT_TRUE(html.ok()) << html.status().ToString();
  EXPECT_NE(html->find("No spatially clustered residual was detected after the findings above"), std::string::npos);
  EXPECT_NE(html->find("not proof that nothing else acts"), std::string::npos);
  EXPECT_NE(html->find("≈95 % interval [1.7, 2.1] (±1.96 std. errors)"), std::string::npos);
  EXPECT_EQ(html->find("Unexplained residual</h3>\n<p>None"), std::string::npos);
}

TEST_F(ReportTest, OvercutFirstCycleSaysTheNextCutsANewBlank) {
  // The fixture's loop 0 bump reaches ±30 µm against α = 20 µm: points lie more than α/2 under the surface.
  formloop::testing::WriteRunFixture(run_);
  Result<std::string> html = RenderRunReport(run_);
  ASSERT_TRUE(html.ok());
  EXPECT_NE(html->find("Loop 0 cut below nominal"), std::string::npos);
  EXPECT_NE(html->find("to be cut on a new blank"), std::string::npos);
  // A virtual machine's cycles start from a new blank, and the report says so.
  std::ofstream(run_ / "loop-1" / "machine.json") << R"({"machine": "virtual-3axis"})";
  html = RenderRunReport(run_);
  ASSERT_TRUE(html.ok());
  EXPECT_NE(html->find("cut on a new blank (the virtual machine machines every cycle from a new blank)"),
            std::string::npos);
  // A first cycle that left material everywhere can be re-cut with the material left as allowance.
  formloop::testing::WriteRunFixture(dir_ / "shallow", {.amplitude_um = 6, .tolerance_um = 40});
  html = RenderRunReport(dir_ / "shallow");
  ASSERT_TRUE(html.ok());
  EXPECT_NE(html->find("can re-cut this workpiece with the material left as allowance"), std::string::npos);
}

TEST_F(ReportTest, WithoutThreeJsThe3dSectionShowsTheStaticViewAndSaysWhy) {
  formloop::testing::WriteRunFixture(run_);
  const fs::path empty = dir_ / "no-three-js";
  fs::create_directories(empty);
  ASSERT_EQ(setenv("FORMLOOP_THREE_JS_DIR", empty.c_str(), 1), 0);
  const Result<std::string> html = RenderRunReport(run_);
  unsetenv("FORMLOOP_THREE_JS_DIR");
  ASSERT_TRUE(html.ok()) << html.status().message();  // the report is still written
  const std::size_t section = html->find("The part in 3-D");
  ASSERT_NE(section, std::string::npos);
  EXPECT_NE(html->find("libjs-three", section), std::string::npos);  // says what is missing and the fix
  EXPECT_NE(html->find("Static view of the part", section), std::string::npos);
  EXPECT_EQ(html->find("<canvas", section), std::string::npos);  // no viewer without its script
  EXPECT_EQ(html->find("three.js r111"), std::string::npos);
  // With the package's folder the interactive view is back.
  const Result<std::string> full = RenderRunReport(run_);
  ASSERT_TRUE(full.ok());
  EXPECT_NE(full->find("<canvas"), std::string::npos);
}

TEST_F(ReportTest, BatchOverviewLinksEachPartsReport) {
  const fs::path batch = dir_ / "batch";
  formloop::testing::WriteRunFixture(batch / "part-a");
  formloop::testing::WriteRunFixture(batch / "part-b", {.loops = 1});
  ASSERT_TRUE(WriteRunReport(batch / "part-a", batch / "part-a" / "report.html").ok());
  std::ofstream(batch / "batch_summary.json")
      << R"({"parts": [{"part": "part-c", "part_file": "c.json", "status": "failed", "error": "bad input: c.json"}]})";
  std::string out;
  ASSERT_EQ(formloop::testing::RunFormloop("report --batch " + batch.string() + " --quiet", &out), 0) << out;
  const std::string html = Slurp(batch / "overview.html");
  EXPECT_NE(html.find("A batch run of 3 parts: <strong>1 within tolerance</strong>, 1 not, 1 failed."),
            std::string::npos);
  EXPECT_NE(html.find("<a href=\"part-a/report.html\">part-a</a>"), std::string::npos);
  EXPECT_NE(html.find("part-b<br><small>no report.html</small>"), std::string::npos);
  EXPECT_NE(html.find("failed: bad input: c.json"), std::string::npos);
  EXPECT_LT(html.find("part-a"), html.find("part-b"));     // name order
  EXPECT_EQ(html.find(dir_.string()), std::string::npos);  // no absolute folder
  // The same folder gives the same bytes; a folder without run folders is refused naming it.
  ASSERT_TRUE(WriteBatchOverview(batch, dir_ / "again.html").ok());
  EXPECT_EQ(Slurp(dir_ / "again.html"), html);
  fs::create_directories(dir_ / "empty");
  const Status status = WriteBatchOverview(dir_ / "empty", dir_ / "empty.html");
  EXPECT_EQ(status.code(), StatusCode::kBadInput);
  EXPECT_NE(status.message().find("holds no run folder"), std::string::npos) << status.message();
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

}  // namespace
}  // namespace formloop::app
