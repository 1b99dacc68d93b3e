#include "metrology/dimensions.h"

#include <algorithm>
#include <cmath>
#include <numbers>
#include <string>
#include <utility>

#include <Eigen/Geometry>

#include "metrology/feature_fit.h"

namespace formloop::metrology {
namespace {

struct TypeName {
  DimensionType type;
  const char* name;
};
constexpr TypeName kTypeNames[] = {
    {DimensionType::kLength, "LENGTH"},
    {DimensionType::kDiameter, "DIAMETER"},
    {DimensionType::kRadius, "RADIUS"},
    {DimensionType::kPosition, "POSITION"},
    {DimensionType::kTruePosition, "TRUE_POSITION"},
    {DimensionType::kFlatness, "FLATNESS"},
    {DimensionType::kRoundness, "ROUNDNESS"},
    {DimensionType::kParallelism, "PARALLELISM"},
    {DimensionType::kPerpendicularity, "PERPENDICULARITY"},
    {DimensionType::kCoaxiality, "COAXIALITY"},
    {DimensionType::kSymmetry, "SYMMETRY"},
    {DimensionType::kAngle, "ANGLE"},
};
struct MethodName {
  DimensionMethod method;
  const char* name;
};
constexpr MethodName kMethodNames[] = {
    {DimensionMethod::kDefault, "DEFAULT"},
    {DimensionMethod::kTwoPoint, "TWO_POINT"},
    {DimensionMethod::kFaceToFace, "FACE_TO_FACE"},
    {DimensionMethod::kCircle, "CIRCLE"},
    {DimensionMethod::kCylinder, "CYLINDER"},
    {DimensionMethod::kPoint, "POINT"},
    {DimensionMethod::kPlane, "PLANE"},
    {DimensionMethod::kAxis, "AXIS"},
    {DimensionMethod::kLine, "LINE"},
};

constexpr double kRadToDeg = 180.0 / std::numbers::pi;

Eigen::Vector3d AxisVector(int axis) { return Eigen::Vector3d::Unit(axis); }
// The two in-plane axes for a circle normal to `axis`: Z -> (X, Y), X -> (Y, Z), Y -> (Z, X).
int UAxis(int axis) { return (axis + 1) % 3; }
int VAxis(int axis) { return (axis + 2) % 3; }

// Evaluation of one dimension over a fixed set of roles (positions may be perturbed between calls).
class Evaluator {
 public:
  Evaluator(const DimensionDefinition& def, const std::vector<RolePoints>& roles)
      : def_(def), roles_(roles), method_(ResolvedMethod(def.type, def.method)) {}

  Result<double> Value() const {
    switch (def_.type) {
      case DimensionType::kLength:
        return Length();
      case DimensionType::kDiameter:
      case DimensionType::kRadius:
        return Size();
      case DimensionType::kPosition:
        return Position();
      case DimensionType::kTruePosition:
        return TruePosition();
      case DimensionType::kFlatness:
        return Flatness();
      case DimensionType::kRoundness:
        return Roundness();
      case DimensionType::kParallelism:
        return Parallelism();
      case DimensionType::kPerpendicularity:
        return Perpendicularity();
      case DimensionType::kCoaxiality:
        return Coaxiality();
      case DimensionType::kSymmetry:
        return Symmetry();
      case DimensionType::kAngle:
        return Angle();
    }
    return Status::Internal("unknown dimension type");
  }

