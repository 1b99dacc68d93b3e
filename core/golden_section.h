#pragma once
// Golden-section search: the minimum of a unimodal function of one variable inside a bracket
// (J. Kiefer, "Sequential minimax search for a maximum", Proc. Amer. Math. Soc. 4 (1953) 502-506;
// W. H. Press et al., Numerical Recipes, 3rd ed., 2007, section 10.2). Two interior points divide the
// bracket in the golden ratio; each step keeps the part that holds the smaller of their two values and
// reuses the surviving interior point, so a step costs one evaluation and shrinks the bracket by
// φ = (√5 - 1)/2 ≈ 0.618. formloop runs it after a coarse grid has found the basin (wear growth's γ).

#include <functional>

namespace formloop {

struct GoldenSectionOptions {
  double tolerance = 1e-7;   // stop once hi - lo <= tolerance (units of x)
  int max_iterations = 200;  // and after this many steps in any case
  // Equal values at the two interior points keep the left part [lo, d] (f(c) <= f(d)); false keeps
  // the right part [c, hi] (the left only when f(c) < f(d)).
  bool ties_keep_left = false;
};

struct GoldenSectionResult {
  double lo = 0, hi = 0;  // the final bracket; the minimum of a unimodal f lies inside it
  int iterations = 0;     // steps taken
  int evaluations = 0;    // calls of f: iterations + 2
  double Mid() const { return 0.5 * (lo + hi); }
};

// Shrinks [lo, hi] (lo <= hi) around a minimum of f. f is called at interior points only, never at
// lo or hi, in a fixed order, so the result is reproducible to the bit.
GoldenSectionResult GoldenSectionMinimise(const std::function<double(double)>& f, double lo, double hi,
                                          const GoldenSectionOptions& options = {});

}  // namespace formloop
