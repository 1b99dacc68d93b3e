// Power-form span polynomials of a tensor-product B-spline (span_polynomials.h).

#include "reconstruction/span_polynomials.h"

#include <Geom_BSplineSurface.hxx>
#include <TColStd_Array1OfReal.hxx>
#include <algorithm>
#include <string>

#include "reconstruction/bspline_surface.h"

namespace formloop::recon {
namespace {

constexpr int kMaxOrder = 8;  // degree ≤ 7 (KnotVector's limit)

std::vector<double> DistinctKnots(const KnotVector& k) {
  std::vector<double> values;
  std::vector<int> multiplicities;
  k.Distinct(&values, &multiplicities);
  return values;
}

// Powers of s and their first and second derivatives: e0[a] = s^a, e1[a] = a s^(a−1), e2[a] = a (a−1) s^(a−2).
template <int kP>
inline void Powers(int p_runtime, double s, double* e0, double* e1, double* e2) {
  const int p = kP > 0 ? kP : p_runtime;
  e0[0] = 1;
  e1[0] = 0;
  e2[0] = 0;
  for (int a = 1; a <= p; ++a) {
    e0[a] = e0[a - 1] * s;
    e1[a] = a * e0[a - 1];
    e2[a] = a >= 2 ? a * (a - 1) * e0[a - 2] : 0.0;
  }
}

// S and its derivatives from span coefficients c at local (s, t); kPu, kPv > 0 fix the degrees at compile
// time (the bicubic case), 0 takes them at run time.
template <int kPu, int kPv>
inline SurfaceDerivatives EvaluateSpan(int pu_runtime, int pv_runtime, const double* c, double s, double t,
                                       double inv_hu, double inv_hv) {
  const int pu = kPu > 0 ? kPu : pu_runtime, pv = kPv > 0 ? kPv : pv_runtime;
  double e0[kMaxOrder], e1[kMaxOrder], e2[kMaxOrder], f0[kMaxOrder], f1[kMaxOrder], f2[kMaxOrder];
  Powers<kPu>(pu, s, e0, e1, e2);
  Powers<kPv>(pv, t, f0, f1, f2);
  double p[3] = {0, 0, 0}, su[3] = {0, 0, 0}, sv[3] = {0, 0, 0}, suu[3] = {0, 0, 0}, suv[3] = {0, 0, 0},
         svv[3] = {0, 0, 0};
  // The terms with e1[0] = e2[0] = e2[1] = 0 (and the same of f) are left out: adding a product with a
  // zero factor to a sum that starts at +0 leaves it unchanged (finite coefficients), so the sums are the
  // same numbers with a sixth fewer multiplications at degree 5 (IEEE arithmetic does not let the compiler
  // drop c · 0 by itself).
  for (int b = 0; b <= pv; ++b) {
    double r0[3] = {0, 0, 0}, r1[3] = {0, 0, 0}, r2[3] = {0, 0, 0};
    const double* row = c + b * (pu + 1) * 3;
    for (int k = 0; k < 3; ++k) r0[k] = row[k] * e0[0];
    for (int a = 1; a <= pu; ++a) {
      for (int k = 0; k < 3; ++k) {
        r0[k] += row[a * 3 + k] * e0[a];
        r1[k] += row[a * 3 + k] * e1[a];
        if (a >= 2) r2[k] += row[a * 3 + k] * e2[a];
      }
    }
    for (int k = 0; k < 3; ++k) {
      p[k] += r0[k] * f0[b];
      su[k] += r1[k] * f0[b];
      suu[k] += r2[k] * f0[b];
      if (b >= 1) {
        sv[k] += r0[k] * f1[b];
        suv[k] += r1[k] * f1[b];
      }
      if (b >= 2) svv[k] += r0[k] * f2[b];
    }
  }
  SurfaceDerivatives d;
  d.p = Eigen::Vector3d(p[0], p[1], p[2]);
  d.su = Eigen::Vector3d(su[0], su[1], su[2]) * inv_hu;
  d.sv = Eigen::Vector3d(sv[0], sv[1], sv[2]) * inv_hv;
  d.suu = Eigen::Vector3d(suu[0], suu[1], suu[2]) * (inv_hu * inv_hu);
  d.suv = Eigen::Vector3d(suv[0], suv[1], suv[2]) * (inv_hu * inv_hv);
  d.svv = Eigen::Vector3d(svv[0], svv[1], svv[2]) * (inv_hv * inv_hv);
  return d;
}

}  // namespace

double SpanPolynomials::EstimateBytes(int u_degree, int v_degree, double u_spans, double v_spans) {
  return u_spans * v_spans * (u_degree + 1) * (v_degree + 1) * 3 * sizeof(double);
}

Result<SpanPolynomials> SpanPolynomials::Make(const KnotVector& u_knots, const KnotVector& v_knots,
                                              const std::vector<Eigen::Vector3d>& poles) {
  const int nu = u_knots.n_poles(), nv = v_knots.n_poles();
  if (nu <= 0 || nv <= 0 || poles.size() != static_cast<std::size_t>(nu) * static_cast<std::size_t>(nv)) {
    return Status::BadInput("span polynomials: " + std::to_string(poles.size()) + " poles for a " + std::to_string(nu) +
                            " × " + std::to_string(nv) + " net");
  }
  SpanPolynomials out;
  out.pu_ = u_knots.degree();
  out.pv_ = v_knots.degree();
  out.u_knots_ = DistinctKnots(u_knots);
  out.v_knots_ = DistinctKnots(v_knots);
  const int su_count = static_cast<int>(out.u_knots_.size()) - 1, sv_count = static_cast<int>(out.v_knots_.size()) - 1;
  const int qu = out.pu_ + 1, qv = out.pv_ + 1, block = qu * qv * 3;
  out.coefficients_.assign(static_cast<std::size_t>(su_count) * sv_count * block, 0.0);
  // Factorials h^a / a! per span and direction, from the basis derivatives at the span centre.
  auto taylor = [](const KnotVector& k, double lo, double hi, Eigen::MatrixXd* ders, int* span) {
    const double c = 0.5 * (lo + hi), h = 0.5 * (hi - lo);
    *span = k.FindSpan(c);
    k.BasisDerivatives(*span, c, k.degree(), ders);
    double scale = 1;
    for (int a = 0; a < ders->rows(); ++a) {
      ders->row(a) *= scale;
      scale *= h / (a + 1);
    }
  };
  Eigen::MatrixXd du, dv;
  for (int j = 0; j < sv_count; ++j) {
    int span_v = 0;
    taylor(v_knots, out.v_knots_[static_cast<std::size_t>(j)], out.v_knots_[static_cast<std::size_t>(j) + 1], &dv,
           &span_v);
    for (int i = 0; i < su_count; ++i) {
      int span_u = 0;
      taylor(u_knots, out.u_knots_[static_cast<std::size_t>(i)], out.u_knots_[static_cast<std::size_t>(i) + 1], &du,
             &span_u);
      double* c = &out.coefficients_[(static_cast<std::size_t>(j) * su_count + i) * block];
      for (int l = 0; l < qv; ++l) {
        for (int k = 0; k < qu; ++k) {
          const Eigen::Vector3d& pole = poles[static_cast<std::size_t>(span_u - out.pu_ + k) +
                                              static_cast<std::size_t>(nu) * (span_v - out.pv_ + l)];
          for (int b = 0; b < dv.rows(); ++b) {
            for (int a = 0; a < du.rows(); ++a) {
              const double w = du(a, k) * dv(b, l);
              double* cab = c + (b * qu + a) * 3;
              cab[0] += w * pole.x();
              cab[1] += w * pole.y();
              cab[2] += w * pole.z();
            }
          }
        }
      }
    }
  }
  return out;
}

Result<SpanPolynomials> SpanPolynomials::Of(const BSplineSurface& surface) {
  if (!surface.valid()) return Status::BadInput("span polynomials: the surface is empty");
  const Handle(Geom_BSplineSurface)& geom = surface.geom();
  if (geom->IsURational() || geom->IsVRational() || geom->IsUPeriodic() || geom->IsVPeriodic()) {
    return Status::BadInput("span polynomials: the surface is rational or periodic");
  }
  auto sequence = [](const TColStd_Array1OfReal& flat, int degree) {
    std::vector<double> knots;
    for (int i = flat.Lower(); i <= flat.Upper(); ++i) knots.push_back(flat(i));
    return KnotVector::FromSequence(degree, std::move(knots));
  };
  FL_ASSIGN_OR_RETURN(const KnotVector ku, sequence(geom->UKnotSequence(), geom->UDegree()));
  FL_ASSIGN_OR_RETURN(const KnotVector kv, sequence(geom->VKnotSequence(), geom->VDegree()));
  std::vector<Eigen::Vector3d> poles;
  poles.reserve(static_cast<std::size_t>(geom->NbUPoles()) * geom->NbVPoles());
  for (int j = 1; j <= geom->NbVPoles(); ++j) {
    for (int i = 1; i <= geom->NbUPoles(); ++i) {
      const gp_Pnt& q = geom->Pole(i, j);
      poles.emplace_back(q.X(), q.Y(), q.Z());
    }
  }
  return Make(ku, kv, poles);
}

int SpanPolynomials::Span(const std::vector<double>& knots, double x, int hint) const {
  const int last = static_cast<int>(knots.size()) - 2;
  const std::size_t h = static_cast<std::size_t>(hint);
  if ((hint == 0 || x >= knots[h]) && (hint == last || x < knots[h + 1])) return hint;
  // Number of interior knots ≤ x: [k_i, k_i+1) with the last span closed, the end spans beyond.
  return static_cast<int>(std::upper_bound(knots.begin() + 1, knots.end() - 1, x) - (knots.begin() + 1));
}

SurfaceDerivatives SpanPolynomials::Evaluator::D2(double u, double v) {
  i_ = s_.Span(s_.u_knots_, u, i_);
  j_ = s_.Span(s_.v_knots_, v, j_);
  const std::size_t i = static_cast<std::size_t>(i_), j = static_cast<std::size_t>(j_);
  const double hu = 0.5 * (s_.u_knots_[i + 1] - s_.u_knots_[i]), hv = 0.5 * (s_.v_knots_[j + 1] - s_.v_knots_[j]);
  const double s = (u - 0.5 * (s_.u_knots_[i] + s_.u_knots_[i + 1])) / hu;
  const double t = (v - 0.5 * (s_.v_knots_[j] + s_.v_knots_[j + 1])) / hv;
  const std::size_t block = static_cast<std::size_t>(s_.pu_ + 1) * (s_.pv_ + 1) * 3;
  const double* c = &s_.coefficients_[(j * (s_.u_knots_.size() - 1) + i) * block];
  // Equal degrees (the usual case) with the loops unrolled at compile time.
  if (s_.pu_ == s_.pv_) {
    switch (s_.pu_) {
      case 2:
        return EvaluateSpan<2, 2>(2, 2, c, s, t, 1 / hu, 1 / hv);
      case 3:
        return EvaluateSpan<3, 3>(3, 3, c, s, t, 1 / hu, 1 / hv);
      case 4:
        return EvaluateSpan<4, 4>(4, 4, c, s, t, 1 / hu, 1 / hv);
      case 5:
        return EvaluateSpan<5, 5>(5, 5, c, s, t, 1 / hu, 1 / hv);
      default:
        break;
    }
  }
  return EvaluateSpan<0, 0>(s_.pu_, s_.pv_, c, s, t, 1 / hu, 1 / hv);
}

Eigen::Vector3d SpanPolynomials::Evaluator::Point(double u, double v) { return D2(u, v).p; }

}  // namespace formloop::recon
