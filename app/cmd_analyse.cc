// `formloop analyse`: the part analysis from a surface and a probe log (spec/metrology.md §1–8), and
// `formloop analyse moran`: Moran's I for any table of points (spec/metrology.md §5–6).
//
//   formloop analyse --surface Q.step --probe-log LOG.csv [--plan PLAN.json] [--probe-profile P.json |
//       --ball-radius R] [--register tx,ty,tz,rx,ry,rz] [--tolerance-um A] [--knn K] [--max-distance-mm D]
//       --out DIR
//
// runs the one analysis of a probe log (metrology/probe_log_analysis.h, the same as each cycle of
// `formloop run`) and writes DIR/analysis.json, DIR/deviations.csv and .ply (the per-point table, the same
// columns as a run's loop-K/deviations.*) and DIR/inputs/ (the options as JSON and copies of the input
// files up to 16 MB); `formloop report DIR` draws it. Everything is computed before DIR is created, so bad input leaves
// no DIR (or an existing DIR untouched); each file is written atomically and analysis.json last, so a DIR with
// analysis.json is complete. Points whose foot point on Q is farther than --max-distance-mm, or whose
// foot point is held at the edge of Q (the deviation is then not a normal distance), are listed under
// "flagged_points" and left out of the statistics and of deviations.csv|.ply.
//
//   formloop analyse moran --points F.csv --value COL [--regressors COL,COL...]
//       (--knn K [--coords u,v | x,y,z] | --weights W.gal [--id COL] | --delaunay [--coords u,v] | --band D)
//       --style W|B [--permutations N --seed S] [--islands refuse|drop|zero] [--lisa OUT.csv [--alpha A]]
//
// Prints one JSON object on stdout: n, I, E[I], variance/z/p under normality and randomisation, the
// weight sums, the island policy, the permutation test when asked, the residual Moran (Cliff–Ord)
// when regressors are given, and the LISA summary when --lisa writes the per-point table.
//
// `analyse` with neither a subcommand nor --surface/--probe-log/--out is a usage error (exit 2).

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <iostream>
#include <limits>
#include <memory>
#include <optional>
#include <set>
#include <sstream>
#include <string>
#include <string_view>
#include <vector>

#include <Eigen/Core>
#include <nlohmann/json.hpp>

#include "app/command.h"
#include "app/run_folder.h"
#include "core/atomic_file.h"
#include "core/csv.h"
#include "core/json_io.h"
#include "core/log.h"
#include "core/number_text.h"
#include "core/output_file.h"
#include "core/point_io.h"
#include "metrology/decomposition.h"
#include "metrology/morans_i.h"
#include "metrology/probe.h"
#include "metrology/probe_log_analysis.h"
#include "metrology/spatial_weights.h"
#include "reconstruction/cad_io.h"

