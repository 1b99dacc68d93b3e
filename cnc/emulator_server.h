#pragma once
// The emulated controller as a network service (`formloop link emulate`): one thread, one poll loop,
// the Controller's event scheduler driven from the monotonic clock. Requests (cnc/wire.h) are handed
// to Controller::Submit; its answer goes back after the drawn latency, or the connection is closed
// (a dropped connection) or left without answers (half-open: the loop keeps reading and discarding
// what arrives, and closes the socket when the client does). Sleeps use ppoll with nanosecond
// timeouts, so a 1 ms ± 0.5 ms latency is kept to tens of microseconds.

#include <atomic>
#include <memory>
#include <string>

#include "cnc/controller.h"

namespace formloop::cnc {

struct EmulatorServerOptions {
  std::string host = "127.0.0.1";
  int port = 0;                // 0: the system picks a free port (see port())
  bool exit_when_done = true;  // leave the loop when the runs are over (plus linger_s)
  double linger_s = 1.0;       // keep answering after the last run ended (the collector's last writes)
  double max_run_s = 0;        // stop after this long whatever happens; 0 = no limit
};

class EmulatorServer {
 public:
  static Result<std::unique_ptr<EmulatorServer>> Start(const ControllerOptions& controller,
                                                       const EmulatorServerOptions& options);
  ~EmulatorServer();
  int port() const { return port_; }
  // Serves until the controller is done (and linger_s passed), max_run_s, or *stop becomes true.
  Status Run(const std::atomic<bool>* stop);
  const Controller& controller() const { return *controller_; }
  long requests() const { return requests_; }

 private:
  EmulatorServer() = default;
  struct Connection;
  void Accept();
  void Receive(Connection& c);
  void Flush(Connection& c);
  void Close(long id);

  EventScheduler scheduler_;
  std::unique_ptr<Controller> controller_;
  EmulatorServerOptions options_;
  int listen_fd_ = -1;
  int port_ = 0;
  double t0_ = 0;
  long next_id_ = 1;
  long requests_ = 0;
  std::map<long, std::unique_ptr<Connection>> connections_;
};

}  // namespace formloop::cnc
