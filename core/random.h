#pragma once
// Seeded random numbers that give the same sequence on every platform and standard library.
// std::normal_distribution and friends are implementation-defined, so formloop draws from
// std::mt19937_64 (whose output is fixed by the standard) through its own transforms.

#include <cstdint>
#include <random>

namespace formloop {

class Rng {
 public:
  explicit Rng(std::uint64_t seed) : engine_(seed) {}

  std::uint64_t NextU64() { return engine_(); }
  // Uniform in [0, 1), 53 random bits.
  double Uniform() { return static_cast<double>(engine_() >> 11) * 0x1.0p-53; }
  double Uniform(double lo, double hi) { return lo + (hi - lo) * Uniform(); }
  // Uniform integer in [0, n) without modulo bias. n > 0.
  std::uint64_t UniformIndex(std::uint64_t n);
  // Standard normal by the Marsaglia polar method.
  double Normal();
  double Normal(double mean, double sigma) { return mean + sigma * Normal(); }
  // A seed for a sub-stream, so that adding draws in one stage does not shift another's.
  std::uint64_t Fork() { return engine_() ^ 0x9E3779B97F4A7C15ULL; }

 private:
  std::mt19937_64 engine_;
  bool has_spare_ = false;
  double spare_ = 0;
};

}  // namespace formloop
