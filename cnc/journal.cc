#include "cnc/journal.h"

#include <fcntl.h>
#include <unistd.h>

#include <array>
#include <cerrno>
#include <cstring>
#include <functional>
#include <optional>
#include <sstream>

#include "core/atomic_file.h"
#include "core/point_io.h"

namespace formloop::cnc {

namespace {

constexpr const char* kHeader = "formloop-link-journal 1";

std::uint32_t Crc32(const std::string& s) {
  static const std::array<std::uint32_t, 256> table = [] {
    std::array<std::uint32_t, 256> t{};
    for (std::uint32_t i = 0; i < 256; ++i) {
      std::uint32_t c = i;
      for (int k = 0; k < 8; ++k) c = (c & 1) ? 0xEDB88320u ^ (c >> 1) : c >> 1;
      t[i] = c;
    }
    return t;
  }();
  std::uint32_t c = 0xFFFFFFFFu;
  for (unsigned char ch : s) c = table[(c ^ ch) & 0xFF] ^ (c >> 8);
  return c ^ 0xFFFFFFFFu;
}

std::string Hex8(std::uint32_t v) {
  static const char* digits = "0123456789abcdef";
  std::string out(8, '0');
  for (int k = 7; k >= 0; --k, v >>= 4) out[k] = digits[v & 0xF];
  return out;
}

std::string Seal(const std::string& record) { return record + " *" + Hex8(Crc32(record)) + "\n"; }

// The record of a sealed line, or nullopt when the CRC does not match.
std::optional<std::string> Unseal(const std::string& line) {
  const auto star = line.rfind(" *");
  if (star == std::string::npos || line.size() != star + 10) return std::nullopt;
  const std::string record = line.substr(0, star);
  if (Hex8(Crc32(record)) != line.substr(star + 2)) return std::nullopt;
  return record;
}

std::vector<std::string> Fields(const std::string& record, std::size_t max_fields) {
  std::vector<std::string> out;
  std::size_t pos = 0;
  while (pos < record.size() && out.size() + 1 < max_fields) {
    const auto space = record.find(' ', pos);
    if (space == std::string::npos) break;
    out.push_back(record.substr(pos, space - pos));
    pos = space + 1;
  }
  out.push_back(record.substr(pos));
  return out;
}

}  // namespace

const char* SessionStatusName(SessionStatus status) {
  switch (status) {
    case SessionStatus::kOpen:
      return "OPEN";
    case SessionStatus::kComplete:
      return "COMPLETE";
    case SessionStatus::kIncomplete:
      return "INCOMPLETE";
    case SessionStatus::kAborted:
      return "ABORTED";
  }
  return "?";
}

Journal::Journal(Journal&& o) noexcept
    : path_(std::move(o.path_)), fd_(o.fd_), fsync_(o.fsync_), sessions_(std::move(o.sessions_)) {
  o.fd_ = -1;
}

Journal& Journal::operator=(Journal&& o) noexcept {
  if (this != &o) {
    if (fd_ >= 0) ::close(fd_);
    path_ = std::move(o.path_);
    fd_ = o.fd_;
    fsync_ = o.fsync_;
    sessions_ = std::move(o.sessions_);
    o.fd_ = -1;
  }
  return *this;
}

Journal::~Journal() {
  if (fd_ >= 0) ::close(fd_);
}

const Session* Journal::open() const {
  return !sessions_.empty() && !sessions_.back().ended() ? &sessions_.back() : nullptr;
}

Status Journal::Apply(const std::string& record, long line, const std::string& file) {
  const auto bad = [&](const std::string& what) {
    return Status::BadInput(Where{.file = file, .line = line}, what,
                            "the journal is written only by `formloop link collect`; restore it or start a new "
                            "collection with a new --journal");
  };
  const std::string type = record.substr(0, record.find(' '));
  const auto number = [&](const std::string& text, double* out) { return ParseDouble(text, out); };
  if (type == "OPEN") {
    const auto f = Fields(record, 3);
    Session s;
    if (f.size() != 3 || !number(f[1], &s.q) || !number(f[2], &s.opened_t_s)) return bad("malformed OPEN record");
    if (open() != nullptr) return bad("OPEN while a session is still open");
    sessions_.push_back(s);
    return Status::Ok();
  }
  Session* s = sessions_.empty() ? nullptr : &sessions_.back();
  if (s == nullptr) return bad(type + " before any OPEN");
  if (type == "P") {
    const auto f = Fields(record, 13);
    if (f.size() != 13) return bad("malformed point record");
    JournalPoint p;
    double q = 0, id = 0, vx = 0, vy = 0, vz = 0, fx = 0, fy = 0, fz = 0;
    if (!number(f[1], &q) || !number(f[2], &id) || !number(f[3], &p.data[0]) || !number(f[4], &p.data[1]) ||
        !number(f[5], &p.data[2]) || !number(f[6], &vx) || !number(f[7], &vy) || !number(f[8], &vz) ||
        !number(f[9], &fx) || !number(f[10], &fy) || !number(f[11], &fz) || !number(f[12], &p.t_s)) {
      return bad("malformed point record");
    }
    if (s->ended() || q != s->q) return bad("point for a session that is not open");
    p.id = static_cast<int>(id);
    p.decoded.v = {static_cast<int>(vx), static_cast<int>(vy), static_cast<int>(vz)};
    p.decoded.flags = {static_cast<AxisFlag>(static_cast<int>(fx)), static_cast<AxisFlag>(static_cast<int>(fy)),
                       static_cast<AxisFlag>(static_cast<int>(fz))};
    if (p.id <= s->last_id())
      return bad("point id " + std::to_string(p.id) + " does not follow " + std::to_string(s->last_id()));
    s->points.push_back(p);
    return Status::Ok();
  }
  if (type == "ERR" || type == "WARN") {
    const auto f = Fields(record, 4);
    if (f.size() != 4) return bad("malformed " + type + " record");
    (type == "ERR" ? s->errors : s->warnings).push_back(f[2] + ": " + f[3]);
    return Status::Ok();
  }
  if (type == "END") {
    const auto f = Fields(record, 4);
    double n = 0;
    if (f.size() != 4 || !number(f[2], &n)) return bad("malformed END record");
    if (s->ended()) return bad("END of a session that already ended");
    s->finished_count = static_cast<int>(n);
    s->status = f[3] == "COMPLETE" ? SessionStatus::kComplete : SessionStatus::kIncomplete;
    return Status::Ok();
  }
  if (type == "ABORT") {
    const auto f = Fields(record, 3);
    if (f.size() != 3) return bad("malformed ABORT record");
    if (s->ended()) return bad("ABORT of a session that already ended");
    s->status = SessionStatus::kAborted;
    s->abort_reason = f[2];
    return Status::Ok();
  }
  return bad("unknown record type '" + type + "'");
}

namespace {

// Replays `text`; *good_bytes receives the length of the intact prefix.
Status Replay(const std::string& text, const std::string& file, std::size_t* good_bytes,
              const std::function<Status(const std::string&, long)>& apply) {
  std::size_t pos = 0;
  long line = 0;
  *good_bytes = 0;
  while (pos < text.size()) {
    const auto nl = text.find('\n', pos);
    ++line;
    if (nl == std::string::npos) break;  // the last write was cut off by a kill: drop it
    const std::string raw = text.substr(pos, nl - pos);
    const bool last = nl + 1 == text.size();
    if (line == 1) {
      if (raw != kHeader) {
        return Status::BadInput(Where{.file = file, .line = 1},
                                "not a formloop link journal (first line '" + raw + "')",
                                "give --journal a new file name or a journal written by `formloop link collect`");
      }
    } else {
      const auto record = Unseal(raw);
      if (!record) {
        if (last) break;  // a torn final line
        return Status::BadInput(Where{.file = file, .line = line},
                                "the line's checksum does not match (the journal is corrupted)",
                                "restore the journal from a backup; the collector never edits old lines");
      }
      FL_RETURN_IF_ERROR(apply(*record, line));
    }
    pos = nl + 1;
    *good_bytes = pos;
  }
  return Status::Ok();
}

}  // namespace

Result<std::vector<Session>> Journal::Read(const std::filesystem::path& path) {
  FL_ASSIGN_OR_RETURN(const std::string text, ReadFile(path));
  Journal j;
  std::size_t good = 0;
  FL_RETURN_IF_ERROR(Replay(text, path.string(), &good,
                            [&](const std::string& r, long line) { return j.Apply(r, line, path.string()); }));
  return j.sessions_;
}

Result<Journal> Journal::Open(const std::filesystem::path& path, bool fsync) {
  Journal j;
  j.path_ = path;
  j.fsync_ = fsync;
  std::size_t good = 0;
  if (std::filesystem::exists(path)) {
    FL_ASSIGN_OR_RETURN(const std::string text, ReadFile(path));
    FL_RETURN_IF_ERROR(Replay(text, path.string(), &good,
                              [&](const std::string& r, long line) { return j.Apply(r, line, path.string()); }));
  }
  j.fd_ = ::open(path.c_str(), O_WRONLY | O_CREAT | O_CLOEXEC, 0644);
  if (j.fd_ < 0) return Status::IoError("cannot open the journal " + path.string() + ": " + std::strerror(errno));
  // Cut off a torn last write, then append after the intact part.
  if (::ftruncate(j.fd_, static_cast<off_t>(good)) != 0 || ::lseek(j.fd_, 0, SEEK_END) < 0) {
    return Status::IoError("cannot prepare the journal " + path.string() + ": " + std::strerror(errno));
  }
  if (good == 0) {
    const std::string header = std::string(kHeader) + "\n";
    if (::write(j.fd_, header.data(), header.size()) != static_cast<ssize_t>(header.size()) ||
        (fsync && ::fsync(j.fd_) != 0)) {
      return Status::IoError("cannot write the journal " + path.string() + ": " + std::strerror(errno));
    }
  }
  return j;
}

Status Journal::Append(const std::string& record) {
  FL_RETURN_IF_ERROR(Apply(record, 0, path_.string()));
  const std::string line = Seal(record);
  std::size_t done = 0;
  while (done < line.size()) {
    const ssize_t n = ::write(fd_, line.data() + done, line.size() - done);
    if (n < 0 && errno == EINTR) continue;
    if (n <= 0) return Status::IoError("cannot append to the journal " + path_.string() + ": " + std::strerror(errno));
    done += static_cast<std::size_t>(n);
  }
  if (fsync_ && ::fdatasync(fd_) != 0)
    return Status::IoError("cannot flush the journal " + path_.string() + ": " + std::strerror(errno));
  return Status::Ok();
}

Status Journal::OpenSession(double q, double t_s) { return Append("OPEN " + FormatExact(q) + " " + FormatExact(t_s)); }

Status Journal::AddPoint(const JournalPoint& p) {
  const Session* s = open();
  if (s == nullptr) return Status::Internal("journal: a point without an open session");
  std::string r = "P " + FormatExact(s->q) + " " + std::to_string(p.id);
  for (double d : p.data) r += " " + FormatExact(d);
  for (int v : p.decoded.v) r += " " + std::to_string(v);
  for (AxisFlag f : p.decoded.flags) r += " " + std::to_string(static_cast<int>(f));
  return Append(r + " " + FormatExact(p.t_s));
}

Status Journal::AddError(const std::string& code, const std::string& text) {
  if (sessions_.empty()) return Status::Internal("journal: an error without a session");
  return Append("ERR " + FormatExact(sessions_.back().q) + " " + code + " " + text);
}

Status Journal::AddWarning(const std::string& code, const std::string& text) {
  if (sessions_.empty()) return Status::Internal("journal: a warning without a session");
  return Append("WARN " + FormatExact(sessions_.back().q) + " " + code + " " + text);
}

Status Journal::End(int finished_count, SessionStatus status) {
  if (open() == nullptr) return Status::Internal("journal: END without an open session");
  return Append("END " + FormatExact(sessions_.back().q) + " " + std::to_string(finished_count) + " " +
                SessionStatusName(status));
}

Status Journal::Abort(const std::string& reason) {
  if (open() == nullptr) return Status::Internal("journal: ABORT without an open session");
  return Append("ABORT " + FormatExact(sessions_.back().q) + " " + reason);
}

}  // namespace formloop::cnc
