#include "cnc/wire.h"

#include <charconv>
#include <sstream>
#include <vector>

#include "core/point_io.h"

namespace formloop::cnc {

namespace {

constexpr int kMaxRange = 1000;  // values in one call (FOCAS reads at most a few hundred at a time)

std::vector<std::string> Split(const std::string& line) {
  std::vector<std::string> out;
  std::istringstream in(line);
  std::string token;
  while (in >> token) out.push_back(token);
  return out;
}

bool ParseU64(const std::string& s, std::uint64_t* out) {
  const auto [p, ec] = std::from_chars(s.data(), s.data() + s.size(), *out);
  return ec == std::errc() && p == s.data() + s.size();
}

bool ParseInt(const std::string& s, int* out) {
  const auto [p, ec] = std::from_chars(s.data(), s.data() + s.size(), *out);
  return ec == std::errc() && p == s.data() + s.size();
}

}  // namespace

std::string EncodeRequest(std::uint64_t seq, const ApiRequest& r) {
  std::string line = std::to_string(seq);
  switch (r.op) {
    case ApiRequest::Op::kReadRange:
      line += " RR " + std::to_string(r.start) + " " + std::to_string(r.count);
      break;
    case ApiRequest::Op::kWriteRange:
      line += " WR " + std::to_string(r.start);
      for (double v : r.values) line += " " + FormatExact(v);
      break;
    case ApiRequest::Op::kReadOffset:
      line += " RO " + r.offset;
      break;
    case ApiRequest::Op::kWriteOffset:
      line += " WO " + r.offset + " " + FormatExact(r.value);
      break;
  }
  return line + "\n";
}

Status DecodeRequest(const std::string& line, std::uint64_t* seq, ApiRequest* r) {
  const auto t = Split(line);
  const auto bad = [&](const std::string& what) { return Status::BadInput("request '" + line + "': " + what); };
  if (t.size() < 2 || !ParseU64(t[0], seq)) return bad("expected '<seq> <op> ...'");
  *r = ApiRequest{};
  if (t[1] == "RR") {
    r->op = ApiRequest::Op::kReadRange;
    if (t.size() != 4 || !ParseInt(t[2], &r->start) || !ParseInt(t[3], &r->count)) return bad("RR <start> <count>");
    if (r->start < 0 || r->count < 1 || r->count > kMaxRange) return bad("address ≥ 0 and 1..1000 values");
    return Status::Ok();
  }
  if (t[1] == "WR") {
    r->op = ApiRequest::Op::kWriteRange;
    if (t.size() < 4 || !ParseInt(t[2], &r->start) || r->start < 0 ||
        t.size() - 3 > static_cast<std::size_t>(kMaxRange)) {
      return bad("WR <start> <v1> ..");
    }
    for (std::size_t k = 3; k < t.size(); ++k) {
      double v = 0;
      if (!ParseDouble(t[k], &v)) return bad("value '" + t[k] + "' is not a number");
      r->values.push_back(v);
    }
    return Status::Ok();
  }
  if (t[1] == "RO" || t[1] == "WO") {
    r->op = t[1] == "RO" ? ApiRequest::Op::kReadOffset : ApiRequest::Op::kWriteOffset;
    if (t.size() != (t[1] == "RO" ? 3u : 4u)) return bad(t[1] == "RO" ? "RO <offset>" : "WO <offset> <value_mm>");
    FL_RETURN_IF_ERROR(ParseOffsetAddress(t[2]).status());
    r->offset = t[2];
    if (t[1] == "WO" && !ParseDouble(t[3], &r->value)) return bad("value '" + t[3] + "' is not a number");
    return Status::Ok();
  }
  return bad("unknown operation '" + t[1] + "'");
}

std::string EncodeResponse(std::uint64_t seq, const ApiRequest& request, const ApiResponse& response) {
  std::string line = std::to_string(seq);
  if (!response.ok) return line + " ERR " + response.error + "\n";
  line += " OK";
  if (request.op == ApiRequest::Op::kReadRange) {
    for (const auto& v : response.values) line += " " + (v ? FormatExact(*v) : std::string("-"));
  } else if (request.op == ApiRequest::Op::kReadOffset) {
    line += " " + FormatExact(response.value);
  }
  return line + "\n";
}

Status DecodeResponse(const std::string& line, const ApiRequest& request, std::uint64_t* seq, ApiResponse* response) {
  const auto t = Split(line);
  const auto bad = [&](const std::string& what) { return Status::IoError("malformed answer '" + line + "': " + what); };
  if (t.size() < 2 || !ParseU64(t[0], seq)) return bad("expected '<seq> OK|ERR ...'");
  *response = ApiResponse{};
  if (t[1] == "ERR") {
    response->ok = false;
    const auto at = line.find("ERR");
    response->error = line.substr(at + 4);
    return Status::Ok();
  }
  if (t[1] != "OK") return bad("expected OK or ERR");
  if (request.op == ApiRequest::Op::kReadRange) {
    if (t.size() != static_cast<std::size_t>(request.count) + 2) return bad("wrong number of values");
    for (std::size_t k = 2; k < t.size(); ++k) {
      if (t[k] == "-") {
        response->values.emplace_back(std::nullopt);
        continue;
      }
      double v = 0;
      if (!ParseDouble(t[k], &v)) return bad("value '" + t[k] + "' is not a number");
      response->values.emplace_back(v);
    }
  } else if (request.op == ApiRequest::Op::kReadOffset) {
    if (t.size() != 3 || !ParseDouble(t[2], &response->value)) return bad("expected one value");
  } else if (t.size() != 2) {
    return bad("unexpected values after OK");
  }
  return Status::Ok();
}

}  // namespace formloop::cnc
