#include "kb/library_url.h"

#include <cctype>

namespace formloop::kb {

std::string RedactPassword(const std::string& url) {
  std::string out = url;
  const std::size_t scheme_end = out.find("://");
  if (scheme_end != std::string::npos) {
    const std::size_t authority = scheme_end + 3;
    const std::size_t at = out.find('@', authority);
    const std::size_t slash = out.find('/', authority);
    if (at != std::string::npos && (slash == std::string::npos || at < slash)) {
      const std::size_t colon = out.find(':', authority);
      if (colon != std::string::npos && colon < at) out.erase(colon, at - colon);
    }
  }
  // ?password=... or &password=...
  for (const char* key : {"?password=", "&password="}) {
    const std::size_t p = out.find(key);
    if (p == std::string::npos) continue;
    const std::size_t value = p + std::string(key).size();
    const std::size_t end = out.find('&', value);
    out.erase(p + 1, (end == std::string::npos ? out.size() : end + 1) - (p + 1));
    if (!out.empty() && (out.back() == '?' || out.back() == '&')) out.pop_back();
  }
  return out;
}

Result<LibraryUrl> LibraryUrl::Parse(const std::string& text) {
  LibraryUrl url;
  if (text.empty()) {
    return Status::BadInput(
        "the case library name is empty. Fix: give a file such as cases.db, sqlite:PATH or "
        "postgresql://user@host:port/db");
  }
  if (text.rfind("postgresql://", 0) == 0 || text.rfind("postgres://", 0) == 0) {
    url.kind = Kind::kPostgres;
    url.conninfo = text;
    url.display = RedactPassword(text);
    return url;
  }
  if (text.rfind("sqlite:", 0) == 0) {
    url.path = text.substr(7);
    if (url.path.empty()) {
      return Status::BadInput("case library '" + text + "': no path after sqlite:. Fix: write sqlite:PATH");
    }
    url.display = url.path.string();
    return url;
  }
  // A scheme this formloop does not know (letters then "://") is refused rather than taken for a path.
  const std::size_t scheme = text.find("://");
  if (scheme != std::string::npos && scheme > 0) {
    bool letters = true;
    for (std::size_t i = 0; i < scheme; ++i) letters = letters && std::isalpha(static_cast<unsigned char>(text[i]));
    if (letters) {
      return Status::BadInput("case library '" + RedactPassword(text) + "': unknown scheme '" + text.substr(0, scheme) +
                              "'. Fix: use a file path, sqlite:PATH or postgresql://user@host:port/db");
    }
  }
  url.path = text;
  url.display = text;
  return url;
}

}  // namespace formloop::kb
