// Level 3 (spec/process-optimization.md §3, acceptance checks 5.3.18-23) on the reference scenario of
// §3.6: z = 20 + 5 sin(πx/100) cos(πy/100) on [0, 100]², ball r = 3, raster in x with step-over 1 (101
// passes of 50 G1 blocks of 2 mm, N10, N20, ..., posted by formloop for LinuxCNC), a 41 x 41 inspection
// grid (h = 2.5) with N(0, 0.003²) noise and t_p = 0.050. The re-cut is checked independently of the
// library: the adjusted program is read back and D, the normal shift of the nearest pass's tool path,
// interpolated along x, is subtracted from the planted error.

#include "planning/inspection_adjustment.h"

#include <gtest/gtest.h>

#include <Eigen/Geometry>
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <map>
#include <numbers>
#include <set>
#include <string>
#include <vector>

#include "core/random.h"
#include "nc-gen/moves.h"
#include "nc-gen/post.h"
#include "planning/program_edit.h"
#include "reconstruction/analytic_surface.h"
#include "tests/support/test_dir.h"

namespace formloop::planning {
namespace {

constexpr double kPi = std::numbers::pi;

class Scenario final : public recon::AnalyticSurface {
 public:
  std::string name() const override { return "level3"; }
  std::string description() const override { return "z = 20 + 5 sin(pi x/100) cos(pi y/100)"; }
  recon::ParamDomain domain() const override { return {0, 100, 0, 100}; }
  bool is_graph() const override { return true; }
  recon::SurfaceDerivatives Derivatives(double x, double y) const override {
    const double a = kPi / 100, sx = std::sin(a * x), cx = std::cos(a * x), sy = std::sin(a * y), cy = std::cos(a * y);
    recon::SurfaceDerivatives d;
    d.p = {x, y, 20 + 5 * sx * cy};
    d.su = {1, 0, 5 * a * cx * cy};
    d.sv = {0, 1, -5 * a * sx * sy};
    d.suu = {0, 0, -5 * a * a * sx * cy};
    d.suv = {0, 0, -5 * a * a * cx * sy};
    d.svv = {0, 0, -5 * a * a * sx * cy};
    return d;
  }
};

constexpr double kR = 3.0, kTol = 0.050, kH = 2.5;

std::string ScenarioProgram(const Scenario& s) {
  nc::MoveList list;
  list.header.tool_number = 1;
  list.header.tool_radius_mm = kR;
  list.header.spindle_rpm = 8000;
  list.header.passes = 101;
  list.safe_z_mm = 40;
  auto tip = [&](double x, double y) {
    const Eigen::Vector3d n = s.Normal(x, y);
    return Eigen::Vector3d(s.Point(x, y) + kR * n - kR * Eigen::Vector3d::UnitZ());
  };
  for (int j = 0; j <= 100; ++j) {
    nc::Move c;
    c.type = nc::MoveType::kComment;
    c.text = "pass " + std::to_string(j);
    list.moves.push_back(c);
    nc::Move m;
    m.type = nc::MoveType::kRapid;
    m.tip = tip(0, j) + Eigen::Vector3d(0, 0, 5);
    list.moves.push_back(m);
    m.type = nc::MoveType::kFeed;
    m.tip = tip(0, j);
    m.feed_mm_per_min = 400;
    list.moves.push_back(m);
    m.type = nc::MoveType::kSetFeed;
    m.feed_mm_per_min = 2000;
    list.moves.push_back(m);
    m.type = nc::MoveType::kFeed;
    for (int i = 1; i <= 50; ++i) {
      m.tip = tip(2.0 * i, j);
      list.moves.push_back(m);
    }
    m.type = nc::MoveType::kRapid;
    m.tip = Eigen::Vector3d(100, j, 40);
    m.axes = nc::kAxisZ;
    list.moves.push_back(m);
    m.axes = nc::kAxisXYZ;
  }
  nc::PostOptions options;
  options.title = "level 3 reference scenario";
  options.block_numbers = true;
  return nc::Post(list, "linuxcnc", options).value();
}

struct Fixture {
  Fixture()
      : program_text(ScenarioProgram(surface)),
        program(EditableProgram::Parse(program_text, "linuxcnc", "level3.ngc").value()),
        projector(recon::FootPointProjector::Build(surface).value()),
        geometry(BuildProgramGeometry(program, projector, kR, 0.5).value()) {}
  Scenario surface;
  std::string program_text;
  EditableProgram program;
  recon::FootPointProjector projector;  // keeps a reference to `surface`
  ProgramGeometry geometry;
};

const Fixture& Shared() {
  static const Fixture* f = new Fixture();
  return *f;
}

// The 41 x 41 inspection with deviation planted(x, y) + N(0, σ²).
template <typename F>
std::vector<metrology::Deviation> Inspect(const Scenario& s, F planted, double sigma, std::uint64_t seed) {
  Rng rng(seed);
  std::vector<metrology::Deviation> out;
  for (int i = 0; i <= 40; ++i) {
    for (int j = 0; j <= 40; ++j) {
      metrology::Deviation d;
      d.id = static_cast<std::int64_t>(out.size() + 1);
      const double x = kH * i, y = kH * j;
      d.foot = s.Point(x, y);
      d.normal = s.Normal(x, y);
      d.deviation_mm = planted(x, y) + sigma * rng.Normal();
      d.contact = d.foot + d.deviation_mm * d.normal;
      out.push_back(d);
    }
  }
  return out;
}

double Bump(double x, double y, double height) {
  return height * std::exp(-((x - 40) * (x - 40) + (y - 60) * (y - 60)) / 50);
}

// Tool tips of each pass (pass -> x-sorted tips), from a program's text.
std::map<int, std::vector<Eigen::Vector3d>> PassTips(const std::string& text) {
  const EditableProgram p = EditableProgram::Parse(text, "linuxcnc", "p").value();
  std::map<int, std::vector<Eigen::Vector3d>> out;
  int pass = -1;
  for (const ProgramLine& l : p.lines()) {
    if (l.text.rfind("(pass ", 0) == 0) pass = std::stoi(l.text.substr(6));
    if (l.move >= 0 && !p.moves()[static_cast<std::size_t>(l.move)].rapid && pass >= 0) {
      out[pass].push_back(p.moves()[static_cast<std::size_t>(l.move)].tip);
    }
  }
  return out;
}

Eigen::Vector3d TipAt(const std::vector<Eigen::Vector3d>& tips, double x) {
  for (std::size_t i = 1; i < tips.size(); ++i) {
    if (x <= tips[i].x() || i + 1 == tips.size()) {
      const double t = std::clamp((x - tips[i - 1].x()) / (tips[i].x() - tips[i - 1].x()), 0.0, 1.0);
      return tips[i - 1] + t * (tips[i] - tips[i - 1]);
    }
  }
  return tips.back();
}

// D at a point: the normal shift (into the material) of the nearest pass's tool path at the point's x.
double RecutShift(const std::map<int, std::vector<Eigen::Vector3d>>& before,
                  const std::map<int, std::vector<Eigen::Vector3d>>& after, const metrology::Deviation& d) {
  const int pass = static_cast<int>(std::lround(d.foot.y()));
  const Eigen::Vector3d delta = TipAt(after.at(pass), d.foot.x()) - TipAt(before.at(pass), d.foot.x());
  return -delta.dot(d.normal);
}

// The true set of §3.6: blocks with a CC sample where the planted |e| exceeds t_p/2.
template <typename F>
std::set<int> TrueBlocks(const ProgramGeometry& g, F planted) {
  std::set<int> out;
  for (std::size_t b = 0; b < g.blocks.size(); ++b) {
    for (const CcSample& s : g.blocks[b].samples) {
      if (std::abs(planted(s.cc.x(), s.cc.y())) > kTol / 2) out.insert(static_cast<int>(b));
    }
  }
  return out;
}

InspectionOptions Options() {
  InspectionOptions o;
  o.tolerance_mm = kTol;
  o.grid_spacing_mm = kH;
  o.part_id = "part-7";
  o.operation_id = "finish";
  o.probe_calibration_id = "cal-1";
  o.time = "2026-11-26T12:00:00Z";
  return o;
}

TEST(InspectionEvaluation, RigidShiftIsRecoveredExactly) {
  const Scenario s;
  const Eigen::Vector3d tau(0.02, -0.01, 0.03), omega(0, 0, 1e-4);
  auto points = Inspect(
      s, [](double, double) { return 0.0; }, 0, 1);
  for (metrology::Deviation& d : points) d.deviation_mm = (tau + omega.cross(d.foot)).dot(d.normal);
  const RigidFit fit = FitRigidDisplacement(points);
  EXPECT_LE((fit.tau - tau).norm(), 1e-6);
  EXPECT_LE((fit.omega - omega).norm(), 1e-8);
  EXPECT_LT(fit.form_error_mm, 1e-6);
}

TEST(InspectionAdjustment, PlantedOffsetIsTracedToItsBlocksAndCompensated) {
  const Fixture& f = Shared();
  auto planted = [](double x, double y) { return Bump(x, y, 0.060); };
  const auto points = Inspect(f.surface, planted, 0.003, 11);
  auto r = AdjustProgramFromInspection(f.program, f.geometry, f.projector, points, {}, Options(), "level3.ngc");
  ASSERT_TRUE(r.ok()) << r.status().ToString();
  EXPECT_GT(r->evaluation.moran_z, 2.33);
  ASSERT_EQ(r->regions.size(), 1u);
  const ErrorRegion& region = r->regions[0];
  EXPECT_EQ(region.type, "offset");
  EXPECT_LE((region.centroid.head<2>() - Eigen::Vector2d(40, 60)).norm(), 1.5);
  // Precision and recall of the block mapping against the true set.
  const std::set<int> truth = TrueBlocks(f.geometry, planted);
  int hits = 0;
  for (int b : region.blocks) hits += truth.count(b) ? 1 : 0;
  const double precision = static_cast<double>(hits) / static_cast<double>(region.blocks.size());
  const double recall = static_cast<double>(hits) / static_cast<double>(truth.size());
  EXPECT_GE(precision, 0.95);
  EXPECT_GE(recall, 0.90);
  // One range per pass touched, each within one pass.
  std::set<int> passes;
  for (int b : region.blocks) passes.insert(f.geometry.blocks[b].pass);
  EXPECT_EQ(region.block_ranges.size(), passes.size());
  ASSERT_EQ(r->kind, "recut");

  // Re-cut: e_new = e − D with D read from the programs.
  const auto before = PassTips(f.program_text), after = PassTips(r->program);
  double sum_before = 0, sum_after = 0, max_after = 0;
  int n = 0;
  for (std::size_t k = 0; k < points.size(); ++k) {
    const metrology::Deviation& d = points[k];
    const double e_new = d.deviation_mm - RecutShift(before, after, d);
    // The library's own prediction (D at the nearest CC sample, 0.5 mm apart) agrees within 1.5 um.
    EXPECT_NEAR(e_new, r->predicted_e_mm[k], 1.5e-3) << "point " << d.id;
    max_after = std::max(max_after, std::abs(e_new));
    if (std::abs(planted(d.foot.x(), d.foot.y())) <= kTol / 2) continue;
    sum_before += d.deviation_mm * d.deviation_mm;
    sum_after += e_new * e_new;
    ++n;
  }
  const double reduction = 1 - std::sqrt(sum_after / sum_before);
  EXPECT_GE(reduction, 0.80);
  EXPECT_LE(max_after, 0.025);
  // Outside the region and its taper band the program is byte-identical: every changed or new block lies
  // near the bump.
  const EditableProgram p0 = EditableProgram::Parse(f.program_text, "linuxcnc", "a").value();
  const EditableProgram p1 = EditableProgram::Parse(r->program, "linuxcnc", "b").value();
  std::map<long, std::string> old_lines;
  for (const ProgramLine& l : p0.lines()) {
    if (l.number >= 0) old_lines[l.number] = l.text;
  }
  int changed = 0;
  for (const ProgramLine& l : p1.lines()) {
    if (l.number < 0) continue;
    auto it = old_lines.find(l.number);
    if (it != old_lines.end() && it->second == l.text) continue;
    ++changed;
    const Eigen::Vector3d tip = p1.moves()[static_cast<std::size_t>(l.move)].tip;
    EXPECT_LT((tip.head<2>() - Eigen::Vector2d(40, 60)).norm(), 16.0) << l.text;
  }
  EXPECT_GT(changed, 0);
  std::printf(
      "planted offset: z = %.1f, 1 region at (%.2f, %.2f), %zu blocks in %zu pass ranges, precision %.3f, "
      "recall %.3f, %d changed/new blocks, RMS over the true region %.4f -> %.4f mm (-%.1f %%), max |e_new| "
      "%.4f mm\n",
      r->evaluation.moran_z, region.centroid.x(), region.centroid.y(), region.blocks.size(), region.block_ranges.size(),
      precision, recall, changed, std::sqrt(sum_before / n), std::sqrt(sum_after / n), 100 * reduction, max_after);
}

TEST(InspectionAdjustment, DeflectionFollowsTheLoadAndReducesTheFeed) {
  const Fixture& f = Shared();
  auto load = [](double x, double y) {
    return 120 + 130 * std::exp(-((x - 70) * (x - 70) + (y - 30) * (y - 30)) / 128);
  };
  auto planted = [&](double x, double y) { return 1.6e-4 * load(x, y); };
  const auto points = Inspect(f.surface, planted, 0.003, 12);
  std::map<std::string, double> block_load;
  for (const CutBlock& b : f.geometry.blocks) {
    const Eigen::Vector3d mid = b.samples[b.samples.size() / 2].cc;
    block_load[f.program.BlockName(b.line)] = load(mid.x(), mid.y());
  }
  auto r = AdjustProgramFromInspection(f.program, f.geometry, f.projector, points, block_load, Options(), "level3.ngc");
  ASSERT_TRUE(r.ok()) << r.status().ToString();
  ASSERT_EQ(r->regions.size(), 1u);
  EXPECT_EQ(r->regions[0].type, "deflection");
  EXPECT_GE(r->regions[0].rho, 0.7);
  EXPECT_GT(r->feeds_changed, 0);
  // Feed ratio of each cut move of the adjusted program: φ in [0.3, 1], below 1 only near the region.
  const EditableProgram p1 = EditableProgram::Parse(r->program, "linuxcnc", "b").value();
  std::map<int, std::vector<std::pair<double, double>>> phi_of_pass;  // pass -> (x, φ)
  int pass = -1;
  for (const ProgramLine& l : p1.lines()) {
    if (l.text.rfind("(pass ", 0) == 0) pass = std::stoi(l.text.substr(6));
    if (l.move < 0) continue;
    const nc::ProgramMove& m = p1.moves()[static_cast<std::size_t>(l.move)];
    if (m.rapid || m.feed_mm_per_min == 400) continue;  // the plunge
    const double phi = m.feed_mm_per_min / 2000;
    EXPECT_GE(phi, 0.3 - 1e-3);
    EXPECT_LE(phi, 1.0);
    if (phi < 1) {
      EXPECT_LT((m.tip.head<2>() - Eigen::Vector2d(70, 30)).norm(), 20.0) << l.text;
    }
    phi_of_pass[pass].emplace_back(m.tip.x(), phi);
  }
  const auto before = PassTips(f.program_text), after = PassTips(r->program);
  double sum_before = 0, sum_after = 0;
  for (const metrology::Deviation& d : points) {
    if (std::abs(planted(d.foot.x(), d.foot.y())) <= kTol / 2) continue;
    // φ of the block that ends at or after the point's x on the nearest pass.
    const auto& row = phi_of_pass.at(static_cast<int>(std::lround(d.foot.y())));
    double phi = 1;
    for (const auto& [x, p] : row) {
      if (x >= d.foot.x() - 1e-9) {
        phi = p;
        break;
      }
    }
    const double e_new = planted(d.foot.x(), d.foot.y()) * std::pow(phi, 0.75) - RecutShift(before, after, d);
    sum_before += d.deviation_mm * d.deviation_mm;
    sum_after += e_new * e_new;
  }
  const double reduction = 1 - std::sqrt(sum_after / sum_before);
  EXPECT_GE(reduction, 0.80);
  std::printf("deflection: rho %.3f, %d feeds reduced, RMS reduction %.1f %%\n", r->regions[0].rho, r->feeds_changed,
              100 * reduction);
}

TEST(InspectionAdjustment, OvercutIsNonConformingAndTheLogRoundTrips) {
  const Fixture& f = Shared();
  const auto points = Inspect(
      f.surface, [](double x, double y) { return Bump(x, y, -0.060); }, 0.003, 13);
  auto r = AdjustProgramFromInspection(f.program, f.geometry, f.projector, points, {}, Options(), "level3.ngc");
  ASSERT_TRUE(r.ok()) << r.status().ToString();
  ASSERT_EQ(r->regions.size(), 1u);
  EXPECT_EQ(r->regions[0].type, "overcut");
  EXPECT_TRUE(r->non_conforming);
  EXPECT_EQ(r->kind, "next_part");  // no re-cut program: the compensation is for the next parts
  EXPECT_NE(r->program.find("for the next part"), std::string::npos);
  ASSERT_TRUE(ValidateInspectionRecord(r->log_record).ok());
  const std::filesystem::path dir = formloop::testing::FreshTestDir("inspection_log");
  const std::filesystem::path log = dir / "inspections.jsonl";
  ASSERT_TRUE(AppendInspectionLog(log, r->log_record).ok());
  ASSERT_TRUE(AppendInspectionLog(log, r->log_record).ok());  // append-only: two records
  auto back = ReadInspectionLog(log);
  ASSERT_TRUE(back.ok()) << back.status().ToString();
  ASSERT_EQ(back->size(), 2u);
  EXPECT_EQ((*back)[1], r->log_record);
  std::filesystem::remove_all(dir);
  // A record without its evaluation is refused, naming the field.
  nlohmann::json broken = r->log_record;
  broken.erase("evaluation");
  const Status s = ValidateInspectionRecord(broken);
  EXPECT_NE(s.message().find("evaluation"), std::string::npos);
}

TEST(InspectionAdjustment, PureNoiseNeverChangesTheProgram) {
  const Fixture& f = Shared();
  int random = 0;
  for (std::uint64_t seed = 1; seed <= 100; ++seed) {
    const auto points = Inspect(
        f.surface, [](double, double) { return 0.0; }, 0.003, seed);
    auto r = AdjustProgramFromInspection(f.program, f.geometry, f.projector, points, {}, Options(), "level3.ngc");
    ASSERT_TRUE(r.ok());
    EXPECT_EQ(r->kind, "none") << "seed " << seed;
    EXPECT_TRUE(r->program.empty());
    random += r->evaluation.moran_z <= 2.33 ? 1 : 0;
  }
  EXPECT_GE(random, 95);
  std::printf("pure noise: Moran z <= 2.33 for %d of seeds 1-100, program unchanged for all\n", random);
}

TEST(InspectionAdjustment, OffsetBeyondTheLimitEditsNothing) {
  const Fixture& f = Shared();
  const auto points = Inspect(
      f.surface, [](double x, double y) { return Bump(x, y, 0.4); }, 0.003, 14);
  auto r = AdjustProgramFromInspection(f.program, f.geometry, f.projector, points, {}, Options(), "level3.ngc");
  ASSERT_TRUE(r.ok());
  EXPECT_EQ(r->kind, "none");
  ASSERT_FALSE(r->alarms.empty());
  EXPECT_EQ(r->alarms[0].rfind("L3-COMP-LIMIT: N", 0), 0u) << r->alarms[0];
}

}  // namespace
}  // namespace formloop::planning
