// The nine analytic reference surfaces (spec/reconstruction.md §1) and their registry.
//
// Each surface gives exact first and second derivatives, has n_z > 0 on its whole domain, sizes of a
// typical machined part (about 100 mm × 80-100 mm, heights within ±50 mm) and no concave radius of
// curvature below 10 mm, so a 6 mm ball can cut it. The tests check all of this on a grid.

#include <cmath>
#include <functional>
#include <numbers>

#include "core/number_text.h"
#include "reconstruction/analytic_surface.h"

namespace formloop::recon {
namespace {

using Eigen::Vector3d;

// Derivatives of a graph z = f(x, y) from f and its partials.
SurfaceDerivatives GraphDerivatives(double x, double y, double f, double fx, double fy, double fxx, double fxy,
                                    double fyy) {
  SurfaceDerivatives d;
  d.p = Vector3d(x, y, f);
  d.su = Vector3d(1, 0, fx);
  d.sv = Vector3d(0, 1, fy);
  d.suu = Vector3d(0, 0, fxx);
  d.suv = Vector3d(0, 0, fxy);
  d.svv = Vector3d(0, 0, fyy);
  return d;
}

std::string Num(double value) { return FormatSignificant(value); }

std::string DomainText(const ParamDomain& d, const char* u, const char* v) {
  return std::string(u) + " in [" + Num(d.u_min) + ", " + Num(d.u_max) + "], " + v + " in [" + Num(d.v_min) + ", " +
         Num(d.v_max) + "] mm";
}

// z = a x + b y + c.
class Plane final : public AnalyticSurface {
 public:
  std::string name() const override { return "plane"; }
  std::string description() const override {
    return "tilted plane z = a x + b y + c, a = " + Num(a_) + ", b = " + Num(b_) + ", c = " + Num(c_) + " mm; " +
           DomainText(domain(), "x", "y");
  }
  ParamDomain domain() const override { return {0, 100, 0, 80}; }
  bool is_graph() const override { return true; }
  SurfaceDerivatives Derivatives(double x, double y) const override {
    return GraphDerivatives(x, y, a_ * x + b_ * y + c_, a_, b_, 0, 0, 0);
  }

 private:
  double a_ = 0.1, b_ = -0.05, c_ = 5;
};

// Upper cap of the sphere (x - x0)² + (y - y0)² + (z - z0)² = R², as a graph.
class SphereCap final : public AnalyticSurface {
 public:
  std::string name() const override { return "sphere_cap"; }
  std::string description() const override {
    return "sphere cap z = z0 + sqrt(R^2 - (x - x0)^2 - (y - y0)^2), R = " + Num(r_) + ", x0 = " + Num(x0_) +
           ", y0 = " + Num(y0_) + ", z0 = " + Num(z0_) + " mm; " + DomainText(domain(), "x", "y");
  }
  ParamDomain domain() const override { return {0, 100, 0, 80}; }
  bool is_graph() const override { return true; }
  SurfaceDerivatives Derivatives(double x, double y) const override {
    const double dx = x - x0_, dy = y - y0_;
    const double h = std::sqrt(r_ * r_ - dx * dx - dy * dy);
    const double h3 = h * h * h;
    return GraphDerivatives(x, y, z0_ + h, -dx / h, -dy / h, -(h * h + dx * dx) / h3, -dx * dy / h3,
                            -(h * h + dy * dy) / h3);
  }

 private:
  double r_ = 100, x0_ = 50, y0_ = 40, z0_ = -80;
};

// Upper half of a cylinder of radius R with its axis along y, as a graph.
class Cylinder final : public AnalyticSurface {
 public:
  std::string name() const override { return "cylinder"; }
  std::string description() const override {
    return "cylinder, axis along y: z = z0 + sqrt(R^2 - (x - x0)^2), R = " + Num(r_) + ", x0 = " + Num(x0_) +
           ", z0 = " + Num(z0_) + " mm; " + DomainText(domain(), "x", "y");
  }
  ParamDomain domain() const override { return {0, 100, 0, 90}; }
  bool is_graph() const override { return true; }
  SurfaceDerivatives Derivatives(double x, double y) const override {
    const double dx = x - x0_;
    const double h = std::sqrt(r_ * r_ - dx * dx);
    return GraphDerivatives(x, y, z0_ + h, -dx / h, 0, -(r_ * r_) / (h * h * h), 0, 0);
  }

