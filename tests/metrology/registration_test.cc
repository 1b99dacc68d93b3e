// Optional registration to the ideal surface (metrology/registration.h, spec/metrology.md §3): a known
// small rigid offset is recovered, masked DOF stay exactly zero, off by default, bad input is named.

#include <array>
#include <cmath>
#include <vector>

#include <gtest/gtest.h>

#include "core/random.h"
#include "metrology/registration.h"
#include "reconstruction/analytic_surface.h"
#include "reconstruction/foot_point.h"

namespace formloop::metrology {
namespace {

struct Fixture {
  std::unique_ptr<recon::AnalyticSurface> surface;
  std::vector<Eigen::Vector3d> on_surface;
};

// n seeded points on the inner 80 % of a reference surface.
Fixture Sample(const std::string& name, int n, std::uint64_t seed) {
  Fixture f;
  auto s = recon::MakeReferenceSurface(name);
  EXPECT_TRUE(s.ok());
  f.surface = std::move(s).value();
  const recon::ParamDomain d = f.surface->domain();
  Rng rng(seed);
  for (int i = 0; i < n; ++i) {
    const double u = d.u_min + d.u_span() * rng.Uniform(0.1, 0.9), v = d.v_min + d.v_span() * rng.Uniform(0.1, 0.9);
    f.on_surface.push_back(f.surface->Point(u, v));
  }
  return f;
}

// The measured points that `values` (about their own centroid) maps back onto the surface points: with
// pivot c = s̄ − t, m_i = Rᵀ(s_i − s̄) + c has centroid c, and RegistrationTransform(values, c)·m_i = s_i.
std::vector<Eigen::Vector3d> Displace(const std::vector<Eigen::Vector3d>& s, const std::array<double, 6>& values) {
  Eigen::Vector3d mean = Eigen::Vector3d::Zero();
  for (const auto& p : s) mean += p;
  mean /= static_cast<double>(s.size());
  const Eigen::Vector3d t(values[kTx], values[kTy], values[kTz]);
  const Eigen::Vector3d pivot = mean - t;
  const Eigen::Matrix3d R = RegistrationTransform(values, pivot).linear();
  std::vector<Eigen::Vector3d> m;
  for (const auto& p : s) m.push_back(R.transpose() * (p - mean) + pivot);
  return m;
}

TEST(RegistrationTest, RecoversASmallRigidOffsetInAllSixDof) {
  Fixture f = Sample("franke", 400, 7);
  const std::array<double, 6> truth = {0.05, -0.03, 0.02, 2e-4, -3e-4, 5e-4};
  const std::vector<Eigen::Vector3d> measured = Displace(f.on_surface, truth);
  auto projector = recon::FootPointProjector::Build(*f.surface);
  ASSERT_TRUE(projector.ok());
  RegistrationOptions options;
  ASSERT_TRUE(ParseDofMask("all").ok());
  options.dofs = *ParseDofMask("all");
  Result<RegistrationReport> report = RegisterToSurface(measured, *projector, options);
  ASSERT_TRUE(report.ok()) << report.status().ToString();
  EXPECT_TRUE(report->enabled);
  for (int d = 0; d < 6; ++d) {
    EXPECT_NEAR(report->values[d], truth[d], d < 3 ? 1e-7 : 1e-9) << kDofNames[d];
  }
  EXPECT_GT(report->rms_before_mm, 0.01);
  EXPECT_LT(report->rms_after_mm, 1e-7);
  EXPECT_LE(report->iterations, 10);
  // The reported transform moves the measured points onto the surface.
  for (int i = 0; i < 5; ++i) EXPECT_LT((report->part_from_machine * measured[i] - f.on_surface[i]).norm(), 1e-6);
  const nlohmann::json json = report->ToJson();
  EXPECT_EQ(json["dofs"], "tx,ty,tz,rx,ry,rz");
  EXPECT_NEAR(json["values"]["rz_rad"].get<double>(), 5e-4, 1e-9);
}

TEST(RegistrationTest, MaskedDofStayExactlyZero) {
  Fixture f = Sample("franke", 300, 11);
  // The setup error has tx and rz too, but only tz, rx, ry are free: tx and rz must stay 0 (not absorbed).
  const std::array<double, 6> truth = {0.0, 0.0, 0.03, 4e-4, -2e-4, 0.0};
  const std::vector<Eigen::Vector3d> measured = Displace(f.on_surface, truth);
  auto projector = recon::FootPointProjector::Build(*f.surface);
  ASSERT_TRUE(projector.ok());
  RegistrationOptions options;
  Result<DofMask> mask = ParseDofMask("tz,rx,ry");
  ASSERT_TRUE(mask.ok());
  options.dofs = *mask;
  Result<RegistrationReport> report = RegisterToSurface(measured, *projector, options);
  ASSERT_TRUE(report.ok()) << report.status().ToString();
  EXPECT_EQ(report->values[kTx], 0.0);
  EXPECT_EQ(report->values[kTy], 0.0);
  EXPECT_EQ(report->values[kRz], 0.0);
  EXPECT_EQ(report->standard_errors[kTx], 0.0);
  EXPECT_NEAR(report->values[kTz], 0.03, 1e-7);
  EXPECT_NEAR(report->values[kRx], 4e-4, 1e-9);
  EXPECT_NEAR(report->values[kRy], -2e-4, 1e-9);
  EXPECT_LT(report->rms_after_mm, 1e-7);
  EXPECT_EQ(DofMaskToString(report->dofs), "tz,rx,ry");
}

TEST(RegistrationTest, OffByDefault) {
  Fixture f = Sample("franke", 50, 3);
  std::vector<Eigen::Vector3d> measured = f.on_surface;
  for (auto& p : measured) p.z() += 0.01;
  auto projector = recon::FootPointProjector::Build(*f.surface);
  ASSERT_TRUE(projector.ok());
  Result<RegistrationReport> report = RegisterToSurface(measured, *projector, RegistrationOptions{});
  ASSERT_TRUE(report.ok());
  EXPECT_FALSE(report->enabled);
  EXPECT_TRUE(report->part_from_machine.matrix().isIdentity(0.0));
  EXPECT_EQ(report->rms_before_mm, report->rms_after_mm);
  EXPECT_GT(report->rms_before_mm, 0.005);  // the 10 µm offset stays in the data, reported
}

TEST(RegistrationTest, BadInputIsNamed) {
  EXPECT_FALSE(ParseDofMask("tx,yaw").ok());
  EXPECT_NE(ParseDofMask("tx,yaw").status().message().find("'yaw'"), std::string::npos);

  // A plane does not constrain sliding along itself.
  Fixture plane = Sample("plane", 40, 5);
  auto projector = recon::FootPointProjector::Build(*plane.surface);
  ASSERT_TRUE(projector.ok());
  RegistrationOptions options;
  options.dofs = *ParseDofMask("tx,tz");
  Status s = RegisterToSurface(plane.on_surface, *projector, options).status();
  EXPECT_EQ(s.code(), StatusCode::kBadInput);
  EXPECT_NE(s.message().find("does not constrain tx"), std::string::npos) << s.message();

  // A point far from the surface is an error naming it, not an outlier silently dropped.
  std::vector<Eigen::Vector3d> points = plane.on_surface;
  points[17].z() += 5.0;
  options.dofs = *ParseDofMask("tz");
  s = RegisterToSurface(points, *projector, options).status();
  EXPECT_EQ(s.code(), StatusCode::kBadInput);
  EXPECT_NE(s.message().find("points[17]"), std::string::npos) << s.message();
  EXPECT_NE(s.message().find("search distance"), std::string::npos) << s.message();
}

}  // namespace
}  // namespace formloop::metrology
