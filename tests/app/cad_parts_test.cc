// A shop's real parts through `formloop run` (issue 19): a trimmed face with a hole (and a pin in it),
// a region of three faces, a scan against the same part given analytically, a tri-lobe probe with and
// without its profile, a public CAD file, a starter family given as CAD, and the bad inputs. The CAD
// files are made here through OpenCASCADE with known exact geometry (tests/support/cad_fixtures.h).

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <optional>
#include <string>
#include <vector>

#include <gtest/gtest.h>
#include <BRepTopAdaptor_FClass2d.hxx>
#include <STEPControl_Reader.hxx>

#include <Eigen/Dense>

#include "app/kb_jobs.h"
#include "app/part.h"
#include "app/pipeline.h"
#include "app/report.h"
#include "app/run_folder.h"
#include "core/atomic_file.h"
#include "core/json_io.h"
#include "core/log.h"
#include "core/point_io.h"
#include "core/random.h"
#include "metrology/probe.h"
#include "nc-gen/toolpath_io.h"
#include "reconstruction/analytic_surface.h"
#include "reconstruction/bspline_surface.h"
#include "reconstruction/cad_io.h"
#include "reconstruction/foot_point.h"
#include "reconstruction/occt_support.h"
#include "reconstruction/surface_family.h"
#include "reconstruction/trim.h"
#include "retrieval/starter.h"
#include "tests/support/cad_fixtures.h"
#include "tests/support/run_binary.h"
#include "tests/support/starter_library.h"
#include "tests/support/swept_ball.h"
#include "tests/support/test_dir.h"

