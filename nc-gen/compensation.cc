#include "nc-gen/compensation.h"

#include <algorithm>
#include <cmath>

#include "core/atomic_file.h"
#include "core/point_io.h"

namespace formloop::nc {
namespace {

std::vector<const ProgramMove*> FeedMoves(const std::vector<ProgramMove>& moves) {
  std::vector<const ProgramMove*> feeds;
  for (const auto& m : moves) {
    if (!m.rapid) feeds.push_back(&m);
  }
  return feeds;
}

}  // namespace

Status CompensationOptions::Validate() const {
  if (!(max_offset_um > 0)) return Status::BadInput(Where{.field = "compensation.max_offset_um"}, "must be > 0");
  return Status::Ok();
}

Result<Compensation> CompensateToolpath(const Toolpath& nominal, const SystematicField& systematic,
                                        const std::string& source, const CompensationOptions& options) {
  FL_RETURN_IF_ERROR(options.Validate());
  Compensation result;
  result.path = nominal;
  result.source = source;
  for (std::size_t k = 0; k < nominal.points.size(); ++k) {
    ClPoint& cl = result.path.points[k];
    const double ds_mm = systematic(cl.u, cl.v);
    if (std::abs(ds_mm) * 1e3 > options.max_offset_um) {
      return Status::SafetyLimit("compensation offset " + FormatFixed(ds_mm * 1e3, 1) + " um at CL point " +
                                 std::to_string(k) + " (pass " + std::to_string(cl.pass) + ") exceeds the limit " +
                                 FormatFixed(options.max_offset_um, 1) +
                                 " um; no compensated program was written. Fix: check the measurement, or raise "
                                 "compensation.max_offset_um if the error is real");
    }
    cl.cc = nominal.points[k].cc - ds_mm * cl.normal;
    CompensationEntry entry;
    entry.cl_index = k;
    entry.nominal_tip = nominal.points[k].tip;
    entry.systematic_um = ds_mm * 1e3;
    result.entries.push_back(entry);
  }
  UpdateCutterLocations(&result.path);
  for (auto& entry : result.entries) {
    entry.offset_mm = result.path.points[entry.cl_index].tip - entry.nominal_tip;
    result.max_offset_um = std::max(result.max_offset_um, 1e3 * entry.offset_mm.norm());
  }
  // Keep the nominal program's safe Z so the rapids do not change.
  result.path.safe_z_mm = std::max(result.path.safe_z_mm, nominal.safe_z_mm);
  return result;
}

Status AssignProgramLines(const std::vector<ProgramMove>& nominal, const std::vector<ProgramMove>& compensated,
                          Compensation* compensation) {
  const auto a = FeedMoves(nominal), b = FeedMoves(compensated);
  if (a.size() != compensation->entries.size() || b.size() != compensation->entries.size()) {
    return Status::Internal("programs have " + std::to_string(a.size()) + " and " + std::to_string(b.size()) +
                            " feed moves for " + std::to_string(compensation->entries.size()) + " CL points");
  }
  for (std::size_t k = 0; k < a.size(); ++k) {
    compensation->entries[k].nominal_line = a[k]->line;
    compensation->entries[k].compensated_line = b[k]->line;
  }
  return Status::Ok();
}

Status WriteSideFile(const std::filesystem::path& path, const Compensation& compensation) {
  std::string text = "# formloop compensation side file: per CL point, the nominal tip, the applied offset, its source\n";
  text += "# source: " + compensation.source + "\n";
  text += "cl_index,pass,nominal_line,compensated_line,nominal_x,nominal_y,nominal_z,offset_x,offset_y,offset_z,ds_um\n";
  for (const auto& e : compensation.entries) {
    const ClPoint& cl = compensation.path.points[e.cl_index];
    text += std::to_string(e.cl_index) + "," + std::to_string(cl.pass) + "," + std::to_string(e.nominal_line) + "," +
            std::to_string(e.compensated_line);
    for (int a = 0; a < 3; ++a) text += "," + FormatFixed(e.nominal_tip[a], 6);
    for (int a = 0; a < 3; ++a) text += "," + FormatFixed(e.offset_mm[a], 6);
    text += "," + FormatFixed(e.systematic_um, 4) + "\n";
  }
  return WriteFileAtomic(path, text);
}

Result<double> VerifyCompensation(const std::vector<ProgramMove>& nominal, const std::vector<ProgramMove>& compensated,
                                  const Compensation& compensation) {
  const auto a = FeedMoves(nominal), b = FeedMoves(compensated);
  if (a.size() != b.size() || a.size() != compensation.entries.size()) {
    return Status::Failed("compensation check: the programs have " + std::to_string(a.size()) + " and " +
                          std::to_string(b.size()) + " feed moves, the side file " +
                          std::to_string(compensation.entries.size()) + " entries");
  }
  double worst = 0;
  for (std::size_t k = 0; k < a.size(); ++k) {
    const Eigen::Vector3d program_offset = b[k]->tip - a[k]->tip;
    worst = std::max(worst, 1e3 * (program_offset - compensation.entries[k].offset_mm).norm());
  }
  return worst;
}

}  // namespace formloop::nc
