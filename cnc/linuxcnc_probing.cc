#include "cnc/linuxcnc_probing.h"

#include <charconv>
#include <cmath>
#include <limits>
#include <sstream>

#include "cnc/linuxcnc_probe_log.h"
#include "core/atomic_file.h"
#include "core/json_io.h"
#include "core/log.h"
#include "core/point_io.h"
#include "metrology/probing_plan.h"

namespace formloop::cnc {
namespace {

namespace fs = std::filesystem;

constexpr const char* kResultsFile = "probe_results.txt";
constexpr const char* kPointsFile = "probe_points.txt";

Result<double> IniNumber(const LinuxCncConfig& config, const std::string& section, const std::string& key) {
  const std::string text = config.Get(section, key);
  double v = 0;
  const auto r = std::from_chars(text.data(), text.data() + text.size(), v);
  if (text.empty() || r.ec != std::errc() || r.ptr != text.data() + text.size() || !std::isfinite(v)) {
    return Status::BadInput(Where{.file = config.ini.string(), .field = "[" + section + "] " + key},
                            "'" + text + "' is not a number");
  }
  return v;
}

}  // namespace

nc::ProbeProgramOptions LinuxCncProbingOptions::DefaultProgram() {
  nc::ProbeProgramOptions p;
  p.clearance_mm = 2.0;
  p.search_mm = 1.0;
  p.probe_feed_mm_per_min = 600;
  p.touch_feed_mm_per_min = 6;
  p.backoff_mm = 0.1;
  p.safe_z_mm = std::numeric_limits<double>::quiet_NaN();
  p.results_file = kResultsFile;
  p.linuxcnc_log_file = kPointsFile;
  p.linuxcnc_time_input = -1;  // set from the configuration's servo clock when it has one
  return p;
}

Status LinuxCncProbingOptions::Validate() const {
  if (nu < 2 || nv < 2) return Status::BadInput(Where{.field = "--grid"}, "needs at least 2 x 2 points");
  if (!(inset_fraction >= 0 && inset_fraction < 0.5)) {
    return Status::BadInput(Where{.field = "--inset"}, "must be in [0, 0.5)");
  }
  if (program.linuxcnc_log_file.empty()) {
    return Status::BadInput(Where{.field = "linuxcnc_log_file"}, "the probe log is read from the program's LOG file");
  }
  return run.Validate();
}

Result<nc::MachineLimits> LimitsOf(const LinuxCncConfig& config) {
  nc::MachineLimits limits;
  const char* axes[] = {"AXIS_X", "AXIS_Y", "AXIS_Z"};
  for (int j = 0; j < 3; ++j) {
    FL_ASSIGN_OR_RETURN(limits.travel_min_mm[j], IniNumber(config, axes[j], "MIN_LIMIT"));
    FL_ASSIGN_OR_RETURN(limits.travel_max_mm[j], IniNumber(config, axes[j], "MAX_LIMIT"));
  }
  FL_ASSIGN_OR_RETURN(const double v, IniNumber(config, "TRAJ", "MAX_LINEAR_VELOCITY"));
  limits.max_feed_mm_per_min = 60 * v;
  FL_RETURN_IF_ERROR(limits.Validate());
  return limits;
}

Result<LinuxCncProbing> ProbeOnLinuxCnc(const LinuxCncConfig& config, const recon::BSplineSurface& q,
                                        const LinuxCncProbingOptions& options, const fs::path& out) {
  FL_RETURN_IF_ERROR(options.Validate());
  FL_ASSIGN_OR_RETURN(const metrology::ProbingPlan plan,
                      metrology::PlanProbingGrid(q, options.nu, options.nv, options.inset_fraction));
  LinuxCncProbingOptions checked = options;
  if (!checked.program.part_surface) {
    FL_ASSIGN_OR_RETURN(checked.program.part_surface, recon::FootPointProjector::Build(q));
  }
  return ProbePlanOnLinuxCnc(config, plan, checked, out);
}

Result<LinuxCncProbing> ProbePlanOnLinuxCnc(const LinuxCncConfig& config, const metrology::ProbingPlan& plan,
                                            const LinuxCncProbingOptions& options, const fs::path& out) {
  FL_RETURN_IF_ERROR(options.Validate());
  std::error_code ec;
  if (fs::exists(out, ec) && !fs::is_empty(out, ec)) {
    return Status::BadInput(Where{.file = out.string()}, "exists and is not empty", "give a new output folder");
  }
  LinuxCncProbing result;
  result.folder = out;
  FL_ASSIGN_OR_RETURN(result.probe.ball_radius_mm, IniNumber(config, "FORMLOOP", "PROBE_BALL_RADIUS_MM"));
  // LinuxCNC records the first servo period with the probe input set: the centre is late by a uniform
  // fraction of one period's travel, on average half of it. That is this probe system's pretravel.
  FL_ASSIGN_OR_RETURN(const double servo_period_ns, IniNumber(config, "EMCMOT", "SERVO_PERIOD"));
  const double measuring_feed = options.program.touch_feed_mm_per_min > 0 ? options.program.touch_feed_mm_per_min
                                                                          : options.program.probe_feed_mm_per_min;
  result.probe.pretravel_mm = 0.5 * measuring_feed / 60 * servo_period_ns * 1e-9;
  result.plan = plan;
  nc::ProbeProgramOptions program = options.program;
  program.ball_radius_mm = result.probe.ball_radius_mm;
  FL_ASSIGN_OR_RETURN(program.post.limits, LimitsOf(config));
  if (program.linuxcnc_time_input < 0 && !config.Get("FORMLOOP", "SERVO_CLOCK_INPUT").empty()) {
    FL_ASSIGN_OR_RETURN(const double clock, IniNumber(config, "FORMLOOP", "SERVO_CLOCK_INPUT"));
    program.linuxcnc_time_input = static_cast<int>(clock);
  }
  if (!config.Get("FORMLOOP", "PROBE_TOOL").empty()) {
    FL_ASSIGN_OR_RETURN(const double tool, IniNumber(config, "FORMLOOP", "PROBE_TOOL"));
    if (tool != program.probe_tool) {
      return Status::BadInput(Where{.file = config.ini.string(), .field = "[FORMLOOP] PROBE_TOOL"},
                              "the configuration's probe is T" + FormatExact(tool) + ", the probing program's T" +
                                  std::to_string(program.probe_tool),
                              "give the probing program the configuration's probe tool (probing.tool)");
    }
  }
  if (program.post.title.empty()) program.post.title = "formloop probing on LinuxCNC, " + config.Get("EMC", "MACHINE");
  if (std::isnan(program.safe_z_mm)) {
    double top = -std::numeric_limits<double>::infinity();
    for (std::size_t i = 0; i < result.plan.points.size(); ++i) {
      const auto& p = result.plan.points[i];
      const bool tilted = program.approaches.size() == result.plan.points.size();
      const Eigen::Vector3d a = tilted ? program.approaches[i] : Eigen::Vector3d(-p.normal);
      const Eigen::Vector3d start = p.point + program.ball_radius_mm * p.normal - program.clearance_mm * a;
      top = std::max(top, start.z() + program.backoff_mm);
    }
    program.safe_z_mm = std::ceil(top + 5.0);
  }
  FL_ASSIGN_OR_RETURN(const std::string text, nc::PostLinuxCncProbing(result.plan, program));
  FL_RETURN_IF_ERROR(MakeDirectories(out));
  FL_RETURN_IF_ERROR(WriteJsonFile(out / "probing_plan.json", result.plan.ToJson()));
  FL_RETURN_IF_ERROR(metrology::WriteProbeProfile(out / "probe_profile.json", result.probe));
  FL_RETURN_IF_ERROR(WriteFileAtomic(out / "probe.ngc", text));
  FL_ASSIGN_OR_RETURN(result.run, RunOnLinuxCnc(config, out / "probe.ngc", out / "controller", options.run));
  FL_RETURN_IF_ERROR(result.run.ToStatus());
  const int touches = program.touch_feed_mm_per_min > 0 ? 2 : 1;
  FL_ASSIGN_OR_RETURN(result.log, ReadLinuxCncProbeLog(out / "controller" / program.linuxcnc_log_file,
                                                       out / "controller" / program.results_file, touches));
  FL_ASSIGN_OR_RETURN(const std::vector<std::int64_t> missing,
                      metrology::CheckProbeLogAgainstPlan(result.log, result.plan));
  if (!missing.empty() || result.log.records.size() != result.plan.points.size()) {
    return Status::Failed(result.log.source + ": " + std::to_string(result.log.records.size()) + " of " +
                          std::to_string(result.plan.points.size()) + " planned points were logged");
  }
  FL_RETURN_IF_ERROR(metrology::WriteProbeLog(out / "probe_log.csv", result.log));
  log::Info("linuxcnc: {} points probed -> {}", result.log.records.size(), (out / "probe_log.csv").string());
  return result;
}

}  // namespace formloop::cnc
