#include "planning/inspection_adjustment.h"

#include <fcntl.h>
#include <unistd.h>

#include <Eigen/Geometry>
#include <Eigen/SVD>
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <limits>
#include <numeric>
#include <unordered_map>

#include "core/file_hash.h"
#include "core/json_io.h"
#include "core/point_io.h"
#include "metrology/morans_i.h"
#include "metrology/spatial_weights.h"

namespace formloop::planning {
namespace {

constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();

// Buckets of points over XY (cell c): neighbours within a radius without a tree.
class XyHash {
 public:
  explicit XyHash(double cell) : cell_(cell) {}
  void Add(const Eigen::Vector3d& p, int id) { cells_[Key(Cell(p.x()), Cell(p.y()))].push_back(id); }
  // Calls f(id) for every id whose cell overlaps the square of half-width r around p.
  template <typename F>
  void ForEachNear(const Eigen::Vector3d& p, double r, F f) const {
    const long x0 = Cell(p.x() - r), x1 = Cell(p.x() + r), y0 = Cell(p.y() - r), y1 = Cell(p.y() + r);
    for (long x = x0; x <= x1; ++x) {
      for (long y = y0; y <= y1; ++y) {
        auto it = cells_.find(Key(x, y));
        if (it == cells_.end()) continue;
        for (int id : it->second) f(id);
      }
    }
  }

 private:
  long Cell(double v) const { return static_cast<long>(std::floor(v / cell_)); }
  static std::int64_t Key(long x, long y) { return (static_cast<std::int64_t>(x) << 32) ^ (y & 0xffffffffLL); }
  double cell_;
  std::unordered_map<std::int64_t, std::vector<int>> cells_;
};

// The systematic field ê(x) = Σ w_k e_k / Σ w_k, w_k = exp(−|x − q_k|²/2h²) over the points within 3h.
class SystematicField {
 public:
  SystematicField(const std::vector<metrology::Deviation>& points, double h) : points_(points), h_(h), hash_(h) {
    for (std::size_t i = 0; i < points.size(); ++i) hash_.Add(points[i].foot, static_cast<int>(i));
  }
  double At(const Eigen::Vector3d& x) const {
    double num = 0, den = 0;
    hash_.ForEachNear(x, 3 * h_, [&](int j) {
      const double d2 = (points_[static_cast<std::size_t>(j)].foot - x).squaredNorm();
      if (d2 > 9 * h_ * h_) return;
      const double w = std::exp(-d2 / (2 * h_ * h_));
      num += w * points_[static_cast<std::size_t>(j)].deviation_mm;
      den += w;
    });
    return den > 0 ? num / den : 0.0;
  }
  const XyHash& hash() const { return hash_; }