 private:
  double r_ = 80, x0_ = 50, z0_ = -70;
};

// Upper cap of the ellipsoid (x - x0)²/a² + (y - y0)²/b² + (z - z0)²/c² = 1, as a graph.
class EllipsoidCap final : public AnalyticSurface {
 public:
  std::string name() const override { return "ellipsoid_cap"; }
  std::string description() const override {
    return "ellipsoid cap z = z0 + c sqrt(1 - (x - x0)^2/a^2 - (y - y0)^2/b^2), a = " + Num(a_) + ", b = " + Num(b_) +
           ", c = " + Num(c_) + ", x0 = " + Num(x0_) + ", y0 = " + Num(y0_) + ", z0 = " + Num(z0_) + " mm; " +
           DomainText(domain(), "x", "y");
  }
  ParamDomain domain() const override { return {0, 100, 0, 80}; }
  bool is_graph() const override { return true; }
  SurfaceDerivatives Derivatives(double x, double y) const override {
    const double dx = x - x0_, dy = y - y0_;
    const double a2 = a_ * a_, b2 = b_ * b_;
    const double s = std::sqrt(1 - dx * dx / a2 - dy * dy / b2);
    const double s3 = s * s * s;
    return GraphDerivatives(x, y, z0_ + c_ * s, -c_ * dx / (a2 * s), -c_ * dy / (b2 * s),
                            -c_ / (a2 * s) - c_ * dx * dx / (a2 * a2 * s3), -c_ * dx * dy / (a2 * b2 * s3),
                            -c_ / (b2 * s) - c_ * dy * dy / (b2 * b2 * s3));
  }

 private:
  double a_ = 120, b_ = 90, c_ = 40, x0_ = 50, y0_ = 40, z0_ = -30;
};

// Hyperbolic paraboloid z = (x² - y²)/(2R), centred on the origin.
class Saddle final : public AnalyticSurface {
 public:
  std::string name() const override { return "saddle"; }
  std::string description() const override {
    return "saddle z = (x^2 - y^2)/(2R), R = " + Num(r_) + " mm; " + DomainText(domain(), "x", "y");
  }
  ParamDomain domain() const override { return {-50, 50, -40, 40}; }
  bool is_graph() const override { return true; }
  SurfaceDerivatives Derivatives(double x, double y) const override {
    return GraphDerivatives(x, y, (x * x - y * y) / (2 * r_), x / r_, -y / r_, 1 / r_, 0, -1 / r_);
  }

 private:
  double r_ = 150;
};

// z = a sin(2πx/λ) sin(2πy/λ): the smallest radius is 1/(a (2π/λ)²) ≈ 20 mm at the crests.
class EggBox final : public AnalyticSurface {
 public:
  std::string name() const override { return "egg_box"; }
  std::string description() const override {
    return "egg box z = a sin(2 pi x/L) sin(2 pi y/L), a = " + Num(a_) + ", L = " + Num(wavelength_) + " mm; " +
           DomainText(domain(), "x", "y");
  }
  ParamDomain domain() const override { return {0, 100, 0, 80}; }
  bool is_graph() const override { return true; }
  SurfaceDerivatives Derivatives(double x, double y) const override {
    const double w = 2 * std::numbers::pi / wavelength_;
    const double sx = std::sin(w * x), cx = std::cos(w * x), sy = std::sin(w * y), cy = std::cos(w * y);
    return GraphDerivatives(x, y, a_ * sx * sy, a_ * w * cx * sy, a_ * w * sx * cy, -a_ * w * w * sx * sy,
                            a_ * w * w * cx * cy, -a_ * w * w * sx * sy);
  }