 private:
  Status Missing(const std::string& role, int have, int need, const std::string& what) const {
    return Status::BadInput("dimension " + def_.id + ": role " + role + " has " + std::to_string(have) + " point(s); " +
                            what + " needs at least " + std::to_string(need) +
                            " (DIM_INSUFFICIENT_POINTS). Fix: list the probe points of " + role +
                            " in the model and measure them");
  }
  const RolePoints* Find(const std::string& role) const {
    for (const auto& r : roles_) {
      if (r.role == role) return &r;
    }
    return nullptr;
  }
  Result<std::vector<Eigen::Vector3d>> Points(const std::string& role, int need, const std::string& what) const {
    const RolePoints* r = Find(role);
    const int have = r ? static_cast<int>(r->points.size()) : 0;
    if (have < need) return Missing(role, have, need, what);
    std::vector<Eigen::Vector3d> out;
    out.reserve(have);
    for (const auto& p : r->points) out.push_back(p.position);
    return out;
  }
  Status Context(const Status& s, const std::string& role) const {
    return Status(s.code(), "dimension " + def_.id + ", role " + role + ": " + s.message());
  }
  Eigen::Vector3d MeanApproach(const std::string& role) const {
    Eigen::Vector3d sum = Eigen::Vector3d::Zero();
    if (const RolePoints* r = Find(role)) {
      for (const auto& p : r->points) {
        if (p.approach.norm() == 0) return Eigen::Vector3d::Zero();  // unknown for one point: unknown
        sum += p.approach.normalized();
      }
    }
    return sum;
  }
  static Eigen::Vector3d Mean(const std::vector<Eigen::Vector3d>& pts) {
    Eigen::Vector3d s = Eigen::Vector3d::Zero();
    for (const auto& p : pts) s += p;
    return s / static_cast<double>(pts.size());
  }
  static std::vector<Eigen::Vector2d> InPlane(const std::vector<Eigen::Vector3d>& pts, int normal) {
    std::vector<Eigen::Vector2d> out;
    out.reserve(pts.size());
    for (const auto& p : pts) out.emplace_back(p(UAxis(normal)), p(VAxis(normal)));
    return out;
  }
  // The circle of a role in the plane normal to `normal` (default: the dimension's axis).
  Result<CircleFit> Circle(const std::string& role, int normal = -1) const {
    if (normal < 0) normal = def_.axis;
    FL_ASSIGN_OR_RETURN(const auto pts, Points(role, 3, "a circle"));
    auto fit = FitCircle(InPlane(pts, normal));
    if (!fit.ok()) return Context(fit.status(), role);
    return fit;
  }
  // Circle centre in 3-D: fitted (u, v) and the mean height along the circle's axis.
  Result<Eigen::Vector3d> CircleCentre(const std::string& role, int normal = -1) const {
    if (normal < 0) normal = def_.axis;
    FL_ASSIGN_OR_RETURN(const auto pts, Points(role, 3, "a circle"));
    FL_ASSIGN_OR_RETURN(const CircleFit fit, Circle(role, normal));
    Eigen::Vector3d c = Mean(pts);
    c(UAxis(normal)) = fit.centre.x();
    c(VAxis(normal)) = fit.centre.y();
    return c;
  }
  Result<PlaneFit> Plane(const std::string& role) const {
    FL_ASSIGN_OR_RETURN(const auto pts, Points(role, 3, "a plane"));
    auto fit = FitPlane(pts);
    if (!fit.ok()) return Context(fit.status(), role);
    return fit;
  }
  // A location: circle centre (CIRCLE; POSITION's circles lie normal to feature_axis) or mean of the
  // points (POINT).
  Result<Eigen::Vector3d> Location(const std::string& role) const {
    if (method_ == DimensionMethod::kCircle) {
      return CircleCentre(role, def_.type == DimensionType::kPosition ? def_.feature_axis : def_.axis);
    }
    FL_ASSIGN_OR_RETURN(const auto pts, Points(role, 1, "a location"));
    return Mean(pts);
  }

  Result<double> Length() const {
    const Eigen::Vector3d a = AxisVector(def_.axis);
    if (method_ == DimensionMethod::kTwoPoint) {
      FL_ASSIGN_OR_RETURN(const auto wa, Points("WALL_A", 1, "a two-point length"));
      FL_ASSIGN_OR_RETURN(const auto wb, Points("WALL_B", 1, "a two-point length"));
      return std::abs(a.dot(Mean(wb)) - a.dot(Mean(wa)));
    }
    FL_ASSIGN_OR_RETURN(const PlaneFit fa, Plane("FACE_A"));
    FL_ASSIGN_OR_RETURN(const auto fb, Points("FACE_B", 1, "a face-to-face length"));
    double sum = 0;
    for (const auto& p : fb) sum += fa.normal.dot(p - fa.centroid);
    return std::abs(sum / static_cast<double>(fb.size()));
  }

