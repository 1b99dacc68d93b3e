#pragma once
// The choice of the smoothing weight λ (GCV, a target RMS, fixed) and of the automatic control net (a
// GCV-scored ladder of nets) for a scattered fit, internal to reconstruction/scattered_fit.cc. The measurements
// behind the choices are beside the constants in scattered_choice.cc.

#include <functional>
#include <memory>
#include <string>
#include <utility>
#include <vector>

#include <nlohmann/json.hpp>

#include "reconstruction/scattered_lsq.h"

namespace formloop::recon::scattered_internal {

struct LambdaChoice {
  TensorLsq::Trial trial;
  std::string note;  // set when the target could not be met
};

// λ for the assembled system by options.smoothing: kGcv (GCV with the uniform energy, then the energy
// weighted locally from that pilot's bias and the fit solved again at the same λ), kTolerance (the largest λ
// whose parametric RMS is at most target_mm; see FitWithCorrection), kNone (kScatteredNoneLambda) or kFixed.
// previous_log: log10 of the previous correction round's λ, NaN for the first. m: the number of points.
LambdaChoice ChooseLambda(TensorLsq& lsq, const ScatteredFitOptions& options, double previous_log, int m,
                          double target_mm);

struct NetChoice {
  int nu = 0, nv = 0;
  nlohmann::json ladder = nlohmann::json::array();  // [u poles, v poles, V in mm²] per rung tried
  std::unique_ptr<TensorLsq> assembled;             // the chosen rung's system (the fit's first round)
};

// The knot vectors of a u × v net (the caller's layout).
using NetKnots = std::function<std::pair<Result<KnotVector>, Result<KnotVector>>(int, int)>;

// The automatic control net (scattered_fit.h, u_poles): rungs of (p + 1) .. nu_max poles along u, each
// kScatteredNetLadderRatio times the last, v in proportion; each fitted by least squares (λ at the floor
// kScatteredNoneLambda) at the initial parameters and scored by V(n) = (RSS/3m) / (1 − n/m)². Stops at the
// first rung whose score does not fall below the best (see kNetFlatGain and kNetResolved in
// scattered_choice.cc); knots(nu, nv) gives the rung's knot vectors.
Result<NetChoice> ChooseNet(const std::vector<Eigen::Vector3d>& centred, const std::vector<double>& u,
                            const std::vector<double>& v, int p, int nu_max, int nv_max, const NetKnots& knots);

}  // namespace formloop::recon::scattered_internal