 private:
  double a_ = 2, wavelength_ = 40;
};

// Franke's test function (Franke 1979, "A critical comparison of some methods for interpolation of
// scattered data", NPS-53-79-003), scaled: z = H F(x/s, y/s).
class Franke final : public AnalyticSurface {
 public:
  std::string name() const override { return "franke"; }
  std::string description() const override {
    return "Franke's function z = H F(x/s, y/s), F = 0.75 exp(-((9X-2)^2+(9Y-2)^2)/4) + 0.75 exp(-(9X+1)^2/49 - "
           "(9Y+1)/10) + 0.5 exp(-((9X-7)^2+(9Y-3)^2)/4) - 0.2 exp(-(9X-4)^2-(9Y-7)^2), H = " +
           Num(height_) + " mm, s = " + Num(scale_) + " mm; " + DomainText(domain(), "x", "y");
  }
  ParamDomain domain() const override { return {0, 100, 0, 100}; }
  bool is_graph() const override { return true; }
  SurfaceDerivatives Derivatives(double x, double y) const override {
    const double X = x / scale_, Y = y / scale_;
    // Each term c·exp(q(X, Y)) with q separable (q_XY = 0): g_X = g q_X, g_XX = g (q_XX + q_X²),
    // g_XY = g q_X q_Y.
    struct Term {
      double c, q, qx, qy, qxx, qyy;
    };
    const double ax = 9 * X - 2, ay = 9 * Y - 2;
    const double bx = 9 * X + 1, by = 9 * Y + 1;
    const double cx = 9 * X - 7, cy = 9 * Y - 3;
    const double dx = 9 * X - 4, dy = 9 * Y - 7;
    const Term terms[] = {
        {0.75, -(ax * ax + ay * ay) / 4, -9 * ax / 2, -9 * ay / 2, -81.0 / 2, -81.0 / 2},
        {0.75, -bx * bx / 49 - by / 10, -18 * bx / 49, -0.9, -162.0 / 49, 0},
        {0.5, -(cx * cx + cy * cy) / 4, -9 * cx / 2, -9 * cy / 2, -81.0 / 2, -81.0 / 2},
        {-0.2, -dx * dx - dy * dy, -18 * dx, -18 * dy, -162, -162},
    };
    double f = 0, fx = 0, fy = 0, fxx = 0, fxy = 0, fyy = 0;
    for (const Term& t : terms) {
      const double g = t.c * std::exp(t.q);
      f += g;
      fx += g * t.qx;
      fy += g * t.qy;
      fxx += g * (t.qxx + t.qx * t.qx);
      fxy += g * t.qx * t.qy;
      fyy += g * (t.qyy + t.qy * t.qy);
    }
    const double k1 = height_ / scale_, k2 = height_ / (scale_ * scale_);
    return GraphDerivatives(x, y, height_ * f, k1 * fx, k1 * fy, k2 * fxx, k2 * fxy, k2 * fyy);
  }

 private:
  double height_ = 20, scale_ = 100;
};

// A twisted ruled surface between a leading-edge curve C0(u) and a trailing-edge curve C1(u):
// S(u, v) = (1 - v/W) C0(u) + (v/W) C1(u), with s = sin(π u/L):
//   C0(u) = (u, a s, h0 s),  C1(u) = (u + dx, W + a s, z1 + h1 s - t u).
class Blade final : public AnalyticSurface {
 public:
  std::string name() const override { return "blade"; }
  std::string description() const override {
    return "ruled blade S(u,v) = (1 - v/W) C0(u) + (v/W) C1(u), s = sin(pi u/L), C0 = (u, a s, h0 s), C1 = (u + dx, W "
           "+ a s, z1 + h1 s - t u), L = " +
           Num(length_) + ", W = " + Num(width_) + ", a = " + Num(sweep_) + ", h0 = " + Num(h0_) +
           ", h1 = " + Num(h1_) + ", dx = " + Num(dx_) + ", z1 = " + Num(z1_) + " mm, t = " + Num(twist_) + "; " +
           DomainText(domain(), "u (along the blade)", "v (across)");
  }
  ParamDomain domain() const override { return {0, length_, 0, width_}; }
  bool is_graph() const override { return false; }
  SurfaceDerivatives Derivatives(double u, double v) const override {
    const double w = std::numbers::pi / length_;
    const double s = std::sin(w * u), c = std::cos(w * u);
    const Vector3d c0(u, sweep_ * s, h0_ * s);
    const Vector3d c0u(1, sweep_ * w * c, h0_ * w * c);
    const Vector3d c0uu(0, -sweep_ * w * w * s, -h0_ * w * w * s);
    const Vector3d c1(u + dx_, width_ + sweep_ * s, z1_ + h1_ * s - twist_ * u);
    const Vector3d c1u(1, sweep_ * w * c, h1_ * w * c - twist_);
    const Vector3d c1uu(0, -sweep_ * w * w * s, -h1_ * w * w * s);
    const double t = v / width_;
    SurfaceDerivatives d;
    d.p = (1 - t) * c0 + t * c1;
    d.su = (1 - t) * c0u + t * c1u;
    d.sv = (c1 - c0) / width_;
    d.suu = (1 - t) * c0uu + t * c1uu;
    d.suv = (c1u - c0u) / width_;
    d.svv = Vector3d::Zero();
    return d;
  }

