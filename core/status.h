#pragma once
// Status and Result<T>: the error vocabulary at every module boundary.
//
// A message says what went wrong with which input and what to do about it. Use Where to name the
// input (file, line, field) and the fix:
//
//   return Status::BadInput(Where{.file = path, .line = 12, .field = "z"},
//                           "value 'abc' is not a number", "write a decimal number such as 1.25");
//   -> "points.csv:12: field 'z': value 'abc' is not a number. Fix: write a decimal number such as 1.25"
//
// Exit codes of the CLI follow from the code (docs/ARCHITECTURE.md): bad input and usage -> 2,
// everything else that fails -> 1.

#include <optional>
#include <string>
#include <type_traits>
#include <utility>
#include <variant>

namespace formloop {

enum class StatusCode {
  kOk = 0,
  kBadInput,     // the user's input is wrong (file content, option value, missing field): exit 2
  kNotFound,     // a named file, surface, table or id does not exist: exit 2
  kIoError,      // the operating system refused a read or write: exit 1
  kSafetyLimit,  // an output would exceed a configured machine limit and is refused: exit 1
  kFailed,       // the job ran but did not reach its goal (e.g. out of tolerance with --strict): exit 1
  kInternal,     // a broken invariant or a library failure that is not the user's fault: exit 1
};

const char* StatusCodeName(StatusCode code);

// Where an input problem sits. Every member is optional; set what you know.
struct Where {
  std::string file;   // path as the user gave it
  long line = 0;      // 1-based; 0 = unknown
  std::string field;  // column, JSON key path ("tool.radius_mm") or option name ("--out")
};

class [[nodiscard]] Status {
 public:
  Status() = default;  // ok
  Status(StatusCode code, std::string message) : code_(code), message_(std::move(message)) {}

  static Status Ok() { return Status(); }
  // what: the problem; fix: what the user should do (may be empty when obvious).
  static Status BadInput(const Where& where, const std::string& what, const std::string& fix = "");
  static Status BadInput(const std::string& message) { return {StatusCode::kBadInput, message}; }
  static Status NotFound(const std::string& message) { return {StatusCode::kNotFound, message}; }
  static Status IoError(const std::string& message) { return {StatusCode::kIoError, message}; }
  static Status SafetyLimit(const std::string& message) { return {StatusCode::kSafetyLimit, message}; }
  static Status Failed(const std::string& message) { return {StatusCode::kFailed, message}; }
  static Status Internal(const std::string& message) { return {StatusCode::kInternal, message}; }

  bool ok() const { return code_ == StatusCode::kOk; }
  StatusCode code() const { return code_; }
  const std::string& message() const { return message_; }
  // "bad input: <message>"
  std::string ToString() const;
  // Prefixes the message with a context such as the stage name: "fit: <message>". No-op when ok.
  Status WithContext(const std::string& context) const;
  // 0 ok, 2 bad input / not found, 1 otherwise.
  int ExitCode() const;

 private:
  StatusCode code_ = StatusCode::kOk;
  std::string message_;
};

// Formats a Where as "file:line: field 'f': " (parts that are unknown are left out).
std::string FormatWhere(const Where& where);

// Either a value or a non-ok Status.
template <typename T>
class [[nodiscard]] Result {
 public:
  Result(T value) : data_(std::move(value)) {}        // NOLINT(google-explicit-constructor)
  Result(Status status) : data_(std::move(status)) {  // NOLINT(google-explicit-constructor)
    if (std::get<Status>(data_).ok()) {
      data_ = Status::Internal("Result constructed from an ok Status without a value");
    }
  }

  bool ok() const { return std::holds_alternative<T>(data_); }
  const Status& status() const {
    static const Status kOk;
    return ok() ? kOk : std::get<Status>(data_);
  }
  T& value() & { return std::get<T>(data_); }
  const T& value() const& { return std::get<T>(data_); }
  T&& value() && { return std::get<T>(std::move(data_)); }
  T& operator*() & { return value(); }
  const T& operator*() const& { return value(); }
  T* operator->() { return &value(); }
  const T* operator->() const { return &value(); }

 private:
  std::variant<T, Status> data_;
};

}  // namespace formloop

#define FL_CONCAT_INNER_(a, b) a##b
#define FL_CONCAT_(a, b) FL_CONCAT_INNER_(a, b)

// Returns the Status from the enclosing function when expr is not ok.
#define FL_RETURN_IF_ERROR(expr)             \
  do {                                       \
    ::formloop::Status fl_status_ = (expr);  \
    if (!fl_status_.ok()) return fl_status_; \
  } while (false)

// FL_ASSIGN_OR_RETURN(auto x, ComputeX()); returns the Status when the Result is not ok.
#define FL_ASSIGN_OR_RETURN(lhs, expr) FL_ASSIGN_OR_RETURN_IMPL_(FL_CONCAT_(fl_result_, __LINE__), lhs, expr)
#define FL_ASSIGN_OR_RETURN_IMPL_(tmp, lhs, expr) \
  auto tmp = (expr);                              \
  if (!tmp.ok()) return tmp.status();             \
  lhs = std::move(tmp).value()
