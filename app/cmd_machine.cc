// `formloop machine linuxcnc ...`: formloop's programs on a real controller, LinuxCNC, running a
// simulated mill headless (cnc/linuxcnc_*.h).
//
//   formloop machine linuxcnc config --out DIR [--surface NAME] [--no-probe] [--no-link] [--ball-radius-mm R]
//       [--shift-um X,Y,Z] [--rotation-urad X,Y,Z | --tilt-deg X,Y,Z] [--travel MM] [--travel-z MM]
//       [--max-velocity MM_PER_S] [--max-acceleration MM_PER_S2] [--name TEXT]
//     writes the configuration (INI, HAL, display program, tool table, probe_surface.json) and prints
//     its report: the probe surface, how it is placed and how exactly the HAL net trips.
//
//   formloop machine linuxcnc run --config INI|DIR --program P.ngc --out SESSION [--timeout-s S]
//     starts LinuxCNC headless, runs the program, shuts the controller down and prints what happened.
//     Exit 1 with "P.ngc:LINE: LinuxCNC (stage): message" when the program fails.
//
//   formloop machine linuxcnc measure --config INI|DIR --surface Q.step [--grid NUxNV] [--inset F] --out DIR
//     the handshake of the link (spec/tuning-and-link.md §7) over HAL: formloop's machine-side program runs
//     on the controller while the collector takes every point through the variable block
//     (cnc/linuxcnc_link.h); prints what arrived, checked against the controller's record of each trip.
//
//   formloop machine linuxcnc probe --config INI|DIR --surface Q.step [--face I] [--grid NUxNV]
//       [--inset F] [--probe-feed F] [--touch-feed F] [--backoff-mm B] [--clearance-mm C]
//       [--search-mm S] [--safe-z-mm Z] [--timeout-s S] --out DIR
//     plans a grid of probe points on Q, runs formloop's LinuxCNC probing program on the controller
//     and writes the probe log, the plan and the probe profile (for `formloop analyse` and
//     `formloop diagnose`), printing the deviations from Q.

#include <cmath>
#include <iostream>
#include <memory>
#include <nlohmann/json.hpp>

#include "app/command.h"
#include "cnc/linuxcnc_config.h"
#include "cnc/linuxcnc_link.h"
#include "cnc/linuxcnc_probing.h"
#include "cnc/linuxcnc_run.h"
#include "core/csv.h"
#include "core/log.h"
#include "core/number_text.h"
#include "metrology/deviations.h"
#include "metrology/probe.h"
#include "reconstruction/cad_io.h"

