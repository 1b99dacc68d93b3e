#pragma once
// Numbers as text and back, without the locale: the one formatter every writer in formloop uses (NC
// programs, CSV and JSON side files, reports, messages). Built on std::to_chars / std::from_chars, so
// "1.5" never becomes "1,5" whatever LC_NUMERIC says, and the same double always gives the same text.

#include <string>
#include <string_view>

namespace formloop {

// FormatFixed(1.5, 3) == "1.500". A result that rounds to zero carries no sign ("0.000", not "-0.000").
// decimals < 0 counts as 0.
std::string FormatFixed(double value, int decimals);
// Shortest text that reads back to exactly the same double.
std::string FormatExact(double value);
// `digits` significant digits, trailing zeros dropped, exponent form for very large or small values:
// printf's "%.<digits>g" (FormatSignificant(0.000012345, 3) == "1.23e-05"). digits is clamped to 1..40.
std::string FormatSignificant(double value, int digits = 6);
// Parses the whole string as a finite or non-finite double; false on anything else (" 1", "1x", "").
// A leading '+' is accepted.
bool ParseDouble(std::string_view text, double* value);
// True when text is a number in ParseDouble's syntax whose magnitude a double cannot hold ("1e400",
// "1e-400"), so a reader can say so instead of "not a number".
bool NumberBeyondDoubleRange(std::string_view text);

}  // namespace formloop
