#pragma once
// The collector's journal (spec/tuning-and-link.md §7.4 K3, K6): every point is appended and fsync'd
// before it is acknowledged, so a collector killed at any moment loses nothing, and the journal tells
// the restarted collector where it stands.
//
// Text, one record per line, each line ending in " *" and the CRC-32 (IEEE) of what precedes it:
//   formloop-link-journal 1
//   OPEN <q> <t_s>                                      a run's first point opens its session
//   P <q> <id> <data0> <data1> <data2> <vx> <vy> <vz> <fx> <fy> <fz> <t_s>
//   ERR <q> <code> <text>                               GAP, PROTOCOL_ERROR, LOST_POINTS, ...
//   WARN <q> <code> <text>                              DUPLICATE, VISIBILITY_TIMEOUT, OVERFLOW, ...
//   END <q> <n> <status>                                FINISHED seen: COMPLETE or INCOMPLETE
//   ABORT <q> <reason>                                  the run was restarted or stopped
// Numbers are written so they read back exactly. A last line without its newline or with a wrong
// CRC is the write a kill interrupted: it is dropped (and cut off before the next append); a bad line
// anywhere else is corruption and an error naming the line.

#include <array>
#include <filesystem>
#include <string>
#include <vector>

#include "cnc/handshake.h"
#include "core/status.h"

namespace formloop::cnc {

struct JournalPoint {
  int id = 0;
  std::array<double, 3> data{};  // D, 0, 0 (packed) or v_x, v_y, v_z (split), as read
  DecodedPoint decoded;
  double t_s = 0;
};

enum class SessionStatus { kOpen, kComplete, kIncomplete, kAborted };
const char* SessionStatusName(SessionStatus status);

struct Session {
  double q = 0;
  double opened_t_s = 0;
  SessionStatus status = SessionStatus::kOpen;
  std::vector<JournalPoint> points;
  std::vector<std::string> errors;    // "GAP: ...", each with its code first
  std::vector<std::string> warnings;  // "DUPLICATE: ..."
  int finished_count = 0;             // N of FINISHED
  std::string abort_reason;
  int last_id() const { return points.empty() ? 0 : points.back().id; }
  bool ended() const { return status != SessionStatus::kOpen; }
};

class Journal {
 public:
  Journal() = default;
  Journal(Journal&&) noexcept;
  Journal& operator=(Journal&&) noexcept;
  Journal(const Journal&) = delete;
  Journal& operator=(const Journal&) = delete;
  ~Journal();

  // Opens (creates) the journal and replays it. fsync: flush every record to the disk before
  // returning (off only for throughput measurements on a RAM disk).
  static Result<Journal> Open(const std::filesystem::path& path, bool fsync = true);
  // Reads a journal without opening it for writing (reports, tests).
  static Result<std::vector<Session>> Read(const std::filesystem::path& path);

  Status OpenSession(double q, double t_s);
  Status AddPoint(const JournalPoint& point);  // to the open session
  Status AddError(const std::string& code, const std::string& text);
  Status AddWarning(const std::string& code, const std::string& text);
  Status End(int finished_count, SessionStatus status);
  Status Abort(const std::string& reason);

  const std::vector<Session>& sessions() const { return sessions_; }
  // The open session, or nullptr.
  const Session* open() const;
  const std::filesystem::path& path() const { return path_; }

 private:
  Status Append(const std::string& record);
  Status Apply(const std::string& record, long line, const std::string& file);

  std::filesystem::path path_;
  int fd_ = -1;
  bool fsync_ = true;
  std::vector<Session> sessions_;
};

}  // namespace formloop::cnc
