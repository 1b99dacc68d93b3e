#include "cnc/handshake.h"

#include <cmath>

namespace formloop::cnc {

const char* WordKindName(WordKind kind) {
  switch (kind) {
    case WordKind::kIdle:
      return "IDLE";
    case WordKind::kMeasuring:
      return "MEASURING";
    case WordKind::kPointReady:
      return "POINT_READY";
    case WordKind::kFinished:
      return "FINISHED";
    case WordKind::kAbort:
      return "ABORT";
    case WordKind::kIllegal:
      return "ILLEGAL";
  }
  return "?";
}

ControlWord IdleWord() { return {}; }
ControlWord MeasuringWord(int last_acknowledged) { return {1, 0, State::kMeasuring, last_acknowledged}; }
ControlWord PointReadyWord(int id) { return {1, 1, State::kPointReady, id}; }
ControlWord FinishedWord(int count) { return {1, 1, State::kFinished, count}; }
ControlWord AbortWord() { return {1, 0, State::kMeasuring, kAbortId}; }

double EncodeControl(const ControlWord& word) {
  return 32768.0 * word.lock + 16384.0 * word.holder + 4096.0 * static_cast<int>(word.state) + word.point;
}

std::optional<ControlWord> DecodeControl(double value) {
  if (!std::isfinite(value) || value < 0 || value > 65535 || value != std::floor(value)) return std::nullopt;
  const int c = static_cast<int>(value);
  ControlWord word;
  word.point = c & 0xFFF;
  word.state = static_cast<State>((c >> 12) & 0x3);
  word.holder = (c >> 14) & 0x1;
  word.lock = (c >> 15) & 0x1;
  return word;
}

WordKind ClassifyControl(const ControlWord& w) {
  if (w == IdleWord()) return WordKind::kIdle;
  if (w.lock != 1) return WordKind::kIllegal;
  if (w.holder == 0 && w.state == State::kMeasuring) {
    if (w.point == kAbortId) return WordKind::kAbort;
    return w.point <= kMaxPointId ? WordKind::kMeasuring : WordKind::kIllegal;
  }
  if (w.holder == 1 && w.state == State::kPointReady && w.point >= 1 && w.point <= kMaxPointId) {
    return WordKind::kPointReady;
  }
  if (w.holder == 1 && w.state == State::kFinished && w.point >= 1 && w.point <= kMaxPointId) {
    return WordKind::kFinished;
  }
  return WordKind::kIllegal;
}

WordKind ClassifyControlValue(double value, ControlWord* word) {
  const auto decoded = DecodeControl(value);
  if (!decoded) return WordKind::kIllegal;
  if (word != nullptr) *word = *decoded;
  return ClassifyControl(*decoded);
}

std::string FormatControl(const ControlWord& w) {
  return "(" + std::to_string(w.lock) + "," + std::to_string(w.holder) + "," +
         std::to_string(static_cast<int>(w.state)) + "," + std::to_string(w.point) + ")";
}

const char* AxisFlagName(AxisFlag flag) {
  switch (flag) {
    case AxisFlag::kOk:
      return "OK";
    case AxisFlag::kOverflow:
      return "OVERFLOW";
    case AxisFlag::kRangeError:
      return "RANGE_ERROR";
  }
  return "?";
}

int QuantiseDeviation(double deviation_mm) {
  const double scaled = deviation_mm * 10000.0;
  if (!std::isfinite(scaled) || std::fabs(scaled) >= 1e9) return kOverflowValue;
  const double rounded = scaled >= 0 ? std::floor(scaled + 0.5) : -std::floor(-scaled + 0.5);
  if (std::fabs(rounded) > kValueLimit) return kOverflowValue;
  return static_cast<int>(rounded);
}

int FieldOf(int v) { return v >= 0 ? v : v + 4096; }

Result<double> PackData(const std::array<int, 3>& v) {
  std::int64_t d = 0;
  for (int a = 0; a < 3; ++a) {
    if (v[a] < -2048 || v[a] > 2047) {
      return Status::Internal("PackData: axis " + std::string(AxisName(a)) + " value " + std::to_string(v[a]) +
                              " is outside the 12-bit field −2048..2047");
    }
    d = d * 4096 + FieldOf(v[a]);
  }
  return static_cast<double>(d);
}

namespace {

// Flags one decoded value: |v| ≤ 999 ok, −2048 the sentinel, anything else a range error.
AxisFlag FlagOf(int v) {
  if (v == kOverflowValue) return AxisFlag::kOverflow;
  if (v < -kValueLimit || v > kValueLimit) return AxisFlag::kRangeError;
  return AxisFlag::kOk;
}

}  // namespace

Result<DecodedPoint> UnpackData(double d) {
  if (!std::isfinite(d) || d != std::floor(d) || d < 0 || d > static_cast<double>(kMaxDataWord)) {
    return Status::BadInput("data word " + std::to_string(d) +
                            " is not a whole number in 0..68719476735 (a corrupted or half-written value)");
  }
  const auto w = static_cast<std::uint64_t>(d);
  const std::array<std::uint64_t, 3> fields = {(w >> 24) & 0xFFF, (w >> 12) & 0xFFF, w & 0xFFF};
  DecodedPoint point;
  for (int a = 0; a < 3; ++a) {
    const int f = static_cast<int>(fields[a]);
    point.v[a] = f >= 2048 ? f - 4096 : f;
    point.flags[a] = FlagOf(point.v[a]);
  }
  return point;
}

Result<DecodedPoint> DecodeSplit(const std::array<double, 3>& v) {
  DecodedPoint point;
  for (int a = 0; a < 3; ++a) {
    if (!std::isfinite(v[a]) || v[a] != std::floor(v[a]) || v[a] < -2048 || v[a] > 2047) {
      return Status::BadInput(std::string("split value of axis ") + AxisName(a) + " = " + std::to_string(v[a]) +
                              " is not a whole number in −2048..2047");
    }
    point.v[a] = static_cast<int>(v[a]);
    point.flags[a] = FlagOf(point.v[a]);
  }
  return point;
}

const char* LayoutName(Layout layout) { return layout == Layout::kPacked ? "packed" : "split"; }

Result<Layout> ParseLayout(const std::string& name) {
  if (name == "packed") return Layout::kPacked;
  if (name == "split") return Layout::kSplit;
  return Status::BadInput("unknown block layout '" + name + "'; use packed or split");
}

const char* AxisName(int axis) {
  static const char* const kNames[] = {"X", "Y", "Z"};
  return axis >= 0 && axis < 3 ? kNames[axis] : "?";
}

}  // namespace formloop::cnc
