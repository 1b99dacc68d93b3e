#pragma once
// MacroTransport over TCP to `formloop link emulate` (cnc/wire.h). Every call has a deadline: a
// connection that stops answering (half-open) or answers too late is closed and the call fails with
// IoError, which the collector treats as "outcome unknown, reconnect and read again". TCP_NODELAY is
// set, so a request is not held back to be merged with the next one.

#include <cstdint>
#include <string>

#include "cnc/api.h"

namespace formloop::cnc {

struct TcpTransportOptions {
  double connect_timeout_s = 2.0;
  double call_timeout_s = 1.0;
};

// "HOST:PORT" with HOST a dotted IPv4 address or "localhost".
Status ParseAddress(const std::string& text, std::string* host, int* port);

class TcpTransport final : public RequestTransport {
 public:
  TcpTransport(std::string host, int port, TcpTransportOptions options = {});
  ~TcpTransport() override;
  TcpTransport(const TcpTransport&) = delete;
  TcpTransport& operator=(const TcpTransport&) = delete;

  Status Connect() override;
  void Disconnect() override;
  std::string Describe() const override { return host_ + ":" + std::to_string(port_); }

 private:
  Result<ApiResponse> Call(const ApiRequest& request) override;
  std::string host_;
  int port_;
  TcpTransportOptions options_;
  int fd_ = -1;
  std::uint64_t seq_ = 0;
  std::string inbox_;
};

}  // namespace formloop::cnc
