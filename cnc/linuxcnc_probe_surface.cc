#include "cnc/linuxcnc_probe_surface.h"

#include <Eigen/SVD>
#include <algorithm>
#include <array>
#include <cmath>
#include <map>

#include "core/point_io.h"

namespace formloop::cnc {
namespace {

using Eigen::Vector3d;
using nlohmann::json;

json VectorJson(const Vector3d& v) { return json::array({v.x(), v.y(), v.z()}); }

// Points and normals of a grid over the surface's domain (n × n, edges included).
struct Samples {
  std::vector<Vector3d> points, normals;
};
Samples SampleGrid(const recon::AnalyticSurface& surface, int n) {
  const recon::ParamDomain d = surface.domain();
  Samples s;
  for (int i = 0; i < n; ++i) {
    for (int j = 0; j < n; ++j) {
      const double u = d.u_min + d.u_span() * i / (n - 1);
      const double v = d.v_min + d.v_span() * j / (n - 1);
      s.points.push_back(surface.Point(u, v));
      s.normals.push_back(surface.Normal(u, v));
    }
  }
  return s;
}

std::string QuadricNames() {
  std::string names;
  for (const std::string& name : recon::ReferenceSurfaceNames()) {
    auto surface = recon::MakeReferenceSurface(name);
    if (!surface.ok()) continue;
    // Only the classification, without recursing into the message of a failure.
    const Samples s = SampleGrid(**surface, 12);
    Eigen::MatrixXd m(static_cast<Eigen::Index>(s.points.size()), 10);
    Vector3d mean = Vector3d::Zero();
    for (const Vector3d& p : s.points) mean += p;
    mean /= static_cast<double>(s.points.size());
    double h = 0;
    for (const Vector3d& p : s.points) h = std::max(h, (p - mean).norm());
    for (std::size_t i = 0; i < s.points.size(); ++i) {
      const Vector3d q = (s.points[i] - mean) / h;
      m.row(static_cast<Eigen::Index>(i)) << q.x() * q.x(), q.y() * q.y(), q.z() * q.z(), q.x() * q.y(), q.x() * q.z(),
          q.y() * q.z(), q.x(), q.y(), q.z(), 1;
    }
    const Eigen::VectorXd sv = Eigen::JacobiSVD<Eigen::MatrixXd>(m).singularValues();
    if (sv(9) <= 1e-10 * sv(0)) names += (names.empty() ? "" : ", ") + name;
  }
  return names;
}

}  // namespace

Eigen::Isometry3d SetupPose::Transform() const {
  Eigen::Isometry3d t = Eigen::Isometry3d::Identity();
  const Vector3d w = rotation_urad * 1e-6;
  if (w.norm() > 0) t.linear() = Eigen::AngleAxisd(w.norm(), w.normalized()).toRotationMatrix();
  t.translation() = shift_um * 1e-3;
  return t;
}

json SetupPose::ToJson() const {
  return {{"shift_um", VectorJson(shift_um)}, {"rotation_urad", VectorJson(rotation_urad)}};
}

ImplicitQuadric ImplicitQuadric::Moved(const Eigen::Isometry3d& placement) const {
  // F'(p) = F(Rᵀ(p − s)).
  const Eigen::Matrix3d r = placement.linear();
  const Vector3d s = placement.translation();
  ImplicitQuadric moved;
  moved.a = r * a * r.transpose();
  moved.b = r * b - 2 * moved.a * s;
  moved.c = s.dot(moved.a * s) - (r * b).dot(s) + c;
  return moved;
}

json ImplicitQuadric::ToJson() const {
  json rows = json::array();
  for (int i = 0; i < 3; ++i) rows.push_back(json::array({a(i, 0), a(i, 1), a(i, 2)}));
  return {{"A", rows}, {"b", VectorJson(b)}, {"c", c}, {"form", "F(p) = p'Ap + b'p + c, F > 0 on the probe's side"}};
}

Result<ImplicitQuadric> QuadricThrough(const recon::AnalyticSurface& surface) {
  const Samples s = SampleGrid(surface, 12);
  const auto n = static_cast<Eigen::Index>(s.points.size());
  Vector3d mean = Vector3d::Zero();
  for (const Vector3d& p : s.points) mean += p;
  mean /= static_cast<double>(n);
  double h = 0;
  for (const Vector3d& p : s.points) h = std::max(h, (p - mean).norm());
  ImplicitQuadric f;
  // A plane first: it lies on a four-parameter family of quadrics, so the ten-column null space
  // would not be unique.
  Eigen::MatrixXd m4(n, 4);
  for (Eigen::Index i = 0; i < n; ++i) m4.row(i) << ((s.points[static_cast<std::size_t>(i)] - mean) / h).transpose(), 1;
  Eigen::JacobiSVD<Eigen::MatrixXd> svd4(m4, Eigen::ComputeFullV);
  if (svd4.singularValues()(3) <= 1e-12 * svd4.singularValues()(0)) {
    const Eigen::Vector4d v = svd4.matrixV().col(3);
    f.a.setZero();
    f.b = v.head<3>() / h;
    f.c = v(3) - f.b.dot(mean);
  } else {
    Eigen::MatrixXd m10(n, 10);
    for (Eigen::Index i = 0; i < n; ++i) {
      const Vector3d q = (s.points[static_cast<std::size_t>(i)] - mean) / h;
      m10.row(i) << q.x() * q.x(), q.y() * q.y(), q.z() * q.z(), q.x() * q.y(), q.x() * q.z(), q.y() * q.z(), q.x(),
          q.y(), q.z(), 1;
    }
    Eigen::JacobiSVD<Eigen::MatrixXd> svd(m10, Eigen::ComputeFullV);
    const Eigen::VectorXd sv = svd.singularValues();
    if (!(sv(9) <= 1e-10 * sv(0)) || !(sv(8) >= 1e-7 * sv(0))) {
      return Status::BadInput(Where{.field = "surface"},
                              "'" + surface.name() + "' is not a plane or a quadric (smallest singular values " +
                                  FormatExact(sv(9) / sv(0)) + ", " + FormatExact(sv(8) / sv(0)) +
                                  " of its monomials), so HAL's math components cannot model it",
                              "use one of: " + QuadricNames());
    }
    const Eigen::VectorXd v = svd.matrixV().col(9);
    Eigen::Matrix3d at;
    at << v(0), v(3) / 2, v(4) / 2, v(3) / 2, v(1), v(5) / 2, v(4) / 2, v(5) / 2, v(2);
    const Vector3d bt(v(6), v(7), v(8));
    f.a = at / (h * h);
    f.b = bt / h - 2 * f.a * mean;
    f.c = mean.dot(f.a * mean) - bt.dot(mean) / h + v(9);
  }
  // Orientation (F > 0 along the normal) and scale (|∇F| = 1 at the median sample).
  std::vector<double> along, magnitude;
  for (Eigen::Index i = 0; i < n; ++i) {
    const Vector3d g = f.Gradient(s.points[static_cast<std::size_t>(i)]);
    along.push_back(g.dot(s.normals[static_cast<std::size_t>(i)]));
    magnitude.push_back(g.norm());
  }
  const auto [lo, hi] = std::minmax_element(along.begin(), along.end());
  if (!(*lo > 0 || *hi < 0)) {
    return Status::Internal("the quadric through '" + surface.name() + "' changes orientation over its domain");
  }
  std::nth_element(magnitude.begin(), magnitude.begin() + n / 2, magnitude.end());
  const double scale = (*hi < 0 ? -1.0 : 1.0) / magnitude[static_cast<std::size_t>(n / 2)];
  f.a *= scale;
  f.b *= scale;
  f.c *= scale;
  // Rounding leaves terms like 1e-17·z from the SVD; one that changes F by less than 1e-12 mm anywhere
  // on the part is exactly zero in the surface (F is about a distance in mm near it), so drop it.
  double extent = 0;
  for (const Vector3d& p : s.points) extent = std::max(extent, p.cwiseAbs().maxCoeff());
  f.a = f.a.unaryExpr([extent](double x) { return std::abs(x) * extent * extent < 1e-12 ? 0.0 : x; });
  f.b = f.b.unaryExpr([extent](double x) { return std::abs(x) * extent < 1e-12 ? 0.0 : x; });
  if (std::abs(f.c) < 1e-12) f.c = 0;
  return f;
}

// ---- HalNet ----

HalNet::HalNet() {
  for (int axis = 0; axis < 3; ++axis) nodes_.push_back(Node{});
}

int HalNet::Add(Node node) {
  nodes_.push_back(std::move(node));
  return static_cast<int>(nodes_.size()) - 1;
}

HalNet::Value HalNet::Affine(const std::vector<std::pair<double, Value>>& terms, double offset) {
  Value out;
  out.constant = offset;
  for (const auto& [k, v] : terms) {
    out.constant += k * v.constant;
    for (const auto& [coefficient, node] : v.terms) {
      const auto& wanted = node;  // clang 14 (sanitizer builds) cannot capture a structured binding
      auto it = std::find_if(out.terms.begin(), out.terms.end(), [&](const auto& t) { return t.second == wanted; });
      if (it == out.terms.end()) {
        out.terms.emplace_back(k * coefficient, node);
      } else {
        it->first += k * coefficient;
      }
    }
  }
  std::erase_if(out.terms, [](const auto& t) { return t.first == 0; });
  return out;
}

HalNet::Value HalNet::Signal(const Value& v) {
  if (v.is_constant() || (v.terms.size() == 1 && v.terms[0].first == 1 && v.constant == 0)) return v;
  int acc = -1;
  for (std::size_t i = 0; i < v.terms.size();) {
    Node sum;
    sum.kind = Kind::kSum;
    if (acc < 0) {
      sum.in = {Pin{v.terms[i].second, 0}, i + 1 < v.terms.size() ? Pin{v.terms[i + 1].second, 0} : Pin{-1, 0}};
      sum.gain0 = v.terms[i].first;
      sum.gain1 = i + 1 < v.terms.size() ? v.terms[i + 1].first : 1;
      i += 2;
    } else {
      sum.in = {Pin{acc, 0}, Pin{v.terms[i].second, 0}};
      sum.gain1 = v.terms[i].first;
      i += 1;
    }
    if (i >= v.terms.size()) sum.offset = v.constant;
    acc = Add(std::move(sum));
  }
  return {0, {{1.0, acc}}};
}

HalNet::Pin HalNet::PinOf(const Value& v) {
  if (v.is_constant()) return {-1, v.constant};
  return {Signal(v).terms[0].second, 0};
}

HalNet::Value HalNet::Product(const Value& a, const Value& b) {
  if (a.is_constant()) return Affine({{a.constant, b}}, 0);
  if (b.is_constant()) return Affine({{b.constant, a}}, 0);
  Node n;
  n.kind = Kind::kProduct;
  n.in = {PinOf(a), PinOf(b)};
  return {0, {{1.0, Add(std::move(n))}}};
}

HalNet::Value HalNet::Quotient(const Value& dividend, const Value& divisor) {
  if (divisor.is_constant()) return Affine({{divisor.constant == 0 ? 0 : 1 / divisor.constant, dividend}}, 0);
  Node n;
  n.kind = Kind::kQuotient;
  n.in = {PinOf(dividend), PinOf(divisor)};
  return {0, {{1.0, Add(std::move(n))}}};
}

HalNet::Value HalNet::Hypot(const Value& a, const Value& b, const Value& c) {
  if (a.is_constant() && b.is_constant() && c.is_constant()) {
    return Constant(std::sqrt(a.constant * a.constant + b.constant * b.constant + c.constant * c.constant));
  }
  Node n;
  n.kind = Kind::kHypot;
  n.in = {PinOf(a), PinOf(b), PinOf(c)};
  return {0, {{1.0, Add(std::move(n))}}};
}

Status HalNet::SetOutput(const Value& v) {
  if (v.is_constant()) return Status::Internal("the probe surface's gap does not depend on the position");
  const int node = Signal(v).terms[0].second;
  if (node < 3) {  // an input itself: give it its own component so the output is a separate signal
    Node sum;
    sum.kind = Kind::kSum;
    sum.in = {Pin{node, 0}, Pin{-1, 0}};
    output_ = Add(std::move(sum));
  } else {
    output_ = node;
  }
  return Status::Ok();
}

namespace {
// div2's dead band: a divisor within it gives 0 (the quadric's gradient is about 1 near the surface).
constexpr double kDivideDeadband = 1e-12;
}  // namespace

double HalNet::Evaluate(const Vector3d& centre) const {
  std::vector<double> v(nodes_.size(), 0.0);
  auto value = [&v](const Pin& x) { return x.node < 0 ? x.constant : v[static_cast<std::size_t>(x.node)]; };
  for (std::size_t k = 0; k < nodes_.size(); ++k) {
    const Node& n = nodes_[k];
    switch (n.kind) {
      case Kind::kInput:
        v[k] = centre[static_cast<Eigen::Index>(k)];
        break;
      case Kind::kSum:  // sum2.comp: out = in0 * gain0 + in1 * gain1 + offset
        v[k] = value(n.in[0]) * n.gain0 + value(n.in[1]) * n.gain1 + n.offset;
        break;
      case Kind::kProduct:  // mult2.comp: out = in0 * in1
        v[k] = value(n.in[0]) * value(n.in[1]);
        break;
      case Kind::kQuotient: {  // div2.comp: 0 within the dead band, else in0 / in1
        const double d = value(n.in[1]);
        v[k] = (d < kDivideDeadband && d > -kDivideDeadband) ? 0.0 : value(n.in[0]) / d;
        break;
      }
      case Kind::kHypot: {  // hypot.comp: out = sqrt(in0^2 + in1^2 + in2^2)
        const double a = value(n.in[0]), b = value(n.in[1]), c = value(n.in[2]);
        v[k] = std::sqrt(a * a + b * b + c * c);
        break;
      }
    }
  }
  return v[static_cast<std::size_t>(output_)];
}

std::string HalNet::Hal(const std::string& prefix, const std::string& thread, const std::vector<std::string>& inputs,
                        const std::string& output) const {
  static const std::map<Kind, std::pair<const char*, const char*>> kComponent = {{Kind::kSum, {"sum2", "s"}},
                                                                                 {Kind::kProduct, {"mult2", "m"}},
                                                                                 {Kind::kQuotient, {"div2", "d"}},
                                                                                 {Kind::kHypot, {"hypot", "h"}}};
  std::vector<std::string> names(nodes_.size());
  std::map<Kind, std::vector<std::string>> by_kind;
  for (std::size_t k = 0; k < nodes_.size(); ++k) {
    if (nodes_[k].kind == Kind::kInput) continue;
    const auto& [component, letter] = kComponent.at(nodes_[k].kind);
    auto& list = by_kind[nodes_[k].kind];
    names[k] = prefix + "-" + letter + std::to_string(list.size());
    list.push_back(names[k]);
  }
  auto signal = [&](int node) {
    return node < 3 ? inputs[static_cast<std::size_t>(node)] : prefix + "-v" + std::to_string(node);
  };
  std::string hal;
  for (const auto& [kind, list] : by_kind) {
    std::string joined;
    for (const std::string& name : list) joined += (joined.empty() ? "" : ",") + name;
    hal += "loadrt " + std::string(kComponent.at(kind).first) + " names=" + joined + "\n";
  }
  std::map<std::string, std::vector<std::string>> readers;  // signal -> input pins
  std::string set;
  for (std::size_t k = 3; k < nodes_.size(); ++k) {
    const Node& n = nodes_[k];
    hal += "addf " + names[k] + " " + thread + "\n";
    for (std::size_t i = 0; i < n.in.size(); ++i) {
      const std::string pin = names[k] + ".in" + std::to_string(i);
      if (n.in[i].node < 0) {
        set += "setp " + pin + " " + FormatExact(n.in[i].constant) + "\n";
      } else {
        readers[signal(n.in[i].node)].push_back(pin);
      }
    }
    if (n.kind == Kind::kSum) {
      set += "setp " + names[k] + ".gain0 " + FormatExact(n.gain0) + "\n";
      set += "setp " + names[k] + ".gain1 " + FormatExact(n.gain1) + "\n";
      set += "setp " + names[k] + ".offset " + FormatExact(n.offset) + "\n";
    }
    if (n.kind == Kind::kQuotient) set += "setp " + names[k] + ".deadband " + FormatExact(kDivideDeadband) + "\n";
  }
  hal += set;
  for (int axis = 0; axis < 3; ++axis) {
    const std::string& s = inputs[static_cast<std::size_t>(axis)];
    for (const std::string& pin : readers[s]) hal += "net " + s + " => " + pin + "\n";
  }
  for (std::size_t k = 3; k < nodes_.size(); ++k) {
    const std::string s = output_ == static_cast<int>(k) ? output : signal(static_cast<int>(k));
    hal += "net " + s + " <= " + names[k] + ".out";
    for (const std::string& pin : readers[signal(static_cast<int>(k))]) hal += " => " + pin;
    hal += "\n";
  }
  return hal;
}

// ---- BuildProbeSurface ----

Status ProbeSurfaceOptions::Validate() const {
  if (!(ball_radius_mm > 0 && ball_radius_mm <= 10)) {
    return Status::BadInput(Where{.field = "ball_radius_mm"},
                            "must be in (0, 10] mm, got " + FormatExact(ball_radius_mm));
  }
  if (!(max_trigger_error_nm > 0)) {
    return Status::BadInput(Where{.field = "max_trigger_error_nm"}, "must be > 0");
  }
  if (max_iterations < 1 || max_iterations > 20) {
    return Status::BadInput(Where{.field = "max_iterations"}, "must be in 1..20");
  }
  if (check_grid < 2 || check_grid > 200) return Status::BadInput(Where{.field = "check_grid"}, "must be in 2..200");
  // A setup error is small by nature; beyond 1 mm or 1° it is a different fixture, not an error.
  if (pose.shift_um.cwiseAbs().maxCoeff() > 1000 || pose.rotation_urad.norm() > 17453.3) {
    return Status::BadInput(Where{.field = "pose"}, "shift beyond 1000 um or rotation beyond 1 deg",
                            "model a different fixture as a different surface");
  }
  return Status::Ok();
}

namespace {

// The net of the header comment with `iterations` fixed-point steps.
Result<HalNet> BuildNet(const ImplicitQuadric& f, double r, int iterations) {
  HalNet net;
  using V = HalNet::Value;
  const std::array<V, 3> c = {HalNet::Input(0), HalNet::Input(1), HalNet::Input(2)};
  auto gradient = [&](const std::array<V, 3>& p) {
    std::array<V, 3> g;
    for (int i = 0; i < 3; ++i) {
      g[static_cast<std::size_t>(i)] =
          HalNet::Affine({{2 * f.a(i, 0), p[0]}, {2 * f.a(i, 1), p[1]}, {2 * f.a(i, 2), p[2]}}, f.b(i));
    }
    return g;
  };
  std::array<V, 3> p = c;
  for (int k = 0; k < iterations; ++k) {
    std::array<V, 3> g = gradient(p);
    for (V& gi : g) gi = net.Signal(gi);  // used by hypot and by the quotient
    const V length = net.Hypot(g[0], g[1], g[2]);
    std::array<V, 3> next;
    for (std::size_t i = 0; i < 3; ++i) next[i] = HalNet::Affine({{1, c[i]}, {-r, net.Quotient(g[i], length)}}, 0);
    p = next;
  }
  // F(p) = ½ p·(∇F(p) + b) + c.
  const std::array<V, 3> g = gradient(p);
  std::vector<std::pair<double, V>> terms;
  for (std::size_t i = 0; i < 3; ++i) {
    terms.emplace_back(0.5, net.Product(p[i], HalNet::Affine({{1, g[i]}}, f.b(static_cast<Eigen::Index>(i)))));
  }
  FL_RETURN_IF_ERROR(net.SetOutput(HalNet::Affine(terms, f.c)));
  return net;
}

}  // namespace

json ProbeSurfaceReport::ToJson() const {
  return {{"surface", surface},
          {"description", description},
          {"pose", pose.ToJson()},
          {"ball_radius_mm", ball_radius_mm},
          {"quadric_nominal", nominal.ToJson()},
          {"quadric_placed", placed.ToJson()},
          {"iterations", iterations},
          {"hal_components", components},
          {"check",
           {{"points", checked_points},
            {"max_trigger_error_nm", max_trigger_error_nm},
            {"what",
             "|distance from the surface at which the net trips - ball radius|, along the exact normal of "
             "each point of a grid over the surface, the net evaluated as the HAL components do"}}}};
}

Result<ProbeSurface> BuildProbeSurface(const ProbeSurfaceOptions& options) {
  FL_RETURN_IF_ERROR(options.Validate());
  FL_ASSIGN_OR_RETURN(const std::unique_ptr<recon::AnalyticSurface> surface,
                      recon::MakeReferenceSurface(options.surface));
  FL_ASSIGN_OR_RETURN(const ImplicitQuadric nominal, QuadricThrough(*surface));
  const Eigen::Isometry3d placement = options.pose.Transform();
  const ImplicitQuadric placed = nominal.Moved(placement);
  const Samples check = SampleGrid(*surface, options.check_grid);
  const double r = options.ball_radius_mm;
  constexpr double kBracketMm = 1e-3;  // a trip more than 1 µm off is a failure whatever the tolerance
  ProbeSurface out;
  double worst_nm = 0;
  for (int iterations = 1; iterations <= options.max_iterations; ++iterations) {
    FL_ASSIGN_OR_RETURN(HalNet net, BuildNet(placed, r, iterations));
    worst_nm = 0;
    bool bracketed = true;
    for (std::size_t i = 0; i < check.points.size() && bracketed; ++i) {
      const Vector3d p = placement * check.points[i];
      const Vector3d n = placement.linear() * check.normals[i];
      auto gap = [&](double t) { return net.Evaluate(p + t * n); };
      double lo = r - kBracketMm, hi = r + kBracketMm;
      if (!(gap(lo) < 0 && gap(hi) > 0)) {
        bracketed = false;
        break;
      }
      for (int step = 0; step < 60; ++step) {
        const double mid = 0.5 * (lo + hi);
        (gap(mid) < 0 ? lo : hi) = mid;
      }
      worst_nm = std::max(worst_nm, std::abs(0.5 * (lo + hi) - r) * 1e6);
    }
    if (!bracketed) worst_nm = kBracketMm * 1e6;
    if (worst_nm <= options.max_trigger_error_nm) {
      out.report.iterations = iterations;
      out.report.components = net.components();
      out.net = std::move(net);
      break;
    }
  }
  if (out.report.iterations == 0) {
    return Status::Failed("the HAL net for '" + options.surface + "' trips up to " + FormatFixed(worst_nm, 3) +
                          " nm away from the ball radius after " + std::to_string(options.max_iterations) +
                          " iterations (limit " + FormatExact(options.max_trigger_error_nm) +
                          " nm); a smaller ball or a larger limit would do");
  }
  out.report.surface = surface->name();
  out.report.description = surface->description();
  out.report.pose = options.pose;
  out.report.ball_radius_mm = r;
  out.report.nominal = nominal;
  out.report.placed = placed;
  out.report.checked_points = static_cast<int>(check.points.size());
  out.report.max_trigger_error_nm = worst_nm;
  return out;
}

}  // namespace formloop::cnc
