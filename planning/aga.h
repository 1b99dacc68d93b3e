#pragma once
// The one adaptive genetic algorithm of formloop (spec/process-optimization.md §1.6), used by the
// cutting-parameter optimisation of Level 1 (planning/cutting_optimisation.h) and by the plan GA of the
// simulation-correction step (planning/plan_ga.h).
//
// Lineage: Srinivas & Patnaik, "Adaptive probabilities of crossover and mutation in genetic algorithms",
// IEEE Trans. SMC 24(4), 1994 — crossover and mutation probabilities that depend on how an individual's
// fitness stands against the population's maximum and mean. The rates here are the source's variant
// (seed 003, §1.6): P_c = 0.9 − 0.3 (f' − f_avg)/(f_max − f_avg) for parents above the mean (else 0.9),
// P_m = 0.1 − 0.099 (f_max − f)/(f_max − f_avg) above the mean (else 0.1), so the best gets the largest
// mutation rate around it while elitism keeps an unmutated copy. The spec's alternative "protect_best"
// (P_m falling towards the best, Srinivas–Patnaik's direction) was measured and left out: on S1 it
// stalls below 99.5 % of the optimum for some seeds (case A seed 4: 99.44 %; case D seed 5), failing
// the acceptance check the spec sets for selecting it.
//
// Genes are real numbers in [0, 1]; the caller's objective decodes them (feasibility-preserving
// decoding is how the callers handle constraints). Operators: binary tournament (fitness equal within
// 1e-12 relative, then the objective's tie key, larger wins, then the lower index), blend crossover
// (λ ~ U[−0.25, 1.25] per gene, children clamped to [0, 1]), Gaussian mutation per gene with
// σ_g = 0.1 − 0.09 g/(G_max − 1), `elites` best copied unchanged. Stops at G_max generations or when
// the best fitness has gained no more than stall_tolerance·|F_best| over stall_window generations.
//
// Determinism: every draw comes from formloop::Rng seeded with `seed` (mt19937_64 with formloop's own
// transforms); sorts are stable with full tie keys. The same seed and objective give the same result
// bit for bit.

#include <cstdint>
#include <functional>
#include <vector>

#include "core/status.h"

namespace formloop::planning {

struct AgaOptions {
  int population = 40;    // N
  int generations = 100;  // G_max
  int elites = 2;
  int stall_window = 20;          // generations compared by the stall rule
  double stall_tolerance = 1e-7;  // relative gain of the best fitness that counts as progress
  Status Validate() const;
};

// What the objective says about one genome: the fitness (larger is better) and a tie key (larger wins
// among equal fitness; e.g. tool life, or minus the machining time).
struct AgaScore {
  double fitness = 0;
  double tie = 0;
};

using AgaObjective = std::function<AgaScore(const std::vector<double>& genes)>;

struct AgaResult {
  std::vector<double> genes;  // the best genome of the last generation
  AgaScore score;
  int generations = 0;  // generations run (0: the initial population was the last)
  // Per generation 0..generations: the best genome and its fitness.
  std::vector<std::vector<double>> best_genes;
  std::vector<double> best_fitness;
};

// Runs the AGA over `gene_count` genes. The options must Validate (checked by the callers).
AgaResult RunAga(int gene_count, const AgaObjective& objective, const AgaOptions& options, std::uint64_t seed);

// The adaptive rates of §1.6 for a population with largest fitness f_max and mean f_avg: crossover for a
// pair whose fitter parent has f_parent, mutation for an individual of fitness f. A degenerate population
// (f_max − f_avg ≤ 1e-12 max(|f_max|, 1e-300)) gets the fixed rates 0.9 and 0.1.
double AgaCrossoverProbability(double f_max, double f_avg, double f_parent);
double AgaMutationProbability(double f_max, double f_avg, double f);

}  // namespace formloop::planning
