#include "simulation/engagement.h"

#include <algorithm>
#include <cmath>
#include <limits>

namespace formloop::sim {
namespace {

constexpr float kNoMaterial = -std::numeric_limits<float>::infinity();

}  // namespace

Status ZMapOptions::Validate() const {
  if (!(cell_mm > 0) || !(x_max_mm > x_min_mm) || !(y_max_mm > y_min_mm)) {
    return Status::BadInput("Z-map stock: the box must have x_max > x_min, y_max > y_min and a cell > 0");
  }
  if ((x_max_mm - x_min_mm) / cell_mm * (y_max_mm - y_min_mm) / cell_mm > 1e8) {
    return Status::BadInput("Z-map stock: more than 1e8 cells; use a coarser cell or a smaller box");
  }
  return Status::Ok();
}

Result<ZMapStock> ZMapStock::Create(const ZMapOptions& options) {
  FL_RETURN_IF_ERROR(options.Validate());
  ZMapStock s;
  s.options_ = options;
  s.nx_ = static_cast<int>(std::ceil((options.x_max_mm - options.x_min_mm) / options.cell_mm));
  s.ny_ = static_cast<int>(std::ceil((options.y_max_mm - options.y_min_mm) / options.cell_mm));
  s.top_.assign(static_cast<std::size_t>(s.nx_) * static_cast<std::size_t>(s.ny_), kNoMaterial);
  return s;
}

void ZMapStock::AddPrism(const std::vector<Eigen::Vector2d>& outline, double top_z) {
  if (outline.size() < 3) return;
  const double c = options_.cell_mm;
  for (int j = 0; j < ny_; ++j) {
    const double y = options_.y_min_mm + (j + 0.5) * c;
    for (int i = 0; i < nx_; ++i) {
      const double x = options_.x_min_mm + (i + 0.5) * c;
      bool inside = false;  // even-odd rule
      for (std::size_t k = 0, l = outline.size() - 1; k < outline.size(); l = k++) {
        const Eigen::Vector2d &p = outline[k], &q = outline[l];
        if ((p.y() > y) != (q.y() > y) && x < (q.x() - p.x()) * (y - p.y()) / (q.y() - p.y()) + p.x()) inside = !inside;
      }
      if (inside) top_[static_cast<std::size_t>(j) * nx_ + i] = static_cast<float>(top_z);
    }
  }
}

double ZMapStock::TopAt(double x, double y) const {
  const int i = static_cast<int>(std::floor((x - options_.x_min_mm) / options_.cell_mm));
  const int j = static_cast<int>(std::floor((y - options_.y_min_mm) / options_.cell_mm));
  if (i < 0 || j < 0 || i >= nx_ || j >= ny_) return -std::numeric_limits<double>::infinity();
  return top_[static_cast<std::size_t>(j) * nx_ + i];
}

void ZMapStock::CutDisc(double cx, double cy, double z, double r, const double* prev_cx, const double* prev_cy,
                        Removed* out) {
  const double c = options_.cell_mm, x0 = options_.x_min_mm, y0 = options_.y_min_mm;
  const int j_lo = std::max(0, static_cast<int>(std::ceil((cy - r - y0) / c - 0.5)));
  const int j_hi = std::min(ny_ - 1, static_cast<int>(std::floor((cy + r - y0) / c - 0.5)));
  const auto zf = static_cast<float>(z);
  auto interval = [&](double centre_x, double centre_y, double y, int* lo, int* hi) {
    const double dy = y - centre_y;
    if (std::abs(dy) > r) return false;
    const double half = std::sqrt(r * r - dy * dy);
    *lo = static_cast<int>(std::ceil((centre_x - half - x0) / c - 0.5));
    *hi = static_cast<int>(std::floor((centre_x + half - x0) / c - 0.5));
    return *lo <= *hi;
  };
  auto cut = [&](int j, int from, int to) {
    from = std::max(from, 0);
    to = std::min(to, nx_ - 1);
    float* row = top_.data() + static_cast<std::size_t>(j) * nx_;
    for (int i = from; i <= to; ++i) {
      if (row[i] > zf) {
        const double depth = static_cast<double>(row[i]) - z;
        out->volume_mm3 += depth * c * c;
        out->area_mm2 += c * c;
        out->max_depth_mm = std::max(out->max_depth_mm, depth);
        row[i] = zf;
      }
    }
  };
  for (int j = j_lo; j <= j_hi; ++j) {
    const double y = y0 + (j + 0.5) * c;
    int lo = 0, hi = -1, plo = 0, phi = -1;
    if (!interval(cx, cy, y, &lo, &hi)) continue;
    if (prev_cx == nullptr || !interval(*prev_cx, *prev_cy, y, &plo, &phi)) {
      cut(j, lo, hi);
      continue;
    }
    cut(j, lo, std::min(hi, plo - 1));  // the new interval less the one already cut
    cut(j, std::max(lo, phi + 1), hi);
  }
}

ZMapStock::Removed ZMapStock::CutSegment(const Eigen::Vector3d& a, const Eigen::Vector3d& b, double r, bool fresh) {
  Removed out;
  const int steps = std::max(1, static_cast<int>(std::ceil((b - a).norm() / options_.cell_mm)));
  const bool level = std::abs(b.z() - a.z()) < 1e-12;
  Eigen::Vector3d prev = a;
  if (fresh) CutDisc(a.x(), a.y(), a.z(), r, nullptr, nullptr, &out);
  for (int k = 1; k <= steps; ++k) {
    const Eigen::Vector3d p = a + (b - a) * (static_cast<double>(k) / steps);
    // Off the level the previous disc was cut to another height: cut the whole disc.
    if (level) {
      CutDisc(p.x(), p.y(), p.z(), r, &prev.x(), &prev.y(), &out);
    } else {
      CutDisc(p.x(), p.y(), p.z(), r, nullptr, nullptr, &out);
    }
    prev = p;
  }
  return out;
}

Result<PathEngagement> EngagementAlongPath(ZMapStock* stock, const std::vector<Eigen::Vector3d>& tips,
                                           const std::vector<bool>& fed, double r, double piece_mm) {
  if (tips.size() != fed.size()) return Status::Internal("EngagementAlongPath: tips and fed differ in size");
  if (!(r > 0) || !(piece_mm > 0)) return Status::BadInput("EngagementAlongPath: tool radius and piece must be > 0");
  PathEngagement out;
  out.segment_a_e_max_mm.assign(tips.size(), 0.0);
  out.segment_a_p_max_mm.assign(tips.size(), 0.0);
  std::vector<EngagementSample> samples;
  double s = 0;
  bool fresh = true;
  for (std::size_t i = 1; i < tips.size(); ++i) {
    if (!fed[i] || !tips[i - 1].allFinite() || !tips[i].allFinite()) {
      fresh = true;
      continue;
    }
    const Eigen::Vector3d a = tips[i - 1], b = tips[i];
    const double xy = (b - a).head<2>().norm();
    const int pieces = std::max(1, static_cast<int>(std::ceil(xy / piece_mm)));
    for (int k = 0; k < pieces; ++k) {
      const Eigen::Vector3d pa = a + (b - a) * (static_cast<double>(k) / pieces);
      const Eigen::Vector3d pb = a + (b - a) * (static_cast<double>(k + 1) / pieces);
      const ZMapStock::Removed cut = stock->CutSegment(pa, pb, r, fresh);
      fresh = false;
      out.segment_a_p_max_mm[i] = std::max(out.segment_a_p_max_mm[i], cut.max_depth_mm);
      if (xy <= 0) continue;  // a plunge: it cuts, but the path length does not advance
      const double ds = xy / pieces;
      const double a_e = cut.area_mm2 / ds, a_p = cut.area_mm2 > 0 ? cut.volume_mm3 / cut.area_mm2 : 0.0;
      out.segment_a_e_max_mm[i] = std::max(out.segment_a_e_max_mm[i], a_e);
      samples.push_back({s + 0.5 * ds, a_e, a_p});
      s += ds;
    }
  }
  if (samples.size() < 2) return Status::BadInput("the tool path has fewer than two pieces of feed in XY");
  FL_ASSIGN_OR_RETURN(out.profile, EngagementProfile::Create(std::move(samples)));
  return out;
}

}  // namespace formloop::sim