  Result<double> Size() const {
    double r = 0;
    if (method_ == DimensionMethod::kCylinder) {
      FL_ASSIGN_OR_RETURN(const auto pts, Points("FEATURE", 5, "a cylinder"));
      auto fit = FitCylinder(pts, AxisVector(def_.axis));
      if (!fit.ok()) return Context(fit.status(), "FEATURE");
      r = fit->radius;
    } else {
      FL_ASSIGN_OR_RETURN(const CircleFit fit, Circle("FEATURE"));
      r = fit.radius;
    }
    return def_.type == DimensionType::kDiameter ? 2 * r : r;
  }

  // The datum of a location: a circle when the method is CIRCLE and it has 3 points or more, otherwise
  // the mean of its points (an edge or face point); the WCS origin when there is no DATUM role.
  Result<Eigen::Vector3d> DatumLocation() const {
    const RolePoints* datum = Find("DATUM");
    if (!datum) return Eigen::Vector3d(Eigen::Vector3d::Zero());
    if (method_ == DimensionMethod::kCircle && datum->points.size() >= 3) return Location("DATUM");
    FL_ASSIGN_OR_RETURN(const auto pts, Points("DATUM", 1, "a datum"));
    return Mean(pts);
  }

  Result<double> Position() const {
    FL_ASSIGN_OR_RETURN(const Eigen::Vector3d cf, Location("FEATURE"));
    FL_ASSIGN_OR_RETURN(const Eigen::Vector3d cd, DatumLocation());
    return AxisVector(def_.axis).dot(cf - cd);
  }

  Result<double> TruePosition() const {
    FL_ASSIGN_OR_RETURN(const Eigen::Vector3d cf, Location("FEATURE"));
    FL_ASSIGN_OR_RETURN(const Eigen::Vector3d cd, DatumLocation());
    const Eigen::Vector3d rel = cf - cd;
    const Eigen::Vector2d delta(rel(UAxis(def_.axis)) - def_.nominal_position.x(),
                                rel(VAxis(def_.axis)) - def_.nominal_position.y());
    return 2 * delta.norm();
  }

  Result<double> Flatness() const {
    FL_ASSIGN_OR_RETURN(const PlaneFit fit, Plane("FEATURE"));
    const auto [lo, hi] = std::minmax_element(fit.heights.begin(), fit.heights.end());
    return *hi - *lo;
  }

  Result<double> Roundness() const {
    FL_ASSIGN_OR_RETURN(const CircleFit fit, Circle("FEATURE"));
    const auto [lo, hi] = std::minmax_element(fit.residuals.begin(), fit.residuals.end());
    return *hi - *lo;
  }

  static double Range(const std::vector<Eigen::Vector3d>& pts, const Eigen::Vector3d& w) {
    double lo = 1e300, hi = -1e300;
    for (const auto& p : pts) {
      lo = std::min(lo, w.dot(p));
      hi = std::max(hi, w.dot(p));
    }
    return hi - lo;
  }

  Result<double> Parallelism() const {
    FL_ASSIGN_OR_RETURN(const PlaneFit datum, Plane("DATUM"));
    FL_ASSIGN_OR_RETURN(const auto pts, Points("FEATURE", 1, "parallelism"));
    return Range(pts, datum.normal);
  }

