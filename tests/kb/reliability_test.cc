// The case library under concurrent writers and under SIGKILL, on both back ends: processes made with
// fork(), each with its own connection (a connection is never shared across fork()).

#include <chrono>
#include <csignal>
#include <cstdio>
#include <set>
#include <string>
#include <thread>

#include <sys/types.h>
#include <sys/wait.h>
#include <unistd.h>

#include <gtest/gtest.h>

#include "kb/library.h"
#include "tests/kb/kb_fixtures.h"

namespace formloop::kb {
namespace {

using testing::KbBackendTest;
using testing::SyntheticCase;
namespace fs = std::filesystem;

double SecondsSince(std::chrono::steady_clock::time_point start) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
}

void WriteAll(int fd, const std::string& text) {
  std::size_t done = 0;
  while (done < text.size()) {
    const ssize_t n = ::write(fd, text.data() + done, text.size() - done);
    if (n <= 0) ::_exit(3);
    done += static_cast<std::size_t>(n);
  }
}

// Child: adds cases [first, first + count) with `prefix`, writing "uid\n" to `fd` after each commit.
// Exit code 0 when every add succeeded.
[[noreturn]] void AddLoop(const std::string& path, const std::string& prefix, int count, int fd) {
  auto lib = Library::Open(path);
  if (!lib.ok()) {
    std::fprintf(stderr, "child open: %s\n", lib.status().message().c_str());
    ::_exit(1);
  }
  for (int i = 0; i < count; ++i) {
    const CaseRecord record = SyntheticCase(i, 5, prefix);
    const Status s = (*lib)->AddCase(record);
    if (!s.ok()) {
      std::fprintf(stderr, "child add %s: %s\n", record.uid.c_str(), s.message().c_str());
      ::_exit(2);
    }
    if (fd >= 0) WriteAll(fd, record.uid + "\n");
  }
  ::_exit(0);
}

std::set<std::string> UidsIn(Library* lib) {
  std::set<std::string> uids;
  auto cases = lib->ListCases();
  EXPECT_TRUE(cases.ok());
  if (cases.ok()) {
    for (const auto& c : *cases) uids.insert(c.uid);
  }
  return uids;
}

TEST_P(KbBackendTest, TwoProcessesAdding500CasesEachGiveExactly1000) {
  const std::string path = LibraryName("cases.db");
  ASSERT_TRUE(InitLibrary(path).ok());
  const auto start = std::chrono::steady_clock::now();
  pid_t children[2];
  for (int k = 0; k < 2; ++k) {
    children[k] = ::fork();
    ASSERT_GE(children[k], 0);
    if (children[k] == 0) AddLoop(path, k == 0 ? "left" : "right", 500, -1);
  }
  for (pid_t child : children) {
    int status = 0;
    ASSERT_EQ(::waitpid(child, &status, 0), child);
    ASSERT_TRUE(WIFEXITED(status)) << "child did not exit normally";
    EXPECT_EQ(WEXITSTATUS(status), 0) << "a concurrent add failed (see stderr)";
  }
  const double seconds = SecondsSince(start);
  std::fprintf(stderr, "[timing] 2 x 500 concurrent adds: %.2f s\n", seconds);
  RecordProperty("seconds", std::to_string(seconds));
  auto lib = Library::Open(path);
  ASSERT_TRUE(lib.ok());
  EXPECT_EQ(*(*lib)->db()->QueryInt("SELECT COUNT(*) FROM cases;"), 1000);
  EXPECT_EQ(*(*lib)->db()->QueryInt("SELECT COUNT(*) FROM case_concepts;"), 3000);
  EXPECT_EQ(*(*lib)->db()->QueryInt("SELECT COUNT(*) FROM audit WHERE action = 'add';"), 1000);
  EXPECT_EQ(*(*lib)->ChangeCounter(), 1000);
  auto check = (*lib)->Check();
  ASSERT_TRUE(check.ok());
  EXPECT_TRUE(check->clean()) << check->ToJson().dump();
}

TEST_P(KbBackendTest, KilledDuringAddLoopKeepsEveryCommittedCase) {
  const std::string path = LibraryName("cases.db");
  ASSERT_TRUE(InitLibrary(path).ok());
  int fds[2];
  ASSERT_EQ(::pipe(fds), 0);
  const auto start = std::chrono::steady_clock::now();
  const pid_t child = ::fork();
  ASSERT_GE(child, 0);
  if (child == 0) {
    ::close(fds[0]);
    AddLoop(path, "killed", 100000, fds[1]);
  }
  ::close(fds[1]);
  // Read committed uids; after 300, kill the child while it is in the middle of its loop.
  std::set<std::string> reported;
  std::string buffer;
  char chunk[4096];
  bool killed = false;
  while (true) {
    const ssize_t n = ::read(fds[0], chunk, sizeof chunk);
    if (n <= 0) break;
    buffer.append(chunk, static_cast<std::size_t>(n));
    std::size_t eol;
    while ((eol = buffer.find('\n')) != std::string::npos) {
      reported.insert(buffer.substr(0, eol));
      buffer.erase(0, eol + 1);
    }
    if (!killed && reported.size() >= 300) {
      ASSERT_EQ(::kill(child, SIGKILL), 0);
      killed = true;
    }
  }
  ::close(fds[0]);
  int status = 0;
  ASSERT_EQ(::waitpid(child, &status, 0), child);
  ASSERT_TRUE(WIFSIGNALED(status) && WTERMSIG(status) == SIGKILL) << "the child finished before the kill";
  std::fprintf(stderr, "[timing] add loop killed after %zu reported commits: %.2f s\n", reported.size(),
               SecondsSince(start));

  auto lib = Library::Open(path);
  ASSERT_TRUE(lib.ok()) << lib.status().message();
  auto check = (*lib)->Check();
  ASSERT_TRUE(check.ok());
  EXPECT_TRUE(check->clean()) << check->ToJson().dump();
  const std::set<std::string> present = UidsIn(lib->get());
  for (const auto& uid : reported) EXPECT_EQ(present.count(uid), 1u) << uid << " was committed but is missing";
  // At most the one add in flight committed without being reported.
  EXPECT_LE(present.size(), reported.size() + 1);
  EXPECT_EQ(*(*lib)->ChangeCounter(), static_cast<long long>(present.size()));
  // The library still takes writes.
  EXPECT_TRUE((*lib)->AddCase(SyntheticCase(0, 5, "after")).ok());
}

TEST_P(KbBackendTest, KilledDuringImportLeavesNothing) {
  const std::string path = LibraryName("cases.db");
  // An export file of 2,000 cases.
  std::string text = "{\"format\":\"formloop-case-library\",\"format_version\":1,\"schema_version\":2}\n";
  for (int i = 0; i < 2000; ++i) {
    text += nlohmann::json{{"type", "case"}, {"case", SyntheticCase(i, 9, "imp").ToJson()}}.dump() + "\n";
  }
  ASSERT_TRUE(InitLibrary(path).ok());
  {
    auto lib = Library::Open(path);
    for (int i = 0; i < 10; ++i) ASSERT_TRUE((*lib)->AddCase(SyntheticCase(i, 3, "kept")).ok());
  }
  int fds[2];
  ASSERT_EQ(::pipe(fds), 0);
  const auto start = std::chrono::steady_clock::now();
  const pid_t child = ::fork();
  ASSERT_GE(child, 0);
  if (child == 0) {
    ::close(fds[0]);
    auto lib = Library::Open(path);
    if (!lib.ok()) ::_exit(1);
    ImportOptions options;
    options.on_case = [fd = fds[1]](std::size_t written) {
      // Three quarters through the transaction: tell the parent, then wait to be killed.
      if (written == 1500) {
        WriteAll(fd, "x");
        std::this_thread::sleep_for(std::chrono::seconds(20));
      }
    };
    (void)(*lib)->ImportText(text, "big.jsonl", options);
    ::_exit(0);
  }
  ::close(fds[1]);
  char byte = 0;
  ASSERT_EQ(::read(fds[0], &byte, 1), 1);
  ASSERT_EQ(::kill(child, SIGKILL), 0);
  ::close(fds[0]);
  int status = 0;
  ASSERT_EQ(::waitpid(child, &status, 0), child);
  ASSERT_TRUE(WIFSIGNALED(status));
  std::fprintf(stderr, "[timing] import killed at case 1500 of 2000: %.2f s\n", SecondsSince(start));

  auto lib = Library::Open(path);
  ASSERT_TRUE(lib.ok()) << lib.status().message();
  auto check = (*lib)->Check();
  ASSERT_TRUE(check.ok());
  EXPECT_TRUE(check->clean()) << check->ToJson().dump();
  const std::set<std::string> present = UidsIn(lib->get());
  EXPECT_EQ(present.size(), 10u);
  for (const auto& uid : present) EXPECT_EQ(uid.rfind("kept-", 0), 0u) << uid;
  EXPECT_EQ(*(*lib)->db()->QueryInt("SELECT COUNT(*) FROM audit WHERE action LIKE 'import%';"), 0);
  // The same import, uninterrupted, now succeeds in full.
  auto report = (*lib)->ImportText(text, "big.jsonl");
  ASSERT_TRUE(report.ok()) << report.status().message();
  EXPECT_EQ(report->cases_added, 2000u);
}

}  // namespace
}  // namespace formloop::kb
