#pragma once
// Probing programs from a probing plan (spec/nc-gen.md §5). This first post is LinuxCNC: for each
// point a rapid to a clearance point along the normal, a G38.2 probing move along −n that ends a
// search distance beyond the surface, a retract; results are logged between (PROBEOPEN ...) and
// (PROBECLOSE). The programmed point is the stylus-ball centre.

#include <string>

#include "core/status.h"
#include "metrology/probe.h"
#include "nc-gen/post.h"

namespace formloop::nc {

struct ProbeProgramOptions {
  double ball_radius_mm = 1.0;
  double clearance_mm = 3.0;          // start this far from the surface along n
  double search_mm = 2.0;             // probe this far beyond the nominal surface
  double probe_feed_mm_per_min = 200;
  double safe_z_mm = 50;              // rapids between points
  std::string results_file = "probe_results.txt";
  PostOptions post;
  Status Validate() const;
};

Result<std::string> PostLinuxCncProbing(const metrology::ProbingPlan& plan, const ProbeProgramOptions& options);

}  // namespace formloop::nc