namespace formloop::app {
namespace {

using metrology::IslandPolicy;
using metrology::SpatialWeights;
using metrology::WeightStyle;

// One numeric column of a table read by the one CSV reader (core/csv.h); `option` names the option
// that asked for it in messages.
Result<Eigen::VectorXd> NumericColumn(const CsvTable& table, const std::string& name, const std::string& option) {
  FL_ASSIGN_OR_RETURN(const int c, table.Column(name, option));
  Eigen::VectorXd out(static_cast<long>(table.rows.size()));
  for (std::size_t r = 0; r < table.rows.size(); ++r) {
    FL_RETURN_IF_ERROR(table.Number(r, c, &out[static_cast<long>(r)]));
  }
  return out;
}

// "u, v,,w" -> {"u", "v", "w"}: an option's comma-separated list, blanks and empty items dropped.
std::vector<std::string> SplitList(const std::string& text) {
  std::vector<std::string_view> cells;
  SplitCsvCells(text, &cells);
  std::vector<std::string> out;
  for (std::string_view cell : cells) {
    if (!cell.empty()) out.emplace_back(cell);
  }
  return out;
}

struct MoranArgs {
  std::string points;
  std::string value;
  std::string regressors;
  int knn = -1;  // unset
  std::string coords;
  std::string gal;
  std::string id_column;
  bool delaunay = false;
  double band = std::numeric_limits<double>::quiet_NaN();  // unset
  std::string style;
  int permutations = 0;
  std::uint64_t seed = 1;
  std::string islands = "refuse";
  std::string lisa_out;
  bool force = false;
  double alpha = 0.05;
  int lisa_permutations = 999;
};

Result<Eigen::MatrixXd> Coordinates(const CsvTable& table, const std::string& coords, bool two_d_only) {
  std::vector<std::string> names = SplitList(coords);
  if (names.empty()) {
    // Default: the surface parameters when the table has them, else x, y.
    const bool has_uv = table.Column("u", "--coords").ok() && table.Column("v", "--coords").ok();
    names = has_uv ? std::vector<std::string>{"u", "v"} : std::vector<std::string>{"x", "y"};
  }
  if (names.size() != 2 && !(names.size() == 3 && !two_d_only)) {
    return Status::BadInput(
        Where{.field = "--coords"}, "'" + coords + "' names " + std::to_string(names.size()) + " columns",
        two_d_only ? "Delaunay weights need two, e.g. --coords u,v" : "give two or three, e.g. --coords u,v or x,y,z");
  }
  Eigen::MatrixXd points(static_cast<long>(names.size()), static_cast<long>(table.rows.size()));
  for (std::size_t d = 0; d < names.size(); ++d) {
    FL_ASSIGN_OR_RETURN(const Eigen::VectorXd column, NumericColumn(table, names[d], "--coords"));
    points.row(static_cast<long>(d)) = column.transpose();
  }
  return points;
}

// More permutations than this add nothing to a p-value reported to 4 digits and cost minutes per point.
constexpr int kMaxPermutations = 99999;

Status RunMoran(const MoranArgs& args) {
  const bool knn = args.knn != -1, band = !std::isnan(args.band);
  const int chosen = knn + !args.gal.empty() + args.delaunay + band;
  if (chosen != 1) {
    return Status::BadInput(Where{.field = "--knn/--weights/--delaunay/--band"},
                            chosen == 0 ? "no spatial weights chosen" : "more than one kind of spatial weights chosen",
                            "give exactly one of --knn K, --weights W.gal, --delaunay, --band D");
  }
  if (knn && args.knn < 1) return Status::BadInput(Where{.field = "--knn"}, "must be at least 1", "use e.g. 8");
  if (band && !(args.band > 0 && std::isfinite(args.band))) {
    return Status::BadInput(Where{.field = "--band"}, "must be a positive distance");
  }
  if (args.permutations < 0 || args.permutations > kMaxPermutations) {
    return Status::BadInput(Where{.field = "--permutations"}, "must lie in 0 .. " + std::to_string(kMaxPermutations),
                            "use e.g. 999, or 0 for none");
  }
  if (args.lisa_permutations < 0 || args.lisa_permutations > kMaxPermutations) {
    return Status::BadInput(Where{.field = "--lisa-permutations"},
                            "must lie in 0 .. " + std::to_string(kMaxPermutations), "use e.g. 999, or 0");
  }
  FL_RETURN_IF_ERROR(
      CheckOutputFiles({{"--lisa", args.lisa_out}}, {{"--points", args.points}, {"--weights", args.gal}}, args.force));
  FL_ASSIGN_OR_RETURN(const WeightStyle style, metrology::ParseWeightStyle(args.style, "--style"));
  FL_ASSIGN_OR_RETURN(const IslandPolicy policy, metrology::ParseIslandPolicy(args.islands, "--islands"));
  FL_ASSIGN_OR_RETURN(const CsvTable table, ReadCsvTable(args.points));
  FL_ASSIGN_OR_RETURN(const Eigen::VectorXd y, NumericColumn(table, args.value, "--value"));
  const long n = y.size();

  // Ids: the --id column, else 1..n in file order (GeoDa's record numbers).
  std::vector<std::string> ids;
  if (!args.id_column.empty()) {
    FL_ASSIGN_OR_RETURN(const int c, table.Column(args.id_column, "--id"));
    for (const auto& row : table.rows) ids.push_back(row[static_cast<std::size_t>(c)]);
  } else {
    for (long i = 1; i <= n; ++i) ids.push_back(std::to_string(i));
  }

  nlohmann::json weights_json = {{"style", metrology::WeightStyleName(style)}};
  Result<SpatialWeights> weights = Status::Internal("no weights");
  if (knn) {
    FL_ASSIGN_OR_RETURN(const Eigen::MatrixXd points, Coordinates(table, args.coords, false));
    weights = metrology::KnnWeights(points, args.knn, style);
    weights_json["kind"] = "knn";
    weights_json["k"] = args.knn;
  } else if (!args.gal.empty()) {
    weights = metrology::ReadGal(args.gal, ids, style);
    weights_json["kind"] = "gal";
    weights_json["file"] = args.gal;
  } else if (args.delaunay) {
    FL_ASSIGN_OR_RETURN(const Eigen::MatrixXd points, Coordinates(table, args.coords, true));
    weights = metrology::DelaunayWeights(points, style);
    weights_json["kind"] = "delaunay";
  } else {
    FL_ASSIGN_OR_RETURN(const Eigen::MatrixXd points, Coordinates(table, args.coords, false));
    weights = metrology::DistanceBandWeights(points, args.band, style);
    weights_json["kind"] = "band";
    weights_json["band"] = args.band;
  }
  if (!weights.ok()) return weights.status().WithContext("analyse moran");
  if (weights->islands > 0 && policy == IslandPolicy::kRefuse) {
    std::string list;
    for (std::size_t m = 0; m < weights->island_indices.size() && m < 10; ++m) {
      list += (m ? ", " : "") + ids[static_cast<std::size_t>(weights->island_indices[m])];
    }
    if (weights->island_indices.size() > 10) list += ", ...";
    return Status::BadInput(
        Where{.file = args.points, .field = "--islands"},
        std::to_string(weights->islands) + " point(s) have no neighbours (islands; ids " + list + ")",
        "add --islands drop (remove them) or --islands zero (zero rows, n kept), or widen the "
        "neighbourhood");
  }
  weights_json["islands"] = weights->islands;
  weights_json["nonzero"] = weights->w.nonZeros();

  FL_ASSIGN_OR_RETURN(
      const metrology::MoranResult moran,
      metrology::MoranI(y, weights.value(), {.islands = policy, .permutations = args.permutations, .seed = args.seed}));
  nlohmann::json out = moran.ToJson();
  out["points"] = args.points;
  out["value"] = args.value;
  out["weights"] = weights_json;
  if (!moran.islands.dropped.empty()) {
    nlohmann::json dropped_ids = nlohmann::json::array();
    for (int row : moran.islands.dropped) dropped_ids.push_back(ids[static_cast<std::size_t>(row)]);
    out["islands"]["dropped_ids"] = dropped_ids;
  }

  const std::vector<std::string> regressors = SplitList(args.regressors);
  if (!regressors.empty()) {
    // The constant is always in the design (a mean), like lm(y ~ x) and spdep's lm.morantest.
    Eigen::MatrixXd design(n, static_cast<long>(regressors.size()) + 1);
    design.col(0).setOnes();
    for (std::size_t k = 0; k < regressors.size(); ++k) {
      FL_ASSIGN_OR_RETURN(const Eigen::VectorXd column, NumericColumn(table, regressors[k], "--regressors"));
      design.col(static_cast<long>(k) + 1) = column;
    }
    FL_ASSIGN_OR_RETURN(const metrology::ResidualMoranResult residual,
                        metrology::ResidualMoranI(y, design, weights.value(), policy));
    nlohmann::json r = residual.ToJson();
    nlohmann::json names = nlohmann::json::array({"(constant)"});
    for (const auto& name : regressors) names.push_back(name);
    r["regressors"] = names;
    r["coefficients"] =
        std::vector<double>(residual.coefficients.data(), residual.coefficients.data() + residual.coefficients.size());
    out["residual"] = r;
  }

  if (!args.lisa_out.empty()) {
    FL_ASSIGN_OR_RETURN(
        const metrology::LocalMoranResult lisa,
        metrology::LocalMoranI(
            y, weights.value(),
            {.islands = policy, .permutations = args.lisa_permutations, .seed = args.seed, .alpha = args.alpha}));
    std::ostringstream csv;
    csv << "# formloop analyse moran: local Moran's I (LISA) per point\n";
    csv << "id,value,I_i,lag,expected,variance,z,p_analytical,p_sim,quadrant,cluster\n";
    auto num = [](double v) { return std::isfinite(v) ? FormatExact(v) : std::string(); };
    for (long i = 0; i < n; ++i) {
      csv << ids[static_cast<std::size_t>(i)] << "," << num(y[i]) << "," << num(lisa.i[i]) << "," << num(lisa.lag[i])
          << "," << num(lisa.expected[i]) << "," << num(lisa.variance[i]) << "," << num(lisa.z[i]) << ","
          << num(lisa.p_analytical[i]) << "," << num(lisa.p_sim[i]) << "," << lisa.quadrant[static_cast<std::size_t>(i)]
          << "," << metrology::LisaClusterName(lisa.cluster[static_cast<std::size_t>(i)]) << "\n";
    }
    FL_RETURN_IF_ERROR(WriteFileAtomic(args.lisa_out, csv.str()));
    out["lisa"] = lisa.SummaryJson();
    out["lisa"]["file"] = args.lisa_out;
  }
  std::cout << out.dump(2) << "\n";
  std::cout.flush();
  if (!std::cout) return Status::IoError("analyse moran: writing to stdout failed");
  return Status::Ok();
}

// ---------------------------------------------------------------------------------------------------
// The part analysis: `formloop analyse --surface Q.step --probe-log LOG.csv --out DIR`.

namespace fs = std::filesystem;

struct PartArgs {
  std::string surface;
  int face_index = -1;
  std::string face_name;
  std::string probe_log;
  std::string plan;
  std::string probe_profile;
  double ball_radius_mm = std::numeric_limits<double>::quiet_NaN();  // unset: 1 mm (ProbeModel's default)
  std::string register_dofs;
  double tolerance_um = std::numeric_limits<double>::quiet_NaN();  // unset: no evaluation
  int knn = 8;
  double max_distance_mm = 1.0;
  int max_control_net = 8;
  double coverage_factor = 2.0;
  int lisa_permutations = 999;
  double alpha = 0.05;
  std::uint64_t seed = 1;
  std::string out;

