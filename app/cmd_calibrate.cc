// `formloop calibrate`: probe calibration on a standard sphere (metrology/probe_calibration.h,
// spec/metrology.md §2).
//
//   formloop calibrate sphere LOG.csv --radius R_s --ball R_nom [--lobes 3] [--elevation-degree 0]
//                                     [--out PROFILE.json]
//     fits the sphere centre, the effective radius and the lobing pretravel; prints the ISO 10360-5
//     style report (probing form error, size error, residuals, coefficients with standard errors) as
//     JSON on stdout and writes the probe profile (atomically) when --out is given.
//   formloop calibrate synth-sphere --out LOG.csv [--points 25] [--amplitude-um 5] [--phase-deg 0]
//                                   [--seed 1] [--noise-um 0.5] [--radius 12.5] [--ball 1] [--pretravel-um 0]
//     writes a synthetic sphere probe log with a known tri-lobe to try the calibration on; prints the
//     true probe profile as JSON on stdout.

#include <cmath>
#include <iostream>
#include <memory>
#include <numbers>
#include <string>

#include <nlohmann/json.hpp>

#include "app/command.h"
#include "core/output_file.h"
#include "metrology/probe.h"
#include "metrology/probe_calibration.h"

namespace formloop::app {
namespace {

Status PrintJson(const nlohmann::json& json, const std::string& command) {
  std::cout << json.dump(2) << "\n";
  std::cout.flush();
  if (!std::cout) return Status::IoError(command + ": writing to stdout failed");
  return Status::Ok();
}

struct SphereArgs {
  std::string log;
  std::string out;
  bool force = false;
  metrology::SphereCalibrationOptions options;
};

Status CalibrateSphere(const SphereArgs& args) {
  FL_RETURN_IF_ERROR(args.options.Validate());
  FL_RETURN_IF_ERROR(CheckOutputFiles({{"--out", args.out}}, {{"LOG", args.log}}, args.force));
  FL_ASSIGN_OR_RETURN(const metrology::ProbeLog log, metrology::ReadProbeLog(args.log));
  FL_ASSIGN_OR_RETURN(const metrology::SphereCalibrationReport report, metrology::CalibrateOnSphere(log, args.options));
  nlohmann::json json = report.ToJson();
  json["log"] = args.log;
  json["profile"] = metrology::ProbeProfileToJson(report.profile);
  if (!args.out.empty()) {
    FL_RETURN_IF_ERROR(metrology::WriteProbeProfile(args.out, report.profile, report.ToJson()));
    json["profile_file"] = args.out;
  }
  return PrintJson(json, "calibrate sphere");
}

struct SynthArgs {
  std::string out;
  bool force = false;
  metrology::SphereLogOptions options;
  double amplitude_um = 5.0;
  double phase_deg = 0.0;
  double pretravel_um = 0.0;
  double ball_radius_mm = 1.0;
};

Status SynthSphere(SynthArgs args) {
  metrology::SphereLogOptions& o = args.options;
  if (!(args.amplitude_um >= 0 && args.amplitude_um < 1000)) {
    return Status::BadInput(Where{.field = "--amplitude-um"}, "must be in [0, 1000) µm");
  }
  o.probe.ball_radius_mm = args.ball_radius_mm;
  o.probe.pretravel_mm = args.pretravel_um * 1e-3;
  o.probe.lobing = metrology::TriLobe(args.amplitude_um * 1e-3, args.phase_deg * std::numbers::pi / 180);
  FL_RETURN_IF_ERROR(CheckOutputFiles({{"--out", args.out}}, {}, args.force));
  FL_ASSIGN_OR_RETURN(const metrology::ProbeLog log, metrology::GenerateSphereProbeLog(o));
  FL_RETURN_IF_ERROR(metrology::WriteProbeLog(args.out, log));
  return PrintJson({{"log", args.out},
                    {"points", log.records.size()},
                    {"sphere_centre_mm", {o.centre_mm.x(), o.centre_mm.y(), o.centre_mm.z()}},
                    {"sphere_radius_mm", o.sphere_radius_mm},
                    {"noise_um", o.noise_um},
                    {"seed", o.seed},
                    {"true_profile", metrology::ProbeProfileToJson(o.probe)}},
                   "calibrate synth-sphere");
}

}  // namespace

void AddCalibrateCommand(CLI::App& root, CommandAction* action) {
  CLI::App* calibrate =
      root.add_subcommand("calibrate", "Probe calibration: pretravel lobing from a standard sphere (ISO 10360-5).");
  calibrate->require_subcommand(1);

  auto sphere_args = std::make_shared<SphereArgs>();
  CLI::App* sphere = calibrate->add_subcommand(
      "sphere",
      "Fit the sphere centre, effective ball radius and direction-dependent pretravel from a probe log on a "
      "standard sphere probed along its normals (>= 25 points over the upper hemisphere). Prints the ISO 10360-5 "
      "style report as JSON; --out writes the probe profile that `analyse --probe-profile` applies.");
  sphere->add_option("log", sphere_args->log, "probe log (CSV: id,x,y,z,ax,ay,az,t)")->required();
  sphere
      ->add_option("--radius", sphere_args->options.sphere_radius_mm,
                   "certified radius of the standard sphere, mm (half the certified diameter)")
      ->required();
  sphere->add_option("--ball", sphere_args->options.ball_radius_mm, "nominal stylus-ball radius, mm")->required();
  sphere
      ->add_option("--lobes", sphere_args->options.max_order,
                   "highest azimuth harmonic K of the pretravel (3 = tri-lobe), 0..3")
      ->capture_default_str();
  sphere
      ->add_option("--elevation-degree", sphere_args->options.elevation_degree,
                   "degree D of the elevation polynomial g_k(sin phi), 0..3 (lowered automatically when the points "
                   "sit at too few elevations)")
      ->capture_default_str();
  sphere->add_option("--out", sphere_args->out, "probe profile to write (JSON)");
  AddForceFlag(sphere, &sphere_args->force);
  sphere->callback([action, sphere_args] { *action = [sphere_args] { return CalibrateSphere(*sphere_args); }; });

  auto synth_args = std::make_shared<SynthArgs>();
  CLI::App* synth = calibrate->add_subcommand(
      "synth-sphere",
      "Write a synthetic standard-sphere probe log (ISO 10360-5 pattern: pole and rings at 0, 22.5, 45, 67.5 deg) "
      "with a known tri-lobe pretravel and Gaussian noise, to try `calibrate sphere` on.");
  synth->add_option("--out", synth_args->out, "probe log to write (CSV)")->required();
  AddForceFlag(synth, &synth_args->force);
  synth->add_option("--points", synth_args->options.points, "number of points, 5..10000 (ISO: 25)")
      ->capture_default_str();
  synth->add_option("--amplitude-um", synth_args->amplitude_um, "tri-lobe amplitude, µm")->capture_default_str();
  synth->add_option("--phase-deg", synth_args->phase_deg, "tri-lobe phase psi in A cos(3 theta - psi), degrees")
      ->capture_default_str();
  synth->add_option("--pretravel-um", synth_args->pretravel_um, "constant pretravel, µm")->capture_default_str();
  synth->add_option("--noise-um", synth_args->options.noise_um, "sigma of the radial noise, µm")->capture_default_str();
  synth->add_option("--seed", synth_args->options.seed, "noise seed")->capture_default_str();
  synth->add_option("--radius", synth_args->options.sphere_radius_mm, "sphere radius, mm")->capture_default_str();
  synth->add_option("--ball", synth_args->ball_radius_mm, "nominal ball radius, mm")->capture_default_str();
  synth->callback([action, synth_args] { *action = [synth_args] { return SynthSphere(*synth_args); }; });
}

}  // namespace formloop::app