namespace formloop::app {
namespace {

namespace fs = std::filesystem;
const fs::path kData = fs::path(FORMLOOP_SOURCE_DIR) / "data";

// A complete part description: a 6 mm ball on a virtual machine with the demo's effects (tool-radius
// error, deflection, thermal drift, roughness and probe noise).
Json PartJson(const std::string& name, const Json& surface) {
  return Json{{"name", name},
              {"surface", surface},
              {"material", "H13"},
              {"tolerance_mm", 0.010},
              {"seed", 20261121},
              {"tool", {{"number", 1}, {"radius_mm", 3.0}}},
              {"toolpath", {{"scallop_um", 3}, {"chord_tolerance_um", 1}, {"max_point_spacing_mm", 0.5}}},
              {"machine",
               {{"name", "virtual-3axis"},
                {"travel_min_mm", {-300, -300, -150}},
                {"travel_max_mm", {300, 300, 150}},
                {"effects",
                 {{"tool_radius_error_um", 8},
                  {"deflection_um", 20},
                  {"thermal_amplitude_um", 6},
                  {"thermal_tau_s", 900},
                  {"surface_noise_um", 1.0},
                  {"probe_noise_um", 0.5}}}}},
              {"probing", {{"grid", {20, 20}}, {"inset_fraction", 0.05}}},
              {"loops", {{"max", 3}}}};
}

class CadPartsTest : public ::testing::Test {
 protected:
  void SetUp() override {
    log::SetLevel(log::Level::kWarn);
    recon::occt::KeepStdoutClean();
    dir_ = formloop::testing::FreshTestDir("formloop-cad-parts");
  }
  void TearDown() override { fs::remove_all(dir_); }
  // Writes the part file into dir_ and runs it.
  Result<RunSummary> Run(const Json& part_json, const std::string& out, bool with_kb = false) {
    const fs::path file = dir_ / (part_json["name"].get<std::string>() + ".json");
    EXPECT_TRUE(WriteJsonFile(file, part_json).ok());
    FL_ASSIGN_OR_RETURN(PartSpec part, ReadPart(file));
    RunOptions o;
    o.out = dir_ / out;
    o.machine = "virtual";
    o.report = false;
    if (with_kb) {
      if (!fs::exists(dir_ / "kb.sqlite")) fs::copy_file(formloop::testing::StarterLibrary(), dir_ / "kb.sqlite");
      o.kb = (dir_ / "kb.sqlite").string();
      o.retain = false;
    }
    return RunPart(part, o);
  }
  fs::path dir_;
};

// The face of a STEP file straight from OpenCASCADE's reader (independent of formloop's CAD reading).
TopoDS_Face FirstBSplineFace(const fs::path& step) {
  STEPControl_Reader reader;
  EXPECT_EQ(reader.ReadFile(step.string().c_str()), IFSelect_RetDone);
  reader.TransferRoots();
  for (TopExp_Explorer it(reader.OneShape(), TopAbs_FACE); it.More(); it.Next()) {
    if (BRep_Tool::Surface(TopoDS::Face(it.Current()))->IsKind(STANDARD_TYPE(Geom_BSplineSurface))) {
      return TopoDS::Face(it.Current());
    }
  }
  return {};
}

// Item 1: a trimmed free-form face with a hole (and a pin standing in it).
TEST_F(CadPartsTest, TrimmedFaceWithAHoleReachesToleranceWithinOneLoop) {
  ASSERT_TRUE(formloop::testing::WriteStepFaces(
      dir_ / "holed.step", {formloop::testing::MakeHoledFace(), formloop::testing::MakePin()}, {"top", "pin"}));
  const auto summary = Run(PartJson("holed", {{"cad", "holed.step"}, {"face_names", {"top"}}}), "holed");
  ASSERT_TRUE(summary.ok()) << summary.status().ToString();
  std::printf("[measured] holed face: form error per loop");
  for (const LoopSummary& l : summary->loops) std::printf(" %.2f", l.form_error_um);
  std::printf(" um (tolerance %.0f um), loops to tolerance %d\n", summary->tolerance_um, summary->LoopsToTolerance());
  EXPECT_GT(summary->loops.front().form_error_um, summary->tolerance_um) << "the loop must have work to do";
  EXPECT_GE(summary->LoopsToTolerance(), 0);
  EXPECT_LE(summary->LoopsToTolerance(), 1);

  // Independently of the planner: every cutting CL's contact point and every probe point classified by
  // OpenCASCADE on the face read from the file (its parameters are x and y).
  const TopoDS_Face top = FirstBSplineFace(dir_ / "holed.step");
  const BRepTopAdaptor_FClass2d classifier(top, 1e-5);
  const auto path = nc::ReadToolpathFile(dir_ / "holed" / "toolpath" / "toolpath.csv");
  ASSERT_TRUE(path.ok()) << path.status().ToString();
  int cut = 0;
  for (const nc::ClPoint& cl : path->points) {
    if (cl.kind != nc::ClKind::kCut) continue;
    ++cut;
    const TopAbs_State s = classifier.Perform(gp_Pnt2d(cl.cc.x(), cl.cc.y()), Standard_False);
    ASSERT_TRUE(s == TopAbs_IN || s == TopAbs_ON) << cl.cc.transpose();
  }
  const Json plan = ReadJsonFile(dir_ / "holed" / "toolpath" / "probing_plan.json").value();
  ASSERT_EQ(plan["trim"]["edge_margin_mm"], metrology::kProbeEdgeMarginMm);
  for (const Json& p : plan["points"]) {
    const double x = p["point"][0], y = p["point"][1];
    ASSERT_EQ(classifier.Perform(gp_Pnt2d(x, y), Standard_False), TopAbs_IN) << p.dump();
    // The stated margin, in the plane (a lower bound of the 3-D distance used by the plan).
    EXPECT_FALSE(formloop::testing::NearHoledBoundary(x, y, 0.9 * metrology::kProbeEdgeMarginMm)) << p.dump();
  }
  std::printf("[measured] holed face: %d cutting CL points and %zu probe points, all inside the face\n", cut,
              plan["points"].size());
  // The trimmed plan reads back (it carries "trim"), as `diagnose`/`simulate` read a run folder's plan.
  const auto read_back = ReadPlanFile(dir_ / "holed" / "toolpath" / "probing_plan.json");
  ASSERT_TRUE(read_back.ok()) << read_back.status().ToString();
  EXPECT_TRUE(read_back->plan.trimmed);
  EXPECT_EQ(read_back->plan.points.size(), plan["points"].size());
  // The run keeps the CAD file and its hash: the resolved part runs again from the folder.
  EXPECT_TRUE(fs::exists(dir_ / "holed" / "inputs" / "holed.step"));
  const auto again = ReadPart(dir_ / "holed" / "inputs" / "part.json");
  ASSERT_TRUE(again.ok()) << again.status().ToString();
  EXPECT_EQ(again->surface_file->sha256,
            ReadJsonFile(dir_ / "holed" / "inputs" / "part.json").value()["surface"]["sha256"]);
}

// Item 2: a region of three faces fitted as one Q; the seams judged on the exact CAD faces.
TEST_F(CadPartsTest, ThreeFaceRegionRunsAndItsSeamsMeetTheScallopBounds) {
  ASSERT_TRUE(formloop::testing::WriteStepFaces(dir_ / "strips.step", formloop::testing::MakeThreeStrips(),
                                                {"left", "middle", "right"}));
  const auto summary = Run(PartJson("strips", {{"cad", "strips.step"}, {"faces", {0, 1, 2}}}), "strips");
  ASSERT_TRUE(summary.ok()) << summary.status().ToString();
  const Json surface = ReadJsonFile(dir_ / "strips" / "surface" / "surface.json").value();
  const double deviation_um = surface["region"]["cad_deviation_max_mm"].get<double>() * 1e3;
  std::printf(
      "[measured] three faces: Q's deviation from the CAD faces max %.4f um (limit %.1f um); form error per loop",
      deviation_um, surface["deviation_limit_mm"].get<double>() * 1e3);
  for (const LoopSummary& l : summary->loops) std::printf(" %.2f", l.form_error_um);
  std::printf(" um\n");
  EXPECT_LE(deviation_um, 0.1 * summary->tolerance_um);
  EXPECT_NEAR(summary->fit_check_max_um, deviation_um, 1e-9);
  EXPECT_TRUE(summary->within_tolerance);

  // Scallop and gouge in 6 mm bands over the two seams (x = -15 and x = 20), against the exact faces.
  const auto faces = recon::ReadCadFaces(dir_ / "strips.step", recon::CadRegionSelector{.indices = {0, 1, 2}});
  ASSERT_TRUE(faces.ok());
  const auto path = nc::ReadToolpathFile(dir_ / "strips" / "toolpath" / "toolpath.csv");
  ASSERT_TRUE(path.ok());
  const formloop::testing::MachinedSurface machined(*path, path->options.tool.radius_mm);
  double max_scallop = 0, max_gouge = 0;
  int samples = 0, uncovered = 0;
  std::vector<Eigen::Vector2d> start;  // per face, the last parameters found (Newton's next start)
  for (const recon::CadFace& face : *faces) {
    const recon::ParamDomain d = face.surface.domain();
    start.emplace_back(0.5 * (d.u_min + d.u_max), 0.5 * (d.v_min + d.v_max));
  }
  for (const double seam : {-15.0, 20.0}) {
    for (double y = -38; y <= 38; y += path->min_step_over_mm / 8) {
      for (double x = seam - 3; x <= seam + 3; x += 0.1) {
        const std::size_t k = x < -15 ? 0 : x < 20 ? 1 : 2;
        const recon::CadFace& face = (*faces)[k];
        const auto uv = recon::ParametersAboveXY(face.surface, x, y, start[k]);
        ASSERT_TRUE(uv.has_value()) << x << " " << y;
        start[k] = *uv;
        const Eigen::Vector3d p = face.surface.Point(uv->x(), uv->y());
        const Eigen::Vector3d n = face.surface.Normal(uv->x(), uv->y());
        const double z = machined.Height(x, y);
        ++samples;
        if (!std::isfinite(z)) {
          ++uncovered;
          continue;
        }
        const double normal_um = (z - p.z()) * std::abs(n.z()) * 1e3;
        max_scallop = std::max(max_scallop, normal_um);
        max_gouge = std::max(max_gouge, -normal_um);
      }
    }
  }
  const double bound = path->options.scallop_um + path->options.chord_tolerance_um;
  std::printf(
      "[measured] three faces, seams: %d samples on the CAD faces, %d uncovered; max scallop %.3f um, max "
      "gouge %.3f um (bounds %.1f and 1.0)\n",
      samples, uncovered, max_scallop, max_gouge, bound);
  EXPECT_EQ(uncovered, 0);
  EXPECT_LE(max_scallop, bound);
  EXPECT_LE(max_gouge, 1.0);
}

// Item 3: a scan of the saddle (5 um noise along the normal) against the saddle given analytically.
TEST_F(CadPartsTest, AScanRunsLikeTheSamePartGivenAnalytically) {
  const auto saddle = recon::MakeReferenceSurface("saddle");
  ASSERT_TRUE(saddle.ok());
  const recon::ParamDomain d = (*saddle)->domain();
  {
    Rng rng(2026);
    std::ofstream scan(dir_ / "saddle_scan.xyz");
    const int n = 121;
    for (int j = 0; j < n; ++j) {
      for (int i = 0; i < n; ++i) {
        const double u = d.u_min + d.u_span() * i / (n - 1), v = d.v_min + d.v_span() * j / (n - 1);
        const Eigen::Vector3d p = (*saddle)->Point(u, v) + 0.005 * rng.Normal() * (*saddle)->Normal(u, v);
        scan << FormatExact(p.x()) << " " << FormatExact(p.y()) << " " << FormatExact(p.z()) << "\n";
      }
    }
  }
  Json analytic = PartJson("saddle-analytic", {{"reference", "saddle"}});
  Json scanned = PartJson("saddle-scan", {{"points", "saddle_scan.xyz"}});
  // The same retrieval description for both (a scan's shape concept is otherwise "free-form"), that of a
  // saddle die of the starter library (medium tolerance, finish-milled), so the route is not the default.
  for (Json* part : {&analytic, &scanned}) {
    (*part)["shape_family"] = "saddle";
    (*part)["tolerance_mm"] = 0.021;
    (*part)["finish_ra_um"] = 1.0;
    (*part)["machine"]["effects"]["tool_radius_error_um"] = 18;
  }
  const auto a = Run(analytic, "analytic", /*with_kb=*/true);
  ASSERT_TRUE(a.ok()) << a.status().ToString();
  const auto b = Run(scanned, "scan", /*with_kb=*/true);
  ASSERT_TRUE(b.ok()) << b.status().ToString();
  EXPECT_EQ(a->route, b->route);
  EXPECT_NE(a->route, "default");
  EXPECT_EQ(a->case_uid, b->case_uid);

  // Tool-path envelopes: the machined surfaces of the two nominal paths, compared in 5 x 5 windows of
  // 6 x 6 mm spread over the part 2 mm inside its outline (the scan's outline is the points' parameter
  // box, which differs from the analytic one by up to a few tenths of a millimetre, so the passes end and
  // the leads start a little differently there), at every 0.1 mm along the passes and a tenth of the
  // step-over across them.
  const auto path_a = nc::ReadToolpathFile(dir_ / "analytic" / "toolpath" / "toolpath.csv");
  const auto path_b = nc::ReadToolpathFile(dir_ / "scan" / "toolpath" / "toolpath.csv");
  ASSERT_TRUE(path_a.ok() && path_b.ok());
  const formloop::testing::MachinedSurface env_a(*path_a, 3.0), env_b(*path_b, 3.0);
  double worst = 0;
  int compared = 0;
  for (int wi = 0; wi < 5; ++wi) {
    for (int wj = 0; wj < 5; ++wj) {
      const double x0 = d.u_min + 2 + (d.u_span() - 10) * wi / 4, y0 = d.v_min + 2 + (d.v_span() - 10) * wj / 4;
      for (double y = y0; y <= y0 + 6; y += path_a->min_step_over_mm / 10) {
        for (double x = x0; x <= x0 + 6; x += 0.1) {
          const double za = env_a.Height(x, y), zb = env_b.Height(x, y);
          if (!std::isfinite(za) || !std::isfinite(zb)) continue;
          worst = std::max(worst, std::abs(za - zb));
          ++compared;
        }
      }
    }
  }
  std::printf(
      "[measured] scan vs analytic saddle: route %s / %s (A %.4f / %.4f); tool-path envelopes differ by at most "
      "%.3f um over %d points; final form error %.3f / %.3f um (difference %.3f um); %zu / %zu loops\n",
      a->route.c_str(), b->route.c_str(), a->similarity, b->similarity, worst * 1e3, compared,
      a->loops.back().form_error_um, b->loops.back().form_error_um,
      std::abs(a->loops.back().form_error_um - b->loops.back().form_error_um), a->loops.size(), b->loops.size());
  EXPECT_GT(compared, 150000);
  EXPECT_LE(worst, 2e-3);
  EXPECT_LE(std::abs(a->loops.back().form_error_um - b->loops.back().form_error_um), 1.0);
  EXPECT_TRUE(std::isnan(b->fit_check_max_um)) << "a scan's truth is not known; the summary says so (null)";
}

// The cos 3θ and sin 3θ coefficients of loop 0's deviations (θ the azimuth of Q's normal, the probing
// direction), by least squares with a constant and a quadric in (x, y) for the machining fields, and their
// standard errors.
struct Lobes {
  double cos_um = 0, sin_um = 0, cos_se = 0, sin_se = 0;
};
Lobes TriLobeTerms(const fs::path& deviations_csv) {
  const auto points = ReadCsv(deviations_csv);
  EXPECT_TRUE(points.ok()) << points.status().ToString();
  const std::vector<double>& d = *points->FindScalar("deviation_um");
  const Eigen::Index n = static_cast<Eigen::Index>(d.size());
  Eigen::MatrixXd a(n, 8);
  Eigen::VectorXd y(n);
  for (Eigen::Index i = 0; i < n; ++i) {
    const Eigen::Vector3d p = points->points[static_cast<std::size_t>(i)];
    const Eigen::Vector3d nrm = points->normals[static_cast<std::size_t>(i)];
    const double theta = std::atan2(nrm.y(), nrm.x());
    a.row(i) << 1, p.x(), p.y(), p.x() * p.x(), p.x() * p.y(), p.y() * p.y(), std::cos(3 * theta), std::sin(3 * theta);
    y(i) = d[static_cast<std::size_t>(i)];
  }
  const Eigen::VectorXd b = a.colPivHouseholderQr().solve(y);
  const double sigma2 = (y - a * b).squaredNorm() / static_cast<double>(n - 8);
  const Eigen::MatrixXd cov = sigma2 * (a.transpose() * a).inverse();
  return {b(6), b(7), std::sqrt(cov(6, 6)), std::sqrt(cov(7, 7))};
}

// Item 4: a tri-lobe probe (amplitude 6 um) measured with and without its profile.
TEST_F(CadPartsTest, AProbeProfileRemovesTheTriLobeFromTheDeviations) {
  metrology::ProbeModel trilobe;
  trilobe.ball_radius_mm = 1.0;
  trilobe.lobing = metrology::PretravelLobing::Zero(3, 0);
  trilobe.lobing.cos_mm(3, 0) = 0.006;
  ASSERT_TRUE(metrology::WriteProbeProfile(dir_ / "trilobe.json", trilobe).ok());
  Json with = PartJson("dome-with-profile", {{"reference", "sphere_cap"}});
  with["machine"]["probe"] = {{"profile", "trilobe.json"}};  // the probe the virtual machine has
  Json without = with;
  without["name"] = "dome-without-profile";
  with["probing"]["profile"] = "trilobe.json";  // the analysis applies the profile
  const auto a = Run(with, "with");
  ASSERT_TRUE(a.ok()) << a.status().ToString();
  const auto b = Run(without, "without");
  ASSERT_TRUE(b.ok()) << b.status().ToString();
  const Lobes la = TriLobeTerms(dir_ / "with" / "loop-0" / "deviations.csv");
  const Lobes lb = TriLobeTerms(dir_ / "without" / "loop-0" / "deviations.csv");
  std::printf(
      "[measured] tri-lobe probe (6 um): loop-0 cos3θ %.3f ± %.3f um, sin3θ %.3f ± %.3f um with the profile; "
      "%.3f ± %.3f um, %.3f ± %.3f um without; form error %.2f / %.2f um\n",
      la.cos_um, la.cos_se, la.sin_um, la.sin_se, lb.cos_um, lb.cos_se, lb.sin_um, lb.sin_se,
      a->loops.front().form_error_um, b->loops.front().form_error_um);
  EXPECT_LT(std::abs(la.cos_um), 3 * la.cos_se);
  EXPECT_LT(std::abs(la.sin_um), 3 * la.sin_se);
  EXPECT_GT(std::abs(lb.cos_um), 3 * lb.cos_se);
  // The resolved part carries the profile inline (a run repeats from its folder without the file).
  const Json resolved = ReadJsonFile(dir_ / "with" / "inputs" / "part.json").value();
  EXPECT_EQ(resolved["probing"]["profile"]["lobing"]["max_order"], 3);
  EXPECT_EQ(resolved["machine"]["probe"]["profile"]["lobing"]["max_order"], 3);
  // The diagnosis reads the probe through the same profile: it names the lobing only when it is not applied.
  const auto causes = [](const RunSummary& s) {
    return std::find(s.causes.begin(), s.causes.end(), "probe_lobing") != s.causes.end();
  };
  EXPECT_FALSE(causes(*a));
  EXPECT_TRUE(causes(*b));
  std::printf("[measured] tri-lobe probe: diagnosis causes with the profile:");
  for (const auto& c : a->causes) std::printf(" %s", c.c_str());
  std::printf("; without:");
  for (const auto& c : b->causes) std::printf(" %s", c.c_str());
  std::printf("\n");
}

// Item 5: the public CAD part, and a starter family given as CAD retrieves that family. The public face
// folds over itself: between v ≈ 0.3 and 0.6 its normal turns from −y to +y, so the points there lie
// under the fold, and a 3-axis probe's vertical descent to them passes the fold's lip (the run this test
// made before the probe clearance check existed drove the probe through the face). The run leaves those
// points out of the 10 × 10 grid (nc::ReachableProbePoints), names them in the log, in
// toolpath/probing_left_out.json, and runs the part with the rest; every move of the
// written probing program keeps the 1 mm gap, re-checked here sample by sample on the run's Q.
TEST_F(CadPartsTest, APublicFaceThatFoldsOverRunsWithoutThePointsUnderTheFoldAndAStarterShapeAsCadRetrievesItsFamily) {
  fs::copy_file(kData / "cad" / "occt_bug24012_face.igs", dir_ / "occt_bug24012_face.igs");
  Json pub = PartJson("occt-face", {{"cad", "occt_bug24012_face.igs"}});
  pub["tool"] = {{"number", 1}, {"radius_mm", 0.5}};
  pub["toolpath"]["lead_mm"] = 0.5;
  pub["tolerance_mm"] = 0.02;
  pub["probing"]["grid"] = {10, 10};
  const auto p = Run(pub, "public");
  ASSERT_TRUE(p.ok()) << p.status().ToString();
  ASSERT_FALSE(p->loops.empty());
  const Json record = ReadJsonFile(dir_ / "public" / "toolpath" / "probing_left_out.json").value();
  std::vector<std::int64_t> left_out;
  for (const Json& e : record["left_out"]) left_out.push_back(e["id"].get<std::int64_t>());
  EXPECT_EQ(record["planned"], 100);
  EXPECT_EQ(record["kept"].get<std::size_t>() + left_out.size(), 100u);
  double v_min = 1e9, v_max = -1e9;
  for (std::size_t i = 0; i < left_out.size(); ++i) {
    EXPECT_NE(record["left_out"][i]["reason"].get<std::string>().find("mm required) on the "), std::string::npos);
    v_min = std::min(v_min, record["left_out"][i]["v"].get<double>());
    v_max = std::max(v_max, record["left_out"][i]["v"].get<double>());
  }
  std::printf(
      "[measured] public part (OCCT bug24012_face.igs): %zu of 100 probe points left out (v %.3f .. %.3f), "
      "form error loop 0 %.2f um; first: point %lld: %s\n",
      left_out.size(), v_min, v_max, p->loops.front().form_error_um,
      left_out.empty() ? 0LL : static_cast<long long>(left_out.front()),
      left_out.empty() ? "" : record["left_out"][0]["reason"].get<std::string>().c_str());
  ASSERT_EQ(left_out.size(), 39u);  // the rows v = 0.45 .. 0.75 under the fold (points 41-79)
  EXPECT_EQ(left_out.front(), 41);
  EXPECT_EQ(left_out.back(), 79);
  EXPECT_NEAR(v_min, 0.45, 1e-9);
  EXPECT_NEAR(v_max, 0.75, 1e-9);
  // The probing program as written: the kept points only, each traverse at safe Z and descent at least
  // 1 mm from the part, the probing move its gap shrinking towards the contact (header of
  // nc-gen/probe_clearance.h), sampled every 10 µm on the run's own Q.
  const auto plan = ReadPlanFile(dir_ / "public" / "toolpath" / "probing_plan.json");
  ASSERT_TRUE(plan.ok()) << plan.status().ToString();
  EXPECT_EQ(plan->plan.points.size(), 100 - left_out.size());
  const auto face = recon::ReadCadFace(dir_ / "public" / "surface" / "Q.step", {});
  ASSERT_TRUE(face.ok()) << face.status().ToString();
  const auto part = recon::FootPointProjector::Build(face->surface);
  ASSERT_TRUE(part.ok());
  const auto gap = [&](const Eigen::Vector3d& x) {
    const auto f = part->Project(x);
    EXPECT_TRUE(f.ok());
    return (f->deviation_mm < 0 && !f->on_boundary ? -f->distance_mm : f->distance_mm) - 1.0;  // ball R = 1 mm
  };
  const auto least_margin = [&](const Eigen::Vector3d& from, const Eigen::Vector3d& to, double req_from,
                                double req_to) {
    double least = 1e9;
    const int n = std::max(1, static_cast<int>((to - from).norm() / 0.01));
    for (int i = 0; i <= n; ++i) {
      const double f = static_cast<double>(i) / n;
      least = std::min(least, gap(from + f * (to - from)) - (req_from + f * (req_to - req_from)));
    }
    return least;
  };
  const std::string text = ReadFile((dir_ / "public" / "toolpath" / "probe.ngc").string()).value();
  const auto number_after = [&](std::size_t at, const std::string& word) {
    return std::stod(text.substr(text.find(word, at) + word.size()));
  };
  const double safe_z = number_after(text.find("G43"), " Z");
  double least = 1e9;
  int shortened = 0;
  std::optional<Eigen::Vector3d> previous_above;
  for (const metrology::ProbePoint& pt : plan->plan.points) {
    const std::size_t at = text.find("(point " + std::to_string(pt.id) + ")\n");
    ASSERT_NE(at, std::string::npos) << pt.id;
    const Eigen::Vector3d contact = pt.point + pt.normal;
    const Eigen::Vector3d start(number_after(at, "G0 X"), number_after(at, " Y"), number_after(at, "G0 Z"));
    // The full 3 mm clearance, or halved or quartered where that clears the part (a warning says so).
    const double clearance = (start - contact).dot(pt.normal);
    EXPECT_LT((start - (contact + clearance * pt.normal)).norm(), 2e-3) << pt.id;
    EXPECT_TRUE(std::abs(clearance - 3) < 2e-3 || std::abs(clearance - 1.5) < 2e-3 || std::abs(clearance - 0.75) < 2e-3)
        << pt.id << ": " << clearance;
    shortened += clearance < 2.9 ? 1 : 0;
    const double g = std::min(1.0, 0.5 * clearance);  // along −n: min(gap, ½·clearance·cos 0)
    const Eigen::Vector3d above(start.x(), start.y(), safe_z);
    if (previous_above) least = std::min(least, least_margin(*previous_above, above, 1.0, 1.0));
    least = std::min(least, least_margin(above, start, g, g));
    least = std::min(least, least_margin(start, contact + 0.1 * clearance * pt.normal, g, 0.1 * g));
    previous_above = above;
  }
  for (const std::int64_t id : left_out) EXPECT_EQ(text.find("(point " + std::to_string(id) + ")"), std::string::npos);
  std::printf(
      "[measured] public part: %d kept points with a shortened clearance; least margin over the required gap on the "
      "written probing program %.4f mm\n",
      shortened, least);
  EXPECT_GE(least, -0.006);  // the samples' spacing: within 5 µm of the check's own
  EXPECT_EQ(shortened, 8);
  // summary.json and the report say which points were left out.
  const Json summary = ReadJsonFile(dir_ / "public" / "summary.json").value();
  EXPECT_EQ(summary["probing"]["planned"], 100);
  EXPECT_EQ(summary["probing"]["left_out"].get<std::vector<std::int64_t>>(), left_out);
  ASSERT_TRUE(WriteRunReport(dir_ / "public", dir_ / "public-report.html").ok());
  const std::string html = ReadFile((dir_ / "public-report.html").string()).value();
  EXPECT_NE(html.find("Probe points left out:</strong> 39 of the 100 planned"), std::string::npos);
  EXPECT_NE(html.find("(points 41, 42, "), std::string::npos);
  // The same part run on a measured log: the log of the kept points (here the virtual run's own) matches the
  // reduced plan point for point and gives the same first-cycle form error; a log that still holds a
  // left-out point is refused, naming it.
  fs::copy_file(dir_ / "public" / "loop-0" / "probe_log.csv", dir_ / "measured.csv");
  const fs::path part_file = dir_ / "occt-face.json";
  auto measured_run = [&](const std::string& out) {
    RunOptions o;
    o.out = dir_ / out;
    o.measured = {(dir_ / "measured.csv").string()};
    o.report = false;
    return RunPart(ReadPart(part_file).value(), o);
  };
  const auto m = measured_run("measured");
  ASSERT_TRUE(m.ok()) << m.status().ToString();
  EXPECT_NEAR(m->loops.front().form_error_um, p->loops.front().form_error_um, 1e-9);
  EXPECT_TRUE(fs::exists(dir_ / "measured" / "toolpath" / "probing_left_out.json"));
  {
    std::ofstream add(dir_ / "measured.csv", std::ios::app);
    add << "41,3.4,9.4,9.0,0,0,-1,999.0\n";
  }
  const auto refused = measured_run("measured-41");
  ASSERT_FALSE(refused.ok());
  const std::string why = refused.status().ToString();
  EXPECT_NE(why.find("measured.csv"), std::string::npos) << why;
  EXPECT_NE(why.find("point 41 was left out of this run's probing plan"), std::string::npos) << why;
  EXPECT_FALSE(fs::exists(dir_ / "measured-41"));

  // A dome of the starter library's "dome" family (sphere_cap, size 90 mm, radius ratio 1.4), exported as a
  // STEP face and described like the family's parts, but with no shape family given.
  const std::map<std::string, double> params{{"size_mm", 90}, {"radius_ratio", 1.4}};
  const auto grid = recon::ParametricGrid("sphere_cap", params, 41);
  ASSERT_TRUE(grid.ok()) << grid.status().ToString();
  recon::FitReport report;
  const auto q = recon::FitGrid(*grid, recon::GridFitOptions{}, &report);
  ASSERT_TRUE(q.ok());
  ASSERT_TRUE(recon::WriteStep(dir_ / "dome.step", *q, "dome").ok());
  Json dome = PartJson("cad-dome", {{"cad", "dome.step"}});
  dome["tolerance_mm"] = 0.012;
  dome["finish_ra_um"] = 0.3;
  dome["tool"] = {{"number", 1}, {"radius_mm", 4.0}};
  const auto r = Run(dome, "dome", /*with_kb=*/true);
  ASSERT_TRUE(r.ok()) << r.status().ToString();
  std::printf("[measured] dome given as CAD (shape concept free-form): best case %s, A %.4f, route %s\n",
              r->case_uid.c_str(), r->similarity, r->route.c_str());
  EXPECT_EQ(r->case_uid.rfind("dome-", 0), 0u) << r->case_uid;
}

// Item 6: bad input through `formloop run`: a clear error naming the field, exit 2, and no run folder
// (nor .partial) left behind.
TEST_F(CadPartsTest, BadInputsAreRefusedBeforeARunFolderExists) {
  ASSERT_TRUE(formloop::testing::WriteStepFaces(
      dir_ / "holed.step", {formloop::testing::MakeHoledFace(), formloop::testing::MakePin()}, {"top", "pin"}));
  formloop::testing::WriteNinePoints(dir_ / "few.csv");
  ASSERT_TRUE(formloop::testing::WriteIgesWithAndWithoutUnit(dir_ / "with_unit.igs", dir_ / "no_unit.igs"));
  struct Case {
    const char* name;
    Json surface;
    std::vector<std::string> expected;
  };
  const std::vector<Case> cases = {
      {"missing-cad", {{"cad", "absent.step"}}, {"field 'surface.cad'", "absent.step", "does not exist"}},
      {"face-out-of-range", {{"cad", "holed.step"}, {"faces", {0, 9}}}, {"surface.faces", "out of range", "0 to 1"}},
      {"unknown-face-name", {{"cad", "holed.step"}, {"face_names", {"lid"}}}, {"surface.face_names", "'top'", "'pin'"}},
      {"too-few-points", {{"points", "few.csv"}}, {"field 'surface.points'", "holds 9 points", "at least 16"}},
      {"unit-less-iges", {{"cad", "no_unit.igs"}}, {"field 'surface.cad'", "units", "no_unit.igs"}},
  };
  for (const Case& c : cases) {
    const fs::path part = dir_ / (std::string(c.name) + ".json");
    ASSERT_TRUE(WriteJsonFile(part, PartJson(c.name, c.surface)).ok());
    const fs::path out = dir_ / "runs" / c.name;
    std::string stdout_text, err;
    const int code =
        formloop::testing::RunFormloop("run " + part.string() + " --out " + out.string(), &stdout_text, &err);
    EXPECT_EQ(code, 2) << c.name << ": " << err;
    for (const std::string& e : c.expected) EXPECT_NE(err.find(e), std::string::npos) << c.name << ": " << err;
    EXPECT_FALSE(fs::exists(out)) << c.name;
    EXPECT_FALSE(fs::exists(out.string() + ".partial")) << c.name;
    std::printf("[measured] %s: %s", c.name, err.substr(err.find("bad input")).c_str());
  }
}

}  // namespace
}  // namespace formloop::app
