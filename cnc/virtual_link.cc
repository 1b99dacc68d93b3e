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
  return answer->first;
}

}  // namespace formloop::cnc
