#include "planning/aga.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <numeric>

#include "core/random.h"

namespace formloop::planning {
namespace {

struct Individual {
  std::vector<double> xi;
  AgaScore score;
};

using Population = std::vector<Individual>;

// Tournament and elite order: higher fitness (equal within 1e-12 relative), then the larger tie key,
// then the lower index.
bool Better(const Population& pop, std::size_t a, std::size_t b) {
  const double fa = pop[a].score.fitness, fb = pop[b].score.fitness;
  if (std::abs(fa - fb) > 1e-12 * std::max(std::abs(fa), std::abs(fb))) return fa > fb;
  if (pop[a].score.tie != pop[b].score.tie) return pop[a].score.tie > pop[b].score.tie;
  return a < b;
}

std::size_t Tournament(const Population& pop, Rng& rng) {
  const std::size_t a = rng.UniformIndex(pop.size()), b = rng.UniformIndex(pop.size());
  return Better(pop, a, b) ? a : b;
}

struct FitnessStats {
  double f_max = -std::numeric_limits<double>::infinity();
  double f_avg = 0;
};

FitnessStats StatsOf(const Population& pop) {
  FitnessStats st;
  for (const Individual& ind : pop) {
    st.f_max = std::max(st.f_max, ind.score.fitness);
    st.f_avg += ind.score.fitness;
  }
  st.f_avg /= static_cast<double>(pop.size());
  return st;
}

bool Flat(double f_max, double f_avg) { return f_max - f_avg <= 1e-12 * std::max(std::abs(f_max), 1e-300); }

std::vector<std::size_t> RankedIndices(const Population& pop) {
  std::vector<std::size_t> idx(pop.size());
  std::iota(idx.begin(), idx.end(), 0);
  std::stable_sort(idx.begin(), idx.end(), [&](std::size_t a, std::size_t b) { return Better(pop, a, b); });
  return idx;
}

class Aga {
 public:
  Aga(const AgaObjective& objective, const AgaOptions& options, std::uint64_t seed)
      : objective_(objective), options_(options), rng_(seed) {}

  Population Initial(int gene_count) {
    Population pop(static_cast<std::size_t>(options_.population));
    for (Individual& ind : pop) {
      ind.xi.resize(static_cast<std::size_t>(gene_count));
      for (double& g : ind.xi) g = rng_.Uniform();
      ind.score = objective_(ind.xi);
    }
    return pop;
  }

  Population Next(const Population& pop, int g) {
    const FitnessStats st = StatsOf(pop);
    const double sigma = 0.1 - 0.09 * g / std::max(1, options_.generations - 1);
    Population next;
    next.reserve(pop.size());
    const std::vector<std::size_t> ranked = RankedIndices(pop);
    for (int e = 0; e < options_.elites && e < static_cast<int>(pop.size()); ++e) next.push_back(pop[ranked[e]]);
    while (next.size() < pop.size()) {
      const Individual& p1 = pop[Tournament(pop, rng_)];
      const Individual& p2 = pop[Tournament(pop, rng_)];
      std::vector<double> c1 = p1.xi, c2 = p2.xi;
      if (rng_.Uniform() < AgaCrossoverProbability(st.f_max, st.f_avg, std::max(p1.score.fitness, p2.score.fitness))) {
        for (std::size_t k = 0; k < c1.size(); ++k) {  // blend crossover, λ ∈ [−0.25, 1.25] per gene
          const double lambda = rng_.Uniform(-0.25, 1.25);
          c1[k] = std::clamp(lambda * p1.xi[k] + (1 - lambda) * p2.xi[k], 0.0, 1.0);
          c2[k] = std::clamp(lambda * p2.xi[k] + (1 - lambda) * p1.xi[k], 0.0, 1.0);
        }
      }
      next.push_back(Child(std::move(c1), st, sigma));
      if (next.size() < pop.size()) next.push_back(Child(std::move(c2), st, sigma));
    }
    return next;
  }

 private:
  // Evaluates the child, mutates each gene with its P_m and evaluates again when anything changed.
  Individual Child(std::vector<double> xi, const FitnessStats& st, double sigma) {
    Individual child{std::move(xi), {}};
    child.score = objective_(child.xi);
    const double p_m = AgaMutationProbability(st.f_max, st.f_avg, child.score.fitness);
    bool mutated = false;
    for (double& gene : child.xi) {
      if (rng_.Uniform() < p_m) {
        gene = std::clamp(gene + sigma * rng_.Normal(), 0.0, 1.0);
        mutated = true;
      }
    }
    if (mutated) child.score = objective_(child.xi);
    return child;
  }

  const AgaObjective& objective_;
  const AgaOptions& options_;
  Rng rng_;
};

}  // namespace

Status AgaOptions::Validate() const {
  if (population < 2) return Status::BadInput(Where{.field = "population"}, "must be at least 2");
  if (generations < 1) return Status::BadInput(Where{.field = "generations"}, "must be at least 1");
  if (elites < 0 || elites >= population) {
    return Status::BadInput(Where{.field = "elites"}, "must be in [0, population)");
  }
  if (stall_window < 1) return Status::BadInput(Where{.field = "stall_window"}, "must be at least 1");
  if (!(stall_tolerance >= 0)) return Status::BadInput(Where{.field = "stall_tolerance"}, "must be >= 0");
  return Status::Ok();
}

double AgaCrossoverProbability(double f_max, double f_avg, double f_parent) {
  if (Flat(f_max, f_avg) || f_parent < f_avg) return 0.9;
  return 0.9 - 0.3 * (f_parent - f_avg) / (f_max - f_avg);
}

// As printed (f_max − f): the best gets the largest rate around it; elitism keeps its unmutated copy.
double AgaMutationProbability(double f_max, double f_avg, double f) {
  if (Flat(f_max, f_avg) || f < f_avg) return 0.1;
  return 0.1 - 0.099 * (f_max - f) / (f_max - f_avg);
}

AgaResult RunAga(int gene_count, const AgaObjective& objective, const AgaOptions& options, std::uint64_t seed) {
  Aga aga(objective, options, seed);
  Population pop = aga.Initial(gene_count);
  AgaResult out;
  int g = 0;
  for (;; ++g) {
    const Individual& best = pop[RankedIndices(pop).front()];
    out.best_genes.push_back(best.xi);
    out.best_fitness.push_back(best.score.fitness);
    const double f_now = best.score.fitness;
    const auto window = static_cast<std::size_t>(options.stall_window);
    const bool stalled =
        static_cast<std::size_t>(g) >= window &&
        f_now - out.best_fitness[static_cast<std::size_t>(g) - window] <= options.stall_tolerance * std::abs(f_now);
    if (g >= options.generations || stalled) break;
    pop = aga.Next(pop, g);
  }
  const Individual& best = pop[RankedIndices(pop).front()];
  out.genes = best.xi;
  out.score = best.score;
  out.generations = g;
  return out;
}

}  // namespace formloop::planning
