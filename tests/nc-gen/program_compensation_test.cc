// Mirror compensation of a program formloop did not write (issue 23, "What it must show" 4). The test
// writes its own finishing program for a 3 mm ball on the reference cylinder (axis along Y, radius 80,
// through X50 Z-70): on a cylinder a ball-centre circle about the axis is an exact G18 arc, the same
// circle rising along the axis an exact helix, and a line along the axis an exact G1, so every nominal
// point touches Q. The field d_s(u, v) = 15 + 0.2 u − 0.1 v µm is given as samples and interpolated by
// the thin-plate field (which reproduces a linear field exactly). Expected positions are computed here
// from the cylinder's own geometry: ball centre B = T + 3 ẑ, normal n = (B − axis)/|B − axis| in XZ,
// foot point (u, v) = (50 + 80 n_x, B_y), offset −d_s(u, v)·n.

#include <cmath>
#include <numbers>
#include <sstream>
#include <string>
#include <vector>

#include <gtest/gtest.h>

#include "core/atomic_file.h"
#include "nc-gen/deviation_field.h"
#include "nc-gen/path_deviation.h"
#include "nc-gen/program_compensation.h"
#include "reconstruction/analytic_surface.h"
#include "tests/support/rs274.h"
#include "tests/support/test_dir.h"

