#pragma once
// A real PostgreSQL server for the tests (nothing mocked): the one ctest's `postgres` fixture started
// (tests/kb/postgres_server.sh, DIR compiled in as FORMLOOP_TEST_PG_DIR), or, when a test binary runs
// on its own, one this process starts in a temporary folder and stops at exit. Each library gets a
// schema of its own in the server's `postgres` database (search_path in the URL), so parallel tests
// never share tables.

#include <unistd.h>

#include <atomic>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <string>

#include <gtest/gtest.h>

#include "kb/database.h"
#include "kb/library_url.h"

namespace formloop::kb::testing {

class PostgresServer {
 public:
  // The server, started on first use; empty url() with error() set when none could be had.
  static PostgresServer& Get() {
    static PostgresServer server;
    return server;
  }
  const std::string& url() const { return url_; }
  const std::string& error() const { return error_; }
  const std::filesystem::path& dir() const { return dir_; }

  // A new, empty schema; returns the URL of a library in it. `hint` becomes part of the schema name.
  std::string NewLibraryUrl(const std::string& hint) {
    static std::atomic<int> counter{0};
    std::string name = "t" + std::to_string(::getpid()) + "_" + std::to_string(counter++) + "_";
    for (char c : hint) name += std::isalnum(static_cast<unsigned char>(c)) ? static_cast<char>(std::tolower(c)) : '_';
    name = name.substr(0, 60);
    auto db = Database::Open(*LibraryUrl::Parse(url_), Database::Mode::kCreate);
    if (!db.ok()) {
      ADD_FAILURE() << db.status().message();
      return "";
    }
    const Status created = (*db)->Execute("CREATE SCHEMA " + name + ";");
    EXPECT_TRUE(created.ok()) << created.message();
    return url_ + "?options=-csearch_path%3D" + name;
  }

  ~PostgresServer() {
    if (owned_) std::system(("sh '" + Script() + "' stop '" + dir_.string() + "' >/dev/null 2>&1").c_str());
  }

 private:
  static std::string Script() { return std::string(FORMLOOP_SOURCE_DIR) + "/tests/kb/postgres_server.sh"; }
  static bool Answers(const std::string& url) {
    auto parsed = LibraryUrl::Parse(url);
    return parsed.ok() && Database::Open(*parsed, Database::Mode::kReadOnly).ok();
  }
  PostgresServer() {
#ifdef FORMLOOP_TEST_PG_DIR
    {
      std::ifstream in(std::filesystem::path(FORMLOOP_TEST_PG_DIR) / "url");
      std::string url;
      if (in >> url && Answers(url)) {
        url_ = url;
        dir_ = FORMLOOP_TEST_PG_DIR;
        return;
      }
    }
#endif
    dir_ = std::filesystem::temp_directory_path() / ("formloop-pg-" + std::to_string(::getpid()));
    const std::string command = "sh '" + Script() + "' start '" + dir_.string() + "'";
    if (std::system(command.c_str()) != 0) {
      error_ = "could not start a PostgreSQL server: `" + command + "` failed";
      return;
    }
    owned_ = true;
    std::ifstream in(dir_ / "url");
    in >> url_;
    if (!Answers(url_)) error_ = "the PostgreSQL server started in " + dir_.string() + " does not answer";
  }
  std::string url_;
  std::string error_;
  std::filesystem::path dir_;
  bool owned_ = false;
};

}  // namespace formloop::kb::testing