  Result<double> Perpendicularity() const {
    FL_ASSIGN_OR_RETURN(const PlaneFit datum, Plane("DATUM"));
    const Eigen::Vector3d nd = datum.normal;
    if (method_ == DimensionMethod::kAxis) {
      FL_ASSIGN_OR_RETURN(const Eigen::Vector3d c1, CircleCentre("LEVEL_1"));
      FL_ASSIGN_OR_RETURN(const Eigen::Vector3d c2, CircleCentre("LEVEL_2"));
      const Eigen::Vector3d d = c2 - c1;
      return (d - d.dot(nd) * nd).norm();
    }
    FL_ASSIGN_OR_RETURN(const PlaneFit feature, Plane("FEATURE"));
    const Eigen::Vector3d w = feature.normal - feature.normal.dot(nd) * nd;
    if (!(w.norm() > 1e-12)) {
      return Status::BadInput("dimension " + def_.id +
                              ": the FEATURE plane is parallel to the DATUM plane, so perpendicularity is undefined. "
                              "Fix: check the roles of the points");
    }
    FL_ASSIGN_OR_RETURN(const auto pts, Points("FEATURE", 3, "a plane"));
    return Range(pts, w.normalized());
  }

  Result<double> Coaxiality() const {
    std::vector<Eigen::Vector3d> datums, features;
    for (const auto& r : roles_) {
      if (r.role.rfind("DATUM", 0) == 0) {
        FL_ASSIGN_OR_RETURN(const Eigen::Vector3d c, CircleCentre(r.role));
        datums.push_back(c);
      } else if (r.role.rfind("FEATURE", 0) == 0) {
        FL_ASSIGN_OR_RETURN(const Eigen::Vector3d c, CircleCentre(r.role));
        features.push_back(c);
      }
    }
    if (datums.empty()) return Missing("DATUM_1", 0, 3, "a datum circle");
    if (features.empty()) return Missing("FEATURE_1", 0, 3, "a feature circle");
    Eigen::Vector3d direction = AxisVector(def_.axis);
    if (datums.size() >= 2) {
      direction = datums.back() - datums.front();
      if (!(direction.norm() > 1e-9)) {
        return Status::BadInput("dimension " + def_.id +
                                ": the datum circles are at the same place, so they do not define an axis. Fix: "
                                "probe the datum at two heights or give one datum circle");
      }
      direction.normalize();
    }
    double worst = 0;
    for (const auto& c : features) {
      const Eigen::Vector3d w = c - datums.front();
      worst = std::max(worst, (w - w.dot(direction) * direction).norm());
    }
    return 2 * worst;
  }

  Result<double> Symmetry() const {
    const Eigen::Vector3d a = AxisVector(def_.axis);
    FL_ASSIGN_OR_RETURN(const auto wa, Points("WALL_A", 1, "symmetry"));
    FL_ASSIGN_OR_RETURN(const auto wb, Points("WALL_B", 1, "symmetry"));
    FL_ASSIGN_OR_RETURN(const auto da, Points("DATUM_A", 1, "symmetry"));
    FL_ASSIGN_OR_RETURN(const auto db, Points("DATUM_B", 1, "symmetry"));
    if (wa.size() != wb.size() || da.size() != db.size()) {
      return Status::BadInput("dimension " + def_.id +
                              ": symmetry pairs WALL_A with WALL_B and DATUM_A with DATUM_B in order, but the counts "
                              "differ. Fix: list the same number of points on both walls");
    }
    double mu = 0;
    for (std::size_t i = 0; i < da.size(); ++i) mu += a.dot(0.5 * (da[i] + db[i]));
    mu /= static_cast<double>(da.size());
    double worst = 0;
    for (std::size_t i = 0; i < wa.size(); ++i) worst = std::max(worst, std::abs(a.dot(0.5 * (wa[i] + wb[i])) - mu));
    return 2 * worst;
  }

