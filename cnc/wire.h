#pragma once
// The text protocol between TcpTransport and the emulator process (`formloop link emulate`). One line
// per request and per answer, so it can be read with `nc`:
//
//   <seq> RR <start> <count>            read a range          → <seq> OK <v1> .. <vn>   ("-" = vacant)
//   <seq> WR <start> <v1> .. <vn>       write a range         → <seq> OK
//   <seq> RO <offset>                   read an offset        → <seq> OK <value_mm>
//   <seq> WO <offset> <value_mm>        write an offset       → <seq> OK
//   any refusal                                               → <seq> ERR <text>
//
// Numbers are written in their shortest exact form (FormatExact) and parsed without the locale, so a
// double crosses the wire bit for bit. The sequence number lets a client drop a late answer to a call
// it already gave up on.

#include <cstdint>
#include <string>

#include "cnc/controller.h"
#include "core/status.h"

namespace formloop::cnc {

std::string EncodeRequest(std::uint64_t seq, const ApiRequest& request);
// BadInput naming what is wrong with the line.
Status DecodeRequest(const std::string& line, std::uint64_t* seq, ApiRequest* request);

std::string EncodeResponse(std::uint64_t seq, const ApiRequest& request, const ApiResponse& response);
// Parses an answer to `request` (the op decides what the values mean).
Status DecodeResponse(const std::string& line, const ApiRequest& request, std::uint64_t* seq, ApiResponse* response);

}  // namespace formloop::cnc
