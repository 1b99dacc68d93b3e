// core/child_process.h: work that crashes in the child is reported, not shared, and the bytes of work that
// finishes reach the parent whole (also beyond a pipe's buffer).

#include "core/child_process.h"

#include <csignal>
#include <cstdlib>
#include <stdexcept>
#include <string>

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

}  // namespace
}  // namespace formloop
