#include "cnc/virtual_link.h"

#include <memory>

namespace formloop::cnc {

Status VirtualLink::Connect() {
  if (!connected_) scheduler_->RunUntil(scheduler_->now_s() + options_.connect_time_s);
  connected_ = true;
  return Status::Ok();
}

Result<ApiResponse> VirtualLink::Call(const ApiRequest& request) {
  if (!connected_) return Status::IoError("not connected to the virtual controller");
  ++calls_;
  const double start = scheduler_->now_s();
  auto answer = std::make_shared<std::pair<ApiResponse, Disposition>>();
  auto arrived = std::make_shared<bool>(false);
  controller_->Submit(request, [answer, arrived](const ApiResponse& r, Disposition d) {
    *answer = {r, d};
    *arrived = true;
  });
  while (!*arrived) {
    if (!scheduler_->RunNext()) return Status::Internal("virtual controller: the call was never answered");
  }
  const Disposition d = answer->second;
  if (d == Disposition::kDropConnection) {
    connected_ = false;
    return Status::IoError("the connection was closed by the controller (injected)");
  }
  if (d == Disposition::kHalfOpen || scheduler_->now_s() - start > options_.call_timeout_s) {
    scheduler_->RunUntil(start + options_.call_timeout_s);
    connected_ = false;
    return Status::IoError("no answer within the call timeout (half-open connection or latency spike)");
  }
  if (!answer->first.ok) return Status::Failed(answer->first.error);
  return answer->first;
}

Result<std::vector<MacroValue>> VirtualLink::ReadRange(int start, int count) {
  ApiRequest r;
  r.op = ApiRequest::Op::kReadRange;
  r.start = start;
  r.count = count;
  FL_ASSIGN_OR_RETURN(ApiResponse a, Call(r));
  return std::move(a.values);
}

Status VirtualLink::WriteRange(int start, const std::vector<double>& values) {
  ApiRequest r;
  r.op = ApiRequest::Op::kWriteRange;
  r.start = start;
  r.values = values;
  return Call(r).status();
}

Result<double> VirtualLink::ReadOffset(const OffsetAddress& offset) {
  ApiRequest r;
  r.op = ApiRequest::Op::kReadOffset;
  r.offset = offset.ToString();
  FL_ASSIGN_OR_RETURN(ApiResponse a, Call(r));
  return a.value;
}

Status VirtualLink::WriteOffset(const OffsetAddress& offset, double value_mm) {
  ApiRequest r;
  r.op = ApiRequest::Op::kWriteOffset;
  r.offset = offset.ToString();
  r.value = value_mm;
  return Call(r).status();
}

}  // namespace formloop::cnc
