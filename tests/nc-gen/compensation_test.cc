// Mirror compensation end to end (spec/nc-gen.md §4): a smooth deviation field from scattered values,
// the compensated program, its side file and the independent check of both programs against the field.

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <string>
#include <vector>

#include <gtest/gtest.h>

#include "core/atomic_file.h"
#include "core/number_text.h"
#include "core/parallel.h"
#include "nc-gen/compensation.h"
#include "nc-gen/deviation_field.h"
#include "nc-gen/post.h"
#include "nc-gen/toolpath.h"
#include "reconstruction/analytic_surface.h"
#include "reconstruction/bspline_surface.h"

namespace formloop::nc {
namespace {

namespace fs = std::filesystem;
constexpr double kPi = 3.14159265358979323846;

fs::path TempDir(const std::string& name) {
  const fs::path dir = fs::temp_directory_path() / ("formloop_compensation_test_" + name);
  fs::remove_all(dir);
  fs::create_directories(dir);
  return dir;
}

void WriteText(const fs::path& path, const std::string& text) {
  std::ofstream out(path);
  out << text;
}

// The moves of a program formloop wrote, as WriteCompensatedProgram takes the nominal one.
std::vector<ProgramMove> MovesOf(const std::string& text) {
  auto moves = ReadLinuxCncMoves(text, "nominal program");
  EXPECT_TRUE(moves.ok()) << moves.status().message();
  return moves.ok() ? *std::move(moves) : std::vector<ProgramMove>();
}

Toolpath SaddlePath(double max_point_spacing_mm = 2.0) {
  auto s = recon::MakeReferenceSurface("saddle");
  recon::FitReport report;
  auto q = recon::FitAnalytic(*s.value(), 30, 30, {}, 0, 1, &report);
  EXPECT_TRUE(q.ok());
  ToolpathOptions o;
  o.tool.radius_mm = 3.0;
  o.scallop_um = 5.0;
  o.max_point_spacing_mm = max_point_spacing_mm;
  auto path = PlanRaster(q.value(), o);
  EXPECT_TRUE(path.ok());
  return path.value();
}

// Scattered (pseudo-random, deterministic) points in [0, 10] x [0, 5].
std::vector<DeviationSample> Scattered(int n, double (*f)(double, double)) {
  std::vector<DeviationSample> samples;
  for (int i = 0; i < n; ++i) {
    const double u = 10.0 * std::fmod(0.6180339887 * (i + 1), 1.0);
    const double v = 5.0 * std::fmod(0.7548776662 * (i + 1) + 0.5698402910 * (i % 7), 1.0);
    samples.push_back({u, v, f(u, v), i + 2});
  }
  return samples;
}

double Wavy(double u, double v) { return 5.0 * std::sin(0.7 * u) * std::cos(0.9 * v) + 0.3 * u; }
double Linear(double u, double v) { return 3.0 + 0.2 * u - 0.7 * v; }

TEST(DeviationFieldTest, InterpolatesExactlyAtTheDataPointsWithoutSmoothing) {
  const auto samples = Scattered(80, Wavy);
  const auto field = DeviationField::Fit(samples, {});
  ASSERT_TRUE(field.ok()) << field.status().message();
  EXPECT_EQ(field->size(), 80u);
  for (const auto& s : samples) EXPECT_NEAR(field->EvaluateUm(s.u, s.v), s.ds_um, 1e-8);
  // Smooth between the points: close to the generating function in the interior (5 µm amplitude).
  EXPECT_NEAR(field->EvaluateUm(5.0, 2.5), Wavy(5.0, 2.5), 0.3);
  // Smoothing gives up exactness at the data points.
  const auto smooth = DeviationField::Fit(samples, {.smoothing = 1.0});
  ASSERT_TRUE(smooth.ok());
  double worst = 0;
  for (const auto& s : samples) worst = std::max(worst, std::abs(smooth->EvaluateUm(s.u, s.v) - s.ds_um));
  EXPECT_GT(worst, 1e-4);
}

TEST(DeviationFieldTest, ReproducesLinearFieldsExactlyForAnySmoothing) {
  const auto samples = Scattered(40, Linear);
  for (double lambda : {0.0, 0.5, 100.0}) {
    const auto field = DeviationField::Fit(samples, {.smoothing = lambda});
    ASSERT_TRUE(field.ok()) << field.status().message();
    for (double u : {-2.0, 0.3, 4.7, 12.0}) {
      for (double v : {-1.0, 2.2, 6.0}) EXPECT_NEAR(field->EvaluateUm(u, v), Linear(u, v), 1e-8) << lambda;
    }
    EXPECT_NEAR(field->AsSystematicField()(4.7, 2.2), 1e-3 * Linear(4.7, 2.2), 1e-11);
  }
}

// The tabulated field against the direct sum: within its tolerance everywhere (random points, the data
// points themselves, cell corners and centres), the direct sum itself off the grid, the same numbers for
// 1 and 2 threads, and chosen by AsSystematicField only for large jobs.
TEST(DeviationFieldTest, TabulatedFieldStaysWithinItsToleranceOfTheDirectSum) {
  std::vector<DeviationSample> samples;
  for (int a = 0; a < 24; ++a) {
    for (int b = 0; b < 24; ++b) {
      const double u = 10.0 * a / 23 + 0.05 * std::sin(7.0 * b), v = 5.0 * b / 23 + 0.05 * std::cos(3.0 * a);
      // Wavy plus a deterministic "noise" that makes the weights large.
      samples.push_back({u, v, Wavy(u, v) + 0.8 * std::sin(97.0 * a + 31.0 * b), a * 24 + b + 2});
    }
  }
  const auto field = DeviationField::Fit(samples, {});
  ASSERT_TRUE(field.ok()) << field.status().message();
  SetThreadCount(1);
  const auto one = field->Tabulate();
  SetThreadCount(2);
  const auto two = field->Tabulate();
  SetThreadCount(0);
  ASSERT_TRUE(one.ok() && two.ok()) << one.status().message();
  EXPECT_LE(one->measured_error_um(), kTabulatedToleranceUm);
  EXPECT_EQ(one->measured_error_um(), two->measured_error_um());
  std::vector<std::pair<double, double>> points;
  for (int i = 0; i < 4000; ++i) {
    points.emplace_back(10.0 * std::fmod(0.6180339887 * (i + 1), 1.0), 5.0 * std::fmod(0.7548776662 * (i + 1), 1.0));
  }
  for (const auto& s : samples) points.emplace_back(s.u, s.v);
  double worst = 0;
  for (const auto& [u, v] : points) {
    const double direct = field->EvaluateUm(u, v), tabulated = one->EvaluateUm(u, v);
    worst = std::max(worst, std::abs(tabulated - direct));
    EXPECT_EQ(tabulated, two->EvaluateUm(u, v));
  }
  EXPECT_LE(worst, kTabulatedToleranceUm);
  EXPECT_GT(worst, 0);  // it is an approximation, and the test can see it
  // Far outside the samples' box: the direct sum, exactly.
  EXPECT_EQ(one->EvaluateUm(40.0, -30.0), field->EvaluateUm(40.0, -30.0));
  // Small jobs keep the direct sum (the same bytes as before); large ones get the table.
  double error_um = 0;
  EXPECT_EQ(field->AsSystematicField(1000, &error_um)(3.3, 1.1), field->EvaluateMm(3.3, 1.1));
  EXPECT_EQ(error_um, -1);
  const SystematicField large = field->AsSystematicField(10'000'000, &error_um);
  EXPECT_EQ(error_um, one->measured_error_um());
  EXPECT_EQ(large(3.3, 1.1), one->EvaluateMm(3.3, 1.1));
}

TEST(DeviationFieldTest, RefusesDegenerateAndOversizedInput) {
  std::vector<DeviationSample> line = {{0, 0, 1, 2}, {1, 1, 2, 3}, {2, 2, 3, 4}};
  EXPECT_EQ(DeviationField::Fit(line, {}).status().code(), StatusCode::kBadInput);
  auto dup = Scattered(10, Linear);
  dup.push_back(dup[3]);
  dup.back().line = 99;
  const auto refused = DeviationField::Fit(dup, {}, "d.csv");
  ASSERT_FALSE(refused.ok());
  EXPECT_NE(refused.status().message().find("d.csv:99"), std::string::npos) << refused.status().message();
  EXPECT_NE(refused.status().message().find("line 5"), std::string::npos) << refused.status().message();
  EXPECT_TRUE(DeviationField::Fit(dup, {.smoothing = 0.1}).ok());
  const auto big = Scattered(static_cast<int>(kMaxDeviationSamples) + 1, Linear);
  const auto too_many = DeviationField::Fit(big, {});
  ASSERT_FALSE(too_many.ok());
  EXPECT_NE(too_many.status().message().find("3001 samples exceed"), std::string::npos);
  EXPECT_FALSE(DeviationField::Fit(Scattered(5, Linear), {.smoothing = -1}).ok());
}

TEST(DeviationFieldTest, ReadsCsvAndNamesFileLineAndField) {
  const fs::path dir = TempDir("csv");
  WriteText(dir / "ok.csv", "# d_s from loop 0\nid,u,v,ds_um\n1,0,0,1\n\n2,1,0,2\n3,0,1,3.5\n4,1,1,4.5\n");
  const auto samples = ReadDeviationSamples(dir / "ok.csv");
  ASSERT_TRUE(samples.ok()) << samples.status().message();
  ASSERT_EQ(samples->size(), 4u);
  EXPECT_EQ((*samples)[1].line, 5);
  EXPECT_DOUBLE_EQ((*samples)[2].ds_um, 3.5);
  const auto field = ReadDeviationField(dir / "ok.csv");
  ASSERT_TRUE(field.ok());
  EXPECT_NEAR(field->EvaluateUm(0, 1), 3.5, 1e-9);

  WriteText(dir / "bad.csv", "u,v,ds_um\n0,0,1\n1,0,x2\n");
  const auto bad = ReadDeviationSamples(dir / "bad.csv");
  ASSERT_FALSE(bad.ok());
  EXPECT_EQ(bad.status().code(), StatusCode::kBadInput);
  EXPECT_NE(bad.status().message().find("bad.csv:3: field 'ds_um'"), std::string::npos) << bad.status().message();
  WriteText(dir / "nocol.csv", "u,w,ds_um\n0,0,1\n");
  const auto nocol = ReadDeviationSamples(dir / "nocol.csv");
  ASSERT_FALSE(nocol.ok());
  EXPECT_NE(nocol.status().message().find("nocol.csv:1: field 'v'"), std::string::npos) << nocol.status().message();
  WriteText(dir / "short.csv", "u,v,ds_um\n0,0\n");
  const auto short_row = ReadDeviationSamples(dir / "short.csv");
  ASSERT_FALSE(short_row.ok());
  EXPECT_NE(short_row.status().message().find("short.csv:2"), std::string::npos);
}

// The known field: 5 µm · sin · cos over the path's parameter box, given at a 12 x 12 grid of points
// and interpolated by the thin-plate spline.
struct Fixture {
  Toolpath path;
  DeviationField field;
  SystematicField ds;
};

Fixture MakeFixture(double max_point_spacing_mm = 2.0) {
  Fixture f;
  f.path = SaddlePath(max_point_spacing_mm);
  double u0 = 1e300, u1 = -1e300, v0 = 1e300, v1 = -1e300;
  for (const auto& p : f.path.points) {
    u0 = std::min(u0, p.u), u1 = std::max(u1, p.u), v0 = std::min(v0, p.v), v1 = std::max(v1, p.v);
  }
  std::vector<DeviationSample> samples;
  for (int i = 0; i < 12; ++i) {
    for (int j = 0; j < 12; ++j) {
      const double u = u0 + (u1 - u0) * i / 11.0, v = v0 + (v1 - v0) * j / 11.0;
      samples.push_back(
          {u, v, 5.0 * std::sin(2 * kPi * (u - u0) / (u1 - u0)) * std::cos(kPi * (v - v0) / (v1 - v0)), 0});
    }
  }
  auto field = DeviationField::Fit(samples, {});
  EXPECT_TRUE(field.ok());
  f.field = field.value();
  f.ds = f.field.AsSystematicField();
  return f;
}

std::string CorruptZ(const std::string& text, long line_number, double delta_mm) {
  std::istringstream in(text);
  std::string line, out;
  long n = 0;
  while (std::getline(in, line)) {
    if (++n == line_number) {
      const auto z = line.find(" Z");
      const auto end = line.find(' ', z + 2);
      const double value = std::stod(line.substr(z + 2, end - z - 2));
      line =
          line.substr(0, z + 2) + FormatFixed(value + delta_mm, 4) + (end == std::string::npos ? "" : line.substr(end));
    }
    out += line + "\n";
  }
  return out;
}

// Both side-file forms: CSV text (".csv") and the compact binary one (any other name, as `formloop run` writes).
class SideFileFormTest : public ::testing::TestWithParam<std::string> {};

TEST_P(SideFileFormTest, EveryBlockMovesByMinusDsNToOutputPrecisionAndTheSideFileMatches) {
  const Fixture f = MakeFixture();
  const fs::path dir = TempDir("roundtrip");
  const fs::path side_path = dir / ("side" + GetParam());
  PostOptions post;  // 4 decimals: 0.1 µm
  const auto nominal_text = PostLinuxCnc(f.path, post);
  ASSERT_TRUE(nominal_text.ok());
  const auto comp = WriteCompensatedProgram(f.path, MovesOf(*nominal_text), f.ds, "TPS field, 144 samples", {}, post,
                                            dir / "compensated.ngc", side_path);
  ASSERT_TRUE(comp.ok()) << comp.status().message();
  EXPECT_GT(comp->max_offset_um, 4.0);
  EXPECT_LE(comp->max_offset_um, 5.05);
  const auto comp_text = ReadFile(dir / "compensated.ngc");
  ASSERT_TRUE(comp_text.ok());
  const auto a = ReadLinuxCncMoves(*nominal_text, "nominal");
  const auto b = ReadLinuxCncMoves(*comp_text, "compensated");
  ASSERT_TRUE(a.ok() && b.ok());
  std::vector<const ProgramMove*> fa, fb;
  for (const auto& m : *a)
    if (!m.rapid) fa.push_back(&m);
  for (const auto& m : *b)
    if (!m.rapid) fb.push_back(&m);
  ASSERT_EQ(fa.size(), f.path.points.size());
  ASSERT_EQ(fb.size(), f.path.points.size());
  // Each axis of each tip is rounded to 0.05 µm, so each axis of the offset is within 0.1 µm.
  for (std::size_t k = 0; k < fa.size(); ++k) {
    const ClPoint& cl = f.path.points[k];
    const Eigen::Vector3d expected = -f.ds(cl.u, cl.v) * cl.normal;
    const Eigen::Vector3d got = fb[k]->tip - fa[k]->tip;
    for (int axis = 0; axis < 3; ++axis) ASSERT_LE(std::abs(got[axis] - expected[axis]), 1e-4 + 1e-9) << k;
  }
  // Side file round trip.
  const auto side = ReadSideFile(side_path);
  ASSERT_TRUE(side.ok()) << side.status().message();
  EXPECT_EQ(side->source, "TPS field, 144 samples");
  EXPECT_TRUE(side->has_field_points);
  EXPECT_EQ(side->has_lambda, false);
  ASSERT_EQ(comp->blocks, f.path.points.size());
  ASSERT_EQ(side->entries.size(), f.path.points.size());
  // The CSV keeps 6 decimals of mm and 4 of um; the compact form 1 nm, 1 pm and 1e-6 um.
  const bool csv = GetParam() == ".csv";
  const double tip_step = 1e-6, offset_step = csv ? 1e-6 : 1e-9, ds_step = csv ? 1e-4 : 1e-6;
  for (std::size_t k = 0; k < side->entries.size(); ++k) {
    const auto& r = side->entries[k];
    const ClPoint& cl = f.path.points[k];
    const double ds_mm = cl.kind == ClKind::kCut ? f.ds(cl.u, cl.v) : 0.0;
    CompensationEntry e;
    e.nominal_tip = cl.tip;
    e.offset_mm = -ds_mm * cl.normal;  // to rounding of the tips (1e-14 mm)
    e.systematic_um = 1e3 * ds_mm;
    e.u = cl.u;
    e.v = cl.v;
    e.normal = cl.normal;
    EXPECT_EQ(r.kind, cl.kind);
    EXPECT_EQ(r.has_field_point, cl.kind == ClKind::kCut);
    EXPECT_EQ(r.cl_index, k);
    EXPECT_EQ(r.pass, f.path.points[k].pass);
    EXPECT_EQ(r.nominal_line, fa[k]->line);
    EXPECT_EQ(r.compensated_line, fb[k]->line);
    EXPECT_LE((r.nominal_tip - e.nominal_tip).cwiseAbs().maxCoeff(), 0.5 * tip_step + 1e-12);
    EXPECT_LE((r.offset_mm - e.offset_mm).cwiseAbs().maxCoeff(), 0.5 * offset_step + 1e-12);
    EXPECT_NEAR(r.systematic_um, e.systematic_um, 0.5 * ds_step + 1e-12);
    EXPECT_EQ(r.u, e.u);
    EXPECT_EQ(r.v, e.v);
    EXPECT_LE((r.normal - e.normal).cwiseAbs().maxCoeff(), 0.5e-9 + 1e-15);
  }
  // The checker agrees with everything: side file and field within the 0.175 µm tolerance.
  const auto report = CheckCompensation(*a, *b, *side, f.ds, {.program_decimals = 4});
  ASSERT_TRUE(report.ok()) << report.status().message();
  EXPECT_TRUE(report->ok()) << (report->ok() ? "" : report->disagreeing.front().Describe());
  EXPECT_TRUE(report->field_checked);
  EXPECT_EQ(report->blocks, fa.size());
  EXPECT_NEAR(report->tolerance_um, 0.1752, 1e-3);
  EXPECT_LE(report->max_side_difference_um, 0.1 * std::sqrt(3.0) + 0.001);
  EXPECT_LE(report->max_field_difference_um, 0.1 * std::sqrt(3.0) + 0.001);
}

INSTANTIATE_TEST_SUITE_P(CsvAndCompact, SideFileFormTest, ::testing::Values(".csv", ".bin"));

// The field is evaluated in parallel chunks of kCompensationChunk CL points: on a path of several chunks, one
// thread and two write the same program and side file, byte for byte.
TEST(CompensationCheckTest, OneThreadAndTwoWriteTheSameBytesOnAPathOfSeveralChunks) {
  const Fixture f = MakeFixture(/*max_point_spacing_mm=*/0.8);
  ASSERT_GT(f.path.points.size(), 2 * static_cast<std::size_t>(kCompensationChunk));
  const fs::path dir = TempDir("threads");
  PostOptions post;
  const auto nominal_text = PostLinuxCnc(f.path, post);
  ASSERT_TRUE(nominal_text.ok());
  const std::vector<ProgramMove> nominal = MovesOf(*nominal_text);
  std::vector<std::string> programs, sides;
  for (const int threads : {1, 2}) {
    SetThreadCount(threads);
    const fs::path program = dir / ("c" + std::to_string(threads) + ".ngc");
    const fs::path side = dir / ("side" + std::to_string(threads) + ".bin");
    const auto comp = WriteCompensatedProgram(f.path, nominal, f.ds, "field", {}, post, program, side);
    ASSERT_TRUE(comp.ok()) << comp.status().message();
    EXPECT_GT(comp->max_offset_um, 4.0);  // the field's 5 µm amplitude moved the points
    programs.push_back(ReadFile(program).value());
    sides.push_back(ReadFile(side).value());
  }
  SetThreadCount(0);
  EXPECT_NE(programs[0], *nominal_text);
  EXPECT_TRUE(programs[0] == programs[1]) << "the programs of 1 and 2 threads differ";
  EXPECT_TRUE(sides[0] == sides[1]) << "the side files of 1 and 2 threads differ";
}

TEST(CompensationCheckTest, ReportsExactlyTheCorruptedBlockWithItsLinesAndBothValues) {
  const Fixture f = MakeFixture();
  const fs::path dir = TempDir("corrupt");
  PostOptions post;
  const auto nominal_text = PostLinuxCnc(f.path, post);
  ASSERT_TRUE(nominal_text.ok());
  const auto comp =
      WriteCompensatedProgram(f.path, MovesOf(*nominal_text), f.ds, "field", {}, post, dir / "c.ngc", dir / "side.csv");
  ASSERT_TRUE(comp.ok()) << comp.status().message();
  const auto side = ReadSideFile(dir / "side.csv");
  ASSERT_TRUE(side.ok());
  const std::size_t victim = side->entries.size() / 2;
  const long victim_line = side->entries[victim].compensated_line;
  const std::string corrupted = CorruptZ(*ReadFile(dir / "c.ngc"), victim_line, 0.010);  // +10 µm in Z
  const auto a = ReadLinuxCncMoves(*nominal_text, "nominal");
  const auto b = ReadLinuxCncMoves(corrupted, "corrupted");
  ASSERT_TRUE(a.ok() && b.ok()) << b.status().message();
  const auto report = CheckCompensation(*a, *b, *side, f.ds, {.program_decimals = 4});
  ASSERT_TRUE(report.ok());
  ASSERT_EQ(report->disagreeing.size(), 1u);
  const BlockCheck& block = report->disagreeing.front();
  EXPECT_EQ(block.cl_index, victim);
  EXPECT_EQ(block.compensated_line, victim_line);
  EXPECT_EQ(block.nominal_line, side->entries[victim].nominal_line);
  EXPECT_NEAR(block.side_difference_um, 10.0, 0.2);
  EXPECT_NEAR(block.field_difference_um, 10.0, 0.2);
  EXPECT_NEAR(1e3 * (block.program_offset_mm - block.side_offset_mm).z(), 10.0, 0.2);
  EXPECT_EQ(block.problems.size(), 2u);  // side file and field
  EXPECT_NE(block.Describe().find("compensated line " + std::to_string(victim_line)), std::string::npos);
  EXPECT_FALSE(report->ToJson()["ok"].get<bool>());

  // Without the field only the side-file comparison runs, and still finds the same block.
  const auto side_only = CheckCompensation(*a, *b, *side, SystematicField{}, {.program_decimals = 4});
  ASSERT_TRUE(side_only.ok());
  EXPECT_FALSE(side_only->field_checked);
  ASSERT_EQ(side_only->disagreeing.size(), 1u);
  EXPECT_EQ(side_only->disagreeing.front().cl_index, victim);

  // A side file whose offset was edited (but the programs are intact) is caught too, on that block only.
  SideFile edited = *side;
  edited.entries[3].offset_mm.x() += 0.001;
  const auto intact = ReadLinuxCncMoves(*ReadFile(dir / "c.ngc"), "c");
  const auto edited_report = CheckCompensation(*a, *intact, edited, f.ds, {.program_decimals = 4});
  ASSERT_TRUE(edited_report.ok());
  ASSERT_EQ(edited_report->disagreeing.size(), 1u);
  EXPECT_EQ(edited_report->disagreeing.front().cl_index, 3u);
  EXPECT_EQ(edited_report->disagreeing.front().problems.size(), 1u);  // the field still agrees

  // A different field (d_s + 1 µm) disagrees on every cutting block; leads (off Q, never moved) are
  // not compared with the field.
  const SystematicField shifted = [&](double u, double v) { return f.ds(u, v) + 0.001; };
  const auto shifted_report = CheckCompensation(*a, *intact, *side, shifted, {.program_decimals = 4});
  ASSERT_TRUE(shifted_report.ok());
  const auto cutting = std::count_if(side->entries.begin(), side->entries.end(),
                                     [](const CompensationEntry& e) { return e.kind == ClKind::kCut; });
  EXPECT_GT(cutting, 0);
  EXPECT_LT(cutting, static_cast<long>(side->entries.size())) << "the path has leads";
  EXPECT_EQ(static_cast<long>(shifted_report->disagreeing.size()), cutting);
  for (const auto& e : side->entries) {
    if (e.kind != ClKind::kCut) {
      EXPECT_FALSE(e.has_field_point);
      EXPECT_EQ(e.offset_mm, Eigen::Vector3d::Zero()) << "leads keep their place";
    }
  }

  // Missing blocks are a failure, not a report.
  SideFile shorter = *side;
  shorter.entries.pop_back();
  EXPECT_EQ(CheckCompensation(*a, *intact, shorter, f.ds).status().code(), StatusCode::kFailed);
}

TEST(CompensationCheckTest, OffsetAboveTheMaximumIsRefusedWithTheReasonAndNothingIsWritten) {
  const Toolpath path = SaddlePath();
  const fs::path dir = TempDir("refuse");
  PostOptions post;
  const auto nominal_text = PostLinuxCnc(path, post);
  ASSERT_TRUE(nominal_text.ok());
  CompensationOptions options;
  options.max_offset_um = 20;
  // 5 µm everywhere except one CL point's neighbourhood where it reaches 25 µm.
  const ClPoint hot = path.points[path.points.size() / 3];
  const SystematicField field = [&](double u, double v) {
    return 0.005 + 0.020 * std::exp(-((u - hot.u) * (u - hot.u) + (v - hot.v) * (v - hot.v)) / 1e-6);
  };
  const auto result = WriteCompensatedProgram(path, MovesOf(*nominal_text), field, "too big", options, post,
                                              dir / "c.ngc", dir / "side.csv");
  ASSERT_FALSE(result.ok());
  EXPECT_EQ(result.status().code(), StatusCode::kSafetyLimit);
  const std::string& message = result.status().message();
  EXPECT_NE(message.find("compensation offset 25.0 um"), std::string::npos) << message;
  EXPECT_NE(message.find("exceeds the limit 20.0 um"), std::string::npos) << message;
  EXPECT_NE(message.find("no compensated program was written"), std::string::npos) << message;
  EXPECT_FALSE(fs::exists(dir / "c.ngc"));
  EXPECT_FALSE(fs::exists(dir / "side.csv"));
  EXPECT_TRUE(fs::is_empty(dir));
  // Just under the limit it goes through.
  options.max_offset_um = 25.5;
  EXPECT_TRUE(
      WriteCompensatedProgram(path, MovesOf(*nominal_text), field, "ok", options, post, dir / "c.ngc", dir / "side.csv")
          .ok());
  EXPECT_TRUE(fs::exists(dir / "c.ngc") && fs::exists(dir / "side.csv"));
}

TEST(CompensationCheckTest, CompactSideFileRoundTripsAndRefusesADamagedOne) {
  const fs::path dir = TempDir("compact");
  Compensation c;
  c.source = "field f.csv";
  for (std::size_t k = 0; k < 3; ++k) {
    CompensationEntry e;
    e.cl_index = k;
    e.pass = k < 2 ? 0 : 1;
    e.nominal_line = 12 + 2 * static_cast<long>(k);
    e.compensated_line = 12 + 2 * static_cast<long>(k);
    e.nominal_tip = Eigen::Vector3d(50.3012 - 0.1 * k, -40.86, 5.3074);
    e.offset_mm = Eigen::Vector3d(0.0012345678, -0.002, k == 0 ? 0.0 : -0.0159);
    e.systematic_um = k == 0 ? 0.0 : 15.987654;
    e.u = 0.1 + 0.3 * k;
    e.v = 1.0 / 3.0;
    e.normal = Eigen::Vector3d(0.6, 0, -0.8);
    e.kind = k == 0 ? ClKind::kLeadIn : ClKind::kCut;
    e.has_field_point = k != 0;
    c.entries.push_back(e);
  }
  ASSERT_TRUE(WriteSideFile(dir / "side.bin", c).ok());
  const std::string bytes = *ReadFile(dir / "side.bin");
  EXPECT_EQ(bytes.substr(0, 8), std::string("\x89"
                                            "FLSIDE\n"));
  const auto side = ParseSideFile(bytes, "side.bin");
  ASSERT_TRUE(side.ok()) << side.status().message();
  EXPECT_EQ(side->source, "field f.csv");
  EXPECT_TRUE(side->has_field_points);
  EXPECT_FALSE(side->has_lambda);
  ASSERT_EQ(side->entries.size(), 3u);
  for (std::size_t k = 0; k < 3; ++k) {
    const CompensationEntry &r = side->entries[k], &e = c.entries[k];
    EXPECT_EQ(r.cl_index, k);
    EXPECT_EQ(r.pass, e.pass);
    EXPECT_EQ(r.kind, e.kind);
    EXPECT_EQ(r.has_field_point, e.has_field_point);
    EXPECT_EQ(r.nominal_line, e.nominal_line);
    EXPECT_EQ(r.compensated_line, e.compensated_line);
    EXPECT_LE((r.nominal_tip - e.nominal_tip).cwiseAbs().maxCoeff(), 0.5e-6 + 1e-12);
    EXPECT_LE((r.offset_mm - e.offset_mm).cwiseAbs().maxCoeff(), 0.5e-9 + 1e-15);
    EXPECT_NEAR(r.systematic_um, e.systematic_um, 0.5e-6 + 1e-12);
    EXPECT_EQ(r.u, e.u);  // exact
    EXPECT_EQ(r.v, e.v);
    EXPECT_LE((r.normal - e.normal).cwiseAbs().maxCoeff(), 0.5e-9 + 1e-15);
  }
  // The same values as the CSV gives for decimals the CSV can hold: 50.3012 mm reads back bit for bit.
  EXPECT_EQ(side->entries[0].nominal_tip.x(), 50.3012);
  // Cut short, a newer version, trailing bytes: refused with the file and the byte.
  const auto cut = ParseSideFile(bytes.substr(0, bytes.size() - 5), "cut.bin");
  ASSERT_FALSE(cut.ok());
  EXPECT_NE(cut.status().message().find("cut.bin"), std::string::npos) << cut.status().message();
  EXPECT_NE(cut.status().message().find("row 2"), std::string::npos) << cut.status().message();
  EXPECT_NE(cut.status().message().find("cut short"), std::string::npos) << cut.status().message();
  std::string newer = bytes;
  newer[8] = 2;
  const auto version = ParseSideFile(newer, "v2.bin");
  ASSERT_FALSE(version.ok());
  EXPECT_NE(version.status().message().find("format version 2"), std::string::npos) << version.status().message();
  const auto trailing = ParseSideFile(bytes + "x", "t.bin");
  ASSERT_FALSE(trailing.ok());
  EXPECT_NE(trailing.status().message().find("after the last"), std::string::npos) << trailing.status().message();
  // Out of order entries are refused by the writer (nothing at the path).
  std::swap(c.entries[1], c.entries[2]);
  EXPECT_FALSE(WriteSideFile(dir / "swapped.bin", c).ok());
  EXPECT_FALSE(fs::exists(dir / "swapped.bin"));
}

TEST(CompensationCheckTest, SideFileReaderNamesLineAndFieldAndAcceptsTheOldColumns) {
  const std::string header =
      "# source: x\ncl_index,pass,nominal_line,compensated_line,nominal_x,nominal_y,nominal_z,offset_x,offset_y,"
      "offset_z,ds_um";
  const auto old = ParseSideFile(header + "\n0,0,12,12,1,2,3,0,0,-0.005,5\n", "old.csv");
  ASSERT_TRUE(old.ok()) << old.status().message();
  EXPECT_FALSE(old->has_field_points);
  EXPECT_EQ(old->source, "x");
  EXPECT_DOUBLE_EQ(old->entries[0].offset_mm.z(), -0.005);
  const auto bad = ParseSideFile(header + ",u,v,nx,ny,nz\n0,0,12,12,1,2,3,0,0,-0.005,5,0.1,0.2,0,0,abc\n", "s.csv");
  ASSERT_FALSE(bad.ok());
  EXPECT_NE(bad.status().message().find("s.csv:3: field 'nz'"), std::string::npos) << bad.status().message();
  const auto partial = ParseSideFile(header + ",u,v\n", "p.csv");
  ASSERT_FALSE(partial.ok());
  const auto order = ParseSideFile(header + "\n1,0,12,12,1,2,3,0,0,-0.005,5\n", "o.csv");
  ASSERT_FALSE(order.ok());
  EXPECT_NE(order.status().message().find("o.csv:3: field 'cl_index'"), std::string::npos);
  const auto missing = ParseSideFile("cl_index,pass\n", "m.csv");
  ASSERT_FALSE(missing.ok());
  EXPECT_NE(missing.status().message().find("m.csv:1: field 'nominal_line'"), std::string::npos);
}

}  // namespace
}  // namespace formloop::nc
