#pragma once
// Test support: run a scope under another global locale, e.g. one with a comma as decimal point,
// to show that formloop's text output does not depend on it.

#include <locale>
#include <string>

namespace formloop::testing {

// Sets the global C++ (and, for named locales, C) locale for one scope.
class GlobalLocale {
 public:
  explicit GlobalLocale(const std::locale& locale) : previous_(std::locale::global(locale)) {}
  ~GlobalLocale() { std::locale::global(previous_); }
  GlobalLocale(const GlobalLocale&) = delete;
  GlobalLocale& operator=(const GlobalLocale&) = delete;

 private:
  std::locale previous_;
};

// German-style numbers without needing an installed locale: "1.234,5".
struct CommaNumpunct : std::numpunct<char> {
  char do_decimal_point() const override { return ','; }
  char do_thousands_sep() const override { return '.'; }
  std::string do_grouping() const override { return "\3"; }
};

}  // namespace formloop::testing
