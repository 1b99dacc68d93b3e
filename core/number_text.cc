#include "core/number_text.h"

#include <algorithm>
#include <charconv>
#include <system_error>

namespace formloop {

std::string FormatFixed(double value, int decimals) {
  decimals = std::max(decimals, 0);
  // On the stack for the usual widths (a heap buffer per number costs more than the conversion); the result
  // then fits the string's own small buffer.
  constexpr int kStackDecimals = 40;
  char stack[kStackDecimals + 330];
  std::string heap;
  char* first = stack;
  char* last = stack + sizeof(stack);
  if (decimals > kStackDecimals) {
    heap.resize(static_cast<std::size_t>(decimals) + 330);
    first = heap.data();
    last = first + heap.size();
  }
  const auto result = std::to_chars(first, last, value, std::chars_format::fixed, decimals);
  std::string out(first, result.ptr);
  // "-0.000" (a tiny negative or -0) reads as a sign error in a report or an NC block: drop the sign.
  if (!out.empty() && out.front() == '-' && out.find_first_not_of("0.", 1) == std::string::npos) {
    out.erase(0, 1);
  }
  return out;
}

std::string FormatSignificant(double value, int digits) {
  char buffer[64];
  const auto result =
      std::to_chars(buffer, buffer + sizeof(buffer), value, std::chars_format::general, std::clamp(digits, 1, 40));
  return std::string(buffer, result.ptr);
}

std::string FormatExact(double value) {
  char buffer[64];
  const auto result = std::to_chars(buffer, buffer + sizeof(buffer), value);
  return std::string(buffer, result.ptr);
}

namespace {

enum class Parsed { kNumber, kOutOfRange, kNotANumber };

// The whole of `text` as a double in ParseDouble's syntax (std::from_chars, with one leading '+').
Parsed ParseWhole(std::string_view text, double* value) {
  const char* first = text.data();
  const char* last = text.data() + text.size();
  if (first != last && *first == '+') {
    ++first;
    if (first != last && (*first == '-' || *first == '+')) return Parsed::kNotANumber;
  }
  if (first == last) return Parsed::kNotANumber;
  const auto [ptr, ec] = std::from_chars(first, last, *value);
  if (ptr != last) return Parsed::kNotANumber;
  if (ec == std::errc::result_out_of_range) return Parsed::kOutOfRange;
  return ec == std::errc() ? Parsed::kNumber : Parsed::kNotANumber;
}

}  // namespace

bool ParseDouble(std::string_view text, double* value) {
  double parsed = 0;
  if (ParseWhole(text, &parsed) != Parsed::kNumber) return false;
  *value = parsed;
  return true;
}

bool NumberBeyondDoubleRange(std::string_view text) {
  double parsed = 0;
  return ParseWhole(text, &parsed) == Parsed::kOutOfRange;
}

}  // namespace formloop
