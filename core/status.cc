#include "core/status.h"

namespace formloop {

const char* StatusCodeName(StatusCode code) {
  switch (code) {
    case StatusCode::kOk:
      return "ok";
    case StatusCode::kBadInput:
      return "bad input";
    case StatusCode::kNotFound:
      return "not found";
    case StatusCode::kIoError:
      return "i/o error";
    case StatusCode::kSafetyLimit:
      return "refused (safety limit)";
    case StatusCode::kFailed:
      return "failed";
    case StatusCode::kInternal:
      return "internal error";
  }
  return "unknown";
}

std::string FormatWhere(const Where& where) {
  std::string out;
  if (!where.file.empty()) {
    out += where.file;
    if (where.line > 0) out += ":" + std::to_string(where.line);
    out += ": ";
  } else if (where.line > 0) {
    out += "line " + std::to_string(where.line) + ": ";
  }
  if (!where.field.empty()) out += "field '" + where.field + "': ";
  return out;
}

Status Status::BadInput(const Where& where, const std::string& what, const std::string& fix) {
  std::string message = FormatWhere(where) + what;
  if (!fix.empty()) message += ". Fix: " + fix;
  return {StatusCode::kBadInput, message};
}

std::string Status::ToString() const {
  if (ok()) return "ok";
  return std::string(StatusCodeName(code_)) + ": " + message_;
}

Status Status::WithContext(const std::string& context) const {
  if (ok()) return *this;
  return {code_, context + ": " + message_};
}

int Status::ExitCode() const {
  switch (code_) {
    case StatusCode::kOk:
      return 0;
    case StatusCode::kBadInput:
    case StatusCode::kNotFound:
      return 2;
    default:
      return 1;
  }
}

}  // namespace formloop
