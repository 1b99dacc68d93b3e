#pragma once
// The logging facade: one spdlog logger named "formloop", to stderr (coloured on a terminal) and,
// during a run, also to <run folder>/formloop.log. stdout is never used for logs: it is reserved for
// machine-readable output.
//
//   log::Info("fitted {} points, rms {:.3f} um", n, rms_um);

#include <filesystem>
#include <string>

#include <spdlog/spdlog.h>

#include "core/status.h"

namespace formloop::log {

enum class Level { kTrace, kDebug, kInfo, kWarn, kError, kOff };

// Parses "trace|debug|info|warn|error|off".
Result<Level> ParseLevel(const std::string& text);
// Sets the stderr sink's level (the run-folder file always records debug and above).
void SetLevel(Level level);
// Adds a file sink; returns non-ok when the file cannot be opened. Replaces a previous file sink.
Status StartFileLog(const std::filesystem::path& path);
// Flushes and removes the file sink.
void StopFileLog();

spdlog::logger& Logger();

template <typename... Args>
void Debug(spdlog::format_string_t<Args...> fmt, Args&&... args) {
  Logger().debug(fmt, std::forward<Args>(args)...);
}
template <typename... Args>
void Info(spdlog::format_string_t<Args...> fmt, Args&&... args) {
  Logger().info(fmt, std::forward<Args>(args)...);
}
template <typename... Args>
void Warn(spdlog::format_string_t<Args...> fmt, Args&&... args) {
  Logger().warn(fmt, std::forward<Args>(args)...);
}
template <typename... Args>
void Error(spdlog::format_string_t<Args...> fmt, Args&&... args) {
  Logger().error(fmt, std::forward<Args>(args)...);
}

}  // namespace formloop::log
