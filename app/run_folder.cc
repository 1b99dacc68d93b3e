#include "app/run_folder.h"

#include <cmath>
#include <limits>
#include <optional>
#include <set>
#include <string>

#include "core/atomic_file.h"
#include "core/json_io.h"
#include "core/log.h"
#include "core/point_io.h"
#include "nc-gen/cutter_locations.h"
#include "nc-gen/toolpath_io.h"
#include "reconstruction/cad_io.h"

namespace formloop::app {
namespace fs = std::filesystem;

namespace {

Status ReadVector3(const JsonFields& f, const std::string& key, Eigen::Vector3d* out) {
  std::vector<double> v;
  FL_RETURN_IF_ERROR(f.NumberArray(key, &v, 3));
  *out = Eigen::Vector3d(v[0], v[1], v[2]);
  return Status::Ok();
}

// A probing plan as written by ProbingPlan::ToJson ({"count": n, "points": [{"id", "u", "v", "point",
// "normal"}, ...], "trim": {...} on a trimmed Q}), e.g. toolpath/probing_plan.json of `formloop run`.
Result<metrology::ProbingPlan> ReadPlanJsonFile(const std::string& path) {
  FL_ASSIGN_OR_RETURN(const Json json, ReadJsonFile(path));
  if (!json.is_object() || !json.contains("points") || !json["points"].is_array() || json["points"].empty()) {
    return Status::BadInput(Where{.file = path, .field = "points"}, "a probing plan needs a non-empty array 'points'",
                            "use a plan written by formloop (e.g. toolpath/probing_plan.json of `formloop run`)");
  }
  JsonFields top(json, path);
  FL_RETURN_IF_ERROR(top.CheckKnown({"count", "points", "trim"}));
  std::vector<JsonFields> points;
  FL_RETURN_IF_ERROR(top.ObjectArray("points", &points));
  metrology::ProbingPlan plan;
  // A plan on a trimmed Q says so (ProbingPlan::ToJson): its edge margin, the grid positions left out and
  // the rule, which is text for the reader.
  std::optional<JsonFields> trim;
  FL_RETURN_IF_ERROR(top.Object("trim", &trim));
  if (trim) {
    FL_RETURN_IF_ERROR(trim->CheckKnown({"edge_margin_mm", "left_out", "rule"}));
    plan.trimmed = true;
    FL_RETURN_IF_ERROR(trim->Number("edge_margin_mm", &plan.edge_margin_mm, NumberRange{.min = 0}));
    long long left_out = 0;
    FL_RETURN_IF_ERROR(trim->OptionalInteger("left_out", &left_out, 0, std::numeric_limits<int>::max()));
    plan.left_out = static_cast<int>(left_out);
    std::string rule;
    FL_RETURN_IF_ERROR(trim->OptionalString("rule", &rule));
  }
  std::set<std::int64_t> ids;
  for (const JsonFields& f : points) {
    FL_RETURN_IF_ERROR(f.CheckKnown({"id", "u", "v", "point", "normal"}));
    metrology::ProbePoint p;
    long long id = 0;
    FL_RETURN_IF_ERROR(f.Integer("id", &id));
    p.id = id;
    FL_RETURN_IF_ERROR(f.Number("u", &p.u));
    FL_RETURN_IF_ERROR(f.Number("v", &p.v));
    FL_RETURN_IF_ERROR(ReadVector3(f, "point", &p.point));
    FL_RETURN_IF_ERROR(ReadVector3(f, "normal", &p.normal));
    const double length = p.normal.norm();
    if (!(length > 0.5 && length < 1.5)) {
      return Status::BadInput(Where{.file = path, .field = f.Path("normal")}, "is not a unit vector",
                              "write the unit outward normal of Q at the point");
    }
    p.normal /= length;
    if (!ids.insert(p.id).second) {
      return Status::BadInput(Where{.file = path, .field = f.Path("id")}, "id " + std::to_string(p.id) + " is repeated",
                              "give every planned point its own id");
    }
    plan.points.push_back(p);
  }
  long long count = static_cast<long long>(plan.points.size());
  FL_RETURN_IF_ERROR(top.OptionalInteger("count", &count));
  if (count != static_cast<long long>(plan.points.size())) {
    return Status::BadInput(Where{.file = path, .field = "count"},
                            "does not match the " + std::to_string(plan.points.size()) + " points",
                            "write the number of points, or leave 'count' out");
  }
  return plan;
}

Result<PlanWithApproaches> ReadPlanJson(const fs::path& path) {
  FL_ASSIGN_OR_RETURN(metrology::ProbingPlan plan, ReadPlanJsonFile(path.string()));
  return PlanWithApproaches{std::move(plan), {}};
}

Result<PlanWithApproaches> ReadPlanCsv(const fs::path& path) {
  FL_ASSIGN_OR_RETURN(const PointSet set, ReadCsv(path));
  const std::string source = path.string();
  const std::vector<double>* u = set.FindScalar("u");
  const std::vector<double>* v = set.FindScalar("v");
  if (u == nullptr || v == nullptr || !set.has_ids() || set.normals.empty()) {
    return Status::BadInput(Where{.file = source, .line = 1},
                            "a probing plan CSV needs the columns id, u, v, x, y, z, nx, ny, nz",
                            "add the missing columns (ax, ay, az are optional)");
  }
  const std::vector<double>* ax = set.FindScalar("ax");
  const std::vector<double>* ay = set.FindScalar("ay");
  const std::vector<double>* az = set.FindScalar("az");
  const bool approaches = ax != nullptr || ay != nullptr || az != nullptr;
  if (approaches && (ax == nullptr || ay == nullptr || az == nullptr)) {
    return Status::BadInput(Where{.file = source, .line = 1, .field = "ax,ay,az"},
                            "give all three approach columns or none");
  }
  PlanWithApproaches out;
  std::set<std::int64_t> ids;
  for (std::size_t i = 0; i < set.points.size(); ++i) {
    const long line = static_cast<long>(i) + 2;  // after the header
    metrology::ProbePoint p;
    p.id = set.ids[i];
    p.u = (*u)[i];
    p.v = (*v)[i];
    p.point = set.points[i];
    p.normal = set.normals[i];
    if (std::abs(p.normal.norm() - 1.0) > 1e-5) {
      return Status::BadInput(Where{.file = source, .line = line, .field = "nx,ny,nz"},
                              "the normal is not a unit vector");
    }
    if (!ids.insert(p.id).second) {
      return Status::BadInput(Where{.file = source, .line = line, .field = "id"},
                              "duplicated id " + std::to_string(p.id));
    }
    out.plan.points.push_back(p);
    if (approaches) {
      const Eigen::Vector3d a((*ax)[i], (*ay)[i], (*az)[i]);
      if (std::abs(a.norm() - 1.0) > 1e-5) {
        return Status::BadInput(Where{.file = source, .line = line, .field = "ax,ay,az"},
                                "the approach is not a unit vector");
      }
      if (-a.dot(p.normal) < 0.2) {
        return Status::BadInput(Where{.file = source, .line = line, .field = "ax,ay,az"},
                                "the approach must point into the surface, within 78 degrees of -n");
      }
      out.approaches.push_back(a);
    }
  }
  if (out.plan.points.empty()) return Status::BadInput(Where{.file = source}, "the plan has no points");
  return out;
}

// "3/9: retrieval" -> "retrieval": the name the stage timer gets.
std::string StageName(const std::string& stage) {
  const auto colon = stage.find(':');
  return colon == std::string::npos ? stage : stage.substr(colon + 2);
}

}  // namespace

RunFolderWriter::RunFolderWriter(fs::path out, StageTimer on_stage)
    : out_(std::move(out)), on_stage_(std::move(on_stage)) {}

RunFolderWriter::~RunFolderWriter() {
  if (logging_) log::StopFileLog();
}

Status RunFolderWriter::Open(bool force, const std::string& what, const std::vector<NamedPath>& inputs) {
  if (out_.empty()) return Status::BadInput(Where{.field = "--out"}, "no run folder given");
  fs::path partial = out_;
  partial += ".partial";
  std::error_code ec;
  std::string previous_stage;
  if (OutputFolder::HasMarker(partial) && fs::exists(partial / "status.json", ec)) {
    auto previous = ReadJsonFile(partial / "status.json");
    previous_stage = previous.ok() ? previous->value("stage", "?") : "?";
  }
  bool had_partial = false;
  FL_RETURN_IF_ERROR(folder_.Open(out_, "--out", "run", inputs, force, &had_partial));
  if (had_partial && !previous_stage.empty()) {
    log::Warn("an incomplete run of '{}' was found in {} (stopped at: {}); starting it again", what, partial.string(),
              previous_stage);
  }
  FL_RETURN_IF_ERROR(log::StartFileLog(dir() / "formloop.log"));
  logging_ = true;
  return Status::Ok();
}

std::string RunFolderWriter::Relative(const fs::path& path) const { return fs::relative(path, dir()).string(); }

Status RunFolderWriter::Begin(const std::string& stage) {
  EndStage();
  stage_ = stage;
  start_ = std::chrono::steady_clock::now();
  return WriteJsonFile(dir() / "status.json", {{"state", "incomplete"}, {"stage", stage}});
}

void RunFolderWriter::EndStage() {
  if (stage_.empty()) return;
  const double s = std::chrono::duration<double>(std::chrono::steady_clock::now() - start_).count();
  if (on_stage_) on_stage_(StageName(stage_), s);
  stage_.clear();
}

Status RunFolderWriter::MakeFolder(const fs::path& relative) const { return MakeDirectories(dir() / relative); }

Status RunFolderWriter::WriteJson(const fs::path& relative, const Json& value) const {
  if (relative.has_parent_path()) FL_RETURN_IF_ERROR(MakeFolder(relative.parent_path()));
  return WriteJsonFile(dir() / relative, value);
}

Status RunFolderWriter::WriteText(const fs::path& relative, std::string_view text) const {
  if (relative.has_parent_path()) FL_RETURN_IF_ERROR(MakeFolder(relative.parent_path()));
  return WriteFileAtomic(dir() / relative, text);
}

Status RunFolderWriter::MarkComplete() const { return WriteJsonFile(dir() / "status.json", {{"state", "complete"}}); }

Status RunFolderWriter::Close(const Status& status, const std::string& what) {
  if (logging_) log::StopFileLog();
  logging_ = false;
  if (!status.ok()) {
    const Status moved = folder_.Fail();
    const std::string where = moved.ok() ? folder_.failed().string() : dir().string();
    return status.WithContext(what + " (log and partial outputs in " + where + ")");
  }
  return folder_.Commit();
}

Result<PlanWithApproaches> ReadPlanFile(const fs::path& path) {
  if (path.extension() == ".csv") return ReadPlanCsv(path);
  return ReadPlanJson(path);
}

namespace {
constexpr const char* kRunFolderFiles[] = {"inputs/part.json", "surface/Q.step", "toolpath/toolpath.csv",
                                           "toolpath/probing_plan.json"};
// Written by the pipeline only when the plan has tilted approaches (the same points, with ax, ay, az).
constexpr const char* kApproachesFile = "toolpath/probing_plan.csv";

// The approaches of the run's tilted plan, checked to be of the same points as the JSON plan.
Result<std::vector<Eigen::Vector3d>> ReadRunApproaches(const fs::path& dir, const metrology::ProbingPlan& plan) {
  if (!fs::exists(dir / kApproachesFile)) return std::vector<Eigen::Vector3d>{};
  FL_ASSIGN_OR_RETURN(const PlanWithApproaches csv, ReadPlanCsv(dir / kApproachesFile));
  const std::string source = (dir / kApproachesFile).string();
  const std::string fix =
      "give the run folder as `formloop run` wrote it (probing_plan.csv and probing_plan.json "
      "are written together)";
  if (csv.approaches.empty()) {
    return Status::BadInput(Where{.file = source, .line = 1, .field = "ax,ay,az"}, "has no approach columns", fix);
  }
  if (csv.plan.points.size() != plan.points.size()) {
    return Status::BadInput(Where{.file = source},
                            "has " + std::to_string(csv.plan.points.size()) + " points, toolpath/probing_plan.json " +
                                std::to_string(plan.points.size()),
                            fix);
  }
  for (std::size_t i = 0; i < plan.points.size(); ++i) {
    if (csv.plan.points[i].id != plan.points[i].id || (csv.plan.points[i].point - plan.points[i].point).norm() > 1e-6) {
      return Status::BadInput(Where{.file = source, .line = static_cast<long>(i) + 2},
                              "point id " + std::to_string(csv.plan.points[i].id) +
                                  " is not the point of toolpath/probing_plan.json in that row (id " +
                                  std::to_string(plan.points[i].id) + ")",
                              fix);
    }
  }
  return csv.approaches;
}
}  // namespace

std::vector<NamedPath> RunFolderInputs(const std::string& option, const fs::path& dir) {
  std::vector<NamedPath> inputs;
  if (dir.empty()) return inputs;
  for (const char* file : kRunFolderFiles) inputs.push_back({option, dir / file});
  if (fs::exists(dir / kApproachesFile)) inputs.push_back({option, dir / kApproachesFile});
  return inputs;
}

Result<RunFolder> ReadRunFolder(const fs::path& dir) {
  if (!fs::is_directory(dir)) {
    return Status::NotFound("run folder '" + dir.string() +
                            "' does not exist. Fix: give the --out folder of `formloop run`");
  }
  RunFolder run;
  run.dir = dir;
  for (const char* file : kRunFolderFiles) {
    if (!fs::exists(dir / file)) {
      return Status::NotFound("run folder '" + dir.string() + "' has no " + file +
                              ". Fix: give a folder written by `formloop run`");
    }
  }
  FL_ASSIGN_OR_RETURN(run.part, ReadPart(dir / "inputs" / "part.json"));
  FL_ASSIGN_OR_RETURN(const recon::CadFace face, recon::ReadCadFace(dir / "surface" / "Q.step", {}));
  run.q = face.surface;
  FL_ASSIGN_OR_RETURN(run.toolpath, nc::ReadToolpathFile(dir / "toolpath" / "toolpath.csv"));
  run.cutter_locations = nc::CutterLocationsOf(run.toolpath);
  // The tool that cut the part is the tool path's (the planner may choose another than the part's).
  run.part.toolpath.tool = run.toolpath.options.tool;
  FL_ASSIGN_OR_RETURN(const PlanWithApproaches plan, ReadPlanJson(dir / "toolpath" / "probing_plan.json"));
  run.plan = plan.plan;
  FL_ASSIGN_OR_RETURN(run.approaches, ReadRunApproaches(dir, run.plan));
  return run;
}

}  // namespace formloop::app