 private:
  const std::vector<metrology::Deviation>& points_;
  double h_;
  XyHash hash_;
};

double MedianNearestSpacing(const std::vector<metrology::Deviation>& points) {
  Eigen::Vector3d lo = points.front().foot, hi = lo;
  for (const auto& p : points) {
    lo = lo.cwiseMin(p.foot);
    hi = hi.cwiseMax(p.foot);
  }
  const double area = std::max((hi - lo).head<2>().prod(), 1e-6);
  const double cell = std::max(std::sqrt(area / static_cast<double>(points.size())), 1e-3);
  XyHash hash(cell);
  for (std::size_t i = 0; i < points.size(); ++i) hash.Add(points[i].foot, static_cast<int>(i));
  std::vector<double> nearest;
  for (std::size_t i = 0; i < points.size(); ++i) {
    double best = std::numeric_limits<double>::infinity();
    for (double r = cell; !std::isfinite(best) && r < 1e3 * cell; r *= 2) {
      hash.ForEachNear(points[i].foot, r, [&](int j) {
        if (j != static_cast<int>(i)) best = std::min(best, (points[j].foot - points[i].foot).norm());
      });
    }
    if (std::isfinite(best)) nearest.push_back(best);
  }
  std::nth_element(nearest.begin(), nearest.begin() + nearest.size() / 2, nearest.end());
  return nearest[nearest.size() / 2];
}

std::string Mm(double v) { return FormatFixed(v, 4); }

nlohmann::json Vec(const Eigen::Vector3d& v) { return {v.x(), v.y(), v.z()}; }

// The shift profile of one edited block: normal shift D (into the material, mm) at fractions along it.
struct ShiftProfile {
  std::vector<std::pair<double, double>> at;  // (fraction, D), ascending
  double D(double t) const {
    if (at.empty()) return 0;
    if (t <= at.front().first) return at.front().second;
    for (std::size_t i = 1; i < at.size(); ++i) {
      if (t <= at[i].first) {
        const double w = (t - at[i - 1].first) / (at[i].first - at[i - 1].first);
        return at[i - 1].second + w * (at[i].second - at[i - 1].second);
      }
    }
    return at.back().second;
  }
};

}  // namespace

Status InspectionOptions::Validate() const {
  if (!(tolerance_mm > 0)) return Status::BadInput(Where{.field = "tolerance_mm"}, "must be > 0");
  if (!(grid_spacing_mm >= 0))
    return Status::BadInput(Where{.field = "grid_spacing_mm"}, "must be >= 0 (0: automatic)");
  if (!(gamma >= 0.5 && gamma <= 1.0)) return Status::BadInput(Where{.field = "gamma"}, "must lie in [0.5, 1] (§3.4)");
  if (!(max_offset_mm > 0)) return Status::BadInput(Where{.field = "max_offset_mm"}, "must be > 0");
  if (!(force_exponent > 0)) return Status::BadInput(Where{.field = "force_exponent"}, "must be > 0");
  return Status::Ok();
}

RigidFit FitRigidDisplacement(const std::vector<metrology::Deviation>& points) {
  const auto n = static_cast<Eigen::Index>(points.size());
  Eigen::MatrixXd a(n, 6);
  Eigen::VectorXd b(n);
  for (Eigen::Index k = 0; k < n; ++k) {
    const metrology::Deviation& p = points[static_cast<std::size_t>(k)];
    a.block<1, 3>(k, 0) = p.normal.transpose();
    a.block<1, 3>(k, 3) = p.foot.cross(p.normal).transpose();  // (ω × q)·n = ω·(q × n)
    b(k) = p.deviation_mm;
  }
  Eigen::JacobiSVD<Eigen::MatrixXd> svd(a, Eigen::ComputeThinU | Eigen::ComputeThinV);
  const Eigen::VectorXd& sv = svd.singularValues();
  Eigen::VectorXd x = Eigen::VectorXd::Zero(6);
  RigidFit fit;
  for (Eigen::Index i = 0; i < sv.size(); ++i) {
    if (sv(i) <= 1e-9 * sv(0)) continue;  // a free DOF: no component along it
    x += svd.matrixV().col(i) * (svd.matrixU().col(i).dot(b) / sv(i));
    ++fit.rank;
  }
  fit.tau = x.head<3>();
  fit.omega = x.tail<3>();
  const Eigen::VectorXd r = b - a * x;
  fit.residual_mm.assign(r.data(), r.data() + r.size());
  fit.form_error_mm = n > 0 ? r.maxCoeff() - r.minCoeff() : 0;
  return fit;
}

nlohmann::json InspectionEvaluation::ToJson() const {
  return {{"h_mm", h_mm},
          {"PE_mm", profile_error_mm},
          {"FE_mm", fit.form_error_mm},
          {"tau_mm", Vec(fit.tau)},
          {"omega_rad", Vec(fit.omega)},
          {"tau_norm_mm", fit.tau.norm()},
          {"omega_norm_rad", fit.omega.norm()},
          {"rigid_rank", fit.rank},
          {"moran_i", moran_i},
          {"moran_z", moran_z},
          {"sigma_rand_mm", sigma_random_mm},
          {"systematic", systematic}};
}

Result<InspectionEvaluation> EvaluateInspection(const std::vector<metrology::Deviation>& points,
                                                const InspectionOptions& options) {
  FL_RETURN_IF_ERROR(options.Validate());
  if (points.size() < 8)
    return Status::BadInput("inspection: at least 8 points are needed, got " + std::to_string(points.size()));
  InspectionEvaluation ev;
  ev.h_mm = options.grid_spacing_mm > 0 ? options.grid_spacing_mm : MedianNearestSpacing(points);
  const SystematicField field(points, ev.h_mm);
  ev.e_hat_mm.resize(points.size());
  double sum = 0, sum2 = 0;
  for (std::size_t k = 0; k < points.size(); ++k) {
    ev.e_hat_mm[k] = field.At(points[k].foot);
    const double eps = points[k].deviation_mm - ev.e_hat_mm[k];
    sum += eps;
    sum2 += eps * eps;
    ev.profile_error_mm = std::max(ev.profile_error_mm, 2 * std::abs(points[k].deviation_mm));
  }
  const double n = static_cast<double>(points.size());
  ev.sigma_random_mm = std::sqrt(std::max(0.0, (sum2 - sum * sum / n) / (n - 1)));
  ev.fit = FitRigidDisplacement(points);
  // Moran's I with inverse-distance weights on the 2h band.
  Eigen::MatrixXd xyz(3, points.size());
  Eigen::VectorXd e(points.size());
  for (std::size_t k = 0; k < points.size(); ++k) {
    xyz.col(static_cast<Eigen::Index>(k)) = points[k].foot;
    e(static_cast<Eigen::Index>(k)) = points[k].deviation_mm;
  }
  FL_ASSIGN_OR_RETURN(metrology::SpatialWeights w,
                      metrology::DistanceBandWeights(xyz, 2 * ev.h_mm * (1 + 1e-9), metrology::WeightStyle::kBinary));
  for (Eigen::Index row = 0; row < w.w.outerSize(); ++row) {
    for (decltype(w.w)::InnerIterator it(w.w, row); it; ++it) {
      it.valueRef() = 1 / (xyz.col(row) - xyz.col(it.col())).norm();
    }
  }
  FL_ASSIGN_OR_RETURN(const metrology::MoranResult moran,
                      metrology::MoranI(e, w, {.islands = metrology::IslandPolicy::kZero}));
  ev.moran_i = moran.i;
  ev.moran_z = moran.z_normality;
  ev.systematic = moran.z_normality > options.z_threshold;
  return ev;
}

Result<ProgramGeometry> BuildProgramGeometry(const EditableProgram& program, const recon::FootPointProjector& nominal,
                                             double ball_radius_mm, double sample_mm) {
  if (!(ball_radius_mm > 0) || !(sample_mm > 0)) {
    return Status::BadInput("program geometry: the ball radius and the sample spacing must be > 0");
  }
  ProgramGeometry g;
  g.ball_radius_mm = ball_radius_mm;
  g.sample_mm = sample_mm;
  const std::vector<nc::ProgramMove>& moves = program.moves();
  int pass = -1;
  bool in_run = false;
  double u = kNaN, v = kNaN;
  for (std::size_t i = 1; i < moves.size(); ++i) {
    if (moves[i].rapid) {
      in_run = false;
      continue;
    }
    const Eigen::Vector3d a = moves[i - 1].tip, b = moves[i].tip;
    if (!a.allFinite() || !b.allFinite() || (b - a).norm() == 0) continue;
    if (!in_run) {
      ++pass;
      in_run = true;
      u = v = kNaN;
    }
    CutBlock block{i, program.LineOfMove(i), pass, a, b, {}};
    const int k = std::max(1, static_cast<int>(std::ceil((b - a).norm() / sample_mm)));
    for (int j = 0; j <= k; ++j) {
      const double t = static_cast<double>(j) / k;
      const Eigen::Vector3d centre = a + (b - a) * t + ball_radius_mm * Eigen::Vector3d::UnitZ();
      Result<recon::FootPoint> f = std::isnan(u) ? nominal.Project(centre) : nominal.ProjectFrom(centre, u, v);
      if (!f.ok()) f = nominal.Project(centre);
      if (!f.ok()) return Status(f.status().code(), program.BlockName(block.line) + ": " + f.status().message());
      u = f->u;
      v = f->v;
      block.samples.push_back({f->foot, f->normal, t});
    }
    g.blocks.push_back(std::move(block));
  }
  if (g.blocks.empty()) return Status::BadInput("the program has no feed moves to map an inspection onto");
  // Pass spacing: from each pass's first CC sample to the nearest sample of the previous pass.
  XyHash hash(1.0);
  std::vector<std::pair<int, int>> ids;
  std::vector<double> spacing;
  std::size_t b = 0;
  for (int p = 0; p <= pass; ++p) {
    const std::size_t first = b;
    for (; b < g.blocks.size() && g.blocks[b].pass == p; ++b) {
    }
    if (p > 0 && first < g.blocks.size()) {
      const Eigen::Vector3d& x = g.blocks[first].samples.front().cc;
      double best = std::numeric_limits<double>::infinity();
      for (double r = 1; !std::isfinite(best) && r < 1e4; r *= 2) {
        hash.ForEachNear(x, r, [&](int id) {
          const auto [bi, si] = ids[static_cast<std::size_t>(id)];
          best = std::min(best, (g.blocks[bi].samples[si].cc - x).norm());
        });
      }
      if (std::isfinite(best)) spacing.push_back(best);
    }
    // The pass just finished joins the hash for the next one (only the previous pass is needed; older
    // passes are farther).
    for (std::size_t k = first; k < b; ++k) {
      for (std::size_t s = 0; s < g.blocks[k].samples.size(); ++s) {
        hash.Add(g.blocks[k].samples[s].cc, static_cast<int>(ids.size()));
        ids.emplace_back(static_cast<int>(k), static_cast<int>(s));
      }
    }
  }
  if (!spacing.empty()) {
    std::nth_element(spacing.begin(), spacing.begin() + spacing.size() / 2, spacing.end());
    g.pass_spacing_mm = spacing[spacing.size() / 2];
  }
  return g;
}

nlohmann::json ErrorRegion::ToJson() const {
  return {{"sign", sign},
          {"centroid_mm", Vec(centroid)},
          {"area_mm2", area_mm2},
          {"peak_mm", peak_mm},
          {"points", points.size()},
          {"blocks", blocks.size()},
          {"block_ranges", block_ranges},
          {"type", type},
          {"rho", std::isnan(rho) ? nlohmann::json(nullptr) : nlohmann::json(rho)}};
}

nlohmann::json InspectionAdjustment::ToJson() const {
  nlohmann::json r = nlohmann::json::array();
  for (const ErrorRegion& region : regions) r.push_back(region.ToJson());
  nlohmann::json out = nlohmann::json::array();
  for (const auto& [id, block] : out_of_tolerance) out.push_back({{"id", id}, {"block", block}});
  return {{"evaluation", evaluation.ToJson()},
          {"regions", r},
          {"out_of_tolerance", out},
          {"program_kind", kind},
          {"non_conforming", non_conforming},
          {"blocks_split", blocks_split},
          {"cl_points_shifted", cl_points_shifted},
          {"feeds_changed", feeds_changed},
          {"max_shift_mm", max_shift_mm},
          {"alarms", alarms},
          {"notes", notes}};
}

Result<InspectionAdjustment> AdjustProgramFromInspection(const EditableProgram& parent, const ProgramGeometry& geometry,
                                                         const recon::FootPointProjector& nominal,
                                                         const std::vector<metrology::Deviation>& points,
                                                         const std::map<std::string, double>& block_load,
                                                         const InspectionOptions& options, const std::string& source) {
  InspectionAdjustment out;
  FL_ASSIGN_OR_RETURN(out.evaluation, EvaluateInspection(points, options));
  const InspectionEvaluation& ev = out.evaluation;
  const double h = ev.h_mm, half_tol = options.tolerance_mm / 2;
  const std::vector<CutBlock>& blocks = geometry.blocks;

  // Every CC sample, its ê, in one hash.
  std::vector<std::pair<int, int>> sample_ids;
  std::vector<double> sample_e_hat;
  XyHash samples(std::max(h, 0.5));
  const SystematicField systematic(points, h);
  const XyHash& point_hash = systematic.hash();
  auto field = [&](const Eigen::Vector3d& x) { return systematic.At(x); };
  for (std::size_t b = 0; b < blocks.size(); ++b) {
    for (std::size_t s = 0; s < blocks[b].samples.size(); ++s) {
      samples.Add(blocks[b].samples[s].cc, static_cast<int>(sample_ids.size()));
      sample_ids.emplace_back(static_cast<int>(b), static_cast<int>(s));
      sample_e_hat.push_back(field(blocks[b].samples[s].cc));
    }
  }
  auto nearest_sample = [&](const Eigen::Vector3d& x, double radius) {
    int best = -1;
    double best_d = radius;
    samples.ForEachNear(x, radius, [&](int id) {
      const auto [b, s] = sample_ids[static_cast<std::size_t>(id)];
      const double d = (blocks[b].samples[s].cc - x).norm();
      if (d <= best_d) {
        best_d = d;
        best = id;
      }
    });
    return best;
  };
  const double map_radius = std::max(geometry.pass_spacing_mm, h);
  for (std::size_t k = 0; k < points.size(); ++k) {
    if (std::abs(points[k].deviation_mm) <= half_tol) continue;
    const int id = nearest_sample(points[k].foot, map_radius);
    out.out_of_tolerance.emplace_back(
        points[k].id,
        id < 0 ? "unmapped" : parent.BlockName(blocks[sample_ids[static_cast<std::size_t>(id)].first].line));
  }

  // Regions: |ê| > t_p/2 of one sign, connected within 1.5h.
  std::vector<int> region_of(points.size(), -1);
  for (std::size_t k = 0; k < points.size(); ++k) {
    if (region_of[k] >= 0 || std::abs(ev.e_hat_mm[k]) <= half_tol) continue;
    ErrorRegion region;
    region.sign = ev.e_hat_mm[k] > 0 ? 1 : -1;
    const int index = static_cast<int>(out.regions.size());
    std::vector<int> stack = {static_cast<int>(k)};
    region_of[k] = index;
    while (!stack.empty()) {
      const int i = stack.back();
      stack.pop_back();
      region.points.push_back(i);
      point_hash.ForEachNear(points[i].foot, 1.5 * h, [&](int j) {
        if (region_of[j] >= 0 || std::abs(ev.e_hat_mm[j]) <= half_tol || (ev.e_hat_mm[j] > 0) != (region.sign > 0) ||
            (points[j].foot - points[i].foot).norm() > 1.5 * h * (1 + 1e-9)) {
          return;
        }
        region_of[j] = index;
        stack.push_back(j);
      });
    }
    std::sort(region.points.begin(), region.points.end());
    for (int i : region.points) {
      region.centroid += points[i].foot;
      if (std::abs(ev.e_hat_mm[i]) > std::abs(region.peak_mm)) region.peak_mm = ev.e_hat_mm[i];
    }
    region.centroid /= static_cast<double>(region.points.size());
    region.area_mm2 = static_cast<double>(region.points.size()) * h * h;
    // Forward mapping: a CC sample within 1.5h of a region point with |ê| > t_p/2 there.
    std::vector<char> in(blocks.size(), 0);
    for (int i : region.points) {
      samples.ForEachNear(points[i].foot, 1.5 * h, [&](int id) {
        const auto [b, s] = sample_ids[static_cast<std::size_t>(id)];
        if ((blocks[b].samples[s].cc - points[i].foot).norm() <= 1.5 * h &&
            std::abs(sample_e_hat[static_cast<std::size_t>(id)]) > half_tol) {
          in[static_cast<std::size_t>(b)] = 1;
        }
      });
    }
    for (std::size_t b = 0; b < blocks.size(); ++b) {
      if (in[b]) region.blocks.push_back(static_cast<int>(b));
    }
    // Ranges per pass.
    for (std::size_t i = 0; i < region.blocks.size();) {
      std::size_t j = i;
      while (j + 1 < region.blocks.size() && region.blocks[j + 1] == region.blocks[j] + 1 &&
             blocks[region.blocks[j + 1]].pass == blocks[region.blocks[i]].pass) {
        ++j;
      }
      region.block_ranges.push_back(parent.BlockName(blocks[region.blocks[i]].line) + "-" +
                                    parent.BlockName(blocks[region.blocks[j]].line));
      i = j + 1;
    }
    out.regions.push_back(std::move(region));
  }

  // Blocks near a set of blocks: a sample within `radius` of one of theirs.
  auto near_blocks = [&](const std::vector<int>& set, double radius) {
    std::vector<char> mark(blocks.size(), 0);
    for (int b : set) {
      mark[static_cast<std::size_t>(b)] = 1;
      for (const CcSample& s : blocks[b].samples) {
        samples.ForEachNear(s.cc, radius, [&](int id) {
          const auto [ob, os] = sample_ids[static_cast<std::size_t>(id)];
          if ((blocks[ob].samples[os].cc - s.cc).norm() <= radius) mark[static_cast<std::size_t>(ob)] = 1;
        });
      }
    }
    return mark;
  };

  // Classification and the corrections (only for a systematic pattern).
  std::map<int, double> phi;                 // block -> feed scale
  std::vector<char> edit(blocks.size(), 0);  // blocks whose CL points are offset
  std::vector<char> deflection(blocks.size(), 0);
  const double dilation = 2 * geometry.pass_spacing_mm * 1.01;
  for (ErrorRegion& region : out.regions) {
    region.rho = kNaN;
    if (region.sign < 0) {
      region.type = "overcut";
      out.non_conforming = true;
    } else {
      const std::vector<char> dilated = near_blocks(region.blocks, dilation);
      std::vector<double> xs, ys;
      for (std::size_t b = 0; b < blocks.size(); ++b) {
        if (!dilated[b]) continue;
        auto it = block_load.find(parent.BlockName(blocks[b].line));
        if (it == block_load.end()) continue;
        for (std::size_t s = 0; s < blocks[b].samples.size(); ++s) {
          xs.push_back(field(blocks[b].samples[s].cc));
          ys.push_back(it->second);
        }
      }
      if (xs.size() >= 3) {
        const double mx = std::accumulate(xs.begin(), xs.end(), 0.0) / static_cast<double>(xs.size());
        const double my = std::accumulate(ys.begin(), ys.end(), 0.0) / static_cast<double>(ys.size());
        double sxy = 0, sxx = 0, syy = 0;
        for (std::size_t i = 0; i < xs.size(); ++i) {
          sxy += (xs[i] - mx) * (ys[i] - my);
          sxx += (xs[i] - mx) * (xs[i] - mx);
          syy += (ys[i] - my) * (ys[i] - my);
        }
        if (sxx > 0 && syy > 0) region.rho = sxy / std::sqrt(sxx * syy);
      }
      region.type = !std::isnan(region.rho) && region.rho >= options.deflection_rho ? "deflection" : "offset";
    }
    if (!ev.systematic) continue;
    if (region.type == "deflection") {
      for (int b : region.blocks) {
        double peak = 0;
        for (const CcSample& s : blocks[b].samples) peak = std::max(peak, field(s.cc));
        const double f = std::clamp(std::pow(0.5 * half_tol / peak, 1 / options.force_exponent), 0.3, 1.0);
        phi[b] = std::min(phi.count(b) ? phi[b] : 1.0, f);
        deflection[static_cast<std::size_t>(b)] = 1;
      }
      // Taper back to 1 over 2 passes.
      for (int b : region.blocks) {
        for (int k = 1; k <= 2; ++k) {
          const std::vector<char> ring = near_blocks({b}, (k + 0.5) * geometry.pass_spacing_mm);
          for (std::size_t o = 0; o < blocks.size(); ++o) {
            if (!ring[o] || std::abs(blocks[o].pass - blocks[b].pass) != k || deflection[o]) continue;
            const double f = 1 - (1 - phi[b]) * (3 - k) / 3.0;
            phi[static_cast<int>(o)] = std::min(phi.count(static_cast<int>(o)) ? phi[static_cast<int>(o)] : 1.0, f);
          }
        }
      }
    }
    const std::vector<char> band = near_blocks(region.blocks, 2 * h);
    for (std::size_t b = 0; b < blocks.size(); ++b) edit[b] = edit[b] || band[b];
  }
  if (!ev.systematic) {
    out.notes.push_back("Moran z = " + FormatFixed(ev.moran_z, 2) + " <= " + FormatFixed(options.z_threshold, 2) +
                        ": the deviations are consistent with random error; report only, no compensation");
  }

  // The edits: split, offset, feeds.
  const double split = std::min(h / 2, 1.0), deadband = 0.1 * options.tolerance_mm;
  const double r = geometry.ball_radius_mm;
  std::map<std::size_t, std::vector<Eigen::Vector3d>> new_points;  // block -> tips of its pieces (last = end)
  std::vector<ShiftProfile> profiles(blocks.size());
  std::vector<double> shift_at_end(blocks.size(), 0.0);
  for (std::size_t b = 0; b < blocks.size(); ++b) {
    if (!edit[b]) continue;
    const CutBlock& blk = blocks[b];
    const double phi_b = phi.count(static_cast<int>(b)) ? phi[static_cast<int>(b)] : 1.0;
    const int k = std::max(1, static_cast<int>(std::ceil((blk.tip_end - blk.tip_start).norm() / split - 1e-9)));
    std::vector<Eigen::Vector3d> tips;
    const bool prev_edited = b > 0 && blocks[b - 1].pass == blk.pass && shift_at_end[b - 1] != 0;
    profiles[b].at.emplace_back(0.0, prev_edited ? shift_at_end[b - 1] : 0.0);
    for (int j = 1; j <= k; ++j) {
      const double t = static_cast<double>(j) / k;
      const Eigen::Vector3d tip = blk.tip_start + (blk.tip_end - blk.tip_start) * t;
      FL_ASSIGN_OR_RETURN(const recon::FootPoint f, nominal.Project(tip + r * Eigen::Vector3d::UnitZ()));
      double e_hat = field(f.foot) * std::pow(phi_b, options.force_exponent);
      if (std::abs(e_hat) <= deadband) e_hat = 0;
      const double d = options.gamma * e_hat;  // normal shift into the material
      if (std::abs(d) > options.max_offset_mm) {
        out.alarms.push_back("L3-COMP-LIMIT: " + parent.BlockName(blk.line) + " would move " + Mm(std::abs(d)) +
                             " mm > " + Mm(options.max_offset_mm) + " mm; nothing is edited");
        out.kind = "none";
        return out;
      }
      const Eigen::Vector3d moved = tip - d * f.normal;
      if (d != 0) {
        // Gouge check: no point of the nominal surface cut deeper than the intended shift plus t_p/2.
        FL_ASSIGN_OR_RETURN(const recon::FootPoint g, nominal.Project(moved + r * Eigen::Vector3d::UnitZ()));
        const double penetration = r - g.distance_mm;
        if (penetration > std::max(d, 0.0) + half_tol + 1e-6) {
          out.alarms.push_back("L3-GOUGE: " + parent.BlockName(blk.line) + " would cut " + Mm(penetration) +
                               " mm into the nominal surface; nothing is edited");
          out.kind = "none";
          return out;
        }
        ++out.cl_points_shifted;
        out.max_shift_mm = std::max(out.max_shift_mm, std::abs(d));
      }
      tips.push_back(moved);
      profiles[b].at.emplace_back(t, d);
    }
    const bool moved = std::any_of(profiles[b].at.begin() + 1, profiles[b].at.end(),
                                   [](const std::pair<double, double>& x) { return x.second != 0; });
    if (!moved) {  // inside the band but nothing above the dead band: the block stays as it is
      profiles[b].at.clear();
      if (prev_edited && shift_at_end[b - 1] != 0) profiles[b].at = {{0.0, shift_at_end[b - 1]}, {1.0, 0.0}};
      continue;
    }
    shift_at_end[b] = profiles[b].at.back().second;
    if (k > 1) ++out.blocks_split;
    new_points[b] = std::move(tips);
  }
  // Blocks that only start at a shifted point (the next block after an edited one).
  for (std::size_t b = 1; b < blocks.size(); ++b) {
    if (!edit[b] && blocks[b - 1].pass == blocks[b].pass && shift_at_end[b - 1] != 0) {
      profiles[b].at = {{0.0, shift_at_end[b - 1]}, {1.0, 0.0}};
    }
  }

  // The re-cut prediction at every point.
  out.predicted_e_mm.resize(points.size());
  for (std::size_t k = 0; k < points.size(); ++k) {
    const int id = nearest_sample(points[k].foot, map_radius);
    double e = points[k].deviation_mm;
    if (id >= 0) {
      const auto [b, s] = sample_ids[static_cast<std::size_t>(id)];
      const double phi_b = phi.count(b) ? phi[b] : 1.0;
      e = e * std::pow(phi_b, options.force_exponent) - profiles[b].D(blocks[b].samples[s].fraction);
    }
    out.predicted_e_mm[k] = e;
  }

  if (new_points.empty() && phi.empty()) {
    out.kind = "none";
  } else {
    EditableProgram program = parent;
    std::map<std::size_t, double> feeds;
    for (const auto& [b, f] : phi) {
      if (f >= 1) continue;
      const CutBlock& blk = blocks[static_cast<std::size_t>(b)];
      feeds[blk.move] = std::max(1.0, std::floor(f * parent.moves()[blk.move].feed_mm_per_min));
      ++out.feeds_changed;
    }
    program.SetFeeds(feeds);
    const int decimals = program.Decimals();
    auto set_tip = [&](std::size_t line, const Eigen::Vector3d& tip) {
      program.SetWord(line, 'X', FormatFixed(tip.x(), decimals));
      program.SetWord(line, 'Y', FormatFixed(tip.y(), decimals));
      program.SetWord(line, 'Z', FormatFixed(tip.z(), decimals));
    };
    // Edits from the end, so inserted lines never shift a line still to be edited.
    for (auto it = new_points.rbegin(); it != new_points.rend(); ++it) {
      const CutBlock& blk = blocks[it->first];
      const std::vector<Eigen::Vector3d>& tips = it->second;
      set_tip(blk.line, tips.back());
      if (tips.size() == 1) continue;
      const long number = parent.lines()[blk.line].number;
      long previous = -1;
      for (std::size_t l = blk.line; l-- > 0;) {
        if (parent.lines()[l].number >= 0) {
          previous = parent.lines()[l].number;
          break;
        }
      }
      const long pieces = static_cast<long>(tips.size());
      if (number >= 0 && (previous < 0 || number - previous < pieces)) {
        return Status::BadInput(Where{.file = source},
                                "no free block numbers between N" + std::to_string(previous) + " and N" +
                                    std::to_string(number) + " for " + std::to_string(pieces - 1) + " new block(s)",
                                "renumber the program with a larger increment (e.g. N10, N20, ...)");
      }
      std::vector<std::string> inserted;
      for (long j = 1; j < pieces; ++j) {
        const Eigen::Vector3d& tip = tips[static_cast<std::size_t>(j - 1)];
        std::vector<std::pair<char, std::string>> words = {{'X', FormatFixed(tip.x(), decimals)},
                                                           {'Y', FormatFixed(tip.y(), decimals)},
                                                           {'Z', FormatFixed(tip.z(), decimals)}};
        if (number >= 0) words.emplace_back('N', std::to_string(previous + (number - previous) * j / pieces));
        inserted.push_back(program.WithWords(blk.line, words));
      }
      program.InsertLines(blk.line, inserted);
    }
    const std::string parent_text = parent.Text();
    program.InsertHeaderComments({"formloop optimise program: parent sha256 " + Sha256Hex(parent_text),
                                  "inspection " + options.inspection_id + ": " + std::to_string(out.regions.size()) +
                                      " region(s), " + std::to_string(out.cl_points_shifted) + " CL point(s) offset, " +
                                      std::to_string(out.feeds_changed) + " feed(s) reduced" +
                                      (out.non_conforming ? ", for the next part (overcut)" : "")});
    FL_ASSIGN_OR_RETURN(out.program, program.Verified(source + " (adjusted)"));
    out.kind = out.non_conforming ? "next_part" : "recut";
  }
  if (out.non_conforming) {
    out.notes.push_back(
        "an overcut region (e < -t_p/2) cannot be repaired by re-cutting: the part is "
        "non-conforming; the compensation is written only into the program for the next parts");
  }

  // The §3.5 record.
  nlohmann::json pts = nlohmann::json::array();
  for (const metrology::Deviation& p : points) {
    pts.push_back({{"id", p.id},
                   {"q", Vec(p.foot)},
                   {"n", Vec(p.normal)},
                   {"c_raw", nullptr},
                   {"p", Vec(p.contact)},
                   {"e", p.deviation_mm}});
  }
  nlohmann::json regions = nlohmann::json::array();
  for (const ErrorRegion& region : out.regions) regions.push_back(region.ToJson());
  nlohmann::json actions = nlohmann::json::array();
  if (out.kind != "none") {
    actions.push_back({{"program", out.kind},
                       {"program_sha256", Sha256Hex(out.program)},
                       {"cl_points_shifted", out.cl_points_shifted},
                       {"blocks_split", out.blocks_split},
                       {"feeds_changed", out.feeds_changed},
                       {"max_shift_mm", out.max_shift_mm}});
  }
  for (const std::string& a : out.alarms) actions.push_back({{"alarm", a}});
  out.log_record = {{"inspection_id", options.inspection_id},
                    {"part_id", options.part_id},
                    {"operation_id", options.operation_id},
                    {"program_sha256", Sha256Hex(parent.Text())},
                    {"probe_calibration_id", options.probe_calibration_id},
                    {"time", options.time},
                    {"points", pts},
                    {"evaluation", ev.ToJson()},
                    {"regions", regions},
                    {"non_conforming", out.non_conforming},
                    {"actions", actions},
                    {"result_after", nullptr}};
  return out;
}

Result<std::vector<metrology::Deviation>> DeviationsFromTable(const PointSet& table, const std::string& source) {
  const char* needed[] = {"foot_x", "foot_y", "foot_z", "deviation_um"};
  for (const char* name : needed) {
    if (table.FindScalar(name) == nullptr) {
      return Status::BadInput(Where{.file = source, .field = name}, "column missing",
                              "use the deviations.csv of `formloop analyse` or of a run's loop folder");
    }
  }
  if (table.normals.size() != table.size()) {
    return Status::BadInput(Where{.file = source, .field = "nx"}, "normals (nx, ny, nz) missing");
  }
  const std::vector<double>&fx = *table.FindScalar("foot_x"), &fy = *table.FindScalar("foot_y"),
        &fz = *table.FindScalar("foot_z"), &dev = *table.FindScalar("deviation_um");
  std::vector<metrology::Deviation> out(table.size());
  for (std::size_t i = 0; i < table.size(); ++i) {
    metrology::Deviation& d = out[i];
    d.id = table.ids.empty() ? static_cast<std::int64_t>(i + 1) : table.ids[i];
    d.contact = table.points[i];
    d.normal = table.normals[i].normalized();
    d.foot = {fx[i], fy[i], fz[i]};
    d.deviation_mm = dev[i] / 1000;
  }
  return out;
}

Status ValidateInspectionRecord(const nlohmann::json& r) {
  auto bad = [](const std::string& field, const std::string& what) {
    return Status::BadInput(Where{.field = field}, what, "write records with `formloop optimise program`");
  };
  if (!r.is_object()) return bad("", "an inspection record must be a JSON object");
  for (const char* key :
       {"inspection_id", "part_id", "operation_id", "program_sha256", "probe_calibration_id", "time"}) {
    if (!r.contains(key) || !r[key].is_string()) return bad(key, "missing or not a string");
  }
  if (r["program_sha256"].get<std::string>().size() != 64) return bad("program_sha256", "not a SHA-256 in hex");
  if (!r.contains("points") || !r["points"].is_array()) return bad("points", "missing or not an array");
  for (std::size_t i = 0; i < r["points"].size(); ++i) {
    const nlohmann::json& p = r["points"][i];
    const std::string at = "points[" + std::to_string(i) + "]";
    if (!p.is_object() || !p.contains("id") || !p["id"].is_number_integer() || !p.contains("e") ||
        !p["e"].is_number()) {
      return bad(at, "needs an integer id and a number e");
    }
    for (const char* v : {"q", "n", "p"}) {
      if (!p.contains(v) || !p[v].is_array() || p[v].size() != 3) return bad(at + "." + v, "needs three numbers");
    }
  }
  if (!r.contains("evaluation") || !r["evaluation"].is_object()) return bad("evaluation", "missing or not an object");
  for (const char* key : {"PE_mm", "FE_mm", "moran_z", "sigma_rand_mm"}) {
    if (!r["evaluation"].contains(key) || !r["evaluation"][key].is_number()) {
      return bad(std::string("evaluation.") + key, "missing or not a number");
    }
  }
  for (const char* key : {"tau_mm", "omega_rad"}) {
    if (!r["evaluation"].contains(key) || !r["evaluation"][key].is_array() || r["evaluation"][key].size() != 3) {
      return bad(std::string("evaluation.") + key, "needs three numbers");
    }
  }
  if (!r.contains("regions") || !r["regions"].is_array()) return bad("regions", "missing or not an array");
  for (std::size_t i = 0; i < r["regions"].size(); ++i) {
    const nlohmann::json& g = r["regions"][i];
    if (!g.is_object() || !g.contains("type") || !g["type"].is_string() || !g.contains("block_ranges") ||
        !g["block_ranges"].is_array()) {
      return bad("regions[" + std::to_string(i) + "]", "needs a type and block_ranges");
    }
  }
  if (!r.contains("actions") || !r["actions"].is_array()) return bad("actions", "missing or not an array");
  if (!r.contains("non_conforming") || !r["non_conforming"].is_boolean()) return bad("non_conforming", "not a boolean");
  if (!r.contains("result_after")) return bad("result_after", "missing (null until the next inspection)");
  return Status::Ok();
}

Status AppendInspectionLog(const std::filesystem::path& path, const nlohmann::json& record) {
  FL_RETURN_IF_ERROR(ValidateInspectionRecord(record));
  const std::string line = record.dump() + "\n";
  const int fd = ::open(path.c_str(), O_WRONLY | O_CREAT | O_APPEND | O_CLOEXEC, 0644);
  if (fd < 0) return Status::IoError("cannot open the inspection log " + path.string() + " for appending");
  const ssize_t written = ::write(fd, line.data(), line.size());
  const bool synced = ::fsync(fd) == 0;
  ::close(fd);
  if (written != static_cast<ssize_t>(line.size()) || !synced) {
    return Status::IoError("could not append to the inspection log " + path.string());
  }
  return Status::Ok();
}

Result<std::vector<nlohmann::json>> ReadInspectionLog(const std::filesystem::path& path) {
  std::ifstream in(path);
  if (!in) return Status::NotFound("inspection log " + path.string() + " not found");
  std::vector<nlohmann::json> out;
  std::string line;
  long number = 0;
  while (std::getline(in, line)) {
    ++number;
    if (line.empty()) continue;
    FL_ASSIGN_OR_RETURN(nlohmann::json record, ParseJson(line, path.string() + ":" + std::to_string(number)));
    const Status valid = ValidateInspectionRecord(record);
    if (!valid.ok()) return Status(valid.code(), path.string() + ":" + std::to_string(number) + ": " + valid.message());
    out.push_back(std::move(record));
  }
  return out;
}

}  // namespace formloop::planning