  Result<double> Angle() const {
    if (method_ == DimensionMethod::kLine) {
      FL_ASSIGN_OR_RETURN(const auto la, Points("LINE_A", 2, "a line"));
      FL_ASSIGN_OR_RETURN(const auto lb, Points("LINE_B", 2, "a line"));
      auto fa = FitLine2d(InPlane(la, def_.axis));
      if (!fa.ok()) return Context(fa.status(), "LINE_A");
      auto fb = FitLine2d(InPlane(lb, def_.axis));
      if (!fb.ok()) return Context(fb.status(), "LINE_B");
      const Eigen::Vector2d u = fa->direction, v = fb->direction;
      return std::atan2(std::abs(u.x() * v.y() - u.y() * v.x()), u.dot(v)) * kRadToDeg;
    }
    FL_ASSIGN_OR_RETURN(PlaneFit fa, Plane("FACE_A"));
    FL_ASSIGN_OR_RETURN(PlaneFit fb, Plane("FACE_B"));
    const Eigen::Vector3d aa = MeanApproach("FACE_A"), ab = MeanApproach("FACE_B");
    if (aa.norm() > 0 && ab.norm() > 0) {
      if (fa.normal.dot(aa) > 0) fa.normal = -fa.normal;
      if (fb.normal.dot(ab) > 0) fb.normal = -fb.normal;
      return std::atan2(fa.normal.cross(fb.normal).norm(), fa.normal.dot(fb.normal)) * kRadToDeg;
    }
    return std::atan2(fa.normal.cross(fb.normal).norm(), std::abs(fa.normal.dot(fb.normal))) * kRadToDeg;
  }