namespace formloop::app {
namespace {

using nlohmann::json;

// "X,Y,Z" into a vector (cells split and numbers read as every CSV cell is: core/csv.h, no locale);
// `option` names the option in the message.
Result<Eigen::Vector3d> ParseTriple(const std::string& text, const std::string& option) {
  std::vector<std::string_view> cells;
  SplitCsvCells(text, &cells);
  Eigen::Vector3d v;
  bool ok = cells.size() == 3;
  for (int k = 0; ok && k < 3; ++k) ok = ParseDouble(cells[k], &v[k]) && std::isfinite(v[k]);
  if (!ok) return Status::BadInput(Where{.field = option}, "'" + text + "' is not three numbers X,Y,Z");
  return v;
}

struct ConfigArgs {
  cnc::LinuxCncMachineOptions machine;
  bool no_probe = false, no_link = false;
  std::string shift_um, rotation_urad, tilt_deg;
  double travel = 300, travel_z = 200;
  std::string out;
};

Status WriteConfig(const ConfigArgs& args) {
  cnc::LinuxCncMachineOptions o = args.machine;
  o.probe = !args.no_probe;
  o.link = !args.no_link;
  o.travel_min_mm = {-args.travel, -args.travel, -args.travel_z};
  o.travel_max_mm = {args.travel, args.travel, args.travel_z};
  if (!args.shift_um.empty()) {
    FL_ASSIGN_OR_RETURN(o.surface.pose.shift_um, ParseTriple(args.shift_um, "--shift-um"));
  }
  if (!args.rotation_urad.empty() && !args.tilt_deg.empty()) {
    return Status::BadInput(Where{.field = "--tilt-deg"}, "give the rotation once: --rotation-urad or --tilt-deg");
  }
  if (!args.rotation_urad.empty()) {
    FL_ASSIGN_OR_RETURN(o.surface.pose.rotation_urad, ParseTriple(args.rotation_urad, "--rotation-urad"));
  }
  if (!args.tilt_deg.empty()) {
    FL_ASSIGN_OR_RETURN(const Eigen::Vector3d deg, ParseTriple(args.tilt_deg, "--tilt-deg"));
    o.surface.pose.rotation_urad = deg * (M_PI / 180 * 1e6);
  }
  FL_ASSIGN_OR_RETURN(const cnc::LinuxCncConfigReport report, cnc::WriteLinuxCncConfig(args.out, o));
  std::cout << report.ToJson().dump(2) << "\n";
  log::Info("machine linuxcnc config: {}", report.ini.string());
  return Status::Ok();
}

struct RunArgs {
  std::string config, program, out;
  cnc::LinuxCncRunOptions run;
};

Status RunProgram(const RunArgs& args) {
  FL_ASSIGN_OR_RETURN(const cnc::LinuxCncConfig config, cnc::ReadLinuxCncConfig(args.config));
  FL_ASSIGN_OR_RETURN(const cnc::LinuxCncRunReport report,
                      cnc::RunOnLinuxCnc(config, args.program, args.out, args.run));
  std::cout << report.ToJson().dump(2) << "\n";
  return report.ToStatus();
}

struct ProbeArgs {
  std::string config, surface, face_name, grid = "3x3", out;
  int face_index = -1;
  cnc::LinuxCncProbingOptions probing;
};

Status Probe(const ProbeArgs& args) {
  cnc::LinuxCncProbingOptions options = args.probing;
  FL_RETURN_IF_ERROR(ParseLayout(args.grid, "--grid", &options.nu, &options.nv));
  FL_ASSIGN_OR_RETURN(const cnc::LinuxCncConfig config, cnc::ReadLinuxCncConfig(args.config));
  FL_ASSIGN_OR_RETURN(
      const recon::CadFace face,
      recon::ReadCadFace(args.surface, recon::CadFaceSelector{.index = args.face_index, .name = args.face_name}));
  FL_ASSIGN_OR_RETURN(const cnc::LinuxCncProbing probing,
                      cnc::ProbeOnLinuxCnc(config, face.surface, options, args.out));
  FL_ASSIGN_OR_RETURN(const std::vector<metrology::Deviation> deviations,
                      metrology::ComputeDeviations(face.surface, probing.plan, probing.log, probing.probe));
  double max_abs = 0, sum = 0, sum2 = 0;
  for (const auto& d : deviations) {
    const double um = d.deviation_mm * 1e3;
    max_abs = std::max(max_abs, std::abs(um));
    sum += um;
    sum2 += um * um;
  }
  const double n = static_cast<double>(deviations.size());
  const json summary = {{"points", deviations.size()},
                        {"probe_log", (probing.folder / "probe_log.csv").string()},
                        {"plan", (probing.folder / "probing_plan.json").string()},
                        {"probe_profile", (probing.folder / "probe_profile.json").string()},
                        {"program", (probing.folder / "probe.ngc").string()},
                        {"deviations_um", {{"mean", sum / n}, {"rms", std::sqrt(sum2 / n)}, {"max_abs", max_abs}}},
                        {"run", probing.run.ToJson()}};
  std::cout << summary.dump(2) << "\n";
  log::Info("machine linuxcnc probe: {} points, deviations from Q: mean {:.3f} um, max |d| {:.3f} um",
            deviations.size(), sum / n, max_abs);
  return Status::Ok();
}

struct MeasureArgs {
  std::string config, surface, grid = "5x5", out;
  double inset_fraction = 0.1;
  cnc::LinuxCncMeasureOptions measure;
};

Status Measure(const MeasureArgs& args) {
  int nu = 0, nv = 0;
  FL_RETURN_IF_ERROR(ParseLayout(args.grid, "--grid", &nu, &nv));
  FL_ASSIGN_OR_RETURN(const cnc::LinuxCncConfig config, cnc::ReadLinuxCncConfig(args.config));
  FL_ASSIGN_OR_RETURN(const recon::CadFace face, recon::ReadCadFace(args.surface, recon::CadFaceSelector{}));
  FL_ASSIGN_OR_RETURN(const metrology::ProbingPlan plan,
                      metrology::PlanProbingGrid(face.surface, nu, nv, args.inset_fraction));
  FL_ASSIGN_OR_RETURN(const cnc::LinuxCncMeasurement m, cnc::MeasureOnLinuxCnc(config, plan, args.measure, args.out));
  std::cout << m.ToJson().dump(2) << "\n";
  if (!m.run.ok) return m.run.ToStatus();
  if (!m.ok()) {
    return Status::Failed("machine linuxcnc measure: " + std::to_string(m.points_received) + " of " +
                          std::to_string(m.points_planned) + " points arrived (" + std::to_string(m.distinct_ids) +
                          " distinct), " + std::to_string(m.checked_against_trips) +
                          " agree with the controller's trips" +
                          (m.collector.ok ? std::string() : "; collector: " + m.collector.fatal));
  }
  return Status::Ok();
}

}  // namespace

void AddMachineCommand(CLI::App& root, CommandAction* action) {
  CLI::App* machine = root.add_subcommand("machine", "Run formloop's programs on a controller.");
  machine->require_subcommand(1);
  CLI::App* linuxcnc = machine->add_subcommand(
      "linuxcnc",
      "LinuxCNC 2.9 (linuxcnc-uspace) running a simulated XYZ mill headless, with a probe surface from "
      "HAL math components.");
  linuxcnc->require_subcommand(1);

  auto config_args = std::make_shared<ConfigArgs>();
  CLI::App* config = linuxcnc->add_subcommand(
      "config",
      "Write a LinuxCNC configuration: a simulated XYZ mill whose touch probe finds a reference surface "
      "(a plane or a quadric), placed with a set-up shift and rotation.");
  cnc::LinuxCncMachineOptions& m = config_args->machine;
  config->add_option("--out", config_args->out, "the configuration folder (formloop.ini, formloop.hal, ...)")
      ->required();
  config->add_option("--surface", m.surface.surface, "the probe surface: a reference surface that is a quadric")
      ->capture_default_str();
  config->add_flag("--no-probe", config_args->no_probe, "no probe surface (motion.probe-input stays low)");
  config->add_flag("--no-link", config_args->no_link,
                   "no handshake link component (analog ports 0..3 stay plain motion I/O)");
  config->add_option("--ball-radius-mm", m.surface.ball_radius_mm, "stylus ball radius the surface is built for, mm")
      ->capture_default_str();
  config->add_option("--shift-um", config_args->shift_um, "the workpiece's shift from its programmed place, um: X,Y,Z");
  config->add_option("--rotation-urad", config_args->rotation_urad,
                     "its rotation about the part origin, a rotation vector in urad: X,Y,Z");
  config->add_option("--tilt-deg", config_args->tilt_deg, "the same rotation in degrees: X,Y,Z");
  config->add_option("--travel", config_args->travel, "soft limits in x and y: +-MM")->capture_default_str();
  config->add_option("--travel-z", config_args->travel_z, "soft limits in z: +-MM")->capture_default_str();
  config->add_option("--max-velocity", m.max_velocity_mm_per_s, "every axis, mm/s")->capture_default_str();
  config->add_option("--max-acceleration", m.max_acceleration_mm_per_s2, "every axis, mm/s^2")->capture_default_str();
  config->add_option("--name", m.name, "the machine's name")->capture_default_str();
  config->callback([action, config_args] { *action = [config_args] { return WriteConfig(*config_args); }; });

  auto run_args = std::make_shared<RunArgs>();
  CLI::App* run = linuxcnc->add_subcommand(
      "run", "Start LinuxCNC headless on a configuration, run a program, shut down; errors name the program line.");
  run->add_option("--config", run_args->config, "formloop.ini or its folder")->required();
  run->add_option("--program", run_args->program, "the G-code program")->required();
  run->add_option("--out", run_args->out,
                  "the session folder (new): copies, controller.log, result.json and "
                  "what the program writes")
      ->required();
  run->add_option("--timeout-s", run_args->run.timeout_s, "the program's time limit, s")->capture_default_str();
  run->callback([action, run_args] { *action = [run_args] { return RunProgram(*run_args); }; });

  auto measure_args = std::make_shared<MeasureArgs>();
  CLI::App* measure = linuxcnc->add_subcommand(
      "measure",
      "The link's handshake over HAL: formloop's machine-side measuring program runs on the controller "
      "while the collector takes each point through the variable block; checked against the "
      "controller's own record of every probe trip.");
  measure->add_option("--config", measure_args->config, "formloop.ini or its folder")->required();
  measure->add_option("--surface", measure_args->surface, "Q as a STEP or IGES file")->required();
  measure->add_option("--grid", measure_args->grid, "points NUxNV equidistant in parameter space")
      ->capture_default_str();
  measure->add_option("--inset", measure_args->inset_fraction, "keep this fraction of the domain free at each edge")
      ->capture_default_str();
  measure->add_option("--timeout-s", measure_args->measure.run.timeout_s, "the program's time limit, s")
      ->capture_default_str();
  measure->add_option("--out", measure_args->out, "output folder (new)")->required();
  measure->callback([action, measure_args] { *action = [measure_args] { return Measure(*measure_args); }; });

  auto probe_args = std::make_shared<ProbeArgs>();
  CLI::App* probe = linuxcnc->add_subcommand(
      "probe",
      "Probe a grid of points on Q with formloop's LinuxCNC probing program on the controller; write the "
      "probe log, plan and probe profile and print the deviations from Q.");
  probe->add_option("--config", probe_args->config, "formloop.ini or its folder")->required();
  probe->add_option("--surface", probe_args->surface, "Q as a STEP or IGES file (e.g. from `formloop fit`)")
      ->required();
  probe->add_option("--face", probe_args->face_index, "0-based face index when the file has several faces");
  probe->add_option("--face-name", probe_args->face_name, "face name");
  probe->add_option("--grid", probe_args->grid, "points NUxNV equidistant in parameter space")->capture_default_str();
  cnc::LinuxCncProbingOptions& p = probe_args->probing;
  probe->add_option("--inset", p.inset_fraction, "keep this fraction of the domain free at each edge")
      ->capture_default_str();
  probe->add_option("--probe-feed", p.program.probe_feed_mm_per_min, "approach (first touch) feed, mm/min")
      ->capture_default_str();
  probe
      ->add_option("--touch-feed", p.program.touch_feed_mm_per_min,
                   "measuring (second touch) feed, mm/min; 0 = one touch at the probe feed")
      ->capture_default_str();
  probe->add_option("--backoff-mm", p.program.backoff_mm, "back-off between the touches, mm")->capture_default_str();
  probe->add_option("--clearance-mm", p.program.clearance_mm, "start this far from Q along n, mm")
      ->capture_default_str();
  probe->add_option("--search-mm", p.program.search_mm, "probe this far beyond Q, mm")->capture_default_str();
  probe
      ->add_option("--min-gap-mm", p.program.min_gap_mm,
                   "least gap between the probe and Q on the moves that do not probe (checked; a point that "
                   "cannot keep it is refused), mm")
      ->capture_default_str();
  probe
      ->add_option("--shank-radius-mm", p.program.shank_radius_mm,
                   "stylus shank radius, kept clear of Q too; 0 = not checked")
      ->capture_default_str();
  probe->add_option("--safe-z-mm", p.program.safe_z_mm,
                    "rapid height between points, mm (default: 5 mm above the "
                    "highest start)");
  probe->add_option("--timeout-s", p.run.timeout_s, "the program's time limit, s")->capture_default_str();
  probe->add_option("--out", probe_args->out, "output folder (new)")->required();
  probe->callback([action, probe_args] { *action = [probe_args] { return Probe(*probe_args); }; });
}

}  // namespace formloop::app
