#include "cnc/tcp_transport.h"

#include <arpa/inet.h>
#include <fcntl.h>
#include <netinet/in.h>
#include <netinet/tcp.h>
#include <poll.h>
#include <sys/socket.h>
#include <unistd.h>

#include <cerrno>
#include <chrono>
#include <cstring>

#include "cnc/wire.h"

namespace formloop::cnc {

namespace {

double Now() { return std::chrono::duration<double>(std::chrono::steady_clock::now().time_since_epoch()).count(); }

int RemainingMs(double deadline) {
  const double left = deadline - Now();
  return left <= 0 ? 0 : static_cast<int>(left * 1000.0) + 1;
}

}  // namespace

Status ParseAddress(const std::string& text, std::string* host, int* port) {
  const auto colon = text.rfind(':');
  const auto bad = [&] {
    return Status::BadInput(Where{.field = "--address"}, "'" + text + "' is not HOST:PORT",
                            "write e.g. 127.0.0.1:5800");
  };
  if (colon == std::string::npos || colon == 0) return bad();
  *host = text.substr(0, colon);
  if (*host == "localhost") *host = "127.0.0.1";
  in_addr probe{};
  if (::inet_pton(AF_INET, host->c_str(), &probe) != 1) return bad();
  try {
    std::size_t used = 0;
    *port = std::stoi(text.substr(colon + 1), &used);
    if (used != text.size() - colon - 1 || *port < 1 || *port > 65535) return bad();
  } catch (const std::exception&) {
    return bad();
  }
  return Status::Ok();
}

TcpTransport::TcpTransport(std::string host, int port, TcpTransportOptions options)
    : host_(std::move(host)), port_(port), options_(options) {}

TcpTransport::~TcpTransport() { Disconnect(); }

void TcpTransport::Disconnect() {
  if (fd_ >= 0) ::close(fd_);
  fd_ = -1;
  inbox_.clear();
}

Status TcpTransport::Connect() {
  Disconnect();
  fd_ = ::socket(AF_INET, SOCK_STREAM | SOCK_NONBLOCK | SOCK_CLOEXEC, 0);
  if (fd_ < 0) return Status::IoError(std::string("socket: ") + std::strerror(errno));
  sockaddr_in addr{};
  addr.sin_family = AF_INET;
  addr.sin_port = htons(static_cast<std::uint16_t>(port_));
  ::inet_pton(AF_INET, host_.c_str(), &addr.sin_addr);
  if (::connect(fd_, reinterpret_cast<sockaddr*>(&addr), sizeof(addr)) != 0 && errno != EINPROGRESS) {
    const std::string err = std::strerror(errno);
    Disconnect();
    return Status::IoError("connect to " + Describe() + ": " + err);
  }
  pollfd p{fd_, POLLOUT, 0};
  const int ready = ::poll(&p, 1, static_cast<int>(options_.connect_timeout_s * 1000));
  int error = 0;
  socklen_t len = sizeof(error);
  if (ready <= 0 || ::getsockopt(fd_, SOL_SOCKET, SO_ERROR, &error, &len) != 0 || error != 0) {
    const std::string err = ready == 0 ? "timed out" : std::strerror(error != 0 ? error : errno);
    Disconnect();
    return Status::IoError("connect to " + Describe() + ": " + err);
  }
  const int one = 1;
  ::setsockopt(fd_, IPPROTO_TCP, TCP_NODELAY, &one, sizeof(one));
  return Status::Ok();
}

Result<ApiResponse> TcpTransport::Call(const ApiRequest& request) {
  if (fd_ < 0) return Status::IoError("not connected to " + Describe());
  const std::uint64_t seq = ++seq_;
  const std::string out = EncodeRequest(seq, request);
  const double deadline = Now() + options_.call_timeout_s;
  const auto fail = [&](const std::string& what) {
    Disconnect();
    return Status::IoError(Describe() + ": " + what);
  };
  std::size_t sent = 0;
  while (sent < out.size()) {
    const ssize_t n = ::send(fd_, out.data() + sent, out.size() - sent, MSG_NOSIGNAL);
    if (n > 0) {
      sent += static_cast<std::size_t>(n);
      continue;
    }
    if (n < 0 && errno != EAGAIN && errno != EINTR) return fail(std::string("send: ") + std::strerror(errno));
    pollfd p{fd_, POLLOUT, 0};
    if (::poll(&p, 1, RemainingMs(deadline)) <= 0) return fail("send timed out");
  }
  for (;;) {
    // Answers to calls given up on earlier carry older sequence numbers: skipped.
    for (auto nl = inbox_.find('\n'); nl != std::string::npos; nl = inbox_.find('\n')) {
      const std::string line = inbox_.substr(0, nl);
      inbox_.erase(0, nl + 1);
      std::uint64_t got = 0;
      ApiResponse answer;
      const Status s = DecodeResponse(line, request, &got, &answer);
      if (got != seq) continue;
      if (!s.ok()) return fail(s.message());
      return answer;
    }
    pollfd p{fd_, POLLIN, 0};
    const int ready = ::poll(&p, 1, RemainingMs(deadline));
    if (ready == 0) return fail("no answer within " + std::to_string(options_.call_timeout_s) + " s");
    if (ready < 0 && errno != EINTR) return fail(std::string("poll: ") + std::strerror(errno));
    char buffer[65536];
    const ssize_t n = ::recv(fd_, buffer, sizeof(buffer), 0);
    if (n == 0) return fail("the controller closed the connection");
    if (n < 0) {
      if (errno == EAGAIN || errno == EINTR) continue;
      return fail(std::string("recv: ") + std::strerror(errno));
    }
    inbox_.append(buffer, static_cast<std::size_t>(n));
  }
}

}  // namespace formloop::cnc
