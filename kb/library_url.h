#pragma once
// Names of case libraries (`--kb`, `formloop kb ... LIBRARY`):
//   cases.db, ./lib/cases.db           a bare path: an SQLite file (as before)
//   sqlite:PATH                        the same, explicitly
//   postgresql://user@host:port/db     a PostgreSQL database (libpq's URI form; postgres:// too). Query
//                                      parameters pass to libpq (e.g. ?host=/run/postgresql for a socket).
// A password may be given in the URL, but the environment (PGPASSWORD) or ~/.pgpass keep it out of
// process lists; messages never show it.

#include <filesystem>
#include <string>

#include "core/status.h"

namespace formloop::kb {

struct LibraryUrl {
  enum class Kind { kSqlite, kPostgres };
  Kind kind = Kind::kSqlite;
  std::filesystem::path path;  // kSqlite
  std::string conninfo;        // kPostgres: the URL as given, password included
  std::string display;         // for messages: the path, or the URL without a password

  bool is_postgres() const { return kind == Kind::kPostgres; }
  // Refuses an empty name and an unknown scheme (`mysql://...`), naming the supported forms.
  static Result<LibraryUrl> Parse(const std::string& text);
};

// The URL with any password (user:PASSWORD@ or ?password=...) removed.
std::string RedactPassword(const std::string& url);

}  // namespace formloop::kb