  nlohmann::json ToJson() const {
    auto optional_number = [](double v) { return std::isnan(v) ? nlohmann::json(nullptr) : nlohmann::json(v); };
    auto optional_string = [](const std::string& s) { return s.empty() ? nlohmann::json(nullptr) : nlohmann::json(s); };
    return {{"surface", surface},
            {"face_index", face_index < 0 ? nlohmann::json(nullptr) : nlohmann::json(face_index)},
            {"face_name", optional_string(face_name)},
            {"probe_log", probe_log},
            {"plan", optional_string(plan)},
            {"probe_profile", optional_string(probe_profile)},
            {"ball_radius_mm", optional_number(ball_radius_mm)},
            {"register", register_dofs.empty() ? "none" : register_dofs},
            {"tolerance_um", optional_number(tolerance_um)},
            {"knn", knn},
            {"max_distance_mm", max_distance_mm},
            {"max_control_net", max_control_net},
            {"coverage_factor", coverage_factor},
            {"lisa_permutations", lisa_permutations},
            {"alpha", alpha},
            {"seed", seed},
            {"out", out}};
  }
};

Status ValidatePartArgs(const PartArgs& a) {
  if (a.knn < 1) return Status::BadInput(Where{.field = "--knn"}, "must be at least 1", "use e.g. 8");
  if (!(a.max_distance_mm > 0) || !std::isfinite(a.max_distance_mm)) {
    return Status::BadInput(Where{.field = "--max-distance-mm"}, "must be a positive distance", "use e.g. 1");
  }
  if (!std::isnan(a.tolerance_um) && !(a.tolerance_um > 0 && std::isfinite(a.tolerance_um))) {
    return Status::BadInput(Where{.field = "--tolerance-um"}, "must be positive",
                            "give the form tolerance in um, e.g. 20");
  }
  if (!std::isnan(a.ball_radius_mm) && !(a.ball_radius_mm > 0 && std::isfinite(a.ball_radius_mm))) {
    return Status::BadInput(Where{.field = "--ball-radius"}, "must be positive", "give the stylus-ball radius in mm");
  }
  if (!std::isnan(a.ball_radius_mm) && !a.probe_profile.empty()) {
    return Status::BadInput(Where{.field = "--ball-radius"}, "given together with --probe-profile",
                            "leave --ball-radius out: the profile holds the ball radius");
  }
  if (a.lisa_permutations < 0 || a.lisa_permutations > kMaxPermutations) {
    return Status::BadInput(Where{.field = "--lisa-permutations"},
                            "must lie in 0 .. " + std::to_string(kMaxPermutations), "use e.g. 999, or 0");
  }
  if (!(a.alpha > 0 && a.alpha < 1)) {
    return Status::BadInput(Where{.field = "--alpha"}, "must lie in (0, 1)", "use e.g. 0.05");
  }
  return Status::Ok();
}

Status CopyInput(const std::string& from, const fs::path& to, nlohmann::json* copies) {
  constexpr std::uintmax_t kMaxCopyBytes = 16u << 20;
  std::error_code ec;
  const std::uintmax_t size = fs::file_size(from, ec);
  if (ec || size > kMaxCopyBytes) {
    (*copies)[to.filename().string()] = {
        {"from", from}, {"copied", false}, {"reason", ec ? "size unknown" : "larger than 16 MB"}};
    return Status::Ok();
  }
  FL_ASSIGN_OR_RETURN(const std::string content, ReadFile(from));
  FL_RETURN_IF_ERROR(WriteFileAtomic(to, content, true));
  (*copies)[to.filename().string()] = {{"from", from}, {"copied", true}, {"bytes", size}};
  return Status::Ok();
}

Status RunPartAnalysis(const PartArgs& args) {
  FL_RETURN_IF_ERROR(ValidatePartArgs(args));
  // Built whole in DIR.partial and renamed into place; only a folder formloop wrote is replaced.
  StagedOutputFolder folder;
  FL_RETURN_IF_ERROR(folder.Open(args.out, "--out", "analyse",
                                 {{"--surface", args.surface},
                                  {"--probe-log", args.probe_log},
                                  {"--plan", args.plan},
                                  {"--probe-profile", args.probe_profile}}));
  metrology::ProbeLogAnalysisOptions options;
  FL_ASSIGN_OR_RETURN(options.registration, metrology::ParseDofMask(args.register_dofs, "--register"));

  // 1. Inputs: Q, the log, the probe model, the plan.
  FL_ASSIGN_OR_RETURN(const recon::CadFace face,
                      recon::ReadCadFace(args.surface, {.index = args.face_index, .name = args.face_name}));
  const recon::BSplineSurface& q = face.surface;
  FL_ASSIGN_OR_RETURN(const metrology::ProbeLog log, metrology::ReadProbeLog(args.probe_log));
  metrology::ProbeModel probe;
  if (!args.probe_profile.empty()) {
    FL_ASSIGN_OR_RETURN(probe, metrology::ReadProbeProfile(args.probe_profile));
  } else if (!std::isnan(args.ball_radius_mm)) {
    probe.ball_radius_mm = args.ball_radius_mm;
  }
  FL_RETURN_IF_ERROR(probe.Validate());
  std::optional<metrology::ProbingPlan> plan;
  if (!args.plan.empty()) {
    FL_ASSIGN_OR_RETURN(const PlanWithApproaches read_plan, ReadPlanFile(args.plan));
    plan = read_plan.plan;
  }

  // 2.–5. The one analysis of a probe log (metrology/probe_log_analysis.h).
  options.decomposition.neighbours = args.knn;
  options.decomposition.max_control_net = args.max_control_net;
  options.decomposition.coverage_factor = args.coverage_factor;
  if (!std::isnan(args.tolerance_um)) options.decomposition.tolerance_mm = args.tolerance_um * 1e-3;
  options.max_distance_mm = args.max_distance_mm;
  options.lisa_permutations = args.lisa_permutations;
  options.lisa_alpha = args.alpha;
  options.lisa_seed = args.seed;
  FL_ASSIGN_OR_RETURN(const metrology::ProbeLogAnalysis result,
                      metrology::AnalyseProbeLog(q, log, probe, plan ? &*plan : nullptr, options));
  const metrology::Decomposition& dec = result.decomposition;
  const PointSet points = result.PerPointTable();
  FL_RETURN_IF_ERROR(points.Validate("analyse deviations"));

  nlohmann::json probe_json = metrology::ProbeProfileToJson(probe);
  probe_json["source"] =
      args.probe_profile.empty()
          ? (std::isnan(args.ball_radius_mm) ? "default (ball radius 1 mm, no pretravel)" : "--ball-radius")
          : args.probe_profile;
  probe_json["compensation"] = "p = c + (R_nom - delta(a)) a along each record's approach direction a";

  nlohmann::json analysis;
  analysis["format"] = "formloop part analysis";
  analysis["version"] = 1;
  analysis["inputs"] = {{"surface",
                         {{"file", args.surface},
                          {"face_index", face.info.index},
                          {"face_name", face.info.name},
                          {"surface_type", face.info.surface_type},
                          {"file_unit", face.file_unit}}},
                        {"probe_log", {{"file", args.probe_log}, {"records", log.records.size()}}},
                        {"plan", plan ? nlohmann::json{{"file", args.plan},
                                                       {"points", plan->points.size()},
                                                       {"not_measured_ids", result.not_measured}}
                                      : nlohmann::json(nullptr)},
                        {"approach", plan ? "from the log; foot-point search started at the planned (u, v)"
                                          : "from the log; foot points by global search on Q (no plan)"},
                        {"options", args.ToJson()}};
  analysis["probe"] = probe_json;
  analysis["registration"] =
      result.registration
          ? result.registration->ToJson()
          : nlohmann::json{{"enabled", false}, {"note", "off (default): deviations in the machine frame"}};
  analysis["search_distance_mm"] = args.max_distance_mm;
  analysis["flagged_points"] = result.FlaggedJson();
  analysis["deviations"] = result.DeviationSummaryJson();
  analysis["raw_moran"] = dec.raw.ToJson();
  analysis["raw_moran"]["weights"] = {{"kind", "knn"}, {"k", args.knn}, {"coords", "u,v"}, {"style", "W"}};
  const bool systematic_detected = dec.raw.z_normality > metrology::kMoranZCritical;
  analysis["systematic_detected"] = systematic_detected;
  analysis["systematic_detected_rule"] = "raw Moran z (normality) > 2.326 (one-sided, 0.01)";
  analysis["decomposition"] = dec.ToJson();
  analysis["chosen_model"] = dec.systematic.name();
  analysis["systematic_rms_um"] = dec.systematic_rms_um;
  analysis["systematic_peak_um"] = dec.systematic_peak_um;
  analysis["fine_scale_rms_um"] = dec.fine_scale_rms_um;
  analysis["random_rms_um"] = dec.random_rms_um;
  analysis["random_sigma_um"] = dec.random_sigma_um;
  analysis["form_error_um"] = dec.form_error_um;
  analysis["lisa"] = result.lisa.SummaryJson();
  analysis["lisa"]["of"] = "the deviations, k-NN weights in (u, v), row-standardised";
  analysis["lisa_random"] = result.LisaRandomJson();
  if (dec.evaluation) {
    analysis["evaluation"] = dec.evaluation->ToJson();
    analysis["compensate"] = dec.evaluation->compensate;
  } else {
    analysis["evaluation"] = nullptr;
    analysis["compensate"] = nullptr;
    analysis["evaluation_note"] = "no --tolerance-um: form error reported, no decision";
  }
  const long n = static_cast<long>(result.deviations.size());
  nlohmann::json columns = {{"position", "compensated contact point (mm; registered when registration is on)"},
                            {"normal", "unit normal of Q at the foot point"},
                            {"scalars", metrology::ProbeLogAnalysis::PerPointColumns()}};
  analysis["outputs"] = {{"deviations.ply", {{"vertices", n}}}, {"deviations.csv", {{"rows", n}}}};
  analysis["outputs"]["deviations.ply"].update(columns);
  analysis["outputs"]["deviations.csv"].update(columns);

  // 8. Write: inputs, points, analysis.json, then the folder into place.
  const fs::path& dir = folder.dir();
  FL_RETURN_IF_ERROR(MakeDirectories(dir / "inputs"));
  nlohmann::json copies = nlohmann::json::object();
  const std::string surface_ext = fs::path(args.surface).extension().string();
  FL_RETURN_IF_ERROR(CopyInput(args.surface, dir / "inputs" / ("surface" + surface_ext), &copies));
  FL_RETURN_IF_ERROR(CopyInput(args.probe_log, dir / "inputs" / "probe_log.csv", &copies));
  if (!args.plan.empty()) FL_RETURN_IF_ERROR(CopyInput(args.plan, dir / "inputs" / "plan.json", &copies));
  if (!args.probe_profile.empty()) {
    FL_RETURN_IF_ERROR(CopyInput(args.probe_profile, dir / "inputs" / "probe_profile.json", &copies));
  }
  nlohmann::json options_json = args.ToJson();
  options_json["copies"] = copies;
  FL_RETURN_IF_ERROR(WriteJsonFile(dir / "inputs" / "options.json", options_json));
  analysis["inputs"]["copies"] = copies;
  FL_RETURN_IF_ERROR(WritePoints(dir / "deviations.ply", points));
  FL_RETURN_IF_ERROR(WritePoints(dir / "deviations.csv", points, {.precision = 6}));
  FL_RETURN_IF_ERROR(WriteJsonFile(dir / "analysis.json", analysis));
  log::Info(
      "analyse: {} points ({} flagged), rms {:.2f} um, raw Moran z {:.2f}; model {}, d_s rms {:.2f} um, "
      "d_u rms {:.2f} um -> {}",
      n, result.flagged.size(), analysis["deviations"]["rms_um"].get<double>(), dec.raw.z_normality,
      dec.systematic.name(), dec.systematic_rms_um, dec.random_rms_um, args.out);
  return folder.Commit();
}

}  // namespace

void AddAnalyseCommand(CLI::App& root, CommandAction* action) {
  CLI::App* analyse = root.add_subcommand(
      "analyse",
      "Analyse a machined part from its probe log: probe compensation, deviations from Q, Moran's I, the "
      "systematic/random decomposition and the compensation decision (--surface --probe-log --out); or "
      "Moran's I for any table of points (moran).");
  analyse->require_subcommand(0, 1);
  auto part = std::make_shared<PartArgs>();
  analyse->add_option("--surface", part->surface, "Q as a STEP or IGES file (e.g. from `formloop fit`)");
  analyse->add_option("--face", part->face_index, "0-based face index in the CAD file (default: its only face)");
  analyse->add_option("--face-name", part->face_name, "face name in the CAD file");
  analyse->add_option("--probe-log", part->probe_log,
                      "probe log CSV: id,x,y,z,ax,ay,az,t (ball centre, approach, time)");
  analyse->add_option("--plan", part->plan,
                      "probing plan JSON (e.g. toolpath/probing_plan.json): ids are checked against it and the "
                      "foot-point search starts at the planned (u, v)");
  analyse->add_option("--probe-profile", part->probe_profile,
                      "probe profile JSON from `formloop calibrate sphere` (ball radius, pretravel, lobing)");
  analyse->add_option("--ball-radius", part->ball_radius_mm,
                      "stylus-ball radius in mm when no --probe-profile is given (default 1, no pretravel)");
  analyse->add_option("--register", part->register_dofs,
                      "registration to Q with these degrees of freedom: tx,ty,tz,rx,ry,rz subset, all or none "
                      "(default none: off; the transform is reported when on)");
  analyse->add_option("--tolerance-um", part->tolerance_um,
                      "form tolerance alpha in um: evaluates the form error and decides on compensation");
  analyse->add_option("--knn", part->knn, "k of the k-NN weights in (u, v) for Moran's I and LISA")
      ->capture_default_str();
  analyse
      ->add_option("--max-distance-mm", part->max_distance_mm,
                   "search distance: points whose foot point is farther are flagged and left out")
      ->capture_default_str();
  analyse
      ->add_option("--max-control-net", part->max_control_net, "largest B-spline field net tried (3: polynomials only)")
      ->capture_default_str();
  analyse->add_option("--coverage-factor", part->coverage_factor, "k in form error = max|d_s| + k sigma(d_u)")
      ->capture_default_str();
  analyse->add_option("--lisa-permutations", part->lisa_permutations, "LISA conditional permutations; 0 = analytical")
      ->capture_default_str();
  analyse->add_option("--alpha", part->alpha, "LISA significance level")->capture_default_str();
  analyse->add_option("--seed", part->seed, "seed of the LISA permutations")->capture_default_str();
  analyse->add_option("--out", part->out, "output folder: analysis.json, deviations.csv|.ply, inputs/");

  auto args = std::make_shared<MoranArgs>();
  CLI::App* moran = analyse->add_subcommand(
      "moran",
      "Moran's I of one column of a CSV table with spatial weights: moments under normality and randomisation "
      "(Cliff & Ord 1981), optional permutation test, residual Moran for least-squares residuals, and local "
      "Moran (LISA, Anselin 1995). JSON on stdout.");
  moran->add_option("--points", args->points, "CSV table with a header row (one row per point)")->required();
  moran->add_option("--value", args->value, "column whose spatial autocorrelation is tested")->required();
  moran->add_option("--regressors", args->regressors,
                    "COL,COL...: also test the least-squares residuals of value on these columns plus a constant "
                    "(exact Cliff–Ord residual moments)");
  moran->add_option("--knn", args->knn, "weights: K nearest neighbours in the --coords columns (asymmetric)");
  moran->add_option(
      "--coords", args->coords,
      "coordinate columns for --knn, --delaunay, --band: u,v or x,y,z (default u,v if present, else x,y)");
  moran->add_option("--weights", args->gal, "weights: a GAL file (GeoDa/PySAL/spdep) whose ids are the --id column");
  moran->add_option("--id", args->id_column, "id column pairing rows with GAL ids (default: 1..n in file order)");
  moran->add_flag("--delaunay", args->delaunay, "weights: Delaunay neighbours of the two --coords columns (CGAL)");
  moran->add_option("--band", args->band, "weights: all points within this distance (inclusive) in --coords");
  moran->add_option("--style", args->style, "W (row-standardised) or B (binary)")->required();
  moran
      ->add_option("--permutations", args->permutations,
                   "random permutations for the pseudo p-value (larger + 1)/(N + 1); 0 = none")
      ->capture_default_str();
  moran->add_option("--seed", args->seed, "seed of the permutations (global and LISA)")->capture_default_str();
  moran
      ->add_option("--islands", args->islands,
                   "points without neighbours: refuse (error), drop (remove them), zero (zero rows, n kept)")
      ->capture_default_str();
  AddForceFlag(moran, &args->force);
  moran->add_option("--lisa", args->lisa_out,
                    "write local Moran per point (I_i, E, Var, z, p, cluster HH/LL/HL/LH) to this CSV");
  moran->add_option("--alpha", args->alpha, "LISA: significance level of the cluster map (p < alpha)")
      ->capture_default_str();
  moran
      ->add_option("--lisa-permutations", args->lisa_permutations,
                   "LISA: conditional permutations per point; 0 = analytical p-values")
      ->capture_default_str();
  moran->callback([action, args] { *action = [args] { return RunMoran(*args); }; });

  // Runs after moran's callback: without the subcommand, the part analysis needs its three options.
  analyse->callback([analyse, moran, action, part] {
    if (moran->parsed()) {
      for (const char* name : {"--surface", "--probe-log", "--out", "--plan", "--probe-profile"}) {
        if (analyse->count(name) > 0) {
          throw CLI::ValidationError(name, "belongs to the part analysis, not to `analyse moran`");
        }
      }
      return;
    }
    if (part->surface.empty() || part->probe_log.empty() || part->out.empty()) {
      throw CLI::ValidationError(
          "analyse",
          "give --surface Q.step --probe-log LOG.csv --out DIR for the part analysis, or a subcommand "
          "(moran); see formloop analyse --help");
    }
    *action = [part] { return RunPartAnalysis(*part); };
  });
}

}  // namespace formloop::app