namespace formloop::nc {
namespace {

using Eigen::Vector3d;

constexpr double kBall = 3, kRho = 83;  // ball radius; ball-centre distance from the axis (80 + 3)
constexpr double kDeg = std::numbers::pi / 180;

// Tip point at angle phi from the vertical (positive towards +X) and height y along the axis.
Vector3d Tip(double phi_deg, double y) {
  return Vector3d(50 + kRho * std::sin(phi_deg * kDeg), y, -70 + kRho * std::cos(phi_deg * kDeg) - kBall);
}

double FieldUm(double u, double v) { return 15 + 0.2 * u - 0.1 * v; }

// The offset the compensation must apply at tip T, from the cylinder's geometry.
Vector3d ExpectedOffset(const Vector3d& tip) {
  const Vector3d b = tip + kBall * Vector3d::UnitZ();
  const Vector3d n = Vector3d(b.x() - 50, 0, b.z() + 70).normalized();
  const double u = 50 + 80 * n.x(), v = b.y();
  return -1e-3 * FieldUm(u, v) * n;
}

std::string Num(double v) { return FormatCoordinate(v, 6); }

// One nominal feed block as the test wrote it: a line or an arc about the axis (phi0 -> phi1, y0 -> y1).
struct Cut {
  long line = 0;
  bool arc = false;
  double phi0 = 0, phi1 = 0, y0 = 0, y1 = 0;
  Vector3d At(double lambda) const {
    if (!arc) return Tip(phi0 + lambda * (phi1 - phi0), y0 + lambda * (y1 - y0));  // lines here keep phi
    return Tip(phi0 + lambda * (phi1 - phi0), y0 + lambda * (y1 - y0));
  }
};

// G18: (u, v) = (Z, X), centre words (K, I). The tip circle's centre is X50 Z-73.
std::string ArcBlock(const char* code, const Vector3d& from, const Vector3d& to) {
  return std::string(code) + " X" + Num(to.x()) + " Y" + Num(to.y()) + " Z" + Num(to.z()) + " I" + Num(50 - from.x()) +
         " K" + Num(-73 - from.z());
}

struct ShopProgram {
  std::string text;
  std::vector<Cut> cuts;
};

ShopProgram MakeProgram() {
  ShopProgram p;
  std::vector<std::string> lines = {"%", "(shop finishing program on the cylinder)", "G21 G90 G94 G18 G91.1"};
  auto add = [&](const std::string& l) { lines.push_back(l); };
  const Vector3d above = Tip(-30, 5) + Vector3d(0, 0, 10);
  add("G0 X" + Num(above.x()) + " Y5. Z" + Num(above.z()));
  // An approach arc in the air (off Q: a semicircle in XZ from 10 mm to 4 mm above the first point):
  // kept, never moved.
  const Vector3d a1 = Tip(-30, 5) + Vector3d(0, 0, 4);
  add("G2 X" + Num(a1.x()) + " Z" + Num(a1.z()) + " I0 K-3. F800");
  add("G1 Z" + Num(Tip(-30, 5).z()));  // plunge: ends on Q
  p.cuts.push_back({.line = 0, .arc = false, .phi0 = -30, .phi1 = -30, .y0 = 5, .y1 = 5});
  add(ArcBlock("G3", Tip(-30, 5), Tip(30, 5)));  // over the top, 60 degrees
  p.cuts.push_back({.line = 0, .arc = true, .phi0 = -30, .phi1 = 30, .y0 = 5, .y1 = 5});
  add("G1 Y45.");  // along the axis
  p.cuts.push_back({.line = 0, .arc = false, .phi0 = 30, .phi1 = 30, .y0 = 5, .y1 = 45});
  add(ArcBlock("G2", Tip(30, 45), Tip(-20, 65)));  // helix: back over the top rising 20 mm along Y
  p.cuts.push_back({.line = 0, .arc = true, .phi0 = 30, .phi1 = -20, .y0 = 45, .y1 = 65});
  add("G1 Y85.");
  p.cuts.push_back({.line = 0, .arc = false, .phi0 = -20, .phi1 = -20, .y0 = 65, .y1 = 85});
  add("G1 Z" + Num(Tip(-20, 85).z() + 4));  // retract in feed: ends off Q
  add("G0 Z30.");
  add("M30");
  add("%");
  for (const auto& l : lines) p.text += l + "\n";
  // Line numbers of the cuts: the plunge is line 6, then 7, 8, 9, 10.
  for (std::size_t i = 0; i < p.cuts.size(); ++i) p.cuts[i].line = 6 + static_cast<long>(i);
  return p;
}

DeviationField LinearField() {
  std::vector<DeviationSample> samples;
  for (double u = 0; u <= 100; u += 25) {
    for (double v = 0; v <= 90; v += 30) samples.push_back({.u = u, .v = v, .ds_um = FieldUm(u, v)});
  }
  auto field = DeviationField::Fit(samples, {});
  EXPECT_TRUE(field.ok());
  return *field;
}

class ProgramCompensationTest : public ::testing::Test {
 protected:
  void SetUp() override {
    auto s = recon::MakeReferenceSurface("cylinder");
    ASSERT_TRUE(s.ok());
    surface_ = std::move(s.value());
    auto q = recon::FootPointProjector::Build(*surface_);
    ASSERT_TRUE(q.ok());
    q_.emplace(std::move(q.value()));
    field_ = LinearField();
    options_.ball_radius_mm = kBall;
  }
  std::unique_ptr<recon::AnalyticSurface> surface_;
  std::optional<recon::FootPointProjector> q_;
  DeviationField field_;
  ProgramCompensationOptions options_;
};

// Issue 17 item 7: the decimals a corrected program is written with are the dialect's (Fanuc: at most 4 in mm,
// IS-C; 5 in inch), for `nc compensate --program` and `nc distribute` alike, refused by option name beyond.
TEST(CorrectedProgramDecimals, FollowTheDialectsLimits) {
  ProgramCompensationOptions o;
  o.ball_radius_mm = 3;
  o.reader.dialect = GcodeDialect::kFanuc;
  o.decimals_mm = 4;
  o.decimals_inch = 5;
  EXPECT_TRUE(o.Validate().ok()) << o.Validate().ToString();
  o.decimals_mm = 5;
  EXPECT_EQ(o.Validate().code(), StatusCode::kBadInput);
  EXPECT_NE(o.Validate().ToString().find("--decimals"), std::string::npos) << o.Validate().ToString();
  EXPECT_NE(o.Validate().ToString().find("fanuc program takes 1..4"), std::string::npos) << o.Validate().ToString();
  o.decimals_mm = 3;
  o.decimals_inch = 6;
  EXPECT_NE(o.Validate().ToString().find("--decimals-inch"), std::string::npos) << o.Validate().ToString();
  o.reader.dialect = GcodeDialect::kRs274ngc;
  o.decimals_mm = 6;
  o.decimals_inch = 7;
  EXPECT_TRUE(o.Validate().ok()) << o.Validate().ToString();
  o.decimals_mm = 7;
  EXPECT_EQ(o.Validate().code(), StatusCode::kBadInput);
  DistributeOptions d;
  d.reader.dialect = GcodeDialect::kFanuc;
  EXPECT_TRUE(d.Validate().ok()) << d.Validate().ToString();
  d.decimals_mm = 5;
  EXPECT_NE(d.Validate().ToString().find("--decimals"), std::string::npos) << d.Validate().ToString();
}

TEST_F(ProgramCompensationTest, EveryPointMovesByMinusDsTimesNormal) {
  const ShopProgram shop = MakeProgram();
  const auto result =
      CompensateProgramText(shop.text, "shop.ngc", *q_, field_.AsSystematicField(), "linear field", options_);
  ASSERT_TRUE(result.ok()) << result.status().message();
  const auto& rows = result->side.entries;
  const auto out = ReadProgramPath(result->program, {}, "out.ngc");
  ASSERT_TRUE(out.ok()) << out.status().message();
  std::vector<const PathMove*> feeds;
  for (const auto& m : out->moves) {
    if (m.motion != Motion::kRapid) feeds.push_back(&m);
  }
  ASSERT_EQ(feeds.size(), rows.size());
  const double q = 1e-4;  // 4 decimals
  double worst = 0, largest = 0;
  std::size_t on = 0, checked_cuts = 0;
  for (std::size_t k = 0; k < rows.size(); ++k) {
    const CompensationEntry& e = rows[k];
    const Cut* cut = nullptr;
    for (const Cut& c : shop.cuts) cut = c.line == e.nominal_line ? &c : cut;
    if (cut == nullptr) {  // the approach and the retract end off Q: written where the program says
      EXPECT_EQ(e.kind, ClKind::kOff) << "line " << e.nominal_line;
      EXPECT_FALSE(e.has_field_point);
      EXPECT_LE(e.offset_mm.norm(), std::sqrt(3.0) * 1e-4 / 2 + 1e-9) << "line " << e.nominal_line;
      continue;
    }
    ++on;
    checked_cuts += e.lambda == 1;
    const Vector3d nominal = cut->At(e.lambda);
    // The program prints 6 decimals: its arcs lie within 1e-6 mm of the ideal ones.
    EXPECT_LE((e.nominal_tip - nominal).norm(), 2e-6) << "row " << k;
    const Vector3d expected = nominal + ExpectedOffset(nominal);
    const double d = (feeds[k]->end - expected).norm();
    worst = std::max(worst, d);
    largest = std::max(largest, ExpectedOffset(nominal).norm());
    EXPECT_LE(d, std::sqrt(3.0) * q / 2 + 2e-6) << "row " << k << " line " << e.nominal_line << " lambda " << e.lambda;
    EXPECT_EQ(e.kind, ClKind::kCut);
  }
  EXPECT_EQ(checked_cuts, shop.cuts.size());
  EXPECT_GT(on, 100u);  // the two arcs are split (the offset turns with the normal along them)
  EXPECT_EQ(result->report.arcs_split, 2u);
  EXPECT_EQ(result->report.arcs_kept, 1u);  // the approach in the air
  EXPECT_NE(result->program.find("G2 X" + Num(Tip(-30, 5).x()) + " Z"), std::string::npos);
  EXPECT_GT(largest, 0.02);
  std::printf(
      "[compensate] %zu points (%zu on Q), arcs split %zu into %zu segments, largest offset %.1f um, "
      "max |written - expected| %.3g um (output resolution 0.1 um)\n",
      rows.size(), on, result->report.arcs_split, result->report.segments, 1e3 * largest, 1e3 * worst);
}

TEST_F(ProgramCompensationTest, CheckAgreesAndFindsACorruptedBlock) {
  const auto dir = testing::FreshTestDir("formloop-shop-comp");
  const ShopProgram shop = MakeProgram();
  ASSERT_TRUE(WriteFileAtomic(dir / "shop.ngc", shop.text).ok());
  const auto report = WriteCompensatedShopProgram(dir / "shop.ngc", *q_, field_.AsSystematicField(), "linear field",
                                                  options_, dir / "comp.ngc", dir / "side.csv");
  ASSERT_TRUE(report.ok()) << report.status().message();
  const auto side = ReadSideFile(dir / "side.csv");
  ASSERT_TRUE(side.ok()) << side.status().message();
  EXPECT_TRUE(side->has_lambda);
  const std::string compensated = *ReadFile(dir / "comp.ngc");
  if (testing::Rs274Installed()) {  // LinuxCNC accepts the compensated program and runs the same moves
    int code = 0;
    std::string console;
    const testing::Canon canon = testing::ParseCanon(testing::RunRs274(dir / "comp.ngc", &code, &console));
    EXPECT_EQ(code, 0) << console;
    const auto ours = ReadProgramPath(compensated, {}, "comp.ngc");
    ASSERT_TRUE(ours.ok());
    ASSERT_EQ(canon.moves.size(), ours->moves.size());
    for (std::size_t k = 1; k < canon.moves.size(); ++k) {  // the first rapid starts where rs274 happens to be
      EXPECT_LE((canon.moves[k].p - ours->moves[k].end).norm(), 1e-4) << "move " << k;
    }
  }
  const auto check =
      CheckProgramCompensation(shop.text, compensated, *side, field_.AsSystematicField(), {}, {.program_decimals = 4});
  ASSERT_TRUE(check.ok()) << check.status().message();
  EXPECT_TRUE(check->ok()) << check->ToJson().dump(1);
  EXPECT_TRUE(check->field_checked);
  EXPECT_LE(check->max_field_difference_um, check->tolerance_um);
  // Corrupt one vertex of the split helix by 0.5 µm in X: exactly that block is found.
  std::vector<std::string> lines;
  std::istringstream in(compensated);
  for (std::string l; std::getline(in, l);) lines.push_back(l);
  const CompensationEntry* target = nullptr;
  for (const auto& e : side->entries)
    target = (e.nominal_line == shop.cuts[3].line && e.lambda > 0.5 && !target) ? &e : target;
  ASSERT_NE(target, nullptr);
  std::string& l = lines[static_cast<std::size_t>(target->compensated_line - 1)];
  const auto x = l.find('X');
  ASSERT_NE(x, std::string::npos) << l;
  const double value = std::strtod(l.c_str() + x + 1, nullptr);
  const auto end = l.find(' ', x);
  l = l.substr(0, x + 1) + FormatCoordinate(value + 0.0005, 4) + (end == std::string::npos ? "" : l.substr(end));
  std::string corrupted;
  for (const auto& s : lines) corrupted += s + "\n";
  const auto bad =
      CheckProgramCompensation(shop.text, corrupted, *side, field_.AsSystematicField(), {}, {.program_decimals = 4});
  ASSERT_TRUE(bad.ok());
  ASSERT_EQ(bad->disagreeing.size(), 1u) << bad->ToJson().dump(1);
  EXPECT_EQ(bad->disagreeing[0].compensated_line, target->compensated_line);
  EXPECT_NEAR(bad->disagreeing[0].side_difference_um, 0.5, 0.1);
  // A side file that skips a nominal block is refused.
  SideFile short_side = *side;
  short_side.entries.pop_back();
  EXPECT_FALSE(CheckProgramCompensation(shop.text, compensated, short_side, {}, {}, {}).ok());
  std::filesystem::remove_all(dir);
}

TEST_F(ProgramCompensationTest, RefusesWhatItCannotMapWithTheLine) {
  auto refused = [&](const std::string& text) {
    return CompensateProgramText(text, "s.ngc", *q_, field_.AsSystematicField(), "f", options_).status();
  };
  const Status comp = refused("G21 G90\nG0 X50 Y5 Z20\nG41 D1 G1 X50 Y10 Z10 F100\n");
  EXPECT_NE(comp.message().find("s.ngc:3"), std::string::npos) << comp.message();
  EXPECT_NE(comp.message().find("cutter radius compensation"), std::string::npos) << comp.message();
  const Status unknown = refused("G21 G90\nG0 X50 Y5 Z20\nG1 X50 Y10 Z10 E1 F100\n");
  EXPECT_NE(unknown.message().find("E_UNKNOWN_WORD"), std::string::npos) << unknown.message();
  const Status position = refused("G21 G90\nG0 X50 Y5\nG1 X51 F100\n");
  EXPECT_NE(position.message().find("E_POSITION_UNKNOWN"), std::string::npos) << position.message();
  ProgramCompensationOptions tight = options_;
  tight.max_offset_um = 10;
  const ShopProgram shop = MakeProgram();
  const auto limit = CompensateProgramText(shop.text, "s.ngc", *q_, field_.AsSystematicField(), "f", tight);
  EXPECT_EQ(limit.status().code(), StatusCode::kSafetyLimit) << limit.status().message();
}

}  // namespace
}  // namespace formloop::nc
