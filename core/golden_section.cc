#include "core/golden_section.h"

#include <cmath>

namespace formloop {

GoldenSectionResult GoldenSectionMinimise(const std::function<double(double)>& f, double lo, double hi,
                                          const GoldenSectionOptions& options) {
  const double phi = (std::sqrt(5.0) - 1) / 2;
  GoldenSectionResult out;
  double c = hi - phi * (hi - lo), d = lo + phi * (hi - lo);
  double fc = f(c), fd = f(d);
  out.evaluations = 2;
  for (; out.iterations < options.max_iterations && hi - lo > options.tolerance; ++out.iterations) {
    if (fc < fd || (options.ties_keep_left && fc == fd)) {
      hi = d;
      d = c;
      fd = fc;
      c = hi - phi * (hi - lo);
      fc = f(c);
    } else {
      lo = c;
      c = d;
      fc = fd;
      d = lo + phi * (hi - lo);
      fd = f(d);
    }
    ++out.evaluations;
  }
  out.lo = lo;
  out.hi = hi;
  return out;
}

}  // namespace formloop
