#include "cnc/emulator_server.h"

#include <arpa/inet.h>
#include <netinet/in.h>
#include <netinet/tcp.h>
#include <poll.h>
#include <sys/socket.h>
#include <unistd.h>

#include <cerrno>
#include <chrono>
#include <cmath>
#include <cstring>
#include <vector>

#include "cnc/wire.h"
#include "core/log.h"

namespace formloop::cnc {

namespace {

double Now() { return std::chrono::duration<double>(std::chrono::steady_clock::now().time_since_epoch()).count(); }

}  // namespace

struct EmulatorServer::Connection {
  long id = 0;
  int fd = -1;
  std::string in, out;
  bool mute = false;  // half-open: nothing is answered any more
};

Result<std::unique_ptr<EmulatorServer>> EmulatorServer::Start(const ControllerOptions& controller,
                                                              const EmulatorServerOptions& options) {
  std::unique_ptr<EmulatorServer> s(new EmulatorServer());
  s->options_ = options;
  FL_ASSIGN_OR_RETURN(s->controller_, Controller::Create(controller, &s->scheduler_));
  s->listen_fd_ = ::socket(AF_INET, SOCK_STREAM | SOCK_NONBLOCK | SOCK_CLOEXEC, 0);
  if (s->listen_fd_ < 0) return Status::IoError(std::string("socket: ") + std::strerror(errno));
  const int one = 1;
  ::setsockopt(s->listen_fd_, SOL_SOCKET, SO_REUSEADDR, &one, sizeof(one));
  sockaddr_in addr{};
  addr.sin_family = AF_INET;
  addr.sin_port = htons(static_cast<std::uint16_t>(options.port));
  if (::inet_pton(AF_INET, options.host.c_str(), &addr.sin_addr) != 1) {
    return Status::BadInput(Where{.field = "--host"}, "'" + options.host + "' is not an IPv4 address",
                            "use e.g. 127.0.0.1");
  }
  if (::bind(s->listen_fd_, reinterpret_cast<sockaddr*>(&addr), sizeof(addr)) != 0 ||
      ::listen(s->listen_fd_, 16) != 0) {
    return Status::IoError("cannot listen on " + options.host + ":" + std::to_string(options.port) + ": " +
                           std::strerror(errno) + " (another process uses the port? use --port 0 for a free one)");
  }
  socklen_t len = sizeof(addr);
  ::getsockname(s->listen_fd_, reinterpret_cast<sockaddr*>(&addr), &len);
  s->port_ = ntohs(addr.sin_port);
  s->t0_ = Now();
  return s;
}

EmulatorServer::~EmulatorServer() {
  for (auto& [id, c] : connections_) ::close(c->fd);
  if (listen_fd_ >= 0) ::close(listen_fd_);
}

void EmulatorServer::Close(long id) {
  const auto it = connections_.find(id);
  if (it == connections_.end()) return;
  ::close(it->second->fd);
  connections_.erase(it);
}

void EmulatorServer::Accept() {
  for (;;) {
    const int fd = ::accept4(listen_fd_, nullptr, nullptr, SOCK_NONBLOCK | SOCK_CLOEXEC);
    if (fd < 0) return;
    const int one = 1;
    ::setsockopt(fd, IPPROTO_TCP, TCP_NODELAY, &one, sizeof(one));
    auto c = std::make_unique<Connection>();
    c->id = next_id_++;
    c->fd = fd;
    connections_[c->id] = std::move(c);
  }
}

void EmulatorServer::Flush(Connection& c) {
  while (!c.out.empty()) {
    const ssize_t n = ::send(c.fd, c.out.data(), c.out.size(), MSG_NOSIGNAL);
    if (n <= 0) return;  // EAGAIN: later; an error shows as POLLERR/POLLHUP
    c.out.erase(0, static_cast<std::size_t>(n));
  }
}

void EmulatorServer::Receive(Connection& c) {
  char buffer[65536];
  for (;;) {
    const ssize_t n = ::recv(c.fd, buffer, sizeof(buffer), 0);
    if (n == 0 || (n < 0 && errno != EAGAIN && errno != EINTR)) {
      Close(c.id);
      return;
    }
    if (n < 0) break;
    if (!c.mute) c.in.append(buffer, static_cast<std::size_t>(n));
  }
  const long id = c.id;
  for (auto nl = c.in.find('\n'); nl != std::string::npos; nl = c.in.find('\n')) {
    const std::string line = c.in.substr(0, nl);
    c.in.erase(0, nl + 1);
    std::uint64_t seq = 0;
    ApiRequest request;
    const Status s = DecodeRequest(line, &seq, &request);
    if (!s.ok()) {
      ApiResponse refused;
      refused.ok = false;
      refused.error = "EW_SYNTAX: " + s.message();
      c.out += EncodeResponse(seq, request, refused);
      continue;
    }
    ++requests_;
    controller_->Submit(request, [this, id, seq, request](const ApiResponse& response, Disposition d) {
      const auto it = connections_.find(id);
      if (it == connections_.end() || it->second->mute) return;
      if (d == Disposition::kDropConnection) {
        Close(id);
        return;
      }
      if (d == Disposition::kHalfOpen) {
        it->second->mute = true;
        it->second->in.clear();
        return;
      }
      it->second->out += EncodeResponse(seq, request, response);
      Flush(*it->second);
    });
  }
}

Status EmulatorServer::Run(const std::atomic<bool>* stop) {
  double done_at = -1;
  std::vector<pollfd> fds;
  std::vector<long> ids;
  while (stop == nullptr || !stop->load()) {
    const double now = Now() - t0_;
    scheduler_.RunUntil(now);
    if (controller_->done() && done_at < 0) done_at = now;
    if (options_.exit_when_done && done_at >= 0 && now - done_at >= options_.linger_s) break;
    if (options_.max_run_s > 0 && now >= options_.max_run_s) {
      log::Warn("link emulate: stopping after --max-run-s {} s", options_.max_run_s);
      break;
    }
    fds.clear();
    ids.clear();
    fds.push_back({listen_fd_, POLLIN, 0});
    ids.push_back(0);
    for (auto& [id, c] : connections_) {
      fds.push_back({c->fd, static_cast<short>(POLLIN | (c->out.empty() ? 0 : POLLOUT)), 0});
      ids.push_back(id);
    }
    double wait = std::min(0.05, scheduler_.NextTime() - (Now() - t0_));
    if (wait < 0) wait = 0;
    timespec ts{static_cast<time_t>(wait), static_cast<long>((wait - std::floor(wait)) * 1e9)};
    const int ready = ::ppoll(fds.data(), fds.size(), &ts, nullptr);
    if (ready < 0 && errno != EINTR) return Status::IoError(std::string("poll: ") + std::strerror(errno));
    if (ready <= 0) continue;
    if (fds[0].revents & POLLIN) Accept();
    for (std::size_t k = 1; k < fds.size(); ++k) {
      const auto it = connections_.find(ids[k]);
      if (it == connections_.end()) continue;
      if (fds[k].revents & (POLLIN | POLLHUP | POLLERR)) {
        Receive(*it->second);
      } else if (fds[k].revents & POLLOUT) {
        Flush(*it->second);
      }
    }
  }
  return Status::Ok();
}

}  // namespace formloop::cnc