  const DimensionDefinition& def_;
  const std::vector<RolePoints>& roles_;
  DimensionMethod method_;
};

}  // namespace

const char* DimensionTypeName(DimensionType type) {
  for (const auto& t : kTypeNames) {
    if (t.type == type) return t.name;
  }
  return "?";
}

const char* DimensionMethodName(DimensionMethod method) {
  for (const auto& m : kMethodNames) {
    if (m.method == method) return m.name;
  }
  return "?";
}

bool ParseDimensionType(const std::string& text, DimensionType* type) {
  for (const auto& t : kTypeNames) {
    if (text == t.name) {
      *type = t.type;
      return true;
    }
  }
  return false;
}

bool ParseDimensionMethod(const std::string& text, DimensionMethod* method) {
  for (const auto& m : kMethodNames) {
    if (text == m.name) {
      *method = m.method;
      return true;
    }
  }
  return false;
}

std::vector<DimensionMethod> MethodsOf(DimensionType type) {
  using M = DimensionMethod;
  switch (type) {
    case DimensionType::kLength:
      return {M::kTwoPoint, M::kFaceToFace};
    case DimensionType::kDiameter:
    case DimensionType::kRadius:
      return {M::kCircle, M::kCylinder};
    case DimensionType::kPosition:
    case DimensionType::kTruePosition:
      return {M::kPoint, M::kCircle};
    case DimensionType::kPerpendicularity:
      return {M::kPlane, M::kAxis};
    case DimensionType::kAngle:
      return {M::kPlane, M::kLine};
    case DimensionType::kFlatness:
    case DimensionType::kParallelism:
    case DimensionType::kSymmetry:
      return {M::kPlane};
    case DimensionType::kRoundness:
    case DimensionType::kCoaxiality:
      return {M::kCircle};
  }
  return {};
}

DimensionMethod ResolvedMethod(DimensionType type, DimensionMethod method) {
  if (method != DimensionMethod::kDefault) return method;
  if (type == DimensionType::kTruePosition) return DimensionMethod::kCircle;
  return MethodsOf(type).front();
}

bool IsZoneType(DimensionType type) {
  switch (type) {
    case DimensionType::kTruePosition:
    case DimensionType::kFlatness:
    case DimensionType::kRoundness:
    case DimensionType::kParallelism:
    case DimensionType::kPerpendicularity:
    case DimensionType::kCoaxiality:
    case DimensionType::kSymmetry:
      return true;
    default:
      return false;
  }
}

std::vector<std::string> RequiredRoles(DimensionType type, DimensionMethod method) {
  method = ResolvedMethod(type, method);
  switch (type) {
    case DimensionType::kLength:
      return method == DimensionMethod::kTwoPoint ? std::vector<std::string>{"WALL_A", "WALL_B"}
                                                  : std::vector<std::string>{"FACE_A", "FACE_B"};
    case DimensionType::kDiameter:
    case DimensionType::kRadius:
    case DimensionType::kPosition:
    case DimensionType::kTruePosition:
    case DimensionType::kFlatness:
    case DimensionType::kRoundness:
      return {"FEATURE"};
    case DimensionType::kParallelism:
      return {"DATUM", "FEATURE"};
    case DimensionType::kPerpendicularity:
      return method == DimensionMethod::kAxis ? std::vector<std::string>{"DATUM", "LEVEL_1", "LEVEL_2"}
                                              : std::vector<std::string>{"DATUM", "FEATURE"};
    case DimensionType::kCoaxiality:
      return {"DATUM_1", "FEATURE_1"};
    case DimensionType::kSymmetry:
      return {"WALL_A", "WALL_B", "DATUM_A", "DATUM_B"};
    case DimensionType::kAngle:
      return method == DimensionMethod::kLine ? std::vector<std::string>{"LINE_A", "LINE_B"}
                                              : std::vector<std::string>{"FACE_A", "FACE_B"};
  }
  return {};
}

bool RoleAccepted(DimensionType type, DimensionMethod method, const std::string& role) {
  if (type == DimensionType::kCoaxiality) return role.rfind("DATUM_", 0) == 0 || role.rfind("FEATURE_", 0) == 0;
  if ((type == DimensionType::kPosition || type == DimensionType::kTruePosition) && role == "DATUM") return true;
  for (const auto& r : RequiredRoles(type, method)) {
    if (r == role) return true;
  }
  return false;
}

Result<double> EvaluateDimensionValue(const DimensionDefinition& definition, const std::vector<RolePoints>& roles) {
  if (definition.axis < 0 || definition.axis > 2) return Status::Internal("dimension axis out of range");
  return Evaluator(definition, roles).Value();
}

Result<DimensionEvaluation> EvaluateDimension(const DimensionDefinition& definition,
                                              const std::vector<RolePoints>& roles) {
  DimensionEvaluation out;
  FL_ASSIGN_OR_RETURN(out.value, EvaluateDimensionValue(definition, roles));
  // GUM propagation by central differences of the whole evaluation.
  constexpr double kStepMm = 1e-5;
  std::vector<RolePoints> work = roles;
  double variance = 0;
  for (std::size_t r = 0; r < work.size(); ++r) {
    out.points += static_cast<int>(work[r].points.size());
    for (std::size_t i = 0; i < work[r].points.size(); ++i) {
      ProbedPoint& p = work[r].points[i];
      if (!(p.u_mm > 0)) continue;
      for (int axis = 0; axis < 3; ++axis) {
        if (!p.measured[axis]) continue;
        const double keep = p.position(axis);
        p.position(axis) = keep + kStepMm;
        auto plus = EvaluateDimensionValue(definition, work);
        p.position(axis) = keep - kStepMm;
        auto minus = EvaluateDimensionValue(definition, work);
        p.position(axis) = keep;
        if (!plus.ok() || !minus.ok()) continue;  // a perturbation that breaks a fit adds nothing
        const double sensitivity = (*plus - *minus) / (2 * kStepMm);
        variance += sensitivity * sensitivity * p.u_mm * p.u_mm;
      }
    }
  }
  out.u = std::sqrt(variance);
  out.expanded_u = 2 * out.u;
  return out;
}

Judgement Judge(const Tolerance& tolerance, double value, double expanded_u) {
  Judgement j;
  j.deviation = value - tolerance.nominal;
  j.ok = tolerance.lower - kJudgementEpsilonMm <= j.deviation && j.deviation <= tolerance.upper + kJudgementEpsilonMm;
  j.excess = std::max({0.0, j.deviation - tolerance.upper, tolerance.lower - j.deviation});
  if (expanded_u > 0) {
    j.ambiguous = std::abs(j.deviation - tolerance.upper) < expanded_u ||
                  (!tolerance.zone && std::abs(j.deviation - tolerance.lower) < expanded_u);
  }
  return j;
}

}  // namespace formloop::metrology
