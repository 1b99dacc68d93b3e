#pragma once
// The macro-variable handshake's words (spec/tuning-and-link.md §7.2; seed 000 claims 5-7 and its
// "2 + 2 + 12" and "12 + 12 + 12" bit budgets).
//
// The variable block sits at consecutive addresses so one range read returns all of it:
//
//   PACKED layout (default)          SPLIT layout (controllers that keep < 11 significant digits)
//   base     C  control word          base     C
//   base+1   D  data word, 36 bits    base+1.. v_x, v_y, v_z as plain integers
//   base+2   Q  run counter           base+4   Q
//   base+3   A  alarm request         base+5   A
//
// Control word, one 16-bit word held in a double:
//   C = 32768·LK + 16384·HD + 4096·ST + PT
//   LK lock held; HD holder (0 machine, 1 collector); ST 0 IDLE, 1 MEASURING, 2 POINT_READY,
//   3 FINISHED; PT point id 1..2000, 4095 = ABORT, 0 = none.
//   Legal words: IDLE 0; MEASURING (1,0,1,p) p = last acknowledged id (0 when just armed);
//   POINT_READY (1,1,2,i); FINISHED (1,1,3,N); ABORT (1,0,1,4095). Anything else is a
//   PROTOCOL_ERROR. Example: (1,1,2,1234) → 58578.
//
// Data word: v_a = round((p_a − p_ref,a)·10000) in units of 0.1 µm, valid when |v_a| ≤ 999;
//   F(v) = v (v ≥ 0) or v + 4096 (12-bit two's complement); D = F(v_x)·2^24 + F(v_y)·2^12 + F(v_z),
//   0 ≤ D ≤ 2^36 − 1 (exact in a double, 2^36 < 2^53); D = −1 is EMPTY. A measuring program writes
//   field 2048 (v = −2048, OVERFLOW) for an axis with |v| ≥ 1000; a decoded 1000 ≤ |v| ≤ 2047 is a
//   RANGE_ERROR (the program should have written the sentinel). Example: (123, −456, 999) →
//   2 078 508 007. In the SPLIT layout each v is written as it is and EMPTY is kSplitEmpty.

#include <array>
#include <cstdint>
#include <optional>
#include <string>

#include "core/status.h"

namespace formloop::cnc {

inline constexpr int kMaxPointId = 2000;      // ids 1..2000 (seed 000: "a positive integer not exceeding 2000")
inline constexpr int kAbortId = 4095;         // PT = 4095 in a collector word: stop the measuring program
inline constexpr double kEmptyData = -1.0;    // D = EMPTY (PACKED layout)
inline constexpr double kSplitEmpty = -9999;  // each of v_x, v_y, v_z = EMPTY (SPLIT layout)
inline constexpr int kValueLimit = 999;       // |v| ≤ 999 (|Δ| < 0.1 mm)
inline constexpr int kOverflowValue = -2048;  // the OVERFLOW sentinel (field 2048)
inline constexpr double kValueUnitMm = 1e-4;  // one step of v, mm (0.1 µm)
inline constexpr std::int64_t kMaxDataWord = (std::int64_t{1} << 36) - 1;  // 68 719 476 735

enum class State { kIdle = 0, kMeasuring = 1, kPointReady = 2, kFinished = 3 };

struct ControlWord {
  int lock = 0;    // LK
  int holder = 0;  // HD: 0 machine, 1 collector
  State state = State::kIdle;
  int point = 0;  // PT
  bool operator==(const ControlWord&) const = default;
};

// What a control word means in the protocol; kIllegal for anything outside the legal words.
enum class WordKind { kIdle, kMeasuring, kPointReady, kFinished, kAbort, kIllegal };
const char* WordKindName(WordKind kind);

// The legal words.
ControlWord IdleWord();
ControlWord MeasuringWord(int last_acknowledged);  // (1,0,1,p), also the arming word with p = 0
ControlWord PointReadyWord(int id);                // (1,1,2,i)
ControlWord FinishedWord(int count);               // (1,1,3,N)
ControlWord AbortWord();                           // (1,0,1,4095)

double EncodeControl(const ControlWord& word);
// Decodes any double; nullopt when it is not a whole number in 0..65535 (vacant is handled by the caller).
std::optional<ControlWord> DecodeControl(double value);
// The kind of a decoded word (kIllegal when it is none of the legal words).
WordKind ClassifyControl(const ControlWord& word);
// Decodes and classifies; kIllegal when the value is not a control word at all.
WordKind ClassifyControlValue(double value, ControlWord* word = nullptr);
// "(1,1,2,1234)"
std::string FormatControl(const ControlWord& word);

// Per-axis outcome of decoding one field.
enum class AxisFlag { kOk = 0, kOverflow, kRangeError };
const char* AxisFlagName(AxisFlag flag);

struct DecodedPoint {
  std::array<int, 3> v{};  // 0.1 µm steps; kOverflowValue for an OVERFLOW axis
  std::array<AxisFlag, 3> flags{AxisFlag::kOk, AxisFlag::kOk, AxisFlag::kOk};
  bool ok() const { return flags[0] == AxisFlag::kOk && flags[1] == AxisFlag::kOk && flags[2] == AxisFlag::kOk; }
};

// The value a measuring program writes for one axis: round((measured − reference)·10000), half away
// from zero, or kOverflowValue when |v| ≥ 1000.
int QuantiseDeviation(double deviation_mm);
// 12-bit two's complement of v in −2048..2047; v outside that range is an internal error.
int FieldOf(int v);
// D for three values in −2048..2047 (each already quantised; |v| ≤ 999 or the sentinel).
Result<double> PackData(const std::array<int, 3>& v);
// Decodes D: BadInput when D is not a whole number in 0..2^36 − 1 (EMPTY must be checked first);
// per-axis OVERFLOW / RANGE_ERROR flags otherwise.
Result<DecodedPoint> UnpackData(double d);
// Classifies split values (each must be a whole number in −2048..2047).
Result<DecodedPoint> DecodeSplit(const std::array<double, 3>& v);

enum class Layout { kPacked, kSplit };
const char* LayoutName(Layout layout);
Result<Layout> ParseLayout(const std::string& name);

// Addresses of the block for one layout.
struct BlockLayout {
  Layout layout = Layout::kPacked;
  int base = 900;
  int control() const { return base; }
  int data() const { return base + 1; }  // D (PACKED) or v_x (SPLIT)
  int data_count() const { return layout == Layout::kPacked ? 1 : 3; }
  int run_counter() const { return base + 1 + data_count(); }
  int alarm() const { return run_counter() + 1; }
  int size() const { return data_count() + 3; }  // C, data, Q, A
};

// The axis names used in messages ("X", "Y", "Z").
const char* AxisName(int axis);

}  // namespace formloop::cnc
