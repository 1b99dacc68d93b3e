#pragma once
// A `formloop run` folder: how the pipeline builds one (RunFolderWriter: the .partial folder, the status
// marker, stage timing, the relative paths the JSON files name, the rename when complete) and how other
// commands (simulate, diagnose) read one back (ReadRunFolder: the resolved part, the ideal surface Q
// (surface/Q.step), the tool path (toolpath/toolpath.csv) and the probing plan
// (toolpath/probing_plan.json, with the approaches of toolpath/probing_plan.csv when the run planned tilted
// points), each read with the error naming the file).
//
// A run folder is built as "<out>.partial" with status.json {"state": "incomplete", "stage": ...} and
// renamed to <out> (state "complete") only when every output is written; a failed run is renamed to
// "<out>.failed" with its log and the error.

#include <chrono>
#include <filesystem>
#include <functional>
#include <string>
#include <string_view>
#include <vector>

#include <Eigen/Core>

#include "app/part.h"
#include "core/json_io.h"
#include "core/output_folder.h"
#include "core/status.h"
#include "metrology/probe.h"
#include "nc-gen/toolpath.h"
#include "reconstruction/bspline_surface.h"
#include "simulation/covariates.h"

namespace formloop::app {

// Called after each stage with its name (without the "k/9: " counter) and its wall time.
using StageTimer = std::function<void(std::string_view stage, double seconds)>;

class RunFolderWriter {
 public:
  RunFolderWriter(std::filesystem::path out, StageTimer on_stage);
  RunFolderWriter(const RunFolderWriter&) = delete;
  RunFolderWriter& operator=(const RunFolderWriter&) = delete;
  ~RunFolderWriter();  // stops the run's log if Close was not reached

  // Refuses an existing `out` unless `force`, and any folder formloop did not write or that holds the
  // current directory or one of `inputs` (core/output_folder.h); starts "<out>.partial" afresh (an
  // incomplete one left by a killed run is logged with the part name `what`, and replaced) and the run's
  // formloop.log in it.
  Status Open(bool force, const std::string& what, const std::vector<NamedPath>& inputs);

  const std::filesystem::path& dir() const { return folder_.dir(); }  // the .partial folder being written
  const std::filesystem::path& out() const { return out_; }
  std::filesystem::path Path(const std::filesystem::path& relative) const { return dir() / relative; }
  static std::filesystem::path LoopDir(int loop) { return "loop-" + std::to_string(loop); }
  // A path inside the folder as the run's JSON files name it ("toolpath/program.ngc").
  std::string Relative(const std::filesystem::path& path) const;

  // status.json {"state": "incomplete", "stage": stage}; the previous stage's time goes to on_stage.
  Status Begin(const std::string& stage);
  // Ends the last stage (its time goes to on_stage).
  void EndStage();
  // Parent folders are created as needed; every file is written atomically.
  Status WriteJson(const std::filesystem::path& relative, const Json& value) const;
  Status WriteText(const std::filesystem::path& relative, std::string_view text) const;
  Status MakeFolder(const std::filesystem::path& relative) const;

  // status.json {"state": "complete"}.
  Status MarkComplete() const;
  // Stops the run's log and renames the folder: to `out` when `status` is ok (replacing an older run
  // folder), else to "<out>.failed", returning `status` with `what` and that folder named.
  Status Close(const Status& status, const std::string& what);

 private:
  std::filesystem::path out_;
  StagedOutputFolder folder_;
  StageTimer on_stage_;
  std::string stage_;
  std::chrono::steady_clock::time_point start_;
  bool logging_ = false;
};

struct RunFolder {
  std::filesystem::path dir;
  PartSpec part;
  recon::BSplineSurface q;
  nc::Toolpath toolpath;
  std::vector<sim::CutterLocation> cutter_locations;  // nc::CutterLocationsOf(toolpath)
  metrology::ProbingPlan plan;
  // The approach of each plan point when the run planned tilted ones (a separating experiment:
  // toolpath/probing_plan.csv beside the JSON plan); empty: every point along −n.
  std::vector<Eigen::Vector3d> approaches;
};

Result<RunFolder> ReadRunFolder(const std::filesystem::path& dir);
// The files ReadRunFolder reads (those present of the optional ones), named by `option` (e.g. "--run"),
// for CheckOutputsNotInputs.
std::vector<NamedPath> RunFolderInputs(const std::string& option, const std::filesystem::path& dir);

// A probing plan with optional approach directions: formloop's JSON ({"points": [{"id", "u", "v",
// "point", "normal"}]}) or CSV with the columns id, u, v, x, y, z, nx, ny, nz and optionally ax, ay, az
// (unit, into the surface). `approaches` is empty when the file gives none (approach along −n).
struct PlanWithApproaches {
  metrology::ProbingPlan plan;
  std::vector<Eigen::Vector3d> approaches;
};
Result<PlanWithApproaches> ReadPlanFile(const std::filesystem::path& path);

}  // namespace formloop::app
