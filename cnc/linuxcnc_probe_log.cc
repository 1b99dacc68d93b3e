#include "cnc/linuxcnc_probe_log.h"

#include <charconv>
#include <cmath>
#include <set>
#include <sstream>

#include "core/atomic_file.h"
#include "core/point_io.h"

namespace formloop::cnc {
namespace {

constexpr const char* kHeader = "formloop probe log 1:";
constexpr double kAgreeMm = 1e-6;  // both files print six decimals of the same number

std::vector<std::string> Words(const std::string& line) {
  std::istringstream in(line);
  std::vector<std::string> words;
  for (std::string w; in >> w;) words.push_back(w);
  return words;
}

Result<double> Number(const std::string& word, const Where& where) {
  double v = 0;
  const char* end = word.data() + word.size();
  const auto r = std::from_chars(word.data(), end, v);
  if (r.ec != std::errc() || r.ptr != end || !std::isfinite(v)) {
    return Status::BadInput(where, "'" + word + "' is not a number");
  }
  return v;
}

}  // namespace

Result<metrology::ProbeLog> ReadLinuxCncProbeLog(const std::filesystem::path& log_file,
                                                 const std::filesystem::path& probe_file, int touches) {
  if (touches < 1) return Status::BadInput(Where{.field = "touches"}, "must be >= 1");
  FL_ASSIGN_OR_RETURN(const std::string text, ReadFile(log_file));
  metrology::ProbeLog log;
  log.source = log_file.string();
  std::istringstream in(text);
  std::string line;
  long line_no = 0;
  bool header = false, timed = false;
  std::set<std::int64_t> ids;
  while (std::getline(in, line)) {
    ++line_no;
    if (!line.empty() && line.back() == '\r') line.pop_back();
    if (line.find_first_not_of(" \t") == std::string::npos) continue;
    const Where where{.file = log_file.string(), .line = line_no};
    if (!header) {
      if (line.rfind(kHeader, 0) != 0) {
        return Status::BadInput(where, "does not start with '" + std::string(kHeader) + "'",
                                "give the (LOGOPEN) file of formloop's LinuxCNC probing program");
      }
      header = true;
      timed = line.find("t_s") != std::string::npos;
      continue;
    }
    const std::vector<std::string> w = Words(line);
    const std::size_t expected = timed ? 10 : 9;
    if (w.size() != expected || w[0] != "point") {
      return Status::BadInput(where, "expected 'point id x y z tripped ax ay az" + std::string(timed ? " t_s" : "") +
                                         "', got '" + line + "'");
    }
    std::vector<double> v;
    for (std::size_t k = 1; k < w.size(); ++k) {
      FL_ASSIGN_OR_RETURN(const double x, Number(w[k], where));
      v.push_back(x);
    }
    metrology::ProbeRecord r;
    r.id = static_cast<std::int64_t>(v[0]);
    if (r.id != v[0] || r.id < 1) return Status::BadInput(where, "point id '" + w[1] + "' is not a positive integer");
    if (!ids.insert(r.id).second) return Status::BadInput(where, "point " + w[1] + " is logged twice");
    if (v[4] != 1) {
      return Status::BadInput(where, "point " + w[1] + ": the probe did not trip (#5070 = " + w[5] + ")",
                              "check the search distance");
    }
    r.centre = Eigen::Vector3d(v[1], v[2], v[3]);
    const Eigen::Vector3d a(v[5], v[6], v[7]);
    if (!(std::abs(a.norm() - 1) <= metrology::kApproachUnitTolerance)) {
      return Status::BadInput(where, "point " + w[1] + ": approach vector is not a unit vector");
    }
    r.approach = a.normalized();
    r.t_s = timed ? v[8] : 0;
    r.line = line_no;
    log.records.push_back(r);
  }
  if (!header) return Status::BadInput(Where{.file = log_file.string()}, "is empty: the program logged nothing");
  if (probe_file.empty()) return log;

  // The controller's own record of every trip.
  FL_ASSIGN_OR_RETURN(const std::string trips_text, ReadFile(probe_file));
  std::vector<std::pair<long, Eigen::Vector3d>> trips;
  std::istringstream trips_in(trips_text);
  line_no = 0;
  while (std::getline(trips_in, line)) {
    ++line_no;
    const std::vector<std::string> w = Words(line);
    if (w.empty()) continue;
    const Where where{.file = probe_file.string(), .line = line_no};
    if (w.size() < 3) return Status::BadInput(where, "expected 'x y z ...', got '" + line + "'");
    Eigen::Vector3d p;
    for (int k = 0; k < 3; ++k) {
      FL_ASSIGN_OR_RETURN(p[k], Number(w[static_cast<std::size_t>(k)], where));
    }
    trips.emplace_back(line_no, p);
  }
  const std::size_t n = log.records.size();
  if (trips.size() != n * static_cast<std::size_t>(touches)) {
    return Status::BadInput(Where{.file = probe_file.string()},
                            "holds " + std::to_string(trips.size()) + " probe trips; " + std::to_string(n) +
                                " logged points with " + std::to_string(touches) + " touch(es) each make " +
                                std::to_string(n * static_cast<std::size_t>(touches)),
                            "give the (PROBEOPEN) file of the same run");
  }
  for (std::size_t i = 0; i < n; ++i) {
    const auto& [trip_line, p] = trips[(i + 1) * static_cast<std::size_t>(touches) - 1];
    const metrology::ProbeRecord& r = log.records[i];
    if ((p - r.centre).cwiseAbs().maxCoeff() > kAgreeMm) {
      return Status::BadInput(Where{.file = probe_file.string(), .line = trip_line},
                              "trip (" + FormatFixed(p.x(), 6) + ", " + FormatFixed(p.y(), 6) + ", " +
                                  FormatFixed(p.z(), 6) + ") disagrees with point " + std::to_string(r.id) + " of " +
                                  log_file.string() + ":" + std::to_string(r.line));
    }
  }
  return log;
}

}  // namespace formloop::cnc
