#include "core/log.h"

#include <memory>
#include <mutex>

#include <spdlog/sinks/basic_file_sink.h>
#include <spdlog/sinks/dist_sink.h>
#include <spdlog/sinks/stdout_color_sinks.h>

namespace formloop::log {
namespace {

struct State {
  std::shared_ptr<spdlog::sinks::stderr_color_sink_mt> console;
  std::shared_ptr<spdlog::sinks::basic_file_sink_mt> file;
  std::shared_ptr<spdlog::logger> logger;
};

State& GetState() {
  static State state = [] {
    State s;
    s.console = std::make_shared<spdlog::sinks::stderr_color_sink_mt>();
    s.console->set_pattern("[%^%l%$] %v");
    s.console->set_level(spdlog::level::info);
    s.logger = std::make_shared<spdlog::logger>("formloop", spdlog::sinks_init_list{s.console});
    s.logger->set_level(spdlog::level::debug);
    return s;
  }();
  return state;
}

spdlog::level::level_enum ToSpd(Level level) {
  switch (level) {
    case Level::kTrace:
      return spdlog::level::trace;
    case Level::kDebug:
      return spdlog::level::debug;
    case Level::kInfo:
      return spdlog::level::info;
    case Level::kWarn:
      return spdlog::level::warn;
    case Level::kError:
      return spdlog::level::err;
    case Level::kOff:
      return spdlog::level::off;
  }
  return spdlog::level::info;
}

}  // namespace

Result<Level> ParseLevel(const std::string& text) {
  if (text == "trace") return Level::kTrace;
  if (text == "debug") return Level::kDebug;
  if (text == "info") return Level::kInfo;
  if (text == "warn") return Level::kWarn;
  if (text == "error") return Level::kError;
  if (text == "off") return Level::kOff;
  return Status::BadInput(Where{.field = "--log-level"}, "unknown level '" + text + "'",
                          "use one of trace, debug, info, warn, error, off");
}

void SetLevel(Level level) {
  State& s = GetState();
  s.console->set_level(ToSpd(level));
  if (level == Level::kTrace) s.logger->set_level(spdlog::level::trace);
}

Status StartFileLog(const std::filesystem::path& path) {
  State& s = GetState();
  StopFileLog();
  try {
    s.file = std::make_shared<spdlog::sinks::basic_file_sink_mt>(path.string(), /*truncate=*/true);
  } catch (const spdlog::spdlog_ex& e) {
    return Status::IoError("cannot open log file '" + path.string() + "': " + e.what());
  }
  s.file->set_pattern("%Y-%m-%dT%H:%M:%S.%e [%l] %v");
  s.file->set_level(spdlog::level::debug);
  s.logger->sinks().push_back(s.file);
  return Status::Ok();
}

void StopFileLog() {
  State& s = GetState();
  if (!s.file) return;
  s.logger->flush();
  auto& sinks = s.logger->sinks();
  sinks.erase(std::remove(sinks.begin(), sinks.end(), s.file), sinks.end());
  s.file.reset();
}

spdlog::logger& Logger() { return *GetState().logger; }

}  // namespace formloop::log
