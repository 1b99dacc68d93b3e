#pragma once
// A MacroTransport to an in-process emulated Controller under virtual time: each call is submitted to
// the controller and the scheduler runs (machine program included) until the answer is due. A
// dropped connection returns IoError at once; a half-open one, or an answer later than
// call_timeout_s, returns IoError after call_timeout_s, as a TCP client with a receive timeout would.
// This is what the deterministic protocol tests and the virtual-time throughput figures run on.

#include "cnc/controller.h"
#include "cnc/transport.h"

namespace formloop::cnc {

struct VirtualLinkOptions {
  double call_timeout_s = 1.0;  // a call with no answer by then fails (IoError)
  double connect_time_s = 0.001;
};

class VirtualLink final : public RequestTransport {
 public:
  VirtualLink(Controller* controller, EventScheduler* scheduler, VirtualLinkOptions options = {})
      : controller_(controller), scheduler_(scheduler), options_(options) {}
  Status Connect() override;
  void Disconnect() override { connected_ = false; }
  std::string Describe() const override { return "virtual controller"; }
  long calls() const { return calls_; }

 private:
  Result<ApiResponse> Call(const ApiRequest& request) override;
  Controller* controller_;
  EventScheduler* scheduler_;
  VirtualLinkOptions options_;
  bool connected_ = false;
  long calls_ = 0;
};

}  // namespace formloop::cnc
