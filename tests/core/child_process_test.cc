// core/child_process.h: work that crashes in the child is reported, not shared, the bytes of work that
// finishes reach the parent whole (also beyond a pipe's buffer), and work still running at the time limit is
// killed and reaped within a bounded time.

#include "core/child_process.h"

#include <sys/wait.h>

#include <cerrno>
#include <chrono>
#include <csignal>
#include <cstdlib>
#include <stdexcept>
#include <string>
#include <thread>

#include <gtest/gtest.h>

namespace formloop {
namespace {

TEST(ChildProcess, ReturnsTheBytesOfFinishedWorkWholeAndInOrder) {
  // 3 MB: many times a pipe's buffer, so the parent must read while the child writes.
  std::string expected(3 << 20, '\0');
  for (std::size_t k = 0; k < expected.size(); ++k) expected[k] = static_cast<char>((k * 7919) % 251);
  ChildFailure failure;
  const auto bytes = RunInChildProcess([&] { return expected; }, &failure);
  ASSERT_TRUE(bytes.ok()) << bytes.status().ToString();
  EXPECT_EQ(*bytes, expected);
  EXPECT_EQ(RunInChildProcess([] { return std::string(); }, nullptr).value(), "");
}

TEST(ChildProcess, AnAbortInTheChildIsAnErrorInTheParentWithItsSignal) {
  ChildFailure failure;
  const auto bytes = RunInChildProcess([]() -> std::string { std::abort(); }, &failure);
  ASSERT_FALSE(bytes.ok());
  EXPECT_EQ(bytes.status().code(), StatusCode::kInternal);
  EXPECT_EQ(failure.signal, SIGABRT);
  EXPECT_NE(bytes.status().message().find("signal 6"), std::string::npos) << bytes.status().message();
  EXPECT_EQ(failure.Describe().rfind("signal 6, ", 0), 0u) << failure.Describe();
}

TEST(ChildProcess, AKilledChildAndAThrowingOneAreErrorsToo) {
  ChildFailure killed;
  EXPECT_FALSE(RunInChildProcess(
                   []() -> std::string {
                     std::raise(SIGKILL);
                     return "never";
                   },
                   &killed)
                   .ok());
  EXPECT_EQ(killed.signal, SIGKILL);
  ChildFailure threw;
  EXPECT_FALSE(RunInChildProcess([]() -> std::string { throw std::runtime_error("no"); }, &threw).ok());
  EXPECT_EQ(threw.signal, 0);
  EXPECT_EQ(threw.exit_code, 5);
  EXPECT_EQ(threw.Describe(), "exit code 5");
}

TEST(ChildProcess, TheChildsMemoryIsItsOwn) {
  int value = 1;
  const auto bytes = RunInChildProcess(
      [&] {
        value = 2;
        return std::to_string(value);
      },
      nullptr);
  ASSERT_TRUE(bytes.ok());
  EXPECT_EQ(*bytes, "2");
  EXPECT_EQ(value, 1);  // the child wrote its copy
}

// True when this process has no child left, running or ended-but-unreaped (a zombie).
bool NoChildLeft() {
  int wstatus = 0;
  return ::waitpid(-1, &wstatus, WNOHANG) < 0 && errno == ECHILD;
}

TEST(ChildProcess, AChildPastItsTimeLimitIsKilledReapedAndReportedAsTimedOut) {
  ASSERT_TRUE(NoChildLeft());
  using Clock = std::chrono::steady_clock;
  const auto start = Clock::now();
  ChildFailure failure;
  const auto bytes = RunInChildProcess(
      []() -> std::string {
        std::this_thread::sleep_for(std::chrono::seconds(60));  // a reader that hangs
        return "too late";
      },
      &failure, 0.3);
  const double waited_s = std::chrono::duration<double>(Clock::now() - start).count();
  ASSERT_FALSE(bytes.ok());
  EXPECT_EQ(bytes.status().code(), StatusCode::kInternal);
  EXPECT_TRUE(failure.timed_out);
  EXPECT_EQ(failure.signal, SIGKILL);
  EXPECT_EQ(failure.limit_s, 0.3);
  EXPECT_EQ(failure.Describe(), "no answer within 0.3 s, stopped with signal 9");
  EXPECT_NE(bytes.status().message().find("no answer within 0.3 s"), std::string::npos) << bytes.status().message();
  // Not before the limit, and not the child's 60 s: the bound leaves room for a loaded machine (and sanitizers).
  EXPECT_GE(waited_s, 0.3);
  EXPECT_LT(waited_s, 20.0);
  EXPECT_TRUE(NoChildLeft()) << "the killed child was not reaped";
}

TEST(ChildProcess, WorkWithinItsTimeLimitIsUnaffected) {
  std::string expected(3 << 20, 'a');  // several pipe buffers: reads wait on the deadline between them
  ChildFailure failure;
  const auto bytes = RunInChildProcess([&] { return expected; }, &failure, 60.0);
  ASSERT_TRUE(bytes.ok()) << bytes.status().ToString();
  EXPECT_EQ(*bytes, expected);
  EXPECT_FALSE(failure.timed_out);
  // A crash before the limit is still a crash, not a time-out.
  ChildFailure crashed;
  EXPECT_FALSE(RunInChildProcess([]() -> std::string { std::abort(); }, &crashed, 60.0).ok());
  EXPECT_FALSE(crashed.timed_out);
  EXPECT_EQ(crashed.signal, SIGABRT);
  EXPECT_TRUE(NoChildLeft());
}

}  // namespace
}  // namespace formloop
