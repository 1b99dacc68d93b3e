#pragma once
// Probing programs from a probing plan (spec/nc-gen.md §5), in the four post dialects: each dialect's
// probing format is part of its post (PostDialect::FormatProbing, nc-gen/post_<dialect>.cc, where its
// conventions and sources are written down), so a new dialect brings its probing with it. Every dialect has
// the same structure: per point a rapid at safe Z over a clearance point that lies clearance_mm above the
// surface along +n (along −a for a tilted approach a), down to it, a probing move along −n that ends search_mm beyond
// the nominal surface, a retract along +n and up to safe Z, and the point id in a comment ("point <id>"), so logs map
// back to the plan. The programmed point is the stylus-ball centre (nominal contact point + R·n). Before any text is
// written, the probe feed and every position (above, clearance, search end) of every point are checked
// against MachineLimits, and, when the part's surface is given, every move against the part
// (ProbeProgramOptions::part_surface); a refusal names the probe point id and no program is returned.
//
//   "linuxcnc"   G38.2 probing, results logged between (PROBEOPEN file) and (PROBECLOSE). With touch_feed_mm_per_min >
//   0 each point is probed twice: the
//                G38.2 at probe_feed_mm_per_min finds the surface, a rapid backs off backoff_mm along +n
//                and a second G38.2 at the slow touch feed measures it (LinuxCNC records the position of
//                the first servo period after the trigger, so the error is up to feed × period). With a
//                linuxcnc_log_file, (LOGOPEN,file) receives one line per point after its last touch:
//                  point <id> <x> <y> <z> <tripped> <ax> <ay> <az> [<t_s>]
//                (#5061..#5063 the ball centre in the work frame, #5070 = 1 when the probe tripped, a the
//                unit approach direction −n, t_s the analog input linuxcnc_time_input read by M66 .. L0
//                just after the touch), after a first line "formloop probe log 1: point id x y z tripped
//                ax ay az [t_s]". cnc/linuxcnc_probe_log.h reads it into a probe log.
//   "fanuc"      G31 skip function; after each probe the skip position #5061..#5063 (workpiece frame) is
//                copied into common variables #[base+3k], #[base+3k+1], #[base+3k+2] for the k-th point
//                (k from 0 in plan order). The range must lie in #100..#199 or #500..#999.
//   "heidenhain" TNC 640 cycle 444 (PROBING IN 3-D) with the nominal surface point and its normal; the
//                cycle itself approaches along the normal (see probe_program.cc for the Q parameters and
//                what is uncertain about them).
//   "sinumerik"  840D sl MEAS=1 G1 (measuring with deletion of distance to go); the measured position
//                $AA_MW[X/Y/Z] (workpiece frame) is copied into R[base+3k] .. R[base+3k+2].

#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include "core/status.h"
#include "metrology/probe.h"
#include "nc-gen/post.h"
#include "reconstruction/foot_point.h"

namespace formloop::nc {

struct ProbeProgramOptions {
  double ball_radius_mm = 1.0;
  double clearance_mm = 3.0;  // start this far from the surface along n
  double search_mm = 2.0;     // probe this far beyond the nominal surface
  double probe_feed_mm_per_min = 200;
  double safe_z_mm = 50;  // rapids between points
  // The probe's tool number: the program changes to it (T.. M6; TOOL CALL on Heidenhain) and activates its
  // length offset (G43 H<tool> on LinuxCNC and Fanuc, D1 on Sinumerik), which must be measured to the
  // stylus-ball centre, the programmed point.
  int probe_tool = 99;
  std::string results_file = "probe_results.txt";  // LinuxCNC (PROBEOPEN)
  // LinuxCNC: > 0 probes each point twice, the second time at this feed (header comment); 0 = once.
  double touch_feed_mm_per_min = 0;
  double backoff_mm = 0.2;        // LinuxCNC, two touches: back off this far along +n between them
  std::string linuxcnc_log_file;  // LinuxCNC: (LOGOPEN) file with one line per point; empty = none
  int linuxcnc_time_input = -1;   // LinuxCNC: analog input logged as t_s (M66 E.. L0); -1 = none
  int fanuc_result_base = 500;    // Fanuc: first macro variable of the result range (#500)
  int sinumerik_r_base = 10;      // Sinumerik: first R parameter of the result range (R10)
  // Sinumerik: the last R parameter the control has (MD28050 MM_NUM_R_PARAM − 1; 99 by default).
  int sinumerik_r_last = 99;
  // Per plan point (plan order), the unit approach direction of a tilted probe (a separating experiment,
  // simulation/proposal_plan.h); empty: every point along −n. A point's clearance and search end then lie
  // along a from the ball centre at contact (nominal point + R·n): start = c − clearance·a, search end =
  // c + search·a, the probing move along a, the back-off along −a and the LOG line's approach = a (the
  // controlled point is the ball centre, which is what moves along a). An approach must come down onto
  // the part (a_z < 0) within kMaxApproachTiltDeg of −n. Heidenhain's cycle 444 probes along the normal it
  // is given and refuses a tilted point.
  std::vector<Eigen::Vector3d> approaches;
  // The part's surface Q (a foot-point projector on it). Given, the moves of every point are checked
  // against it before any text is written (nc-gen/probe_clearance.h): the stylus ball keeps min_gap_mm
  // from the part on the traverse at safe Z, min(min_gap_mm, ½·clearance·cos tilt) on the vertical
  // descent to the start, and that gap shrinking towards the contact on the probing move; the shank too
  // when shank_radius_mm > 0. A point that fails (tilted or along −n) is tried again with the clearance
  // halved, then quartered (above backoff_mm with two touches): the first that clears is programmed (a
  // warning names the point and the clearance); otherwise the program is refused naming the point, the
  // move and the least gap on it (SafetyLimit). Not given: nothing is checked against the part.
  std::optional<recon::FootPointProjector> part_surface;
  double min_gap_mm = 1.0;
  double shank_radius_mm = 0;  // the stylus shank, a vertical cylinder above the ball centre; 0 = not checked
  PostOptions post;
  Status Validate() const;
};

inline constexpr double kMaxApproachTiltDeg = 60;

// The dialects PostProbing knows: every post (PostNames()), in registry order.
std::vector<std::string> ProbingDialectNames();

// The probing program for `plan` in `dialect` (a name of PostNames()); unknown dialects are refused.
Result<std::string> PostProbing(const metrology::ProbingPlan& plan, std::string_view dialect,
                                const ProbeProgramOptions& options);

// The plan split into consecutive batches of at most the dialect's ProbeResultCapacity points (all in one
// when it has no limit or the plan fits), each posted as its own program with " (batch i of n, points
// a-b)" appended to the title; every batch stores its results from the same base, so the controller's
// results are read out after each batch (issue 17 item 7: 400 points on a Fanuc with #500-#999).
Result<std::vector<std::string>> PostProbingBatches(const metrology::ProbingPlan& plan, std::string_view dialect,
                                                    const ProbeProgramOptions& options);

// = PostProbing(plan, "linuxcnc", options).
Result<std::string> PostLinuxCncProbing(const metrology::ProbingPlan& plan, const ProbeProgramOptions& options);

}  // namespace formloop::nc
