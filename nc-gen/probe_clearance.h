#pragma once
// The probe's clearance from the part on a probing program's moves (internal to nc-gen; the rule is
// described with ProbeProgramOptions::part_surface in nc-gen/probe_program.h).
//
// Per point the ball centre travels: at safe Z from the previous point's position above its start to
// this one's (the traverse), straight down to the start (the descent; the rise after probing goes back
// up the same line), and from the start along the approach a towards the contact position c = nominal
// point + R·n (the probing move; the retract and a two-touch back-off run back along the same line).
// Required gap between the ball (radius R) and the part: g on the traverse, g_p = min(g, ½·clearance·
// cos θ) on the descent (θ the tilt between a and −n: a flat surface leaves clearance·cos θ at the start),
// and on the probing move g_p·s/clearance at the distance s still to go, checked down to s =
// kProbeTouchZone·clearance; closer to c the ball is meant to meet the part. The shank, when
// shank_radius_mm > 0, is a vertical cylinder of that radius from the ball centre up to safe Z; it must
// keep the same gap at the start (the whole descent lies on that one line) and along the probing
// move down to the contact itself.
//
// Method. The distance from a point to the part is the foot-point distance of FootPointProjector::
// Project (reconstruction/foot_point.h, with its global check), negative on the material's side. Beyond
// Q's edge (a foot point the parameter domain's edge holds back, FootPoint::on_boundary) the side is not
// defined — the edge's normal can point either way, e.g. a steep face whose start points lie out past its
// edge — and the unsigned distance is taken: every move is traced from the previous one's end, from safe
// Z, so reaching Q's material side means passing within the required gap of Q, which is refused; the
// part's other faces beyond Q's edge are not known to the check. The distance is
// 1-Lipschitz, so a segment is followed by sphere tracing (J. C. Hart, "Sphere tracing: a geometric
// method for the antialiased ray tracing of implicit surfaces", The Visual Computer 12(10):527-545,
// 1996): a sample whose gap exceeds the requirement by m clears everything within m/(1 + k) of it (k the
// slope of the requirement along the segment), and the next sample is taken there. Near the
// requirement the steps shrink with the margin down to kProbeTraceFineStepMm; a sample followed by that
// least step must clear half of it more ((1 + k)·kProbeTraceFineStepMm/2, at most 0.75 µm), so the check
// never passes a move that comes closer than required and refuses one only when its least gap is within
// that allowance above the requirement. A refusal reports the least gap of the move (sampled every
// kProbeReportStepMm from the first sample short of it). The
// shank's vertical lines along the probing move are taken every kProbeShankSpacingMm and each must clear
// the requirement plus half that spacing (a line moved by δ is within δ of the one before).
//
// Cost: a projection is about 10 µs on open surfaces, up to 0.6 ms inside a steep narrow valley (the
// global check's restarts); a point takes some ten to a few hundred of them.
//
// On a trimmed Q the projection runs over the untrimmed patch (reconstruction/foot_point.h): material
// beyond a trim edge or over a hole counts as part, which can only refuse a safe point, never pass an
// unsafe one.

#include <string>

#include "core/status.h"
#include "nc-gen/post_text.h"
#include "reconstruction/foot_point.h"

namespace formloop::nc::internal {

inline constexpr double kProbeTouchZone = 0.1;          // of the clearance, before the contact: not checked (ball)
inline constexpr double kProbeTraceFineStepMm = 0.001;  // the least step of the sphere tracing
inline constexpr double kProbeReportStepMm = 0.05;      // a refused move's least gap: sampled this often
inline constexpr double kProbeShankSpacingMm = 0.25;    // between the shank's lines along the probing move

// OK when station s keeps its gaps (header comment); `previous` is the station probed before it (its
// position above starts the traverse), null for the first. SafetyLimit otherwise, naming the probe
// point, the move, the gap found and the one required; `finding` (when given) then receives that finding
// without the point and the fix ("the stylus ball would come within ... on the descent ..., at (x, y, z)").
Status CheckProbeClearance(const recon::FootPointProjector& part, const ProbeStation& s, const ProbeStation* previous,
                           const ProbeProgramOptions& options, std::string* finding = nullptr);

}  // namespace formloop::nc::internal
