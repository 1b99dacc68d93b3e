#include "reconstruction/analytic_surface.h"

#include <cmath>

#include <Eigen/Dense>

namespace formloop::recon {

Eigen::Vector3d NormalFromDerivatives(const SurfaceDerivatives& d) {
  const Eigen::Vector3d n = d.su.cross(d.sv);
  const double length = n.norm();
  if (!(length > 0)) return Eigen::Vector3d::UnitZ();  // degenerate parametrisation: no normal
  return n / length;
}

// First fundamental form I = [E F; F G], second II = [L M; M N] with L = S_uu·n etc. The normal
// curvature in the tangent direction (du, dv) is (II / I)(du, dv) with the classical sign (positive
// where the surface bends towards n). formloop's convention is the opposite (positive = bends away
// from n, convex as seen by the tool), so the principal curvatures are the negated eigenvalues of
// the generalised symmetric problem II w = λ I w.
PrincipalCurvatures CurvaturesFromDerivatives(const SurfaceDerivatives& d) {
  const Eigen::Vector3d n = NormalFromDerivatives(d);
  Eigen::Matrix2d first;
  first << d.su.dot(d.su), d.su.dot(d.sv), d.su.dot(d.sv), d.sv.dot(d.sv);
  Eigen::Matrix2d second;
  second << d.suu.dot(n), d.suv.dot(n), d.suv.dot(n), d.svv.dot(n);

  PrincipalCurvatures out;
  // 2 × 2 generalised problem by Cholesky of I: I = C Cᵀ, A = C⁻¹ II C⁻ᵀ (symmetric).
  const Eigen::LLT<Eigen::Matrix2d> llt(first);
  if (llt.info() != Eigen::Success) {
    out.dir1 = d.su.normalized();
    out.dir2 = n.cross(out.dir1);
    return out;
  }
  const Eigen::Matrix2d c = llt.matrixL();
  const Eigen::Matrix2d c_inv = c.inverse();
  const Eigen::Matrix2d a = c_inv * second * c_inv.transpose();
  const Eigen::SelfAdjointEigenSolver<Eigen::Matrix2d> eig(0.5 * (a + a.transpose()));
  // Eigenvalues ascending: λ0 <= λ1, so k1 = -λ0 >= k2 = -λ1.
  out.k1 = -eig.eigenvalues()(0);
  out.k2 = -eig.eigenvalues()(1);
  const Eigen::Matrix2d w = c_inv.transpose() * eig.eigenvectors();  // parameter-space directions
  Eigen::Vector3d dir1 = d.su * w(0, 0) + d.sv * w(1, 0);
  dir1.normalize();
  out.dir1 = dir1;
  out.dir2 = n.cross(dir1);  // orthogonal to dir1 in the tangent plane (principal directions are)
  return out;
}

}  // namespace formloop::recon
