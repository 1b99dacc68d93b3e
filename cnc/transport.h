#pragma once
// The transport to a controller, shaped like the controllers' own APIs so a vendor adapter slots in:
// FOCAS (cnc_rdmacror2 / cnc_wrmacror2 for a consecutive range of macro variables, cnc_rdtofs /
// cnc_wrtofs for tool offsets, cnc_rdzofs / cnc_wrzofs for work offsets), a Sinumerik or Heidenhain
// link (R parameters / Q parameters and offset tables), LinuxCNC (HAL pins and the tool table).
// TcpTransport (cnc/tcp_transport.h) talks to formloop's emulated controller over TCP.
//
// Errors: IoError means the connection is gone (the transport is disconnected; call Connect() again);
// Failed means the controller refused this call (an API error code) and the connection is still up.
// Either way the outcome of a write is UNKNOWN to the caller: it may or may not have been applied.
// The collector never repeats a write blindly; it reads the block again and decides from what it sees.

#include <optional>
#include <string>
#include <vector>

#include "core/status.h"

namespace formloop::cnc {

// A macro variable's value; nullopt = vacant (Fanuc #0, "<vacant>").
using MacroValue = std::optional<double>;

enum class OffsetKind { kToolRadiusWear, kToolLengthWear, kWorkOffset };

// One controller offset. Text form (the wire and the emulator's table): "T3.radius_wear",
// "T3.length_wear", "G54.X".
struct OffsetAddress {
  OffsetKind kind = OffsetKind::kToolRadiusWear;
  int tool = 0;     // tool kinds: 1..9999
  std::string wcs;  // WORK_OFFSET: G54..G59
  int axis = 0;     // WORK_OFFSET: 0 X, 1 Y, 2 Z
  bool operator<(const OffsetAddress& o) const { return ToString() < o.ToString(); }
  bool operator==(const OffsetAddress& o) const { return ToString() == o.ToString(); }
  std::string ToString() const;
};
Result<OffsetAddress> ParseOffsetAddress(const std::string& text);

class MacroTransport {
 public:
  virtual ~MacroTransport() = default;
  virtual Status Connect() = 0;
  virtual void Disconnect() = 0;
  // `count` consecutive variables from `start` in one call.
  virtual Result<std::vector<MacroValue>> ReadRange(int start, int count) = 0;
  // Consecutive variables from `start`, written in ascending order in one call.
  virtual Status WriteRange(int start, const std::vector<double>& values) = 0;
  Status Write(int address, double value) { return WriteRange(address, {value}); }
  virtual Result<double> ReadOffset(const OffsetAddress& offset) = 0;
  virtual Status WriteOffset(const OffsetAddress& offset, double value_mm) = 0;
  // Where it talks to, for messages ("127.0.0.1:5800").
  virtual std::string Describe() const = 0;
};

}  // namespace formloop::cnc
