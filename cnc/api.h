#pragma once
// The calls a controller API offers (read and write a consecutive range of macro variables, read and
// write an offset) as data, and a MacroTransport built on one function that carries such a call:
// the in-process VirtualLink and the TcpTransport differ only in how a call travels.

#include <optional>
#include <string>
#include <vector>

#include "cnc/transport.h"
#include "core/status.h"

namespace formloop::cnc {

struct ApiRequest {
  enum class Op { kReadRange, kWriteRange, kReadOffset, kWriteOffset };
  Op op = Op::kReadRange;
  int start = 0;
  int count = 0;
  std::vector<double> values;
  std::string offset;
  double value = 0;
};
struct ApiResponse {
  bool ok = true;
  std::string error;  // "EW_BUSY: ...": the controller refused the call
  std::vector<MacroValue> values;
  double value = 0;
};
enum class Disposition { kAnswer, kDropConnection, kHalfOpen };

// MacroTransport over Call(): IoError from Call means the connection is gone; an answer with ok =
// false becomes Failed (the controller refused the call).
class RequestTransport : public MacroTransport {
 public:
  Result<std::vector<MacroValue>> ReadRange(int start, int count) override;
  Status WriteRange(int start, const std::vector<double>& values) override;
  Result<double> ReadOffset(const OffsetAddress& offset) override;
  Status WriteOffset(const OffsetAddress& offset, double value_mm) override;

 protected:
  virtual Result<ApiResponse> Call(const ApiRequest& request) = 0;
};

}  // namespace formloop::cnc