 private:
  double length_ = 100, width_ = 80, sweep_ = 3, h0_ = 12, h1_ = 20, dx_ = 10, z1_ = 4, twist_ = 0.08;
};

// The paraboloid P(u, v) = (u, v, (u² + v²)/(2R)) rotated by θ about the x axis and shifted by t:
// S = Rx(θ) P + t. A concave bowl (k1 = k2 = -1/R at the vertex) that is not a graph over (u, v).
class TiltedParaboloid final : public AnalyticSurface {
 public:
  std::string name() const override { return "tilted_paraboloid"; }
  std::string description() const override {
    return "tilted paraboloid S(u,v) = Rx(theta) (u, v, (u^2 + v^2)/(2R)) + t, R = " + Num(r_) +
           " mm, theta = " + Num(theta_deg_) + " deg, t = (" + Num(t_.x()) + ", " + Num(t_.y()) + ", " + Num(t_.z()) +
           ") mm; " + DomainText(domain(), "u", "v");
  }
  ParamDomain domain() const override { return {-50, 50, -40, 40}; }
  bool is_graph() const override { return false; }
  SurfaceDerivatives Derivatives(double u, double v) const override {
    const double theta = theta_deg_ * std::numbers::pi / 180;
    const double c = std::cos(theta), s = std::sin(theta);
    auto rot = [&](const Vector3d& a) { return Vector3d(a.x(), c * a.y() - s * a.z(), s * a.y() + c * a.z()); };
    SurfaceDerivatives d;
    d.p = rot(Vector3d(u, v, (u * u + v * v) / (2 * r_))) + t_;
    d.su = rot(Vector3d(1, 0, u / r_));
    d.sv = rot(Vector3d(0, 1, v / r_));
    d.suu = rot(Vector3d(0, 0, 1 / r_));
    d.suv = Vector3d::Zero();
    d.svv = rot(Vector3d(0, 0, 1 / r_));
    return d;
  }

 private:
  double r_ = 150, theta_deg_ = 15;
  Vector3d t_ = Vector3d(50, 40, -5);
};

struct Entry {
  const char* name;
  std::function<std::unique_ptr<AnalyticSurface>()> make;
};

const std::vector<Entry>& Registry() {
  static const std::vector<Entry> registry = {
      {"plane", [] { return std::make_unique<Plane>(); }},
      {"sphere_cap", [] { return std::make_unique<SphereCap>(); }},
      {"cylinder", [] { return std::make_unique<Cylinder>(); }},
      {"ellipsoid_cap", [] { return std::make_unique<EllipsoidCap>(); }},
      {"saddle", [] { return std::make_unique<Saddle>(); }},
      {"egg_box", [] { return std::make_unique<EggBox>(); }},
      {"franke", [] { return std::make_unique<Franke>(); }},
      {"blade", [] { return std::make_unique<Blade>(); }},
      {"tilted_paraboloid", [] { return std::make_unique<TiltedParaboloid>(); }},
  };
  return registry;
}

}  // namespace

std::vector<std::string> ReferenceSurfaceNames() {
  std::vector<std::string> names;
  for (const Entry& entry : Registry()) names.emplace_back(entry.name);
  return names;
}

Result<std::unique_ptr<AnalyticSurface>> MakeReferenceSurface(const std::string& name) {
  for (const Entry& entry : Registry()) {
    if (name == entry.name) return entry.make();
  }
  std::string valid;
  for (const Entry& entry : Registry()) valid += (valid.empty() ? "" : ", ") + std::string(entry.name);
  return Status::NotFound("no reference surface named '" + name + "'. Valid names: " + valid);
}

}  // namespace formloop::recon
