// The quadric itself (reconstruction/quadric_fit.h): its centre form, value, JSON, and the orthogonal
// distance of a point to it (QuadricFootPoint). quadric_fit.cc fits one to points (algebraic, then geometric).

#include <Eigen/Dense>
#include <algorithm>
#include <array>
#include <cmath>
#include <limits>
#include <string>

#include "core/number_text.h"
#include "reconstruction/point_checks.h"
#include "reconstruction/quadric_fit.h"

namespace formloop::recon {
namespace {

using Eigen::Vector3d;

constexpr double kEps = std::numeric_limits<double>::epsilon();
constexpr const char* kAxisName[3] = {"x", "y", "z"};

std::string Num(double value, int precision = 6) { return FormatSignificant(value, precision); }

nlohmann::json ToJsonArray(const Vector3d& v) { return nlohmann::json::array({v.x(), v.y(), v.z()}); }

int SignOf(double v) { return v < 0 ? -1 : 1; }

}  // namespace

// ---------------------------------------------------------------------------------------------
// Quadric and its centre form

nlohmann::json QuadricCentreForm::ToJson() const {
  return nlohmann::json{
      {"centre_mm", ToJsonArray(centre)},
      {"semi_axes_mm", ToJsonArray(semi_axes)},
      {"signs", nlohmann::json::array({signs.x(), signs.y(), signs.z()})},
      {"kind", kind},
      {"sign_flipped", sign_flipped},
      {"form", "s_x (x - x0)^2/A^2 + s_y (y - y0)^2/B^2 + s_z (z - z0)^2/C^2 = 1"},
  };
}

double Quadric::Evaluate(const Vector3d& p) const {
  return p.x() * p.x() + a * p.y() * p.y() + b * p.z() * p.z() + c * p.x() + d * p.y() + e * p.z() + f;
}

Vector3d Quadric::Gradient(const Vector3d& p) const { return {2 * p.x() + c, 2 * a * p.y() + d, 2 * b * p.z() + e}; }

Result<QuadricCentreForm> Quadric::CentreForm() const {
  if (!std::isfinite(a) || !std::isfinite(b) || !std::isfinite(c) || !std::isfinite(d) || !std::isfinite(e) ||
      !std::isfinite(f)) {
    return Status::BadInput(Where{.field = "quadric"}, "a coefficient is not finite", "");
  }
  if (std::abs(a) <= kMinQuadraticRatio || std::abs(b) <= kMinQuadraticRatio) {
    return Status::BadInput(Where{.field = "quadric"},
                            "a = " + Num(a) + ", b = " + Num(b) +
                                ": the y² or z² coefficient vanishes next to x², so the surface is a paraboloid or a "
                                "cylinder and has no centre (x0, y0, z0)",
                            "use the general form a..f, or a B-spline fit");
  }
  QuadricCentreForm form;
  form.centre = Vector3d(-c / 2, -d / (2 * a), -e / (2 * b));
  const Vector3d& o = form.centre;
  const double g = o.x() * o.x() + a * o.y() * o.y() + b * o.z() * o.z() - f;
  // g is a difference of terms of this size; below a few hundred ulps of it, g is rounding: a cone.
  const double g_scale = o.x() * o.x() + std::abs(a) * o.y() * o.y() + std::abs(b) * o.z() * o.z() + std::abs(f);
  if (!(std::abs(g) > 256 * kEps * g_scale)) {
    return Status::BadInput(Where{.field = "quadric"},
                            "g = x0² + a y0² + b z0² − f = " + Num(g) +
                                " mm² is zero to rounding: the surface is a cone (apex " + PointText(o) +
                                ") with no semi-axes",
                            "use the general form a..f");
  }
  form.sign_flipped = g < 0;
  const double flip = form.sign_flipped ? -1.0 : 1.0;
  form.signs = Eigen::Vector3i(static_cast<int>(flip), SignOf(flip * a), SignOf(flip * b));
  const int n_plus = static_cast<int>((form.signs.array() > 0).count());
  if (n_plus == 0) {
    return Status::BadInput(Where{.field = "quadric"},
                            "every sign of the centre form is negative: the quadric has no real points "
                            "(an imaginary ellipsoid)",
                            "check the data; a real surface has at least one + sign");
  }
  form.kind = n_plus == 3 ? "ellipsoid" : n_plus == 2 ? "hyperboloid_one_sheet" : "hyperboloid_two_sheets";
  const double g_abs = std::abs(g);
  form.semi_axes = Vector3d(std::sqrt(g_abs), std::sqrt(g_abs / std::abs(a)), std::sqrt(g_abs / std::abs(b)));
  return form;
}

Result<Quadric> Quadric::FromCentreForm(const QuadricCentreForm& form) {
  if (!form.centre.allFinite() || !form.semi_axes.allFinite() || !(form.semi_axes.minCoeff() > 0)) {
    return Status::BadInput(Where{.field = "centre_form"},
                            "centre and semi-axes must be finite and the semi-axes positive, got centre " +
                                PointText(form.centre) + ", semi-axes " + PointText(form.semi_axes),
                            "");
  }
  for (int i = 0; i < 3; ++i) {
    if (form.signs(i) != 1 && form.signs(i) != -1) {
      return Status::BadInput(Where{.field = std::string("centre_form.signs.") + kAxisName[i]},
                              "sign " + std::to_string(form.signs(i)) + " is not +1 or -1", "");
    }
  }
  if ((form.signs.array() > 0).count() == 0) {
    return Status::BadInput(Where{.field = "centre_form.signs"}, "all signs negative: no real points",
                            "make at least one sign +1");
  }
  // Multiply s_x (x−x0)²/A² + ... = 1 by s_x A² so that x² has coefficient 1.
  const Vector3d& o = form.centre;
  const Vector3d& s = form.semi_axes;
  const double sx = form.signs.x();
  Quadric q;
  q.a = sx * form.signs.y() * (s.x() * s.x()) / (s.y() * s.y());
  q.b = sx * form.signs.z() * (s.x() * s.x()) / (s.z() * s.z());
  q.c = -2 * o.x();
  q.d = -2 * q.a * o.y();
  q.e = -2 * q.b * o.z();
  q.f = o.x() * o.x() + q.a * o.y() * o.y() + q.b * o.z() * o.z() - sx * s.x() * s.x();
  return q;
}

nlohmann::json Quadric::ToJson() const {
  return nlohmann::json{
      {"form", "x^2 + a y^2 + b z^2 + c x + d y + e z + f = 0"},
      {"a", a},
      {"b", b},
      {"c_mm", c},
      {"d_mm", d},
      {"e_mm", e},
      {"f_mm2", f},
  };
}

nlohmann::json QuadricFit::ToJson() const {
  return nlohmann::json{
      {"method", method},
      {"n_points", n_points},
      {"quadric", quadric.ToJson()},
      {"centre_form", centre_form ? centre_form->ToJson() : nlohmann::json(nullptr)},
      {"distance", "true orthogonal distance of each fitted point to the fitted quadric"},
      {"rms_distance_mm", rms_distance_mm},
      {"max_distance_mm", max_distance_mm},
      {"max_at_mm", ToJsonArray(max_at)},
      {"rms_algebraic_mm2", rms_algebraic},
      {"iterations", iterations},
      {"converged", converged},
      {"notes", notes},
  };
}

// ---------------------------------------------------------------------------------------------
// Orthogonal distance (see the header for the method and its sources).

Result<QuadricFoot> QuadricFootPoint(const Quadric& quadric, const Vector3d& p) {
  if (!p.allFinite()) {
    return Status::BadInput(Where{.field = "point"}, "point " + PointText(p) + " is not finite", "");
  }
  const Vector3d dq(1, quadric.a, quadric.b);
  const Vector3d lq(quadric.c, quadric.d, quadric.e);
  if (!dq.allFinite() || !lq.allFinite() || !std::isfinite(quadric.f)) {
    return Status::BadInput(Where{.field = "quadric"}, "a coefficient is not finite", "");
  }
  // Move the origin to the centre along every axis that has one, so G has no linear term there and the
  // foot's coordinates are small numbers relative to it (no cancellation for parts far from the origin).
  Vector3d ctr = Vector3d::Zero(), lin = lq;
  for (int i = 0; i < 3; ++i) {
    if (std::abs(dq(i)) > kMinQuadraticRatio) {
      ctr(i) = -lq(i) / (2 * dq(i));
      lin(i) = 0;
    }
  }
  const double g0 = quadric.Evaluate(ctr);  // constant term in the moved frame
  const Vector3d pt = p - ctr;
  auto value_at = [&](const Vector3d& y) { return dq.dot(y.cwiseProduct(y)) + lin.dot(y) + g0; };
  auto finish = [&](const Vector3d& y, double lambda, bool ambiguous, double side) {
    QuadricFoot out;
    out.foot = ctr + y;
    const Vector3d grad = 2 * dq.cwiseProduct(y) + lin;
    const double grad_norm = grad.norm();
    out.normal = grad_norm > 0 ? Vector3d(grad / grad_norm) : Vector3d::Zero();
    out.distance_mm = side * (pt - y).norm();
    out.lambda = lambda;
    out.ambiguous = ambiguous;
    return out;
  };

  const double g_p = value_at(pt);
  if (g_p == 0) return finish(pt, 0, false, 0);
  const double side = g_p > 0 ? 1.0 : -1.0;

  // Empty quadric: an ellipsoid in every axis with G > 0 at its centre. G = 0 there: a single point.
  if ((dq.array() > kMinQuadraticRatio).all()) {
    if (g0 > 0) {
      return Status::BadInput(Where{.field = "quadric"},
                              "the quadric has no real points (G > 0 everywhere: an imaginary ellipsoid)",
                              "check the fit; a real surface needs g = x0² + a y0² + b z0² − f > 0");
    }
    if (g0 == 0) return finish(Vector3d::Zero(), 0, false, side);
  }

  // The admissible interval of λ is (L, U): every 1 + λ D_i > 0. D_x = 1 > 0, so L is finite.
  const double d_max = dq.maxCoeff();
  const double d_min = dq.minCoeff();
  const double lower = -1 / d_max;
  const bool has_upper = d_min < 0;
  const double upper = has_upper ? -1 / d_min : std::numeric_limits<double>::infinity();

  // The secular function in the offset t from an anchor pole: λ = anchor + dir·t, with numerators and
  // denominators precomputed at the anchor and the pole's own denominator set to exactly 0.
  struct Frame {
    double anchor, dir;
    Vector3d num0, den0;
    std::array<bool, 3> pole;
  };
  auto make_frame = [&](bool at_lower) {
    Frame fr;
    fr.anchor = at_lower ? lower : upper;
    fr.dir = at_lower ? 1.0 : -1.0;
    const double d_pole = at_lower ? d_max : d_min;
    for (int i = 0; i < 3; ++i) {
      fr.pole[i] = dq(i) == d_pole;
      fr.num0(i) = pt(i) - fr.anchor * lin(i) / 2;
      fr.den0(i) = fr.pole[i] ? 0.0 : 1 + fr.anchor * dq(i);
    }
    return fr;
  };
  struct Eval {
    Vector3d y;
    double phi, dphi_dt;
  };
  auto evaluate = [&](const Frame& fr, double t) {
    Eval ev;
    double dphi_dlambda = 0;
    for (int i = 0; i < 3; ++i) {
      const double num = fr.num0(i) - fr.dir * t * lin(i) / 2;
      const double den = fr.den0(i) + fr.dir * t * dq(i);
      ev.y(i) = num / den;
      const double gi = 2 * dq(i) * ev.y(i) + lin(i);
      dphi_dlambda -= gi * gi / (2 * den);
    }
    ev.phi = value_at(ev.y);
    ev.dphi_dt = fr.dir * dphi_dlambda;
    return ev;
  };

  // Bracket the root on the side of λ = 0 given by G(p), and anchor at the nearer pole.
  Frame fr = make_frame(true);
  double t_lo, t_hi, t_start;
  bool touches_pole = false;  // the bracket's t = 0 end is the anchor pole
  if (g_p < 0) {
    t_lo = 0;
    t_hi = -lower;  // λ = 0
    t_start = t_hi;
    touches_pole = true;
  } else if (has_upper) {
    const Eval mid = evaluate(fr, -lower + upper / 2);
    if (mid.phi == 0) return finish(mid.y, upper / 2, false, side);
    if (mid.phi < 0) {
      t_lo = -lower;
      t_hi = -lower + upper / 2;
      t_start = t_lo;
    } else {
      fr = make_frame(false);
      t_lo = 0;
      t_hi = upper / 2;
      t_start = t_hi / 2;
      touches_pole = true;
    }
  } else {
    t_lo = -lower;
    t_hi = 2 * t_lo;
    int doublings = 0;
    while (!(evaluate(fr, t_hi).phi < 0)) {
      t_hi *= 2;
      if (++doublings > 1100 || !std::isfinite(t_hi)) {
        return Status::BadInput(Where{.field = "quadric"},
                                "no foot point for " + PointText(p) +
                                    ": the secular equation has no root, so the quadric has no real points",
                                "check the fit");
      }
    }
    t_start = t_lo;
  }

  // Hard case: p on the symmetry plane(s) of the anchor pole and the rest of φ already on the root's side
  // at the pole: the multiplier is the pole itself and the pole coordinate follows from G = 0.
  bool on_pole_planes = touches_pole;
  for (int i = 0; i < 3; ++i) on_pole_planes = on_pole_planes && (!fr.pole[i] || fr.num0(i) == 0);
  if (on_pole_planes) {
    Vector3d y = Vector3d::Zero();
    for (int i = 0; i < 3; ++i) {
      if (!fr.pole[i]) y(i) = fr.num0(i) / fr.den0(i);
    }
    const double rest = value_at(y);
    const double d_pole = fr.dir > 0 ? d_max : d_min;
    if (fr.dir * rest <= 0) {
      const int k = fr.pole[0] ? 0 : fr.pole[1] ? 1 : 2;
      y(k) = std::sqrt(std::max(0.0, -rest / d_pole));
      const int n_pole = fr.pole[0] + fr.pole[1] + fr.pole[2];
      return finish(y, fr.anchor, y(k) > 0 || n_pole > 1, side);
    }
  }

  // ψ = dir·φ decreases in t; ψ > 0 at t_lo and < 0 at t_hi (as limits at a pole).
  double t = t_start;
  Eval ev = evaluate(fr, t);
  for (int iter = 0; iter < 400; ++iter) {
    const double psi = fr.dir * ev.phi;
    if (psi == 0) break;
    if (psi > 0) {
      t_lo = std::max(t_lo, t);
    } else {
      t_hi = std::min(t_hi, t);
    }
    double t_next = t - ev.phi / ev.dphi_dt;
    if (!(t_next > t_lo && t_next < t_hi)) t_next = t_lo + (t_hi - t_lo) / 2;
    const bool done = std::abs(t_next - t) <= 4 * kEps * std::abs(t) || t_hi - t_lo <= 4 * kEps * t_hi;
    t = t_next;
    ev = evaluate(fr, t);
    if (done) break;
  }
  return finish(ev.y, fr.anchor + fr.dir * t, false, side);
}

}  // namespace formloop::recon
